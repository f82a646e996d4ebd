//! Horizontal velocity estimation: the stage between the camera board's Edge-FS estimates and
//! guidance.
//!
//! Takes: every [`Estimate`] with the [`VisionContext`] it arrived in (arrival time, height and
//! climb rate), and at 512 Hz the attitude and the yaw rate ([`VelocityEstimation::predict`]).
//! Gives: the [`VelocityState`] guidance flies on (the velocity of the configured
//! [`VelocitySource`] and when that source last took an estimate), the time of the last valid
//! estimate for the failsafe ([`VelocityEstimation::last_valid_estimate`]), and for each
//! estimate the [`Gate`] it stopped at.
//!
//! The gates, in order (tunables are [`EstimationConfig`] fields, the parameter table's):
//!
//! 1. Valid: the estimate's flags, `min_quality`, a finite velocity within `max_estimate_mps`
//!    (with [`VelocitySource::KalmanFits`]: the frame's own fit, present only when valid, and
//!    its quality). An invalid one ends the run of valid ones.
//! 2. Run: only the `min_valid_run`-th valid estimate in a row and later ones count, for the
//!    velocity and for the failsafe. A gap of more than `median_reset_gap` since the last
//!    valid one empties the median.
//! 3. Height: below `min_vision_height_m`, or climbing or descending faster than
//!    `max_vision_climb_mps` over a view with less than `vision_climb_min_depth` of it in
//!    stereo depth, an estimate counts for the failsafe only.
//! 4. Yaw: within `yaw_settle` of a yaw rate above `max_yaw_rate_radps`, likewise (counted
//!    in [`VelocityEstimation::yaw_gated`]). An estimate invalid only for its flow (a poor fit
//!    or no flow match) whose flow window reaches back into a fast yaw counts for the failsafe
//!    too: the camera sees texture and depth, the turn spoiled the fit (the camera board
//!    derotates with a few-ms-old attitude, and flags the fits around a change of yaw rate).
//! 5. The Kalman filter ([`VelocitySource::Kalman`]) takes what passed 4, as the mean velocity
//!    over the window the estimate describes, behind its own innovation gate.
//! 6. Plausibility (the paper's path): further than `max_velocity_jump_mps` from the median
//!    output is an outlier and skipped, unless it is the `max_consecutive_outliers`-th in a row
//!    that agrees with the one before, which restarts the median from it.
//! 7. The median-5, whose output corrects the velocity observer
//!    ([`VelocitySource::MedianObserver`]).
//!

use crate::guidance::ObserverConfig;
use crate::guidance::VelocityObserver;
use crate::median::VelocityMedian;
use crate::velocity_kf::VelocityKfConfig;
use crate::velocity_kf::{Fusion, VelocityKf};
use protocol::{Estimate, EstimateFlags};
use timebase::{Duration, Instant};

