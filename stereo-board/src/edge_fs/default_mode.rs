//! The default mode's fit of one frame, [`EdgeFs::fit_default`], in named stages: brightness,
//! the noise model, stereo, the nearest obstacle, the view's coverage, the flow horizon and its
//! derotation, flow, the adaptive horizon, the robust fit, the velocity and its checks, the
//! output median, quality, standard errors and the coupled three-axis fit.
//!
//! Each stage runs once per frame and is `#[inline(always)]`: the split is for the reader; the
//! stages compile into one function, as the single function did (`cargo xtask insns`). The
//! stages hand their per-frame results on in small fixed-size structs on the stack; no heap.

use super::divergence::FlowSamples;
use super::fit::MAD_TO_SIGMA;
use super::histogram::NOISE_DIFF_PER_SIGMA;
use super::matching::RowMatch;
use super::{
    coverage_u8, flow_row, fmax, fmin, histogram_steps, longest_run, median, pixel_noise_dn,
    robust_line_fit, stereo_row, stereo_row_checked, window_sums, wrap_pi, EdgeFs, EdgeFsOutput,
    LineFit, Slot, IMG_H, IMG_W, LR_KEEP_PAIRS, MEDIAN_MAX,
};
use super::{Diagnostics, EdgeFsParams, EdgeHistogram};
use protocol::{EstimateFlags, STEREO_FRAME_BYTES};

/// Mean intensity of the left image, DN, below which the frame is flagged
/// [`EstimateFlags::TOO_DARK`].
const TOO_DARK_MEAN: u8 = 12;

/// Mean intensity of the left image, DN, above which the frame is flagged
/// [`EstimateFlags::TOO_BRIGHT`].
const TOO_BRIGHT_MEAN: u8 = 243;

/// The mean step between neighbouring histogram bins that pixel noise of 1 DN gives alone.
/// Each bin sums `IMG_H` absolute differences of two pixels, each of variance 2σ²(1 - 2/π);
/// neighbouring bins share no pixel, so their difference has variance 4·IMG_H·σ²(1 - 2/π),
/// and its absolute value averages √(2/π) of its spread: 0.798 · √(4 · 96 · 0.3634) = 9.43.
const NOISE_STEP_PER_SIGMA: f32 = 9.43;

/// Disjoint windows of a frame that must not be noise
/// ([`EdgeFsParams::noise_texture_ratio`](super::EdgeFsParams::noise_texture_ratio),
/// [`EdgeFsParams::noise_structure_ratio`](super::EdgeFsParams::noise_structure_ratio)) for a
/// velocity.
const MIN_TEXTURED_WINDOWS: usize = 3;

/// The edge energy summed over the frame's disjoint column windows must reach this many times
/// [`EdgeFsParams::min_texture`](super::EdgeFsParams::min_texture), else the frame is flagged
/// [`EstimateFlags::NO_TEXTURE`].
const FRAME_TEXTURE_WINDOWS: u32 = 4;

/// Largest stereo peak ratio recorded in
/// [`Diagnostics::confidence`](super::Diagnostics::confidence) (the ratio of an exact match,
/// SAD 0, is infinite).
const MAX_DIAG_CONFIDENCE: f32 = 100.0;

/// Fewest columns of a line fit whatever
/// [`EdgeFsParams::min_fit_columns`](super::EdgeFsParams::min_fit_columns) says: two points
/// make a line.
const MIN_LINE_POINTS: usize = 2;

/// Shortest time span of the flow horizon, s: at or below it the flow is not measured
/// ([`EstimateFlags::NO_FLOW_MATCH`]).
const MIN_FLOW_SPAN_S: f32 = 1e-4;

/// The image's centre column, px (0-based): the fit's `x` is the column minus this.
const CENTRE_COLUMN: f32 = 0.5 * (IMG_W - 1) as f32;

/// The guided flow search's window (`prior_window_px` plus the prediction's own uncertainty)
/// reaches at most this many times
/// [`EdgeFsParams::prior_window_px`](super::EdgeFsParams::prior_window_px) to either side of
/// the predicted match.
const PRIOR_WINDOW_CAP: f32 = 2.0;

/// Smallest depth, m, in a column's fit weight `Z^-depth_weight_exp`.
const MIN_WEIGHT_DEPTH_M: f32 = 0.05;

/// The guided flow search is doubted (the next frame searches the whole range) when more than
/// one in this many textured columns miss the predicted window.
const PRIOR_DOUBT_SHARE: usize = 4;

/// The adaptive horizon shortens when more than one in this many textured columns' flow
/// searches hit the end of the search range.
const HORIZON_SHORTEN_SHARE: usize = 8;

