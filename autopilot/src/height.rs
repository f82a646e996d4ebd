//! Vertical loop: height measurement and height setpoint to a collective thrust command.
//!
//! A PID on the height error with the climb rate from the measurements (finite difference,
//! low-passed) as the derivative, around a hover-thrust feed-forward. The integrator only runs
//! when the caller says the drone is airborne and the output is not saturated in the error's
//! direction, and it is clamped, so nothing winds up on the ground. The output is the thrust for
//! a level drone; the caller divides by `cos(roll) cos(pitch)` (see [`tilt_compensate`]).
//!
//! Height is positive up, m (the external position's `-z`).

use timebase::Instant;

/// Height loop tunables (defaults: the 40 g pocket drone, hover near 65 % throttle).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeightConfig {
    /// Thrust to hover, 0..=1 (feed-forward).
    pub hover_thrust: f32,
    /// Proportional gain, thrust per m of height error.
    pub kp: f32,
    /// Integral gain, thrust per m·s.
    pub ki: f32,
    /// Damping, thrust per m/s of climb rate error.
    pub kd: f32,
    /// Integrator clamp, thrust (±).
    pub max_integral: f32,
    /// Thrust output range, 0..=1.
    pub min_thrust: f32,
    /// Thrust output range, 0..=1.
    pub max_thrust: f32,
    /// Time constant of the climb-rate low-pass, s.
    pub rate_tau_s: f32,
    /// Largest tilt compensation factor `1/(cos roll cos pitch)`.
    pub max_tilt_factor: f32,
}

impl Default for HeightConfig {
    fn default() -> Self {
        Self {
            hover_thrust: 0.65,
            kp: 0.27,
            ki: 0.12,
            kd: 0.22,
            max_integral: 0.2,
            min_thrust: 0.15,
            max_thrust: 1.0,
            rate_tau_s: 0.05,
            max_tilt_factor: 1.3,
        }
    }
}

/// Height controller state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeightController {
    cfg: HeightConfig,
    integral: f32,
    height_m: f32,
    climb_mps: f32,
    last: Option<Instant>,
}

impl HeightController {
    /// Takes a new configuration, keeping the state (used from the next step on).
    pub fn set_config(&mut self, cfg: HeightConfig) {
        self.cfg = cfg;
    }

