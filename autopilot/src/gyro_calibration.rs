//! Ground gyro calibration: while the drone stands still on the ground, the mean gyro over a
//! block of samples becomes the gyro offset.
//!
//! Takes: each IMU sample while the motors cannot run (disarmed, killed, IMU fault), with the
//! block length and the stillness limit ([`GyroCalibrationConfig`]). Gives: the offset
//! ([`GyroCalibration::offset`]) and every gyro sample corrected by it
//! ([`GyroCalibration::correct`], on the 512 Hz path whether armed or not);
//! [`GyroCalibration::update`] says when a block gave the first offset since boot (the caller
//! then restarts the attitude estimate without the tilt error the uncorrected gyro built up).
//!
//! A sample is still while every gyro axis is below the limit and the specific force is within
//! 5 % of 1 g; any other sample restarts the block. Each full block replaces the offset.

use crate::attitude::GRAVITY;
use protocol::ImuSample;

/// The board is still while the specific force is within this fraction of gravity (and every
/// rate below the still threshold).
const STILL_ACCEL_FRACTION: f32 = 0.05;

/// Ground gyro calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GyroCalibrationConfig {
    /// Ground gyro calibration: while disarmed and still, the mean gyro over this many IMU
    /// samples becomes the gyro offset (every later sample is corrected by it). The
    /// MPU-6000's zero-rate offset is ±0.5 deg/s-class even after factory trim; uncorrected,
    /// the attitude filter's low accelerometer gain leaves a tilt error of `offset / kp`
    /// (several degrees) that the velocity loop then flies as a trim.
    pub samples: u16,
    /// A sample counts as still while every gyro axis is below this, rad/s, and the
    /// specific force is within 5 % of 1 g; anything else restarts the average.
    pub still_radps: f32,
}

impl Default for GyroCalibrationConfig {
    fn default() -> Self {
        Self {
            samples: 256,
            still_radps: 0.1,
        }
    }
}

/// Block average of still gyro samples and the offset it gave.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GyroCalibration {
    /// Offset from the last full block, rad/s.
    offset: Option<[f32; 3]>,
    /// Sum of the current block's samples, rad/s.
    sum: [f32; 3],
    /// Samples in the current block.
    n: u16,
}

impl GyroCalibration {
    /// Not calibrated, empty block.
    pub fn new() -> Self {
        Self::default()
    }

    /// Gyro offset from the last full block, rad/s (`None`: not calibrated yet).
    pub fn offset(&self) -> Option<[f32; 3]> {
        self.offset
    }

    /// `gyro_radps` less the offset (as it is before the first calibration), rad/s.
    #[inline]
    pub fn correct(&self, gyro_radps: [f32; 3]) -> [f32; 3] {
        let off = self.offset.unwrap_or([0.0; 3]);
        [
            gyro_radps[0] - off[0],
            gyro_radps[1] - off[1],
            gyro_radps[2] - off[2],
        ]
    }

    /// One sample on the ground: blocks of `samples` still ones (every gyro axis below
    /// `still_radps`, the specific force within 5 % of 1 g) become the offset. True when this
    /// sample completed the first block since boot.
    pub fn update(&mut self, imu: &ImuSample, samples: u16, still_radps: f32) -> bool {
        let g = imu.gyro_radps;
        let a = imu.accel_mps2;
        let an = libm::sqrtf(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        let still = g.iter().all(|x| x.abs() < still_radps)
            && (an - GRAVITY).abs() < STILL_ACCEL_FRACTION * GRAVITY;
        if !still {
            self.sum = [0.0; 3];
            self.n = 0;
            return false;
        }
        for (s, x) in self.sum.iter_mut().zip(g.iter()) {
            *s += x;
        }
        self.n = self.n.saturating_add(1);
        if self.n < samples.max(1) {
            return false;
        }
        let k = 1.0 / self.n as f32;
        let first = self.offset.is_none();
        self.offset = Some(self.sum.map(|s| s * k));
        self.sum = [0.0; 3];
        self.n = 0;
        first
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::WireTime;

    fn sample(gyro_radps: [f32; 3], accel_mps2: [f32; 3]) -> ImuSample {
        ImuSample {
            timestamp_us: WireTime(0),
            gyro_radps,
            accel_mps2,
        }
    }

    const LEVEL: [f32; 3] = [0.0, 0.0, -GRAVITY];

    #[test]
    fn a_still_block_becomes_the_offset_and_only_the_first_says_so() {
        let mut cal = GyroCalibration::new();
        let bias = [0.008, -0.006, 0.004];
        assert_eq!(cal.correct([0.1, 0.2, 0.3]), [0.1, 0.2, 0.3]);
        for _ in 0..9 {
            assert!(!cal.update(&sample(bias, LEVEL), 10, 0.1));
        }
        assert_eq!(cal.offset(), None);
        assert!(cal.update(&sample(bias, LEVEL), 10, 0.1));
        let off = cal.offset().expect("calibrated");
        for i in 0..3 {
            assert!((off[i] - bias[i]).abs() < 1e-6, "{off:?}");
        }
        assert!(cal.correct(bias).iter().all(|w| w.abs() < 1e-6));
        // The next block replaces the offset without saying it is the first.
        let later = [0.002, 0.0, -0.001];
        for _ in 0..10 {
            assert!(!cal.update(&sample(later, LEVEL), 10, 0.1));
        }
        assert!((cal.offset().unwrap()[0] - 0.002).abs() < 1e-6);
    }

    #[test]
    fn motion_or_a_push_restarts_the_block() {
        let mut cal = GyroCalibration::new();
        for _ in 0..9 {
            cal.update(&sample([0.01; 3], LEVEL), 10, 0.1);
        }
        // Turned: the block restarts.
        cal.update(&sample([0.0, 0.0, 0.5], LEVEL), 10, 0.1);
        for _ in 0..9 {
            cal.update(&sample([0.01; 3], LEVEL), 10, 0.1);
        }
        assert_eq!(cal.offset(), None);
        // Pushed (specific force 10 % above 1 g): restarts too.
        cal.update(&sample([0.01; 3], [0.0, 0.0, -1.1 * GRAVITY]), 10, 0.1);
        for _ in 0..9 {
            cal.update(&sample([0.01; 3], LEVEL), 10, 0.1);
        }
        assert_eq!(cal.offset(), None);
        assert!(cal.update(&sample([0.01; 3], LEVEL), 10, 0.1));
    }
}
