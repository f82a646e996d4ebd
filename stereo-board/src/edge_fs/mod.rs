//! Edge-FS: velocity and nearest-obstacle estimation from edge histograms of a 128x96 stereo
//! pair (McGuire et al., "Efficient optical flow and stereo vision for velocity estimation and
//! obstacle avoidance on an autonomous pocket drone").
//!
//! Steps of one frame ([`EdgeFs::process`]): horizontal gradient summed per column
//! ([`edge_histograms`]); per-column stereo disparity by SAD block matching with the calibrated
//! stereo shift, all columns at once ([`stereo_row`]; [`stereo_match`] is the same for one
//! column); per-column temporal flow against a history of histograms with an adaptive time
//! horizon ([`flow_row`], one column: [`flow_match`]); derotation by the yaw change; depth
//! `Z = f·b/disparity` with `f = 128 / FOV_x`; depth-scaled flow `Z·u` per column; a line fit
//! `Z·u = a·x + b` ([`line_fit`], [`robust_line_fit`]) whose slope is the forward velocity and
//! whose value at the image centre divided by `f` is (minus) the sideways velocity; the nearest
//! obstacle from runs of confident stereo columns.
//!
//! Two modes ([`Mode`]):
//! * [`Mode::Paper`]: the paper-era MATLAB pipeline exactly (first-minimum ties, integer
//!   matches, post-hoc derotation with the n-frame yaw difference / n, consecutive-frame rate,
//!   zero histories for the first H+1 frames, `polyfit` degenerate cases). With
//!   [`EdgeFsParams::paper`] and the data set's protocol it reproduces the published per-take
//!   numbers to 4 decimals (see `sim-host eval`). Uses f64 for the fit (libm-free, `no_std`).
//! * [`Mode::Default`]: our estimator. Sub-pixel (parabolic) stereo and flow; columns masked by
//!   texture and peak-ratio confidence; the flow search is centred on the rotation predicted
//!   from the gyro/attitude yaw change, which is then removed exactly (sub-pixel); the horizon
//!   is shortened while the rotation exceeds `max_rotation_px`, and flow is not measured (the
//!   frame is flagged) when even one frame rotates more; frames whose derotation is uncertain
//!   (yaw rate changing while the attitude sample is stale) are flagged; flow per second from
//!   the true capture times across the horizon; robust (Huber, MAD scale) fit; quality and
//!   validity flags; a temporal filter ([`AxisFilter`]: constant-velocity Kalman per axis,
//!   measurement noise from the fit's residual scale, innovation gating that rejects and flags
//!   outliers). The default mode also says what it does not know: the share of the view with
//!   a confident depth ([`EdgeFsOutput::depth_coverage`]; below
//!   [`EdgeFsParams::min_depth_coverage`] the velocity is invalid), a fit over too narrow a
//!   patch of columns is flagged, and textured columns whose disparity search ran out of range
//!   are counted ([`EdgeFsOutput::near_columns`]): a run of them is an obstacle at the minimum
//!   range, never "nothing there". Optionally ([`EdgeFsParams::lr_check`], off by default)
//!   stereo is checked both ways ([`stereo_row_checked`]): a column whose match, searched
//!   back from the left image, does not find its disparity again within ±1 px (occluded or
//!   ambiguous) is dropped before depth, obstacle and fit use it. Flow is
//!   tracked in the right image, the one the disparity is indexed by, so a column's depth and
//!   flow belong to the same scene point (the paper-era code mixes left-image flow with
//!   right-indexed depth). Integer SAD, f32 elsewhere (no f64 in the hot path).
//!
//!   Vertical flow ([`EdgeFsParams::vertical_search_px`]): row edge histograms of the frame
//!   ([`row_histogram`]), flow per row against the same history and horizon, searched around
//!   the pitch rotation and derotated by it ([`flow_row_within`]), and a coupled fit of the
//!   three axes: the rows' depth-scaled flow `Z̄·v = F·y + f·U` shares the forward velocity
//!   `F` with the columns' `Z·u = F·x - f·S`, so the forward velocity comes from the
//!   divergence of both axes, with the fit's R² ([`EdgeFsOutput::fit_r2`]) and the vertical
//!   velocity's own validity ([`EdgeFsOutput::up_flags`]).
//!
//!   Time to contact ([`EdgeFsOutput::divergence`]): the slope of the derotated flow against
//!   the column over every column with a flow match, with or without a stereo depth, so it
//!   needs no range (a surface nearer than the stereo search, a plain object's textured edges).
//!
//! Conventions: column `x` is 0-based from the left of the image (in docs "1-based" is said
//! where the MATLAB index is meant). Image motion is positive towards larger `x`. The yaw in
//! [`protocol::GyroAttitude::attitude_rad`]`[2]` is the body-frame yaw (z down: positive turns
//! right), so a yaw increase moves the scene towards smaller `x`; `attitude_rad[1]` is the
//! pitch (positive nose up), and a pitch increase moves the scene down the image (towards
//! larger rows). Outputs follow
//! [`protocol::Estimate`]: forward positive towards the scene, sideways positive to the right.
//!
//! How the default parameters were chosen: see [`EdgeFsParams::default_config`].

mod default_mode;
mod divergence;
mod fit;
mod histogram;
mod matching;
mod temporal;

pub use fit::{line_fit, robust_line_fit, weighted_line_fit, LineFit};
pub use histogram::{
    edge_histograms, edge_histograms_and_mean, mean_intensity, pixel_noise_dn, row_histogram,
    EdgeHistogram,
};
pub use matching::{
    best_match, column_costs, flow_match, flow_row, flow_row_within, match_column, parabola, sad,
    stereo_match, stereo_row, stereo_row_checked, ColumnMatch, RowMatch, LR_KEEP_PAIRS,
};
pub use temporal::{AxisFilter, Update};

use protocol::{
    ConfigError, Divergence, EdgeFsConfig, EstimateFlags, FrameFit, GyroAttitude,
    STEREO_FRAME_BYTES,
};
use timebase::Instant;

/// Image width, px.
pub const IMG_W: usize = 128;
/// Image height, px.
pub const IMG_H: usize = 96;
/// The camera's horizontal field of view, rad (57.4 deg, the paper's hardware value).
pub const CAMERA_HFOV_RAD: f32 = 57.4 * core::f32::consts::PI / 180.0;
/// The camera's calibrated focal length, px per rad of view angle: `IMG_W / CAMERA_HFOV_RAD`
/// (127.8 px). Edge-FS's default configuration converts disparities and flow with it, and the
/// simulator's pinhole renderer uses it as its focal length, so both agree on the geometry.
pub const CAMERA_FOCAL_PX: f32 = IMG_W as f32 / CAMERA_HFOV_RAD;
/// History ring length: the longest horizon plus the current frame.
const RING: usize = EdgeFsConfig::MAX_HORIZON as usize + 1;
/// Longest output median filter.
const MEDIAN_MAX: usize = 5;
/// Largest rotation the flow search is centred on, px.
const MAX_ROTATION_PX: f32 = 40.0;
/// Largest vertical flow search range, px.
pub const MAX_VERTICAL_SEARCH: u8 = 20;
/// Largest stereo shift (either way) the parameter check keeps, px.
const MAX_STEREO_SHIFT_PX: i32 = 20;
/// The horizontal field of view the parameter check accepts lies strictly between these, rad.
const FOV_X_RANGE_RAD: (f32, f32) = (0.1, 3.0);
/// The field of view the parameter check puts in place of one outside that range, rad.
const FALLBACK_FOV_X_RAD: f32 = 1.0;
/// The largest baseline the parameter check accepts, m (exclusive).
const MAX_BASELINE_M: f32 = 10.0;
/// The camera board's stereo baseline, m: the defaults' and the parameter check's fallback.
const BOARD_BASELINE_M: f32 = 0.06;
/// Microseconds per second: the paper mode's frame rate from its capture interval.
const US_PER_S: f64 = 1e6;
/// The shortest frame interval the velocity filter and the flow prior trust, s: a shorter one
/// is a clock glitch, not a frame.
const MIN_FRAME_GAP_S: f32 = 1e-4;
/// The longest frame interval they trust, s: after a longer gap the track is lost.
const MAX_FRAME_GAP_S: f32 = 1.0;
/// Paper mode: a global translation above this (px per frame) shortens the flow horizon.
const HORIZON_SHRINK_PX: f64 = 2.0;
/// Paper mode: a global translation below this (px per frame) lengthens the flow horizon.
const HORIZON_GROW_PX: f64 = 0.01;
/// Paper mode: the image's centre column in the fit's 1-based column numbers (`IMG_W / 2`),
/// where the translation and the sideways velocity are read off the flow line.
const CENTRE_COLUMN: f64 = 64.0;
/// Paper mode: the fit's R² in [0, 1] to the estimate's 8-bit quality.
const QUALITY_FULL_SCALE: f32 = 255.0;
/// Floor of the coupled fit's weight sum, so that no weight does not divide by zero.
const MIN_WEIGHT_SUM: f32 = 1e-6;
/// Floor of the coupled fit's slope variance, so that a perfect fit does not divide by zero.
const MIN_SLOPE_VARIANCE: f32 = 1e-12;
/// Nearest obstacle: the fewest adjacent columns of valid depth that make an obstacle.
const OBSTACLE_RUN_COLUMNS: usize = 5;
/// Nearest obstacle: neighbouring columns belong to one obstacle while their depths differ by
/// less than this fraction of the larger.
const OBSTACLE_DEPTH_STEP: f32 = 0.3;