/// The horizontal velocity estimation: the gates an Edge-FS estimate passes, the velocity
/// filters and the timing of an estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EstimationConfig {
    /// Estimates with a lower quality are treated as invalid (0..=255).
    pub min_quality: u8,
    /// A gap between valid estimates longer than this empties the median filter.
    pub median_reset_gap: Duration,
    /// Largest accepted velocity estimate magnitude per axis, m/s (bigger is treated as invalid).
    pub max_estimate_mps: f32,
    /// Plausibility gate: an estimate further than this from the median output on either axis
    /// is an outlier and skipped, m/s (a 15 deg bank changes the velocity by about 0.1 m/s
    /// per 25 Hz frame). The median alone cannot reject two spikes in a row.
    pub max_velocity_jump_mps: f32,
    /// After this many consecutive outliers that agree with each other (within
    /// `max_velocity_jump_mps`) the gate restarts the median from the new value (the filter,
    /// not the estimates, lost track).
    pub max_consecutive_outliers: u8,
    /// Guidance flies on the observer's velocity only while the last fused estimate is
    /// younger than this (in between the observer dead-reckons from the attitude, which
    /// keeps braking through fast yaw and short link outages); older, it holds the trim
    /// attitude.
    pub velocity_max_age: Duration,
    /// Velocity observer (prediction from the attitude, correction by the filtered Edge-FS
    /// velocity).
    pub observer: ObserverConfig,
    /// Which velocity guidance flies on.
    pub velocity_source: VelocitySource,
    /// Horizontal velocity Kalman filter.
    pub velocity_kf: VelocityKfConfig,
    /// Time span an Edge-FS velocity averages over: its flow horizon (`horizon_s`, 0.25 s
    /// by default) widened by the camera board's output filter, which smooths over several
    /// frames. The velocity filter takes each estimate as the mean velocity over this long.
    pub estimate_horizon: Duration,
    /// [`VelocitySource::KalmanFits`]: the time span a frame's own fit averages over (the
    /// flow horizon `horizon_s`; no filter lag).
    pub fit_horizon: Duration,
    /// Time an estimate spends on the link after the camera board sent it (an `Estimate`
    /// frame of ~40 bytes at 115,200 Bd; its `processing_us` covers capture to sending).
    pub estimate_link: Duration,
    /// Delay of the camera board's output filter: the averaging window ends this long
    /// before the frame's capture. The filter (a velocity random walk on the board) passes a
    /// step in a few frames, so the estimate describes an older, wider window than the flow
    /// horizon alone; fitted in the simulator on tuning seeds (see `docs/parameters.md`).
    pub estimate_filter_lag: Duration,
    /// Estimates are not used for the velocity while the gyro's yaw rate is above this, rad/s
    /// (Edge-FS flow is unreliable under fast yaw; the observer dead-reckons instead). They
    /// still count as valid for the failsafe (the camera board is alive).
    pub max_yaw_rate_radps: f32,
    /// Estimates are not used for the velocity below this height, m: near the floor the view
    /// is mostly floor nearer than the stereo range, and a wrong take-off estimate teaches the
    /// velocity filter a wrong bias. They still count as valid for the failsafe.
    pub min_vision_height_m: f32,
    /// Estimates are not used for the velocity while the drone climbs or descends faster than
    /// this, m/s: Edge-FS takes all image motion for horizontal translation, and a climb over a
    /// floor seen in perspective moves its edges sideways as a forward flight would (in a room
    /// with plain walls a take-off read as 1.1 m/s forward). They still count as valid for the
    /// failsafe.
    pub max_vision_climb_mps: f32,
    /// ... unless the view has at least this fraction of its columns with a stereo depth
    /// (0..1): textured walls in range move as the scene does, only a view of little but the
    /// floor reads a climb as forward flight.
    pub vision_climb_min_depth: f32,
    /// A valid estimate counts (for the velocity and for the failsafe) only as the
    /// `min_valid_run`-th or later of an unbroken run of valid ones. On a textured view nearly
    /// every frame is valid; a lone valid frame among invalid ones comes from a scrap of
    /// texture (the floor's perspective lines at the bottom of a view of a plain wall, which
    /// pitch and heave move sideways as forward flight would) and was seen 1 m/s wrong.
    pub min_valid_run: u8,
    /// ... nor until this long after the yaw rate was last above the limit (covers the
    /// exposure-to-arrival latency and the estimator's history).
    pub yaw_settle: Duration,
}

impl Default for EstimationConfig {
    fn default() -> Self {
        Self {
            min_quality: 0,
            median_reset_gap: Duration::from_millis(500),
            max_estimate_mps: 5.0,
            max_velocity_jump_mps: 0.6,
            max_consecutive_outliers: 3,
            velocity_max_age: Duration::from_millis(2_500),
            observer: ObserverConfig::default(),
            velocity_source: VelocitySource::Kalman,
            velocity_kf: VelocityKfConfig::default(),
            estimate_horizon: Duration::from_millis(350),
            fit_horizon: Duration::from_millis(250),
            estimate_link: Duration::from_micros(3_500),
            estimate_filter_lag: Duration::from_millis(97),
            max_yaw_rate_radps: 0.6,
            min_vision_height_m: 0.6,
            max_vision_climb_mps: 0.25,
            vision_climb_min_depth: 0.9,
            min_valid_run: 3,
            yaw_settle: Duration::from_millis(150),
        }
    }
}

/// The velocity estimate guidance flies on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VelocitySource {
    /// [`VelocityKf`]: every gated estimate (the camera board's filtered output), weighted by
    /// its quality, against the predicted mean over the time window it describes.
    Kalman,
    /// The paper's path: median-5 of the gated estimates into the [`VelocityObserver`].
    MedianObserver,
    /// [`VelocityKf`] on each frame's own fit ([`protocol::Estimate::fit`]) instead of the
    /// board's filtered output, over the flow window [`EstimationConfig::fit_horizon`]: 2x
    /// less velocity error in most simulated flights (0.02 against 0.045 m/s RMS), but a
    /// frame's fit can alias to the wrong sign when the flow outruns the search (seen above
    /// 0.5 m/s), and runs of such fits have thrown the filter off; not the default.
    KalmanFits,
}

