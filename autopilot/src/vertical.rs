//! Vertical state estimation without motion capture: a three-state Kalman filter over height,
//! climb rate and the barometer's offset, driven by the accelerometer and corrected by the
//! MS5611's pressure altitude, the camera board's climb rate (its vertical flow, when that is
//! on) and, when one arrives, an external height fix (motion capture in the paper's lab).
//!
//! ```text
//! state  x = [h, v, b]       height above the take-off floor (m, up), climb rate (m/s, up),
//!                            barometer offset (m: what the barometer reads at the true height 0)
//! model  h' = h + v dt + a dt^2 / 2,  v' = v + a dt,  b' = b (+ random walk)
//!        a: vertical acceleration from the IMU (specific force rotated to the world, plus g)
//! baro   z = h + b          noise sigma_baro (about 0.1 m for the MS5611 at OSR 4096)
//! fix    z = h              noise sigma_fix (about 1 cm for motion capture)
//! climb  z = v              noise sigma_climb (the camera's vertical velocity turned to the
//!                           world with the attitude; see `Autopilot::on_estimate`)
//! ```
//!
//! The offset absorbs the reference pressure of the day and its slow drift, so no calibration
//! step is needed: the first reading sets the reference (the drone stands on the floor at
//! boot). Within [`VerticalConfig::ground_effect_height_m`] of the floor the running rotors' wash raises
//! the static pressure under the drone and the barometer reads low; there its noise is
//! inflated so the accelerometer and the offset carry the estimate through. A reading whose
//! innovation is beyond [`VerticalConfig::gate_sigma`] standard deviations is rejected and
//! counted. Nothing here allocates or panics; non-finite inputs are ignored.

use timebase::Duration;

/// Tuning of the vertical estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VerticalConfig {
    /// Vertical acceleration noise, m/s^2 per sqrt(Hz) (vibration, thrust and drag not in the
    /// model).
    pub accel_noise: f32,
    /// Barometer offset random walk, m per sqrt(s) (weather, temperature drift).
    pub baro_offset_walk: f32,
    /// Barometer height noise, m (1 sigma).
    pub baro_noise_m: f32,
    /// External height fix noise, m (1 sigma).
    pub fix_noise_m: f32,
    /// Below this estimated height the barometer is in the rotors' ground effect, m.
    pub ground_effect_height_m: f32,
    /// Barometer noise multiplier in ground effect.
    pub ground_effect_noise_factor: f32,
    /// Innovation gate, standard deviations.
    pub gate_sigma: f32,
    /// Whether external height fixes (`ExternalPosition`: motion capture, the HIL bench) are
    /// used at all. Off on a drone that flies without motion capture: then nothing a host sends
    /// moves its height, signed or not.
    pub external_fixes: bool,
    /// A barometer whose readings (pressure and temperature, as compensated from the raw
    /// conversions) stay bit-for-bit identical for longer than this is frozen: its readings
    /// are not used (as a stuck IMU's), so the height failsafe acts without fixes. A live
    /// MS5611's noise (about 1.5 Pa rms on a 1 Pa resolution) repeats a reading with about
    /// 0.3 probability: 25 repeats in a row (0.5 s at 50 Hz) happen with about 1e-13.
    pub baro_stuck: Duration,
    /// Whether the camera board's climb rate (`Estimate::up_mps`, produced only with its
    /// vertical flow on) corrects the climb-rate state. Off: in the simulator (room, seeds
    /// 5151 and 5152, 60 s, vertical flow on: camera parameter `vertical_search = 8`) the camera's
    /// valid climb rate reads 0.03 m/s through a 0.85 m/s take-off and about half the true
    /// rate in the climb after it (0.29 against 0.52 m/s); fused, at any noise from 0.02 to
    /// 0.2 m/s, the height estimate lags the climb and the drone overshoots its target height:
    /// seed 5151 hits the ceiling at 5.4 s, seed 5152 lands on `no texture`. Without the
    /// fusion both fly the 60 s (height RMS error 0.057 m).
    pub camera_climb: bool,
    /// Camera climb-rate noise, m/s (1 sigma): the spread of the valid `up_mps` against the
    /// true climb rate in the simulator's hover (room, seeds 5151 and 5152, motion capture,
    /// vertical flow on): 0.02 m/s RMS at most (0.013 m/s about its mean). Its frames are not
    /// independent (the board's temporal filter smooths over several).
    pub climb_noise_mps: f32,
}

