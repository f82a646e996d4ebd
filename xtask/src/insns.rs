//! `cargo xtask insns`: exact Cortex-M4 instruction counts per call, measured in QEMU.
//!
//! 1. Builds the project's QEMU TCG plugin (`xtask/qemu-plugin/insn_markers.c`) with gcc.
//! 2. Builds the benchmark firmware (`xtask/insns-firmware`, release profile, thumbv7em) with
//!    real frames of a recorded take embedded.
//! 3. Runs it on `qemu-system-arm -M netduinoplus2` with the plugin, which counts the
//!    instructions executed between the firmware's `insns_begin` and `insns_end` markers.
//! 4. Pairs the counts with the measurement names the firmware prints, subtracts the cost of an
//!    empty measurement and prints one `NAME INSTRUCTIONS` line per function (the median over
//!    repeated measurements; for whole Edge-FS frames, over the frames after the history is
//!    full).
//!
//! 5. With the default take and frame count, compares every figure with its expectation in
//!    `xtask/budgets.toml` and fails on a regression (or an unrecorded improvement) beyond the
//!    stated tolerance, or on a hard limit (see [`crate::budget`]).
//!
//! Options: `--take DIR` (a take directory of the stereoboard_testing layout; default: board 1
//! take 1 in `../shared/data` beside the checkout), `--frames N` (default 16), `--runs N` (run the
//! measurement N times and fail unless every run gives identical counts; default 1). Another
//! take or frame count measures other frames, so the budget comparison is skipped then.

use crate::size::workspace_root;
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// Frames measured by default (the budgets are for this count on the default take).
const DEFAULT_FRAMES: usize = 16;

/// Names measured, in print order.
const REPORT_ORDER: &[&str] = &[
    "edge_fs_frame_default",
    "edge_fs_frame_paper",
    "edge_histograms",
    "row_histogram",
    "flow_row_vertical",
    "stereo_match",
    "flow_match",
    "stereo_row",
    "flow_row",
    "line_fit",
    "line_fit_paper",
    "indi_step",
    "guidance_fsm_step",
    "estimate_encode",
    "estimate_decode",
    "gyro_decode",
];

/// Frame rate of the camera, Hz: the budget is per frame at this rate.
const FRAME_HZ: f64 = 25.0;
/// Gyro/attitude messages (128 Hz) that can arrive within one frame period (128 / 25, rounded
/// up).
const GYRO_PER_FRAME: u64 = 6;
/// Core clock of the camera board's STM32F407, Hz.
const CPU_HZ: f64 = 168e6;
/// Conservative cycles per instruction for this integer/FPU code on the M4 with the ART
/// accelerator (see docs/performance.md).
const CYCLES_PER_INSN: f64 = 1.5;

