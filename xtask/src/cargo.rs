//! Running cargo and other tools from the xtasks, and where the workspace is.

use anyhow::{bail, Context, Result};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The firmware target.
pub const FIRMWARE_TARGET: &str = "thumbv7em-none-eabihf";

/// The workspace root (the parent of xtask/).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."))
}

/// Runs a command, echoing it, and fails on a non-zero exit status.
pub fn run_checked(cmd: &mut Command) -> Result<()> {
    eprintln!("xtask: running {cmd:?}");
    let status = cmd
        .status()
        .with_context(|| format!("could not start {cmd:?}"))?;
    if !status.success() {
        bail!("{cmd:?} failed with {status}");
    }
    Ok(())
}

/// Runs `cargo` with `args`, echoing the command; fails on a non-zero exit status.
pub fn cargo(args: &[&str]) -> Result<()> {
    run_checked(Command::new("cargo").args(args))
}

/// Runs a `cargo test` command, streaming its output, and sums the `test result:` lines.
pub fn cargo_test(args: &[&str]) -> Result<(u64, u64)> {
    cargo_test_with(Command::new("cargo").args(args))
}

/// Runs a prepared `cargo test` command (arguments, directory, environment set), streaming its
/// output, and sums the `test result:` lines. Fails on a failed test or when no test ran.
pub fn cargo_test_with(cmd: &mut Command) -> Result<(u64, u64)> {
    eprintln!("xtask: running {cmd:?}");
    let mut child = cmd
        .stdout(Stdio::piped())
        .spawn()
        .context("could not start cargo test")?;
    let (mut passed, mut failed) = (0u64, 0u64);
    if let Some(stdout) = child.stdout.take() {
        for line in BufReader::new(stdout).lines() {
            let line = line?;
            println!("{line}");
            if let Some(rest) = line.strip_prefix("test result: ") {
                passed += count_before(rest, " passed");
                failed += count_before(rest, " failed");
            }
        }
    }
    let status = child.wait()?;
    if !status.success() || failed > 0 {
        println!("{passed} passed, {failed} failed");
        bail!("cargo test failed ({failed} failed)");
    }
    if passed == 0 {
        bail!("cargo test ran no test");
    }
    Ok((passed, failed))
}

/// In `ok. 12 passed; 0 failed; ...`, the number before `word`.
fn count_before(text: &str, word: &str) -> u64 {
    text.split(';')
        .find_map(|part| {
            part.trim()
                .trim_start_matches("ok. ")
                .trim_start_matches("FAILED. ")
                .strip_suffix(word.trim_start())
                .map(str::trim)
        })
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::count_before;

    #[test]
    fn parses_cargo_test_summaries() {
        let line =
            "ok. 12 passed; 3 failed; 1 ignored; 0 measured; 0 filtered out; finished in 0.1s";
        assert_eq!(count_before(line, " passed"), 12);
        assert_eq!(count_before(line, " failed"), 3);
        assert_eq!(
            count_before("FAILED. 2 passed; 1 failed; 0 ignored", " failed"),
            1
        );
    }
}