impl Default for VerticalConfig {
    fn default() -> Self {
        Self {
            accel_noise: 0.5,
            baro_offset_walk: 0.01,
            baro_noise_m: 0.1,
            fix_noise_m: 0.01,
            ground_effect_height_m: 0.3,
            ground_effect_noise_factor: 5.0,
            gate_sigma: 5.0,
            external_fixes: true,
            baro_stuck: Duration::from_millis(500),
            camera_climb: false,
            climb_noise_mps: 0.02,
        }
    }
}

/// External height fixes the vertical estimator must take in a row before they are the height
/// loop's measurement (100 ms of a 50 Hz motion-capture stream): one fix, even one the gate
/// takes, makes no height fresh for arming.
pub const FIXES_TO_LEAD: u8 = 5;

/// Height of `pressure_pa` above the level of `reference_pa` (international standard
/// atmosphere, valid for the few metres of a room), m.
pub fn pressure_altitude_m(pressure_pa: f32, reference_pa: f32) -> f32 {
    // h = T0 / L * (1 - (p / p0)^(R L / g M)), T0 / L = 44,330.8 m, exponent 0.190263.
    44_330.8 * (1.0 - libm::powf(pressure_pa / reference_pa, 0.190_263))
}

/// The vertical Kalman filter.
#[derive(Debug, Clone)]
pub struct VerticalEstimator {
    cfg: VerticalConfig,
    /// [h, v, b].
    x: [f32; 3],
    /// Covariance of `x`.
    p: [[f32; 3]; 3],
    reference_pa: Option<f32>,
    rejected: u32,
    /// Consecutive rejections of the barometer and of the fixes.
    rejected_in_row: [u8; 2],
    /// Time since the last accepted height fix, s.
    since_fix_s: f32,
}

/// After this many consecutive rejections a source is believed and the filter re-initialised
/// from it (the prior was wrong, not the sensor: a fix from a floor the filter did not take
/// off from, a barometer after a pressure step).
const REINIT_AFTER: u8 = 5;
/// A height fix this recent makes the fix, not the floor, the height reference on the ground,
/// s.
const FIX_HOLDS_S: f32 = 0.5;

impl VerticalEstimator {
    /// Takes a new configuration, keeping the state (used from the next step on).
    pub fn set_config(&mut self, cfg: VerticalConfig) {
        self.cfg = cfg;
    }

    /// A filter that has seen nothing: at the floor, at rest, offset unknown.
    pub fn new(cfg: VerticalConfig) -> Self {
        Self {
            cfg,
            x: [0.0; 3],
            p: [[1.0, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 1.0]],
            reference_pa: None,
            rejected: 0,
            rejected_in_row: [0; 2],
            since_fix_s: f32::INFINITY,
        }
    }

    /// Estimated height above the take-off floor, m.
    pub fn height_m(&self) -> f32 {
        self.x[0]
    }

    /// Estimated climb rate, m/s (up).
    pub fn climb_mps(&self) -> f32 {
        self.x[1]
    }

    /// Estimated barometer offset, m.
    pub fn baro_offset_m(&self) -> f32 {
        self.x[2]
    }

    /// Standard deviation of the height estimate, m.
    pub fn height_sigma_m(&self) -> f32 {
        libm::sqrtf(self.p[0][0].max(0.0))
    }

    /// Whether a height fix was accepted within the last 0.5 s: the fixes are then the height
    /// reference.
    pub fn has_recent_fix(&self) -> bool {
        self.since_fix_s <= FIX_HOLDS_S
    }

    /// Measurements rejected by the innovation gate.
    pub fn rejected(&self) -> u32 {
        self.rejected
    }

