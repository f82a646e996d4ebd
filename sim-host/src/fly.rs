//! `sim-host fly`: closed-loop simulated flight (in progress).

/// Command-line arguments of `sim-host fly`.
#[derive(Debug, clap::Args)]
pub struct FlyArgs {}

/// Runs `sim-host fly`.
pub fn run(_args: &FlyArgs) -> anyhow::Result<()> {
    anyhow::bail!("sim-host fly is not implemented yet")
}
