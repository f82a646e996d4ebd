//! `cargo xtask size`: static flash/RAM/CCM use of each firmware.
//!
//! ```text
//! cargo xtask size [--flavour real|qemu|hil] [--no-build]
//! ```
//!
//! Builds both firmwares in release (unless `--no-build`) and prints one line per firmware,
//! `NAME flash=BYTES ram=BYTES ccm=BYTES stack=BYTES`, read from the ELF section headers
//! (parsed here; no binutils needed): flash is every allocated section with contents (code,
//! read-only data, the vector table and the initial values of `.data`); ram is `.data`, `.bss`
//! and `.uninit` in SRAM; ccm is the `.ccmram` section. The stack is not static: it takes what
//! the `RAM` region of the flavour's memory map (`memory.x`, or `memory-qemu.x` for `qemu`)
//! leaves, `stack` = RAM length - ram; for the real flavour it is checked against a floor. How
//! much of it the firmware actually uses is measured at run time (`stack_free=` in each board's
//! status log line, see `board_support::stack`), and on the virtual boards: for the real flavour
//! the line goes on with `stack_bound=BYTES stack_margin=BYTES`, the bound on the use the bench
//! measures (`xtask/budgets.toml`'s `[stack]`, which every clean bench run is checked against)
//! and what it leaves of the reserve.

use crate::cargo::{workspace_root, FIRMWARE_TARGET};
use crate::elf::{sections, symbol};
use anyhow::{bail, Context, Result};
use std::path::PathBuf;
use std::process::Command;

/// Firmware packages, in print order.
pub const FIRMWARES: [&str; 2] = ["stereo-board", "autopilot"];

/// CCM of the STM32F405/407/415, bytes.
const CCM_BYTES: u64 = 64 * 1024;
/// The least SRAM that must stay free for the stack, bytes.
const MIN_STACK_BYTES: u64 = 8 * 1024;

/// Static memory use of one firmware image.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Usage {
    /// Bytes stored in flash.
    pub flash: u64,
    /// Bytes of SRAM taken by statics.
    pub ram: u64,
    /// Bytes of CCM taken by statics.
    pub ccm: u64,
}

/// Runs `cargo xtask size`.
pub fn run(args: &[String]) -> Result<()> {
    let mut flavour = Flavour::Real;
    let mut build = true;
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--flavour" | "--flavor" => {
                flavour = Flavour::parse(it.next().context("--flavour needs a value")?)?
            }
            "--no-build" => build = false,
            other => bail!("cargo xtask size: unknown argument {other:?}"),
        }
    }
    if build {
        build_firmwares(flavour, &FIRMWARES)?;
    }
    let mut over = Vec::new();
    let mut measured = Vec::new();
    for name in FIRMWARES {
        let elf = firmware_elf(flavour, name);
        let bytes = std::fs::read(&elf).with_context(|| format!("reading {}", elf.display()))?;
        let usage = usage(&bytes).with_context(|| format!("parsing {}", elf.display()))?;
        check_layout(&bytes).with_context(|| format!("{}", elf.display()))?;
        let map = workspace_root().join(name).join(flavour.memory_map());
        let text =
            std::fs::read_to_string(&map).with_context(|| format!("reading {}", map.display()))?;
        let ram_len = ram_length(&text).with_context(|| format!("parsing {}", map.display()))?;
        let stack = ram_len.saturating_sub(usage.ram);
        // The bound on the use the virtual boards measure (real flavour), and what it leaves.
        let stack_use = match flavour {
            Flavour::Real => crate::budget::load()?.stack.get(name).copied(),
            _ => None,
        }
        .map(|used| {
            format!(
                " stack_bound={used} stack_margin={}",
                stack as i64 - used as i64
            )
        })
        .unwrap_or_default();
        println!(
            "{name} flash={} ram={} ccm={} stack={stack}{stack_use}",
            usage.flash, usage.ram, usage.ccm
        );
        if flavour == Flavour::Real {
            measured.push((name, usage));
        }
        if flavour == Flavour::Real && (stack < MIN_STACK_BYTES || usage.ccm > CCM_BYTES) {
            over.push(name);
        }
    }
    if !over.is_empty() {
        bail!("firmware does not fit with {MIN_STACK_BYTES} bytes of stack: {over:?}");
    }
    if !measured.is_empty() {
        let budgets = crate::budget::load()?;
        let mut failed = Vec::new();
        for (name, usage) in measured {
            let table = budgets
                .size
                .get(name)
                .with_context(|| format!("budgets.toml has no [size.{name}]"))?;
            let figures = [
                ("flash", usage.flash),
                ("ram", usage.ram),
                ("ccm", usage.ccm),
            ]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v as f64))
            .collect();
            if let Err(e) = crate::budget::check(&format!("size.{name}"), table, &figures) {
                failed.push(format!("{e:#}"));
            }
        }
        if !failed.is_empty() {
            bail!("{}", failed.join("\n"));
        }
    }
    Ok(())
}

