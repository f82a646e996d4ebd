//! Attitude estimation from gyro and accelerometer (the paper's drone had no external attitude),
//! and the quaternion helpers the controller needs.
//!
//! A Mahony-type complementary filter: the gyro is integrated, and the direction of the measured
//! specific force pulls the estimate towards "gravity down" with a small proportional gain (an
//! integral gyro-bias gain is available, off by default: see [`AttitudeConfig::ki`]). On a
//! quadcopter the accelerometer mostly sees thrust along body -z, so the gain is low (seconds)
//! and the correction is skipped while the specific force is far from 1 g. Yaw has no absolute reference and is the gyro integral (the avoidance logic only
//! uses heading changes).
//!
//! Frames: body x forward, y right, z down; world x north, y east, z down. Angles are ZYX Euler
//! (roll, pitch, yaw), rad. At rest and level the accelerometer reads `[0, 0, -9.81]` m/s².

use libm::{asinf, atan2f, sqrtf};

/// Standard gravity, m/s².
pub const GRAVITY: f32 = 9.81;
/// A quaternion whose norm is below this is degenerate: normalising it gives the identity.
const MIN_QUATERNION_NORM: f32 = 1e-6;
/// The largest `|x|` [`sin_cos`] reduces itself: beyond it `k·P1` and `k·P2` stop being exact.
const SIN_COS_MAX_ARG: f32 = 1.0e4;
/// Below this specific force, m/s², the accelerometer has no direction to correct with.
const MIN_ACCEL_MPS2: f32 = 1e-3;

/// Unit quaternion `w + xi + yj + zk` (body-to-world rotation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quat {
    /// Scalar part.
    pub w: f32,
    /// i part.
    pub x: f32,
    /// j part.
    pub y: f32,
    /// k part.
    pub z: f32,
}

impl Quat {
    /// The identity rotation.
    pub const IDENTITY: Self = Self {
        w: 1.0,
        x: 0.0,
        y: 0.0,
        z: 0.0,
    };

    /// Hamilton product `self ⊗ o`.
    pub fn hamilton(self, o: Self) -> Self {
        Self {
            w: self.w * o.w - self.x * o.x - self.y * o.y - self.z * o.z,
            x: self.w * o.x + self.x * o.w + self.y * o.z - self.z * o.y,
            y: self.w * o.y - self.x * o.z + self.y * o.w + self.z * o.x,
            z: self.w * o.z + self.x * o.y - self.y * o.x + self.z * o.w,
        }
    }

    /// Conjugate (the inverse of a unit quaternion).
    pub fn conj(self) -> Self {
        Self {
            w: self.w,
            x: -self.x,
            y: -self.y,
            z: -self.z,
        }
    }

    /// Normalised copy; the identity when the norm is zero or not finite.
    pub fn normalized(self) -> Self {
        let n = sqrtf(self.w * self.w + self.x * self.x + self.y * self.y + self.z * self.z);
        if n.is_finite() && n > MIN_QUATERNION_NORM {
            Self {
                w: self.w / n,
                x: self.x / n,
                y: self.y / n,
                z: self.z / n,
            }
        } else {
            Self::IDENTITY
        }
    }

    /// Rotation from ZYX Euler angles roll, pitch, yaw (rad).
    pub fn from_euler(roll: f32, pitch: f32, yaw: f32) -> Self {
        let (sr, cr) = sin_cos(roll * 0.5);
        let (sp, cp) = sin_cos(pitch * 0.5);
        let (sy, cy) = sin_cos(yaw * 0.5);
        Self {
            w: cr * cp * cy + sr * sp * sy,
            x: sr * cp * cy - cr * sp * sy,
            y: cr * sp * cy + sr * cp * sy,
            z: cr * cp * sy - sr * sp * cy,
        }
    }

    /// ZYX Euler angles `[roll, pitch, yaw]`, rad.
    pub fn to_euler(self) -> [f32; 3] {
        let Self { w, x, y, z } = self;
        let roll = atan2f(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y));
        let pitch = asinf((2.0 * (w * y - z * x)).clamp(-1.0, 1.0));
        let yaw = atan2f(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z));
        [roll, pitch, yaw]
    }

    /// World "down" (0, 0, 1) expressed in body axes.
    pub fn down_in_body(self) -> [f32; 3] {
        let Self { w, x, y, z } = self;
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ]
    }
}