/// Which Edge-FS variant runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Exact reproduction of the paper-era MATLAB reference (see the module docs).
    Paper,
    /// Our best estimator (see the module docs).
    Default,
}

/// Edge-FS parameters. Build with [`EdgeFsParams::paper`] or [`EdgeFsParams::default_config`]
/// and adjust; out-of-range values are clamped by [`EdgeFs::new`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeFsParams {
    /// Algorithm variant.
    pub mode: Mode,
    /// SAD half-window W, px (window 2W+1). 1..=12.
    pub half_window: u8,
    /// Search range D, px: flow -D..=D (around the predicted rotation in default mode),
    /// disparity 0..=D. 1..=20.
    pub search_range: u8,
    /// Longest flow horizon H, frames. 1..=9.
    pub max_horizon: u8,
    /// Stereo calibration shift, px, in the MATLAB / protocol convention: at infinity a feature
    /// sits this much further left in the left image than in the right one, i.e. the true
    /// disparity is `x_left - x_right + stereo_shift_px` (data set: board 1 +5, board 2 -2;
    /// the data set's calibration_data.txt stores the opposite sign). -20..=20.
    pub stereo_shift_px: i32,
    /// Horizontal field of view, rad (focal length `f = 128 / fov_x_rad` px/rad).
    pub fov_x_rad: f32,
    /// Stereo baseline, m.
    pub baseline_m: f32,
    /// Default mode: flow time span, s. The horizon is the fewest frames (up to the adaptive
    /// cap, itself at most `max_horizon`) whose capture times span at least this, so the
    /// estimator behaves alike at 7 Hz and at 25 Hz. 0: always use the adaptive cap.
    pub horizon_s: f32,
    /// Default mode: largest stereo disparity searched, px (the paper mode uses
    /// `search_range`); up to 40 here, and set to `search_range` by a run-time `Config`
    /// ([`EdgeFsParams::apply`]). Closer obstacles than `f·b/stereo_range` get no depth.
    pub stereo_range: u8,
    /// Default mode: smallest sub-pixel disparity used for depth, px.
    pub min_disparity_px: f32,
    /// Default mode: smallest stereo peak ratio (second-best / best SAD) of a used column.
    pub min_stereo_confidence: f32,
    /// Default mode: smallest flow peak ratio of a used column.
    pub min_flow_confidence: f32,
    /// Default mode: smallest edge energy (sum of the window's histogram bins) of a used column.
    pub min_texture: u32,
    /// Default mode: Huber threshold of the robust fit, in MAD-scale units.
    pub huber_k: f32,
    /// Default mode: fit weight of a column is `Z^-depth_weight_exp` (2 = inverse variance of
    /// `Z·u` when the flow error dominates; 0 = unweighted).
    pub depth_weight_exp: f32,
    /// Default mode: fits whose robust residual RMS (converted to m/s) exceeds this are
    /// flagged [`EstimateFlags::POOR_FIT`].
    pub max_fit_rms_mps: f32,
    /// Default mode: fewest columns with both a confident depth and flow for a fit.
    pub min_fit_columns: u8,
    /// Default mode: median filter length over the last fitted velocities (1 = off, up to
    /// 5); it removes single-frame outliers at the cost of about `(len-1)/2` frames of lag.
    /// Off in [`EdgeFsParams::default_config`]: the temporal filter (`filter_*`) rejects
    /// outliers with less lag, and the autopilot applies the paper's median over the last 5
    /// estimates on top. Applied before the temporal filter.
    pub output_median: u8,
    /// Obstacles farther than this are reported as `None`, m.
    pub max_obstacle_m: f32,
    /// Default mode: temporal filter of the velocity, acceleration noise (1σ of the
    /// piecewise-constant acceleration of the constant-velocity Kalman filter per axis,
    /// [`AxisFilter`]), m/s². 0 (or less): no temporal filter, every frame's fit is output.
    pub filter_accel_mps2: f32,
    /// Default mode: innovation gate of the temporal filter, in standard deviations; a fit
    /// outside it is rejected (the prediction is output, flagged
    /// [`EstimateFlags::POOR_FIT`]). 0: no gating.
    pub filter_gate: f32,
    /// Default mode: measurement noise floor of the temporal filter, m/s (1σ), added in
    /// quadrature to the fit's own standard error.
    pub filter_noise_floor_mps: f32,
    /// Default mode: scale of the fit's standard error (from its robust residual scale and
    /// column spread) in the temporal filter's measurement noise.
    pub filter_noise_scale: f32,
    /// Default mode: time constant of the temporal filter's acceleration state, s (it decays
    /// towards 0 between measurements); 0: no acceleration state.
    pub filter_accel_tau_s: f32,
    /// Default mode: largest rotation (yaw change over the flow horizon, from the attitude)
    /// searched around, px. The horizon is shortened until the rotation fits; when even one
    /// frame rotates more, the flow is not measured ([`EstimateFlags::NO_FLOW_MATCH`]).
    /// Up to 40.
    pub max_rotation_px: f32,
    /// Default mode: worst-case age of the attitude sample at the exposure, s. The board uses
    /// the latest gyro/attitude sample, not one taken at the exposure, so when the yaw rate
    /// changes by `Δr` over the horizon the derotation can be off by `|Δr|·age·f` px; that
    /// error enters the temporal filter's noise, and frames where it exceeds
    /// `max_derotation_error_px` are flagged [`EstimateFlags::POOR_FIT`].
    pub gyro_age_s: f32,
    /// Default mode: largest tolerated derotation uncertainty, px (see `gyro_age_s`).
    pub max_derotation_error_px: f32,
    /// Default mode: smallest fraction of the searchable columns with a confident stereo depth
    /// for a valid velocity (0..=1); below it the frame is flagged
    /// [`EstimateFlags::NO_STEREO_MATCH`]: a few matched columns on an otherwise plain view
    /// are not enough to trust a velocity.
    pub min_depth_coverage: f32,
    /// Default mode: the columns used in the velocity fit must span at least this many
    /// pixels, else [`EstimateFlags::POOR_FIT`] (a slope over a narrow patch is unfounded).
    pub min_fit_spread_px: f32,
    /// Default mode: this many adjacent textured columns whose disparity search ran out of
    /// range (nearer than the minimum range) are an obstacle at the minimum range. 0: off.
    /// 12 (not 5): floor tiles seen at a slant give short false runs, and a false obstacle at
    /// the minimum range pushes the drone backwards through the force field.
    pub min_near_run: u8,
    /// Flow search guided by the temporal filter: a column with stereo depth takes the best
    /// match within this many px (plus the prediction's own uncertainty) of the motion the
    /// filter's velocity predicts for it, so a periodic texture (stripes, a bar code) whose
    /// period is near the motion cannot alias to a wrong stripe. 0: off (the whole search).
    pub prior_window_px: f32,
    /// Default mode: a column window is noise unless its edge sum is this many times what the
    /// frame's pixel noise alone gives ([`pixel_noise_dn`]) or its histogram has the shape
    /// [`Self::noise_structure_ratio`] asks. A column of noise gets no depth and no flow, and
    /// a frame is [`EstimateFlags::NO_TEXTURE`] unless at least 3 disjoint windows are not
    /// noise. Sensor noise on a plain wall passes any fixed `min_texture` (a plain room at light
    /// 0.44 sums 3000 to 3500 per window, `min_texture` is 2000) and then yields matches of
    /// noise: velocities near zero, depths anywhere (a fifth of the columns "see" a plain
    /// wall). With the gate such a room gives 3 valid estimates of 100 (63 without), and the
    /// recorded takes keep 98 % of their valid estimates. 0: off.
    pub noise_texture_ratio: f32,
    /// Default mode, with [`Self::noise_texture_ratio`]: a column window is also not noise
    /// when the mean step between its neighbouring histogram bins is this many times the step
    /// noise alone gives. The matcher compares histograms by their shape, not their level: a
    /// faint, fine texture (wood grain at 1.5 times the noise's edge sum) matches well, and
    /// most of its windows have 3.5 to 7 times noise's shape; windows of noise alone reach 2.4.
    /// 0: off.
    pub noise_structure_ratio: f32,
    /// Default mode: vertical flow search range, px (rows move -D..=D around the pitch
    /// rotation over the horizon); 0: no vertical flow (the vertical velocity is flagged
    /// [`EstimateFlags::NO_FLOW_MATCH`] and the fit is the columns' alone). Up to 20.
    /// [`Self::VERTICAL_SEARCH_PX`] turns it on. Off in [`EdgeFsParams::default_config`]: it
    /// costs about 71,800 Cortex-M4 instructions a frame (`edge_fs_frame_vertical` against
    /// `edge_fs_frame_default` in `cargo xtask insns`: row histograms 12,400, the row search
    /// with its per-row sub-pixel and peak ratio 42,900, the rows' fits and the coupled fit
    /// 13,500), which the frame's budget of 250,000 does not hold yet, and on the recorded
    /// takes (which barely move vertically) its MSE is above a zero predictor's.
    pub vertical_search_px: u8,
    /// Default mode: stereo checked both ways (left-right consistency). A column's best
    /// disparity `d` (the right image searched against the left) must come back from the other
    /// way: the left-image content at the matched position, searched against the right-image
    /// columns, must find its own best disparity within ±1 px of `d`; a column that does not is
    /// dropped like an unconfident one before depth, the nearest obstacle, the coverage and
    /// the fit use it (occluded columns, which see background in one eye and an object in the
    /// other, and ambiguous ones). The reverse costs are the search's own, the diagonal of the
    /// kept cost rows ([`stereo_row_checked`]; 2 KiB of them on the stack, [`LR_KEEP_PAIRS`]).
    ///
    /// Off in [`EdgeFsParams::default_config`]. On the recorded takes (`sim-host eval
    /// --config default --lr-check`, paper alignment) it drops 3.1 % of the columns that pass every other
    /// stereo test (0.7 % on take 1/9 to 8.1 % on 1/1) and the velocity gets worse, not
    /// better: forward MSE +94 % on take 1/3, +28 % on 1/7, +9 % on 1/15, -9 % to -12 % on
    /// 1/1, 1/13 and 1/17, within ±5 % on the other six (geometric mean +5 %); sideways within
    /// ±8 %. Flying the simulator's room at seeds 5151/5152 the velocity error rises (vel_rmse
    /// 0.041 / 0.027 to 0.044 / 0.030 m/s), and in the room with obstacles it is mixed (0.041 /
    /// 0.027 to 0.039 / 0.030 m/s). And it costs about 13,500 Cortex-M4 instructions a frame
    /// (`edge_fs_frame_default` 257,967 with it on), beyond the frame's 250,000.
    pub lr_check: bool,
}

