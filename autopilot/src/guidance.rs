//! Velocity guidance: a body-velocity setpoint and the estimated body velocity (the velocity
//! Kalman filter's by default, the median-5 observer's in paper mode) become roll and pitch
//! setpoints.
//!
//! One PI per horizontal body axis, output an angle, bank-limited to
//! [`GuidanceConfig::max_bank_rad`] (15 deg by default). Signs (body x forward, y right, z down,
//! ZYX Euler angles):
//!
//! * a forward velocity error (`setpoint - measured > 0`: should go faster forward) pitches the
//!   nose **down** (negative pitch), which tilts the thrust forward;
//! * a sideways velocity error to the right rolls right (positive roll).
//!
//! The PI does not chase a step: a reference model moves towards the requested setpoint at
//! most [`GuidanceConfig::max_accel_mps2`], and the tilt that gives the reference's
//! acceleration is fed forward (`atan(a / g)`), so a start or a stop is flown at once instead
//! of waiting for the velocity error to build up through the estimate's lag. The drone's
//! acceleration follows a tilt command only after the attitude loop has turned it
//! ([`GuidanceConfig::response_lag_s`], modelled as a first-order lag), so the velocity the PI
//! holds the drone to is the reference passed through that lag: the PI corrects what the
//! feedforward did not achieve and does not fight the lag it expects (which made every start
//! and stop overshoot by about 0.06 m/s).
//!
//! Anti-windup: conditional integration (the integrator stops while the output is at the bank
//! limit and the error would push it further) plus a clamp on the integral's contribution.
//! [`VelocityGuidance::hold`] gives the trim attitude (integral only) when no velocity estimate
//! is available (the reference then restarts from the next estimate), and
//! [`VelocityGuidance::reset`] clears everything (on the ground).
//!
//! [`VelocityObserver`] is the velocity guidance flies on: it predicts the velocity from the
//! attitude and the yaw rate between vision measurements and corrects it with them, so the
//! loop keeps braking through fast yaw (when Edge-FS is unreliable) and short link outages.

use crate::velocity_model::{
    heading_frame_step, tilt_acceleration, VelocityHistory, HISTORY_SPACING,
};
use timebase::{Duration, Instant};

/// Velocity loop tunables.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidanceConfig {
    /// Proportional gain, rad of tilt per m/s of velocity error.
    pub kp: f32,
    /// Integral gain, rad of tilt per m of integrated velocity error.
    pub ki: f32,
    /// Bank (and pitch) limit, rad.
    pub max_bank_rad: f32,
    /// Largest tilt the integral alone may hold, rad.
    pub max_integral_rad: f32,
    /// Acceleration of the reference model, m/s² per axis (0: the requested setpoint is
    /// flown as a step, without feedforward, as in the paper).
    pub max_accel_mps2: f32,
    /// Time constant of the drone's acceleration following a tilt command (the attitude
    /// loop's response), s.
    pub response_lag_s: f32,
}

impl Default for GuidanceConfig {
    fn default() -> Self {
        Self {
            kp: 0.2,
            ki: 0.1,
            max_bank_rad: 15.0_f32.to_radians(),
            max_integral_rad: 5.0_f32.to_radians(),
            max_accel_mps2: 1.5,
            response_lag_s: 0.15,
        }
    }
}

/// Farthest the reference model's velocity may be from the estimate before a step, m/s.
pub const REFERENCE_MAX_LEAD_MPS: f32 = 0.5;

/// The reference model of one step: its velocity (rate-limited towards the request), the
/// acceleration that took it there (fed forward), and the velocity the drone is expected to
/// have (the reference behind the response lag), per axis `[forward, sideways]`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Reference {
    velocity: [f32; 2],
    /// The commanded acceleration through the response lag, m/s².
    lagged_accel: [f32; 2],
}

impl Reference {
    /// At rest at `velocity`.
    fn at(velocity: [f32; 2]) -> Self {
        Self {
            velocity,
            lagged_accel: [0.0; 2],
        }
    }

    /// The velocity expected of the drone: behind the reference by the lag times the lagged
    /// acceleration (for a first-order lag this is exactly the integral of the lagged
    /// acceleration).
    fn expected(&self, lag_s: f32) -> [f32; 2] {
        [0, 1].map(|i| self.velocity[i] - lag_s * self.lagged_accel[i])
    }
}

