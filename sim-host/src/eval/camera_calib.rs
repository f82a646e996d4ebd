//! `sim-host camera-calib`: measures the recorded camera pair's physical effects on its own
//! frames and timing files (never from the Edge-FS error), per take and per board.
//!
//! Methods (images `1..=N-1` of each take, valid rows only: rows not black in most frames):
//! * **column / row fixed pattern**: per frame the column (row) means minus their 9-px moving
//!   average (a high-pass that keeps what changes from one column to the next), averaged over
//!   the take's frames. The scene's share of that profile differs from take to take, a
//!   sensor-fixed pattern is the same in every take: the pattern's variance is estimated by the
//!   mean covariance of the profiles of different takes of the board (`fixed rms`, DN), the
//!   mean pairwise correlation tells how much of a take's profile it explains;
//! * **pixel pattern (dust, hot pixels)**: the same with the per-pixel temporal mean minus its
//!   3x3 neighbourhood mean;
//! * **vignetting**: the mean over every frame of the board's takes, per column; a parabola
//!   `a (1 + k (x - cx)²)` fitted to it (the scene's horizontal structure averages out over
//!   takes of different headings, its vertical structure - floor, ceiling - is not looked at);
//!   reported as the relative level at the image's side edge (64 px from the centre);
//! * **noise** at the take's gain, DN ([`FrameStats::noise_dn`]), both cameras;
//! * **right vs left**: level and edge-energy ratios, and the sharpness of each camera:
//!   `sum |I(x+1) - I(x-1)| / sum |I(x+2) - I(x-2)|` (blur lowers it);
//! * **frame timing**: intervals of the images' recorded times (`%i.bmp.tme` or timing.dat):
//!   mean, standard deviation (jitter) and largest;
//! * **the two cameras' relative timing**: the whole image's left-right shift against the
//!   motion-capture yaw rate, both high-passed over the frames (a running median of 7 removes
//!   the scene's slow depth changes; frames whose shift jumps by over a pixel are left out): a
//!   right camera exposed `t` after the left shifts by `f t` px per rad/s;
//! * **depth structure**: the 10th / 50th / 90th percentiles of the frames' median Edge-FS
//!   stereo depth, and the median over frames of each frame's spread of column depths
//!   (90th / 10th percentile ratio).

use super::dataset::{discover_takes, load_frame, stereo_shift, Frame, Take};
use super::frame_stats::FrameStats;
use super::select_takes;
use super::truth::{image_times, MocapTrack, RECORDER_LATENCY_S};
use anyhow::{Context, Result};
use std::fmt::Write as _;
use std::path::PathBuf;
use stereo_board::edge_fs::{EdgeFs, EdgeFsParams, CAMERA_FOCAL_PX, IMG_H, IMG_W};

/// Command-line arguments of `sim-host camera-calib`.
#[derive(Debug, Clone, clap::Args)]
pub struct CameraCalibArgs {
    /// Data set directory (layout of stereoboard_testing).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Takes to measure, BOARD/TAKE (e.g. `--take 1/3`, `1/*`); default all.
    #[arg(long = "take", value_name = "BOARD/TAKE")]
    pub takes: Vec<String>,
}

/// Half-width of the moving average the column and row profiles are high-passed with, px.
const PROFILE_HALF_WINDOW: usize = 4;

/// What one take's frames show of each camera effect.
#[derive(Debug, Clone)]
pub struct TakeCalib {
    /// Board number.
    pub board: u32,
    /// Take number.
    pub take: u32,
    /// High-passed mean column profile per camera (left, right), DN.
    pub col_profile: [Vec<f64>; 2],
    /// High-passed mean row profile per camera over the valid rows, DN.
    pub row_profile: [Vec<f64>; 2],
    /// Per-pixel temporal mean minus its 3x3 mean, left camera, DN (0 outside valid rows).
    pub pixel_pattern: Vec<f64>,
    /// Mean grey level per column, left and right camera, DN.
    pub col_mean: [Vec<f64>; 2],
    /// Noise, left and right camera, DN.
    pub noise_dn: [f64; 2],
    /// Mean level, left and right, DN.
    pub level_dn: [f64; 2],
    /// Right / left edge energy.
    pub right_left_edges: f64,
    /// Sharpness (`sum |g1| / sum |g2|`), left and right.
    pub sharpness: [f64; 2],
    /// Frame intervals: mean, standard deviation, largest, s.
    pub interval_s: [f64; 3],
    /// Frames' median stereo depth: 10th, 50th, 90th percentile, m.
    pub depth_m: [f64; 3],
    /// Median over frames of the 90th / 10th percentile ratio of the confident column depths.
    pub depth_spread: f64,
    /// Frames in the take.
    pub frames: usize,
    /// Per frame: (yaw rate at the image time, rad/s; horizontal shift of the bottom half's
    /// column edge histogram against the top half's, px).
    pub skew: Vec<(f64, f64)>,
    /// Per consecutive frame pair: the global horizontal shift of the left column edge
    /// histogram, px.
    pub global_shift: Vec<f64>,
    /// Per lag of [`LAGS_S`], per consecutive frame pair: the yaw change between the image
    /// times moved by the lag, rad.
    pub yaw_step: Vec<Vec<f64>>,
    /// Per frame: (yaw rate at the image's motion time, rad/s; the whole image's left-right
    /// column-edge shift, px), both less their running median over 7 frames.
    pub lr_on_yaw: Vec<(f64, f64)>,
}

