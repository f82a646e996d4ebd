//! Horizontal velocity Kalman filter: the IMU-driven quadrotor model predicts, every Edge-FS
//! measurement corrects, weighted by its quality and taken at the time it describes.
//!
//! State per axis of the heading frame (forward, right): velocity `v` and an acceleration bias
//! `b` (tilt-estimate offsets, a centre-of-gravity trim, a steady draught). The model between
//! measurements is the one [`crate::guidance::VelocityObserver`] uses: thrust holding the height
//! tilts into `a_fwd = -g tan(pitch)`, `a_right = g tan(roll) / cos(pitch)`, linear rotor drag
//! `-k v`, the bias, and the heading frame turning under a room-fixed velocity with the yaw rate.
//! The bias turns with it ([`VelocityKfConfig::bias_in_room_frame`]): its main part is the
//! attitude estimate's tilt error, which a yaw leaves fixed in the room.
//!
//! What a measurement is: Edge-FS fits the flow over its horizon (a quarter of a second by
//! default), so each velocity is the *mean* velocity over `[capture - horizon, capture]`, and it
//! reaches the autopilot after the board's processing and the link. The filter keeps a short
//! history of its own prediction and compares the measurement with the predicted mean over that
//! same window (the innovation), instead of with the velocity of the moment it arrives. The gain
//! comes from the current covariance (the classic approximation for a delayed measurement whose
//! delay is short against the dynamics), and the correction shifts the history with the state so
//! that the next innovation does not count it again.
//!
//! Both axes have the same model and the same measurement noise, so they share one 2 x 2
//! covariance (a rotation by the yaw rate leaves an isotropic covariance unchanged): the 512 Hz
//! prediction costs a few multiply-adds more than the observer's.
//!
//! Measurement noise falls with quality: `sigma = sigma_best * 255 / max(quality, min)`. An
//! innovation beyond [`VelocityKfConfig::gate_sigmas`] standard deviations is rejected and
//! counted; [`VelocityKfConfig::reinit_after`] rejections in a row that agree with each other
//! mean the filter, not the camera, is wrong (a wrong prior after a long gap), and it restarts
//! from the measurement.

use crate::velocity_model::{
    heading_frame_step, tilt_acceleration, VelocityHistory, HISTORY_SPACING, MAX_SPEED_MPS,
};
use timebase::{Duration, Instant};

/// Tunables of [`VelocityKf`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityKfConfig {
    /// Linear drag of the airframe per unit mass, 1/s.
    pub drag_per_s: f32,
    /// Process noise of the acceleration model (tilt errors, gusts), (m/s²)/√Hz.
    pub accel_noise: f32,
    /// Random walk of the acceleration bias, (m/s²)/√s.
    pub bias_walk: f32,
    /// Standard deviation of the initial bias, m/s².
    pub initial_bias_sigma: f32,
    /// Largest bias the filter may hold per axis, m/s².
    pub max_bias_mps2: f32,
    /// Measurement noise of an estimate of the best quality (255), m/s.
    pub sigma_best_mps: f32,
    /// Quality below which the noise stops growing (the estimate is weighted as this one).
    pub min_quality: u8,
    /// Innovation gate, standard deviations of the innovation.
    pub gate_sigmas: f32,
    /// This many gated measurements in a row, agreeing among themselves within the gate,
    /// restart the filter from the last one.
    pub reinit_after: u8,
    /// Tilt used in the model is limited to this, rad.
    pub max_tilt_rad: f32,
    /// The bias is held in the room frame: it turns in the heading frame with the yaw rate, as
    /// the velocity does. An attitude estimate's tilt error, the bias's main part, stays fixed
    /// in the room while the drone yaws (the gyro turns the estimate and the truth alike); held
    /// in the heading frame instead, the bias learnt before a turn is wrong after it.
    pub bias_in_room_frame: bool,
}