impl EdgeFsParams {
    /// The vertical search range that turns the vertical flow on
    /// ([`Self::vertical_search_px`]): ±8 px over the horizon, 1 m/s at 1 m at 25 fps over
    /// 0.25 s.
    pub const VERTICAL_SEARCH_PX: u8 = 8;

    /// The configuration that produced the paper's per-take table: W=8, D=15, H=5, FOV 60°,
    /// baseline 6 cm, paper mode. Set `stereo_shift_px` per board (+5 / -2).
    pub const fn paper() -> Self {
        Self {
            mode: Mode::Paper,
            half_window: 8,
            search_range: 15,
            max_horizon: 5,
            stereo_shift_px: 0,
            fov_x_rad: core::f32::consts::FRAC_PI_3,
            baseline_m: BOARD_BASELINE_M,
            horizon_s: 0.0,
            stereo_range: 15,
            min_disparity_px: 2.0,
            min_stereo_confidence: 0.0,
            min_flow_confidence: 0.0,
            min_texture: 0,
            huber_k: 0.0,
            depth_weight_exp: 0.0,
            max_fit_rms_mps: 1.0,
            min_fit_columns: 8,
            output_median: 1,
            max_obstacle_m: 5.0,
            filter_accel_mps2: 0.0,
            filter_gate: 0.0,
            filter_noise_floor_mps: 0.0,
            filter_noise_scale: 0.0,
            filter_accel_tau_s: 0.0,
            max_rotation_px: 40.0,
            gyro_age_s: 0.0,
            max_derotation_error_px: 0.0,
            min_depth_coverage: 0.0,
            min_fit_spread_px: 0.0,
            min_near_run: 0,
            prior_window_px: 0.0,
            noise_texture_ratio: 0.0,
            noise_structure_ratio: 0.0,
            vertical_search_px: 0,
            lr_check: false,
        }
    }

    /// Our best estimator: default mode, FOV 57.4° (the paper's hardware value), baseline 6 cm,
    /// stereo shift 0 (set the board's calibration).
    ///
    /// Parameter choice (never per take), on a tuning subset of the recorded takes only —
    /// board 1 takes 1, 5, 9, 13, 17, 21 (forward, sideways and corridor motions) — scored
    /// with `--alignment paper` by the mean over those takes and both axes of
    /// `ln(MSE / min(published Edge-FS MSE, published Farnebäck MSE))`; the other takes (1/3,
    /// 1/7, 1/11, 1/15, 1/19, 2/3) were held out and only reported. Tool and procedure:
    /// `tests/tests/integration/eval_tune.rs`.
    /// * Per-frame fit: a grid over W ∈ {5,6,7,8}, H ∈ {2,3,4,5}, minimum disparity ∈ {1, 1.5}
    ///   px, Huber k ∈ {1, 1.5} (scored then after a median of 5): W=6, H=2, 1 px, k=1.
    /// * Temporal filter, scored on the raw output (exactly what the board sends): a grid over
    ///   acceleration noise `filter_accel_mps2` ∈ {0.2, 0.3, 0.4, 0.6, 0.8, 1.2}, noise floor
    ///   ∈ {0.1, 0.15, 0.2} m/s, fit-error scale ∈ {6, 10}, gate ∈ {1.5, 2, 2.5} σ and
    ///   acceleration time constant ∈ {0 (no acceleration state), 0.2, 0.5} s, with the
    ///   horizon kept at the per-frame choice (0.25 s), under a constraint fixed for flight:
    ///   the filter must pass half of a velocity step of any size within 1 frame at the data
    ///   set's 7 Hz (a median of 5 needs 2). Unconstrained, the objective prefers heavier
    ///   smoothing (best −0.96 vs −0.88) that lags 4 frames; longer horizons (0.55 s: −0.95)
    ///   add half the horizon of delay that the step test does not see, so they were not
    ///   taken. Winner: 0.3, 0.2 m/s, 10, 1.5 σ, no acceleration state (a velocity random
    ///   walk). Tuning takes: objective −0.88, lower MSE than both published methods on 6/6
    ///   (x) and 6/6 (y); held out: 6/6 (x), 5/6 (y). At 25 Hz the same filter passes steps
    ///   beyond its gate within 1 frame and smaller ones within 6 frames (0.24 s), see the
    ///   tests of `temporal.rs`.
    /// * The remaining thresholds (confidences 1.2, texture 2000, search and stereo range
    ///   15 px, fit RMS 1 m/s, 8 columns, rotation 30 px, attitude age 20 ms, derotation error
    ///   1 px) are engineering defaults, not tuned on the data set (it has no gyro).
    ///
    /// H was tuned in frames on the data set's 7–8 Hz frames (H=2, 0.25–0.29 s). So that the
    /// estimator behaves the same at the board's 25 Hz, the default expresses it as a time
    /// span, `horizon_s` = 0.25 s (2 frames at 7–8 Hz, 7 at 25 Hz), with `max_horizon` 9 as the
    /// cap; the adaptive horizon still shortens it when flow reaches the search range.
    pub const fn default_config() -> Self {
        Self {
            mode: Mode::Default,
            half_window: 6,
            search_range: 15,
            max_horizon: 9,
            stereo_shift_px: 0,
            fov_x_rad: CAMERA_HFOV_RAD,
            baseline_m: BOARD_BASELINE_M,
            horizon_s: 0.25,
            stereo_range: 15,
            min_disparity_px: 1.0,
            min_stereo_confidence: 1.2,
            min_flow_confidence: 1.2,
            min_texture: 2000,
            huber_k: 1.0,
            depth_weight_exp: 0.0,
            max_fit_rms_mps: 1.0,
            min_fit_columns: 8,
            output_median: 1,
            max_obstacle_m: 5.0,
            filter_accel_mps2: 0.3,
            filter_gate: 1.5,
            filter_noise_floor_mps: 0.2,
            filter_noise_scale: 10.0,
            filter_accel_tau_s: 0.0,
            max_rotation_px: 30.0,
            gyro_age_s: 0.02,
            max_derotation_error_px: 1.0,
            min_depth_coverage: 0.1,
            min_fit_spread_px: 16.0,
            min_near_run: 12,
            prior_window_px: 2.0,
            noise_texture_ratio: 1.85,
            noise_structure_ratio: 3.0,
            vertical_search_px: 0,
            lr_check: false,
        }
    }

