//! Linker set-up for a firmware binary, run from its `build.rs`.

use std::{env, fs, path::PathBuf};

/// Only when building for the MCU (`target_os = "none"`): picks the memory map of the flavour
/// (`memory.x`, or `memory-qemu.x` with feature `qemu`, both in the package directory) and
/// passes cortex-m-rt's `link.x` and defmt's `defmt.x` to the linker of the binary only. Host
/// builds (library, tests, the stub binary) get nothing.
pub fn link_firmware() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=memory-qemu.x");
    if env::var("CARGO_CFG_TARGET_OS").as_deref() != Ok("none") {
        return;
    }
    let map = if env::var_os("CARGO_FEATURE_QEMU").is_some() {
        "memory-qemu.x"
    } else {
        "memory.x"
    };
    let out = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::copy(map, out.join("memory.x")).expect("copy the memory map into OUT_DIR");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
}