impl VelocitySource {
    /// True for the two Kalman-filter sources.
    pub fn is_kalman(self) -> bool {
        matches!(self, Self::Kalman | Self::KalmanFits)
    }
}

/// True for an invalid estimate whose only faults are the flow's (a poor fit, no flow match):
/// its image has texture and stereo depth.
fn spoiled_by_rotation(est: &Estimate) -> bool {
    let flow = EstimateFlags::POOR_FIT.0 | EstimateFlags::NO_FLOW_MATCH.0;
    est.flags.0 != 0 && est.flags.0 & !flow == 0
}

/// What the autopilot knew when an estimate arrived.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionContext {
    /// Arrival time.
    pub now: Instant,
    /// Height above the floor, m.
    pub height_m: f32,
    /// Climb rate, m/s (up positive).
    pub climb_mps: f32,
}

/// The gate an estimate stopped at (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gate {
    /// Invalid: flags, quality, or a velocity not finite or too large. It counts for nothing
    /// and ends the run of valid ones.
    Invalid,
    /// Valid, but too early in a run of valid ones: it counts for nothing.
    ShortRun,
    /// Valid for the failsafe; too low, or climbing or descending too fast, for the velocity.
    Height,
    /// Valid for the failsafe; taken under or just after fast yaw, not for the velocity (an
    /// estimate invalid only because a turn spoiled its flow fit stops here too).
    Yaw,
    /// Skipped by the plausibility gate before the median; it does not count for the
    /// failsafe (the Kalman filter, behind its own gate, may have taken it).
    Outlier,
    /// Through every gate: into the median (and the observer in paper mode).
    Passed,
}

/// The velocity guidance flies on, at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityState {
    /// `[forward, sideways]` body velocity, m/s (`None` before the first estimate taken).
    pub velocity_mps: Option<[f32; 2]>,
    /// When the velocity source last took an estimate.
    pub last_fix: Option<Instant>,
}

impl VelocityState {
    /// True if the source took an estimate at most `max_age` before `now`.
    pub fn fixed_within(&self, now: Instant, max_age: Duration) -> bool {
        matches!(self.last_fix, Some(t) if now.since(t) <= max_age)
    }

    /// The velocity, if the source took an estimate at most `max_age` before `now`.
    pub fn fresh(&self, now: Instant, max_age: Duration) -> Option<[f32; 2]> {
        if self.fixed_within(now, max_age) {
            self.velocity_mps
        } else {
            None
        }
    }
}

/// Gates, median-5, observer and Kalman filter over the Edge-FS velocities.
#[derive(Debug, Clone)]
pub struct VelocityEstimation {
    median: VelocityMedian,
    observer: VelocityObserver,
    /// When the observer last took a median output.
    last_fused: Option<Instant>,
    kf: VelocityKf,
    /// When the Kalman filter last took an estimate (or was held still on the ground).
    last_kf_fused: Option<Instant>,
    last_fast_yaw: Option<Instant>,
    yaw_gated_total: u32,
    /// When the last estimate valid for the failsafe arrived.
    last_valid_estimate: Option<Instant>,
    /// The median's output.
    velocity: Option<[f32; 2]>,
    estimates_received: u32,
    outliers_in_a_row: u8,
    /// Valid estimates in a row (saturating), see [`EstimationConfig::min_valid_run`].
    valid_run: u8,
    last_outlier: [f32; 2],
    outliers_total: u32,
}

impl VelocityEstimation {
    /// Nothing estimated yet; the observer and the Kalman filter from `cfg`.
    pub fn new(cfg: &EstimationConfig) -> Self {
        Self {
            median: VelocityMedian::default(),
            observer: VelocityObserver::new(cfg.observer),
            last_fused: None,
            kf: VelocityKf::new(cfg.velocity_kf),
            last_kf_fused: None,
            last_fast_yaw: None,
            yaw_gated_total: 0,
            last_valid_estimate: None,
            velocity: None,
            estimates_received: 0,
            outliers_in_a_row: 0,
            valid_run: 0,
            last_outlier: [0.0; 2],
            outliers_total: 0,
        }
    }