    /// Applies a run-time configuration from the autopilot (validated first; on error nothing
    /// changes). Every field takes effect: `search_range` bounds the disparity search in both
    /// modes, so in the default mode it also sets `stereo_range` (the wire's "disparity over
    /// 0..=D").
    pub fn apply(&mut self, cfg: &EdgeFsConfig) -> Result<(), ConfigError> {
        cfg.validate()?;
        self.half_window = cfg.half_window;
        self.search_range = cfg.search_range;
        if self.mode == Mode::Default {
            self.stereo_range = cfg.search_range;
        }
        self.max_horizon = cfg.max_horizon;
        self.stereo_shift_px = i32::from(cfg.stereo_shift);
        Ok(())
    }

    /// The run-time-configurable part of these parameters.
    pub fn to_config(&self) -> EdgeFsConfig {
        EdgeFsConfig {
            half_window: self.half_window,
            search_range: self.search_range,
            max_horizon: self.max_horizon,
            stereo_shift: self.stereo_shift_px.clamp(-20, 20) as i8,
        }
    }

    /// Clamps every field into its valid range (NaN/inf floats fall back to safe values).
    const fn sanitized(mut self) -> Self {
        self.half_window = clamp_u8(self.half_window, 1, EdgeFsConfig::MAX_HALF_WINDOW);
        self.search_range = clamp_u8(self.search_range, 1, EdgeFsConfig::MAX_SEARCH_RANGE);
        self.max_horizon = clamp_u8(self.max_horizon, 1, EdgeFsConfig::MAX_HORIZON);
        self.output_median = clamp_u8(self.output_median, 1, MEDIAN_MAX as u8);
        self.stereo_range = clamp_u8(self.stereo_range, 1, 2 * EdgeFsConfig::MAX_SEARCH_RANGE);
        self.vertical_search_px = clamp_u8(self.vertical_search_px, 0, MAX_VERTICAL_SEARCH);
        if self.stereo_shift_px > MAX_STEREO_SHIFT_PX {
            self.stereo_shift_px = MAX_STEREO_SHIFT_PX;
        } else if self.stereo_shift_px < -MAX_STEREO_SHIFT_PX {
            self.stereo_shift_px = -MAX_STEREO_SHIFT_PX;
        }
        // `!(x > 0)` also catches NaN.
        if !(self.fov_x_rad > FOV_X_RANGE_RAD.0 && self.fov_x_rad < FOV_X_RANGE_RAD.1) {
            self.fov_x_rad = FALLBACK_FOV_X_RAD;
        }
        if !(self.baseline_m > 0.0 && self.baseline_m < MAX_BASELINE_M) {
            self.baseline_m = BOARD_BASELINE_M;
        }
        self.filter_accel_mps2 = finite_or_zero(self.filter_accel_mps2);
        self.filter_gate = finite_or_zero(self.filter_gate);
        self.filter_noise_floor_mps = finite_or_zero(self.filter_noise_floor_mps);
        self.filter_noise_scale = finite_or_zero(self.filter_noise_scale);
        self.filter_accel_tau_s = finite_or_zero(self.filter_accel_tau_s);
        self.max_rotation_px = finite_or_zero(self.max_rotation_px);
        if self.max_rotation_px > MAX_ROTATION_PX {
            self.max_rotation_px = MAX_ROTATION_PX;
        }
        self.gyro_age_s = finite_or_zero(self.gyro_age_s);
        self.max_derotation_error_px = finite_or_zero(self.max_derotation_error_px);
        self.min_depth_coverage = finite_or_zero(self.min_depth_coverage);
        if self.min_depth_coverage > 1.0 {
            self.min_depth_coverage = 1.0;
        }
        self.min_fit_spread_px = finite_or_zero(self.min_fit_spread_px);
        self.prior_window_px = finite_or_zero(self.prior_window_px);
        self.noise_texture_ratio = finite_or_zero(self.noise_texture_ratio);
        self.noise_structure_ratio = finite_or_zero(self.noise_structure_ratio);
        self
    }

    /// Focal length, px/rad.
    pub fn focal_px(&self) -> f32 {
        IMG_W as f32 / self.fov_x_rad
    }
}

/// `v` if finite and positive, else 0 (`const`: no `is_finite` in const fns on stable).
const fn finite_or_zero(v: f32) -> f32 {
    if v > 0.0 && v <= f32::MAX {
        v
    } else {
        0.0
    }
}

/// An angle difference wrapped to [-pi, pi] (NaN stays NaN).
fn wrap_pi(a: f32) -> f32 {
    use core::f32::consts::TAU;
    a - TAU * libm::roundf(a / TAU)
}

const fn clamp_u8(v: u8, lo: u8, hi: u8) -> u8 {
    if v < lo {
        lo
    } else if v > hi {
        hi
    } else {
        v
    }
}

/// Edge-FS result of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeFsOutput {
    /// Forward velocity, m/s (positive towards the scene). 0 when not estimated.
    pub forward_mps: f32,
    /// Sideways velocity, m/s (positive to the right). 0 when not estimated.
    pub sideways_mps: f32,
    /// Distance to the nearest obstacle, m; `None` when nothing confident is within
    /// `max_obstacle_m`.
    pub obstacle_m: Option<f32>,
    /// Confidence 0..=255 of the velocity (default mode: fit residual and number of columns;
    /// paper mode: 255·R² of the fit).
    pub quality: u8,
    /// Why the velocity must not be used (empty: valid).
    pub flags: EstimateFlags,
    /// Fraction of the searchable columns with a confident stereo depth, 0 (none) ..= 255
    /// (all): how much of the view is known. An unknown view is not a clear one.
    pub depth_coverage: u8,
    /// Textured columns whose disparity search ran out of range: something nearer than the
    /// minimum stereo range (default mode; 0 in paper mode).
    pub near_columns: u8,
    /// Default mode: the frame's own velocity fit before the temporal filter, when it is valid
    /// (`None` otherwise, and always in paper mode); see [`protocol::Estimate::fit`].
    pub fit: Option<FrameFit>,
    /// Default mode: vertical velocity, m/s (positive: climbing), from the coupled fit of the
    /// row flow; 0 when not estimated.
    pub up_mps: f32,
    /// Why [`Self::up_mps`] must not be used (empty: valid): the frame's flags (the vertical
    /// velocity needs the same depth and texture) and the row fit's own.
    pub up_flags: EstimateFlags,
    /// Default mode: R² of the coupled three-axis fit, 0..=255 (paper mode: 0).
    pub fit_r2: u8,
    /// Default mode: the divergence of the horizontal flow, from every column with a flow
    /// match (with or without depth), and so the time to contact; `None` when too few columns
    /// have flow, and in paper mode.
    pub divergence: Option<Divergence>,
}

