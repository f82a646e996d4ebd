//! `sim-host eval`: Edge-FS against motion-capture ground truth on the stereoboard_testing
//! data set (spec: edgefs-spec.md §1–§3, §7).
//!
//! Per take: discover the images, build the ground truth ([`truth`]), run the board's
//! [`EdgeFs`] on every image `1..=N-1` (the last image is never used, as in the reference),
//! and score images `10..=N-11` with NMXM, MSE and VAR ([`metrics`](mod@metrics)).
//!
//! Protocol rules that belong to the evaluation, not to the estimator, live here: the paper
//! configuration's outputs for images `i <= 2H` are set to 0; the estimator gets the OptiTrack
//! yaw (converted to the body convention: `yaw_body = -yaw_optitrack`) as its attitude and the
//! image times as capture times; its sideways output (positive right) is compared with the
//! data set's lateral velocity, which is positive to the left, so it is negated here; its
//! vertical output is compared with OptiTrack's vertical velocity (Y, up positive). Every
//! estimate is scored as it is, flagged or not (the flags are kept in [`Series::flags`]); the
//! default configuration is scored on the board's raw output (its temporal filter is part of
//! the estimator; no autopilot-side filter is applied here). The data set has no gyro rates,
//! so the attitude carries the yaw only and the rates are zero (the rigid body's OptiTrack
//! pitch is not the camera's: derotating the vertical flow by it, with either sign, raised the
//! vertical MSE on every take).

pub mod camera_calib;
pub mod dataset;
pub mod frame_stats;
pub mod metrics;
pub mod paper_table;
pub mod plot;
pub mod replay;
pub mod truth;

use anyhow::{bail, ensure, Context, Result};
use dataset::{discover_takes, load_frame, Take};
use indicatif::{ProgressBar, ProgressStyle};
use metrics::{metrics, Metrics};
use paper_table::paper_row;
use protocol::GyroAttitude;
use rayon::prelude::*;
use std::path::PathBuf;
use stereo_board::edge_fs::{EdgeFs, EdgeFsParams};
pub use truth::Alignment;

/// Which Edge-FS configuration to evaluate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Config {
    /// The paper's configuration (reproduces the published numbers with `--alignment paper`).
    Paper,
    /// Our best estimator exactly as the camera board emits it
    /// ([`EdgeFsParams::default_config`], temporal filter included; no autopilot-side filter).
    Default,
}

/// Output format of the results.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Human-readable table with a summary.
    Table,
    /// `board,take,frames,nmxm_x,mse_x,var_x,nmxm_y,mse_y,var_y,nmxm_z,mse_z,var_z,mse_z_zero`,
    /// full precision (`z`: vertical, up positive; `mse_z_zero`: the MSE of a zero-velocity
    /// predictor on the same frames).
    Csv,
}

/// Command-line arguments of `sim-host eval`.
#[derive(Debug, Clone, clap::Args)]
pub struct EvalArgs {
    /// Data set directory (layout of stereoboard_testing: database_stereoboard_N/forward_camera/takeK/).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Edge-FS configuration.
    #[arg(long, value_enum, default_value_t = Config::Default)]
    pub config: Config,
    /// Image-to-ground-truth alignment.
    #[arg(long, value_enum, default_value_t = Alignment::Paper)]
    pub alignment: Alignment,
    /// Takes to evaluate, comma-separated BOARD/TAKE (e.g. `1/3,2/3`) or BOARD/* ; default all.
    #[arg(long)]
    pub takes: Option<String>,
    /// Directory for PNG plots (one per take and a summary).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Table)]
    pub format: Format,
    /// Default configuration only: run the vertical flow with this search range, px (the
    /// board's default has it off, `EdgeFsParams::vertical_search_px`; 8 is
    /// `EdgeFsParams::VERTICAL_SEARCH_PX`). Without it the vertical columns score a zero
    /// estimate.
    #[arg(long)]
    pub vertical_search_px: Option<u8>,
    /// Default configuration only: check every stereo match both ways and drop the columns
    /// that disagree (`EdgeFsParams::lr_check`, off on the board).
    #[arg(long)]
    pub lr_check: bool,
}