/// The adaptive horizon lengthens when at most one in this many textured columns' flow searches
/// hit the end of the search range.
const HORIZON_LENGTHEN_SHARE: usize = 32;

/// Huber reweighting rounds of the robust line fit ([`robust_line_fit`]).
const ROBUST_FIT_ROUNDS: usize = 4;

/// Columns in the fit for full [`EdgeFsOutput::quality`]; fewer scale it down in proportion.
const FULL_QUALITY_COLUMNS: f32 = 32.0;

/// Robust residual scale, m/s, at which [`EdgeFsOutput::quality`] has fallen to 1/e of that of
/// a perfect fit (it scales with `exp(-rms / QUALITY_RMS_SCALE_MPS)`).
const QUALITY_RMS_SCALE_MPS: f32 = 0.3;

/// The 0..=255 scale of [`EdgeFsOutput::quality`] and [`EdgeFsOutput::fit_r2`].
const FULL_SCALE: f32 = 255.0;

/// Floor of the fit columns' sum of squared deviations from their mean, px², in the slope's
/// standard error.
const MIN_SLOPE_SPREAD: f32 = 1.0;

/// The frame's texture against its pixel noise ([`EdgeFs::noise_model`]).
struct NoiseModel {
    /// Edge energy per column: the sum of the histogram bins of the `2w+1` window
    /// ([`window_sums`]).
    texture: [u32; IMG_W],
    /// Shape per column: the sum of the window's steps between neighbouring bins
    /// ([`histogram_steps`]); zeros when the shape test is off.
    shape: [u32; IMG_W],
    /// A window whose edge energy reaches this is not noise.
    clear_of_noise: u32,
    /// A window whose shape reaches this is not noise (`u32::MAX`: the shape test is off).
    shaped: u32,
}

impl NoiseModel {
    /// The window at column `c` is not noise: its edge sum stands out of the noise's, or its
    /// histogram has more shape than noise gives it.
    #[inline(always)]
    fn not_noise(&self, c: usize) -> bool {
        self.texture[c] >= self.clear_of_noise || self.shape[c] >= self.shaped
    }
}

/// The stereo result per column ([`EdgeFs::stereo_stage`]); the depths themselves are in the
/// diagnostics.
struct StereoColumns {
    /// Column with a confident depth.
    ok: [bool; IMG_W],
    /// Columns with a confident depth.
    count: usize,
    /// Textured column whose disparity search ran out of range (nearer than the minimum range).
    near: [bool; IMG_W],
    /// Columns nearer than the minimum range.
    near_count: usize,
}

impl StereoColumns {
    const EMPTY: Self = Self {
        ok: [false; IMG_W],
        count: 0,
        near: [false; IMG_W],
        near_count: 0,
    };
}

/// The frame's flow horizon and the rotation over it ([`EdgeFs::flow_horizon`]).
#[derive(Clone, Copy)]
struct FlowHorizon {
    /// Frames back to the frame matched against.
    n: usize,
    /// Image motion of the yaw change over the horizon, px.
    rot_px: f32,
    /// `rot_px` rounded: the centre of the flow search, px.
    offset: i32,
    /// Time span of the horizon, s.
    dt_s: f32,
    /// Derotation uncertainty from a stale attitude sample, px.
    derot_err_px: f32,
}

/// Counts of the flow stage ([`EdgeFs::flow_stage`]).
struct FlowCounts {
    /// Points `(x, Z·u, weight)` written for the fit.
    points: usize,
    /// Textured columns whose best match was at an end of the search.
    edge_hits: usize,
    /// Columns with enough texture for a flow search.
    textured: usize,
    /// Guided columns whose best match lay outside the predicted window.
    prior_misses: usize,
}

/// The frame's robust line fit `Z·u = a·x + b` ([`EdgeFs::fit_stage`]).
struct FrameLine {
    fit: LineFit,
    /// Slope, m/s.
    a: f32,
    /// Value at the image centre, m·px/s.
    b: f32,
    /// Robust residual scale, m/s.
    rms_mps: f32,
    /// Sum of the depths of the columns it used (in column order), m.
    depth_sum_m: f32,
}

/// Brightness flags of a frame from the mean intensity of its left image.
#[inline(always)]
fn brightness_flags(mean: u8) -> EstimateFlags {
    if mean < TOO_DARK_MEAN {
        EstimateFlags::TOO_DARK
    } else if mean > TOO_BRIGHT_MEAN {
        EstimateFlags::TOO_BRIGHT
    } else {
        EstimateFlags::NONE
    }
}

