//! `cargo xtask vboard`: the virtual-board bench (`virtual-board/`).
//!
//! Builds both `real` firmwares (`cargo xtask fw`) and both `hil`-flavour ones (`cargo xtask fw
//! --flavour hil`, for the test that flies them with `sim-host hil`), then runs `cargo test
//! --ignore-rust-version --release` in `virtual-board/`, its own workspace (rigless declares
//! rust-version 1.98; we build it on 1.95 with that flag, which stays out of the main
//! workspace), and prints a one-line summary. It builds `sim-host` first, for the test that
//! serves the virtual autopilot to `sim-host monitor`. Extra arguments go to that `cargo test`
//! (a test name filter, `-- --nocapture`).

use anyhow::{bail, Context, Result};
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use crate::cargo::{cargo, cargo_test_with};
use crate::size::{build_firmwares, firmware_dir, Flavour, FIRMWARES};

fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("xtask sits in the workspace")
        .to_path_buf()
}

/// The virtual-board bench's directory (its own workspace).
pub fn bench_dir() -> PathBuf {
    workspace_root().join("virtual-board")
}

/// The main workspace's target directory.
fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map_or_else(|| workspace_root().join("target"), PathBuf::from)
}

/// Runs `cargo xtask vboard [ARGS]`.
pub fn run(args: &[String]) -> Result<()> {
    let started = Instant::now();
    let (passed, failed) = run_tests_with(args)?;
    println!(
        "xtask vboard: OK in {:.0} s: {passed} virtual-board tests passed",
        started.elapsed().as_secs_f64()
    );
    println!("{passed} passed, {failed} failed");
    Ok(())
}

/// Builds the firmwares and runs every virtual-board test (for `cargo xtask test`).
/// Builds what the bench runs (both firmwares in the `real` and `hil` flavours, and `sim-host`),
/// then builds and runs the bench's tests with `args`.
fn run_tests_with(args: &[String]) -> Result<(u64, u64)> {
    let build = Instant::now();
    build_firmwares(Flavour::Real, &FIRMWARES).context("firmware build (cargo xtask fw) failed")?;
    build_firmwares(Flavour::Hil, &FIRMWARES)
        .context("firmware build (cargo xtask fw --flavour hil) failed")?;
    cargo(&["build", "-p", "sim-host"]).context("building sim-host failed")?;
    let built = build.elapsed().as_secs_f64();
    let tests = Instant::now();
    let result = run_built_tests(args);
    eprintln!(
        "xtask vboard: firmware build {built:.0} s, bench build and run {:.0} s",
        tests.elapsed().as_secs_f64()
    );
    result
}

/// `cargo test` in the bench with `args`, against the firmware images and the `sim-host` binary
/// already built (the debug `sim-host`, which `cargo test --workspace` also builds).
pub fn run_built_tests(args: &[String]) -> Result<(u64, u64)> {
    let sim_host = sim_host_binary();
    if !sim_host.is_file() {
        bail!(
            "{} is missing: build it first (cargo build -p sim-host)",
            sim_host.display()
        );
    }
    let mut cmd = bench_test_command();
    cmd.args(args);
    cargo_test_with(&mut cmd).context("virtual-board tests failed")
}

/// `cargo test --ignore-rust-version --release` in the bench, with the environment that points
/// it at the firmware images and `sim-host`.
pub fn bench_test_command() -> Command {
    let mut cmd = Command::new("cargo");
    cmd.args(["test", "--ignore-rust-version", "--release"])
        .current_dir(bench_dir())
        .env("VBOARD_FIRMWARE_DIR", firmware_dir(Flavour::Real))
        .env("VBOARD_HIL_FIRMWARE_DIR", firmware_dir(Flavour::Hil))
        .env("VBOARD_SIM_HOST", sim_host_binary());
    cmd
}

/// The debug `sim-host` binary the bench's monitor test serves the virtual autopilot to.
fn sim_host_binary() -> PathBuf {
    target_dir().join("debug").join("sim-host")
}
