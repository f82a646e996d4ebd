//! Mixer for an X quadcopter with four brushed motors.
//!
//! # Geometry and conventions
//!
//! Body frame x forward, y right, z down. Motor order (as in `protocol::MotorCommand`):
//!
//! ```text
//!            front
//!     4 FL (CW)   1 FR (CCW)
//!            \   /
//!             [ ]
//!            /   \
//!     3 RL (CCW)  2 RR (CW)
//!            rear
//! ```
//!
//! Spin directions are seen from above: front-right and rear-left turn counter-clockwise,
//! rear-right and front-left clockwise. A propeller's drag torque turns the body the other way,
//! so speeding up the counter-clockwise pair yaws the nose to the right (positive yaw about the
//! downward z axis).
//!
//! Commands are normalised: `thrust` in [0, 1] is the mean throttle; `roll`, `pitch`, `yaw` are
//! differential throttles, with 1.0 meaning one motor's whole throttle range (Paparazzi's
//! `MAX_PPRZ` = 9600 corresponds to 1.0 here). Motor `i` gets
//! `thrust + R[i]*roll + P[i]*pitch + Y[i]*yaw` with
//!
//! | motor | R (roll right) | P (pitch nose up) | Y (yaw nose right) |
//! |---|---|---|---|
//! | 1 FR | -1 | +1 | +1 |
//! | 2 RR | -1 | -1 | -1 |
//! | 3 RL | +1 | -1 | +1 |
//! | 4 FL | +1 | +1 | -1 |
//!
//! # Saturation: attitude first
//!
//! 1. Roll and pitch are kept whole if their motor spread fits in [0, 1]; otherwise both are
//!    scaled down together (direction kept).
//! 2. Yaw gets what spread is left (scaled down, never the roll/pitch part).
//! 3. Thrust is shifted so the result fits in [0, 1]: collective thrust is given up before
//!    attitude.
//!
//! The *achieved* roll/pitch/yaw are returned so that the INDI actuator model follows what the
//! motors were really asked to do. Non-finite inputs are treated as zero.

/// Roll coefficient per motor (FR, RR, RL, FL).
pub const ROLL: [f32; 4] = [-1.0, -1.0, 1.0, 1.0];
/// Pitch coefficient per motor (FR, RR, RL, FL).
pub const PITCH: [f32; 4] = [1.0, -1.0, -1.0, 1.0];
/// Yaw coefficient per motor (FR, RR, RL, FL).
pub const YAW: [f32; 4] = [1.0, -1.0, 1.0, -1.0];

/// Result of one mixing step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MixOutput {
    /// Throttle per motor (FR, RR, RL, FL), each in [0, 1].
    pub throttle: [f32; 4],
    /// Roll, pitch, yaw differential actually applied (normalised, see module docs).
    pub achieved: [f32; 3],
    /// Collective thrust actually applied, 0..=1.
    pub achieved_thrust: f32,
    /// True when any command had to be reduced.
    pub saturated: bool,
}

fn finite_or_zero(x: f32) -> f32 {
    if x.is_finite() {
        x
    } else {
        0.0
    }
}

