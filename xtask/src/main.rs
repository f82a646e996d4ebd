//! `cargo xtask`: project orchestration.
//!
//! * `cargo xtask test`: the CI test command (installs what a fresh machine lacks, then runs
//!   fmt, clippy on host and thumbv7em, all host tests, firmware builds, a bounded fuzz run).
//! * `cargo xtask fw [camera|autopilot]`: build the firmwares (one cargo invocation per board).
//! * `cargo xtask flash camera|autopilot [--key FILE]`: build and flash one board with
//!   probe-rs; `--key` first writes the host link key into the autopilot's parameter flash
//!   ([`keyflash`]).
//! * `cargo xtask size`: static flash/RAM/CCM use of each firmware, against its budget.
//! * `cargo xtask qemu`: build a firmware flavour and run it in QEMU.
//! * `cargo xtask vboard`: build both real firmwares and run them on the virtual boards
//!   (`virtual-board/`, its own workspace), with a one-line summary.
//! * `cargo xtask insns`: exact Cortex-M4 instruction counts per call (QEMU plugin), against
//!   their budgets.
//!
//! The budgets are `xtask/budgets.toml` (see [`budget`]).

mod budget;
mod cargo;
mod ci;
mod elf;
mod fw;
mod insns;
mod keyflash;
mod qemu;
mod size;
mod vboard;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (command, rest) = args
        .split_first()
        .map(|(c, r)| (c.as_str(), r))
        .unwrap_or(("help", &[]));
    match command {
        "test" => ci::run(rest),
        "fw" => fw::run(rest),
        "flash" => fw::flash(rest),
        "size" => size::run(rest),
        "qemu" => qemu::run(rest),
        "insns" => insns::run(rest),
        "vboard" => vboard::run(rest),
        _ => {
            eprintln!("usage: cargo xtask <test|fw|flash|size|qemu|insns|vboard> [ARGS]");
            std::process::exit(2)
        }
    }
}