/// Quality 0..=255 of a fit over `np` columns with robust residual scale `rms_mps`.
#[inline(always)]
fn quality(np: usize, rms_mps: f32) -> u8 {
    let cover = (np as f32 / FULL_QUALITY_COLUMNS).min(1.0);
    (FULL_SCALE * cover * libm::expf(-rms_mps / QUALITY_RMS_SCALE_MPS)) as u8
}

/// One column of the stereo stage ([`EdgeFs::stereo_stage`]): its disparity into the
/// diagnostics; a textured column whose best match is at the end of the search is near; a
/// usable one (inside the search, above the smallest disparity, textured, not noise) with a
/// peak ratio of at least `min_stereo_confidence` gets its depth and confidence and is counted.
/// Returns whether the column has a confident depth.
#[inline(always)]
fn stereo_column(
    p: &EdgeFsParams,
    f: f32,
    noise: &NoiseModel,
    diag: &mut Diagnostics,
    stereo: &mut StereoColumns,
    c: usize,
    m: RowMatch<'_>,
) -> bool {
    let ds = usize::from(p.stereo_range);
    let texture = &noise.texture;
    let disp = m.best as f32 + m.subpixel();
    diag.disparity_px[c] = disp;
    if m.best >= ds && texture[c] >= p.min_texture {
        // Textured, best match at the end of the search: nearer than the range.
        stereo.near[c] = true;
        stereo.near_count += 1;
        return false;
    }
    // The peak ratio (a scan of all candidates) only where the rest holds.
    let usable = m.best > 0
        && m.best < ds
        && disp >= p.min_disparity_px
        && texture[c] >= p.min_texture
        && noise.not_noise(c);
    if !usable {
        return false;
    }
    let confidence = m.confidence();
    if confidence >= p.min_stereo_confidence {
        diag.depth_m[c] = f * p.baseline_m / disp;
        diag.confidence[c] = fmin(confidence, MAX_DIAG_CONFIDENCE);
        stereo.ok[c] = true;
        stereo.count += 1;
        return true;
    }
    false
}

/// [`EdgeFs::stereo_stage`] with the left-right check ([`stereo_row_checked`]) of the
/// histograms `other` (left) and `cur` (right): the columns that fail it lose their depth and
/// confidence again. Its per-column stage is [`stereo_column`], the same as the closure of
/// [`EdgeFs::stereo_stage`] (`the_left_right_check_keeps_a_wall_and_changes_nothing_else`).
/// Cold, not inlined and handed only what it needs: the frame without the check then pays about
/// 300 instructions for the branch.
#[cold]
#[inline(never)]
fn stereo_stage_checked(
    p: &EdgeFsParams,
    other: &EdgeHistogram,
    cur: &EdgeHistogram,
    diag: &mut Diagnostics,
    noise: &NoiseModel,
) -> StereoColumns {
    let (w, s, f) = (p.half_window as usize, p.stereo_shift_px, p.focal_px());
    let mut stereo = StereoColumns::EMPTY;
    let ds = usize::from(p.stereo_range);
    // Columns that fail the check, dropped once the search is done.
    let mut failed = [0u8; IMG_W];
    let mut n_failed = 0;
    let mut keep = [[0u32; 2]; LR_KEEP_PAIRS];
    stereo_row_checked(
        other,
        cur,
        ds,
        s,
        w,
        &mut keep,
        |c, m| stereo_column(p, f, noise, diag, &mut stereo, c, m),
        |c| {
            if let Some(x) = failed.get_mut(n_failed) {
                *x = c as u8;
                n_failed += 1;
            }
        },
    );
    for &c in failed.get(..n_failed).unwrap_or(&[]) {
        let c = usize::from(c);
        if let (Some(ok), Some(z), Some(q)) = (
            stereo.ok.get_mut(c),
            diag.depth_m.get_mut(c),
            diag.confidence.get_mut(c),
        ) {
            *ok = false;
            *z = 0.0;
            *q = 0.0;
            stereo.count -= 1;
        }
    }
    diag.lr_dropped = n_failed as u8;
    stereo
}

