//! `cargo xtask test`: the CI test command.

/// Runs `cargo xtask test`.
pub fn run(_args: &[String]) -> anyhow::Result<()> {
    anyhow::bail!("cargo xtask test is not implemented yet")
}
