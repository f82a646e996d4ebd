//! Embeds the benchmark frames and sets up the QEMU memory map, for the MCU target only.
//!
//! `INSNS_TAKE_DIR` names a take directory of the stereoboard_testing layout (`1.bmp`, `2.bmp`,
//! ...); `INSNS_FRAMES` how many consecutive frames to embed (default 8). The BMPs (256x96,
//! 8-bit, bottom-up, right camera in the left half) are converted to the camera's interleaved
//! `[L0 R0 L1 R1 ...]` layout. `cargo xtask insns` sets both; without them no frame is embedded
//! and the firmware reports that and fails. `INSNS_WORST_FRAMES` (read by the firmware itself)
//! names the host file of frames it streams over semihosting for the worst frame.

use std::{env, fs, path::PathBuf};

#[path = "bmp.rs"]
mod bmp;
use bmp::interleave;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=bmp.rs");
    println!("cargo:rerun-if-env-changed=INSNS_TAKE_DIR");
    println!("cargo:rerun-if-env-changed=INSNS_FRAMES");
    println!("cargo:rerun-if-env-changed=INSNS_WORST_FRAMES");
    let out = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    let mut blob = Vec::new();
    if let Ok(dir) = env::var("INSNS_TAKE_DIR") {
        let count: usize = env::var("INSNS_FRAMES")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(8);
        for k in 1..=count {
            let path = PathBuf::from(&dir).join(format!("{k}.bmp"));
            println!("cargo:rerun-if-changed={}", path.display());
            let bmp = fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            blob.extend(interleave(&bmp).unwrap_or_else(|e| panic!("{}: {e}", path.display())));
        }
    }
    fs::write(out.join("frames.bin"), &blob).expect("write frames.bin");

    if env::var("CARGO_CFG_TARGET_OS").as_deref() == Ok("none") {
        let map = PathBuf::from(env::var("CARGO_MANIFEST_DIR").expect("manifest dir"))
            .join("../../stereo-board/memory-qemu.x");
        println!("cargo:rerun-if-changed={}", map.display());
        fs::copy(&map, out.join("memory.x")).expect("copy the QEMU memory map");
        println!("cargo:rustc-link-search={}", out.display());
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
}