impl EdgeFs {
    /// The frame's own estimate into `out` (no temporal filter), and the standard errors of its
    /// forward, sideways and vertical velocity (m/s); `Err` with the flag that stopped the fit
    /// when nothing was fitted (the caller inserts it into `out`).
    pub(super) fn fit_default(
        &mut self,
        frame: &[u8; STEREO_FRAME_BYTES],
        has_gyro: bool,
        out: &mut EdgeFsOutput,
    ) -> Result<[f32; 3], EstimateFlags> {
        if !has_gyro {
            out.flags.insert(EstimateFlags::NO_GYRO);
        }
        let mean = self.compute_histograms(frame);
        out.flags.insert(brightness_flags(mean));
        let noise = self.noise_model(frame);
        let stereo = self.stereo_stage(&noise);
        self.obstacle_stage(&stereo, out);
        self.coverage_stage(&noise, &stereo, out);
        let horizon = self.flow_horizon()?;
        out.flags.insert(self.derotation_flags(&horizon));
        let mut pts = [(0.0f32, 0.0f32, 0.0f32); IMG_W];
        let mut samples = FlowSamples::EMPTY;
        let flow = self.flow_stage(&noise, &stereo, &horizon, &mut pts, &mut samples);
        out.divergence = samples.divergence();
        self.adapt_horizon(&flow);
        out.flags.insert(self.history_flags(horizon.n));
        let pts = pts.get_mut(..flow.points).unwrap_or(&mut []);
        let line = self.fit_stage(pts)?;
        self.velocity_stage(pts, &line, out)?;
        let median_len = self.output_median(out);
        out.quality = quality(pts.len(), line.rms_mps);
        let sigma = self.standard_errors(pts, &line, &horizon);
        Ok(self.coupled_stage(pts, &line, &horizon, median_len, sigma, out))
    }

    /// The noise model: each column window's edge energy and shape, and the levels above which
    /// a window is not noise ([`EdgeFsParams::noise_texture_ratio`],
    /// [`EdgeFsParams::noise_structure_ratio`]; records the noise's window sum in the
    /// diagnostics).
    ///
    /// [`EdgeFsParams::noise_texture_ratio`]: super::EdgeFsParams::noise_texture_ratio
    /// [`EdgeFsParams::noise_structure_ratio`]: super::EdgeFsParams::noise_structure_ratio
    #[inline(always)]
    fn noise_model(&mut self, frame: &[u8; STEREO_FRAME_BYTES]) -> NoiseModel {
        let p = self.params;
        let w = p.half_window as usize;
        // A window's edge sum from noise alone: (2w+1) bins of IMG_H absolute differences of
        // two pixels, each 2σ/√π = 1.128σ on average.
        let (noise_window, noise_step) = if p.noise_texture_ratio > 0.0 {
            let sigma = pixel_noise_dn(frame);
            (
                sigma * NOISE_DIFF_PER_SIGMA * (IMG_H * (2 * w + 1)) as f32,
                sigma * NOISE_STEP_PER_SIGMA,
            )
        } else {
            (0.0, 0.0)
        };
        self.diag.noise_window = noise_window;
        let cur = &self.ring[self.idx(0)].hist;
        let mut texture = [0u32; IMG_W];
        window_sums(cur, w, &mut texture);
        // A column window is not noise when its edge sum stands out of the noise's, or when
        // its histogram has more shape than noise gives it: a fine, faint texture (wood grain)
        // sums little more than noise, but the matcher compares shapes, and its shape matches.
        // Noise's depths are not depth, nor its flow motion.
        let clear_of_noise = (p.noise_texture_ratio * noise_window) as u32;
        let mut shape = [0u32; IMG_W];
        let shaped = if p.noise_texture_ratio > 0.0 && p.noise_structure_ratio > 0.0 {
            window_sums(&histogram_steps(cur), w, &mut shape);
            (p.noise_structure_ratio * noise_step * (2 * w + 1) as f32) as u32
        } else {
            u32::MAX
        };
        NoiseModel {
            texture,
            shape,
            clear_of_noise,
            shaped,
        }
    }

    /// Stereo with sub-pixel refinement and confidence masking: disparity, depth and confidence
    /// per column into the diagnostics, and which columns have a confident depth or are nearer
    /// than the stereo range; with [`EdgeFsParams::lr_check`], checked both ways
    /// ([`stereo_stage_checked`]).
    #[inline(always)]
    fn stereo_stage(&mut self, noise: &NoiseModel) -> StereoColumns {
        if self.params.lr_check {
            let cur = &self.ring[self.idx(0)].hist;
            return stereo_stage_checked(&self.params, &self.other, cur, &mut self.diag, noise);
        }
        let p = self.params;
        let (w, s, f) = (p.half_window as usize, p.stereo_shift_px, p.focal_px());
        let mut stereo = StereoColumns::EMPTY;
        let ds = usize::from(p.stereo_range);
        let cur = &self.ring[self.idx(0)].hist;
        let diag = &mut self.diag;
        stereo_row(&self.other, cur, ds, s, w, |c, m| {
            stereo_column(&p, f, noise, diag, &mut stereo, c, m);
        });
        stereo
    }