/// Estimates and ground truth of one take for images `1..=N-1` (index 0 = image 1).
#[derive(Debug, Clone, Default)]
pub struct Series {
    /// Image times, s.
    pub time_s: Vec<f64>,
    /// Estimated forward velocity, m/s.
    pub est_x: Vec<f64>,
    /// Estimated lateral velocity (data set convention), m/s.
    pub est_y: Vec<f64>,
    /// Ground-truth forward velocity, m/s.
    pub gt_x: Vec<f64>,
    /// Ground-truth lateral velocity, m/s.
    pub gt_y: Vec<f64>,
    /// Estimated vertical velocity (up positive), m/s; 0 where the board does not estimate it
    /// (paper configuration).
    pub est_z: Vec<f64>,
    /// Ground-truth vertical velocity (up positive), m/s.
    pub gt_z: Vec<f64>,
    /// Validity flags of each estimate ([`protocol::EstimateFlags`] bits).
    pub flags: Vec<u8>,
    /// First and last evaluated index (0-based, inclusive).
    pub window: (usize, usize),
}

/// Result of one take.
#[derive(Debug, Clone)]
pub struct TakeResult {
    /// Board number.
    pub board: u32,
    /// Take number.
    pub take: u32,
    /// Number of images in the take.
    pub frames: usize,
    /// Forward-velocity metrics.
    pub x: Metrics,
    /// Sideways-velocity metrics.
    pub y: Metrics,
    /// Vertical-velocity metrics (up positive).
    pub z: Metrics,
    /// MSE of a zero-velocity predictor of the vertical velocity, (m/s)².
    pub z_zero_mse: f64,
    /// The series behind the metrics.
    pub series: Series,
}

/// Edge-FS parameters for a take: the configuration as the board runs it, with the board's
/// stereo shift from calibration_data.txt (the only per-board setting). The default
/// configuration is scored on the estimator's raw output, exactly what the camera board sends
/// (no filter the board does not run).
pub fn params_for(config: Config, take: &Take) -> Result<EdgeFsParams> {
    let mut p = match config {
        Config::Paper => EdgeFsParams::paper(),
        Config::Default => EdgeFsParams::default_config(),
    };
    p.stereo_shift_px = dataset::stereo_shift(take)?;
    Ok(p)
}

/// Evaluates one take. `on_frame` is called after every processed image.
pub fn evaluate_take(
    take: &Take,
    config: Config,
    alignment: Alignment,
    on_frame: &(dyn Fn() + Sync),
) -> Result<TakeResult> {
    let params = params_for(config, take)?;
    evaluate_take_with(take, params, config == Config::Paper, alignment, on_frame)
}

/// Evaluates one take with explicit parameters; `zero_first_2h` applies the paper protocol's
/// zeroing of the outputs of images `i <= 2H`.
pub fn evaluate_take_with(
    take: &Take,
    params: EdgeFsParams,
    zero_first_2h: bool,
    alignment: Alignment,
    on_frame: &(dyn Fn() + Sync),
) -> Result<TakeResult> {
    let n = take.image_count();
    ensure!(
        n > 0,
        "{}: no images (1.bmp or 1.png ...)",
        take.dir.display()
    );
    ensure!(
        n >= 22,
        "{}: only {n} images; the evaluation window 10..N-11 needs at least 22",
        take.dir.display()
    );
    let truth = truth::ground_truth(take, n, alignment)?;
    let s = estimate_series(
        &truth,
        params,
        zero_first_2h,
        &mut |i| load_frame(&take.image_path(i)),
        on_frame,
    )?;
    let (a, b) = s.window;
    let x = metrics(&s.est_x[a..=b], &s.gt_x[a..=b]);
    let y = metrics(&s.est_y[a..=b], &s.gt_y[a..=b]);
    let z = metrics(&s.est_z[a..=b], &s.gt_z[a..=b]);
    let zero = vec![0.0; b + 1 - a];
    let z_zero_mse = metrics(&zero, &s.gt_z[a..=b]).mse;
    Ok(TakeResult {
        board: take.board,
        take: take.take,
        frames: n,
        x,
        y,
        z,
        z_zero_mse,
        series: s,
    })
}

