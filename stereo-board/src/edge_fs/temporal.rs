//! Temporal estimation of the velocity from the per-frame fits: one constant-velocity Kalman
//! filter per axis whose measurement noise comes from the fit's residual scale, with innovation
//! gating (outliers are rejected and flagged instead of passed on).
//!
//! State `[v, a]` (velocity, m/s; acceleration, m/s²), piecewise-constant white acceleration
//! of standard deviation `accel` over each frame interval `dt`:
//! `F = [[1, dt], [0, 1]]`, `Q = accel² · [[dt⁴/4, dt³/2], [dt³/2, dt²]]`; measurement
//! `z = v + e`, `e ~ N(0, R)`. A measurement whose innovation exceeds `gate` standard
//! deviations is rejected (the prediction is output). Two rejected measurements in a row
//! that agree with each other (within the gate of their own noise) mean the motion really
//! changed: the filter restarts at the newer one, so a genuine step costs one frame, not a
//! lock-out. f32 only, a few dozen flops per axis and frame; no heap.

/// Floor of a measurement's noise variance, (m/s)²: a perfect fit still leaves the filter its
/// own say.
const MIN_NOISE_VARIANCE: f32 = 1e-8;
/// Noise variance of a measurement whose variance is not finite, (m/s)²: large enough that
/// the measurement barely moves the estimate.
const UNKNOWN_NOISE_VARIANCE: f32 = 1e6;

/// Outcome of one measurement update.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Update {
    /// The measurement was fused.
    Accepted,
    /// The measurement was rejected as an outlier; the output is the prediction.
    Rejected,
    /// The filter (re)started at the measurement.
    Restarted,
}

/// Constant-velocity Kalman filter of one velocity axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisFilter {
    v: f32,
    a: f32,
    p00: f32,
    p01: f32,
    p11: f32,
    init: bool,
    /// A measurement was fused since the filter (re)started: the track is not one measurement's.
    confirmed: bool,
    /// Last rejected measurement and its noise variance, if the previous update rejected one.
    rejected: Option<(f32, f32)>,
}

impl Default for AxisFilter {
    fn default() -> Self {
        Self::new()
    }
}

impl AxisFilter {
    /// A filter without state (the first measurement initialises it).
    pub const fn new() -> Self {
        Self {
            v: 0.0,
            a: 0.0,
            p00: 0.0,
            p01: 0.0,
            p11: 0.0,
            init: false,
            confirmed: false,
            rejected: None,
        }
    }

    /// True once a measurement has initialised the state.
    pub fn is_initialised(&self) -> bool {
        self.init
    }

    /// True once a measurement has been fused since the filter (re)started: the track rests on
    /// at least two measurements that agree.
    pub fn is_confirmed(&self) -> bool {
        self.confirmed
    }

    /// Current velocity estimate, m/s (0 before the first measurement).
    pub fn velocity(&self) -> f32 {
        self.v
    }

    /// Standard deviation of the velocity estimate, m/s (infinite before initialisation).
    pub fn velocity_sigma(&self) -> f32 {
        if self.init {
            libm::sqrtf(self.p00.max(0.0))
        } else {
            f32::INFINITY
        }
    }

    /// Propagates the state by `dt_s` seconds with acceleration noise `accel` (m/s², 1σ).
    /// The acceleration estimate decays with time constant `tau_s` (first-order Gauss-Markov,
    /// so a track that loses its measurements holds its velocity instead of extrapolating a
    /// ramp); `tau_s <= 0`: no acceleration state (velocity random walk).
    pub fn predict(&mut self, dt_s: f32, accel: f32, tau_s: f32) {
        if !self.init || dt_s.is_nan() || dt_s <= 0.0 {
            return;
        }
        let dt = dt_s.min(1.0);
        let q = accel * accel;
        let dt2 = dt * dt;
        if tau_s.is_nan() || tau_s <= 0.0 {
            self.a = 0.0;
            (self.p01, self.p11) = (0.0, 0.0);
            self.p00 += q * dt;
            return;
        }
        let e = 1.0 / (1.0 + dt / tau_s);
        self.v += self.a * dt;
        self.a *= e;
        // P = F P Fᵀ + Q with F = [[1, dt], [0, e]] and the continuous white-acceleration
        // noise integrated over dt (so the response in seconds does not depend on the rate).
        let p00 = self.p00 + 2.0 * dt * self.p01 + dt2 * self.p11 + q * dt2 * dt / 3.0;
        let p01 = e * (self.p01 + dt * self.p11) + q * dt2 * 0.5;
        let p11 = e * e * self.p11 + q * dt;
        (self.p00, self.p01, self.p11) = (p00, p01, p11);
    }