    /// The nearest obstacle: from runs of confident depths, or at the minimum range when a run
    /// of columns is nearer than the stereo range; and the count of such near columns.
    #[inline(always)]
    fn obstacle_stage(&self, stereo: &StereoColumns, out: &mut EdgeFsOutput) {
        let p = self.params;
        let f = p.focal_px();
        out.obstacle_m = self.nearest_obstacle();
        let run = usize::from(p.min_near_run);
        if run > 0 && longest_run(&stereo.near) >= run {
            // Something nearer than the stereo range fills part of the view.
            let min_range_m = f * p.baseline_m / f32::from(p.stereo_range.max(1));
            out.obstacle_m = Some(out.obstacle_m.map_or(min_range_m, |d| d.min(min_range_m)));
        }
        out.near_columns = stereo.near_count.min(usize::from(u8::MAX)) as u8;
    }

    /// How much of the view is known: the depth coverage, and the flags of a view with too
    /// little texture or too few confident depths.
    #[inline(always)]
    fn coverage_stage(&self, noise: &NoiseModel, stereo: &StereoColumns, out: &mut EdgeFsOutput) {
        let p = self.params;
        let w = p.half_window as usize;
        let searchable = IMG_W.saturating_sub(2 * w);
        out.depth_coverage = coverage_u8(stereo.count, searchable);
        // Over disjoint windows: the texture, and the windows that are not noise (a plain
        // room's lone corner is not a view to measure velocity on).
        let (mut total_texture, mut textured_windows) = (0u32, 0usize);
        for (c, &t) in noise.texture.iter().enumerate().step_by(2 * w + 1) {
            total_texture = total_texture.saturating_add(t);
            textured_windows += usize::from(noise.not_noise(c));
        }
        if total_texture < p.min_texture.saturating_mul(FRAME_TEXTURE_WINDOWS)
            || textured_windows < MIN_TEXTURED_WINDOWS
        {
            out.flags.insert(EstimateFlags::NO_TEXTURE);
        }
        if stereo.count < usize::from(p.min_fit_columns).max(MIN_LINE_POINTS)
            || (stereo.count as f32) < p.min_depth_coverage * searchable as f32
        {
            out.flags.insert(EstimateFlags::NO_STEREO_MATCH);
        }
    }

    /// The flow horizon: the frame `n` back to match against (the adaptive cap, shortened to
    /// the time span `horizon_s`, then until the rotation fits the search), the rotation over it
    /// and its time span. `Err` with the flag when the flow cannot be measured.
    #[inline(always)]
    fn flow_horizon(&mut self) -> Result<FlowHorizon, EstimateFlags> {
        let p = self.params;
        let h = p.max_horizon as usize;
        let f = p.focal_px();
        // Flow against the frame `n` back, searched around the predicted rotation.
        let avail = (self.frames as usize).saturating_sub(1);
        let mut n = (self.horizon as usize).clamp(1, h).min(avail);
        if p.horizon_s > 0.0 {
            // Time-based horizon: the fewest frames spanning `horizon_s`, within the cap.
            let now = self.ring[self.idx(0)].capture;
            if let Some(k) = (1..=n)
                .find(|&k| now.since(self.ring[self.idx(k)].capture).as_secs_f32() >= p.horizon_s)
            {
                n = k;
            }
        }
        if n == 0 {
            return Err(EstimateFlags::HISTORY_FILLING);
        }
        // Rotation over the horizon from the attitude (the scene moves left when the yaw
        // grows); shorten the horizon until it fits the search. The yaw change is wrapped:
        // a heading crossing +-pi is a small turn, not a full one.
        let cur = &self.ring[self.idx(0)];
        let rotation = |older: &Slot| {
            if cur.has_yaw && older.has_yaw {
                -wrap_pi(cur.yaw_rad - older.yaw_rad) * f
            } else {
                0.0
            }
        };
        let mut rot_px = rotation(&self.ring[self.idx(n)]);
        let too_fast = |r: f32| r.is_nan() || r.abs() > p.max_rotation_px;
        while n > 1 && too_fast(rot_px) {
            n -= 1;
            rot_px = rotation(&self.ring[self.idx(n)]);
        }
        self.diag.horizon = n as u8;
        if too_fast(rot_px) {
            // Rotating faster than the search can follow even over one frame.
            return Err(EstimateFlags::NO_FLOW_MATCH);
        }
        let older = &self.ring[self.idx(n)];
        let offset = libm::roundf(rot_px) as i32;
        let dt_s = cur.capture.since(older.capture).as_secs_f32();
        if dt_s.is_nan() || dt_s <= MIN_FLOW_SPAN_S {
            return Err(EstimateFlags::NO_FLOW_MATCH);
        }
        // Derotation uncertainty from a stale attitude sample while the yaw rate changes.
        let derot_err_px = (cur.yaw_rate - older.yaw_rate).abs() * p.gyro_age_s * f;
        Ok(FlowHorizon {
            n,
            rot_px,
            offset,
            dt_s,
            derot_err_px,
        })
    }