/// Firmware build flavour.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flavour {
    /// The flight firmware.
    Real,
    /// `qemu-system-arm -M netduinoplus2` (feature `qemu`).
    Qemu,
    /// Hardware-in-the-loop (feature `hil`).
    Hil,
}

impl Flavour {
    /// Parses `real`, `qemu` or `hil`.
    pub fn parse(s: &str) -> Result<Self> {
        Ok(match s {
            "real" => Self::Real,
            "qemu" => Self::Qemu,
            "hil" => Self::Hil,
            other => bail!("unknown flavour {other:?} (real, qemu, hil)"),
        })
    }

    fn feature(self) -> Option<&'static str> {
        match self {
            Self::Real => None,
            Self::Qemu => Some("qemu"),
            Self::Hil => Some("hil"),
        }
    }

    /// The memory map the firmware's build script links with (as `board_support::build`
    /// picks it): `memory-qemu.x` for `qemu`, `memory.x` otherwise.
    pub fn memory_map(self) -> &'static str {
        match self {
            Self::Qemu => "memory-qemu.x",
            Self::Real | Self::Hil => "memory.x",
        }
    }

    /// The flavour's name, as `--flavour` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Real => "real",
            Self::Qemu => "qemu",
            Self::Hil => "hil",
        }
    }
}

/// The workspace's target directory (`CARGO_TARGET_DIR` if set).
fn target_base() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("target"))
}

/// The directory holding a flavour's firmware images after [`build_firmwares`]:
/// `target/firmware/<flavour>`.
pub fn firmware_dir(flavour: Flavour) -> PathBuf {
    target_base().join("firmware").join(flavour.name())
}

/// Path of a firmware's ELF after [`build_firmwares`].
pub fn firmware_elf(flavour: Flavour, name: &str) -> PathBuf {
    firmware_dir(flavour).join(name)
}

/// Builds the named firmwares of a flavour in release, one cargo invocation per firmware: each
/// board selects its own part's HAL feature, and cargo unifies features within an invocation.
pub fn build_firmwares(flavour: Flavour, names: &[&str]) -> Result<()> {
    for name in names {
        build_firmware(flavour, name, |cmd| {
            let status = cmd.status().context("running cargo build")?;
            if !status.success() {
                bail!("firmware build failed ({flavour:?}: {name})");
            }
            Ok(())
        })?;
    }
    Ok(())
}

/// Builds one firmware of `flavour` in release, running the `cargo build` with `run`, and puts
/// its ELF at [`firmware_elf`].
///
/// Every flavour builds in the workspace's target directory, so the dependencies (the HAL, its
/// device crate, RTIC, defmt) are built once for all of them and a change of flavour rebuilds
/// only the board's own crates. Cargo writes every flavour's image to the same path, so the
/// build and the copy out of it hold a lock file (`target/firmware/.lock`): a build of another
/// flavour, in this process or another, cannot replace the image in between.
pub fn build_firmware(
    flavour: Flavour,
    name: &str,
    run: impl FnOnce(&mut Command) -> Result<()>,
) -> Result<()> {
    let dir = firmware_dir(flavour);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let lock_path = target_base().join("firmware").join(".lock");
    let lock = std::fs::File::create(&lock_path)
        .with_context(|| format!("creating {}", lock_path.display()))?;
    lock.lock()
        .with_context(|| format!("locking {}", lock_path.display()))?;
    run(&mut firmware_build_command(flavour, name))?;
    let built = target_base()
        .join(FIRMWARE_TARGET)
        .join("release")
        .join(name);
    // Copied under a temporary name and renamed: a reader never sees half an image.
    let elf = firmware_elf(flavour, name);
    let partial = dir.join(format!(".{name}.partial"));
    std::fs::copy(&built, &partial)
        .with_context(|| format!("copying {} to {}", built.display(), partial.display()))?;
    std::fs::rename(&partial, &elf)
        .with_context(|| format!("renaming {} to {}", partial.display(), elf.display()))?;
    Ok(())
}

/// The `cargo build` of one firmware in `flavour` (release, the workspace's target directory).
fn firmware_build_command(flavour: Flavour, name: &str) -> Command {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.current_dir(workspace_root())
        .args(["build", "--release", "--target", FIRMWARE_TARGET])
        .arg("--target-dir")
        .arg(target_base())
        .args(["-p", name]);
    if let Some(feature) = flavour.feature() {
        cmd.args(["--features", &format!("{name}/{feature}")]);
    }
    cmd
}