/// Runs `cargo xtask insns`.
pub fn run(args: &[String]) -> Result<()> {
    let default_take = workspace_root()
        .join("../shared/data/stereoboard_testing/database_stereoboard_1/forward_camera/take1");
    let mut take = default_take.clone();
    let mut frames = DEFAULT_FRAMES;
    let mut runs = 1usize;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        let mut value = || it.next().context("option needs a value");
        match arg.as_str() {
            "--take" => take = PathBuf::from(value()?),
            "--frames" => frames = value()?.parse().context("--frames N")?,
            "--runs" => runs = value()?.parse().context("--runs N")?,
            other => bail!("unknown option {other} (--take DIR, --frames N, --runs N)"),
        }
    }
    if frames < 10 {
        bail!("--frames must be at least 10 (the Edge-FS history must fill first)");
    }
    if !take.join("1.bmp").is_file() {
        bail!(
            "{}: no take there (expected 1.bmp ...); pass --take DIR",
            take.display()
        );
    }
    let plugin = build_plugin()?;
    let elf = build_firmware(&take, frames)?;
    let (begin, end) = marker_addresses(&elf)?;
    let mut first: Option<BTreeMap<String, Vec<u64>>> = None;
    for run in 0..runs.max(1) {
        let samples = measure(&elf, &plugin, begin, end)?;
        match &first {
            None => first = Some(samples),
            Some(f) if *f == samples => {}
            Some(_) => bail!(
                "run {} gave different instruction counts than run 1",
                run + 1
            ),
        }
    }
    let samples = first.context("no run")?;
    let skip = frames / 2;
    let mut counts = BTreeMap::new();
    for name in REPORT_ORDER {
        let values = samples
            .get(*name)
            .with_context(|| format!("no measurement named {name}"))?;
        let values = if name.starts_with("edge_fs_frame") {
            values.get(skip..).unwrap_or(&[])
        } else {
            &values[..]
        };
        let count = median(values).context("no samples")?;
        println!("{name} {count}");
        counts.insert(*name, count);
    }
    // The camera board's work per frame: one default Edge-FS frame, one estimate encoded and
    // the gyro messages of one frame period decoded.
    let per_frame = counts["edge_fs_frame_default"]
        + counts["estimate_encode"]
        + GYRO_PER_FRAME * counts["gyro_decode"];
    println!("camera_board_frame {per_frame}");
    let budget = CPU_HZ / FRAME_HZ;
    let percent = 100.0 * per_frame as f64 * CYCLES_PER_INSN / budget;
    println!(
        "camera_board_frame_percent {percent:.1} (x {CYCLES_PER_INSN} cycles/insn = {:.0} of the \
         {budget:.0} cycles of a {FRAME_HZ} fps frame at 168 MHz)",
        per_frame as f64 * CYCLES_PER_INSN,
    );
    if runs > 1 {
        println!("deterministic: {runs} runs gave identical counts");
    }
    let same_take = take.canonicalize().ok() == default_take.canonicalize().ok();
    if !same_take || frames != DEFAULT_FRAMES {
        println!("budget: not compared (another take or frame count than the budgeted one)");
        return Ok(());
    }
    let mut measured: BTreeMap<String, f64> = counts
        .iter()
        .map(|(name, count)| ((*name).to_string(), *count as f64))
        .collect();
    measured.insert("camera_board_frame".into(), per_frame as f64);
    measured.insert(
        "camera_board_frame_percent".into(),
        (percent * 10.0).round() / 10.0,
    );
    crate::budget::check("insns", &crate::budget::load()?.insns, &measured)
}

fn median(values: &[u64]) -> Option<u64> {
    let mut v = values.to_vec();
    v.sort_unstable();
    v.get(v.len() / 2).copied()
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target"))
}

fn build_plugin() -> Result<PathBuf> {
    let src = workspace_root().join("xtask/qemu-plugin/insn_markers.c");
    let out_dir = target_dir().join("insns");
    std::fs::create_dir_all(&out_dir)?;
    let out = out_dir.join("insn_markers.so");
    let status = Command::new("gcc")
        .args([
            "-shared",
            "-fPIC",
            "-O2",
            "-fvisibility=hidden",
            "-Wall",
            "-Wextra",
            "-o",
        ])
        .arg(&out)
        .arg(&src)
        .status()
        .context("running gcc (needed to build the QEMU plugin)")?;
    if !status.success() {
        bail!("gcc failed to build {}", src.display());
    }
    Ok(out)
}

fn build_firmware(take: &Path, frames: usize) -> Result<PathBuf> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(cargo)
        .current_dir(workspace_root())
        .args([
            "build",
            "--release",
            "--target",
            "thumbv7em-none-eabihf",
            "-p",
            "insns-firmware",
        ])
        // The benchmark is not flight firmware: it keeps its large statics and deep stack in
        // the default layout (rust-lld, stack at the top of SRAM) rather than flip-link's.
        .env("CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER", "rust-lld")
        .env("INSNS_TAKE_DIR", take)
        .env("INSNS_FRAMES", frames.to_string())
        .status()
        .context("running cargo build")?;
    if !status.success() {
        bail!("building the benchmark firmware failed");
    }
    Ok(target_dir().join("thumbv7em-none-eabihf/release/insns-firmware"))
}

