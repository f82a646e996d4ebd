//! Linker set-up for the firmware binary (shared with the other board: `board_support::build`),
//! only when building for the MCU (`target_os = "none"`):
//! picks the memory map of the flavour (`memory.x`, or `memory-qemu.x` with feature `qemu`) and
//! passes cortex-m-rt's `link.x` and defmt's `defmt.x` to the linker of the binary only. Host
//! builds (library, tests, the stub binary) get nothing.

fn main() {
    board_support::build::link_firmware();
}
