//! Budgets that fail loudly: the figures `cargo xtask insns` and `cargo xtask size` measure,
//! compared with the expectations committed in `xtask/budgets.toml`.
//!
//! Each figure has an `expected` value and a `tolerance_percent`; figures with a hard ceiling
//! (the Edge-FS frame, the INDI step, the camera board's share of a frame period) also carry a
//! `limit`. A figure fails the check when it
//!
//! * exceeds `expected` by more than the tolerance (a regression), or
//! * falls below `expected` by more than the tolerance (an improvement the file does not record
//!   yet: lower the expectation, so that a later regression cannot hide in the slack), or
//! * exceeds its `limit`.
//!
//! Updating an expectation is a deliberate change to `xtask/budgets.toml`, reviewed like code:
//! the check prints the line to write.

use anyhow::{bail, Context, Result};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// One budgeted figure.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Expectation {
    /// The value the committed code measures.
    pub expected: f64,
    /// Allowed relative deviation either way, percent.
    pub tolerance_percent: f64,
    /// Hard ceiling, if any.
    #[serde(default)]
    pub limit: Option<f64>,
}

/// The whole file: `[insns]` (instruction counts by measurement name, plus derived figures) and
/// `[size.FIRMWARE]` (bytes of flash, SRAM and CCM the `real` flavour's statics take; the stack
/// reserve is what SRAM they leave, checked against its minimum by `cargo xtask size`).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budgets {
    /// `cargo xtask insns` figures.
    pub insns: BTreeMap<String, Expectation>,
    /// `cargo xtask size` figures per firmware.
    pub size: BTreeMap<String, BTreeMap<String, Expectation>>,
    /// The deepest stack use of each `real` firmware, bytes, measured on the virtual boards
    /// (`virtual-board/src/stack.rs`, which checks every clean run against it); `cargo xtask
    /// size` prints the margin it leaves in the stack reserve.
    pub stack: BTreeMap<String, u64>,
}

/// Where the expectations live.
pub fn path() -> PathBuf {
    crate::cargo::workspace_root().join("xtask/budgets.toml")
}

/// Reads and parses `xtask/budgets.toml`.
pub fn load() -> Result<Budgets> {
    let path = path();
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    parse(&text).with_context(|| format!("parsing {}", path.display()))
}

fn parse(text: &str) -> Result<Budgets> {
    Ok(toml::from_str(text)?)
}

/// The verdict on one measured figure.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// Within tolerance of its expectation and under its limit.
    Ok,
    /// Worse than expected beyond the tolerance.
    Regression,
    /// Better than expected beyond the tolerance: the expectation must be lowered.
    Unrecorded,
    /// Above the hard limit.
    OverLimit,
}

impl Expectation {
    /// Judges a measured value.
    pub fn judge(&self, measured: f64) -> Verdict {
        let slack = self.expected.abs() * self.tolerance_percent / 100.0;
        if self.limit.is_some_and(|limit| measured > limit) {
            Verdict::OverLimit
        } else if measured > self.expected + slack {
            Verdict::Regression
        } else if measured < self.expected - slack {
            Verdict::Unrecorded
        } else {
            Verdict::Ok
        }
    }
}

/// Compares measured figures with a table of expectations; prints one line per figure and fails
/// listing every figure out of budget. `section` names the table in `budgets.toml`
/// (`insns`, `size.stereo-board`, ...). A figure measured but not budgeted, or budgeted but not
/// measured, fails too: the file and the measurement must name the same things.
pub fn check(
    section: &str,
    table: &BTreeMap<String, Expectation>,
    measured: &BTreeMap<String, f64>,
) -> Result<()> {
    let mut failures = Vec::new();
    for (name, value) in measured {
        let Some(exp) = table.get(name) else {
            failures.push(format!(
                "{section}.{name} = {value} is measured but has no expectation in budgets.toml"
            ));
            continue;
        };
        let verdict = exp.judge(*value);
        let delta = 100.0 * (value - exp.expected) / exp.expected.abs().max(1.0);
        let limit = exp
            .limit
            .map(|l| format!(", limit {l}"))
            .unwrap_or_default();
        println!(
            "budget {section}.{name}: {value} vs expected {} ({delta:+.2} %, tolerance {} %{limit}): {verdict:?}",
            exp.expected, exp.tolerance_percent
        );
        match verdict {
            Verdict::Ok => {}
            Verdict::OverLimit => failures.push(format!(
                "{section}.{name} = {value} is over its limit {}",
                exp.limit.unwrap_or_default()
            )),
            Verdict::Regression => failures.push(format!(
                "{section}.{name} = {value} regressed {delta:+.2} % against the expected {} \
                 (tolerance {} %)",
                exp.expected, exp.tolerance_percent
            )),
            Verdict::Unrecorded => failures.push(format!(
                "{section}.{name} = {value} is {delta:+.2} % below the expected {}: if the \
                 improvement is real, record it in budgets.toml (expected = {value})",
                exp.expected
            )),
        }
    }
    for name in table.keys().filter(|n| !measured.contains_key(*n)) {
        failures.push(format!(
            "{section}.{name} has an expectation but was not measured"
        ));
    }
    if !failures.is_empty() {
        bail!(
            "out of budget ({}):\n  {}",
            path().display(),
            failures.join("\n  ")
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn exp(expected: f64, tolerance_percent: f64, limit: Option<f64>) -> Expectation {
        Expectation {
            expected,
            tolerance_percent,
            limit,
        }
    }

    #[test]
    fn judges_both_directions_and_the_limit() {
        let e = exp(1000.0, 1.0, Some(1005.0));
        assert_eq!(e.judge(1000.0), Verdict::Ok);
        assert_eq!(e.judge(1004.0), Verdict::Ok);
        assert_eq!(e.judge(990.0), Verdict::Ok);
        assert_eq!(e.judge(989.0), Verdict::Unrecorded);
        assert_eq!(e.judge(1006.0), Verdict::OverLimit);
        assert_eq!(exp(1000.0, 1.0, None).judge(1011.0), Verdict::Regression);
    }

    #[test]
    fn check_fails_on_unknown_and_missing_figures() {
        let mut table = BTreeMap::new();
        table.insert("a".to_string(), exp(10.0, 5.0, None));
        let mut measured = BTreeMap::new();
        measured.insert("a".to_string(), 10.2);
        assert!(check("t", &table, &measured).is_ok());
        measured.insert("b".to_string(), 1.0);
        assert!(check("t", &table, &measured).is_err());
        measured.remove("b");
        measured.remove("a");
        assert!(check("t", &table, &measured).is_err());
    }

    #[test]
    fn the_committed_file_parses_and_keeps_the_hard_limits() {
        let b = load().expect("xtask/budgets.toml");
        assert_eq!(b.insns["edge_fs_frame_default"].limit, Some(250_000.0));
        assert_eq!(b.insns["edge_fs_frame_worst"].limit, Some(448_000.0));
        assert_eq!(b.insns["indi_step"].limit, Some(5_000.0));
        assert!(b.insns.contains_key("camera_board_frame_percent"));
        for firmware in ["stereo-board", "autopilot"] {
            for figure in ["flash", "ram", "ccm"] {
                assert!(
                    b.size[firmware].contains_key(figure),
                    "size.{firmware}.{figure} missing"
                );
            }
            assert!(b.stack.contains_key(firmware), "stack.{firmware} missing");
        }
        assert!(parse("[insns]\nx = { expected = 1 }\n[size]\n").is_err());
    }
}
