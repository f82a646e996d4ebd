//! `cargo xtask size`: static flash/RAM/CCM use of each firmware.

/// Runs `cargo xtask size`.
pub fn run(_args: &[String]) -> anyhow::Result<()> {
    anyhow::bail!("cargo xtask size is not implemented yet")
}
