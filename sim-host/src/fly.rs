//! `sim-host fly`: closed-loop simulated flight of the pocket drone with both boards' task
//! graphs in the loop (see [`crate::sim`]).
//!
//! One seed: prints a summary and writes `log.csv`, `flight.mcap` (the MCAP flight log of
//! [`crate::log`], or at `--mcap PATH`), `trajectory.png`, `velocity.png`, `fsm.png` and
//! `flight.gif` to `--out`. `--seeds N`: Monte Carlo over seeds `seed..seed+N`
//! on all cores, one summary row per seed (and `montecarlo.csv` in `--out`).

use crate::log::live::LiveServer;
use crate::log::sim::{LogRates, SimRecorder};
use crate::log::FlightLog;
use crate::param::ParamFile;
use crate::sim::battery::BatteryParams;
use crate::sim::flight::{run_flight, run_flight_observed, FlightConfig, FlightResult};
use crate::sim::output;
use crate::sim::scene_spec::SceneSpec;
use crate::sim::suite::{self, FlightFigures, SuiteRoom};
use crate::sim::uart::LinkFaults;
use anyhow::Context;
use autopilot::estimation::VelocitySource;
use autopilot::fsm::FsmVariant;
use autopilot::AutopilotConfig;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;
use stereo_board::edge_fs::EdgeFsParams;

/// Avoidance FSM choice on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum FsmArg {
    /// The paper's FSM: check, forward, hover 1 s, turn 60 deg.
    Paper,
    /// Check and turn merged: keep turning until the way ahead is clear.
    Improved,
}

impl FsmArg {
    /// The autopilot's FSM variant this choice selects.
    pub fn variant(self) -> FsmVariant {
        match self {
            Self::Paper => FsmVariant::Paper,
            Self::Improved => FsmVariant::TurnUntilClear,
        }
    }

    /// The command-line name of a variant.
    pub fn name_of(variant: FsmVariant) -> &'static str {
        match variant {
            FsmVariant::Paper => "paper",
            FsmVariant::TurnUntilClear => "improved",
        }
    }
}

/// The autopilot's horizontal velocity estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum VelocityArg {
    /// The Kalman filter (IMU model, every estimate weighted by quality, delays modelled).
    Kalman,
    /// The paper's median-5 of the estimates into the velocity observer.
    Median,
    /// The Kalman filter on each frame's own fit instead of the camera board's filtered output.
    KalmanFits,
}

/// Output format of the summary.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Human-readable summary.
    Table,
    /// One row per flight, the columns of [`CSV_HEADER`] (the suite adds the room's).
    Csv,
}