    /// Fuses the measurement `z` (m/s) of noise variance `r` ((m/s)²). `gate`: rejection
    /// threshold in innovation standard deviations (0 or less: never reject).
    /// `accel`: the acceleration noise, which sets the initial acceleration uncertainty.
    pub fn update(&mut self, z: f32, r: f32, gate: f32, accel: f32) -> Update {
        let r = if r.is_finite() {
            r.max(MIN_NOISE_VARIANCE)
        } else {
            UNKNOWN_NOISE_VARIANCE
        };
        if !z.is_finite() {
            return Update::Rejected;
        }
        if !self.init {
            self.restart(z, r, accel);
            return Update::Restarted;
        }
        let s = self.p00 + r;
        let nu = z - self.v;
        if gate > 0.0 && nu * nu > gate * gate * s {
            if let Some((z0, r0)) = self.rejected {
                let d = z - z0;
                if d * d <= gate * gate * (r + r0) {
                    self.restart(z, r, accel);
                    return Update::Restarted;
                }
            }
            self.rejected = Some((z, r));
            return Update::Rejected;
        }
        self.rejected = None;
        self.confirmed = true;
        let (k0, k1) = (self.p00 / s, self.p01 / s);
        self.v += k0 * nu;
        self.a += k1 * nu;
        // P = (I - K H) P.
        let p00 = (1.0 - k0) * self.p00;
        let p01 = (1.0 - k0) * self.p01;
        let p11 = self.p11 - k1 * self.p01;
        (self.p00, self.p01, self.p11) = (p00, p01, p11.max(0.0));
        Update::Accepted
    }