    /// A controller with no measurement yet.
    pub fn new(cfg: HeightConfig) -> Self {
        Self {
            cfg,
            integral: 0.0,
            height_m: 0.0,
            climb_mps: 0.0,
            last: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &HeightConfig {
        &self.cfg
    }

    /// Latest height, m (0 before the first measurement).
    pub fn height_m(&self) -> f32 {
        self.height_m
    }

    /// Filtered climb rate, m/s (positive up).
    pub fn climb_mps(&self) -> f32 {
        self.climb_mps
    }

    /// Integrator state, thrust.
    pub fn integral(&self) -> f32 {
        self.integral
    }

    /// Time of the latest accepted measurement.
    pub fn last_measurement(&self) -> Option<Instant> {
        self.last
    }

    /// Feeds a height measurement (m, positive up) taken at `now`. Non-finite or absurd
    /// values (outside -1..100 m) are ignored.
    pub fn on_measurement(&mut self, height_m: f32, now: Instant) {
        if !height_m.is_finite() || !(-1.0..100.0).contains(&height_m) {
            return;
        }
        match self.last {
            Some(t) if now > t => {
                let dt = (now - t).as_secs_f32();
                if dt < 0.5 {
                    let rate = (height_m - self.height_m) / dt;
                    let a = dt / (self.cfg.rate_tau_s.max(0.0) + dt);
                    self.climb_mps += a * (rate.clamp(-10.0, 10.0) - self.climb_mps);
                } else {
                    self.climb_mps = 0.0;
                }
            }
            Some(_) => return,
            None => self.climb_mps = 0.0,
        }
        self.height_m = height_m;
        self.last = Some(now);
    }

    /// Clears the integrator (on the ground, disarmed).
    pub fn reset_integral(&mut self) {
        self.integral = 0.0;
    }

    /// One control step of `dt` s towards `setpoint_m` (m) climbing at `setpoint_rate_mps`
    /// (m/s, feed-forward of a ramping setpoint). `airborne` enables the integrator. Returns the
    /// level-flight thrust, `min_thrust..=max_thrust`.
    pub fn step(
        &mut self,
        setpoint_m: f32,
        setpoint_rate_mps: f32,
        dt: f32,
        airborne: bool,
    ) -> f32 {
        let c = &self.cfg;
        let sp = if setpoint_m.is_finite() {
            setpoint_m
        } else {
            self.height_m
        };
        let sp_rate = if setpoint_rate_mps.is_finite() {
            setpoint_rate_mps
        } else {
            0.0
        };
        let dt = if dt.is_finite() {
            dt.clamp(0.0, 0.1)
        } else {
            0.0
        };
        let err = sp - self.height_m;
        let unsat = c.hover_thrust + c.kp * err + c.kd * (sp_rate - self.climb_mps) + self.integral;
        let saturated_up = unsat >= c.max_thrust && err > 0.0;
        let saturated_down = unsat <= c.min_thrust && err < 0.0;
        if airborne && !saturated_up && !saturated_down {
            self.integral =
                (self.integral + c.ki * err * dt).clamp(-c.max_integral, c.max_integral);
        } else if !airborne {
            self.integral = 0.0;
        }
        let out = c.hover_thrust + c.kp * err + c.kd * (sp_rate - self.climb_mps) + self.integral;
        if out.is_finite() {
            out.clamp(c.min_thrust, c.max_thrust)
        } else {
            c.hover_thrust
        }
    }
}

/// Divides a level-flight thrust by `cos(roll) cos(pitch)` (at most `max_factor`), so that a
/// tilted drone keeps its vertical thrust. Returns 0..=1.
///
/// The cosines come from the single-precision [`crate::attitude::sin_cos`] (libm's `cosf` runs
/// an f64 kernel, software on the M4).
pub fn tilt_compensate(thrust: f32, roll: f32, pitch: f32, max_factor: f32) -> f32 {
    let c = crate::attitude::sin_cos(roll).1 * crate::attitude::sin_cos(pitch).1;
    let factor = if c.is_finite() && c > 1e-3 {
        (1.0 / c).min(max_factor.max(1.0))
    } else {
        max_factor.max(1.0)
    };
    let t = thrust * factor;
    if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::at;

    /// Point mass: accel = (thrust / hover - 1) g, integrated at 50 Hz, measured at 50 Hz.
    fn simulate(true_hover: f32, steps: usize) -> (f32, HeightController) {
        let mut hc = HeightController::new(HeightConfig::default());
        let (mut h, mut v) = (0.0f32, 0.0f32);
        let dt = 0.02;
        for k in 0..steps {
            let now = (k as u64) * 20_000;
            hc.on_measurement(h, at(now));
            let t = hc.step(1.0, 0.0, dt, true);
            let a = (t / true_hover - 1.0) * 9.81;
            v += a * dt;
            h += v * dt;
            if h < 0.0 {
                h = 0.0;
                v = v.max(0.0);
            }
        }
        (h, hc)
    }

    #[test]
    fn reaches_setpoint_without_error_despite_wrong_hover_thrust() {
        // The true hover thrust is 0.72, the feed-forward says 0.65: the integrator makes up.
        let (h, hc) = simulate(0.72, 50 * 20);
        assert!((h - 1.0).abs() < 0.02, "height {h}");
        assert!(
            (hc.integral() - 0.07).abs() < 0.01,
            "integral {}",
            hc.integral()
        );
    }

    #[test]
    fn no_windup_on_the_ground() {
        let mut hc = HeightController::new(HeightConfig::default());
        for k in 0..500 {
            hc.on_measurement(0.0, at(k * 20_000));
            hc.step(1.0, 0.0, 0.02, false);
        }
        assert_eq!(hc.integral(), 0.0);
    }

    #[test]
    fn climb_rate_from_measurements() {
        let mut hc = HeightController::new(HeightConfig::default());
        for k in 0..100u64 {
            hc.on_measurement(0.5 * k as f32 * 0.02, at(k * 20_000));
        }
        assert!((hc.climb_mps() - 0.5).abs() < 0.01);
        // Garbage and time going backwards are ignored.
        hc.on_measurement(f32::NAN, at(3_000_000));
        hc.on_measurement(5.0, at(10));
        assert!((hc.height_m() - 0.99).abs() < 1e-4);
    }

    #[test]
    fn tilt_compensation_bounded() {
        assert!((tilt_compensate(0.65, 0.0, 0.0, 1.3) - 0.65).abs() < 1e-6);
        let t = tilt_compensate(0.65, 0.26, 0.0, 1.3);
        assert!((t - 0.65 / libm::cosf(0.26)).abs() < 1e-5);
        assert!((tilt_compensate(0.65, 1.5, 1.5, 1.3) - 0.845).abs() < 1e-4);
        assert_eq!(tilt_compensate(f32::NAN, 0.0, 0.0, 1.3), 0.0);
        // Non-finite angles: the largest factor, no panic.
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert!((tilt_compensate(0.65, bad, 0.1, 1.3) - 0.845).abs() < 1e-4);
            assert!((tilt_compensate(0.65, 0.1, bad, 1.3) - 0.845).abs() < 1e-4);
        }
    }

    #[test]
    fn tilt_compensation_matches_libm_cosines() {
        for i in -40..=40 {
            for j in -40..=40 {
                let (r, p) = (0.04 * i as f32, 0.04 * j as f32);
                let c = libm::cos(f64::from(r)) * libm::cos(f64::from(p));
                let factor = if c > 1e-3 { (1.0 / c).min(1.3) } else { 1.3 };
                let want = 0.5 * factor;
                let got = f64::from(tilt_compensate(0.5, r, p, 1.3));
                assert!((got - want).abs() < 1e-6, "r {r} p {p}: {got} vs {want}");
            }
        }
    }
}
