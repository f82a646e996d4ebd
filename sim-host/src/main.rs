//! `sim-host`: command-line front end of the host tools.

use clap::{Parser, Subcommand};

/// Host tools for the pocket drone: simulator, Edge-FS evaluation, hardware-in-the-loop bridge.
#[derive(Debug, Parser)]
#[command(name = "sim-host", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Fly the simulated pocket drone in a textured room with both boards' task graphs in the loop.
    Fly(sim_host::fly::FlyArgs),
    /// Evaluate Edge-FS on a recorded stereo data set against motion-capture ground truth.
    Eval(sim_host::eval::EvalArgs),
    /// Render each recorded take's motion-capture trajectory in a scene matched to its frames'
    /// texture statistics, run Edge-FS on the recorded and the rendered frames, and compare
    /// their errors and statistics.
    Replay(sim_host::eval::replay::ReplayArgs),
    /// Measure the recorded camera pair's effects (fixed patterns, vignetting, noise, the two
    /// cameras' mismatch, frame timing, depth structure) on a data set's frames and timing.
    CameraCalib(sim_host::eval::camera_calib::CameraCalibArgs),
    /// Hardware in the loop: fly the simulated world with the two boards' hil firmwares, on the
    /// real boards (serial links), the virtual boards or in QEMU (TCP), in lockstep on world
    /// time.
    Hil(sim_host::hil::HilArgs),
    /// Live view of a board's telemetry link (serial port or TCP), recorded to MCAP.
    Monitor(sim_host::monitor::MonitorArgs),
    /// List, read, write and save a board's parameters over its telemetry link (serial port or
    /// TCP).
    Param(sim_host::param::ParamArgs),
    /// The host link's key: make a key file, provision it over the link, write its flash
    /// record image for SWD.
    Key(sim_host::key::KeyArgs),
    /// Room suites: merge the CSVs of a suite's shards into the suite's table or CSV.
    Suite(sim_host::suite::SuiteArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match &cli.command {
        Command::Fly(args) => sim_host::fly::run(args),
        Command::Eval(args) => sim_host::eval::run(args),
        Command::Replay(args) => sim_host::eval::replay::run(args),
        Command::CameraCalib(args) => sim_host::eval::camera_calib::run(args),
        Command::Hil(args) => sim_host::hil::run_cli(args),
        Command::Monitor(args) => sim_host::monitor::run(args),
        Command::Param(args) => sim_host::param::run(args),
        Command::Suite(args) => sim_host::suite::run(args),
        Command::Key(args) => sim_host::key::run(args),
    }
}