impl EdgeFsOutput {
    const EMPTY: Self = Self {
        forward_mps: 0.0,
        sideways_mps: 0.0,
        obstacle_m: None,
        quality: 0,
        flags: EstimateFlags::NONE,
        depth_coverage: 0,
        near_columns: 0,
        fit: None,
        up_mps: 0.0,
        up_flags: EstimateFlags::NO_FLOW_MATCH,
        fit_r2: 0,
        divergence: None,
    };
}

/// Per-column diagnostics of the last processed frame, for tools (index = 0-based column).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Diagnostics {
    /// Stereo disparity (with the calibration shift applied), px; 0 where not computed.
    pub disparity_px: [f32; IMG_W],
    /// Depth from the disparity, m; 0 where invalid.
    pub depth_m: [f32; IMG_W],
    /// Derotated image motion, px/s (paper mode: px/frame·rate); 0 where not computed.
    pub flow_pxps: [f32; IMG_W],
    /// Stereo confidence (peak ratio, >= 1; paper mode: 1 for valid columns), 0 where invalid.
    pub confidence: [f32; IMG_W],
    /// Column used in the velocity fit.
    pub used: [bool; IMG_W],
    /// Derotated vertical image motion per row (index = 0-based row, positive downwards),
    /// px/s; 0 where not computed.
    pub row_flow_pxps: [f32; IMG_H],
    /// Rows used in the vertical fit.
    pub fit_rows: u8,
    /// Flow horizon of the last frame, frames.
    pub horizon: u8,
    /// Columns used in the fit.
    pub fit_columns: u8,
    /// The flow search was guided by the temporal filter ([`EdgeFsParams::prior_window_px`]).
    pub guided: bool,
    /// Guided columns whose best match lay outside the predicted window (not used).
    pub prior_misses: u8,
    /// The edge sum of a column window that this frame's pixel noise alone gives (0 when
    /// [`EdgeFsParams::noise_texture_ratio`] is off).
    pub noise_window: f32,
    /// Columns the left-right check dropped ([`EdgeFsParams::lr_check`]): they passed every
    /// other stereo test.
    pub lr_dropped: u8,
}

impl Diagnostics {
    const EMPTY: Self = Self {
        disparity_px: [0.0; IMG_W],
        depth_m: [0.0; IMG_W],
        flow_pxps: [0.0; IMG_W],
        confidence: [0.0; IMG_W],
        used: [false; IMG_W],
        row_flow_pxps: [0.0; IMG_H],
        fit_rows: 0,
        horizon: 0,
        fit_columns: 0,
        guided: false,
        prior_misses: 0,
        noise_window: 0.0,
        lr_dropped: 0,
    };
}

#[derive(Debug, Clone, Copy)]
struct Slot {
    hist: EdgeHistogram,
    /// Row edge histogram ([`row_histogram`]; default mode with vertical flow only).
    rows: EdgeHistogram,
    /// Pitch, rad (body: positive nose up; 0 when unknown).
    pitch_rad: f32,
    /// Exposure time, on the board clock.
    capture: Instant,
    yaw_rad: f32,
    /// Body yaw rate, rad/s (0 when unknown).
    yaw_rate: f32,
    has_yaw: bool,
}

impl Slot {
    const EMPTY: Self = Self {
        hist: [0; IMG_W],
        rows: [0; IMG_W],
        pitch_rad: 0.0,
        capture: Instant::ZERO,
        yaw_rad: 0.0,
        yaw_rate: 0.0,
        has_yaw: false,
    };
}

/// Edge-FS state: a ring of past edge histograms and the adaptive-horizon state. Fixed size
/// (about 5 kB), no heap; `const fn new` so it can be a `static` (e.g. in CCM).
#[derive(Debug, Clone)]
pub struct EdgeFs {
    params: EdgeFsParams,
    ring: [Slot; RING],
    head: usize,
    frames: u32,
    horizon: u8,
    tau_x: f64,
    /// Current histogram of the camera whose history is not kept (paper: right, default: left).
    other: EdgeHistogram,
    diag: Diagnostics,
    recent: [(f32, f32); MEDIAN_MAX],
    recent_len: usize,
    /// Temporal filters of the forward, sideways and vertical velocity.
    filter: [AxisFilter; 3],
    /// The previous frame's guided search missed most columns: search the whole range once.
    prior_doubted: bool,
}

impl EdgeFs {
    /// New estimator with empty history (parameters clamped into range).
    pub const fn new(params: EdgeFsParams) -> Self {
        Self {
            params: params.sanitized(),
            ring: [Slot::EMPTY; RING],
            head: 0,
            frames: 0,
            horizon: 1,
            tau_x: 0.0,
            other: [0; IMG_W],
            diag: Diagnostics::EMPTY,
            recent: [(0.0, 0.0); MEDIAN_MAX],
            recent_len: 0,
            filter: [AxisFilter::new(), AxisFilter::new(), AxisFilter::new()],
            prior_doubted: false,
        }
    }

    /// The parameters in use.
    pub fn params(&self) -> &EdgeFsParams {
        &self.params
    }

    /// Replaces the parameters and clears the history.
    pub fn set_params(&mut self, params: EdgeFsParams) {
        *self = Self::new(params);
    }

    /// Forgets the history (e.g. after a gap in the frame stream).
    pub fn reset(&mut self) {
        *self = Self::new(self.params);
    }

    /// Diagnostics of the last processed frame.
    pub fn diagnostics(&self) -> &Diagnostics {
        &self.diag
    }

    /// Processes one frame.
    ///
    /// `frame`: interleaved `[L0 R0 L1 R1 ...]`, 128x96, row-major, top row first.
    /// `capture`: exposure time (monotonic). `motion`: latest gyro/attitude from the
    /// autopilot (`None`: no derotation; the default mode then sets
    /// [`EstimateFlags::NO_GYRO`]).
    pub fn process(
        &mut self,
        frame: &[u8; STEREO_FRAME_BYTES],
        capture: Instant,
        motion: Option<&GyroAttitude>,
    ) -> EdgeFsOutput {
        self.frames = self.frames.saturating_add(1);
        self.head = (self.head + 1) % RING;
        let yaw = motion.map(|m| m.attitude_rad[2]).filter(|y| y.is_finite());
        if let Some(slot) = self.ring.get_mut(self.head) {
            slot.capture = capture;
            slot.yaw_rad = yaw.unwrap_or(0.0);
            slot.yaw_rate = motion
                .map(|m| m.rates_radps[2])
                .filter(|r| r.is_finite())
                .unwrap_or(0.0);
            slot.has_yaw = yaw.is_some();
            // The pitch only with a yaw (one attitude sample): rotation needs both ends.
            slot.pitch_rad = motion
                .map(|m| m.attitude_rad[1])
                .filter(|p| p.is_finite() && yaw.is_some())
                .unwrap_or(0.0);
            slot.hist = [0; IMG_W];
        }
        self.diag = Diagnostics::EMPTY;
        match self.params.mode {
            Mode::Paper => self.process_paper(frame),
            Mode::Default => self.process_default(frame, motion.is_some()),
        }
    }

    fn slot(&self, back: usize) -> &Slot {
        &self.ring[self.idx(back)]
    }

    fn idx(&self, back: usize) -> usize {
        (self.head + RING - back % RING) % RING
    }