/// `(sin x, cos x)` in single precision only (x in rad), within about 1e-7 of the exact
/// values for `|x| <= 1e4` (farther out, and for non-finite `x`, it defers to `libm`).
///
/// `libm`'s `sinf`/`cosf` evaluate their kernels in `f64`, which the Cortex-M4 (single-precision
/// FPU) runs in software: about 1,100 instructions each. This is a quadrant reduction by
/// `pi/2` (three-part Cody-Waite constant, so `x - k·pi/2` is exact to f32 rounding for these
/// `k`) and minimax polynomials on `[-pi/4, pi/4]`: a few dozen FPU instructions for both.
pub fn sin_cos(x: f32) -> (f32, f32) {
    // pi/2 = P1 + P2 + P3; P1 and P2 have few significant bits, so k·P1 and k·P2 are exact.
    const P1: f32 = 1.570_312_5;
    const P2: f32 = 4.837_513e-4;
    const P3: f32 = 7.549_79e-8;
    // Minimax coefficients for |r| <= pi/4 (single precision).
    const S1: f32 = -0.166_666_55;
    const S2: f32 = 0.008_332_161;
    const S3: f32 = -0.000_195_152_96;
    const C1: f32 = 0.041_666_646;
    const C2: f32 = -0.001_388_731_6;
    const C3: f32 = 2.443_315_7e-5;
    if x.is_nan() || x.abs() > SIN_COS_MAX_ARG {
        return (libm::sinf(x), libm::cosf(x));
    }
    let k = libm::roundf(x * core::f32::consts::FRAC_2_PI);
    let r = ((x - k * P1) - k * P2) - k * P3;
    let z = r * r;
    let s = r + r * z * (S1 + z * (S2 + z * S3));
    let c = 1.0 - 0.5 * z + z * z * (C1 + z * (C2 + z * C3));
    match (k as i32) & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Small-angle attitude error (rad, body axes): the rotation vector taking `current` to
/// `setpoint`, along the shorter way round.
pub fn attitude_error(current: Quat, setpoint: Quat) -> [f32; 3] {
    let mut e = current.conj().hamilton(setpoint);
    if e.w < 0.0 {
        e = Quat {
            w: -e.w,
            x: -e.x,
            y: -e.y,
            z: -e.z,
        };
    }
    [2.0 * e.x, 2.0 * e.y, 2.0 * e.z]
}

/// Wraps an angle to (-pi, pi], rad.
pub fn wrap_pi(a: f32) -> f32 {
    if !a.is_finite() {
        return 0.0;
    }
    let two_pi = 2.0 * core::f32::consts::PI;
    let mut a = a % two_pi;
    if a > core::f32::consts::PI {
        a -= two_pi;
    } else if a <= -core::f32::consts::PI {
        a += two_pi;
    }
    a
}

/// Complementary-filter tunables.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeConfig {
    /// Proportional correction gain, rad/s per unit of direction error (1/time constant).
    /// Low on purpose: a quadcopter's accelerometer mostly measures thrust (body -z), so while
    /// it accelerates a strong correction would pull the estimate towards level and the
    /// velocity loop would see a tilt it did not command.
    pub kp: f32,
    /// Gyro bias integral gain, rad/s² per unit of direction error. 0 by default: the gyro
    /// is calibrated on the ground before take-off, and in flight the direction error is
    /// mostly thrust and rotor drag read as tilt, not gyro drift. Integrated, it becomes a
    /// false gyro bias (simulated, 0.003 rad/s after 300 s at 0.005, ten times the gyro's own
    /// drift), and that holds the estimate a degree or two off level. A yaw leaves such an
    /// error fixed in the room, so after every turn the velocity filter's learnt tilt offset
    /// points the wrong way (see `docs/parameters.md`).
    pub ki: f32,
    /// Largest gyro bias estimate per axis, rad/s.
    pub max_bias: f32,
    /// The accelerometer is used only while `| |a| - g | < accel_gate * g`.
    pub accel_gate: f32,
}

