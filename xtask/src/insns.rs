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
//! 5. Streams every frame of every shipped take (`../shared/data/stereoboard_testing`, each
//!    take from an empty history) and adversarial sequences ([`adversarial`]: all texture, all
//!    noise, saturated, every column usable) through a default-mode Edge-FS, one frame at a time
//!    over semihosting from a host file, and reports the most expensive frame as
//!    `edge_fs_frame_worst`, with the frame it was.
//!
//! 6. With the default take and frame count, compares every figure with its expectation in
//!    `xtask/budgets.toml` and fails on a regression (or an unrecorded improvement) beyond the
//!    stated tolerance, or on a hard limit (see [`crate::budget`]).
//!
//! Options: `--take DIR` (a take directory of the stereoboard_testing layout; default: board 1
//! take 1 in `../shared/data` beside the checkout), `--frames N` (default 16), `--runs N` (run the
//! measurement N times and fail unless every run gives identical counts; default 1). Another
//! take or frame count measures other frames, so the budget comparison is skipped then.

use crate::cargo::workspace_root;
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
    "edge_fs_frame_vertical",
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

/// Frames of each adversarial sequence (enough to fill the Edge-FS history and run on it).
const ADVERSARIAL_FRAMES: usize = 16;

/// The data set's takes.
fn data_set() -> PathBuf {
    workspace_root().join("../shared/data/stereoboard_testing")
}

#[path = "../insns-firmware/bmp.rs"]
mod bmp;

/// A sequence of interleaved stereo frames streamed to the benchmark from an empty history.
struct Sequence {
    /// Where it comes from (a take's directory, or the adversarial pattern's name).
    name: String,
    /// The frames, interleaved `[L0 R0 L1 R1 ...]`, 128x96.
    frames: Vec<Vec<u8>>,
}

/// Every take of the data set (`*/forward_camera/take*`), each with all its frames in order.
fn shipped_takes(root: &Path) -> Result<Vec<Sequence>> {
    let mut takes = Vec::new();
    for board in sorted_dirs(root)? {
        let camera = board.join("forward_camera");
        if !camera.is_dir() {
            continue;
        }
        for take in sorted_dirs(&camera)? {
            let mut numbered = Vec::new();
            for entry in std::fs::read_dir(&take)? {
                let path = entry?.path();
                let number = path
                    .extension()
                    .filter(|e| *e == "bmp")
                    .and(path.file_stem())
                    .and_then(|s| s.to_str()?.parse::<u32>().ok());
                if let Some(number) = number {
                    numbered.push((number, path));
                }
            }
            numbered.sort();
            let mut frames = Vec::new();
            for (_, path) in &numbered {
                let bytes =
                    std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
                frames.push(
                    bmp::interleave(&bytes)
                        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?,
                );
            }
            if !frames.is_empty() {
                takes.push(Sequence {
                    name: take
                        .strip_prefix(root)
                        .unwrap_or(&take)
                        .display()
                        .to_string(),
                    frames,
                });
            }
        }
    }
    if takes.is_empty() {
        bail!("no take under {}", root.display());
    }
    Ok(takes)
}