/// Command-line arguments of `sim-host fly`.
#[derive(Debug, clap::Args)]
pub struct FlyArgs {
    /// Scene preset: room (the paper's 4 x 4 m room), room-obstacles, corridor, plain-room,
    /// office (the files in sim-host/scenes/).
    #[arg(long, default_value = "room")]
    pub scenario: String,
    /// Scene file (TOML, see docs/scenes.md) instead of a preset.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Simulated flight duration, s.
    #[arg(long, default_value_t = 120.0)]
    pub duration: f64,
    /// Seed (textures, start heading, sensor noise, link faults).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Monte Carlo: fly seeds `seed..seed+N` in parallel on all cores (no plots or GIF).
    #[arg(long, conflicts_with = "suite")]
    pub seeds: Option<u64>,
    /// Room suite: fly N rooms generated from `--seed` (sides 3-8 m, 0-4 obstacles,
    /// textured, mixed, low-contrast and featureless walls, light 0.1-2) in parallel; a table
    /// by class of room, or one CSV row per flight.
    #[arg(long, conflicts_with_all = ["scene"])]
    pub suite: Option<u64>,
    /// With `--suite`: fly only shard I of N (`I/N`, 0-based: rooms I, I+N, I+2N, ...), for
    /// splitting a large suite over machines.
    #[arg(long, value_parser = parse_shard, requires = "suite")]
    pub shard: Option<(u64, u64)>,
    /// With `--suite`: also write each flight's 50 Hz log as `--out`/ROOM/log.csv (the room's
    /// name: suite-SEED-INDEX), to study the flights the table counts.
    #[arg(long, requires = "suite")]
    pub room_logs: bool,
    /// Avoidance FSM (default: the parameter file's `fsm_variant`, else paper).
    #[arg(long, value_enum)]
    pub fsm: Option<FsmArg>,
    /// Velocity estimate guidance flies on (default: the parameter file's
    /// `velocity_source`, else the Kalman filter).
    #[arg(long, value_enum)]
    pub velocity: Option<VelocityArg>,
    /// Board parameters (TOML, `[autopilot]` and `[camera]` tables keyed by the names of
    /// `sim-host param list`; see docs/parameters.md) over the defaults; `[camera]` configures
    /// the simulated camera board's Edge-FS.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Output directory.
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Where to write the MCAP flight log (default: flight.mcap in --out; one seed only).
    #[arg(long)]
    pub mcap: Option<PathBuf>,
    /// Serve the log's channels live over the Foxglove WebSocket protocol on 127.0.0.1 as
    /// they are written, the flight paced to real time (see `--live-port`; one seed only).
    #[arg(long)]
    pub live: bool,
    /// Port of the live view (0: any free port; the address is printed at the start).
    #[arg(long, default_value_t = crate::log::live::DEFAULT_PORT)]
    pub live_port: u16,
    /// Summary format.
    #[arg(long, value_enum, default_value_t = Format::Table)]
    pub format: Format,
    /// Board-to-board UART baud rate, bit/s.
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// Bit error rate on both UART directions.
    #[arg(long, default_value_t = 0.0)]
    pub ber: f64,
    /// Probability of losing a byte on both UART directions.
    #[arg(long, default_value_t = 0.0)]
    pub drop_rate: f64,
    /// Link outage on both directions, `START_S:DURATION_S` (repeatable).
    #[arg(long, value_parser = parse_outage)]
    pub outage: Vec<(f64, f64)>,
    /// Motion capture: the autopilot gets height fixes at 100 Hz, as in the paper's lab.
    /// Without it (the default) it holds height on its barometer and accelerometer.
    #[arg(long)]
    pub mocap: bool,
    /// Camera frame rate, Hz.
    #[arg(long, default_value_t = 25.0)]
    pub fps: f64,
    /// Camera-board processing time per frame, ms.
    #[arg(long, default_value_t = 15.0)]
    pub processing_ms: f64,
    /// Horizontal stereo misalignment of the rendered camera pair, px.
    #[arg(long, default_value_t = 0.0)]
    pub misalign_px: f32,
    /// Camera model: `calibrated` (the effects measured on the recorded frames) or `ideal`
    /// (without them, for comparison).
    #[arg(long, value_enum, default_value_t = crate::sim::camera::CameraModel::Calibrated)]
    pub camera: crate::sim::camera::CameraModel,
    /// Start pose `X,Y,YAW_DEG` (m, m, deg) instead of the scene's (and its seeded heading).
    #[arg(long, value_parser = parse_start, allow_hyphen_values = true)]
    pub start: Option<[f64; 3]>,
    /// Fly on a 1S LiPo of this capacity, mAh, charged (its voltage sags under thrust and
    /// falls as it discharges; the autopilot reads it and lands when it runs low). Without it
    /// the supply is ideal and the autopilot reads no voltage.
    #[arg(long)]
    pub battery_mah: Option<f64>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

fn parse_start(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("{e} in {s:?}")))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, yaw] if v.iter().all(|a| a.is_finite()) => Ok([*x, *y, *yaw]),
        _ => Err(format!("expected X,Y,YAW_DEG, got {s:?}")),
    }
}

fn parse_shard(s: &str) -> Result<(u64, u64), String> {
    let (i, n) = s
        .split_once('/')
        .ok_or_else(|| format!("expected I/N, got {s:?}"))?;
    let i: u64 = i.trim().parse().map_err(|e| format!("{e} in {s:?}"))?;
    let n: u64 = n.trim().parse().map_err(|e| format!("{e} in {s:?}"))?;
    if n == 0 || i >= n {
        return Err(format!("shard I/N needs 0 <= I < N, got {s:?}"));
    }
    Ok((i, n))
}

