//! What the two horizontal velocity estimators share ([`crate::guidance::VelocityObserver`],
//! [`crate::velocity_kf::VelocityKf`]): the quadrotor's horizontal model in the heading frame,
//! and a short history of the predicted velocity, so that a delayed measurement is compared
//! with the prediction of the time it describes.

use crate::attitude::{sin_cos, GRAVITY};
use timebase::{Duration, Instant};

/// Largest velocity magnitude per axis an estimator holds, m/s.
pub const MAX_SPEED_MPS: f32 = 10.0;

/// Spacing of [`VelocityHistory`] entries.
pub const HISTORY_SPACING: Duration = Duration::from_micros(6_000);

/// Horizontal acceleration `[forward, right]` (m/s²) of thrust that holds the height at roll and
/// pitch (rad), each limited to `max_tilt` (rad): `a_fwd = -g tan(pitch)`,
/// `a_right = g tan(roll) / cos(pitch)`.
pub fn tilt_acceleration(roll: f32, pitch: f32, max_tilt: f32) -> [f32; 2] {
    let lim = max_tilt.abs();
    // tan p = sp / cp and tan r / cos p = sr / (cr cp), from the single-precision `sin_cos`
    // (libm's tanf/cosf run f64 kernels: software on the M4). The cosines are kept away from 0
    // (only reachable with a tilt limit near pi/2), keeping their sign as tan does.
    let (sr, cr) = sin_cos(roll.clamp(-lim, lim));
    let (sp, cp) = sin_cos(pitch.clamp(-lim, lim));
    let (cr, cp) = (away_from_zero(cr), away_from_zero(cp));
    [-GRAVITY * (sp / cp), GRAVITY * (sr / (cr * cp))]
}

/// One Euler step of the heading-frame velocity `v` under acceleration `a` (m/s²), linear
/// drag `drag` (1/s) and the yaw rate (rad/s): the frame turns under a room-fixed velocity,
/// `dv_fwd/dt = r v_right`, `dv_right/dt = -r v_fwd`. `None` if the result is not finite.
pub fn heading_frame_step(
    v: [f32; 2],
    a: [f32; 2],
    drag: f32,
    yaw_rate: f32,
    dt: f32,
) -> Option<[f32; 2]> {
    let k = drag.max(0.0);
    let w = yaw_rate.clamp(-20.0, 20.0);
    let [vf, vs] = v;
    let nv = [
        vf + (a[0] - k * vf + w * vs) * dt,
        vs + (a[1] - k * vs - w * vf) * dt,
    ];
    nv.iter()
        .all(|x| x.is_finite())
        .then(|| nv.map(|x| x.clamp(-MAX_SPEED_MPS, MAX_SPEED_MPS)))
}

/// `c` with its magnitude at least `1e-6` (sign kept; NaN stays NaN): a divisor for `tan`.
pub(crate) fn away_from_zero(c: f32) -> f32 {
    const MIN: f32 = 1e-6;
    if c.abs() < MIN {
        MIN.copysign(c)
    } else {
        c
    }
}

/// The predicted `[forward, right]` velocity every [`HISTORY_SPACING`], the last `N`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityHistory<const N: usize> {
    slots: [(Instant, [f32; 2]); N],
    head: usize,
    last_record: Option<Instant>,
}

impl<const N: usize> VelocityHistory<N> {
    /// An empty history (every slot at time 0, velocity 0).
    pub const fn new() -> Self {
        Self {
            slots: [(Instant::ZERO, [0.0; 2]); N],
            head: 0,
            last_record: None,
        }
    }

    /// Records `v` at `now` if the spacing has passed since the last entry (or the clock
    /// went back).
    pub fn record(&mut self, now: Instant, v: [f32; 2]) {
        let due = match self.last_record {
            Some(t) => now.since(t) >= HISTORY_SPACING || now < t,
            None => true,
        };
        if due && N > 0 {
            self.last_record = Some(now);
            self.head = (self.head + 1) % N;
            if let Some(slot) = self.slots.get_mut(self.head) {
                *slot = (now, v);
            }
        }
    }

    /// Every slot becomes `(t, v)`; the next record is due a spacing after `recorded`.
    pub fn fill(&mut self, t: Instant, v: [f32; 2], recorded: Instant) {
        self.slots = [(t, v); N];
        self.last_record = Some(recorded);
    }

    /// Adds `dv` to axis `axis` of every entry (a correction moves the past with the present,
    /// so that the next innovation does not count it again).
    pub fn shift(&mut self, axis: usize, dv: f32) {
        for s in self.slots.iter_mut() {
            if let Some(x) = s.1.get_mut(axis) {
                *x += dv;
            }
        }
    }

    /// The entries, newest first.
    pub fn newest_first(&self) -> impl Iterator<Item = (Instant, [f32; 2])> + '_ {
        (0..N).filter_map(move |i| self.slots.get((self.head + N - i) % N).copied())
    }
}

impl<const N: usize> Default for VelocityHistory<N> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn history_keeps_the_spacing_and_lists_newest_first() {
        let mut h = VelocityHistory::<4>::new();
        for k in 0..10u64 {
            h.record(Instant::from_micros(k * 2_000), [k as f32, 0.0]);
        }
        // Recorded at 0, 6, 12, 18 ms: the four newest.
        let t: [u64; 4] = core::array::from_fn(|i| h.newest_first().nth(i).unwrap().0.as_micros());
        assert_eq!(t, [18_000, 12_000, 6_000, 0]);
        h.shift(0, 1.0);
        assert_eq!(h.newest_first().next().unwrap().1, [10.0, 0.0]);
        h.fill(Instant::ZERO, [0.5, 0.5], Instant::from_micros(20_000));
        assert!(h.newest_first().all(|e| e == (Instant::ZERO, [0.5, 0.5])));
    }

    #[test]
    fn tilt_and_heading_model() {
        let a = tilt_acceleration(0.0, -0.1, 0.5);
        assert!((a[0] - GRAVITY * libm::tanf(0.1)).abs() < 1e-4 && a[1].abs() < 1e-6);
        // Limited tilt.
        assert_eq!(
            tilt_acceleration(2.0, 0.0, 0.5),
            tilt_acceleration(0.5, 0.0, 0.5)
        );
        assert_eq!(
            heading_frame_step([1.0, 0.0], [0.0; 2], 0.0, 0.0, 0.1),
            Some([1.0, 0.0])
        );
        assert_eq!(
            heading_frame_step([f32::MAX, 0.0], [f32::MAX; 2], 0.0, 0.0, 1.0),
            None
        );
        assert_eq!(away_from_zero(0.0), 1e-6);
        assert_eq!(away_from_zero(-0.0), -1e-6);
        assert_eq!(away_from_zero(-1e-9), -1e-6);
        assert_eq!(away_from_zero(0.5), 0.5);
        assert!(away_from_zero(f32::NAN).is_nan());
    }
}