    /// Takes the observer's and the Kalman filter's parts of a new configuration, keeping the
    /// state (the gates read theirs at every call).
    pub fn set_config(&mut self, cfg: &EstimationConfig) {
        self.observer.set_config(cfg.observer);
        self.kf.set_config(cfg.velocity_kf);
    }

    /// 512 Hz: the configured source predicts over `dt` s from the attitude (`roll`, `pitch`,
    /// rad) and the gyro's `yaw_rate` (rad/s); a yaw rate above
    /// [`EstimationConfig::max_yaw_rate_radps`] starts the yaw gate's settle time.
    #[inline]
    pub fn predict(
        &mut self,
        roll: f32,
        pitch: f32,
        yaw_rate: f32,
        dt: f32,
        now: Instant,
        cfg: &EstimationConfig,
    ) {
        match cfg.velocity_source {
            VelocitySource::Kalman | VelocitySource::KalmanFits => {
                self.kf.predict(roll, pitch, yaw_rate, dt, now)
            }
            VelocitySource::MedianObserver => self.observer.predict(roll, pitch, yaw_rate, dt, now),
        }
        if yaw_rate.abs() > cfg.max_yaw_rate_radps {
            self.last_fast_yaw = Some(now);
        }
    }

    /// One Edge-FS estimate through the gates (see the module documentation).
    pub fn on_estimate(
        &mut self,
        est: &Estimate,
        ctx: &VisionContext,
        cfg: &EstimationConfig,
    ) -> Gate {
        let now = ctx.now;
        self.estimates_received = self.estimates_received.wrapping_add(1);
        // What the frame says of the velocity: the board's output, or with
        // `VelocitySource::KalmanFits` the frame's own fit.
        let fits = cfg.velocity_source == VelocitySource::KalmanFits;
        let measured = match (fits, est.fit) {
            (true, Some(fit)) => Some(([fit.forward_mps, fit.sideways_mps], fit.quality)),
            (true, None) => None,
            (false, _) => est
                .is_valid()
                .then_some(([est.forward_mps, est.sideways_mps], est.quality)),
        };
        let lim = cfg.max_estimate_mps;
        let usable = |(v, q): &([f32; 2], u8)| {
            *q >= cfg.min_quality && v.iter().all(|x| x.is_finite() && x.abs() <= lim)
        };
        let Some((v, quality)) = measured.filter(usable) else {
            self.valid_run = 0;
            // The flow window of the estimate (and the settle time) reaches back into a turn.
            let horizon = if fits {
                cfg.fit_horizon
            } else {
                cfg.estimate_horizon
            };
            let turned = self.fast_yaw_within(now, cfg.yaw_settle + horizon);
            if turned && spoiled_by_rotation(est) {
                // Not blindness: it keeps the failsafe quiet, as a valid estimate under yaw.
                self.yaw_gated_total = self.yaw_gated_total.wrapping_add(1);
                self.last_valid_estimate = Some(now);
                return Gate::Yaw;
            }
            return Gate::Invalid;
        };
        self.valid_run = self.valid_run.saturating_add(1);
        if self.valid_run < cfg.min_valid_run {
            return Gate::ShortRun;
        }
        let gap = match self.last_valid_estimate {
            Some(t) => now.since(t) > cfg.median_reset_gap,
            None => true,
        };
        if gap {
            self.median.reset();
            self.outliers_in_a_row = 0;
        }
        let depth = f32::from(est.depth_coverage) / f32::from(u8::MAX);
        let climbing =
            ctx.climb_mps.abs() > cfg.max_vision_climb_mps && depth < cfg.vision_climb_min_depth;
        if ctx.height_m < cfg.min_vision_height_m || climbing {
            // Valid for the failsafe, not for the velocity (see `min_vision_height_m` and
            // `max_vision_climb_mps`).
            self.median.reset();
            self.outliers_in_a_row = 0;
            self.last_valid_estimate = Some(now);
            return Gate::Height;
        }
        if self.fast_yaw_within(now, cfg.yaw_settle) {
            // Valid for the failsafe, not for the velocity; the median restarts after the
            // turn (its samples are in the old heading).
            self.yaw_gated_total = self.yaw_gated_total.wrapping_add(1);
            self.median.reset();
            self.outliers_in_a_row = 0;
            self.last_valid_estimate = Some(now);
            return Gate::Yaw;
        }
        // The Kalman filter has its own innovation gate; it takes the estimate as the mean
        // velocity over the window it describes: for the board's output the flow window
        // widened by the board's filter and ending its lag before the frame's capture, for a
        // frame's own fit the flow window ending at the capture.
        let (lag, horizon) = if fits {
            (Duration::ZERO, cfg.fit_horizon)
        } else {
            (cfg.estimate_filter_lag, cfg.estimate_horizon)
        };
        let end =
            now - Duration::from_micros(u64::from(est.processing_us)) - cfg.estimate_link - lag;
        let start = end - horizon;
        if cfg.velocity_source.is_kalman()
            && matches!(
                self.kf.correct(v, quality, start, end),
                Fusion::Fused | Fusion::Initialised
            )
        {
            self.last_kf_fused = Some(now);
        }
        let jump = cfg.max_velocity_jump_mps;
        let outlier = match self.median.output() {
            Some([f, s]) => (v[0] - f).abs() > jump || (v[1] - s).abs() > jump,
            None => false,
        };
        if outlier {
            let [f, s] = self.last_outlier;
            let agrees =
                self.outliers_in_a_row > 0 && (v[0] - f).abs() <= jump && (v[1] - s).abs() <= jump;
            let run = if agrees { self.outliers_in_a_row } else { 0 };
            if run < cfg.max_consecutive_outliers {
                self.outliers_in_a_row = run + 1;
                self.last_outlier = [v[0], v[1]];
                self.outliers_total = self.outliers_total.wrapping_add(1);
                return Gate::Outlier;
            }
        }
        if outlier {
            self.median.reset();
        }
        self.outliers_in_a_row = 0;
        self.velocity = self.median.push(v[0], v[1]);
        if let (Some(v), VelocitySource::MedianObserver) = (self.velocity, cfg.velocity_source) {
            self.observer.correct(v, now);
            self.last_fused = Some(now);
        }
        self.last_valid_estimate = Some(now);
        Gate::Passed
    }