    /// [`EstimateFlags::POOR_FIT`] when the derotation is more uncertain than tolerated.
    #[inline(always)]
    fn derotation_flags(&self, horizon: &FlowHorizon) -> EstimateFlags {
        if horizon.derot_err_px > self.params.max_derotation_error_px {
            EstimateFlags::POOR_FIT
        } else {
            EstimateFlags::NONE
        }
    }

    /// Flow of the textured columns against the frame `horizon.n` back, searched around the
    /// predicted rotation (and, for columns with a depth, guided by the temporal filter's
    /// velocity), derotated, per second: into the diagnostics, and the points `(x, Z·u, weight)`
    /// of the columns with a confident depth and flow into `pts`.
    #[inline(always)]
    fn flow_stage(
        &mut self,
        noise: &NoiseModel,
        stereo: &StereoColumns,
        horizon: &FlowHorizon,
        pts: &mut [(f32, f32, f32); IMG_W],
        samples: &mut FlowSamples,
    ) -> FlowCounts {
        let p = self.params;
        let (w, d) = (p.half_window as usize, p.search_range as usize);
        let f = p.focal_px();
        let FlowHorizon {
            n,
            rot_px,
            offset,
            dt_s,
            ..
        } = *horizon;
        let mut counts = FlowCounts {
            points: 0,
            edge_hits: 0,
            textured: 0,
            prior_misses: 0,
        };
        let prior = self.flow_prior();
        {
            let (cur, older) = (&self.ring[self.idx(0)], &self.ring[self.idx(n)]);
            let (cur_h, old_h) = (&cur.hist, &older.hist);
            let diag = &mut self.diag;
            // `flow_row`: the first minimum is found while the costs are updated (same
            // matches as `best_match` of `column_costs`' costs, bit for bit); the parabola
            // only for textured columns, the peak ratio only where the stereo depth is valid.
            flow_row(old_h, cur_h, d, offset, w, |c, m| {
                if noise.texture[c] < p.min_texture {
                    return;
                }
                counts.textured += 1;
                let mut base = 0;
                let mut m = m;
                if let (Some(pr), true) = (prior, stereo.ok[c]) {
                    // The motion the filter's velocity predicts here, as a candidate index.
                    let (x, z) = (c as f32 - CENTRE_COLUMN, diag.depth_m[c]);
                    let u = (pr.forward_mps * x - f * pr.sideways_mps) / z;
                    let k = rot_px + u * dt_s - offset as f32 + d as f32;
                    let spread = (x.abs() * pr.forward_sigma + f * pr.sideways_sigma) / z;
                    let r = fmin(
                        p.prior_window_px + spread * dt_s,
                        PRIOR_WINDOW_CAP * p.prior_window_px,
                    );
                    let (lo, hi) = (libm::floorf(k - r), libm::ceilf(k + r));
                    if lo > 0.0 || hi < (2 * d) as f32 {
                        let lo = lo.clamp(0.0, (2 * d) as f32) as usize;
                        let hi = hi.clamp(0.0, (2 * d) as f32) as usize;
                        let Some(w) = m.within(lo, hi) else {
                            counts.prior_misses += 1;
                            return;
                        };
                        let at_edge = |i: usize, end: usize| i == end && end != 0 && end != 2 * d;
                        if at_edge(lo + w.best, lo) || at_edge(lo + w.best, hi) {
                            // The best match in the window lies beyond it: not what was
                            // predicted.
                            counts.prior_misses += 1;
                            return;
                        }
                        (base, m) = (lo, w);
                    }
                }
                let best = base + m.best;
                if best == 0 || best == 2 * d {
                    counts.edge_hits += 1;
                    return;
                }
                let motion = offset as f32 + best as f32 - d as f32 + m.subpixel();
                let u = (motion - rot_px) / dt_s;
                diag.flow_pxps[c] = u;
                samples.push(c as f32 - CENTRE_COLUMN, u);
                if stereo.ok[c] && m.confidence() >= p.min_flow_confidence {
                    let z = diag.depth_m[c];
                    if let Some(pt) = pts.get_mut(counts.points) {
                        let wgt = if p.depth_weight_exp == 0.0 {
                            1.0
                        } else {
                            libm::powf(z.max(MIN_WEIGHT_DEPTH_M), -p.depth_weight_exp)
                        };
                        *pt = (c as f32 - CENTRE_COLUMN, z * u, wgt);
                        counts.points += 1;
                    }
                }
            });
        }
        // Over one in PRIOR_DOUBT_SHARE columns disagreeing with the filter: it may have lost
        // the motion, so the next frame searches the whole range (a real change then restarts
        // the filter).
        self.prior_doubted =
            prior.is_some() && counts.prior_misses * PRIOR_DOUBT_SHARE > counts.textured;
        self.diag.guided = prior.is_some();
        self.diag.prior_misses = counts.prior_misses.min(usize::from(u8::MAX)) as u8;
        counts
    }