/// Static memory use of an ELF32 little-endian image, from its section headers.
pub fn usage(elf: &[u8]) -> Result<Usage> {
    let mut u = Usage::default();
    for s in sections(elf)? {
        if !s.alloc || s.size == 0 {
            continue;
        }
        let in_flash = (0x0800_0000..0x0810_0000).contains(&s.addr);
        if s.name.starts_with(".ccmram") || (0x1000_0000..0x1001_0000).contains(&s.addr) {
            u.ccm += s.size;
        } else if in_flash {
            u.flash += s.size;
        } else {
            u.ram += s.size;
            // Initialised data is also stored in flash (copied at start-up).
            if !s.nobits {
                u.flash += s.size;
            }
        }
    }
    Ok(u)
}

/// Checks the start-up layout: flip-link's (the stack at the bottom of SRAM, `_stack_end <
/// _stack_start <= __sdata`) and what cortex-m-rt relies on (`__sbss <= __ebss`, in SRAM). The
/// reset handler zeroes `.bss` with a loop that runs until it
/// meets `__ebss`: a section inserted after `.bss` in another region (CCM is below SRAM) moves
/// `__ebss` there and the loop runs off the end of SRAM.
pub fn check_layout(elf: &[u8]) -> Result<()> {
    let sym =
        |n: &str| -> Result<u32> { symbol(elf, n)?.with_context(|| format!("no symbol {n}")) };
    let (sdata, sbss, ebss) = (sym("__sdata")?, sym("__sbss")?, sym("__ebss")?);
    let (end, start) = (sym("_stack_end")?, sym("_stack_start")?);
    let sram = 0x2000_0000..=0x2002_0000;
    // flip-link's layout: the stack from the bottom of SRAM up to `_stack_start`, the statics
    // above it, so an overflow runs off the start of SRAM and faults.
    if !(end < start
        && start <= sdata
        && sdata <= sbss
        && sbss <= ebss
        && sram.contains(&end)
        && sram.contains(&ebss))
    {
        bail!(
            "bad start-up layout: _stack_end {end:#x} _stack_start {start:#x} __sdata {sdata:#x} \
             __sbss {sbss:#x} __ebss {ebss:#x} (need _stack_end < _stack_start <= __sdata <= \
             __sbss <= __ebss in SRAM: the stack below the statics, as flip-link links it)"
        );
    }
    Ok(())
}