    /// True when the yaw rate was above the limit within `window` before `now`.
    fn fast_yaw_within(&self, now: Instant, window: Duration) -> bool {
        matches!(self.last_fast_yaw, Some(t) if now.since(t) <= window)
    }

    /// On the ground and still (disarmed): the Kalman filter holds zero velocity, whatever the
    /// camera makes of the view, and counts as fixed at `now`.
    pub fn hold_still(&mut self, now: Instant) {
        self.kf.hold_still(now);
        self.last_kf_fused = Some(now);
    }

    /// The camera board reports its camera stopped: no valid estimate since (until the next).
    pub fn camera_stopped(&mut self) {
        self.last_valid_estimate = None;
    }

    /// The velocity of `source` and when it last took an estimate.
    pub fn state(&self, source: VelocitySource) -> VelocityState {
        match source {
            VelocitySource::Kalman | VelocitySource::KalmanFits => VelocityState {
                velocity_mps: self.kf.velocity(),
                last_fix: self.last_kf_fused,
            },
            VelocitySource::MedianObserver => VelocityState {
                velocity_mps: self.observer.velocity(),
                last_fix: self.last_fused,
            },
        }
    }

    /// When the last estimate valid for the failsafe arrived.
    pub fn last_valid_estimate(&self) -> Option<Instant> {
        self.last_valid_estimate
    }

    /// The median-5's `[forward, sideways]` output, m/s (`None` before the first estimate
    /// through every gate).
    pub fn median_velocity(&self) -> Option<[f32; 2]> {
        self.velocity
    }

    /// The horizontal velocity Kalman filter.
    pub fn kf(&self) -> &VelocityKf {
        &self.kf
    }

    /// The velocity observer of the paper's path.
    pub fn observer(&self) -> &VelocityObserver {
        &self.observer
    }

    /// Estimates received since boot (valid or not, wrapping).
    pub fn estimates_received(&self) -> u32 {
        self.estimates_received
    }

    /// Valid estimates skipped by the plausibility gate since boot (wrapping).
    pub fn outliers(&self) -> u32 {
        self.outliers_total
    }

