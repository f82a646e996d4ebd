//! Velocity guidance: a body-velocity setpoint and the median-filtered Edge-FS velocity become
//! roll and pitch setpoints.
//!
//! One PI per horizontal body axis, output an angle, bank-limited to
//! [`GuidanceConfig::max_bank_rad`] (15 deg by default). Signs (body x forward, y right, z down,
//! ZYX Euler angles):
//!
//! * a forward velocity error (`setpoint - measured > 0`: should go faster forward) pitches the
//!   nose **down** (negative pitch), which tilts the thrust forward;
//! * a sideways velocity error to the right rolls right (positive roll).
//!
//! Anti-windup: conditional integration (the integrator stops while the output is at the bank
//! limit and the error would push it further) plus a clamp on the integral's contribution.
//! [`VelocityGuidance::hold`] gives the trim attitude (integral only) when no velocity estimate
//! is available, and [`VelocityGuidance::reset`] clears everything (on the ground).

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
}

impl Default for GuidanceConfig {
    fn default() -> Self {
        Self {
            kp: 0.2,
            ki: 0.1,
            max_bank_rad: 15.0_f32.to_radians(),
            max_integral_rad: 5.0_f32.to_radians(),
        }
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
}

impl VelocityGuidance {
    /// A controller with empty integrators.
    pub fn new(cfg: GuidanceConfig) -> Self {
        Self {
            cfg,
            integral: [0.0; 2],
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

    /// Clears the integrators.
    pub fn reset(&mut self) {
        self.integral = [0.0; 2];
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
        let mut tilt = [0.0f32; 2];
        for i in 0..2 {
            let e = setpoint[i] - measured[i];
            let e = if e.is_finite() {
                e.clamp(-5.0, 5.0)
            } else {
                0.0
            };
            let p = self.cfg.kp * e;
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

    /// Trim attitude without a velocity measurement: the integral part only (it holds the
    /// learned trim, e.g. a centre-of-gravity offset), integrators frozen.
    pub fn hold(&self) -> TiltSetpoint {
        let lim = self.cfg.max_bank_rad.abs();
        TiltSetpoint {
            pitch_rad: -self.integral[0].clamp(-lim, lim),
            roll_rad: self.integral[1].clamp(-lim, lim),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let cfg = GuidanceConfig::default();
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

    #[test]
    fn nan_inputs_give_finite_output() {
        let mut g = VelocityGuidance::new(GuidanceConfig::default());
        let t = g.step([f32::NAN, f32::INFINITY], [0.0, f32::NAN], f32::NAN);
        assert_eq!(t, TiltSetpoint::default());
    }
}