    /// Adaptive horizon: shorten when many searches hit the range end
    /// ([`HORIZON_SHORTEN_SHARE`]), lengthen when hardly any do ([`HORIZON_LENGTHEN_SHARE`]).
    #[inline(always)]
    fn adapt_horizon(&mut self, flow: &FlowCounts) {
        let h = self.params.max_horizon as usize;
        if flow.edge_hits * HORIZON_SHORTEN_SHARE > flow.textured && self.horizon > 1 {
            self.horizon -= 1;
        } else if flow.edge_hits * HORIZON_LENGTHEN_SHARE <= flow.textured
            && (self.horizon as usize) < h
        {
            self.horizon += 1;
        }
    }

    /// [`EstimateFlags::HISTORY_FILLING`] while the history is too short for the longest
    /// horizon and this frame's horizon `n` is shorter.
    #[inline(always)]
    fn history_flags(&self, n: usize) -> EstimateFlags {
        let h = self.params.max_horizon as usize;
        if n < h && (self.frames as usize) <= h {
            EstimateFlags::HISTORY_FILLING
        } else {
            EstimateFlags::NONE
        }
    }

    /// The robust line fit of the points `(x, Z·u, weight)`, the columns it used (into the
    /// diagnostics) and its robust residual scale. `Err` with the flag when there is no fit.
    #[inline(always)]
    fn fit_stage(&mut self, pts: &mut [(f32, f32, f32)]) -> Result<FrameLine, EstimateFlags> {
        let p = self.params;
        let f = p.focal_px();
        let np = pts.len();
        let (mut prior, mut scratch) = ([0.0f32; IMG_W], [0.0f32; IMG_W]);
        let fit = if np >= usize::from(p.min_fit_columns).max(MIN_LINE_POINTS) {
            robust_line_fit(pts, &mut prior, &mut scratch, ROBUST_FIT_ROUNDS, p.huber_k)
        } else {
            None
        };
        let Some(fit) = fit else {
            return Err(EstimateFlags::NO_FLOW_MATCH);
        };
        let (a, b) = (fit.slope as f32, fit.intercept as f32);
        // Robust residual scale (1.4826 · median |residual|), converted to m/s.
        let (mut m, mut depth_sum_m) = (0, 0.0f32);
        for pt in pts.iter() {
            if let Some(r) = scratch.get_mut(m) {
                *r = (pt.1 - (a * pt.0 + b)).abs();
                m += 1;
            }
            // `pt.0` is `c - CENTRE_COLUMN` for an integer column `c`: exactly `c` again, no
            // rounding.
            let col = pt.0 + CENTRE_COLUMN;
            if (0.0..IMG_W as f32).contains(&col) {
                let c = col as usize;
                if let (Some(u), Some(z)) = (self.diag.used.get_mut(c), self.diag.depth_m.get(c)) {
                    *u = true;
                    depth_sum_m += z;
                }
            }
        }
        let res = scratch.get_mut(..m).unwrap_or(&mut []);
        let rms_mps = MAD_TO_SIGMA * median(res) / f;
        Ok(FrameLine {
            fit,
            a,
            b,
            rms_mps,
            depth_sum_m,
        })
    }

