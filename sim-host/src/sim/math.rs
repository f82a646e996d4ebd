//! Small 3-D vector and quaternion types for the simulator (f64: the world state is integrated
//! in double precision so that long flights stay bit-reproducible and drift-free).

use core::ops::{Add, AddAssign, Mul, Neg, Sub};

/// A 3-vector.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct V3 {
    /// x component.
    pub x: f64,
    /// y component.
    pub y: f64,
    /// z component.
    pub z: f64,
}

impl V3 {
    /// The zero vector.
    pub const ZERO: V3 = V3::new(0.0, 0.0, 0.0);
    /// A vector from its components.
    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        Self { x, y, z }
    }
    /// Dot product.
    pub fn dot(self, o: V3) -> f64 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    /// Cross product.
    pub fn cross(self, o: V3) -> V3 {
        V3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    /// Euclidean norm.
    pub fn norm(self) -> f64 {
        self.dot(self).sqrt()
    }
    /// Component-wise product.
    pub fn mul_elem(self, o: V3) -> V3 {
        V3::new(self.x * o.x, self.y * o.y, self.z * o.z)
    }
    /// As an `f32` array.
    pub fn to_f32(self) -> [f32; 3] {
        [self.x as f32, self.y as f32, self.z as f32]
    }
}

impl Add for V3 {
    type Output = V3;
    fn add(self, o: V3) -> V3 {
        V3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl AddAssign for V3 {
    fn add_assign(&mut self, o: V3) {
        *self = *self + o;
    }
}
impl Sub for V3 {
    type Output = V3;
    fn sub(self, o: V3) -> V3 {
        V3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl Mul<f64> for V3 {
    type Output = V3;
    fn mul(self, s: f64) -> V3 {
        V3::new(self.x * s, self.y * s, self.z * s)
    }
}
impl Neg for V3 {
    type Output = V3;
    fn neg(self) -> V3 {
        V3::new(-self.x, -self.y, -self.z)
    }
}

/// A unit quaternion `w + xi + yj + zk` rotating body-frame vectors into the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quat {
    /// Scalar part.
    pub w: f64,
    /// i part.
    pub x: f64,
    /// j part.
    pub y: f64,
    /// k part.
    pub z: f64,
}

impl Default for Quat {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Quat {
    /// No rotation.
    pub const IDENTITY: Quat = Quat {
        w: 1.0,
        x: 0.0,
        y: 0.0,
        z: 0.0,
    };

    /// From ZYX Euler angles (roll about x, pitch about y, yaw about z), rad.
    pub fn from_euler(roll: f64, pitch: f64, yaw: f64) -> Quat {
        let (sr, cr) = (roll * 0.5).sin_cos();
        let (sp, cp) = (pitch * 0.5).sin_cos();
        let (sy, cy) = (yaw * 0.5).sin_cos();
        Quat {
            w: cr * cp * cy + sr * sp * sy,
            x: sr * cp * cy - cr * sp * sy,
            y: cr * sp * cy + sr * cp * sy,
            z: cr * cp * sy - sr * sp * cy,
        }
    }

    /// ZYX Euler angles (roll, pitch, yaw), rad.
    pub fn to_euler(self) -> (f64, f64, f64) {
        let Quat { w, x, y, z } = self;
        let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
        let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
        let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
        (roll, pitch, yaw)
    }

    /// Rotation matrix (body to world), rows.
    pub fn to_matrix(self) -> [[f64; 3]; 3] {
        let Quat { w, x, y, z } = self;
        [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y - w * z),
                2.0 * (x * z + w * y),
            ],
            [
                2.0 * (x * y + w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z - w * x),
            ],
            [
                2.0 * (x * z - w * y),
                2.0 * (y * z + w * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ]
    }

    /// Rotates a body-frame vector into the world frame.
    pub fn rotate(self, v: V3) -> V3 {
        let m = self.to_matrix();
        V3::new(
            m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z,
            m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
            m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z,
        )
    }

    /// Rotates a world-frame vector into the body frame.
    pub fn rotate_inv(self, v: V3) -> V3 {
        let m = self.to_matrix();
        V3::new(
            m[0][0] * v.x + m[1][0] * v.y + m[2][0] * v.z,
            m[0][1] * v.x + m[1][1] * v.y + m[2][1] * v.z,
            m[0][2] * v.x + m[1][2] * v.y + m[2][2] * v.z,
        )
    }

    /// Time derivative of the quaternion for body rates `w` (rad/s): q' = q ⊗ (0, w) / 2.
    pub fn derivative(self, w: V3) -> Quat {
        let Quat {
            w: qw,
            x: qx,
            y: qy,
            z: qz,
        } = self;
        Quat {
            w: 0.5 * (-qx * w.x - qy * w.y - qz * w.z),
            x: 0.5 * (qw * w.x + qy * w.z - qz * w.y),
            y: 0.5 * (qw * w.y - qx * w.z + qz * w.x),
            z: 0.5 * (qw * w.z + qx * w.y - qy * w.x),
        }
    }

    /// `self + d * s`, component-wise (for integrators; not normalised).
    pub fn add_scaled(self, d: Quat, s: f64) -> Quat {
        Quat {
            w: self.w + d.w * s,
            x: self.x + d.x * s,
            y: self.y + d.y * s,
            z: self.z + d.z * s,
        }
    }

    /// Unit-norm copy.
    pub fn normalized(self) -> Quat {
        let n = (self.w * self.w + self.x * self.x + self.y * self.y + self.z * self.z).sqrt();
        if n > 0.0 && n.is_finite() {
            Quat {
                w: self.w / n,
                x: self.x / n,
                y: self.y / n,
                z: self.z / n,
            }
        } else {
            Quat::IDENTITY
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn euler_round_trip_and_rotation() {
        let q = Quat::from_euler(0.1, -0.2, 2.0);
        let (r, p, y) = q.to_euler();
        assert!((r - 0.1).abs() < 1e-12 && (p + 0.2).abs() < 1e-12 && (y - 2.0).abs() < 1e-12);
        // Yaw 90 deg: body x (forward) points world y (east).
        let q = Quat::from_euler(0.0, 0.0, core::f64::consts::FRAC_PI_2);
        let v = q.rotate(V3::new(1.0, 0.0, 0.0));
        assert!((v.y - 1.0).abs() < 1e-12 && v.x.abs() < 1e-12);
        let b = q.rotate_inv(v);
        assert!((b.x - 1.0).abs() < 1e-12);
    }
}