fn spread(d: &[f32; 4]) -> (f32, f32) {
    let mut lo = d[0];
    let mut hi = d[0];
    for &x in d.iter() {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    (lo, hi)
}

/// Mixes thrust (0..=1) and roll/pitch/yaw differentials into four throttles in [0, 1].
pub fn mix(thrust: f32, roll: f32, pitch: f32, yaw: f32) -> MixOutput {
    let thrust_in = finite_or_zero(thrust).clamp(0.0, 1.0);
    let roll_in = finite_or_zero(roll).clamp(-1.0, 1.0);
    let pitch_in = finite_or_zero(pitch).clamp(-1.0, 1.0);
    let yaw_in = finite_or_zero(yaw).clamp(-1.0, 1.0);
    let mut saturated =
        thrust_in != thrust || roll_in != roll || pitch_in != pitch || yaw_in != yaw;
    let (mut roll, mut pitch) = (roll_in, pitch_in);

    // 1. roll/pitch spread.
    let mut rp = [0.0f32; 4];
    for (i, d) in rp.iter_mut().enumerate() {
        *d = ROLL[i] * roll + PITCH[i] * pitch;
    }
    let (lo, hi) = spread(&rp);
    let range = hi - lo;
    if range > 1.0 {
        let k = 1.0 / range;
        roll *= k;
        pitch *= k;
        for d in rp.iter_mut() {
            *d *= k;
        }
        saturated = true;
    }

    // 2. yaw in the spread that is left: for every motor pair (i, j),
    //    rp[i] - rp[j] + k*yaw*(Y[i] - Y[j]) <= 1.
    //    Every Y is ±1, so the constraining pairs are the motors yaw speeds up (i) against the
    //    ones it slows down (j), all with slope 2|yaw|: the tightest is the largest rp[i]
    //    against the smallest rp[j]. (Rounding is monotone, so this equals the minimum over
    //    the pairs exactly.)
    let mut k_yaw = 1.0f32;
    if yaw_in != 0.0 {
        let (mut up_hi, mut down_lo) = (f32::NEG_INFINITY, f32::INFINITY);
        for (&d, &y) in rp.iter().zip(YAW.iter()) {
            if y * yaw_in > 0.0 {
                up_hi = up_hi.max(d);
            } else {
                down_lo = down_lo.min(d);
            }
        }
        let room = (1.0 - (up_hi - down_lo)).max(0.0);
        k_yaw = k_yaw.min(room / (2.0 * yaw_in.abs()));
    }
    let k_yaw = k_yaw.clamp(0.0, 1.0);
    if k_yaw < 1.0 {
        saturated = true;
    }
    let yaw = yaw_in * k_yaw;
    let mut d = rp;
    for (i, x) in d.iter_mut().enumerate() {
        *x += YAW[i] * yaw;
    }

    // 3. thrust shifted into the feasible interval [-lo, 1 - hi].
    let (lo, hi) = spread(&d);
    let t_min = -lo;
    let t_max = 1.0 - hi;
    let t = if t_min <= t_max {
        thrust_in.clamp(t_min, t_max)
    } else {
        0.5 * (t_min + t_max)
    };
    if t != thrust_in {
        saturated = true;
    }
    let mut throttle = [0.0f32; 4];
    for (o, x) in throttle.iter_mut().zip(d.iter()) {
        *o = finite_or_zero(t + x).clamp(0.0, 1.0);
    }
    MixOutput {
        throttle,
        achieved: [roll, pitch, yaw],
        achieved_thrust: t,
        saturated,
    }
}

/// All motors off.
pub const MOTORS_OFF: [f32; 4] = [0.0; 4];

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < 1e-5
    }

    #[test]
    fn pure_thrust_is_equal_on_all_motors() {
        let m = mix(0.65, 0.0, 0.0, 0.0);
        assert_eq!(m.throttle, [0.65; 4]);
        assert!(!m.saturated);
    }

    #[test]
    fn signs_follow_the_documented_geometry() {
        // Roll right: left motors (RL, FL) up.
        let m = mix(0.5, 0.1, 0.0, 0.0);
        assert!(m.throttle[2] > 0.5 && m.throttle[3] > 0.5);
        assert!(m.throttle[0] < 0.5 && m.throttle[1] < 0.5);
        // Pitch nose up: front motors (FR, FL) up.
        let m = mix(0.5, 0.0, 0.1, 0.0);
        assert!(m.throttle[0] > 0.5 && m.throttle[3] > 0.5);
        // Yaw right: counter-clockwise pair (FR, RL) up.
        let m = mix(0.5, 0.0, 0.0, 0.1);
        assert!(m.throttle[0] > 0.5 && m.throttle[2] > 0.5);
        assert!(m.throttle[1] < 0.5 && m.throttle[3] < 0.5);
        // The differentials cancel in the mean: thrust is kept.
        let mean: f32 = m.throttle.iter().sum::<f32>() / 4.0;
        assert!(close(mean, 0.5));
    }

    #[test]
    fn thrust_is_given_up_before_attitude() {
        // Full thrust plus a roll command: roll is kept, thrust drops.
        let m = mix(1.0, 0.2, 0.0, 0.0);
        assert!(close(m.achieved[0], 0.2));
        assert!(close(m.throttle[2] - m.throttle[0], 0.4));
        assert!(m.achieved_thrust < 1.0);
        assert!(m.saturated);
    }

    #[test]
    fn yaw_is_given_up_before_roll_and_pitch() {
        let m = mix(0.5, 0.3, 0.2, 0.5);
        assert!(close(m.achieved[0], 0.3));
        assert!(close(m.achieved[1], 0.2));
        assert!(m.achieved[2] < 0.5 && m.achieved[2] >= 0.0);
        let (lo, hi) = spread(&m.throttle);
        assert!(lo >= 0.0 && hi <= 1.0);
        assert!(m.saturated);
    }

    #[test]
    fn oversized_roll_pitch_keeps_its_direction() {
        let m = mix(0.5, 0.8, 0.4, 0.0);
        assert!(close(m.achieved[0] / m.achieved[1], 2.0));
        let (lo, hi) = spread(&m.throttle);
        assert!(close(hi - lo, 1.0));
    }

    /// The mixer as first written: the yaw room over all 16 motor pairs.
    fn mix_reference(thrust: f32, roll: f32, pitch: f32, yaw: f32) -> MixOutput {
        let thrust_in = finite_or_zero(thrust).clamp(0.0, 1.0);
        let roll_in = finite_or_zero(roll).clamp(-1.0, 1.0);
        let pitch_in = finite_or_zero(pitch).clamp(-1.0, 1.0);
        let yaw_in = finite_or_zero(yaw).clamp(-1.0, 1.0);
        let mut saturated =
            thrust_in != thrust || roll_in != roll || pitch_in != pitch || yaw_in != yaw;
        let (mut roll, mut pitch) = (roll_in, pitch_in);
        let mut rp = [0.0f32; 4];
        for (i, d) in rp.iter_mut().enumerate() {
            *d = ROLL[i] * roll + PITCH[i] * pitch;
        }
        let (lo, hi) = spread(&rp);
        let range = hi - lo;
        if range > 1.0 {
            let k = 1.0 / range;
            roll *= k;
            pitch *= k;
            for d in rp.iter_mut() {
                *d *= k;
            }
            saturated = true;
        }
        let mut k_yaw = 1.0f32;
        if yaw_in != 0.0 {
            for i in 0..4 {
                for j in 0..4 {
                    let slope = yaw_in * (YAW[i] - YAW[j]);
                    if slope > 0.0 {
                        let room = (1.0 - (rp[i] - rp[j])).max(0.0);
                        k_yaw = k_yaw.min(room / slope);
                    }
                }
            }
        }
        let k_yaw = k_yaw.clamp(0.0, 1.0);
        if k_yaw < 1.0 {
            saturated = true;
        }
        let yaw = yaw_in * k_yaw;
        let mut d = rp;
        for (i, x) in d.iter_mut().enumerate() {
            *x += YAW[i] * yaw;
        }
        let (lo, hi) = spread(&d);
        let (t_min, t_max) = (-lo, 1.0 - hi);
        let t = if t_min <= t_max {
            thrust_in.clamp(t_min, t_max)
        } else {
            0.5 * (t_min + t_max)
        };
        if t != thrust_in {
            saturated = true;
        }
        let mut throttle = [0.0f32; 4];
        for (o, x) in throttle.iter_mut().zip(d.iter()) {
            *o = finite_or_zero(t + x).clamp(0.0, 1.0);
        }
        MixOutput {
            throttle,
            achieved: [roll, pitch, yaw],
            achieved_thrust: t,
            saturated,
        }
    }

    #[test]
    fn yaw_room_equals_the_all_pairs_search_bit_for_bit() {
        assert!(YAW.iter().all(|&y| y == 1.0 || y == -1.0));
        let mut x: u32 = 7;
        let mut next = |scale: f32| {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            ((x >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0) * scale
        };
        for _ in 0..20_000 {
            let (t, r, p, y) = (next(0.7) + 0.5, next(0.8), next(0.8), next(1.3));
            let (a, b) = (mix(t, r, p, y), mix_reference(t, r, p, y));
            assert_eq!(a.throttle.map(f32::to_bits), b.throttle.map(f32::to_bits));
            assert_eq!(a.achieved.map(f32::to_bits), b.achieved.map(f32::to_bits));
            assert_eq!(a.achieved_thrust.to_bits(), b.achieved_thrust.to_bits());
            assert_eq!(a.saturated, b.saturated);
        }
    }

    #[test]
    fn garbage_in_gives_safe_outputs() {
        let m = mix(f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::NAN);
        assert_eq!(m.throttle, [0.0; 4]);
    }
}
