//! `cargo xtask qemu`: build a firmware flavour and run it in QEMU with a timeout.

/// Runs `cargo xtask qemu`.
pub fn run(_args: &[String]) -> anyhow::Result<()> {
    anyhow::bail!("cargo xtask qemu is not implemented yet")
}
