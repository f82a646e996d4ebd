//! Embeds the benchmark frames and sets up the QEMU memory map, for the MCU target only.
//!
//! `INSNS_TAKE_DIR` names a take directory of the stereoboard_testing layout (`1.bmp`, `2.bmp`,
//! ...); `INSNS_FRAMES` how many consecutive frames to embed (default 8). The BMPs (256x96,
//! 8-bit, bottom-up, right camera in the left half) are converted to the camera's interleaved
//! `[L0 R0 L1 R1 ...]` layout. `cargo xtask insns` sets both; without them no frame is embedded
//! and the firmware reports that and fails.

use std::{env, fs, path::PathBuf};

const W: usize = 128;
const H: usize = 96;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=INSNS_TAKE_DIR");
    println!("cargo:rerun-if-env-changed=INSNS_FRAMES");
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

/// Converts one data-set BMP into an interleaved 128x96 stereo frame.
fn interleave(bmp: &[u8]) -> Result<Vec<u8>, String> {
    let u32_at = |at: usize| -> Result<u32, String> {
        bmp.get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| "truncated header".to_string())
    };
    let offset = u32_at(10)? as usize;
    let (width, height) = (u32_at(18)? as i32, u32_at(22)? as i32);
    let bpp = bmp.get(28).copied().unwrap_or(0);
    if width != 2 * W as i32 || height.unsigned_abs() as usize != H || bpp != 8 {
        return Err(format!(
            "expected 256x96 8-bit, got {width}x{height} {bpp}-bit"
        ));
    }
    let pixels = bmp
        .get(offset..offset + 2 * W * H)
        .ok_or("truncated pixel data")?;
    let mut frame = vec![0u8; 2 * W * H];
    for row in 0..H {
        let src_row = if height > 0 { H - 1 - row } else { row };
        let src = &pixels[src_row * 2 * W..(src_row + 1) * 2 * W];
        for c in 0..W {
            frame[2 * (row * W + c)] = src[W + c]; // left camera: right half of the BMP
            frame[2 * (row * W + c) + 1] = src[c]; // right camera: left half
        }
    }
    Ok(frame)
}