    /// Propagates the state over `dt_s` with the vertical acceleration `accel_up_mps2` (world
    /// frame, up, gravity removed).
    pub fn predict(&mut self, accel_up_mps2: f32, dt_s: f32) {
        if !(accel_up_mps2.is_finite() && dt_s.is_finite() && dt_s > 0.0 && dt_s < 0.5) {
            return;
        }
        let a = accel_up_mps2.clamp(-50.0, 50.0);
        let dt = dt_s;
        self.since_fix_s += dt;
        self.x[0] += self.x[1] * dt + 0.5 * a * dt * dt;
        self.x[1] += a * dt;
        // P = F P F^T + Q, F = [[1, dt, 0], [0, 1, 0], [0, 0, 1]].
        let p = self.p;
        let mut n = p;
        n[0][0] = p[0][0] + dt * (p[1][0] + p[0][1]) + dt * dt * p[1][1];
        n[0][1] = p[0][1] + dt * p[1][1];
        n[1][0] = n[0][1];
        n[0][2] = p[0][2] + dt * p[1][2];
        n[2][0] = n[0][2];
        let qa = self.cfg.accel_noise * self.cfg.accel_noise * dt;
        n[0][0] += qa * dt * dt / 3.0;
        n[0][1] += qa * dt / 2.0;
        n[1][0] += qa * dt / 2.0;
        n[1][1] += qa;
        n[2][2] += self.cfg.baro_offset_walk * self.cfg.baro_offset_walk * dt;
        self.p = n;
    }

    /// A barometer reading, with the rotors running or not (stopped, there is no wash); returns
    /// whether it was used.
    pub fn on_pressure(&mut self, pressure_pa: f32, rotors_running: bool) -> bool {
        if !(pressure_pa.is_finite() && (30_000.0..120_000.0).contains(&pressure_pa)) {
            return false;
        }
        let reference = *self.reference_pa.get_or_insert(pressure_pa);
        let z = pressure_altitude_m(pressure_pa, reference);
        let mut sigma = self.cfg.baro_noise_m;
        if rotors_running && self.x[0] < self.cfg.ground_effect_height_m {
            sigma *= self.cfg.ground_effect_noise_factor;
        }
        if self.update([1.0, 0.0, 1.0], z, sigma * sigma) {
            self.rejected_in_row[0] = 0;
            return true;
        }
        self.rejected_in_row[0] = self.rejected_in_row[0].saturating_add(1);
        if self.rejected_in_row[0] >= REINIT_AFTER {
            // Keep the height; the barometer's offset is what changed.
            self.x[2] = z - self.x[0];
            self.p[2] = [0.0, 0.0, sigma * sigma];
            self.p[0][2] = 0.0;
            self.p[1][2] = 0.0;
            self.rejected_in_row[0] = 0;
        }
        false
    }

    /// An external height fix (m above the floor, motion capture); returns whether it was
    /// used.
    pub fn on_height_fix(&mut self, height_m: f32) -> bool {
        if !(height_m.is_finite() && (-1.0..100.0).contains(&height_m)) {
            return false;
        }
        let r = self.cfg.fix_noise_m * self.cfg.fix_noise_m;
        if self.update([1.0, 0.0, 0.0], height_m, r) {
            self.rejected_in_row[1] = 0;
            self.since_fix_s = 0.0;
            return true;
        }
        self.rejected_in_row[1] = self.rejected_in_row[1].saturating_add(1);
        if self.rejected_in_row[1] >= REINIT_AFTER {
            // The fix is the height reference: start again from it, keeping what the
            // barometer reads (its offset follows).
            let baro_reading = self.x[0] + self.x[2];
            self.x[0] = height_m;
            self.x[2] = baro_reading - height_m;
            self.p = [
                [r, 0.0, 0.0],
                [0.0, self.p[1][1], 0.0],
                [0.0, 0.0, self.p[2][2]],
            ];
            self.rejected_in_row[1] = 0;
            self.since_fix_s = 0.0;
            return true;
        }
        false
    }