/// Length of the `RAM` region in a cortex-m-rt memory map (the `MEMORY { RAM : ORIGIN = ..,
/// LENGTH = .. }` line of a `memory.x`), bytes. Accepts decimal or `0x` hexadecimal with an
/// optional `K` or `M` suffix.
pub fn ram_length(map: &str) -> Result<u64> {
    // Comments out first (they may mention RAM too).
    let mut text = String::with_capacity(map.len());
    let mut rest = map;
    while let Some(start) = rest.find("/*") {
        text.push_str(&rest[..start]);
        rest = match rest[start..].find("*/") {
            Some(end) => &rest[start + end + 2..],
            None => "",
        };
    }
    text.push_str(rest);
    let line = text
        .lines()
        .map(str::trim)
        .find(|l| {
            l.strip_prefix("RAM")
                .is_some_and(|r| r.trim_start().starts_with(':'))
        })
        .context("no RAM region in the memory map")?;
    let value = line
        .split(',')
        .find_map(|field| {
            let (key, value) = field.split_once('=')?;
            (key.trim().rsplit(':').next()?.trim() == "LENGTH").then(|| value.trim())
        })
        .context("the RAM region has no LENGTH")?;
    let (digits, scale) = match value.chars().last() {
        Some('K' | 'k') => (&value[..value.len() - 1], 1024),
        Some('M' | 'm') => (&value[..value.len() - 1], 1024 * 1024),
        _ => (value, 1),
    };
    let digits = digits.trim();
    let n = match digits
        .strip_prefix("0x")
        .or_else(|| digits.strip_prefix("0X"))
    {
        Some(hex) => u64::from_str_radix(hex, 16),
        None => digits.parse(),
    }
    .with_context(|| format!("bad RAM LENGTH {value:?}"))?;
    Ok(n * scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal ELF32 LE image with the given (name, type, flags, addr, size) sections, after
    /// the null section and before the section-name table.
    fn elf(secs: &[(&str, u32, u32, u32, u32)]) -> Vec<u8> {
        let mut strtab = vec![0u8];
        let mut names = vec![0];
        for (n, ..) in secs.iter().chain([(".shstrtab", 3, 0, 0, 0)].iter()) {
            names.push(strtab.len() as u32);
            strtab.extend_from_slice(n.as_bytes());
            strtab.push(0);
        }
        let strtab_off = 52u32;
        let shoff = (52 + strtab.len() as u32 + 3) & !3;
        let mut b = vec![0u8; shoff as usize];
        b[..4].copy_from_slice(b"\x7fELF");
        b[4] = 1;
        b[5] = 1;
        b[6] = 1;
        b[0x20..0x24].copy_from_slice(&shoff.to_le_bytes());
        b[0x2e..0x30].copy_from_slice(&40u16.to_le_bytes());
        let n = secs.len() as u16 + 2;
        b[0x30..0x32].copy_from_slice(&n.to_le_bytes());
        b[0x32..0x34].copy_from_slice(&(n - 1).to_le_bytes());
        b[52..52 + strtab.len()].copy_from_slice(&strtab);
        let all: Vec<_> = [("", 0, 0, 0, 0)]
            .into_iter()
            .chain(secs.iter().copied())
            .chain([(".shstrtab", 3u32, 0u32, 0u32, strtab.len() as u32)])
            .collect();
        for (i, (_, kind, flags, addr, size)) in all.iter().enumerate() {
            let mut h = [0u8; 40];
            h[0..4].copy_from_slice(&names[i].to_le_bytes());
            h[4..8].copy_from_slice(&kind.to_le_bytes());
            h[8..12].copy_from_slice(&flags.to_le_bytes());
            h[12..16].copy_from_slice(&addr.to_le_bytes());
            let off = if *kind == 3 { strtab_off } else { 0 };
            h[16..20].copy_from_slice(&off.to_le_bytes());
            h[20..24].copy_from_slice(&size.to_le_bytes());
            b.extend_from_slice(&h);
        }
        b
    }

    #[test]
    fn classifies_sections() {
        let img = elf(&[
            (".vector_table", 1, 2, 0x0800_0000, 0x188),
            (".text", 1, 6, 0x0800_0188, 10_000),
            (".rodata", 1, 2, 0x0800_2898, 500),
            (".data", 1, 3, 0x2000_0000, 64),
            (".bss", 8, 3, 0x2000_0040, 50_000),
            (".uninit", 8, 3, 0x2000_c390, 16),
            (".ccmram", 8, 3, 0x1000_0000, 9_000),
            (".defmt", 1, 0, 0, 300),
            (".debug_info", 1, 0, 0, 99_999),
        ]);
        let u = usage(&img).unwrap();
        assert_eq!(
            u,
            Usage {
                flash: 0x188 + 10_000 + 500 + 64,
                ram: 64 + 50_000 + 16,
                ccm: 9_000
            }
        );
        // The QEMU map puts ".ccmram" inside SRAM: classified by name.
        let img = elf(&[(".ccmram", 8, 3, 0x2001_0000, 100)]);
        assert_eq!(usage(&img).unwrap().ccm, 100);
    }

    #[test]
    fn reads_the_ram_length_of_memory_maps() {
        let map = "/* RAM : ORIGIN = 0, LENGTH = 1K in a comment */\nMEMORY\n{\n  FLASH : ORIGIN = 0x08000000, LENGTH = 1024K\n  RAM : ORIGIN = 0x20000000, LENGTH = 112K\n  CCMRAM : ORIGIN = 0x10000000, LENGTH = 64K\n}\n";
        assert_eq!(ram_length(map).unwrap(), 112 * 1024);
        assert_eq!(
            ram_length("RAM:ORIGIN=0x20000000,LENGTH=0x10000").unwrap(),
            0x10000
        );
        assert_eq!(
            ram_length("RAM : ORIGIN = 0, LENGTH = 2M").unwrap(),
            2 << 20
        );
        assert!(ram_length("CCMRAM : ORIGIN = 0, LENGTH = 64K").is_err());
        assert!(ram_length("RAM : ORIGIN = 0, LENGTH = lots").is_err());
        // The maps the firmwares link with.
        for name in FIRMWARES {
            for flavour in [Flavour::Real, Flavour::Qemu, Flavour::Hil] {
                let path = workspace_root().join(name).join(flavour.memory_map());
                let text = std::fs::read_to_string(&path).unwrap();
                let len = ram_length(&text).unwrap();
                assert!((64 * 1024..=128 * 1024).contains(&len), "{path:?}: {len}");
            }
        }
    }

    #[test]
    fn rejects_garbage() {
        assert!(usage(b"not an elf").is_err());
        assert!(usage(b"\x7fELF\x01\x01").is_err());
        let mut img = elf(&[(".text", 1, 6, 0x0800_0000, 4)]);
        img.truncate(img.len() - 30);
        assert!(usage(&img).is_err());
    }
}