/// Runs Edge-FS with `params` on images `1..=N-1` of a take under the evaluation's protocol
/// (attitude = the truth's yaw in the body convention, capture time = the truth's image time,
/// sideways negated into the data set's convention), `frame(i)` giving image `i` (1-based).
/// `truth` has one entry per image `1..=N-1`; the evaluation window is `10..=N-11`.
pub fn estimate_series(
    truth: &truth::Truth,
    params: EdgeFsParams,
    zero_first_2h: bool,
    frame: &mut dyn FnMut(usize) -> Result<Box<[u8; protocol::STEREO_FRAME_BYTES]>>,
    on_frame: &(dyn Fn() + Sync),
) -> Result<Series> {
    let n = truth.time_s.len() + 1;
    ensure!(
        n >= 22,
        "only {n} images; the evaluation window 10..N-11 needs at least 22"
    );
    let mut fs = EdgeFs::new(params);
    let mut s = Series {
        time_s: truth.time_s.clone(),
        gt_x: truth.fwd.clone(),
        gt_y: truth.side.clone(),
        gt_z: truth.up.clone(),
        window: (9, n - 12),
        ..Series::default()
    };
    let h = params.max_horizon as usize;
    for i in 1..n {
        let frame = frame(i)?;
        let t = truth.time_s[i - 1];
        let yaw_body = -(truth.yaw_deg[i - 1] * std::f64::consts::PI / 180.0);
        let motion = GyroAttitude {
            timestamp_us: protocol::WireTime(0),
            rates_radps: [0.0; 3],
            attitude_rad: [0.0, 0.0, yaw_body as f32],
        };
        let capture_us = (t * 1e6).round().max(0.0) as u64;
        let out = fs.process(
            &frame,
            timebase::Instant::from_micros(capture_us),
            Some(&motion),
        );
        s.flags.push(out.flags.0);
        let (mut ex, mut ey) = (f64::from(out.forward_mps), -f64::from(out.sideways_mps));
        let mut ez = f64::from(out.up_mps);
        if zero_first_2h && i <= 2 * h {
            (ex, ey, ez) = (0.0, 0.0, 0.0);
        }
        s.est_z.push(ez);

        s.est_x.push(ex);
        s.est_y.push(ey);
        on_frame();
    }
    Ok(s)
}

/// Keeps the takes named in `list` (`B/T` or `B/*`, comma-separated).
pub fn select_takes(takes: Vec<Take>, list: Option<&str>) -> Result<Vec<Take>> {
    let Some(list) = list else {
        return Ok(takes);
    };
    let mut wanted: Vec<(u32, Option<u32>)> = Vec::new();
    for item in list.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let (b, t) = item
            .split_once('/')
            .with_context(|| format!("--takes: {item:?} is not BOARD/TAKE (e.g. 1/3)"))?;
        let b: u32 = b
            .parse()
            .with_context(|| format!("--takes: bad board in {item:?}"))?;
        let t = if t == "*" {
            None
        } else {
            Some(
                t.parse()
                    .with_context(|| format!("--takes: bad take in {item:?}"))?,
            )
        };
        wanted.push((b, t));
    }
    let sel: Vec<Take> = takes
        .into_iter()
        .filter(|tk| {
            wanted
                .iter()
                .any(|&(b, t)| b == tk.board && t.is_none_or(|t| t == tk.take))
        })
        .collect();
    ensure!(
        !sel.is_empty(),
        "--takes {list:?} matches no take in the data set"
    );
    Ok(sel)
}

/// Runs `sim-host eval`.
pub fn run(args: &EvalArgs) -> Result<()> {
    ensure!(
        args.vertical_search_px.is_none() || args.config == Config::Default,
        "--vertical-search-px applies to --config default only"
    );
    ensure!(
        !args.lr_check || args.config == Config::Default,
        "--lr-check applies to --config default only"
    );
    let takes = select_takes(discover_takes(&args.dataset)?, args.takes.as_deref())?;
    let total: usize = takes
        .iter()
        .map(|t| t.image_count().saturating_sub(1))
        .sum();
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} frames ({eta})")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let tick = || bar.inc(1);
    let results: Vec<(Take, Result<TakeResult>)> = takes
        .par_iter()
        .map(|t| {
            // The flags apply to the default configuration only (checked above).
            let r = params_for(args.config, t).and_then(|mut p| {
                if let Some(d) = args.vertical_search_px {
                    p.vertical_search_px = d;
                }
                p.lr_check |= args.lr_check;
                let paper = args.config == Config::Paper;
                evaluate_take_with(t, p, paper, args.alignment, &tick)
            });
            (t.clone(), r)
        })
        .collect();
    bar.finish_and_clear();
    let mut ok = Vec::new();
    let mut failed = 0;
    for (take, r) in results {
        match r {
            Ok(r) => ok.push(r),
            Err(e) => {
                failed += 1;
                eprintln!("error: board {} take {}: {e:#}", take.board, take.take);
            }
        }
    }
    match args.format {
        Format::Csv => print!("{}", csv(&ok)),
        Format::Table => print!("{}", table(&ok, args.config, args.alignment)),
    }
    if let Some(dir) = &args.out {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create output directory {}", dir.display()))?;
        for r in &ok {
            let path = dir.join(format!("board{}_take{}.png", r.board, r.take));
            plot::plot_take(r, &path).with_context(|| format!("plot {}", path.display()))?;
        }
        let path = dir.join("summary.png");
        plot::plot_summary(&ok, &path).with_context(|| format!("plot {}", path.display()))?;
        eprintln!("plots written to {}", dir.display());
    }
    if failed > 0 {
        bail!("{failed} take(s) could not be evaluated (see above)");
    }
    Ok(())
}