/// Runs the firmware once under the plugin; returns the counts per measurement name, in order,
/// with the empty-measurement baseline subtracted.
fn measure(elf: &Path, plugin: &Path, begin: u32, end: u32) -> Result<BTreeMap<String, Vec<u64>>> {
    let log = elf.with_extension("plugin.log");
    let _ = std::fs::remove_file(&log);
    let mut child = Command::new("qemu-system-arm")
        .args([
            "-M",
            "netduinoplus2",
            "-nographic",
            "-monitor",
            "none",
            "-serial",
            "null",
        ])
        .args(["-semihosting-config", "enable=on,target=native"])
        .arg("-kernel")
        .arg(elf)
        .arg("-plugin")
        .arg(format!(
            "{},begin={begin:#x},end={end:#x}",
            plugin.display()
        ))
        .args(["-d", "plugin", "-D"])
        .arg(&log)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .context("starting qemu-system-arm (cargo xtask test installs it)")?;
    let deadline = std::time::Instant::now() + Duration::from_secs(900);
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            bail!("QEMU did not finish within 15 minutes");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let mut stdout = String::new();
    if let Some(mut out) = child.stdout.take() {
        use std::io::Read;
        out.read_to_string(&mut stdout)?;
    }
    if !status.success() {
        bail!("benchmark firmware failed ({status}):\n{stdout}");
    }
    for line in stdout.lines().filter(|l| !l.starts_with("measure ")) {
        eprintln!("firmware: {line}");
    }
    let names: Vec<&str> = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("measure "))
        .collect();
    let plugin_out = std::fs::read_to_string(&log)
        .with_context(|| format!("reading the plugin log {}", log.display()))?;
    let counts: Vec<u64> = plugin_out
        .lines()
        .filter_map(|l| l.strip_prefix("insns "))
        .filter_map(|l| l.split_whitespace().nth(1)?.parse().ok())
        .collect();
    if names.len() != counts.len() || names.first() != Some(&"baseline") {
        bail!(
            "{} measurement names but {} counts (firmware output:\n{stdout})",
            names.len(),
            counts.len()
        );
    }
    let baseline = counts[0];
    let mut samples: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    for (name, count) in names.iter().zip(&counts).skip(1) {
        samples
            .entry((*name).to_string())
            .or_default()
            .push(count.saturating_sub(baseline));
    }
    Ok(samples)
}

/// Addresses of the `insns_begin` and `insns_end` functions, from the ELF symbol table.
fn marker_addresses(elf_path: &Path) -> Result<(u32, u32)> {
    let elf = std::fs::read(elf_path).with_context(|| format!("reading {}", elf_path.display()))?;
    let begin = symbol(&elf, "insns_begin")?;
    let end = symbol(&elf, "insns_end")?;
    if begin == end {
        bail!("insns_begin and insns_end share an address: the markers were folded");
    }
    Ok((begin, end))
}

/// Value of a symbol in an ELF32 little-endian file.
fn symbol(elf: &[u8], wanted: &str) -> Result<u32> {
    let u16_at = |at: usize| -> Result<usize> {
        Ok(u16::from_le_bytes(elf.get(at..at + 2).context("ELF truncated")?.try_into()?) as usize)
    };
    let u32_at = |at: usize| -> Result<usize> {
        Ok(u32::from_le_bytes(elf.get(at..at + 4).context("ELF truncated")?.try_into()?) as usize)
    };
    if elf.get(..4) != Some(b"\x7fELF".as_slice()) {
        bail!("not an ELF file");
    }
    let (shoff, shentsize, shnum) = (u32_at(0x20)?, u16_at(0x2e)?, u16_at(0x30)?);
    const SHT_SYMTAB: usize = 2;
    for i in 0..shnum {
        let h = shoff + i * shentsize;
        if u32_at(h + 0x04)? != SHT_SYMTAB {
            continue;
        }
        let (offset, size, link) = (u32_at(h + 0x10)?, u32_at(h + 0x14)?, u32_at(h + 0x18)?);
        let strtab = u32_at(shoff + link * shentsize + 0x10)?;
        for entry in (offset..offset + size).step_by(16) {
            let name_off = u32_at(entry)?;
            let name = elf
                .get(strtab + name_off..)
                .and_then(|s| s.split(|&c| c == 0).next())
                .unwrap_or_default();
            if name == wanted.as_bytes() {
                return Ok(u32_at(entry + 4)? as u32);
            }
        }
    }
    bail!("symbol {wanted} not found")
}