    /// A climb-rate measurement (m/s, up, world frame) with its noise `sigma_mps` (1 sigma):
    /// the camera's vertical velocity. Gated as the other measurements (a rejection is
    /// counted); a non-finite or absurd value (beyond 20 m/s) or sigma is ignored. Returns
    /// whether it was used.
    pub fn on_climb_rate(&mut self, climb_mps: f32, sigma_mps: f32) -> bool {
        let sane = climb_mps.is_finite() && climb_mps.abs() <= 20.0;
        if !(sane && sigma_mps.is_finite() && sigma_mps > 0.0) {
            return false;
        }
        self.update([0.0, 1.0, 0.0], climb_mps, sigma_mps * sigma_mps)
    }

    /// Tells the filter the drone stands on the floor (disarmed, touched down): the climb is
    /// zero, and unless height fixes are coming in (they are the reference then) so is the
    /// height, and what the barometer reads now is its offset.
    pub fn on_ground(&mut self) {
        self.x[1] = 0.0;
        self.p[1] = [0.0, 1e-4, 0.0];
        self.p[0][1] = 0.0;
        self.p[2][1] = 0.0;
        if self.since_fix_s > FIX_HOLDS_S {
            self.x[0] = 0.0;
            self.p[0] = [1e-4, 0.0, 0.0];
            self.p[2][0] = 0.0;
        }
    }

