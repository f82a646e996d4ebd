//! The MS5611 barometer as the autopilot sees it: the static pressure at the drone's height in
//! a room, with the sensor's noise, a slow drift (weather, doors, the sensor warming up) and
//! the rotors' wash near the floor.
//!
//! * Pressure falls about 12 Pa per metre near sea level (international standard atmosphere).
//! * Noise: 1.5 Pa (1 sigma) per reading, about 12 cm: the MS5611's 1.2 Pa resolution at OSR
//!   4096 (datasheet, "Operating range") plus room air movement.
//! * Drift: a random walk of 0.05 Pa per sqrt(s), about 7 cm over a 5-minute flight.
//! * Ground effect: within a few rotor diameters of the floor the wash raises the pressure
//!   under the drone, so the barometer reads low: +4 Pa (about 0.3 m) at the floor at hover
//!   thrust, decaying with a 0.15 m length, scaled with the thrust.

use super::imu::gauss;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The ISA's height scale of the barometric formula, T0 / L, m.
const ISA_HEIGHT_SCALE_M: f64 = 44_330.8;
/// The ISA's exponent of the barometric formula, g M / (R L).
const ISA_PRESSURE_EXPONENT: f64 = 5.255_88;

/// The barometer's error model.
#[derive(Debug, Clone, PartialEq)]
pub struct BaroParams {
    /// Pressure at the floor, Pa.
    pub floor_pa: f64,
    /// Noise per reading, Pa (1 sigma).
    pub noise_pa: f64,
    /// Drift, Pa per sqrt(s).
    pub drift_pa_per_sqrt_s: f64,
    /// Pressure rise at the floor from the rotors' wash at hover thrust, Pa.
    pub ground_effect_pa: f64,
    /// Decay length of the ground effect, m.
    pub ground_effect_length_m: f64,
    /// Readings per second.
    pub rate_hz: f64,
}

impl Default for BaroParams {
    fn default() -> Self {
        Self {
            floor_pa: 101_325.0,
            noise_pa: 1.5,
            drift_pa_per_sqrt_s: 0.05,
            ground_effect_pa: 4.0,
            ground_effect_length_m: 0.15,
            rate_hz: 50.0,
        }
    }
}

/// Static pressure `height_m` above a floor at `floor_pa` (ISA), Pa.
pub fn pressure_at(floor_pa: f64, height_m: f64) -> f64 {
    floor_pa * (1.0 - height_m / ISA_HEIGHT_SCALE_M).powf(ISA_PRESSURE_EXPONENT)
}

/// One barometer.
#[derive(Debug, Clone)]
pub struct Barometer {
    params: BaroParams,
    drift_pa: f64,
    last_s: Option<f64>,
    rng: ChaCha8Rng,
}

impl Barometer {
    /// A barometer with its noise drawn from `seed`.
    pub fn new(params: BaroParams, seed: u64) -> Self {
        Self {
            params,
            drift_pa: 0.0,
            last_s: None,
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0xba80),
        }
    }

    /// Its parameters.
    pub fn params(&self) -> &BaroParams {
        &self.params
    }

    /// The reading at world time `t_s` at height `height_m` above the floor, with the rotors
    /// at `thrust_ratio` of hover thrust, Pa.
    pub fn read(&mut self, t_s: f64, height_m: f64, thrust_ratio: f64) -> f64 {
        let dt = self.last_s.map_or(0.0, |last| (t_s - last).max(0.0));
        self.last_s = Some(t_s);
        self.drift_pa += gauss(&mut self.rng) * self.params.drift_pa_per_sqrt_s * dt.sqrt();
        let p = &self.params;
        let wash = p.ground_effect_pa
            * thrust_ratio.clamp(0.0, 2.0)
            * (-height_m.max(0.0) / p.ground_effect_length_m).exp();
        pressure_at(p.floor_pa, height_m) + wash + self.drift_pa + gauss(&mut self.rng) * p.noise_pa
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_metre_is_about_twelve_pascal_and_the_wash_reads_low_near_the_floor() {
        let p = BaroParams {
            noise_pa: 0.0,
            drift_pa_per_sqrt_s: 0.0,
            ..BaroParams::default()
        };
        let mut b = Barometer::new(p.clone(), 1);
        let drop = b.read(0.0, 0.0, 0.0) - b.read(0.1, 1.0, 0.0);
        assert!((drop - 12.0).abs() < 0.3, "{drop}");
        let wash = b.read(0.2, 0.05, 1.0) - pressure_at(p.floor_pa, 0.05);
        assert!(wash > 2.5 && wash < 4.0, "{wash}");
        let high = b.read(0.3, 1.0, 1.0) - pressure_at(p.floor_pa, 1.0);
        assert!(high.abs() < 0.01, "no wash at 1 m: {high}");
    }

    #[test]
    fn noise_and_drift_are_as_configured() {
        let mut b = Barometer::new(BaroParams::default(), 3);
        let n = 15_000;
        let readings: Vec<f64> = (0..n).map(|i| b.read(i as f64 * 0.02, 1.0, 0.0)).collect();
        let mean = readings.iter().sum::<f64>() / n as f64;
        let first = readings[..500].iter().sum::<f64>() / 500.0;
        let sd = (readings[..500]
            .iter()
            .map(|r| (r - first) * (r - first))
            .sum::<f64>()
            / 500.0)
            .sqrt();
        assert!((sd - 1.5).abs() < 0.25, "noise {sd} Pa");
        // Five minutes of drift stays within a few sigma of 0.05 * sqrt(300) = 0.87 Pa.
        assert!((mean - pressure_at(101_325.0, 1.0)).abs() < 3.0, "{mean}");
    }
}