    /// Valid estimates not used for the velocity because of fast yaw since boot (wrapping).
    pub fn yaw_gated(&self) -> u32 {
        self.yaw_gated_total
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;
    use crate::test_support::forward_estimate;
    use crate::AutopilotConfig;
    use protocol::EstimateFlags;

    /// Level at 1 m at `now_us`: nothing but the estimate itself gates it.
    fn level(now_us: u64) -> VisionContext {
        VisionContext {
            now: at(now_us),
            height_m: 1.0,
            climb_mps: 0.0,
        }
    }

    /// A stage and the configuration it runs on, fed one estimate per 25 Hz frame.
    struct Feed {
        cfg: AutopilotConfig,
        est: VelocityEstimation,
        t: u64,
    }

    impl Feed {
        fn new(source: VelocitySource) -> Self {
            let mut cfg = AutopilotConfig::default();
            cfg.estimation.velocity_source = source;
            Self {
                est: VelocityEstimation::new(&cfg.estimation),
                cfg,
                t: 0,
            }
        }

        /// The next frame's estimate in `ctx` (its time set to the frame's).
        fn frame(&mut self, e: &Estimate, ctx: VisionContext) -> Gate {
            self.t += 40_000;
            let ctx = VisionContext {
                now: at(self.t),
                ..ctx
            };
            self.est.on_estimate(e, &ctx, &self.cfg.estimation)
        }

        fn level(&mut self, forward_mps: f32) -> Gate {
            self.frame(&forward_estimate(forward_mps), level(0))
        }
    }

    /// Lone valid estimates among invalid ones (a scrap of texture on a plain view) count for
    /// nothing, neither for the velocity nor for the failsafe; a run of them does.
    #[test]
    fn a_valid_estimate_counts_only_within_a_run_of_valid_ones() {
        let mut f = Feed::new(VelocitySource::MedianObserver);
        let run = f.cfg.estimation.min_valid_run;
        assert!(run >= 2);
        let mut invalid = forward_estimate(1.1);
        invalid.flags = EstimateFlags::NO_FLOW_MATCH;
        for k in 0..40 {
            if k % u32::from(run) == 0 {
                assert_eq!(f.frame(&invalid, level(0)), Gate::Invalid);
            } else {
                assert_eq!(f.level(1.1), Gate::ShortRun);
            }
        }
        assert_eq!(f.est.median_velocity(), None);
        assert_eq!(f.est.last_valid_estimate(), None);
        for _ in 1..run {
            assert_eq!(f.level(0.3), Gate::ShortRun);
        }
        assert_eq!(f.level(0.3), Gate::Passed);
        assert_eq!(f.est.last_valid_estimate(), Some(at(f.t)));
        assert_eq!(f.est.median_velocity(), Some([0.3, 0.0]));
        assert_eq!(f.est.estimates_received(), 40 + u32::from(run));
    }

    #[test]
    fn garbage_and_low_quality_are_invalid() {
        let mut f = Feed::new(VelocitySource::Kalman);
        f.cfg.estimation.min_quality = 100;
        let poor = Estimate {
            quality: 99,
            ..forward_estimate(0.1)
        };
        assert_eq!(f.frame(&poor, level(0)), Gate::Invalid);
        assert_eq!(f.level(f32::NAN), Gate::Invalid);
        assert_eq!(
            f.level(f.cfg.estimation.max_estimate_mps + 0.1),
            Gate::Invalid
        );
        assert_eq!(f.est.last_valid_estimate(), None);
    }

    /// Near the floor, and while the height changes fast over a view mostly without depth,
    /// estimates keep the failsafe quiet but do not reach the velocity.
    #[test]
    fn too_low_or_climbing_counts_for_the_failsafe_only() {
        // A quarter of the view with depth: little but the floor.
        let shallow = Estimate {
            depth_coverage: 64,
            ..forward_estimate(0.4)
        };
        for source in [VelocitySource::Kalman, VelocitySource::MedianObserver] {
            let mut f = Feed::new(source);
            let low = VisionContext {
                height_m: f.cfg.estimation.min_vision_height_m - 0.01,
                ..level(0)
            };
            let climbing = VisionContext {
                climb_mps: f.cfg.estimation.max_vision_climb_mps + 0.01,
                ..level(0)
            };
            let descending = VisionContext {
                climb_mps: -climbing.climb_mps,
                ..level(0)
            };
            for ctx in [low, climbing, descending] {
                for _ in 0..10 {
                    f.frame(&shallow, ctx);
                }
                assert_eq!(f.frame(&shallow, ctx), Gate::Height);
                assert_eq!(f.est.last_valid_estimate(), Some(at(f.t)));
                assert_eq!(f.est.median_velocity(), None);
                assert_eq!(f.est.state(source).velocity_mps, None);
                assert_eq!(f.est.state(source).last_fix, None);
            }
            // Level at height, the same estimates are taken.
            assert_eq!(f.level(0.4), Gate::Passed);
            assert_eq!(f.est.median_velocity(), Some([0.4, 0.0]));
            assert_eq!(f.est.state(source).last_fix, Some(at(f.t)));
            // Climbing over a view with depth at least `vision_climb_min_depth`: taken too.
            let deep = Estimate {
                depth_coverage: (f.cfg.estimation.vision_climb_min_depth * 255.0).ceil() as u8,
                ..forward_estimate(0.4)
            };
            assert_eq!(f.frame(&deep, climbing), Gate::Passed);
            assert_eq!(f.est.state(source).last_fix, Some(at(f.t)));
        }
    }

    #[test]
    fn velocity_outliers_are_gated_and_a_real_change_is_followed() {
        let mut f = Feed::new(VelocitySource::MedianObserver);
        let mut feed = |v: f32| {
            let gate = f.level(v);
            (gate, f.est.median_velocity().map_or(f32::NAN, |v| v[0]))
        };
        for _ in 0..5 {
            feed(0.3);
        }
        // Two spikes in a row (the median-5 alone would follow the second one to -1.8).
        assert_eq!(feed(-1.7), (Gate::Outlier, 0.3));
        assert_eq!(feed(-1.9), (Gate::Outlier, 0.3));
        assert_eq!(feed(0.32), (Gate::Passed, 0.3));
        // Outliers that disagree with each other never restart the filter.
        for v in [1.5, -1.5, 1.5, -1.5, 1.5] {
            assert_eq!(feed(v), (Gate::Outlier, 0.3));
        }
        // A sustained change: after three agreeing outliers the filter restarts from the new
        // value.
        for _ in 0..2 {
            assert_eq!(feed(1.5), (Gate::Outlier, 0.3));
        }
        assert_eq!(feed(1.45), (Gate::Passed, 1.45));
        assert_eq!(f.est.outliers(), 9);
    }

    #[test]
    fn a_gap_in_the_valid_estimates_restarts_the_median() {
        let mut f = Feed::new(VelocitySource::MedianObserver);
        for _ in 0..5 {
            f.level(0.3);
        }
        f.t += f.cfg.estimation.median_reset_gap.as_micros();
        // Far from the old output, but the old output is gone.
        assert_eq!(f.level(1.5), Gate::Passed);
        assert_eq!(f.est.median_velocity(), Some([1.5, 0.0]));
        assert_eq!(f.est.outliers(), 0);
    }

    #[test]
    fn estimates_under_fast_yaw_are_not_fused_but_keep_the_failsafe_quiet() {
        let cfg = AutopilotConfig::default();
        let mut est = VelocityEstimation::new(&cfg.estimation);
        let mut t = 0;
        // `dt_us` of prediction at `yaw_rate`, then an estimate of `v` forward.
        let mut step = |est: &mut VelocityEstimation, yaw_rate: f32, v: f32, dt_us: u64| {
            t += dt_us;
            est.predict(
                0.0,
                0.0,
                yaw_rate,
                dt_us as f32 * 1e-6,
                at(t),
                &cfg.estimation,
            );
            (
                est.on_estimate(&forward_estimate(v), &level(t), &cfg.estimation),
                t,
            )
        };
        let velocity = |est: &VelocityEstimation| est.state(VelocitySource::Kalman).velocity_mps;
        // Long enough for the estimates' windows (about 0.5 s old) to lie after the filter's
        // start.
        for _ in 0..60 {
            step(&mut est, 0.0, 0.2, 20_000);
        }
        let v0 = velocity(&est).unwrap()[0];
        assert!((v0 - 0.2).abs() < 0.01, "{v0}");
        // Turning at 1.5 rad/s: the (garbage) estimates are counted valid but not fused.
        for _ in 0..20 {
            let (gate, now) = step(&mut est, 1.5, 2.5, 20_000);
            assert_eq!(gate, Gate::Yaw);
            assert_eq!(est.last_valid_estimate(), Some(at(now)));
        }
        assert_eq!(est.yaw_gated(), 20);
        assert_eq!(est.outliers(), 0);
        let v = velocity(&est).unwrap();
        assert!(v.iter().all(|x| x.abs() < 0.25), "{v:?}");
        // Right after the turn the estimates are still skipped for the settle time, then
        // fused again.
        assert_eq!(step(&mut est, 0.0, 0.0, 20_000).0, Gate::Yaw);
        for _ in 0..20 {
            step(&mut est, 0.0, 0.0, 40_000);
        }
        assert_eq!(est.yaw_gated(), 24);
        let v = velocity(&est).unwrap();
        assert!(v[0].abs() < 0.05, "{v:?}");
    }

    /// After a turn the camera board flags the fits whose flow window spans it (`POOR_FIT`,
    /// no flow match): they keep the failsafe quiet until the window has passed the turn; a
    /// blind frame does not, and neither do spoiled fits when the drone has not turned.
    #[test]
    fn fits_spoiled_by_a_turn_keep_the_failsafe_quiet() {
        let cfg = AutopilotConfig::default();
        let mut est = VelocityEstimation::new(&cfg.estimation);
        let with_flags = |flags: u8| Estimate {
            flags: EstimateFlags(flags),
            ..forward_estimate(0.0)
        };
        let spoiled = with_flags(EstimateFlags::POOR_FIT.0 | EstimateFlags::NO_FLOW_MATCH.0);
        let blind = with_flags(EstimateFlags::POOR_FIT.0 | EstimateFlags::NO_TEXTURE.0);
        let mut t = 1_000_000;
        // Not turning: a spoiled fit is invalid and leaves the failsafe's clock alone.
        est.predict(0.0, 0.0, 0.0, 0.02, at(t), &cfg.estimation);
        assert_eq!(
            est.on_estimate(&spoiled, &level(t), &cfg.estimation),
            Gate::Invalid
        );
        assert_eq!(est.last_valid_estimate(), None);
        // Turning: it counts for the failsafe (not for the velocity); a blind frame does not.
        t += 20_000;
        est.predict(0.0, 0.0, 1.5, 0.02, at(t), &cfg.estimation);
        assert_eq!(
            est.on_estimate(&spoiled, &level(t), &cfg.estimation),
            Gate::Yaw
        );
        assert_eq!(est.last_valid_estimate(), Some(at(t)));
        assert_eq!(est.yaw_gated(), 1);
        assert_eq!(
            est.on_estimate(&blind, &level(t + 1), &cfg.estimation),
            Gate::Invalid
        );
        assert_eq!(est.last_valid_estimate(), Some(at(t)));
        // Until the flow window has left the turn behind, and no longer.
        let window = (cfg.estimation.yaw_settle + cfg.estimation.estimate_horizon).as_micros();
        let (inside, after) = (t + window, t + window + 1);
        est.predict(0.0, 0.0, 0.0, 0.02, at(inside), &cfg.estimation);
        assert_eq!(
            est.on_estimate(&spoiled, &level(inside), &cfg.estimation),
            Gate::Yaw
        );
        assert_eq!(
            est.on_estimate(&spoiled, &level(after), &cfg.estimation),
            Gate::Invalid
        );
        assert_eq!(est.last_valid_estimate(), Some(at(inside)));
        assert_eq!(est.state(VelocitySource::Kalman).last_fix, None);
    }

    #[test]
    fn the_state_is_the_configured_source_and_its_last_fix() {
        let mut f = Feed::new(VelocitySource::Kalman);
        for _ in 0..3 {
            f.level(0.3);
        }
        let kf = f.est.state(VelocitySource::Kalman);
        assert_eq!(kf.last_fix, Some(at(f.t)));
        assert!(kf.velocity_mps.is_some());
        assert!(kf.fixed_within(at(f.t + 100), Duration::from_micros(100)));
        assert!(!kf.fixed_within(at(f.t + 101), Duration::from_micros(100)));
        assert_eq!(kf.fresh(at(f.t + 101), Duration::from_micros(100)), None);
        assert_eq!(kf.fresh(at(f.t), Duration::from_micros(0)), kf.velocity_mps);
        // The observer runs only in paper mode.
        assert_eq!(f.est.state(VelocitySource::MedianObserver).last_fix, None);
        // Held still on the ground: zero, fixed now.
        f.est.hold_still(at(5_000_000));
        let held = f.est.state(VelocitySource::Kalman);
        assert_eq!(held.velocity_mps, Some([0.0, 0.0]));
        assert_eq!(held.last_fix, Some(at(5_000_000)));
        // A stopped camera ends the failsafe's valid estimates at once.
        assert!(f.est.last_valid_estimate().is_some());
        f.est.camera_stopped();
        assert_eq!(f.est.last_valid_estimate(), None);
    }
}