    /// Histograms of the current frame: the flow camera's goes into the ring, the other one
    /// into `self.other`. The paper mode tracks flow in the left image (and indexes stereo by
    /// right-image column, so depth and flow of a column come from different scene points
    /// near depth edges); the default mode tracks flow in the right image, the one stereo is
    /// indexed by, so each column's depth and flow belong together.
    ///
    /// Returns the mean intensity of the left image in the default mode (computed in the same
    /// pass, [`edge_histograms_and_mean`]); the paper mode does not use it and gets 0.
    fn compute_histograms(&mut self, frame: &[u8; STEREO_FRAME_BYTES]) -> u8 {
        if self.params.mode == Mode::Default && self.params.vertical_search_px > 0 {
            if let Some(slot) = self.ring.get_mut(self.head) {
                row_histogram(frame, &mut slot.rows);
            }
        }
        // Written in place (every bin is overwritten): no copies of the histograms.
        let mut unused;
        let tracked = match self.ring.get_mut(self.head) {
            Some(slot) => &mut slot.hist,
            None => {
                unused = [0; IMG_W];
                &mut unused
            }
        };
        let other = &mut self.other;
        match self.params.mode {
            Mode::Paper => {
                edge_histograms(frame, tracked, other);
                0
            }
            Mode::Default => {
                let mean = edge_histograms_and_mean(frame, other, tracked);

                // The zero-padded border bins hold image intensity, not edges: drop them.
                for h in [tracked, other] {
                    h[0] = 0;
                    h[IMG_W - 1] = 0;
                }
                mean
            }
        }
    }

    /// The paper-era MATLAB pipeline (spec §4.2), frame `i = self.frames`.
    fn process_paper(&mut self, frame: &[u8; STEREO_FRAME_BYTES]) -> EdgeFsOutput {
        let p = self.params;
        let (w, d, h) = (
            p.half_window as usize,
            p.search_range as usize,
            p.max_horizon as usize,
        );
        let s = p.stereo_shift_px;
        let mut out = EdgeFsOutput::EMPTY;
        if self.frames as usize <= h + 1 {
            // History filling: the slot keeps an all-zero histogram (as the reference's ring).
            out.flags = EstimateFlags::HISTORY_FILLING;
            return out;
        }
        self.compute_histograms(frame);

        // Horizon update from the previous processed frame's global translation.
        let tau = self.tau_x.abs();
        let mut n = self.horizon as usize;
        if tau > HORIZON_SHRINK_PX && n > 1 {
            n -= 1;
        }
        if tau < HORIZON_GROW_PX && n < h {
            n += 1;
        }
        self.horizon = n as u8;

        // Temporal flow, columns W+D+1 ..= 128-W-D (1-based), divided by the horizon.
        let mut flow = [0.0f64; IMG_W];
        {
            let cur = &self.slot(0).hist;
            let older = &self.slot(n).hist;
            let cols = (w + d)..(IMG_W - w - d);
            flow_row(older, cur, d, 0, w, |c0, m| {
                if cols.contains(&c0) {
                    flow[c0] = (m.best as f64 - d as f64) / n as f64;
                }
            });
        }
        let global = line_fit(
            flow.iter()
                .enumerate()
                .filter(|(_, &f)| f != 0.0)
                .map(|(c, &f)| ((c + 1) as f64, f)),
        );
        self.tau_x = CENTRE_COLUMN * global.slope + global.intercept;

        // Stereo, columns W+1+max(s,0) ..= 128-W-D+min(s,0) (1-based).
        let mut disp = [0u8; IMG_W];
        let lo = w as i32 + 1 + s.max(0);
        let hi = (IMG_W - w - d) as i32 + s.min(0);
        {
            let cur = &self.slot(0).hist;
            let cols = lo.max(1)..=hi.min(IMG_W as i32);
            stereo_row(cur, &self.other, d, s, w, |c0, m| {
                if cols.contains(&(c0 as i32 + 1)) {
                    disp[c0] = m.best as u8;
                }
            });
        }

        // Post-hoc derotation with the n-frame yaw difference / n (data set yaw = -body yaw).
        let f = IMG_W as f64 / f64::from(p.fov_x_rad);
        let (cur, older) = (self.slot(0), self.slot(n));
        let delta = if cur.has_yaw && older.has_yaw {
            -(f64::from(cur.yaw_rad) - f64::from(older.yaw_rad)) * f / n as f64
        } else {
            0.0
        };
        // The unsigned difference: a capture time going back gives a frame rate of about zero.
        let dt_us = cur.capture.wrapping_since(self.slot(1).capture).as_micros();
        let fr = US_PER_S / dt_us as f64;
        let border = w + d;
        let (vlo, vhi) = (d + w + 2, IMG_W - d - w - 2);
        let mut pts = [(0.0f64, 0.0f64); IMG_W];
        let mut np = 0;
        for c1 in 1..=IMG_W {
            let c0 = c1 - 1;
            let mut u = flow[c0] - delta;
            if c1 <= border || c1 >= IMG_W - border {
                u = 0.0;
            }
            self.diag.disparity_px[c0] = f32::from(disp[c0]);
            self.diag.flow_pxps[c0] = (u * fr) as f32;
            if disp[c0] >= 2 && (vlo..=vhi).contains(&c1) {
                let z = f * f64::from(p.baseline_m) / f64::from(disp[c0]);
                self.diag.depth_m[c0] = z as f32;
                self.diag.confidence[c0] = 1.0;
                self.diag.used[c0] = true;
                if let Some(pt) = pts.get_mut(np) {
                    *pt = (c1 as f64, z * u * fr);
                    np += 1;
                }
            }
        }
        let fit = line_fit(pts.iter().take(np).copied());
        self.diag.horizon = n as u8;
        self.diag.fit_columns = np as u8;
        out.forward_mps = fit.slope as f32;
        // MATLAB's sideways output (line at the centre in rad) is positive to the left.
        out.sideways_mps = (-(fit.intercept + CENTRE_COLUMN * fit.slope) * f64::from(p.fov_x_rad)
            / IMG_W as f64) as f32;
        out.quality = (fit.r2.clamp(0.0, 1.0) * QUALITY_FULL_SCALE) as u8;
        out.obstacle_m = self.nearest_obstacle();
        out.depth_coverage = coverage_u8(np, IMG_W.saturating_sub(2 * w));
        if np < 2 {
            out.flags.insert(EstimateFlags::NO_STEREO_MATCH);
        }
        if !(out.forward_mps.is_finite() && out.sideways_mps.is_finite()) {
            // Only with repeated capture times (infinite frame rate): never on real data.
            out.forward_mps = 0.0;
            out.sideways_mps = 0.0;
            out.quality = 0;
            out.flags.insert(EstimateFlags::POOR_FIT);
        }
        out
    }

    /// Our estimator (see the module docs): the frame's fit, then the temporal filter.
    fn process_default(
        &mut self,
        frame: &[u8; STEREO_FRAME_BYTES],
        has_gyro: bool,
    ) -> EdgeFsOutput {
        let mut out = EdgeFsOutput::EMPTY;
        let sigma = match self.fit_default(frame, has_gyro, &mut out) {
            Ok(sigma) => Some(sigma),
            Err(flag) => {
                out.flags.insert(flag);
                None
            }
        };
        if out.flags.is_valid() {
            out.fit = Some(FrameFit {
                forward_mps: out.forward_mps,
                sideways_mps: out.sideways_mps,
                quality: out.quality,
            });
        }
        let p = self.params;
        if p.filter_accel_mps2 <= 0.0 {
            return out;
        }
        // The unsigned difference: a capture time going back reads as a gap far too long.
        let now = self.ring[self.idx(0)].capture;
        let dt_s = now
            .wrapping_since(self.ring[self.idx(1)].capture)
            .as_secs_f32();
        if self.frames < 2 || !(dt_s > MIN_FRAME_GAP_S && dt_s < MAX_FRAME_GAP_S) {
            // First frame, a gap or a clock jump: the track is lost.
            self.filter = [AxisFilter::new(), AxisFilter::new(), AxisFilter::new()];
        }
        let q = p.filter_accel_mps2;
        let mut rejected = false;
        let mut up_rejected = false;
        let z = [out.forward_mps, out.sideways_mps, out.up_mps];
        for (k, f) in self.filter.iter_mut().enumerate() {
            f.predict(dt_s, q, p.filter_accel_tau_s);
            // The vertical axis takes only valid vertical fits, and its rejection flags only
            // the vertical velocity.
            if k == 2 && p.vertical_search_px == 0 {
                break;
            }
            let measured = k < 2 || out.up_flags.is_valid();
            if let (Some(sig), true) = (sigma, measured) {
                let s = p.filter_noise_scale * sig[k];
                // Fits of consecutive frames share all but one frame of their horizon, so
                // their errors are correlated: one independent measurement per horizon, i.e.
                // the variance per frame scales with the horizon in frames. This keeps the
                // filter's response the same in seconds at 7 Hz and at 25 Hz.
                let span = f32::from(self.diag.horizon.max(1));
                let r = span * (s * s + p.filter_noise_floor_mps * p.filter_noise_floor_mps);
                let outlier = f.update(z[k], r, p.filter_gate, q) == Update::Rejected;
                if k < 2 {
                    rejected |= outlier;
                } else {
                    up_rejected = outlier;
                }
            }
        }
        if rejected {
            out.flags.insert(EstimateFlags::POOR_FIT);
            out.quality = 0;
        }
        if self.filter[0].is_initialised() {
            out.forward_mps = self.filter[0].velocity();
            out.sideways_mps = self.filter[1].velocity();
        }
        if up_rejected {
            out.up_flags.insert(EstimateFlags::POOR_FIT);
        }
        if self.filter[2].is_initialised() && p.vertical_search_px > 0 {
            out.up_mps = self.filter[2].velocity();
        }
        out
    }

