//! MPU-6000-class IMU model sampled at 512 Hz: white noise, bias random walk, a constant
//! turn-on bias and rotor-frequency vibration.

use super::dynamics::Drone;
use super::math::V3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// IMU noise parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct ImuParams {
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Gyro white noise density, rad/s/√Hz (MPU-6000: 0.005 °/s/√Hz).
    pub gyro_noise_density: f64,
    /// Accelerometer white noise density, m/s²/√Hz (MPU-6000: 400 µg/√Hz).
    pub accel_noise_density: f64,
    /// Gyro bias random walk, rad/s/√s.
    pub gyro_bias_walk: f64,
    /// Accelerometer bias random walk, m/s²/√s.
    pub accel_bias_walk: f64,
    /// Standard deviation of the turn-on gyro bias, rad/s (MPU-6000: ±20 °/s before
    /// calibration; after the usual power-up calibration about 0.5 °/s).
    pub gyro_turn_on_bias: f64,
    /// Standard deviation of the turn-on accelerometer bias, m/s² (after calibration).
    pub accel_turn_on_bias: f64,
    /// Vibration acceleration amplitude at hover rotor speed, m/s² (scales with rotor speed²).
    pub vib_accel_mps2: f64,
    /// Vibration angular-rate amplitude at hover rotor speed, rad/s.
    pub vib_gyro_radps: f64,
    /// Digital low-pass filter of the sensor (MPU-6000 DLPF), Hz; applied as a first-order
    /// filter on the internal 1 kHz-class signal approximated at the physics rate.
    pub dlpf_hz: f64,
}

impl Default for ImuParams {
    fn default() -> Self {
        Self {
            rate_hz: 512.0,
            gyro_noise_density: 0.005_f64.to_radians(),
            accel_noise_density: 400e-6 * 9.81,
            gyro_bias_walk: 3e-5,
            accel_bias_walk: 3e-4,
            gyro_turn_on_bias: 0.5_f64.to_radians(),
            accel_turn_on_bias: 0.05,
            vib_accel_mps2: 1.5,
            vib_gyro_radps: 0.03,
            dlpf_hz: 98.0,
        }
    }
}

/// One IMU reading, body frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuReading {
    /// Body rates, rad/s.
    pub gyro: V3,
    /// Specific force, m/s².
    pub accel: V3,
}

/// Stateful IMU model.
#[derive(Debug, Clone)]
pub struct Imu {
    /// Parameters.
    pub params: ImuParams,
    gyro_bias: V3,
    accel_bias: V3,
    rotor_phase: [f64; 4],
    lp_gyro: V3,
    lp_accel: V3,
}

fn gauss3(rng: &mut ChaCha8Rng, sigma: f64) -> V3 {
    V3::new(gauss(rng) * sigma, gauss(rng) * sigma, gauss(rng) * sigma)
}

/// A standard normal sample (Box-Muller).
pub fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (core::f64::consts::TAU * u2).cos()
}

impl Imu {
    /// A new IMU with turn-on biases drawn from `rng`.
    pub fn new(params: ImuParams, rng: &mut ChaCha8Rng) -> Self {
        let gyro_bias = gauss3(rng, params.gyro_turn_on_bias);
        let accel_bias = gauss3(rng, params.accel_turn_on_bias);
        Self {
            params,
            gyro_bias,
            accel_bias,
            rotor_phase: [0.0, 1.3, 2.9, 4.4],
            lp_gyro: V3::ZERO,
            lp_accel: V3::new(0.0, 0.0, -9.81),
        }
    }

    /// Called every physics step (`dt` s): advances the vibration phases and the sensor's
    /// internal low-pass filter on the true signal plus vibration.
    pub fn track(&mut self, drone: &Drone, dt: f64) {
        let p = &self.params;
        let hover_w = drone.params.hover_throttle() * drone.params.rotor_max_radps;
        let mut vib_a = V3::ZERO;
        let mut vib_g = V3::ZERO;
        for i in 0..4 {
            let w = drone.state.rotor_radps[i];
            self.rotor_phase[i] = (self.rotor_phase[i] + w * dt) % core::f64::consts::TAU;
            let s = (w / hover_w).powi(2) * self.rotor_phase[i].sin();
            let c = (w / hover_w).powi(2) * self.rotor_phase[i].cos();
            // Unbalanced rotors shake the frame mostly in the rotor plane and a little in z.
            vib_a += V3::new(s, c, 0.5 * s) * (p.vib_accel_mps2 * 0.25);
            vib_g += V3::new(c, s, 0.3 * c) * (p.vib_gyro_radps * 0.25);
        }
        let g = drone.state.rates + vib_g;
        let a = drone.specific_force_body + vib_a;
        let alpha = 1.0 - (-core::f64::consts::TAU * p.dlpf_hz * dt).exp();
        self.lp_gyro = self.lp_gyro + (g - self.lp_gyro) * alpha;
        self.lp_accel = self.lp_accel + (a - self.lp_accel) * alpha;
    }

    /// Takes one sample (call at [`ImuParams::rate_hz`]): filtered truth + bias + white noise.
    pub fn sample(&mut self, rng: &mut ChaCha8Rng) -> ImuReading {
        let p = &self.params;
        let dt = 1.0 / p.rate_hz;
        self.gyro_bias += gauss3(rng, p.gyro_bias_walk * dt.sqrt());
        self.accel_bias += gauss3(rng, p.accel_bias_walk * dt.sqrt());
        let bw = (p.rate_hz * 0.5).sqrt();
        ImuReading {
            gyro: self.lp_gyro + self.gyro_bias + gauss3(rng, p.gyro_noise_density * bw),
            accel: self.lp_accel + self.accel_bias + gauss3(rng, p.accel_noise_density * bw),
        }
    }

    /// Current gyro bias, rad/s (truth, for tests and logs).
    pub fn gyro_bias(&self) -> V3 {
        self.gyro_bias
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::dynamics::DroneParams;
    use rand::SeedableRng;

    #[test]
    fn at_rest_reads_gravity_and_small_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let params = ImuParams {
            vib_accel_mps2: 0.0,
            vib_gyro_radps: 0.0,
            ..ImuParams::default()
        };
        let mut imu = Imu::new(params, &mut rng);
        let d = Drone::on_floor(DroneParams::pocket_drone(), 0.0, 0.0, 0.0);
        let mut sum_a = V3::ZERO;
        let mut sum_g2 = 0.0;
        let n = 5120;
        for k in 0..n * 4 {
            imu.track(&d, 1.0 / 2048.0);
            if k % 4 == 3 {
                let r = imu.sample(&mut rng);
                sum_a += r.accel;
                let e = r.gyro - imu.gyro_bias();
                sum_g2 += e.dot(e);
            }
        }
        let mean_a = sum_a * (1.0 / n as f64);
        assert!((mean_a.z + 9.81).abs() < 0.2, "{mean_a:?}");
        let sigma_g = (sum_g2 / (3.0 * n as f64)).sqrt();
        // 0.005 deg/s/sqrt(Hz) over 256 Hz: ~1.4e-3 rad/s.
        assert!(sigma_g > 0.8e-3 && sigma_g < 2.0e-3, "sigma {sigma_g}");
    }
}