fn sorted_dirs(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| Some(e.ok()?.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    Ok(dirs)
}

/// Frames made to be expensive, [`ADVERSARIAL_FRAMES`] each, moving one pixel a frame (so the
/// flow has something to match) with the right camera 4 px behind the left (a disparity):
///
/// * all texture: alternate columns black and white, an edge at every column;
/// * all noise: every pixel of every frame random;
/// * saturated: every pixel 255;
/// * every column usable: each column its own grey level (a random one, fixed), so every
///   column's edge is distinct and matches once, in stereo and in flow.
pub fn adversarial() -> Vec<(String, Vec<Vec<u8>>)> {
    let (w, h) = (bmp::W, bmp::H);
    let frame = |pixel: &mut dyn FnMut(usize, usize, bool) -> u8| {
        let mut f = vec![0u8; 2 * w * h];
        for row in 0..h {
            for c in 0..w {
                f[2 * (row * w + c)] = pixel(row, c, false);
                f[2 * (row * w + c) + 1] = pixel(row, c, true);
            }
        }
        f
    };
    // xorshift64*: a fixed sequence, so the figure is the same on every run.
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut random = move || {
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 56) as u8
    };
    let levels: Vec<u8> = (0..w + ADVERSARIAL_FRAMES + 8).map(|_| random()).collect();
    let shift = |c: usize, k: usize, right: bool| c + k + if right { 4 } else { 0 };
    let mut out = Vec::new();
    let sequence = |pixel: &mut dyn FnMut(usize, usize, usize, bool) -> u8| {
        (0..ADVERSARIAL_FRAMES)
            .map(|k| frame(&mut |row, c, right| pixel(row, c, k, right)))
            .collect::<Vec<_>>()
    };
    out.push((
        "all texture".to_string(),
        sequence(&mut |_, c, k, right| {
            if shift(c, k, right) % 2 == 0 {
                0
            } else {
                255
            }
        }),
    ));
    out.push((
        "all noise".to_string(),
        sequence(&mut |_, _, _, _| random()),
    ));
    out.push(("saturated".to_string(), sequence(&mut |_, _, _, _| 255)));
    out.push((
        "every column usable".to_string(),
        sequence(&mut |_, c, k, right| levels[shift(c, k, right)]),
    ));
    out
}

/// Writes the worst-frame file the benchmark streams: per frame a flag byte (1: the first of
/// its sequence) and the frame. Returns each record's label.
fn write_worst_frames(path: &Path, sequences: &[Sequence]) -> Result<Vec<String>> {
    use std::io::Write;
    let file =
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    let mut labels = Vec::new();
    for sequence in sequences {
        for (k, frame) in sequence.frames.iter().enumerate() {
            out.write_all(&[u8::from(k == 0)])?;
            out.write_all(frame)?;
            labels.push(format!("{} frame {}", sequence.name, k + 1));
        }
    }
    out.flush()?;
    Ok(labels)
}

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
    let mut sequences = shipped_takes(&data_set())?;
    let shipped: usize = sequences.iter().map(|s| s.frames.len()).sum();
    let takes = sequences.len();
    sequences.extend(
        adversarial()
            .into_iter()
            .map(|(name, frames)| Sequence { name, frames }),
    );
    let worst_file = target_dir().join("insns/worst_frames.bin");
    let labels = write_worst_frames(&worst_file, &sequences)?;
    let elf = build_firmware(&take, frames, &worst_file)?;
    let (begin, end) = marker_addresses(&elf)?;
    let mut first: Option<BTreeMap<String, Vec<u64>>> = None;
    let started = std::time::Instant::now();
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
    let qemu_s = started.elapsed().as_secs_f64() / runs.max(1) as f64;
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
    // The worst frame over every shipped frame and the adversarial ones.
    let worst = samples
        .get("edge_fs_frame_worst")
        .context("no measurement named edge_fs_frame_worst")?;
    if worst.len() != labels.len() {
        bail!(
            "{} worst-frame counts for {} frames streamed",
            worst.len(),
            labels.len()
        );
    }
    let (at, &worst_count) = worst
        .iter()
        .enumerate()
        .max_by_key(|(_, count)| **count)
        .context("no frame streamed")?;
    let shipped_worst = worst[..shipped].iter().max().copied().unwrap_or_default();
    println!(
        "edge_fs_frame_worst {worst_count} ({}; {shipped} frames of {takes} takes, worst \
         {shipped_worst}, and {} adversarial; {:.0} s in QEMU for the whole run)",
        labels[at],
        labels.len() - shipped,
        qemu_s
    );
    counts.insert("edge_fs_frame_worst", worst_count);
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

fn build_firmware(take: &Path, frames: usize, worst_frames: &Path) -> Result<PathBuf> {
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
        .env("INSNS_WORST_FRAMES", worst_frames)
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
    let image =
        std::fs::read(elf_path).with_context(|| format!("reading {}", elf_path.display()))?;
    let symbol = |name: &str| -> Result<u32> {
        crate::elf::symbol(&image, name)?.with_context(|| format!("symbol {name} not found"))
    };
    let begin = symbol("insns_begin")?;
    let end = symbol("insns_end")?;
    if begin == end {
        bail!("insns_begin and insns_end share an address: the markers were folded");
    }
    Ok((begin, end))
}
