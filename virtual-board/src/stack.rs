//! Stack low-water marks, read off the emulated part's memory.
//!
//! Both firmwares paint their stack region at boot (`board_support::stack::paint`, first thing
//! in RTIC `init`): every word from the bottom of the region (`_stack_end`; flip-link puts the
//! stack at the bottom of SRAM) up to just below the stack pointer becomes [`PATTERN`]. A word
//! still holding the pattern was never written since. The bench scans up from the bottom for
//! the first word that is not the pattern every [`SCAN_PERIOD_NS`] of virtual time and at the
//! run's end, and keeps the least headroom seen ([`StackUse`]). Unlike the firmware's own
//! `stack_free` (its 1 Hz status line), this sees the last second of a run too, and a run's
//! deepest point before a watchdog reset repaints the stack.
//!
//! The deepest use of the `real` images over the flight, fault and parameter tests is recorded
//! in `xtask/budgets.toml` (`[stack]`, bytes from the top of the stack region down to the
//! deepest word written); every clean run of a `real` image checks its own use against it
//! ([`crate::bench::Outcome::assert_clean`]), and `cargo xtask size` prints the margin it
//! leaves in the stack reserve.

use std::path::Path;

use rigless::emulator::Memory;
use rigless::soc::Width;

use crate::firmware::Firmware;

/// `board_support::stack::PATTERN`: the word the firmware paints its unused stack with.
pub const PATTERN: u32 = 0x57AC_C0DE;

/// How often a run scans the stack, ns of virtual time (a scan reads every free word: about
/// 25,000 reads of the emulator's memory for the autopilot's 100 KiB).
pub const SCAN_PERIOD_NS: u64 = 50_000_000;

/// What a run measured of one image's stack.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StackUse {
    /// Bytes of the stack region (`_stack_start - _stack_end`: the reserve `cargo xtask size`
    /// reports).
    pub reserve: u64,
    /// The least headroom seen: bytes from the bottom of the region up to the deepest word
    /// written since the stack was painted.
    pub least_free: u64,
    /// The package (`autopilot`, `stereo-board`) if the image is the `real` flavour, whose
    /// deepest use `xtask/budgets.toml` records.
    pub real_image: Option<String>,
}

impl StackUse {
    /// Bytes used at the deepest point: from the top of the region down to the deepest word
    /// written.
    #[must_use]
    pub fn used(&self) -> u64 {
        self.reserve - self.least_free
    }
}

/// A run's scanner of one image's painted stack.
#[derive(Debug, Clone)]
pub(crate) struct StackScan {
    bottom: u64,
    top: u64,
    real_image: Option<String>,
    least_free: Option<u64>,
    next_ns: u64,
}

impl StackScan {
    /// The scanner of `firmware`'s stack region, or `None` if its symbols do not say where the
    /// region is.
    pub(crate) fn new(firmware: &Firmware) -> Option<Self> {
        let bottom = firmware.symbol("_stack_end")?;
        let top = firmware.symbol("_stack_start")?;
        let real = firmware.path.parent() == Some(crate::firmware::firmware_dir().as_path());
        let real_image = real
            .then(|| firmware.path.file_name().and_then(|n| n.to_str()))
            .flatten()
            .map(str::to_owned);
        (bottom < top).then_some(Self {
            bottom,
            top,
            real_image,
            least_free: None,
            // Not before the firmware has painted: `init` paints bottom-up in its first
            // fraction of a millisecond, and a scan in the middle of the painting would take
            // the painting's progress for the deepest use.
            next_ns: SCAN_PERIOD_NS,
        })
    }

    /// Called at every stop: scans if one is due, or `last` (the run's final stop).
    pub(crate) fn at_stop(&mut self, now: u64, memory: &mut dyn Memory, last: bool) {
        if now < self.next_ns && !last {
            return;
        }
        self.next_ns = now + SCAN_PERIOD_NS;
        if let Some(free) = self.free(memory) {
            self.least_free = Some(self.least_free.map_or(free, |least| least.min(free)));
        }
    }

    /// Bytes from the bottom up to the first word that is not the paint, or `None` if the
    /// bottom word is not the paint (not painted yet, or overflowed).
    fn free(&self, memory: &mut dyn Memory) -> Option<u64> {
        let painted = |memory: &mut dyn Memory, address: u64| {
            memory
                .read(address, Width::W32)
                .is_ok_and(|w| w == u64::from(PATTERN))
        };
        if !painted(memory, self.bottom) {
            return None;
        }
        let mut address = self.bottom;
        while address < self.top && painted(memory, address) {
            address += 4;
        }
        Some(address - self.bottom)
    }

    /// What the run measured, if the stack was ever seen painted.
    pub(crate) fn result(&self) -> Option<StackUse> {
        Some(StackUse {
            reserve: self.top - self.bottom,
            least_free: self.least_free?,
            real_image: self.real_image.clone(),
        })
    }
}

/// The deepest stack use of the `real` image of `package` recorded in `xtask/budgets.toml`'s
/// `[stack]` table, bytes.
///
/// # Errors
/// The file is unreadable or has no such line.
pub fn recorded_use(package: &str) -> Result<u64, String> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../xtask/budgets.toml");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    recorded_in(&text, package).ok_or_else(|| {
        format!(
            "{} has no `{package} = BYTES` line in its [stack] table",
            path.display()
        )
    })
}

/// `package`'s figure in the `[stack]` table of `budgets`' text.
fn recorded_in(budgets: &str, package: &str) -> Option<u64> {
    let mut in_stack = false;
    for line in budgets.lines().map(str::trim) {
        if line.starts_with('[') {
            in_stack = line == "[stack]";
        } else if in_stack
            && let Some((key, value)) = line.split_once('=')
            && key.trim() == package
        {
            return value.trim().parse().ok();
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_recorded_figure_is_read_from_the_stack_table_only() {
        let text = "[insns]\nautopilot = 1\n[stack]\n# a comment\nstereo-board = 20\nautopilot = 30\n[size.autopilot]\nflash = 4\n";
        assert_eq!(recorded_in(text, "autopilot"), Some(30));
        assert_eq!(recorded_in(text, "stereo-board"), Some(20));
        assert_eq!(recorded_in(text, "flash"), None);
    }

    #[test]
    fn the_committed_budgets_record_both_images() {
        for package in ["autopilot", "stereo-board"] {
            recorded_use(package).expect("a recorded figure");
        }
    }
}