    fn restart(&mut self, z: f32, r: f32, accel: f32) {
        *self = Self {
            v: z,
            a: 0.0,
            p00: r,
            p01: 0.0,
            p11: accel * accel,
            init: true,
            confirmed: false,
            rejected: None,
        };
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    #[test]
    fn a_track_is_confirmed_by_its_second_agreeing_measurement() {
        let mut f = AxisFilter::new();
        assert_eq!(f.update(-60.0, 1.0, 1.5, 0.3), Update::Restarted);
        assert!(f.is_initialised() && !f.is_confirmed());
        // The next measurements disagree: rejected, then a restart at them, still unconfirmed.
        f.predict(0.04, 0.3, 0.0);
        assert_eq!(f.update(0.0, 0.01, 1.5, 0.3), Update::Rejected);
        assert!(!f.is_confirmed());
        f.predict(0.04, 0.3, 0.0);
        assert_eq!(f.update(0.01, 0.01, 1.5, 0.3), Update::Restarted);
        assert!(!f.is_confirmed());
        f.predict(0.04, 0.3, 0.0);
        assert_eq!(f.update(0.0, 0.01, 1.5, 0.3), Update::Accepted);
        assert!(f.is_confirmed());
    }

    /// Frames after a `0 -> step` m/s velocity step at `fps` until the output first exceeds
    /// half the step (0 = on the step's own frame), through the filter exactly as
    /// `EdgeFs` drives it with the default configuration (noise-free fits of standard error
    /// `sigma_fit`, variance scaled by the horizon in frames).
    fn step_lag(step: f32, fps: f32, sigma_fit: f32) -> usize {
        let p = crate::edge_fs::EdgeFsParams::default_config();
        let (q, tau, gate) = (p.filter_accel_mps2, p.filter_accel_tau_s, p.filter_gate);
        let span = libm::ceilf(p.horizon_s * fps - 1e-3).max(1.0);
        let s = p.filter_noise_scale * sigma_fit;
        let r = span * (s * s + p.filter_noise_floor_mps * p.filter_noise_floor_mps);
        let mut f = AxisFilter::new();
        for _ in 0..50 {
            f.predict(1.0 / fps, q, tau);
            f.update(0.0, r, gate, q);
        }
        for k in 0..100 {
            f.predict(1.0 / fps, q, tau);
            f.update(step, r, gate, q);
            if f.velocity() > 0.5 * step {
                return k;
            }
        }
        usize::MAX
    }

    #[test]
    fn tracks_a_ramp_without_lag_and_smooths_noise() {
        let mut f = AxisFilter::new();
        let dt = 0.1;
        let mut err2 = 0.0;
        let mut raw2 = 0.0;
        let mut bias = 0.0;
        let mut seed = 1u32;
        for k in 0..200 {
            let truth = 0.5 * (k as f32 * dt);
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let noise = ((seed >> 8) as f32 / (1 << 24) as f32 - 0.5) * 0.2;
            f.predict(dt, 0.5, 1.0);
            f.update(truth + noise, 0.0033, 0.0, 0.5);
            if k >= 50 {
                err2 += (f.velocity() - truth).powi(2);
                raw2 += noise * noise;
                bias += f.velocity() - truth;
            }
        }
        assert!(err2 < 0.5 * raw2, "filtered {err2} raw {raw2}");
        // The ramp gains 0.05 m/s per frame: less than half a frame of lag.
        assert!((bias / 150.0).abs() < 0.02, "ramp lag {}", bias / 150.0);
    }

    #[test]
    fn rejects_single_outliers_and_restarts_on_agreeing_ones() {
        let mut f = AxisFilter::new();
        for _ in 0..20 {
            f.predict(0.1, 1.0, 0.5);
            f.update(0.3, 0.01, 3.0, 1.0);
        }
        f.predict(0.1, 1.0, 0.5);
        assert_eq!(f.update(5.0, 0.01, 3.0, 1.0), Update::Rejected);
        assert!((f.velocity() - 0.3).abs() < 0.01);
        f.predict(0.1, 1.0, 0.5);
        assert_eq!(f.update(0.31, 0.01, 3.0, 1.0), Update::Accepted);
        // A real jump: rejected once, then the agreeing second sample restarts the filter.
        f.predict(0.1, 1.0, 0.5);
        assert_eq!(f.update(-1.0, 0.01, 3.0, 1.0), Update::Rejected);
        f.predict(0.1, 1.0, 0.5);
        assert_eq!(f.update(-1.02, 0.01, 3.0, 1.0), Update::Restarted);
        assert!((f.velocity() + 1.02).abs() < 1e-6);
        // Non-finite input never corrupts the state.
        assert_eq!(f.update(f32::NAN, 0.01, 3.0, 1.0), Update::Rejected);
        assert!(f.velocity().is_finite());
    }

    #[test]
    fn step_lag_against_a_median_of_five() {
        // A median of 5 passes a step on its 3rd new sample: 2 frames of lag at any size.
        // At the data set's 7 Hz the filter follows any step within 1 frame; at 25 Hz, large
        // steps (beyond the gate) restart it on the 2nd agreeing sample, small ones are
        // smoothed over about a quarter of a second.
        for step in [0.1f32, 0.2, 0.3, 0.5, 1.0] {
            let (l7, l25) = (step_lag(step, 7.0, 0.01), step_lag(step, 25.0, 0.01));
            std::println!("50 % step lag, {step} m/s: {l7} frames at 7 Hz, {l25} at 25 Hz");
            assert!(l7 <= 1, "{step} m/s at 7 Hz: {l7} frames");
            assert!(
                l25 as f32 / 25.0 <= 0.3,
                "{step} m/s at 25 Hz: {l25} frames"
            );
        }
        assert!(step_lag(1.0, 25.0, 0.01) <= 1);
    }
}
