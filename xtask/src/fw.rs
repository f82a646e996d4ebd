//! `cargo xtask fw` and `cargo xtask flash`: per-board firmware builds and flashing.
//!
//! ```text
//! cargo xtask fw [camera|autopilot] [--flavour real|qemu|hil]
//! cargo xtask flash camera|autopilot [--no-build] [--key FILE]
//! ```
//!
//! Each board has its own part (the camera board an STM32F407VG, the autopilot an STM32F415RG)
//! and so its own HAL chip feature. Cargo unifies features within one invocation, so the two
//! firmwares cannot build in one `cargo build`: `fw` runs one invocation per board (release,
//! thumbv7em-none-eabihf, both linked by flip-link, see `.cargo/config.toml`). Without a board
//! it builds both. The images land in `target/firmware/<flavour>/` (printed after the build);
//! all flavours share the workspace's target directory, see [`crate::size::build_firmware`].
//!
//! `flash` builds the real flavour and runs `probe-rs run --chip <part>` on it: it flashes over
//! SWD (ST-Link or CMSIS-DAP), resets the board and prints its defmt log over RTT. With
//! `--key FILE` (the autopilot only) it first writes the host link key in FILE (`sim-host key
//! new`) into the board's parameter flash beside the saved parameters ([`crate::keyflash`]),
//! so the firmware boots keyed.

use crate::keyflash;
use crate::size::{build_firmwares, firmware_elf, Flavour};
use anyhow::{bail, Context, Result};
use std::path::PathBuf;
use std::process::Command;

/// A board of the drone.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Board {
    /// The TU Delft stereo camera board.
    Camera,
    /// The Paparazzi Lisa/MX 2.1 autopilot.
    Autopilot,
}

impl Board {
    /// Both boards, in build order.
    pub const ALL: [Board; 2] = [Board::Camera, Board::Autopilot];

    /// Parses `camera` (or the package name `stereo-board`) and `autopilot`.
    pub fn parse(s: &str) -> Result<Self> {
        Ok(match s {
            "camera" | "stereo-board" => Self::Camera,
            "autopilot" => Self::Autopilot,
            other => bail!("unknown board {other:?} (camera, autopilot)"),
        })
    }

    /// The board's cargo package (and firmware binary) name.
    pub fn package(self) -> &'static str {
        match self {
            Self::Camera => "stereo-board",
            Self::Autopilot => "autopilot",
        }
    }

    /// The probe-rs name of the board's part.
    pub fn probe_rs_chip(self) -> &'static str {
        match self {
            // STM32F407VG in LQFP100 ([SB] stm32_flash.ld, Makefile).
            Self::Camera => "STM32F407VGTx",
            // STM32F415RG in LQFP64 (Lisa/MX 2.1).
            Self::Autopilot => "STM32F415RGTx",
        }
    }
}

/// Runs `cargo xtask fw`.
pub fn run(args: &[String]) -> Result<()> {
    let mut boards = Vec::new();
    let mut flavour = Flavour::Real;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--flavour" | "--flavor" => {
                flavour = Flavour::parse(it.next().context("--flavour needs a value")?)?
            }
            other => boards.push(Board::parse(other)?),
        }
    }
    if boards.is_empty() {
        boards.extend(Board::ALL);
    }
    let names: Vec<&str> = boards.iter().map(|b| b.package()).collect();
    build_firmwares(flavour, &names)?;
    for name in names {
        println!("{}", firmware_elf(flavour, name).display());
    }
    Ok(())
}

/// Runs `cargo xtask flash`.
pub fn flash(args: &[String]) -> Result<()> {
    let mut board = None;
    let mut build = true;
    let mut key_file = None;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--no-build" => build = false,
            "--key" => key_file = Some(PathBuf::from(it.next().context("--key needs a file")?)),
            other => board = Some(Board::parse(other)?),
        }
    }
    let board =
        board.context("usage: cargo xtask flash camera|autopilot [--no-build] [--key FILE]")?;
    // The key file is read before anything is built or touched on the board.
    let key = match &key_file {
        Some(file) if board == Board::Autopilot => Some(keyflash::load_key_file(file)?),
        Some(_) => bail!("--key: only the autopilot holds the host link key"),
        None => None,
    };
    if build {
        build_firmwares(Flavour::Real, &[board.package()])?;
    }
    if let Some(key) = key {
        let chip = board.probe_rs_chip();
        let slots = keyflash::read_slots(chip)?;
        let write = keyflash::key_write(key, [&slots[0], &slots[1]], now_signing_timestamp())?;
        keyflash::program(chip, &write)?;
        println!(
            "link key written into parameter slot {} ({:#010x}) as record {}, parameters kept",
            write.slot, write.address, write.sequence
        );
    }
    let elf = firmware_elf(Flavour::Real, board.package());
    let status = Command::new("probe-rs")
        .args(["run", "--chip", board.probe_rs_chip()])
        .arg(&elf)
        .status()
        .context("starting probe-rs (install it once: cargo install probe-rs-tools --locked)")?;
    if !status.success() {
        bail!("probe-rs run failed with {status}");
    }
    Ok(())
}

/// The signing clock now (10 µs units since 2015-01-01 UTC): the replay floor of a key written
/// over SWD.
fn now_signing_timestamp() -> u64 {
    let unix_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64);
    protocol::signing::timestamp_from_unix_us(unix_us)
}
