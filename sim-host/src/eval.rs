//! `sim-host eval`: Edge-FS against motion-capture ground truth (in progress).

/// Command-line arguments of `sim-host eval`.
#[derive(Debug, clap::Args)]
pub struct EvalArgs {}

/// Runs `sim-host eval`.
pub fn run(_args: &EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("sim-host eval is not implemented yet")
}