    /// The vertical flow of the rows against the frame `self.diag.horizon` back, and the
    /// coupled fit of the three axes with the columns' fit (`cols`: its points `(x, Z·u, w)`;
    /// `line`: its slope and intercept; `slope_sigma`: the slope's standard error).
    ///
    /// The rows share one depth `Z̄`, the harmonic mean of the used columns' (a row's flow
    /// averages `1/Z` along it), and centred on the image `Z̄·v = F·y + f·U` (`y` downwards, `U`
    /// up), the columns `Z·u = F·x - f·S`: one forward velocity `F` from the divergence of
    /// both axes. The least squares of both blocks with the shared slope: each block's slope,
    /// combined by inverse variance, each intercept moved with it through its block's
    /// centroid. The rows' fit takes one Huber round (MAD scale) after least squares.
    fn coupled_fit(
        &mut self,
        cols: &[(f32, f32, f32)],
        line: &LineFit,
        slope_sigma: f32,
        dt_s: f32,
    ) -> Coupled {
        let p = self.params;
        let f = p.focal_px();
        let (a, b) = (line.slope as f32, line.intercept as f32);
        // The columns' own fit (its R² under the robust fit's final weights).
        let columns_only = |up_flags: EstimateFlags| Coupled {
            forward_mps: a,
            sideways_mps: -b / f,
            up_mps: 0.0,
            forward_sigma: slope_sigma,
            up_sigma: f32::INFINITY,
            r2: line.r2,
            up_flags,
        };
        let d = usize::from(p.vertical_search_px);
        if d == 0 {
            return columns_only(EstimateFlags::NO_FLOW_MATCH);
        }
        let (i0, i1) = (self.idx(0), self.idx(usize::from(self.diag.horizon.max(1))));
        let (cur, older) = (&self.ring[i0], &self.ring[i1]);
        // The rows' depth: harmonic mean over the columns of the fit.
        let (mut inv_sum, mut used) = (0.0f32, 0usize);
        for (&u, &z) in self.diag.used.iter().zip(self.diag.depth_m.iter()) {
            if u && z > 0.0 {
                inv_sum += 1.0 / z;
                used += 1;
            }
        }
        // Nose up moves the scene down the image (towards larger rows).
        let rot_px = if cur.has_yaw && older.has_yaw {
            (cur.pitch_rad - older.pitch_rad) * f
        } else {
            0.0
        };
        if inv_sum <= 0.0 || rot_px.is_nan() || rot_px.abs() > p.max_rotation_px {
            return columns_only(EstimateFlags::NO_FLOW_MATCH);
        }
        let z_bar = used as f32 / inv_sum;
        let w = usize::from(p.half_window);
        let offset = libm::roundf(rot_px) as i32;
        let mut texture = [0u32; IMG_W];
        window_sums(&cur.rows, w, &mut texture);
        // A row bin sums 2·128 pixels, a column bin 96: the same texture per pixel.
        let min_texture = p.min_texture.saturating_mul(8) / 3;
        let mut rows = [(0.0f32, 0.0f32, 1.0f32); IMG_H];
        let mut nr = 0;
        let row_flow = &mut self.diag.row_flow_pxps;
        // Windows inside rows 1..=IMG_H-2 (the border bins hold no gradient) in both frames.
        flow_row_within(
            &older.rows,
            &cur.rows,
            d,
            offset,
            w,
            1,
            IMG_H - 2,
            |r, m| {
                let usable = texture[r] >= min_texture
                    && m.best > 0
                    && m.best < 2 * d
                    && m.confidence() >= p.min_flow_confidence;
                if !usable {
                    return;
                }
                let motion = offset as f32 + m.best as f32 - d as f32 + m.subpixel();
                let v = (motion - rot_px) / dt_s;
                if let (Some(slot), Some(pt)) = (row_flow.get_mut(r), rows.get_mut(nr)) {
                    *slot = v;
                    *pt = (r as f32 - 0.5 * (IMG_H - 1) as f32, z_bar * v, 1.0);
                    nr += 1;
                }
            },
        );
        self.diag.fit_rows = nr as u8;
        let rows = rows.get_mut(..nr).unwrap_or(&mut []);
        if nr < usize::from(p.min_fit_columns).max(3) {
            return columns_only(EstimateFlags::NO_FLOW_MATCH);
        }
        let Some(first) = weighted_line_fit(rows) else {
            return columns_only(EstimateFlags::NO_FLOW_MATCH);
        };
        let (a0, b0) = (first.slope as f32, first.intercept as f32);
        let mut res = [0.0f32; IMG_H];
        for (r, pt) in res.iter_mut().zip(rows.iter()) {
            *r = (pt.1 - (a0 * pt.0 + b0)).abs();
        }
        let scale =
            (fit::MAD_TO_SIGMA * median(res.get_mut(..nr).unwrap_or(&mut []))).max(fit::MIN_SCALE);
        let (cut, reject) = (p.huber_k * scale, fit::REJECT_SCALES * scale);
        for pt in rows.iter_mut() {
            let r = (pt.1 - (a0 * pt.0 + b0)).abs();
            pt.2 = if p.huber_k > 0.0 {
                fit::reweight(r, 1.0, cut, reject)
            } else {
                1.0
            };
        }
        let Some(row_fit) = weighted_line_fit(rows) else {
            return columns_only(EstimateFlags::NO_FLOW_MATCH);
        };
        let (ar, br) = (row_fit.slope as f32, row_fit.intercept as f32);
        let (mut sw, mut sy, mut syy) = (0.0f32, 0.0f32, 0.0f32);
        let (mut y_lo, mut y_hi) = (f32::MAX, f32::MIN);
        for pt in rows.iter().filter(|pt| pt.2 > 0.0) {
            sw += pt.2;
            sy += pt.2 * pt.0;
            syy += pt.2 * pt.0 * pt.0;
            y_lo = fmin(y_lo, pt.0);
            y_hi = fmax(y_hi, pt.0);
        }
        let y_mean = sy / sw.max(MIN_WEIGHT_SUM);
        let row_var = scale * scale;
        let var_ar = row_var / (syy - sy * y_mean).max(1.0);
        let var_a = (slope_sigma * slope_sigma).max(MIN_SLOPE_VARIANCE);
        // The shared slope and both intercepts through their blocks' centroids.
        let x_mean = cols.iter().map(|pt| pt.0).sum::<f32>() / cols.len().max(1) as f32;
        let var_f = 1.0 / (1.0 / var_a + 1.0 / var_ar);
        let forward = var_f * (a / var_a + ar / var_ar);
        let (bc, brc) = (b + (a - forward) * x_mean, br + (ar - forward) * y_mean);
        let mut up_flags = EstimateFlags::NONE;
        if scale / f > p.max_fit_rms_mps || y_hi - y_lo < p.min_fit_spread_px {
            up_flags.insert(EstimateFlags::POOR_FIT);
        }
        let r2 = match (block_r2(cols, forward, bc), block_r2(rows, forward, brc)) {
            (Some((rc, tc)), Some((rr, tr))) => 1.0 - (rc + rr) / (tc + tr),
            _ => 0.0,
        };
        let up_sigma = libm::sqrtf(row_var / sw.max(MIN_WEIGHT_SUM) + y_mean * y_mean * var_f) / f;
        if !(forward.is_finite() && bc.is_finite() && brc.is_finite() && up_sigma.is_finite()) {
            return columns_only(EstimateFlags::POOR_FIT);
        }
        Coupled {
            forward_mps: forward,
            sideways_mps: -bc / f,
            up_mps: brc / f,
            forward_sigma: libm::sqrtf(var_f),
            up_sigma,
            r2,
            up_flags,
        }
    }