fn parse_outage(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("expected START_S:DURATION_S, got {s:?}"))?;
    let a: f64 = a.trim().parse().map_err(|e| format!("{e}"))?;
    let b: f64 = b.trim().parse().map_err(|e| format!("{e}"))?;
    if !(a >= 0.0 && b > 0.0) {
        return Err(format!("outage start must be >= 0 and duration > 0: {s:?}"));
    }
    Ok((a, b))
}

impl FlyArgs {
    /// The flight configuration these arguments describe, for `seed`, in `scene`.
    pub fn config(&self, scene: &SceneSpec, seed: u64, params: Option<&ParamFile>) -> FlightConfig {
        let faults = LinkFaults {
            bit_error_rate: self.ber,
            drop_rate: self.drop_rate,
            outages: self
                .outage
                .iter()
                .map(|&(a, d)| ((a * 1e6) as u64, ((a + d) * 1e6) as u64))
                .collect(),
        };
        let mut cfg = FlightConfig {
            scene: scene.clone(),
            duration_s: self.duration,
            seed,
            autopilot: params.map_or_else(AutopilotConfig::default, |p| p.autopilot),
            edge_fs: params.map_or_else(EdgeFsParams::default_config, |p| p.camera),
            baud: self.baud,
            faults_s2a: faults.clone(),
            faults_a2s: faults,
            processing: timebase::Duration::from_micros((self.processing_ms * 1e3) as u64),
            mocap: self.mocap,
            ..FlightConfig::default()
        };
        if let Some(fsm) = self.fsm {
            cfg.autopilot.fsm.variant = fsm.variant();
        }
        if let Some([x, y, yaw_deg]) = self.start {
            cfg.start_xy = Some([x, y]);
            cfg.start_yaw_rad = Some(yaw_deg.to_radians());
        }
        cfg.camera = self.camera.params();
        cfg.camera.fps = self.fps;
        cfg.camera.misalign_px = self.misalign_px;
        cfg.battery = self.battery_mah.map(BatteryParams::lipo_1s);
        match self.velocity {
            Some(VelocityArg::Kalman) => {
                cfg.autopilot.estimation.velocity_source = VelocitySource::Kalman
            }
            Some(VelocityArg::Median) => {
                cfg.autopilot.estimation.velocity_source = VelocitySource::MedianObserver
            }
            Some(VelocityArg::KalmanFits) => {
                cfg.autopilot.estimation.velocity_source = VelocitySource::KalmanFits
            }
            None => {}
        }
        cfg
    }
}

/// The summary's columns, one literal for both headers.
macro_rules! summary_columns {
    () => {
        "seed,duration_s,flight_time_s,collisions,vel_rmse_mps,min_clearance_m,distance_m,\
         track_rmse_mps,hover_speed_mps,height_rmse_m,tilt_rmse_deg,stop_speed_mps,\
         hover_drift_m,end_reason"
    };
}

/// CSV header of the summary (`--format csv`).
pub const CSV_HEADER: &str = summary_columns!();

/// One CSV summary row.
pub fn csv_row(r: &FlightResult) -> String {
    format!(
        "{},{:.1},{:.2},{},{:.4},{:.4},{:.2},{:.4},{:.4},{:.4},{:.3},{:.4},{:.3},{}",
        r.seed,
        r.duration_s,
        r.flight_time_s,
        r.collisions,
        r.vel_rmse_mps,
        r.min_clearance_m,
        r.distance_m,
        r.tracking.track_rmse_mps,
        r.tracking.hover_speed_mps,
        r.tracking.height_rmse_m,
        r.tracking.tilt_rmse_deg,
        r.tracking.stop_speed_mps,
        r.tracking.hover_drift_m,
        r.end_reason.describe()
    )
}

fn bar(len: u64, quiet: bool, unit: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{{elapsed_precise}} [{{bar:40}}] {{pos}}/{{len}} {unit} ({{eta}})"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb
}