/// The CSV output (header and one row per take, full-precision floats).
pub fn csv(results: &[TakeResult]) -> String {
    let mut s = String::from(
        "board,take,frames,nmxm_x,mse_x,var_x,nmxm_y,mse_y,var_y,nmxm_z,mse_z,var_z,mse_z_zero\n",
    );
    for r in results {
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.board,
            r.take,
            r.frames,
            r.x.nmxm,
            r.x.mse,
            r.x.var,
            r.y.nmxm,
            r.y.mse,
            r.y.var,
            r.z.nmxm,
            r.z.mse,
            r.z.var,
            r.z_zero_mse
        );
    }
    s
}

fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| !x.is_nan());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

/// Win counts of our MSE against the published numbers of the takes that have them.
/// A win is a strictly lower unrounded MSE than the published (4-decimal) value; NaN never
/// wins.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Wins {
    /// Takes with published numbers.
    pub takes: usize,
    /// Forward: lower than the paper's Edge-FS.
    pub x_edgefs: usize,
    /// Forward: lower than the paper's Farnebäck.
    pub x_farneback: usize,
    /// Forward: lower than both.
    pub x_both: usize,
    /// Sideways: lower than the paper's Edge-FS.
    pub y_edgefs: usize,
    /// Sideways: lower than the paper's Farnebäck.
    pub y_farneback: usize,
    /// Sideways: lower than both.
    pub y_both: usize,
}

/// Counts the [`Wins`] of `results`.
pub fn wins(results: &[TakeResult]) -> Wins {
    let mut w = Wins::default();
    for r in results {
        if let Some(p) = paper_row(r.board, r.take) {
            let (xe, xf) = (r.x.mse < p.edgefs[1], r.x.mse < p.farneback[1]);
            let (ye, yf) = (r.y.mse < p.edgefs[4], r.y.mse < p.farneback[4]);
            w.takes += 1;
            w.x_edgefs += usize::from(xe);
            w.x_farneback += usize::from(xf);
            w.x_both += usize::from(xe && xf);
            w.y_edgefs += usize::from(ye);
            w.y_farneback += usize::from(yf);
            w.y_both += usize::from(ye && yf);
        }
    }
    w
}

/// The table output with summary.
pub fn table(results: &[TakeResult], config: Config, alignment: Alignment) -> String {
    let mut s = format!("Edge-FS config {config:?}, alignment {alignment:?}\n");
    s += "board take frames |  nmxm_x   mse_x   var_x |  nmxm_y   mse_y   var_y |  nmxm_z   mse_z   var_z  zero_z | paper Edge-FS mse_x mse_y | Farneback mse_x mse_y\n";
    for r in results {
        s += &format!(
            "{:>5} {:>4} {:>6} | {:>7.4} {:>7.4} {:>7.4} | {:>7.4} {:>7.4} {:>7.4} | {:>7.4} {:>7.4} {:>7.4} {:>7.4}",
            r.board,
            r.take,
            r.frames,
            r.x.nmxm,
            r.x.mse,
            r.x.var,
            r.y.nmxm,
            r.y.mse,
            r.y.var,
            r.z.nmxm,
            r.z.mse,
            r.z.var,
            r.z_zero_mse
        );
        if let Some(p) = paper_row(r.board, r.take) {
            s += &format!(
                " | {:>13.4} {:>5.4} | {:>15.4} {:>5.4}",
                p.edgefs[1], p.edgefs[4], p.farneback[1], p.farneback[4]
            );
        }
        s += "\n";
    }
    let mx = median(results.iter().map(|r| r.x.mse).collect());
    let my = median(results.iter().map(|r| r.y.mse).collect());
    s += &format!(
        "median MSE: x {mx:.4}, y {my:.4} ({} takes)\n",
        results.len()
    );
    let w = wins(results);
    let n = w.takes;
    if n > 0 {
        s += &format!(
            "takes with lower MSE than the paper's Edge-FS: x {}/{n}, y {}/{n}; than its Farneback: x {}/{n}, y {}/{n}; than both: x {}/{n}, y {}/{n}\n",
            w.x_edgefs, w.y_edgefs, w.x_farneback, w.y_farneback, w.x_both, w.y_both
        );
    }
    s
}