impl Default for VelocityKfConfig {
    fn default() -> Self {
        Self {
            drag_per_s: 0.2,
            accel_noise: 0.35,
            bias_walk: 0.02,
            initial_bias_sigma: 0.3,
            max_bias_mps2: 0.8,
            sigma_best_mps: 0.06,
            min_quality: 32,
            gate_sigmas: 4.0,
            reinit_after: 4,
            max_tilt_rad: 0.5,
            bias_in_room_frame: true,
        }
    }
}

/// What [`VelocityKf::correct`] did with a measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fusion {
    /// The first measurement (or one after a restart): the filter starts from it.
    Initialised,
    /// Fused.
    Fused,
    /// Outside the innovation gate: not used (counted).
    Rejected,
    /// Not a usable measurement (non-finite, or a window the history cannot place).
    Ignored,
}

/// History slots (one at least every 6 ms).
const HISTORY_LEN: usize = 200;

/// The oldest window start the filter can always place, before the newest prediction
/// (199 spacings: 1.194 s). [`crate::params::validate`] keeps the estimate's window within it.
pub const MAX_WINDOW_AGE: Duration = HISTORY_SPACING.saturating_mul(HISTORY_LEN as u64 - 1);

/// The filter. Fixed size, no heap.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityKf {
    cfg: VelocityKfConfig,
    v: [f32; 2],
    bias: [f32; 2],
    /// Shared covariance of (v, b): [p_vv, p_vb, p_bb].
    p: [f32; 3],
    initialised: bool,
    history: VelocityHistory<HISTORY_LEN>,
    rejected_in_a_row: u8,
    last_rejected: [f32; 2],
    rejected_total: u32,
}

impl VelocityKf {
    /// A filter without a velocity yet.
    pub fn new(cfg: VelocityKfConfig) -> Self {
        let sb = cfg.initial_bias_sigma;
        Self {
            cfg,
            v: [0.0; 2],
            bias: [0.0; 2],
            p: [1.0, 0.0, sb * sb],
            initialised: false,
            history: VelocityHistory::new(),
            rejected_in_a_row: 0,
            last_rejected: [0.0; 2],
            rejected_total: 0,
        }
    }

    /// Takes a new configuration, keeping the state (used from the next step on).
    pub fn set_config(&mut self, cfg: VelocityKfConfig) {
        self.cfg = cfg;
    }

    /// The configuration.
    pub fn config(&self) -> &VelocityKfConfig {
        &self.cfg
    }

    /// `[forward, right]` velocity, m/s (`None` before the first measurement).
    pub fn velocity(&self) -> Option<[f32; 2]> {
        self.initialised.then_some(self.v)
    }

    /// Standard deviation of the velocity (each axis), m/s.
    pub fn velocity_sigma(&self) -> f32 {
        libm::sqrtf(self.p[0].max(0.0))
    }

    /// Learned acceleration bias `[forward, right]`, m/s².
    pub fn bias(&self) -> [f32; 2] {
        self.bias
    }

    /// Measurements rejected by the innovation gate since start.
    pub fn rejected(&self) -> u32 {
        self.rejected_total
    }

    /// Forgets the velocity; the learned bias stays, with its uncertainty.
    pub fn reset(&mut self) {
        let (bias, p_bb, rejected) = (self.bias, self.p[2], self.rejected_total);
        *self = Self::new(self.cfg);
        self.bias = bias;
        self.p[2] = p_bb;
        self.rejected_total = rejected;
    }

    /// Standing on the floor (motors off): the velocity is known to be zero, whatever the
    /// camera says about a blank wall.
    pub fn hold_still(&mut self, now: Instant) {
        self.v = [0.0; 2];
        self.p[0] = 1e-4;
        self.p[1] = 0.0;
        self.initialised = true;
        // Held since forever, as far as any later window is concerned.
        self.history.fill(Instant::ZERO, [0.0; 2], now);
        self.rejected_in_a_row = 0;
    }