/// Runs `sim-host fly`.
pub fn run(args: &FlyArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.duration > 0.0 && args.duration.is_finite(),
        "--duration must be positive"
    );
    anyhow::ensure!(
        args.fps > 0.0 && args.fps <= 200.0,
        "--fps must be in (0, 200]"
    );
    if let Some(mah) = args.battery_mah {
        anyhow::ensure!(
            mah > 0.0 && mah.is_finite(),
            "--battery-mah must be positive, got {mah}"
        );
    }
    let scene = SceneSpec::from_cli(args.scene.as_deref(), &args.scenario)?;
    let params = args.params.as_deref().map(ParamFile::load).transpose()?;
    let params = params.as_ref();
    std::fs::create_dir_all(&args.out)?;
    if let Some(n) = args.suite {
        return run_suite(args, n, params);
    }
    let wall = Instant::now();
    match args.seeds {
        None | Some(1) => {
            let mut cfg = args.config(&scene, args.seed, params);
            cfg.keep_image_every = (cfg.camera.fps / 2.5).round().max(1.0) as u32;
            let pb = bar(
                args.duration.ceil() as u64,
                args.quiet || args.format == Format::Csv,
                "s",
            );
            let mcap_path = args
                .mcap
                .clone()
                .unwrap_or_else(|| args.out.join("flight.mcap"));
            let mut log = FlightLog::create(&mcap_path)?;
            if args.live {
                log.serve_live(LiveServer::start_announced(args.live_port)?);
            }
            let mut recorder = SimRecorder::new(log, LogRates::default());
            if args.live {
                recorder.pace_to_wall_clock();
            }
            let interrupted = crate::interrupt_flag()?;
            recorder.interrupt_on(interrupted.clone());
            let r = run_flight_observed(&cfg, &mut |t| pb.set_position(t as u64), &mut recorder)?;
            pb.finish_and_clear();
            if interrupted.load(Ordering::SeqCst) {
                eprintln!(
                    "interrupted at {:.1} s: writing the logs of the flight so far",
                    r.duration_s
                );
            }
            let secs = wall.elapsed().as_secs_f64();
            let mcap = recorder.finish()?;
            output::write_log_csv(&r, &args.out.join("log.csv"))?;
            output::plot_trajectory(&r, &args.out.join("trajectory.png"))?;
            output::plot_velocity(&r, &args.out.join("velocity.png"))?;
            output::plot_fsm(&r, &args.out.join("fsm.png"))?;
            output::write_gif(&r, &args.out.join("flight.gif"))?;
            match args.format {
                Format::Csv => {
                    println!("{CSV_HEADER}");
                    println!("{}", csv_row(&r));
                }
                Format::Table => {
                    println!(
                        "scene           {}  (seed {}, fsm {})",
                        scene.name,
                        r.seed,
                        FsmArg::name_of(cfg.autopilot.fsm.variant)
                    );
                    println!(
                        "duration        {:.1} s simulated in {:.1} s ({:.1}x real time)",
                        r.duration_s,
                        secs,
                        r.duration_s / secs
                    );
                    println!(
                        "flight time     {:.1} s (until the first collision)",
                        r.flight_time_s
                    );
                    println!("collisions      {}", r.collisions);
                    println!("end             {}", r.end_reason.describe());
                    println!(
                        "vel RMSE        {:.3} m/s (autopilot's velocity estimate vs truth; raw Edge-FS {:.3} m/s)",
                        r.vel_rmse_mps, r.raw_vel_rmse_mps
                    );
                    println!(
                        "min clearance   {:.3} m (to the drone's rotor tips)",
                        r.min_clearance_m
                    );
                    println!("distance flown  {:.1} m", r.distance_m);
                    println!(
                        "tracking        {:.3} m/s RMS in Forward, {:.3} m/s mean speed in Hover ({:.3} over the whole stop, Brake included), {:.3} m RMS height (level flight, true state vs setpoints)",
                        r.tracking.track_rmse_mps,
                        r.tracking.hover_speed_mps,
                        r.tracking.stop_speed_mps,
                        r.tracking.height_rmse_m
                    );
                    println!(
                        "hover drift     {:.3} m (largest distance from where a Hover began, within {:.0} s of it; true position)",
                        r.tracking.hover_drift_m,
                        crate::sim::metrics::HOVER_DRIFT_WINDOW_S
                    );
                    println!(
                        "attitude        {:.2} deg RMS tilt error of the estimate (level flight)",
                        r.tracking.tilt_rmse_deg
                    );
                    println!(
                        "estimates       {} received, {} valid; {} frames dropped",
                        r.estimates[0], r.estimates[1], r.frames_dropped
                    );
                    println!(
                        "link            cam->ap {:?}\n                ap->cam {:?}",
                        r.uart[0], r.uart[1]
                    );
                    println!("wrote           {}/{{log.csv,trajectory.png,velocity.png,fsm.png,flight.gif}}", args.out.display());
                    println!(
                        "flight log      {} ({} messages on {} channels, MCAP)",
                        mcap.path.display(),
                        mcap.total(),
                        mcap.counts.len()
                    );
                }
            }
        }
        Some(n) => {
            anyhow::ensure!(n > 0, "--seeds must be at least 1");
            let pb = bar(n, args.quiet || args.format == Format::Csv, "flights");
            let done = AtomicU64::new(0);
            let mut results: Vec<FlightResult> = (args.seed..args.seed + n)
                .into_par_iter()
                .map(|seed| {
                    let r = run_flight(&args.config(&scene, seed, params), &mut |_| {});
                    pb.set_position(done.fetch_add(1, Ordering::Relaxed) + 1);
                    r.map(|mut r| {
                        r.log = Vec::new();
                        r
                    })
                })
                .collect::<anyhow::Result<_>>()?;
            pb.finish_and_clear();
            results.sort_by_key(|r| r.seed);
            let mut csv = format!("{CSV_HEADER}\n");
            for r in &results {
                csv.push_str(&csv_row(r));
                csv.push('\n');
            }
            std::fs::write(args.out.join("montecarlo.csv"), &csv)?;
            match args.format {
                Format::Csv => print!("{csv}"),
                Format::Table => {
                    println!(
                        "{:>6} {:>10} {:>10} {:>5} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}  end",
                        "seed",
                        "duration",
                        "flight",
                        "coll",
                        "rmse",
                        "min_clr",
                        "dist",
                        "track",
                        "hover_v",
                        "stop_v",
                        "height",
                        "h_drift"
                    );
                    for r in &results {
                        println!(
                            "{:>6} {:>10.1} {:>10.1} {:>5} {:>9.3} {:>9.3} {:>9.1} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3}  {}",
                            r.seed,
                            r.duration_s,
                            r.flight_time_s,
                            r.collisions,
                            r.vel_rmse_mps,
                            r.min_clearance_m,
                            r.distance_m,
                            r.tracking.track_rmse_mps,
                            r.tracking.hover_speed_mps,
                            r.tracking.stop_speed_mps,
                            r.tracking.height_rmse_m,
                            r.tracking.hover_drift_m,
                            r.end_reason.describe()
                        );
                    }
                    let ok = results.iter().filter(|r| r.collisions == 0).count();
                    let mean_ft = results.iter().map(|r| r.flight_time_s).sum::<f64>() / n as f64;
                    let sim_s: f64 = results.iter().map(|r| r.duration_s).sum();
                    println!(
                        "{ok}/{n} flights without collision; mean flight time {mean_ft:.1} s; {:.1} s simulated in {:.1} s wall",
                        sim_s,
                        wall.elapsed().as_secs_f64()
                    );
                }
            }
        }
    }
    Ok(())
}