/// Roll and pitch setpoints, rad.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TiltSetpoint {
    /// Roll setpoint, rad (positive: right side down).
    pub roll_rad: f32,
    /// Pitch setpoint, rad (positive: nose up).
    pub pitch_rad: f32,
}

/// Velocity PI state for the forward and sideways axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityGuidance {
    cfg: GuidanceConfig,
    /// Integral part, rad, as "tilt towards +axis": forward (nose down) and right (roll right).
    integral: [f32; 2],
    /// The reference model; `None` until the first step after a [`VelocityGuidance::hold`]
    /// (it starts from the estimate then).
    reference: Option<Reference>,
}

impl VelocityGuidance {
    /// Takes a new configuration, keeping the state (used from the next step on).
    pub fn set_config(&mut self, cfg: GuidanceConfig) {
        self.cfg = cfg;
    }

    /// A controller with empty integrators.
    pub fn new(cfg: GuidanceConfig) -> Self {
        Self {
            cfg,
            integral: [0.0; 2],
            reference: Some(Reference::default()),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &GuidanceConfig {
        &self.cfg
    }

    /// Integrator state `[forward, sideways]`, rad of tilt towards +x / +y.
    pub fn integral(&self) -> [f32; 2] {
        self.integral
    }

    /// The velocity setpoint flown `[forward, sideways]`, m/s: the velocity the reference
    /// model expects of the drone, `None` while it waits for an estimate to start from.
    pub fn reference(&self) -> Option<[f32; 2]> {
        self.reference.map(|r| r.expected(self.lag_s()))
    }

    /// Clears the integrators; the reference is at rest.
    pub fn reset(&mut self) {
        self.integral = [0.0; 2];
        self.reference = Some(Reference::default());
    }

    fn lag_s(&self) -> f32 {
        let lag = self.cfg.response_lag_s;
        if lag.is_finite() {
            lag.max(0.0)
        } else {
            0.0
        }
    }

    /// Moves the reference towards `setpoint` over `dt` s (from `measured` if it has to
    /// restart; both finite); returns the velocity expected of the drone and the acceleration
    /// to feed forward, per axis.
    fn advance_reference(
        &mut self,
        setpoint: [f32; 2],
        measured: [f32; 2],
        dt: f32,
    ) -> ([f32; 2], [f32; 2]) {
        let a_max = self.cfg.max_accel_mps2;
        let lag = self.lag_s();
        let mut r = self.reference.unwrap_or(Reference::at(measured));
        let mut accel = [0.0f32; 2];
        for i in 0..2 {
            let target = setpoint[i];
            if !(a_max > 0.0 && a_max.is_finite() && r.velocity[i].is_finite()) {
                r.velocity[i] = target;
                r.lagged_accel[i] = 0.0;
                continue;
            }
            // A reference that runs away from a drone that cannot follow (at the bank limit)
            // would wind up like an integrator: it stays within reach of the estimate.
            let reachable = r.velocity[i].clamp(
                measured[i] - REFERENCE_MAX_LEAD_MPS,
                measured[i] + REFERENCE_MAX_LEAD_MPS,
            );
            let held_back = reachable != r.velocity[i];
            let step = (target - reachable).clamp(-a_max * dt, a_max * dt);
            r.velocity[i] = reachable + step;
            // Held at the reach, the reference does not accelerate the drone: nothing to feed
            // forward.
            if dt > 0.0 && !held_back {
                accel[i] = step / dt;
            }
            let k = if lag > dt { dt / lag } else { 1.0 };
            r.lagged_accel[i] += (accel[i] - r.lagged_accel[i]) * k;
        }
        self.reference = Some(r);
        (r.expected(lag), accel)
    }

    /// One step of `dt` s: `setpoint` and `measured` are `[forward, sideways]` body velocities,
    /// m/s. Non-finite inputs count as zero error.
    pub fn step(&mut self, setpoint: [f32; 2], measured: [f32; 2], dt: f32) -> TiltSetpoint {
        let lim = self.cfg.max_bank_rad.abs();
        let ilim = self.cfg.max_integral_rad.abs().min(lim);
        let dt = if dt.is_finite() {
            dt.clamp(0.0, 0.5)
        } else {
            0.0
        };
        let finite = |v: [f32; 2]| v.map(|x| if x.is_finite() { x } else { 0.0 });
        let (reference, accel) = self.advance_reference(finite(setpoint), finite(measured), dt);
        let mut tilt = [0.0f32; 2];
        for i in 0..2 {
            let feedforward = libm::atanf(accel[i] / crate::attitude::GRAVITY);
            let e = reference[i] - measured[i];
            let e = if e.is_finite() {
                e.clamp(-5.0, 5.0)
            } else {
                0.0
            };
            let p = self.cfg.kp * e + feedforward;
            let unsat = p + self.integral[i];
            let pushing_out = (unsat >= lim && e > 0.0) || (unsat <= -lim && e < 0.0);
            if !pushing_out {
                self.integral[i] = (self.integral[i] + self.cfg.ki * e * dt).clamp(-ilim, ilim);
            }
            let t = p + self.integral[i];
            tilt[i] = if t.is_finite() {
                t.clamp(-lim, lim)
            } else {
                0.0
            };
        }
        TiltSetpoint {
            // Tilting towards +x (forward) is nose down: negative pitch.
            pitch_rad: -tilt[0],
            roll_rad: tilt[1],
        }
    }

    /// Flying without a velocity measurement: the [`VelocityGuidance::trim`], integrators
    /// frozen; the reference restarts from the next estimate.
    pub fn hold(&mut self) -> TiltSetpoint {
        self.reference = None;
        self.trim()
    }

    /// The trim attitude: the integral part only (it holds the learned trim, e.g. a
    /// centre-of-gravity offset).
    pub fn trim(&self) -> TiltSetpoint {
        let lim = self.cfg.max_bank_rad.abs();
        TiltSetpoint {
            pitch_rad: -self.integral[0].clamp(-lim, lim),
            roll_rad: self.integral[1].clamp(-lim, lim),
        }
    }
}

/// Velocity observer tunables (see [`VelocityObserver`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObserverConfig {
    /// Linear drag of the airframe per unit mass, 1/s (horizontal `a = -drag * v`; a 40 g
    /// pocket drone with ~8e-3 N/(m/s) of rotor-induced drag: 0.2/s).
    pub drag_per_s: f32,
    /// Fraction of the velocity innovation applied per measurement (0..=1).
    pub velocity_gain: f32,
    /// Acceleration-bias learning per measurement, (m/s²) per (m/s) of innovation.
    pub bias_gain: f32,
    /// Largest learned acceleration bias per axis, m/s².
    pub max_bias_mps2: f32,
    /// Age of a measurement when it is fused (camera exposure to its filtered value reaching
    /// the observer: read-out, processing, link and the median-5's two frames). The
    /// innovation is taken against the prediction of that time.
    pub measurement_delay: Duration,
    /// Tilt used for the predicted acceleration is limited to this, rad.
    pub max_tilt_rad: f32,
}

impl Default for ObserverConfig {
    fn default() -> Self {
        Self {
            drag_per_s: 0.2,
            velocity_gain: 0.25,
            bias_gain: 0.03,
            max_bias_mps2: 0.5,
            measurement_delay: Duration::from_millis(100),
            max_tilt_rad: 0.5,
        }
    }
}

/// Slots of the observer's history (one every [`HISTORY_SPACING`]: 32 x 6 ms, 192 ms back).
const HISTORY_LEN: usize = 32;
/// Longest [`ObserverConfig::measurement_delay`] the history reaches back to.
pub const MAX_MEASUREMENT_DELAY: Duration = HISTORY_SPACING.saturating_mul(HISTORY_LEN as u64 - 1);

/// Horizontal velocity observer in the heading frame (level body axes: forward, right).
///
/// Between measurements it integrates the acceleration the attitude implies (thrust holding
/// the height: `a_fwd = -g tan(pitch)`, `a_right = g tan(roll) / cos(pitch)`) minus linear
/// drag plus a learned bias, and rotates the velocity with the yaw rate (the heading frame
/// turns under a velocity that is fixed in the room: `dv_fwd/dt = r v_right`,
/// `dv_right/dt = -r v_fwd`). Each vision measurement corrects it by
/// [`ObserverConfig::velocity_gain`] of the innovation, taken against the prediction of
/// [`ObserverConfig::measurement_delay`] ago (a short history is kept), and the same
/// innovation trains the acceleration bias (tilt-estimate offsets, centre-of-gravity trim).
///
/// This is what lets guidance keep braking while vision is unusable (fast yaw, a link outage):
/// the velocity is dead-reckoned instead of frozen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityObserver {
    cfg: ObserverConfig,
    v: [f32; 2],
    bias: [f32; 2],
    initialised: bool,
    history: VelocityHistory<HISTORY_LEN>,
}