impl Default for AttitudeConfig {
    fn default() -> Self {
        Self {
            kp: 0.1,
            ki: 0.0,
            max_bias: 0.1,
            accel_gate: 0.15,
        }
    }
}

/// Mahony-type attitude estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeEstimator {
    cfg: AttitudeConfig,
    q: Quat,
    bias: [f32; 3],
    initialised: bool,
}

impl AttitudeEstimator {
    /// Takes a new configuration, keeping the state (used from the next step on).
    pub fn set_config(&mut self, cfg: AttitudeConfig) {
        self.cfg = cfg;
    }

    /// An estimator that initialises its roll and pitch from the first usable accelerometer
    /// sample (yaw starts at 0).
    pub fn new(cfg: AttitudeConfig) -> Self {
        Self {
            cfg,
            q: Quat::IDENTITY,
            bias: [0.0; 3],
            initialised: false,
        }
    }

    /// Current attitude.
    pub fn quat(&self) -> Quat {
        self.q
    }

    /// Current `[roll, pitch, yaw]`, rad.
    pub fn euler(&self) -> [f32; 3] {
        self.q.to_euler()
    }

    /// Gyro bias estimate, rad/s.
    pub fn bias(&self) -> [f32; 3] {
        self.bias
    }

    /// True once the first accelerometer sample set roll and pitch.
    pub fn initialised(&self) -> bool {
        self.initialised
    }