/// Lags tried between the image times and the motion-capture times, s.
pub const LAGS_S: [f64; 31] = {
    let mut l = [0.0; 31];
    let mut i = 0;
    while i < 31 {
        l[i] = (i as f64 - 15.0) * 0.02;
        i += 1;
    }
    l
};

/// Column edge histogram (`sum |I(x+1) - I(x-1)|` per column) of one camera over `rows`.
fn column_edges(f: &Frame, eye: usize, rows: &[usize]) -> Vec<f64> {
    let mut h = vec![0.0; IMG_W];
    for &y in rows {
        for (x, hx) in h.iter_mut().enumerate().take(IMG_W - 1).skip(1) {
            let a = f[2 * (y * IMG_W + x - 1) + eye];
            let b = f[2 * (y * IMG_W + x + 1) + eye];
            *hx += f64::from(a.abs_diff(b));
        }
    }
    h
}

/// Shift `d` (px, sub-pixel) that best matches `b[x + d]` to `a[x]` (mean absolute difference
/// over the columns both cover), searched over `-max..=max`.
fn histogram_shift(a: &[f64], b: &[f64], max: i32) -> f64 {
    let n = a.len() as i32;
    let cost = |d: i32| {
        let (lo, hi) = ((max + 1).max(1 - d), (n - 1 - max).min(n - 1 - d));
        let m = (lo..hi)
            .map(|x| (a[x as usize] - b[(x + d) as usize]).abs())
            .sum::<f64>();
        m / f64::from((hi - lo).max(1))
    };
    let costs: Vec<f64> = (-max..=max).map(cost).collect();
    let best = (0..costs.len())
        .min_by(|&i, &j| costs[i].total_cmp(&costs[j]))
        .unwrap_or(0);
    let mut d = best as f64 - f64::from(max);
    if best > 0 && best + 1 < costs.len() {
        let (c0, c1, c2) = (costs[best - 1], costs[best], costs[best + 1]);
        let den = c0 - 2.0 * c1 + c2;
        if den > 0.0 {
            d += 0.5 * (c0 - c2) / den;
        }
    }
    d
}

/// Least-squares slope and its standard error of `y` on `x` (with an intercept).
pub fn slope(points: &[(f64, f64)]) -> (f64, f64) {
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0 / n, b + p.1 / n));
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let b = sxy / sxx;
    let a = my - b * mx;
    let res: f64 = points.iter().map(|p| (p.1 - a - b * p.0).powi(2)).sum();
    (b, (res / (n - 2.0).max(1.0) / sxx).sqrt())
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma).powi(2);
        sbb += (y - mb).powi(2);
    }
    sab / (saa * sbb).sqrt().max(1e-12)
}

fn high_pass(p: &[f64]) -> Vec<f64> {
    let n = p.len();
    (0..n)
        .map(|i| {
            let lo = i.saturating_sub(PROFILE_HALF_WINDOW);
            let hi = (i + PROFILE_HALF_WINDOW + 1).min(n);
            p[i] - p[lo..hi].iter().sum::<f64>() / (hi - lo) as f64
        })
        .collect()
}

/// Largest high-passed left-right shift of a frame the timing measurement uses, px.
const MAX_TIMING_SHIFT_PX: f64 = 1.0;

/// Half-width of the running median a frame series is high-passed with, frames.
const SERIES_HALF_WINDOW: usize = 3;