impl VelocityObserver {
    /// Takes a new configuration, keeping the state (used from the next step on).
    pub fn set_config(&mut self, cfg: ObserverConfig) {
        self.cfg = cfg;
    }

    /// An observer without a velocity yet.
    pub fn new(cfg: ObserverConfig) -> Self {
        Self {
            cfg,
            v: [0.0; 2],
            bias: [0.0; 2],
            initialised: false,
            history: VelocityHistory::new(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ObserverConfig {
        &self.cfg
    }

    /// Forgets the velocity (keeps the learned bias).
    pub fn reset(&mut self) {
        let bias = self.bias;
        *self = Self::new(self.cfg);
        self.bias = bias;
    }

    /// Current `[forward, right]` velocity, m/s (`None` before the first measurement).
    pub fn velocity(&self) -> Option<[f32; 2]> {
        self.initialised.then_some(self.v)
    }

    /// Learned acceleration bias `[forward, right]`, m/s².
    pub fn bias(&self) -> [f32; 2] {
        self.bias
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
            if let Some(v) = heading_frame_step(self.v, a, self.cfg.drag_per_s, yaw_rate, dt) {
                self.v = v;
            }
        }
        self.history.record(now, self.v);
    }

    /// The prediction as it was at `at` (the newest recorded one not after it; the oldest
    /// held when the history does not reach back that far).
    fn predicted_at(&self, at: Instant) -> [f32; 2] {
        let mut best = self.v;
        for (t, v) in self.history.newest_first() {
            best = v;
            if t <= at {
                break;
            }
        }
        best
    }

    /// Fuses a `[forward, right]` velocity measurement (m/s) that reached the observer at
    /// `now` (its age is [`ObserverConfig::measurement_delay`]). The first one
    /// initialises the observer. Non-finite measurements are ignored.
    pub fn correct(&mut self, measured: [f32; 2], now: Instant) {
        if !measured.iter().all(|x| x.is_finite()) {
            return;
        }
        if !self.initialised {
            self.initialised = true;
            self.v = measured;
            self.history.fill(now, measured, now);
            return;
        }
        let then = self.predicted_at(now - self.cfg.measurement_delay);
        let kv = self.cfg.velocity_gain.clamp(0.0, 1.0);
        let blim = self.cfg.max_bias_mps2.abs();
        for i in 0..2 {
            let e = (measured[i] - then[i]).clamp(-5.0, 5.0);
            let dv = kv * e;
            self.v[i] += dv;
            // The history moves with the correction, so the next innovation does not count
            // this one again.
            self.history.shift(i, dv);
            self.bias[i] = (self.bias[i] + self.cfg.bias_gain * e).clamp(-blim, blim);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;

    #[test]
    fn forward_error_pitches_nose_down_sideways_error_rolls_right() {
        let mut g = VelocityGuidance::new(GuidanceConfig::default());
        let t = g.step([0.3, 0.0], [0.0, 0.0], 0.02);
        assert!(t.pitch_rad < 0.0, "nose down expected, got {}", t.pitch_rad);
        assert_eq!(t.roll_rad, 0.0);
        let mut g = VelocityGuidance::new(GuidanceConfig::default());
        let t = g.step([0.0, 0.2], [0.0, 0.0], 0.02);
        assert!(t.roll_rad > 0.0);
        // Going too fast forward: nose up to brake.
        let t = g.step([0.0, 0.0], [0.5, 0.0], 0.02);
        assert!(t.pitch_rad > 0.0);
    }

    #[test]
    fn bank_limit_holds_and_integrator_does_not_wind_up() {
        // The PI alone: the setpoint flown as a step.
        let cfg = GuidanceConfig {
            max_accel_mps2: 0.0,
            ..GuidanceConfig::default()
        };
        let mut g = VelocityGuidance::new(cfg);
        for _ in 0..50 * 60 {
            let t = g.step([3.0, -3.0], [0.0, 0.0], 0.02);
            assert!(t.pitch_rad.abs() <= cfg.max_bank_rad + 1e-6);
            assert!(t.roll_rad.abs() <= cfg.max_bank_rad + 1e-6);
        }
        // The P part alone saturates: the integrator stopped at its value when the output hit
        // the limit (here: never started), so when the error reverses the output reverses at once.
        assert!(g.integral()[0].abs() <= cfg.max_integral_rad + 1e-6);
        let t = g.step([0.0, 0.0], [0.3, 0.0], 0.02);
        assert!(t.pitch_rad > 0.0, "must brake at once, got {}", t.pitch_rad);
    }

    /// A drone whose tilt follows the command with a first-order lag (the attitude loop) and
    /// whose velocity follows `g tan(tilt)`, along one axis.
    struct LaggedDrone {
        v: f32,
        tilt: f32,
        lag_s: f32,
    }

    impl LaggedDrone {
        /// Flies 2 s on `g` towards `setpoint`; the velocity at each 20 ms step.
        fn fly(&mut self, g: &mut VelocityGuidance, setpoint: f32) -> [f32; 100] {
            let (dt, sub) = (0.02f32, 20);
            let mut out = [0.0f32; 100];
            for o in out.iter_mut() {
                let cmd = -g.step([setpoint, 0.0], [self.v, 0.0], dt).pitch_rad;
                for _ in 0..sub {
                    let h = dt / sub as f32;
                    self.tilt += (cmd - self.tilt) * h / self.lag_s;
                    self.v += crate::attitude::GRAVITY * libm::tanf(self.tilt) * h;
                }
                *o = self.v;
            }
            out
        }
    }

    #[test]
    fn a_start_and_a_stop_follow_the_reference_with_its_tilt_fed_forward() {
        let cfg = GuidanceConfig::default();
        let a = cfg.max_accel_mps2;
        let mut g = VelocityGuidance::new(cfg);
        // First step of a start: the tilt for the reference's acceleration is flown at once.
        let t = g.step([0.3, 0.0], [0.0, 0.0], 0.02);
        assert!(
            -t.pitch_rad >= libm::atanf(a / crate::attitude::GRAVITY),
            "{t:?}"
        );
        // On a drone with the modelled response lag a start reaches the request in the
        // reference's time plus a few lags, without overshoot: the PI does not fight the lag
        // it expects.
        let at_rest = || LaggedDrone {
            v: 0.0,
            tilt: 0.0,
            lag_s: cfg.response_lag_s,
        };
        let mut g = VelocityGuidance::new(cfg);
        let mut drone = at_rest();
        let v = drone.fly(&mut g, 0.3);
        let reached = v.iter().position(|&x| x >= 0.29).unwrap() as f32 * 0.02;
        assert!(
            reached <= 0.3 / a + 3.0 * cfg.response_lag_s,
            "{reached} s: {v:?}"
        );
        let peak = v.iter().cloned().fold(f32::MIN, f32::max);
        assert!(peak < 0.32, "overshoot to {peak}: {v:?}");
        // The stop that follows comes to rest as fast and does not reverse.
        let v = drone.fly(&mut g, 0.0);
        let stopped = v.iter().position(|&x| x <= 0.01).unwrap() as f32 * 0.02;
        assert!(
            stopped <= 0.3 / a + 3.0 * cfg.response_lag_s,
            "{stopped} s: {v:?}"
        );
        assert!(v.iter().all(|&x| x > -0.02), "{v:?}");
        // The PI alone (a step, no feedforward) is slower to get there.
        let mut g = VelocityGuidance::new(GuidanceConfig {
            max_accel_mps2: 0.0,
            ..cfg
        });
        let v = at_rest().fly(&mut g, 0.3);
        let pi_reached = v.iter().position(|&x| x >= 0.29).unwrap_or(v.len()) as f32 * 0.02;
        assert!(
            pi_reached >= reached + 0.2,
            "{pi_reached} s against {reached} s"
        );
    }

    #[test]
    fn the_reference_stays_within_reach_and_restarts_from_the_estimate() {
        let cfg = GuidanceConfig::default();
        let mut g = VelocityGuidance::new(cfg);
        // A drone that cannot follow (pinned at 0): the reference does not run away, and
        // held at its reach it feeds nothing forward.
        let mut t = TiltSetpoint::default();
        for _ in 0..50 * 10 {
            t = g.step([3.0, -3.0], [0.0, 0.0], 0.02);
        }
        let r = g.reference().unwrap();
        let reach = REFERENCE_MAX_LEAD_MPS + cfg.max_accel_mps2 * 0.02;
        assert!(r.iter().all(|x| x.abs() <= reach + 1e-6), "{r:?}");
        let pi_only = cfg.kp * reach + cfg.max_integral_rad;
        assert!(t.pitch_rad.abs() <= pi_only + 1e-3, "{t:?}");
        // So when the request reverses the drone brakes within a lead's worth of ramp.
        let t = g.step([0.0, 0.0], [0.3, 0.0], 0.02);
        assert!(t.pitch_rad > -cfg.kp * REFERENCE_MAX_LEAD_MPS, "{t:?}");
        // Without an estimate the reference is dropped; it restarts from the next one.
        g.hold();
        assert_eq!(g.reference(), None);
        g.step([0.2, -0.1], [0.2, -0.1], 0.02);
        assert_eq!(g.reference(), Some([0.2, -0.1]));
    }

    #[test]
    fn integral_removes_steady_state_error() {
        // Velocity plant: dv/dt = g*tan(tilt) - drag*v - disturbance.
        let mut g = VelocityGuidance::new(GuidanceConfig::default());
        let (mut v, dt) = (0.0f32, 0.02f32);
        for _ in 0..50 * 30 {
            let t = g.step([0.3, 0.0], [v, 0.0], dt);
            let a = 9.81 * libm::tanf(-t.pitch_rad) - 1.0 * v - 0.3;
            v += a * dt;
        }
        assert!((v - 0.3).abs() < 0.01, "v = {v}");
        let h = g.hold();
        assert!(
            h.pitch_rad < 0.0,
            "trim keeps leaning forward against the disturbance"
        );
    }

    fn observer(drag: f32) -> VelocityObserver {
        VelocityObserver::new(ObserverConfig {
            drag_per_s: drag,
            ..ObserverConfig::default()
        })
    }

    #[test]
    fn observer_integrates_tilt_and_turns_the_velocity_with_the_heading() {
        let mut o = observer(0.0);
        assert_eq!(o.velocity(), None);
        o.predict(0.0, -0.1, 0.0, 0.002, at(0));
        assert_eq!(o.velocity(), None, "nothing before the first measurement");
        o.correct([0.0, 0.0], at(0));
        // 1 s nose down 0.1 rad: forward g tan(0.1) = 0.984 m/s.
        for k in 1..=500 {
            o.predict(0.0, -0.1, 0.0, 0.002, at(k * 2_000));
        }
        let v = o.velocity().unwrap();
        assert!((v[0] - 0.984).abs() < 0.01 && v[1].abs() < 1e-6, "{v:?}");
        // Level, a quarter turn to the right in 1 s: the room-fixed velocity is now to the left.
        let w = core::f32::consts::FRAC_PI_2;
        for k in 501..=1000 {
            o.predict(0.0, 0.0, w, 0.002, at(k * 2_000));
        }
        let v = o.velocity().unwrap();
        assert!(v[0].abs() < 0.01 && (v[1] + 0.984).abs() < 0.01, "{v:?}");
        // Drag slows it: 1 s at 0.2/s leaves exp(-0.2).
        let mut o = observer(0.2);
        o.correct([1.0, 0.0], at(0));
        for k in 1..=500 {
            o.predict(0.0, 0.0, 0.0, 0.002, at(k * 2_000));
        }
        assert!((o.velocity().unwrap()[0] - libm::expf(-0.2)).abs() < 0.01);
    }

    #[test]
    fn observer_compares_a_delayed_measurement_with_the_past_prediction() {
        let mut o = observer(0.0);
        o.correct([0.0, 0.0], at(0));
        // Accelerate forward at ~1 m/s² for 1 s.
        let pitch = -libm::atanf(1.0 / crate::attitude::GRAVITY);
        let mut t = 0;
        for _ in 0..500 {
            t += 2_000;
            o.predict(0.0, pitch, 0.0, 0.002, at(t));
        }
        let now = o.velocity().unwrap()[0];
        assert!((now - 1.0).abs() < 0.01);
        // A measurement that matches the prediction of 100 ms ago changes nothing.
        o.correct([0.9, 0.0], at(t));
        assert!((o.velocity().unwrap()[0] - now).abs() < 0.01);
        // One 0.4 m/s higher moves the estimate by the gain's share of it.
        o.correct([1.3, 0.0], at(t));
        let g = ObserverConfig::default().velocity_gain;
        assert!((o.velocity().unwrap()[0] - now - 0.4 * g).abs() < 0.02);
    }

    #[test]
    fn observer_learns_an_acceleration_bias_and_dead_reckons_with_it() {
        // The attitude says level, but the drone really accelerates at 0.3 m/s² (a tilt
        // estimate offset): measurements of the true velocity every 40 ms.
        let mut o = observer(0.0);
        let (mut t, mut v_true) = (0u64, 0.0f32);
        o.correct([0.0, 0.0], at(0));
        for _ in 0..(25 * 30) {
            for _ in 0..20 {
                t += 2_000;
                v_true += 0.3 * 0.002;
                o.predict(0.0, 0.0, 0.0, 0.002, at(t));
            }
            let delayed = v_true - 0.3 * 0.1;
            o.correct([delayed, 0.0], at(t));
        }
        assert!((o.bias()[0] - 0.3).abs() < 0.05, "bias {:?}", o.bias());
        // Measurements stop: 1 s of dead reckoning stays within 0.1 m/s of the truth.
        for _ in 0..500 {
            t += 2_000;
            v_true += 0.3 * 0.002;
            o.predict(0.0, 0.0, 0.0, 0.002, at(t));
        }
        let err = o.velocity().unwrap()[0] - v_true;
        assert!(err.abs() < 0.1, "error {err}");
    }

    #[test]
    fn observer_prediction_matches_libm_trigonometry() {
        // One 50 ms step from rest, no drag or yaw: v = a * dt with the tilt acceleration of
        // the libm form `-g tan p`, `g tan r / cos p`, over the whole tilt range and beyond.
        let g = f64::from(crate::attitude::GRAVITY);
        let cfg = ObserverConfig {
            drag_per_s: 0.0,
            max_tilt_rad: 1.2,
            ..ObserverConfig::default()
        };
        let dt = 0.05;
        for i in -24..=24 {
            for j in -24..=24 {
                let (r, p) = (0.05 * i as f32, 0.05 * j as f32);
                let mut o = VelocityObserver::new(cfg);
                o.correct([0.0, 0.0], at(0));
                o.predict(r, p, 0.0, dt, at(50_000));
                let v = o.velocity().unwrap();
                let want = [
                    -g * libm::tan(f64::from(p)),
                    g * libm::tan(f64::from(r)) / libm::cos(f64::from(p)),
                ];
                for k in 0..2 {
                    let want = (want[k] * f64::from(dt)).clamp(-10.0, 10.0);
                    let err = (f64::from(v[k]) - want).abs();
                    assert!(
                        err <= 2e-6 * want.abs().max(1.0),
                        "r {r} p {p}: {v:?} vs {want}"
                    );
                }
            }
        }
        // A tilt limit of pi/2 (both cosines round to about 0): the huge accelerations of the
        // libm form's signs, clamped to the velocity limit.
        let mut o = VelocityObserver::new(ObserverConfig {
            max_tilt_rad: core::f32::consts::FRAC_PI_2,
            ..cfg
        });
        o.correct([0.0, 0.0], at(0));
        o.predict(2.0, -2.0, 0.0, dt, at(50_000));
        assert_eq!(o.velocity(), Some([-10.0, 10.0]));
    }

    #[test]
    fn observer_ignores_garbage() {
        let mut o = observer(0.2);
        o.correct([f32::NAN, 0.0], at(0));
        assert_eq!(o.velocity(), None);
        o.correct([0.1, -0.1], at(0));
        o.predict(f32::NAN, 0.0, 0.0, 0.002, at(2_000));
        o.predict(0.0, f32::INFINITY, 1e30, f32::NAN, at(4_000));
        o.predict(1e9, -1e9, 1e9, 1e9, at(6_000));
        let v = o.velocity().unwrap();
        assert!(v.iter().all(|x| x.is_finite() && x.abs() <= 10.0), "{v:?}");
    }

    #[test]
    fn nan_inputs_give_finite_output() {
        let mut g = VelocityGuidance::new(GuidanceConfig::default());
        let t = g.step([f32::NAN, f32::INFINITY], [0.0, f32::NAN], f32::NAN);
        assert_eq!(t, TiltSetpoint::default());
    }
}