    /// The temporal filter's velocity to guide this frame's flow search, if it has a track
    /// that reaches this frame (the previous frame within a second), confirmed by a second
    /// measurement, and the guide is on. A track started by one wild fit would otherwise
    /// guide the search to the matches it predicts and confirm itself.
    fn flow_prior(&self) -> Option<FlowPrior> {
        // As the filter's gap: a capture time going back reads as a gap far too long.
        let now = self.ring[self.idx(0)].capture;
        let gap_s = now
            .wrapping_since(self.ring[self.idx(1)].capture)
            .as_secs_f32();
        let [fw, sw, _] = &self.filter;
        let usable = self.params.prior_window_px > 0.0
            && self.params.filter_accel_mps2 > 0.0
            && !self.prior_doubted
            && self.frames >= 2
            && gap_s > MIN_FRAME_GAP_S
            && gap_s < MAX_FRAME_GAP_S
            && fw.is_confirmed()
            && sw.is_confirmed();
        usable.then(|| FlowPrior {
            forward_mps: fw.velocity(),
            sideways_mps: sw.velocity(),
            forward_sigma: fw.velocity_sigma(),
            sideways_sigma: sw.velocity_sigma(),
        })
    }

    /// Nearest obstacle: the smallest mean depth over runs of at least 5 adjacent columns with
    /// a valid depth whose neighbours differ by less than 30 %.
    fn nearest_obstacle(&self) -> Option<f32> {
        let depth = &self.diag.depth_m;
        let mut best: Option<f32> = None;
        let (mut run, mut sum) = (0usize, 0.0f32);
        let mut prev = 0.0f32;
        // A run of at least 5 columns ended: keep its mean if it is the nearest so far.
        let end_run = |run: usize, sum: f32, best: &mut Option<f32>| {
            if run >= OBSTACLE_RUN_COLUMNS {
                let mean = sum / run as f32;
                if best.is_none_or(|b| mean < b) {
                    *best = Some(mean);
                }
            }
        };
        for &z in depth.iter() {
            let continues =
                z > 0.0 && run > 0 && (z - prev).abs() < OBSTACLE_DEPTH_STEP * fmax(prev, z);
            if z > 0.0 && (run == 0 || continues) {
                run += 1;
                sum += z;
            } else {
                end_run(run, sum, &mut best);
                (run, sum) = if z > 0.0 { (1, z) } else { (0, 0.0) };
            }
            prev = z;
        }
        // The image edge ends the last run.
        end_run(run, sum, &mut best);
        best.filter(|&z| z <= self.params.max_obstacle_m)
    }
}

/// The coupled three-axis fit of a frame ([`EdgeFs::coupled_fit`]).
#[derive(Debug, Clone, Copy)]
struct Coupled {
    forward_mps: f32,
    sideways_mps: f32,
    up_mps: f32,
    /// Standard errors of the forward and vertical velocity, m/s.
    forward_sigma: f32,
    up_sigma: f32,
    /// Coefficient of determination of both blocks together.
    r2: f32,
    /// The vertical velocity's own invalidity.
    up_flags: EstimateFlags,
}

/// The weighted residual and total sums of squares of `points` `(x, v, w)` about the line
/// `v = a·x + b` and about their weighted mean; `None` without weight or spread.
fn block_r2(points: &[(f32, f32, f32)], a: f32, b: f32) -> Option<(f32, f32)> {
    let (mut sw, mut sv) = (0.0f32, 0.0f32);
    for pt in points {
        sw += pt.2;
        sv += pt.2 * pt.1;
    }
    if sw <= 0.0 {
        return None;
    }
    let mean = sv / sw;
    let (mut res, mut tot) = (0.0f32, 0.0f32);
    for pt in points {
        let r = pt.1 - (a * pt.0 + b);
        res += pt.2 * r * r;
        tot += pt.2 * (pt.1 - mean) * (pt.1 - mean);
    }
    (tot > 0.0).then_some((res, tot))
}

/// The velocity that guides the flow search ([`EdgeFsParams::prior_window_px`]), m/s.
#[derive(Debug, Clone, Copy)]
struct FlowPrior {
    forward_mps: f32,
    sideways_mps: f32,
    forward_sigma: f32,
    sideways_sigma: f32,
}

/// `a.max(b)` as the Cortex-M4's `fmaxf` computes it (`b` when `a < b` or `a` is NaN, else
/// `a`), inline: without `VMAXNM` (FPv4) `f32::max` is a library call, about a dozen
/// instructions with the call for two compares. For the per-column and per-point loops.
#[inline(always)]
fn fmax(a: f32, b: f32) -> f32 {
    if a < b || a.is_nan() {
        b
    } else {
        a
    }
}

/// `a.min(b)` as the Cortex-M4's `fminf` computes it (`a` when `a < b` or `b` is NaN, else
/// `b`), inline (see [`fmax`]).
#[inline(always)]
fn fmin(a: f32, b: f32) -> f32 {
    if a < b || b.is_nan() {
        a
    } else {
        b
    }
}

/// `n` of `of` as a fraction 0..=255 (0 when `of` is 0).
fn coverage_u8(n: usize, of: usize) -> u8 {
    if of == 0 {
        return 0;
    }
    (n.min(of) * 255 / of) as u8
}

/// Length of the longest run of `true` in `v`.
fn longest_run(v: &[bool]) -> usize {
    let (mut best, mut run) = (0, 0);
    for &b in v {
        run = if b { run + 1 } else { 0 };
        best = best.max(run);
    }
    best
}

/// Median of a short slice (mean of the two middle values for even lengths, 0 when empty),
/// under the total order of `f32`.
///
/// By selection, not sorting: the element a sort would put at `len / 2` and, for even
/// lengths, the largest of those before it (the sort's `len / 2 - 1`). Under the total order
/// both are unique, so the result is bit for bit the sorted form's.
fn median(v: &mut [f32]) -> f32 {
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    let (lower, &mut upper, _) = v.select_nth_unstable_by_key(n / 2, fit::order_key);
    if n % 2 == 1 {
        upper
    } else {
        let below = lower
            .iter()
            .copied()
            .max_by(|a, b| a.total_cmp(b))
            .unwrap_or(upper);
        0.5 * (below + upper)
    }
}

/// The steps between neighbouring inner bins of a histogram: bin `c` holds `|h[c] - h[c-1]|`
/// (0 where either is a border bin, which holds a plain column sum). Neighbouring bins share no
/// pixel, so noise alone gives independent steps.
fn histogram_steps(h: &EdgeHistogram) -> EdgeHistogram {
    let mut steps = [0u16; IMG_W];
    let inner = h.get(1..IMG_W - 1).unwrap_or(&[]);
    for (s, pair) in steps.iter_mut().skip(2).zip(inner.windows(2)) {
        *s = pair[1].abs_diff(pair[0]);
    }
    steps
}

/// Edge energy per column: `out[c]` is the sum of the histogram bins of the `2w+1` window
/// centred at `c`, 0 where the window leaves the image.
///
/// A running sum (integers, so exactly the per-window sums): each column adds the bin entering
/// the window and subtracts the one leaving it.
fn window_sums(h: &EdgeHistogram, w: usize, out: &mut [u32; IMG_W]) {
    *out = [0; IMG_W];
    let Some(first) = h.get(..=2 * w) else {
        return;
    };
    let mut sum: u32 = first.iter().map(|&v| u32::from(v)).sum();
    if let Some(o) = out.get_mut(w) {
        *o = sum;
    }
    // Column `c` (from `w + 1`): bin `c + w` enters, bin `c - w - 1` leaves.
    let entering = h.iter().skip(2 * w + 1);
    for ((o, &enter), &leave) in out.iter_mut().skip(w + 1).zip(entering).zip(h.iter()) {
        sum = sum + u32::from(enter) - u32::from(leave);
        *o = sum;
    }
}

#[cfg(test)]
mod tests;