/// CSV header of the suite (`--suite N --format csv`): the summary columns, then the room's.
pub const SUITE_CSV_HEADER: &str = concat!(
    summary_columns!(),
    ",room,class,size_x_m,size_y_m,obstacles,light,mean_speed_mps,hovering_s,landed_s"
);

/// Runs `sim-host fly --suite N`.
/// Where the suite draws a flight's contact ([`output::plot_contact`]): `OUT/contacts/ROOM.png`.
fn contact_plot_path(out: &Path, room: &str) -> PathBuf {
    out.join("contacts").join(format!("{room}.png"))
}

fn run_suite(args: &FlyArgs, n: u64, params: Option<&ParamFile>) -> anyhow::Result<()> {
    anyhow::ensure!(n > 0, "--suite must be at least 1");
    let (shard, of) = args.shard.unwrap_or((0, 1));
    let rooms: Vec<SuiteRoom> = suite::shard_indices(n, shard, of)
        .map(|i| suite::room(args.seed, i))
        .collect();
    let wall = Instant::now();
    let pb = bar(
        rooms.len() as u64,
        args.quiet || args.format == Format::Csv,
        "flights",
    );
    let done = AtomicU64::new(0);
    let results: Vec<(FlightResult, FlightFigures)> = rooms
        .par_iter()
        .map(|room| {
            let r = run_flight(&args.config(&room.spec, room.seed, params), &mut |_| {});
            pb.set_position(done.fetch_add(1, Ordering::Relaxed) + 1);
            let mut r = r?;
            if args.room_logs {
                let dir = args.out.join(&room.spec.name);
                std::fs::create_dir_all(&dir)
                    .with_context(|| format!("creating {}", dir.display()))?;
                output::write_log_csv(&r, &dir.join("log.csv"))?;
            }
            if r.collisions > 0 {
                let plot = contact_plot_path(&args.out, &room.spec.name);
                if let Some(dir) = plot.parent() {
                    std::fs::create_dir_all(dir)
                        .with_context(|| format!("creating {}", dir.display()))?;
                }
                output::plot_contact(&r, &plot)
                    .with_context(|| format!("plotting {}", plot.display()))?;
            }
            let f = suite::figures(&r);
            r.log = Vec::new();
            Ok((r, f))
        })
        .collect::<anyhow::Result<_>>()?;
    pb.finish_and_clear();
    let mut csv = format!("{SUITE_CSV_HEADER}\n");
    for (room, (r, f)) in rooms.iter().zip(&results) {
        csv.push_str(&format!(
            "{},{},{},{:.2},{:.2},{},{:.3},{:.3},{:.1},{:.1}\n",
            csv_row(r),
            room.spec.name,
            room.class.name(),
            room.spec.size_m[0],
            room.spec.size_m[1],
            room.spec.obstacles.len(),
            room.spec.light,
            f.mean_speed_mps,
            f.hovering_s,
            f.landed_s
        ));
    }
    std::fs::write(args.out.join("suite.csv"), &csv)?;
    if args.format == Format::Csv {
        print!("{csv}");
        return Ok(());
    }
    let rows = suite::parse_csv("suite.csv", &csv, SUITE_CSV_HEADER)?;
    print!("{}", suite::table(&rows));
    let sim_s: f64 = results.iter().map(|(r, _)| r.duration_s).sum();
    println!(
        "{sim_s:.0} s simulated in {:.0} s wall; rows in {}",
        wall.elapsed().as_secs_f64(),
        args.out.join("suite.csv").display()
    );
    for (room, (r, _)) in rooms.iter().zip(&results) {
        if r.collisions > 0 {
            println!(
                "contact: {:<24} at {:>6.1} s  {}",
                room.spec.name,
                r.flight_time_s,
                contact_plot_path(&args.out, &room.spec.name).display()
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        fly: FlyArgs,
    }

    #[test]
    fn a_parameter_file_configures_both_simulated_boards() {
        let args = Cli::parse_from(["fly"]).fly;
        let scene = SceneSpec::preset(&args.scenario).unwrap();
        let file = ParamFile::parse(
            "[camera]\nstereo_shift = -3\nhalf_window = 5\n[autopilot]\nguid_kp = 0.25\n",
            "p.toml",
        )
        .unwrap();
        let cfg = args.config(&scene, 1, Some(&file));
        assert_eq!(cfg.edge_fs.stereo_shift_px, -3);
        assert_eq!(cfg.edge_fs.half_window, 5);
        assert_eq!(cfg.autopilot.guidance.kp, 0.25);
        let plain = args.config(&scene, 1, None);
        assert_eq!(plain.edge_fs, EdgeFsParams::default_config());
    }
}