    /// Prediction over `dt` s ending at `now` from the estimated roll and pitch (rad) and
    /// the yaw rate (rad/s, body z down: positive turns right). Non-finite inputs skip it.
    pub fn predict(&mut self, roll: f32, pitch: f32, yaw_rate: f32, dt: f32, now: Instant) {
        if !(roll.is_finite() && pitch.is_finite() && yaw_rate.is_finite() && dt.is_finite()) {
            return;
        }
        let dt = dt.clamp(0.0, 0.05);
        if self.initialised {
            let [ax, ay] = tilt_acceleration(roll, pitch, self.cfg.max_tilt_rad);
            let a = [ax + self.bias[0], ay + self.bias[1]];
            let k = self.cfg.drag_per_s.max(0.0);
            if let Some(v) = heading_frame_step(self.v, a, k, yaw_rate, dt) {
                self.v = v;
            }
            if self.cfg.bias_in_room_frame {
                // The same frame turn, without drag or forcing: the bias keeps its room
                // direction (an isotropic covariance is unchanged by it).
                if let Some(b) = heading_frame_step(self.bias, [0.0; 2], 0.0, yaw_rate, dt) {
                    let lim = self.cfg.max_bias_mps2.abs();
                    self.bias = b.map(|x| x.clamp(-lim, lim));
                }
            }
            // P <- F P F' + Q with F = [[1 - k dt, dt], [0, 1]].
            let f00 = 1.0 - k * dt;
            let [pvv, pvb, pbb] = self.p;
            let qa = self.cfg.accel_noise * self.cfg.accel_noise * dt;
            let qb = self.cfg.bias_walk * self.cfg.bias_walk * dt;
            let n_vb = f00 * pvb + dt * pbb;
            let n_vv = f00 * (f00 * pvv + dt * pvb) + dt * n_vb + qa;
            self.p = [n_vv.min(100.0), n_vb, (pbb + qb).min(100.0)];
        }
        self.history.record(now, self.v);
    }

    /// Mean of the recorded prediction over `[start, end]` (the entries inside it, or the
    /// nearest one when the window falls between entries); `None` when the history does not
    /// reach back to the window.
    fn predicted_mean(&self, start: Instant, end: Instant) -> Option<[f32; 2]> {
        let mut sum = [0.0f32; 2];
        let mut n = 0u32;
        let mut newest_before: Option<[f32; 2]> = None;
        let mut reaches_back = false;
        for (t, v) in self.history.newest_first() {
            if t > end {
                continue;
            }
            if t < start {
                newest_before = Some(v);
                reaches_back = true;
                break;
            }
            sum[0] += v[0];
            sum[1] += v[1];
            n += 1;
            if t == start {
                reaches_back = true;
            }
        }
        if !reaches_back {
            return None;
        }
        if n == 0 {
            return newest_before;
        }
        let n = n as f32;
        Some([sum[0] / n, sum[1] / n])
    }

    /// Fuses a `[forward, right]` velocity measurement of Edge-FS quality `quality` that is the
    /// mean velocity over `[start, end]` (autopilot time; the window the flow spans,
    /// ending at the frame's capture).
    pub fn correct(
        &mut self,
        measured: [f32; 2],
        quality: u8,
        start: Instant,
        end: Instant,
    ) -> Fusion {
        if !measured.iter().all(|x| x.is_finite()) || start > end {
            return Fusion::Ignored;
        }
        if !self.initialised {
            self.start_from(measured, end);
            return Fusion::Initialised;
        }
        let Some(then) = self.predicted_mean(start, end) else {
            // Older than the history: the filter cannot place it. A restarted filter (no
            // history yet) starts from it.
            return Fusion::Ignored;
        };
        let q = quality.max(self.cfg.min_quality).max(1) as f32;
        let sigma = self.cfg.sigma_best_mps * 255.0 / q;
        let r = sigma * sigma;
        let [pvv, pvb, pbb] = self.p;
        let s = pvv + r;
        let e = [measured[0] - then[0], measured[1] - then[1]];
        let gate = self.cfg.gate_sigmas * self.cfg.gate_sigmas * s;
        if e[0] * e[0] > gate || e[1] * e[1] > gate {
            let agrees = self.rejected_in_a_row > 0
                && (0..2).all(|i| {
                    let d = measured[i] - self.last_rejected[i];
                    d * d <= gate
                });
            self.rejected_in_a_row = if agrees {
                self.rejected_in_a_row + 1
            } else {
                1
            };
            self.last_rejected = measured;
            self.rejected_total = self.rejected_total.wrapping_add(1);
            if self.rejected_in_a_row >= self.cfg.reinit_after.max(1) {
                self.start_from(measured, end);
                return Fusion::Initialised;
            }
            return Fusion::Rejected;
        }
        self.rejected_in_a_row = 0;
        let (kv, kb) = (pvv / s, pvb / s);
        let blim = self.cfg.max_bias_mps2.abs();
        for (i, &ei) in e.iter().enumerate() {
            let dv = kv * ei;
            self.v[i] = (self.v[i] + dv).clamp(-MAX_SPEED_MPS, MAX_SPEED_MPS);
            self.history.shift(i, dv);
            self.bias[i] = (self.bias[i] + kb * ei).clamp(-blim, blim);
        }
        // P <- (I - K H) P, H = [1, 0].
        self.p = [(1.0 - kv) * pvv, (1.0 - kv) * pvb, pbb - kb * pvb];
        Fusion::Fused
    }