    /// One step: gyro rad/s, accel (specific force) m/s², step `dt` s. Non-finite inputs are
    /// ignored (the gyro then counts as zero for this step).
    pub fn update(&mut self, gyro: [f32; 3], accel: [f32; 3], dt: f32) {
        let dt = if dt.is_finite() {
            dt.clamp(0.0, 0.1)
        } else {
            0.0
        };
        let accel_ok = accel.iter().all(|a| a.is_finite());
        let an = if accel_ok {
            sqrtf(accel[0] * accel[0] + accel[1] * accel[1] + accel[2] * accel[2])
        } else {
            0.0
        };
        if !self.initialised {
            if accel_ok && (an - GRAVITY).abs() < self.cfg.accel_gate * GRAVITY {
                let roll = atan2f(-accel[1], -accel[2]);
                let pitch = atan2f(accel[0], sqrtf(accel[1] * accel[1] + accel[2] * accel[2]));
                self.q = Quat::from_euler(roll, pitch, 0.0);
                self.initialised = true;
            }
            return;
        }
        let mut w = [0.0f32; 3];
        for (i, wi) in w.iter_mut().enumerate() {
            *wi = if gyro[i].is_finite() {
                gyro[i] - self.bias[i]
            } else {
                0.0
            };
        }
        if accel_ok && an > MIN_ACCEL_MPS2 && (an - GRAVITY).abs() < self.cfg.accel_gate * GRAVITY {
            // Measured "down" is opposite the specific force; the error is the rotation that
            // brings the estimated down direction onto the measured one.
            let m = [-accel[0] / an, -accel[1] / an, -accel[2] / an];
            let v = self.q.down_in_body();
            let e = [
                m[1] * v[2] - m[2] * v[1],
                m[2] * v[0] - m[0] * v[2],
                m[0] * v[1] - m[1] * v[0],
            ];
            for i in 0..3 {
                w[i] += self.cfg.kp * e[i];
                let b = self.bias[i] - self.cfg.ki * e[i] * dt;
                self.bias[i] = b.clamp(-self.cfg.max_bias, self.cfg.max_bias);
            }
        }
        let dq = self.q.hamilton(Quat {
            w: 0.0,
            x: w[0],
            y: w[1],
            z: w[2],
        });
        self.q = Quat {
            w: self.q.w + 0.5 * dq.w * dt,
            x: self.q.x + 0.5 * dq.x * dt,
            y: self.q.y + 0.5 * dq.y * dt,
            z: self.q.z + 0.5 * dq.z * dt,
        }
        .normalized();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn accel_for(roll: f32, pitch: f32) -> [f32; 3] {
        let d = Quat::from_euler(roll, pitch, 0.0).down_in_body();
        [-GRAVITY * d[0], -GRAVITY * d[1], -GRAVITY * d[2]]
    }

    #[test]
    fn euler_round_trip() {
        let q = Quat::from_euler(0.2, -0.3, 1.0);
        let e = q.to_euler();
        assert!(
            (e[0] - 0.2).abs() < 1e-5 && (e[1] + 0.3).abs() < 1e-5 && (e[2] - 1.0).abs() < 1e-5
        );
    }

    #[test]
    fn level_accel_reads_minus_g() {
        let a = accel_for(0.0, 0.0);
        assert!((a[2] + GRAVITY).abs() < 1e-5);
        // Nose up: specific force has a positive x component.
        assert!(accel_for(0.0, 0.2)[0] > 0.0);
    }

    #[test]
    fn initialises_from_accel_and_converges_after_gyro_error() {
        let mut est = AttitudeEstimator::new(AttitudeConfig::default());
        est.update([0.0; 3], accel_for(0.1, -0.2), 1.0 / 512.0);
        let e = est.euler();
        assert!((e[0] - 0.1).abs() < 1e-3 && (e[1] + 0.2).abs() < 1e-3);
        // Gyro integration follows a rotation.
        for _ in 0..512 {
            est.update([0.0, 0.0, 0.5], accel_for(0.1, -0.2), 1.0 / 512.0);
        }
        assert!((est.euler()[2] - 0.5).abs() < 0.02);
        // With the integral gain on, a constant gyro bias is learnt (time constant about 20 s):
        // the roll/pitch end up at the accelerometer's.
        est.set_config(AttitudeConfig {
            ki: 0.005,
            ..AttitudeConfig::default()
        });
        for _ in 0..512 * 120 {
            est.update([0.02, -0.01, 0.0], accel_for(0.0, 0.0), 1.0 / 512.0);
        }
        let e = est.euler();
        assert!(e[0].abs() < 0.02 && e[1].abs() < 0.02, "{e:?}");
    }

    #[test]
    fn attitude_error_sign() {
        let cur = Quat::from_euler(0.0, 0.0, 0.0);
        let sp = Quat::from_euler(0.1, 0.0, 0.0);
        let e = attitude_error(cur, sp);
        assert!((e[0] - 0.1).abs() < 1e-3 && e[1].abs() < 1e-6);
        let sp = Quat::from_euler(0.0, 0.0, 1.0);
        assert!(attitude_error(cur, sp)[2] > 0.9);
    }

    #[test]
    fn sin_cos_matches_libm() {
        let mut x = -40.0f32;
        while x <= 40.0 {
            let (s, c) = sin_cos(x);
            let (ls, lc) = (libm::sin(f64::from(x)), libm::cos(f64::from(x)));
            assert!((f64::from(s) - ls).abs() < 2.5e-7, "sin {x}: {s} vs {ls}");
            assert!((f64::from(c) - lc).abs() < 2.5e-7, "cos {x}: {c} vs {lc}");
            x += 0.000_37;
        }
        for x in [0.0f32, -0.0, 1e-30, 1e3, -9_999.9, 2e4, 1e30] {
            let (s, c) = sin_cos(x);
            assert!(
                (s - libm::sinf(x)).abs() < 2e-4 && (c - libm::cosf(x)).abs() < 2e-4,
                "{x}"
            );
        }
        assert_eq!(sin_cos(0.0), (0.0, 1.0));
        let (s, c) = sin_cos(f32::NAN);
        assert!(s.is_nan() && c.is_nan());
        assert!(sin_cos(f32::INFINITY).0.is_nan());
    }

    #[test]
    fn wrap() {
        assert!((wrap_pi(3.5) - (3.5 - 2.0 * core::f32::consts::PI)).abs() < 1e-5);
        assert!((wrap_pi(-3.5) - (-3.5 + 2.0 * core::f32::consts::PI)).abs() < 1e-5);
        assert_eq!(wrap_pi(f32::NAN), 0.0);
    }
}