    /// The velocity of the fit into `out`, flagged [`EstimateFlags::POOR_FIT`] when its
    /// residual is too large or its columns too narrow a patch. `Err` with the flag when it is
    /// not finite.
    #[inline(always)]
    fn velocity_stage(
        &mut self,
        pts: &[(f32, f32, f32)],
        line: &FrameLine,
        out: &mut EdgeFsOutput,
    ) -> Result<(), EstimateFlags> {
        let p = self.params;
        let f = p.focal_px();
        self.diag.fit_columns = pts.len() as u8;
        out.forward_mps = line.a;
        out.sideways_mps = -line.b / f;
        if !(out.forward_mps.is_finite() && out.sideways_mps.is_finite()) {
            out.forward_mps = 0.0;
            out.sideways_mps = 0.0;
            return Err(EstimateFlags::POOR_FIT);
        }
        if line.rms_mps > p.max_fit_rms_mps {
            out.flags.insert(EstimateFlags::POOR_FIT);
        }
        let (lo, hi) = pts.iter().fold((f32::MAX, f32::MIN), |(lo, hi), pt| {
            (fmin(lo, pt.0), fmax(hi, pt.0))
        });
        if hi - lo < p.min_fit_spread_px {
            out.flags.insert(EstimateFlags::POOR_FIT);
        }
        Ok(())
    }

    /// The median over the last fitted velocities
    /// ([`EdgeFsParams::output_median`](super::EdgeFsParams::output_median)) into `out`;
    /// returns the median's length (1: off).
    #[inline(always)]
    fn output_median(&mut self, out: &mut EdgeFsOutput) -> usize {
        let k = usize::from(self.params.output_median).clamp(1, MEDIAN_MAX);
        if k > 1 {
            self.recent.rotate_right(1);
            self.recent[0] = (out.forward_mps, out.sideways_mps);
            self.recent_len = (self.recent_len + 1).min(k);
            let m = self.recent_len;
            let (mut fw, mut sw) = ([0.0f32; MEDIAN_MAX], [0.0f32; MEDIAN_MAX]);
            for (j, &(a, b)) in self.recent.iter().take(m).enumerate() {
                fw[j] = a;
                sw[j] = b;
            }
            out.forward_mps = median(&mut fw[..m]);
            out.sideways_mps = median(&mut sw[..m]);
        }
        k
    }

    /// Standard errors of the forward, sideways and vertical velocity (m/s) of the columns'
    /// fit; the vertical one is infinite (no vertical fit yet).
    #[inline(always)]
    fn standard_errors(
        &self,
        pts: &[(f32, f32, f32)],
        line: &FrameLine,
        horizon: &FlowHorizon,
    ) -> [f32; 3] {
        let f = self.params.focal_px();
        let (rms_mps, dt_s) = (line.rms_mps, horizon.dt_s);
        // Standard errors of the slope and of the centre value (x is centred on the image).
        let (mut sx, mut sxx) = (0.0f32, 0.0f32);
        for pt in pts.iter() {
            sx += pt.0;
            sxx += pt.0 * pt.0;
        }
        let n = pts.len() as f32;
        let spread = (sxx - sx * sx / n).max(MIN_SLOPE_SPREAD);
        let sigma_res = rms_mps * f;
        // A derotation error of `e` px over `dt_s` biases every column's flow by `e/dt_s`,
        // i.e. the sideways velocity by `mean(Z)·e/(dt_s·f)`.
        let rot_sigma = line.depth_sum_m / n * horizon.derot_err_px / (dt_s * f);
        let side = rms_mps / libm::sqrtf(n);
        [
            sigma_res / libm::sqrtf(spread),
            libm::sqrtf(side * side + rot_sigma * rot_sigma),
            f32::INFINITY,
        ]
    }

    /// The coupled three-axis fit ([`EdgeFs::coupled_fit`]): its R² and the vertical
    /// velocity's flags into `out`, and, when its vertical velocity is valid and no output
    /// median runs, its velocities into `out` and its standard errors into the returned
    /// `sigma`.
    #[inline(always)]
    fn coupled_stage(
        &mut self,
        pts: &[(f32, f32, f32)],
        line: &FrameLine,
        horizon: &FlowHorizon,
        median_len: usize,
        mut sigma: [f32; 3],
        out: &mut EdgeFsOutput,
    ) -> [f32; 3] {
        let coupled = self.coupled_fit(pts, &line.fit, sigma[0], horizon.dt_s);
        out.fit_r2 = (coupled.r2.clamp(0.0, 1.0) * FULL_SCALE) as u8;
        out.up_flags = out.flags | coupled.up_flags;
        if coupled.up_flags.is_valid() && median_len == 1 {
            out.forward_mps = coupled.forward_mps;
            out.sideways_mps = coupled.sideways_mps;
            out.up_mps = coupled.up_mps;
            sigma[0] = coupled.forward_sigma;
            sigma[2] = coupled.up_sigma;
        }
        sigma
    }
}