    /// The scalar update with measurement row `h`, value `z`, variance `r`.
    fn update(&mut self, h: [f32; 3], z: f32, r: f32) -> bool {
        let p = self.p;
        let ph: [f32; 3] = core::array::from_fn(|i| (0..3).map(|j| p[i][j] * h[j]).sum());
        let s = (0..3).map(|i| h[i] * ph[i]).sum::<f32>() + r;
        let predicted: f32 = (0..3).map(|i| h[i] * self.x[i]).sum();
        let innovation = z - predicted;
        if !(s.is_finite() && s > 0.0) {
            return false;
        }
        if innovation * innovation > self.cfg.gate_sigma * self.cfg.gate_sigma * s {
            self.rejected = self.rejected.saturating_add(1);
            return false;
        }
        let k: [f32; 3] = core::array::from_fn(|i| ph[i] / s);
        for (x, k) in self.x.iter_mut().zip(k) {
            *x += k * innovation;
        }
        // P = (I - K H) P, then symmetrised.
        let mut n = p;
        for (i, row) in n.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = p[i][j] - k[i] * ph[j];
            }
        }
        for (i, j) in [(0, 1), (0, 2), (1, 2)] {
            let m = 0.5 * (n[i][j] + n[j][i]);
            n[i][j] = m;
            n[j][i] = m;
        }
        self.p = n;
        true
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    /// Sea-level standard pressure, Pa.
    const P0: f32 = 101_325.0;

    /// The pressure at `h` m above the reference level (the inverse of
    /// [`pressure_altitude_m`]).
    fn pressure_at(h: f32) -> f32 {
        P0 * libm::powf(1.0 - h / 44_330.8, 5.255_88)
    }

    /// A small deterministic generator of unit-variance noise.
    struct Noise(u64);
    impl Noise {
        fn gauss(&mut self) -> f32 {
            let mut sum = 0.0;
            for _ in 0..12 {
                self.0 = self
                    .0
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1);
                sum += (self.0 >> 40) as f32 / (1u64 << 24) as f32;
            }
            sum - 6.0
        }
    }

    #[test]
    fn pressure_altitude_is_about_8_cm_per_pascal_near_sea_level() {
        let h = pressure_altitude_m(P0 - 12.0, P0);
        assert!((h - 1.0).abs() < 0.02, "{h}");
        assert!((pressure_altitude_m(pressure_at(2.0), P0) - 2.0).abs() < 1e-3);
    }

    /// A 1 m climb and hold, barometer at 50 Hz with 0.1 m noise, accelerometer at 512 Hz with
    /// 0.3 m/s^2 noise, a barometer drift of 0.05 m over 30 s (the weather; without a fix a
    /// drift is indistinguishable from a climb, so it is height error): the height stays
    /// within 0.1 m RMS of the truth.
    #[test]
    fn barometer_and_accelerometer_hold_height_without_a_fix() {
        let mut f = VerticalEstimator::new(VerticalConfig::default());
        let mut noise = Noise(7);
        let dt = 1.0 / 512.0;
        let (mut h, mut v) = (0.0f32, 0.0f32);
        let (mut sq, mut n) = (0.0f32, 0);
        for i in 0..(512 * 30) {
            let t = i as f32 * dt;
            // Climb to 1 m between 2 s and 4 s (a smooth profile), hold.
            let a = if (2.0..3.0).contains(&t) {
                0.8
            } else if (3.0..4.0).contains(&t) {
                -0.8
            } else {
                0.0
            };
            h += v * dt + 0.5 * a * dt * dt;
            v += a * dt;
            f.predict(a + 0.3 * noise.gauss(), dt);
            if i % 10 == 0 {
                let drift = 0.05 * t / 30.0;
                let z = pressure_at(h + drift + 0.1 * noise.gauss());
                f.on_pressure(z, true);
            }
            if t > 5.0 {
                sq += (f.height_m() - h) * (f.height_m() - h);
                n += 1;
            }
        }
        let rms = libm::sqrtf(sq / n as f32);
        assert!((h - 0.8).abs() < 0.05, "the profile climbs 0.8 m: {h}");
        assert!(rms < 0.1, "height RMS error {rms} m");
        std::println!("vertical estimate without a fix: height RMS error {rms:.3} m");
        assert_eq!(f.rejected(), 0);
    }

    #[test]
    fn a_height_fix_dominates_and_a_wild_reading_is_rejected() {
        let mut f = VerticalEstimator::new(VerticalConfig::default());
        let dt = 1.0 / 512.0;
        for i in 0..512 {
            f.predict(0.0, dt);
            if i % 5 == 0 {
                assert!(f.on_height_fix(0.5));
            }
            if i % 10 == 0 {
                f.on_pressure(pressure_at(0.0), false);
            }
        }
        assert!((f.height_m() - 0.5).abs() < 0.02, "{}", f.height_m());
        // The barometer still reads the floor: its offset took the difference.
        assert!(
            (f.baro_offset_m() + 0.5).abs() < 0.1,
            "{}",
            f.baro_offset_m()
        );
        assert!(!f.on_height_fix(25.0), "a 24.5 m jump is gated");
        assert_eq!(f.rejected(), 1);
        assert!(
            f.on_height_fix(0.5),
            "and forgotten when the fixes agree again"
        );
        for _ in 0..4 {
            assert!(!f.on_height_fix(0.9));
        }
        assert!(
            f.on_height_fix(0.9),
            "five fixes in a row that disagree are believed"
        );
        assert!((f.height_m() - 0.9).abs() < 1e-6);
        assert!(!f.on_pressure(f32::NAN, true));
        assert!(!f.on_height_fix(f32::INFINITY));
        f.predict(f32::NAN, dt);
        assert!(f.height_m().is_finite());
    }

    #[test]
    fn on_the_ground_the_height_is_zero_and_the_offset_is_kept() {
        let mut f = VerticalEstimator::new(VerticalConfig::default());
        for _ in 0..50 {
            f.on_pressure(pressure_at(0.0), false);
            f.predict(0.05, 0.02);
        }
        f.on_pressure(pressure_at(0.3), false);
        f.on_ground();
        assert_eq!(f.height_m(), 0.0);
        assert_eq!(f.climb_mps(), 0.0);
        assert!(f.height_sigma_m() < 0.02);
    }

    /// A constant climb of 0.3 m/s seen only by the camera (25 Hz, 0.05 m/s noise; the
    /// accelerometer reads nothing, as it would at a constant rate): the climb rate converges
    /// to it.
    #[test]
    fn the_climb_rate_converges_to_the_cameras() {
        let mut f = VerticalEstimator::new(VerticalConfig::default());
        let mut noise = Noise(11);
        let dt = 1.0 / 512.0;
        let (mut sum, mut n) = (0.0, 0);
        for i in 0..(512 * 5) {
            f.predict(0.3 * noise.gauss(), dt);
            if i % 20 == 0 {
                assert!(f.on_climb_rate(0.3 + 0.05 * noise.gauss(), 0.05));
            }
            if i >= 512 * 2 {
                sum += f.climb_mps();
                n += 1;
            }
        }
        let mean = sum / n as f32;
        assert!(
            (mean - 0.3).abs() < 0.02,
            "mean climb rate of the last 3 s {mean}"
        );
        assert!((f.climb_mps() - 0.3).abs() < 0.15, "{}", f.climb_mps());
        assert_eq!(f.rejected(), 0);
    }

    #[test]
    fn a_wild_climb_rate_is_rejected_and_counted_and_nonsense_ignored() {
        let mut f = VerticalEstimator::new(VerticalConfig::default());
        let dt = 1.0 / 512.0;
        for i in 0..512 {
            f.predict(0.0, dt);
            if i % 20 == 0 {
                assert!(f.on_climb_rate(0.0, 0.1));
            }
        }
        assert!(!f.on_climb_rate(3.0, 0.1), "3 m/s out of hover is gated");
        assert_eq!(f.rejected(), 1);
        assert!(f.climb_mps().abs() < 0.01, "{}", f.climb_mps());
        assert!(!f.on_climb_rate(f32::NAN, 0.1));
        assert!(!f.on_climb_rate(0.1, 0.0));
        assert!(!f.on_climb_rate(0.1, f32::INFINITY));
        assert!(!f.on_climb_rate(1e9, 1e9));
        assert_eq!(f.rejected(), 1, "nonsense is ignored, not counted");
        assert!(f.on_climb_rate(0.05, 0.1));
    }

    /// Hovering at the reference height for 60 s while the barometer drifts up 0.3 m (a ramp
    /// on its pressure altitude, with 0.1 m noise): alone, the filter takes most of the drift
    /// as height (0.26 m); with the camera's climb rate of zero (25 Hz, 0.05 m/s noise) more
    /// of it goes to the barometer's offset (0.16 m of height error: the height is still the
    /// integral of a climb rate known to 0.05 m/s).
    #[test]
    fn the_cameras_climb_rate_holds_the_height_against_barometer_drift() {
        let final_error = |camera: bool| {
            let mut f = VerticalEstimator::new(VerticalConfig::default());
            let mut noise = Noise(3);
            let dt = 1.0 / 512.0;
            for i in 0..(512 * 60) {
                let t = i as f32 * dt;
                f.predict(0.3 * noise.gauss(), dt);
                if i % 10 == 0 {
                    let drift = 0.3 * t / 60.0;
                    f.on_pressure(pressure_at(drift + 0.1 * noise.gauss()), false);
                }
                if camera && i % 20 == 0 {
                    f.on_climb_rate(0.05 * noise.gauss(), 0.05);
                }
            }
            f.height_m().abs()
        };
        let (without, with) = (final_error(false), final_error(true));
        std::println!("height error after a 0.3 m barometer drift: {without:.3} m without the camera's climb rate, {with:.3} m with");
        assert!(without > 0.2, "{without}");
        assert!(with < 0.2 && with < 0.7 * without, "{with} vs {without}");
    }

    /// Disarmed on a stand or under a motion-capture floor that is not the take-off floor: the
    /// fixes are the reference, the floor reset does not fight them.
    #[test]
    fn fixes_on_the_ground_win_over_the_floor() {
        let mut f = VerticalEstimator::new(VerticalConfig::default());
        for i in 0..500 {
            f.predict(0.0, 1.0 / 512.0);
            if i % 5 == 0 {
                f.on_height_fix(1.0);
            }
            if i % 10 == 0 {
                f.on_ground();
            }
        }
        assert!((f.height_m() - 1.0).abs() < 0.01, "{}", f.height_m());
    }
}
