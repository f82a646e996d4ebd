//! The `sim-host hil` command: its arguments ([`HilArgs`]) and [`run_cli`], which opens the
//! boards' links (and the relay), flies the run and writes the summary, the CSV log and the
//! MCAP flight log.

use super::lockstep::run_logged;
use super::recorder::write_log_csv;
use super::relay::Relay;
use super::HilConfig;
use crate::log::FlightLog;
use crate::param::ParamFile;
use crate::sim::flight::FlightConfig;
use crate::sim::scene_spec::SceneSpec;
use crate::transport::open_link;
use anyhow::{bail, Context as _};
use std::path::PathBuf;
use std::time::Duration;

/// `sim-host hil`: fly the simulated world with the boards' lockstep firmwares in the loop: on
/// the real boards, on the virtual boards or in QEMU.
#[derive(Debug, clap::Args)]
pub struct HilArgs {
    /// The camera board's host link: a serial device (/dev/ttyUSB0) or tcp:HOST:PORT (`vboard
    /// serve hil`, a QEMU `-chardev socket,server=on`).
    #[arg(long)]
    pub stereo: String,
    /// The autopilot's host link (same forms as --stereo).
    #[arg(long)]
    pub autopilot: String,
    /// Relay the board-to-board UART through this host: the camera board's link UART (USART1
    /// in QEMU) ...
    #[arg(long, requires = "relay_autopilot")]
    pub relay_stereo: Option<String>,
    /// ... and the autopilot's (USART2; for two QEMUs: wired boards and the virtual boards do
    /// not need it).
    #[arg(long, requires = "relay_stereo")]
    pub relay_autopilot: Option<String>,
    /// Baud rate of serial devices.
    #[arg(long, default_value_t = 921_600)]
    pub baud: u32,
    /// World time to fly, s.
    #[arg(long, default_value_t = 10.0)]
    pub duration: f64,
    /// Scene preset (room, room-obstacles, corridor, plain-room, office).
    #[arg(long, default_value = "room")]
    pub scenario: String,
    /// Scene file (TOML, see docs/scenes.md) instead of a preset.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Seed of the world (textures, sensor noise).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Camera frames per second of world time (each frame takes 0.27 s of a 921,600 Bd link;
    /// the world waits for the link; see the docs).
    #[arg(long, default_value_t = 4.0)]
    pub fps: f64,
    /// World time of the arm command, s: once the autopilot counts the camera board's estimates
    /// (its flow history fills with the 10th frame, at 2.35 s at 4 fps, and the autopilot
    /// counts the third valid estimate in a row, at 2.85 s; armed earlier, the failsafe lands
    /// before it sees one).
    #[arg(long, default_value_t = 3.0)]
    pub arm_at: f64,
    /// Longest wait for a reply from a board, s (wall time).
    #[arg(long, default_value_t = 5.0)]
    pub reply_timeout: f64,
    /// Directory for the logs (hil_log.csv, and flight.mcap unless --mcap says otherwise).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Where to write the MCAP flight log (default: flight.mcap in --out, if given).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Serve the log's channels live over the Foxglove WebSocket protocol on 127.0.0.1 as
    /// they are written (see `--live-port`).
    #[arg(long)]
    pub live: bool,
    /// Port of the live view (0: any free port; the address is printed at the start).
    #[arg(long, default_value_t = crate::log::live::DEFAULT_PORT)]
    pub live_port: u16,
    /// Board parameters (TOML, `[autopilot]` and `[camera]`, as `fly --params`; see
    /// docs/parameters.md): set on the boards and read back before the flight; any refusal or
    /// mismatch stops the run before arming.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Drive the autopilot's PWM outputs with its motor commands (motors on the bench turn).
    /// Without it they stay at 0 and the commands are seen in the `Motors` replies and the log.
    #[arg(long)]
    pub outputs: bool,
    /// The link key file (`sim-host key new`): commands to the autopilot are signed with it.
    #[arg(long)]
    pub key: Option<PathBuf>,
}

/// Runs `sim-host hil`.
pub fn run_cli(args: &HilArgs) -> anyhow::Result<()> {
    let cfg = HilConfig {
        world: FlightConfig {
            scene: SceneSpec::from_cli(args.scene.as_deref(), &args.scenario)?,
            seed: args.seed,
            ..FlightConfig::default()
        },
        duration_s: args.duration,
        fps: args.fps,
        arm_at_s: args.arm_at,
        outputs: args.outputs,
        reply_timeout: Duration::from_secs_f64(args.reply_timeout.max(0.01)),
        params: match &args.params {
            Some(path) => Some((
                path.display().to_string(),
                ParamFile::load_sections(path)?.1,
            )),
            None => None,
        },
        interrupt: Some(crate::interrupt_flag()?),
        key: args.key.as_deref().map(crate::key::load_key).transpose()?,
        ..HilConfig::default()
    };
    let stereo = open_link(&args.stereo, args.baud)?;
    let autopilot = open_link(&args.autopilot, args.baud)?;
    let relay = match (&args.relay_stereo, &args.relay_autopilot) {
        (Some(s), Some(a)) => Some(Relay::start(
            open_link(s, args.baud)?,
            open_link(a, args.baud)?,
        )?),
        _ => None,
    };
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mcap_path = args
        .mcap
        .clone()
        .or_else(|| args.out.as_ref().map(|d| d.join("flight.mcap")));
    let mut mcap = mcap_path.as_deref().map(FlightLog::create).transpose()?;
    if args.live {
        let log = mcap.as_mut().ok_or_else(|| {
            anyhow::anyhow!("hil --live serves the flight log's channels: give --out or --mcap")
        })?;
        log.serve_live(crate::log::live::LiveServer::start_announced(
            args.live_port,
        )?);
    }
    let r = run_logged(
        &cfg,
        stereo,
        autopilot,
        relay.as_ref(),
        &mut |t| {
            eprint!("\rworld time {t:.0} s");
        },
        mcap.as_mut(),
    );
    let r = match r {
        Ok(r) => r,
        Err(e) => {
            // What was recorded before the failure stays readable.
            if let Some(log) = mcap {
                let _ = log.finish();
            }
            return Err(e);
        }
    };
    eprintln!();
    if let Some((file, sections)) = &cfg.params {
        let n: usize = sections.iter().map(|s| s.values.len()).sum();
        println!("parameters        {n} from {file} set and read back");
    }
    println!("{}", r.summary());
    if let Some(dir) = &args.out {
        write_log_csv(&r, &dir.join("hil_log.csv"))?;
        println!("log               {}", dir.join("hil_log.csv").display());
    }
    if let Some(log) = mcap {
        let summary = log.finish()?;
        println!(
            "flight log        {} ({} messages on {} channels, MCAP)",
            summary.path.display(),
            summary.total(),
            summary.counts.len()
        );
    }
    match r.ended_early.as_deref() {
        None | Some("interrupted") => {}
        Some(why) => bail!("the flight ended early ({why}); its logs are written"),
    }
    if let Some(e) = &r.log_error {
        bail!("the flight log stopped early: {e}");
    }
    Ok(())
}