    fn start_from(&mut self, measured: [f32; 2], at: Instant) {
        let r = self.cfg.sigma_best_mps * 255.0 / self.cfg.min_quality.max(1) as f32;
        self.v = measured.map(|x| x.clamp(-MAX_SPEED_MPS, MAX_SPEED_MPS));
        self.p[0] = r * r;
        self.p[1] = 0.0;
        self.initialised = true;
        // The best knowledge of any earlier window is the measurement itself.
        self.history.fill(Instant::ZERO, self.v, at);
        self.rejected_in_a_row = 0;
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::attitude::GRAVITY;
    use crate::test_support::at;

    const DT_US: u64 = 1_953; // 512 Hz

    /// A drone flying a velocity profile; the filter sees its attitude and delayed, windowed,
    /// noisy measurements.
    struct Run {
        kf: VelocityKf,
        t_us: u64,
        v_true: f32,
        /// (time, true velocity) every step, to form measurements.
        truth: std::vec::Vec<(u64, f32)>,
    }

    impl Run {
        fn new(cfg: VelocityKfConfig) -> Self {
            let mut kf = VelocityKf::new(cfg);
            kf.hold_still(at(0));
            Self {
                kf,
                t_us: 0,
                v_true: 0.0,
                truth: std::vec::Vec::new(),
            }
        }

        /// One step with nose-down pitch `pitch` (true), the filter told `pitch + tilt_err`.
        fn step(&mut self, pitch: f32, tilt_err: f32, drag: f32) {
            let dt = DT_US as f32 * 1e-6;
            self.v_true += (-GRAVITY * libm::tanf(pitch) - drag * self.v_true) * dt;
            self.t_us += DT_US;
            self.truth.push((self.t_us, self.v_true));
            self.kf
                .predict(0.0, pitch + tilt_err, 0.0, dt, at(self.t_us));
        }

        /// The true mean over the window ending `delay_us` ago, `horizon_us` long.
        fn window_mean(&self, delay_us: u64, horizon_us: u64) -> (f32, u64, u64) {
            let end = self.t_us.saturating_sub(delay_us);
            let start = end.saturating_sub(horizon_us);
            let xs: std::vec::Vec<f32> = self
                .truth
                .iter()
                .filter(|(t, _)| (start..=end).contains(t))
                .map(|&(_, v)| v)
                .collect();
            (xs.iter().sum::<f32>() / xs.len().max(1) as f32, start, end)
        }
    }

    #[test]
    fn windowed_delayed_measurements_track_an_acceleration_without_lag() {
        // Accelerate for 1 s, then hold: measurements are 0.25 s means arriving 30 ms after
        // the capture. The filter's velocity must follow the truth of *now*, not of the window
        // centre ~155 ms ago.
        let mut run = Run::new(VelocityKfConfig::default());
        let (mut worst_kf, mut worst_window) = (0.0f32, 0.0f32);
        for k in 0..(3 * 512) {
            let pitch = if k < 512 { -0.05 } else { 0.0 };
            run.step(pitch, 0.0, 0.2);
            if k % 20 == 19 {
                let (z, s, e) = run.window_mean(30_000, 250_000);
                run.kf.correct([z, 0.0], 200, at(s), at(e));
                if k > 300 {
                    worst_window = worst_window.max((z - run.v_true).abs());
                }
            }
            if k > 300 {
                let v = run.kf.velocity().unwrap()[0];
                worst_kf = worst_kf.max((v - run.v_true).abs());
            }
        }
        assert!(worst_kf < 0.03, "{worst_kf}");
        // The measurement itself lags the truth by far more while accelerating.
        assert!(worst_window > 0.06, "{worst_window}");
    }

    #[test]
    fn a_tilt_offset_is_learnt_as_bias() {
        // The attitude estimate reads 2 deg nose-up too much: the model predicts braking that
        // does not happen; measurements teach the bias.
        let mut run = Run::new(VelocityKfConfig::default());
        for k in 0..(20 * 512) {
            run.step(-0.02, 0.035, 0.2);
            if k % 20 == 19 {
                let (z, s, e) = run.window_mean(30_000, 250_000);
                run.kf.correct([z, 0.0], 200, at(s), at(e));
            }
        }
        let want = -GRAVITY * libm::tanf(-0.02) - (-GRAVITY * libm::tanf(0.015));
        let b = run.kf.bias()[0];
        assert!((b - want).abs() < 0.05, "bias {b}, expected {want}");
        let v = run.kf.velocity().unwrap()[0];
        assert!((v - run.v_true).abs() < 0.03, "{v} vs {}", run.v_true);
        // And without measurements it now dead-reckons correctly for a second.
        for _ in 0..512 {
            run.step(-0.02, 0.035, 0.2);
        }
        let v = run.kf.velocity().unwrap()[0];
        assert!((v - run.v_true).abs() < 0.06, "{v} vs {}", run.v_true);
    }

    /// The attitude estimate is off by a tilt fixed in the room (an error the gyro carries
    /// through a turn unchanged): the offset learnt while facing north must still hold after a
    /// 90 deg turn made without measurements, as it does for a bias held in the room frame.
    #[test]
    fn a_room_fixed_tilt_offset_survives_a_turn() {
        let dt = DT_US as f32 * 1e-6;
        // The model's acceleration error, m/s², north and east; the drone truly hovers still.
        let err_room = [0.2f32, 0.0];
        let drift_after_turn = |cfg: VelocityKfConfig| {
            let mut kf = VelocityKf::new(cfg);
            kf.hold_still(at(0));
            let (mut t, mut yaw) = (0u64, 0.0f32);
            let mut step = |kf: &mut VelocityKf, rate: f32| {
                yaw += rate * dt;
                t += DT_US;
                let (s, c) = (libm::sinf(yaw), libm::cosf(yaw));
                let a = [
                    c * err_room[0] + s * err_room[1],
                    -s * err_room[0] + c * err_room[1],
                ];
                let pitch = libm::atanf(-a[0] / GRAVITY);
                let roll = libm::atanf(a[1] * libm::cosf(pitch) / GRAVITY);
                kf.predict(roll, pitch, rate, dt, at(t));
                t
            };
            // 20 s facing north with a still drone's zero velocity measured at 25 Hz.
            for k in 0..(20 * 512) {
                let now = step(&mut kf, 0.0);
                if k % 20 == 19 {
                    kf.correct(
                        [0.0; 2],
                        200,
                        at(now.saturating_sub(280_000)),
                        at(now.saturating_sub(30_000)),
                    );
                }
            }
            // A quarter turn at 1 rad/s and 1 s after it, blind.
            for _ in 0..((core::f32::consts::FRAC_PI_2 / dt) as usize) {
                step(&mut kf, 1.0);
            }
            for _ in 0..512 {
                step(&mut kf, 0.0);
            }
            let v = kf.velocity().unwrap();
            libm::sqrtf(v[0] * v[0] + v[1] * v[1])
        };
        let room = drift_after_turn(VelocityKfConfig::default());
        let heading = drift_after_turn(VelocityKfConfig {
            bias_in_room_frame: false,
            ..VelocityKfConfig::default()
        });
        assert!(room < 0.03, "room-frame bias: {room} m/s after the turn");
        // Held in the heading frame, the learnt offset points the wrong way after the turn.
        assert!(heading > 0.2, "heading-frame bias: {heading} m/s");
    }

    #[test]
    fn low_quality_moves_the_estimate_less_than_high_quality() {
        let fuse = |quality: u8| {
            let mut kf = VelocityKf::new(VelocityKfConfig::default());
            kf.hold_still(at(0));
            kf.predict(0.0, 0.0, 0.0, 0.002, at(100_000));
            kf.correct([0.1, 0.0], quality, at(0), at(100_000));
            kf.velocity().unwrap()[0]
        };
        let (lo, hi) = (fuse(40), fuse(255));
        assert!(lo > 0.0 && hi > lo * 2.0, "lo {lo}, hi {hi}");
    }

    #[test]
    fn an_outlier_is_gated_and_a_persistent_disagreement_restarts() {
        let mut kf = VelocityKf::new(VelocityKfConfig::default());
        let mut t = 400_000;
        kf.hold_still(at(t));
        let mut step = |kf: &mut VelocityKf, z: f32| {
            for _ in 0..20 {
                t += DT_US;
                kf.predict(0.0, 0.0, 0.0, DT_US as f32 * 1e-6, at(t));
            }
            kf.correct(
                [z, 0.0],
                255,
                at(t.saturating_sub(250_000)),
                at(t.saturating_sub(30_000)),
            )
        };
        for _ in 0..50 {
            assert_eq!(step(&mut kf, 0.0), Fusion::Fused);
        }
        assert_eq!(step(&mut kf, 2.5), Fusion::Rejected);
        assert_eq!(kf.velocity().unwrap()[0], 0.0);
        assert_eq!(step(&mut kf, 0.0), Fusion::Fused);
        // A wrong prior: the camera keeps saying 1.5 m/s.
        let outcomes: std::vec::Vec<Fusion> = (0..4).map(|_| step(&mut kf, 1.5)).collect();
        assert_eq!(outcomes[..3], [Fusion::Rejected; 3]);
        assert_eq!(outcomes[3], Fusion::Initialised);
        assert_eq!(kf.velocity().unwrap()[0], 1.5);
        assert_eq!(kf.rejected(), 5);
    }

    #[test]
    fn the_yaw_rate_turns_the_velocity_and_garbage_is_ignored() {
        let mut kf = VelocityKf::new(VelocityKfConfig {
            drag_per_s: 0.0,
            ..VelocityKfConfig::default()
        });
        assert_eq!(kf.velocity(), None);
        assert_eq!(
            kf.correct([1.0, 0.0], 255, at(0), at(0)),
            Fusion::Initialised
        );
        let w = core::f32::consts::FRAC_PI_2;
        for k in 1..=512 {
            kf.predict(0.0, 0.0, w, 1.0 / 512.0, at(k * DT_US));
        }
        let v = kf.velocity().unwrap();
        assert!(v[0].abs() < 0.02 && (v[1] + 1.0).abs() < 0.02, "{v:?}");
        assert_eq!(
            kf.correct([f32::NAN, 0.0], 255, at(0), at(10)),
            Fusion::Ignored
        );
        for k in 513..=1024 {
            kf.predict(0.0, 0.0, 0.0, 1.0 / 512.0, at(k * DT_US));
        }
        kf.predict(f32::NAN, 0.0, 0.0, 0.002, at(2_002_000));
        assert!(kf.velocity().unwrap().iter().all(|x| x.is_finite()));
        // A window older than the history cannot be placed.
        assert_eq!(
            kf.correct([0.0, 0.0], 255, at(0), at(1_000)),
            Fusion::Ignored
        );
    }
}