/// A series minus its running median over `2 SERIES_HALF_WINDOW + 1` frames: what changes
/// from frame to frame, without the slow drift (the scene's depth over a take).
fn high_pass_series(v: &[f64]) -> Vec<f64> {
    (0..v.len())
        .map(|i| {
            let lo = i.saturating_sub(SERIES_HALF_WINDOW);
            let hi = (i + SERIES_HALF_WINDOW + 1).min(v.len());
            let mut w = v[lo..hi].to_vec();
            v[i] - quantile(&mut w, 0.5)
        })
        .collect()
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Rows black in most frames (the recorder's padding).
fn valid_rows(frames: &[Frame]) -> Vec<usize> {
    (0..IMG_H)
        .filter(|&y| {
            let black = frames
                .iter()
                .filter(|f| (0..IMG_W).all(|x| f[2 * (y * IMG_W + x)] == 0))
                .count();
            2 * black <= frames.len()
        })
        .collect()
}

/// One frame's image motion against its stereo disparity over the columns that have both:
/// `u = a d + b d x + c + e x` (`u` the column's flow, px/s, `d` its disparity, px, `x` the
/// column from the image centre, px). A translating camera sees `u = d_true (p + q x)` plus a
/// rotation's constant; a disparity error `d - d_true = offset + slope x` (a calibration shift
/// off by a fraction of a pixel, cameras of different scale) puts `e = -offset b - slope a`.
#[derive(Debug, Clone, Copy)]
pub struct FlowOnDisparity {
    /// Coefficient of `d`, 1/s.
    pub a: f64,
    /// Coefficient of `d x`, 1/(px s).
    pub b: f64,
    /// Coefficient of `x`, 1/s.
    pub e: f64,
}

/// Least columns with both a disparity and a flow for a frame's [`FlowOnDisparity`].
const MIN_FLOW_DISPARITY_COLUMNS: usize = 16;

/// Least squares `y = X beta` by the normal equations (Gauss-Jordan with partial pivoting);
/// `None` when they are singular.
fn least_squares<const K: usize>(rows: &[([f64; K], f64)]) -> Option<[f64; K]> {
    // The normal equations as an augmented matrix [X'X | X'y].
    let mut m = [[0.0; K]; K];
    let mut v = [0.0; K];
    for (x, y) in rows {
        for ((mi, vi), xi) in m.iter_mut().zip(&mut v).zip(x) {
            *vi += xi * y;
            for (mij, xj) in mi.iter_mut().zip(x) {
                *mij += xi * xj;
            }
        }
    }
    let scale = m.iter().flatten().fold(0.0f64, |a, b| a.max(b.abs()));
    for col in 0..K {
        let piv = (col..K).max_by(|&i, &j| m[i][col].abs().total_cmp(&m[j][col].abs()))?;
        if m[piv][col].abs() <= 1e-12 * scale {
            return None;
        }
        m.swap(col, piv);
        v.swap(col, piv);
        let (pivot_row, pivot_v) = (m[col], v[col]);
        for (r, (mr, vr)) in m.iter_mut().zip(&mut v).enumerate() {
            if r != col {
                let k = mr[col] / pivot_row[col];
                for (a, p) in mr.iter_mut().zip(pivot_row) {
                    *a -= k * p;
                }
                *vr -= k * pivot_v;
            }
        }
    }
    let mut out = [0.0; K];
    for ((o, vi), mi) in out.iter_mut().zip(v).zip(m.iter().enumerate()) {
        *o = vi / mi.1[mi.0];
    }
    Some(out)
}

/// Per frame, [`FlowOnDisparity`] over the columns with a confident disparity and a flow
/// (Edge-FS default configuration with the take's stereo shift, no rotation given).
pub fn flow_on_disparity(frames: &[Frame], shift: i32, times: &[f64]) -> Vec<FlowOnDisparity> {
    let mut p = EdgeFsParams::default_config();
    p.stereo_shift_px = shift;
    let mut fs = EdgeFs::new(p);
    let centre = (IMG_W as f64 - 1.0) * 0.5;
    let mut out = Vec::new();
    for (f, &t) in frames.iter().zip(times) {
        fs.process(f, timebase::Instant::from_micros((t * 1e6) as u64), None);
        let dg = fs.diagnostics();
        let rows: Vec<([f64; 4], f64)> = (0..IMG_W)
            .filter(|&c| {
                dg.confidence[c] > 0.0 && dg.disparity_px[c] > 0.0 && dg.flow_pxps[c] != 0.0
            })
            .map(|c| {
                let (d, x) = (f64::from(dg.disparity_px[c]), c as f64 - centre);
                ([d, d * x, 1.0, x], f64::from(dg.flow_pxps[c]))
            })
            .collect();
        if rows.len() < MIN_FLOW_DISPARITY_COLUMNS {
            continue;
        }
        if let Some([a, b, _, e]) = least_squares(&rows) {
            out.push(FlowOnDisparity { a, b, e });
        }
    }
    out
}

/// The disparity error `d - d_true = offset + slope x` that frames' [`FlowOnDisparity`] show
/// (least squares of `e` on `a` and `b` over the frames): `(offset px, slope px/px)`.
///
/// The estimate is biased (noise in the disparities, the flow's horizon, the scene), so it
/// means something only against the same estimate on frames of a known error: `replay`
/// reports it for the recorded frames and for their rendering, whose error is zero.
pub fn disparity_error(fits: &[FlowOnDisparity]) -> (f64, f64) {
    let rows: Vec<([f64; 3], f64)> = fits.iter().map(|g| ([g.a, g.b, 1.0], g.e)).collect();
    least_squares(&rows).map_or((f64::NAN, f64::NAN), |k| (-k[1], -k[0]))
}

/// The left-right shear: median over frames of the left-right shift (the right image's
/// column edge histogram against the left's, px) of the bottom half of the valid rows minus
/// that of the top half. The cameras' relative roll shows in it, and so does the depth
/// structure (a nearer floor in the bottom half): `replay` compares it with the same
/// statistic of the take's rendering.
pub fn lr_shear(frames: &[Frame]) -> f64 {
    let rows = valid_rows(frames);
    let (top, bottom) = rows.split_at(rows.len() / 2);
    let mut dif: Vec<f64> = frames
        .iter()
        .map(|f| {
            let st = histogram_shift(&column_edges(f, 0, top), &column_edges(f, 1, top), 24);
            let sb = histogram_shift(&column_edges(f, 0, bottom), &column_edges(f, 1, bottom), 24);
            sb - st
        })
        .collect();
    quantile(&mut dif, 0.5)
}

/// Measures one take (see the module docs).
pub fn measure_take(take: &Take) -> Result<TakeCalib> {
    let n = take.image_count();
    anyhow::ensure!(n >= 3, "{}: only {n} images", take.dir.display());
    let frames: Vec<Frame> = (1..n)
        .map(|i| load_frame(&take.image_path(i)))
        .collect::<Result<_>>()?;
    let rows = valid_rows(&frames);
    let nf = frames.len() as f64;
    let mut col_profile = [vec![0.0; IMG_W], vec![0.0; IMG_W]];
    let mut row_profile = [vec![0.0; rows.len()], vec![0.0; rows.len()]];
    let mut col_mean = [vec![0.0; IMG_W], vec![0.0; IMG_W]];
    let mut pix_mean = vec![0.0; IMG_W * IMG_H];
    let (mut g1, mut g2) = ([0.0; 2], [0.0; 2]);
    let (mut noise, mut level) = ([0.0; 2], [0.0; 2]);
    let mut edges = 0.0;
    for f in &frames {
        let st = FrameStats::of_frame(f);
        noise[0] += st.noise_dn / nf;
        level[0] += st.mean_dn / nf;
        edges += st.right_left_edges / nf;
        // The right camera's statistics: swap the two images of the frame.
        let mut swapped: Frame = f.clone();
        for px in swapped.chunks_exact_mut(2) {
            px.swap(0, 1);
        }
        let sr = FrameStats::of_frame(&swapped);
        noise[1] += sr.noise_dn / nf;
        level[1] += sr.mean_dn / nf;
        for eye in 0..2 {
            let px = |x: usize, y: usize| f64::from(f[2 * (y * IMG_W + x) + eye]);
            let cols: Vec<f64> = (0..IMG_W)
                .map(|x| rows.iter().map(|&y| px(x, y)).sum::<f64>() / rows.len() as f64)
                .collect();
            let rws: Vec<f64> = rows
                .iter()
                .map(|&y| (0..IMG_W).map(|x| px(x, y)).sum::<f64>() / IMG_W as f64)
                .collect();
            for (a, b) in col_profile[eye].iter_mut().zip(high_pass(&cols)) {
                *a += b / nf;
            }
            for (a, b) in row_profile[eye].iter_mut().zip(high_pass(&rws)) {
                *a += b / nf;
            }
            for (a, b) in col_mean[eye].iter_mut().zip(&cols) {
                *a += b / nf;
            }
            for &y in &rows {
                for x in 2..IMG_W - 2 {
                    g1[eye] += (px(x + 1, y) - px(x - 1, y)).abs();
                    g2[eye] += (px(x + 2, y) - px(x - 2, y)).abs();
                }
                if eye == 0 {
                    for x in 0..IMG_W {
                        pix_mean[y * IMG_W + x] += px(x, y) / nf;
                    }
                }
            }
        }
    }
    let mut pixel_pattern = vec![0.0; IMG_W * IMG_H];
    for w in rows.windows(3) {
        if w[2] != w[0] + 2 {
            continue;
        }
        let y = w[1];
        for x in 1..IMG_W - 1 {
            let mut s = 0.0;
            for yy in y - 1..=y + 1 {
                for xx in x - 1..=x + 1 {
                    s += pix_mean[yy * IMG_W + xx];
                }
            }
            pixel_pattern[y * IMG_W + x] = pix_mean[y * IMG_W + x] - s / 9.0;
        }
    }
    let times = image_times(take, n)?;
    let dt: Vec<f64> = times.windows(2).map(|w| w[1] - w[0]).collect();
    let mean_dt = dt.iter().sum::<f64>() / dt.len().max(1) as f64;
    let sd_dt =
        (dt.iter().map(|d| (d - mean_dt).powi(2)).sum::<f64>() / dt.len().max(1) as f64).sqrt();
    let max_dt = dt.iter().copied().fold(0.0, f64::max);
    let (depths, spread) = depth_structure(&frames, stereo_shift(take)?);
    let track = MocapTrack::read(take)?;
    let yaw_rad = |t: f64| track.at(&track.yaw, t).to_radians();
    let (top, bottom) = rows.split_at(rows.len() / 2);
    let skew: Vec<(f64, f64)> = frames
        .iter()
        .zip(&times)
        .map(|(f, &t)| {
            let rate = (yaw_rad(t + 0.05) - yaw_rad(t - 0.05)) / 0.1;
            let shift = histogram_shift(&column_edges(f, 0, top), &column_edges(f, 0, bottom), 3);
            (rate, shift)
        })
        .collect();
    let hists: Vec<Vec<f64>> = frames.iter().map(|f| column_edges(f, 0, &rows)).collect();
    let global_shift: Vec<f64> = hists
        .windows(2)
        .map(|w| histogram_shift(&w[0], &w[1], 10))
        .collect();
    let yaw_step: Vec<Vec<f64>> = LAGS_S
        .iter()
        .map(|lag| {
            times
                .windows(2)
                .map(|w| yaw_rad(w[1] + lag) - yaw_rad(w[0] + lag))
                .collect()
        })
        .collect();
    let motion_rate = |t: f64| {
        let t = t - RECORDER_LATENCY_S;
        (yaw_rad(t + 0.05) - yaw_rad(t - 0.05)) / 0.1
    };
    let lr: Vec<f64> = frames
        .iter()
        .zip(&hists)
        .map(|(f, left)| histogram_shift(left, &column_edges(f, 1, &rows), 24))
        .collect();
    let rates: Vec<f64> = times.iter().map(|&t| motion_rate(t)).collect();
    let lr_on_yaw = high_pass_series(&rates)
        .into_iter()
        .zip(high_pass_series(&lr))
        .collect();
    let mut d = depths.clone();
    let mut s = spread;
    Ok(TakeCalib {
        board: take.board,
        take: take.take,
        col_profile,
        row_profile,
        pixel_pattern,
        col_mean,
        noise_dn: noise,
        level_dn: level,
        right_left_edges: edges,
        sharpness: [g1[0] / g2[0].max(1.0), g1[1] / g2[1].max(1.0)],
        interval_s: [mean_dt, sd_dt, max_dt],
        depth_m: [
            quantile(&mut d, 0.1),
            quantile(&mut d, 0.5),
            quantile(&mut d, 0.9),
        ],
        depth_spread: quantile(&mut s, 0.5),
        frames: frames.len(),
        skew,
        global_shift,
        yaw_step,
        lr_on_yaw,
    })
}

/// Per frame with confident stereo columns: the median depth and the 90th / 10th percentile
/// ratio of the column depths.
fn depth_structure(frames: &[Frame], shift: i32) -> (Vec<f64>, Vec<f64>) {
    let mut p = EdgeFsParams::default_config();
    p.stereo_shift_px = shift;
    let mut fs = EdgeFs::new(p);
    let (mut med, mut spread) = (Vec::new(), Vec::new());
    for (i, f) in frames.iter().enumerate() {
        fs.process(f, timebase::Instant::from_micros(143_000 * i as u64), None);
        let d = fs.diagnostics();
        let mut v: Vec<f64> = d
            .depth_m
            .iter()
            .zip(&d.confidence)
            .filter(|(z, c)| **z > 0.0 && **c > 0.0)
            .map(|(z, _)| f64::from(*z))
            .collect();
        if v.len() >= 4 {
            let lo = quantile(&mut v, 0.1);
            let hi = quantile(&mut v, 0.9);
            med.push(quantile(&mut v, 0.5));
            spread.push(hi / lo);
        }
    }
    (med, spread)
}

/// Fixed-pattern estimate from the profiles of several takes: `(rms of the common part, mean
/// pairwise correlation, rms of one take's profile)`. The common part's variance is the mean
/// covariance of the profiles of two different takes (the scene's share is independent between
/// takes and averages out of it).
pub fn common_pattern(profiles: &[&[f64]]) -> (f64, f64, f64) {
    let n = profiles.len();
    let len = profiles.first().map_or(0, |p| p.len());
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>() / len as f64;
    let (mut cov, mut corr, mut pairs) = (0.0, 0.0, 0.0);
    for i in 0..n {
        for j in i + 1..n {
            let c = dot(profiles[i], profiles[j]);
            cov += c;
            corr += c / (dot(profiles[i], profiles[i]) * dot(profiles[j], profiles[j])).sqrt();
            pairs += 1.0;
        }
    }
    let own = profiles.iter().map(|p| dot(p, p)).sum::<f64>() / n.max(1) as f64;
    if pairs == 0.0 {
        return (f64::NAN, f64::NAN, own.sqrt());
    }
    ((cov / pairs).max(0.0).sqrt(), corr / pairs, own.sqrt())
}

/// Relative vignetting `k` (per px²) and the level at the side edge relative to the centre,
/// from the mean column profile: least squares of `a + b (x - cx)²`.
pub fn vignetting(col_mean: &[f64]) -> (f64, f64) {
    let cx = (col_mean.len() as f64 - 1.0) * 0.5;
    let pts: Vec<(f64, f64)> = col_mean
        .iter()
        .enumerate()
        .skip(2)
        .take(col_mean.len() - 4)
        .map(|(x, &v)| ((x as f64 - cx).powi(2), v))
        .collect();
    let n = pts.len() as f64;
    let (sx, sy) = pts.iter().fold((0.0, 0.0), |(a, b), p| (a + p.0, b + p.1));
    let (mx, my) = (sx / n, sy / n);
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let b = sxy / sxx;
    let a = my - b * mx;
    let k = b / a;
    (k, 1.0 + k * 64.0 * 64.0)
}

/// The report: one line per take, then per board the fixed patterns and vignetting.
pub fn report(takes: &[TakeCalib]) -> String {
    let mut s = String::new();
    s += "board take frames | noise L  R  | level L   R  | R/L edges | sharp L  R   | dt mean  sd    max   s | depth p10 p50 p90 m spread | colHP rms L | rowHP rms L\n";
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    for t in takes {
        let _ = writeln!(
            s,
            "{:>5} {:>4} {:>6} | {:>4.2} {:>4.2} | {:>5.1} {:>5.1} | {:>9.3} | {:>5.3} {:>5.3} | {:>6.4} {:>6.4} {:>6.4} | {:>5.2} {:>5.2} {:>5.2} {:>6.2} | {:>11.3} | {:>11.3}",
            t.board,
            t.take,
            t.frames,
            t.noise_dn[0],
            t.noise_dn[1],
            t.level_dn[0],
            t.level_dn[1],
            t.right_left_edges,
            t.sharpness[0],
            t.sharpness[1],
            t.interval_s[0],
            t.interval_s[1],
            t.interval_s[2],
            t.depth_m[0],
            t.depth_m[1],
            t.depth_m[2],
            t.depth_spread,
            rms(&t.col_profile[0]),
            rms(&t.row_profile[0]),
        );
    }
    let mut boards: Vec<u32> = takes.iter().map(|t| t.board).collect();
    boards.dedup();
    for b in boards {
        let bt: Vec<&TakeCalib> = takes.iter().filter(|t| t.board == b).collect();
        let c = board_calib(&bt);
        let _ = writeln!(s, "board {b} ({} takes):", bt.len());
        for (eye, name) in [(0, "left"), (1, "right")] {
            let _ = writeln!(
                s,
                "  {name:>5}: column pattern fixed rms {:.3} DN (corr {:.2}); row pattern fixed rms {:.3} DN (corr {:.2}); vignetting k {:.2e}/px^2, side edge {:.3}",
                c.column_fixed_dn[eye],
                c.column_corr[eye],
                c.row_fixed_dn[eye],
                c.row_corr[eye],
                c.vignetting_k[eye],
                1.0 + c.vignetting_k[eye] * 64.0 * 64.0,
            );
        }
        let _ = writeln!(
            s,
            "   left: pixel pattern fixed rms {:.3} DN (corr {:.2})",
            c.pixel_fixed_dn, c.pixel_corr
        );
        let _ = writeln!(
            s,
            "  rolling shutter: readout {:.1} +- {:.1} ms (top to bottom)",
            1e3 * c.readout_s[0],
            1e3 * c.readout_s[1]
        );
        let best = (0..c.lag_corr.len())
            .max_by(|&i, &j| c.lag_corr[i].abs().total_cmp(&c.lag_corr[j].abs()))
            .unwrap_or(0);
        let _ = writeln!(
            s,
            "  latency: image-shift vs yaw-step correlation best at lag {:+.2} s (image time + lag = motion time; corr {:.2}; at 0: {:.2})",
            LAGS_S[best],
            c.lag_corr[best],
            c.lag_corr[LAGS_S.len() / 2]
        );
        let curve: Vec<String> = LAGS_S
            .iter()
            .zip(&c.lag_corr)
            .step_by(2)
            .map(|(l, c)| format!("{l:+.2}:{c:.2}"))
            .collect();
        let _ = writeln!(s, "    correlation by lag: {}", curve.join(" "));
        let _ = writeln!(
            s,
            "  right camera after the left: {:+.2} +- {:.2} ms (left-right shift on the yaw rate; yaw rate rms {:.3} rad/s)",
            1e3 * c.right_delay_s[0],
            1e3 * c.right_delay_s[1],
            c.timing_yaw_rate_rms
        );
    }
    s
}

/// A board's effects measured over several of its takes (see the module docs).
#[derive(Debug, Clone)]
pub struct BoardCalib {
    /// Column fixed-pattern rms common to the takes, left and right camera, DN.
    pub column_fixed_dn: [f64; 2],
    /// Mean correlation of the takes' column profiles, left and right.
    pub column_corr: [f64; 2],
    /// Row fixed-pattern rms common to the takes, left and right, DN.
    pub row_fixed_dn: [f64; 2],
    /// Mean correlation of the takes' row profiles, left and right.
    pub row_corr: [f64; 2],
    /// Pixel fixed-pattern rms common to the takes (left camera), DN.
    pub pixel_fixed_dn: f64,
    /// Mean correlation of the takes' pixel patterns.
    pub pixel_corr: f64,
    /// Vignetting `k` (level `1 + k x²` from the centre column), left and right, per px².
    pub vignetting_k: [f64; 2],
    /// Rolling-shutter readout time (top to bottom row) and its standard error, s.
    pub readout_s: [f64; 2],
    /// Correlation of the images' global shift with the yaw step at each lag of [`LAGS_S`].
    pub lag_corr: Vec<f64>,
    /// The right camera's exposure after the left's and its standard error, s: the whole
    /// image's left-right shift on the yaw rate (both high-passed) over the focal length.
    pub right_delay_s: [f64; 2],
    /// The rms of the high-passed yaw rate that measurement had, rad/s (its sensitivity).
    pub timing_yaw_rate_rms: f64,
}

/// Pools a board's takes (at least two for the fixed patterns).
pub fn board_calib(bt: &[&TakeCalib]) -> BoardCalib {
    let mut c = BoardCalib {
        column_fixed_dn: [0.0; 2],
        column_corr: [0.0; 2],
        row_fixed_dn: [0.0; 2],
        row_corr: [0.0; 2],
        pixel_fixed_dn: 0.0,
        pixel_corr: 0.0,
        vignetting_k: [0.0; 2],
        readout_s: [0.0; 2],
        lag_corr: Vec::new(),
        right_delay_s: [f64::NAN; 2],
        timing_yaw_rate_rms: f64::NAN,
    };
    for eye in 0..2 {
        let cols: Vec<&[f64]> = bt.iter().map(|t| t.col_profile[eye].as_slice()).collect();
        let (fixed, corr, _) = common_pattern(&cols);
        (c.column_fixed_dn[eye], c.column_corr[eye]) = (fixed, corr);
        let row_len = bt
            .iter()
            .map(|t| t.row_profile[eye].len())
            .min()
            .unwrap_or(0);
        let rows: Vec<&[f64]> = bt.iter().map(|t| &t.row_profile[eye][..row_len]).collect();
        let (fixed, corr, _) = common_pattern(&rows);
        (c.row_fixed_dn[eye], c.row_corr[eye]) = (fixed, corr);
        let mut mean = vec![0.0; IMG_W];
        for t in bt {
            for (m, v) in mean.iter_mut().zip(&t.col_mean[eye]) {
                *m += v / bt.len() as f64;
            }
        }
        c.vignetting_k[eye] = vignetting(&mean).0;
    }
    let pix: Vec<&[f64]> = bt.iter().map(|t| t.pixel_pattern.as_slice()).collect();
    let (fixed, corr, _) = common_pattern(&pix);
    (c.pixel_fixed_dn, c.pixel_corr) = (fixed, corr);
    let skew: Vec<(f64, f64)> = bt.iter().flat_map(|t| t.skew.iter().copied()).collect();
    let (k, k_se) = slope(&skew);
    // The halves' centres are half the valid rows apart: half the readout time.
    let f = f64::from(CAMERA_FOCAL_PX);
    c.readout_s = [2.0 * k / f, 2.0 * k_se / f];
    let shifts: Vec<f64> = bt
        .iter()
        .flat_map(|t| t.global_shift.iter().copied())
        .collect();
    c.lag_corr = (0..LAGS_S.len())
        .map(|l| {
            let steps: Vec<f64> = bt
                .iter()
                .flat_map(|t| t.yaw_step[l].iter().copied())
                .collect();
            correlation(&shifts, &steps)
        })
        .collect();
    // A frame whose shift jumps by over a pixel changed its view (an object came close), not
    // its timing.
    let lr_on_yaw: Vec<(f64, f64)> = bt
        .iter()
        .flat_map(|t| t.lr_on_yaw.iter().copied())
        .filter(|p| p.1.abs() <= MAX_TIMING_SHIFT_PX)
        .collect();
    let (k, k_se) = slope(&lr_on_yaw);
    c.right_delay_s = [k / f, k_se / f];
    c.timing_yaw_rate_rms =
        (lr_on_yaw.iter().map(|p| p.0 * p.0).sum::<f64>() / lr_on_yaw.len().max(1) as f64).sqrt();
    c
}

/// Runs `sim-host camera-calib`.
pub fn run(args: &CameraCalibArgs) -> Result<()> {
    use rayon::prelude::*;
    let list = args.takes.join(",");
    let takes = select_takes(
        discover_takes(&args.dataset)?,
        (!list.is_empty()).then_some(list.as_str()),
    )?;
    let calibs: Vec<TakeCalib> = takes
        .par_iter()
        .map(|t| measure_take(t).with_context(|| format!("board {} take {}", t.board, t.take)))
        .collect::<Result<_>>()?;
    print!("{}", report(&calibs));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn least_squares_recovers_a_plane_and_refuses_a_singular_one() {
        let rows: Vec<([f64; 3], f64)> = (0..40)
            .map(|i| {
                let (x, z) = (f64::from(i % 7) - 3.0, f64::from(i % 5) * 0.5);
                ([x, z, 1.0], 2.0 * x - 0.75 * z + 4.0)
            })
            .collect();
        let k = least_squares(&rows).unwrap();
        for (got, want) in k.iter().zip([2.0, -0.75, 4.0]) {
            assert!((got - want).abs() < 1e-9, "{k:?}");
        }
        let collinear: Vec<([f64; 2], f64)> = (0..10)
            .map(|i| ([f64::from(i), 2.0 * f64::from(i)], 1.0))
            .collect();
        assert!(least_squares(&collinear).is_none());
    }

    #[test]
    fn a_disparity_error_shows_in_the_x_term_of_the_image_motion() {
        // Frames whose fits carry e = -offset b - slope a (lateral and forward motion varying).
        let (offset, slope) = (0.4, 0.006);
        let fits: Vec<FlowOnDisparity> = (0..50)
            .map(|i| {
                let a = (f64::from(i) * 0.7).sin() * 3.0;
                let b = (f64::from(i) * 1.3).cos() * 0.02;
                FlowOnDisparity {
                    a,
                    b,
                    e: -offset * b - slope * a,
                }
            })
            .collect();
        let (o, s) = disparity_error(&fits);
        assert!(
            (o - offset).abs() < 1e-9 && (s - slope).abs() < 1e-9,
            "{o} {s}"
        );
    }
}
