//! The obstacle's range rate: how fast the stereo distance to the nearest obstacle shrinks. It
//! measures the closing speed with nothing in common with the flow's velocity (one frame's
//! disparity against the next's), so it can check the velocity estimate: a static obstacle
//! cannot close faster than the drone moves.
//!
//! The track is the last stereo distances within [`WINDOW`], taken while the heading holds
//! (turning sweeps the view over other surfaces: the nearest one changes without any motion);
//! a distance far off the track's line, a turn, a reading without a distance or a gap starts a
//! new track. The closing speed is the least-squares slope of distance against time.

use timebase::{Duration, Instant};

/// Readings kept (at 25 fps: 1 s).
pub const TRACK_LEN: usize = 25;
/// Readings older than this are dropped.
pub const WINDOW: Duration = Duration::from_secs(1);
/// A reading this long after the previous one starts a new track (half the window).
const GAP: Duration = Duration::from_micros(WINDOW.as_micros() / 2);
/// Fewest readings for a closing speed.
pub const MIN_READINGS: usize = 10;
/// Shortest time the readings must span.
pub const MIN_SPAN: Duration = Duration::from_millis(400);
/// A distance further than this from the track's line is another surface: a new track, m
/// (the stereo distance's noise is 3 to 8 cm within the range; a 0.12 m step in one frame
/// would be a closing speed of 3 m/s).
pub const JUMP_M: f32 = 0.12;
/// Distances beyond this are too coarse for a rate (the disparity is 4.8 px at 1.6 m: a
/// tenth of a pixel is 3 cm), m.
pub const MAX_RANGE_M: f32 = 1.6;
/// A heading change beyond this over the track starts a new one, rad.
pub const MAX_TURN_RAD: f32 = 0.05;

/// The closing speed on the nearest obstacle, from its stereo distances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Closing {
    /// Closing speed, m/s (positive: the distance shrinks).
    pub mps: f32,
    /// Standard error of [`Self::mps`], m/s.
    pub sigma_mps: f32,
}

/// The least-squares line of a track: distance `d0 + slope·(t - t0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct TrackLine {
    /// The track's first time.
    t0: Instant,
    /// Distance at `t0`, m.
    d0: f32,
    /// m/s (negative: closing).
    slope: f32,
    /// Standard error of the slope, m/s.
    sigma: f32,
}

/// The track of stereo distances ([module docs](self)).
#[derive(Debug, Clone)]
pub struct RangeRate {
    /// `(received, distance m)`, oldest first.
    track: [(Instant, f32); TRACK_LEN],
    len: usize,
    /// Heading at the track's first reading, rad.
    yaw_rad: f32,
    /// The track's line, refitted at each reading (`None`: fewer than two readings).
    line: Option<TrackLine>,
}

impl Default for RangeRate {
    fn default() -> Self {
        Self::new()
    }
}

impl RangeRate {
    /// An empty track.
    pub const fn new() -> Self {
        Self {
            track: [(Instant::ZERO, 0.0); TRACK_LEN],
            len: 0,
            yaw_rad: 0.0,
            line: None,
        }
    }

    /// A stereo reading received at `now` at heading `yaw_rad`: the nearest obstacle's
    /// distance (`None`: nothing in range, which ends the track).
    pub fn on_distance(&mut self, distance_m: Option<f32>, yaw_rad: f32, now: Instant) {
        let Some(d) = distance_m.filter(|d| d.is_finite() && *d > 0.0 && *d <= MAX_RANGE_M) else {
            self.reset();
            return;
        };
        let turned = crate::attitude::wrap_pi(yaw_rad - self.yaw_rad).abs() > MAX_TURN_RAD;
        let newest = self.track.get(self.len.wrapping_sub(1)).copied();
        let gap = newest.is_none_or(|r| now.since(r.0) > GAP);
        let off_track = match (self.line, newest) {
            (Some(l), _) => {
                let dt = now.since(l.t0).as_secs_f32();
                (d - (l.d0 + l.slope * dt)).abs() > JUMP_M
            }
            (None, Some(last)) => (d - last.1).abs() > JUMP_M,
            (None, None) => false,
        };
        if turned || gap || off_track || !yaw_rad.is_finite() {
            self.reset();
            self.yaw_rad = yaw_rad;
        }
        // Drop what left the window, and the oldest when full.
        let keep_from = self
            .track
            .iter()
            .take(self.len)
            .position(|r| now.since(r.0) <= WINDOW)
            .unwrap_or(self.len);
        let drop = keep_from.max((self.len + 1).saturating_sub(TRACK_LEN));
        self.track.copy_within(drop..self.len, 0);
        self.len -= drop;
        if let Some(slot) = self.track.get_mut(self.len) {
            *slot = (now, d);
            self.len += 1;
        }
        self.line = self.fit();
    }

    /// Ends the track (the drone stopped flying, the camera stopped).
    pub fn reset(&mut self) {
        self.len = 0;
        self.line = None;
    }

    /// The least-squares line of the track; `None` with fewer than two readings or no time
    /// spread.
    fn fit(&self) -> Option<TrackLine> {
        let track = self.track.get(..self.len)?;
        let t0 = track.first()?.0;
        let n = track.len() as f32;
        let (mut st, mut sd, mut stt, mut std, mut sdd) = (0.0f32, 0.0f32, 0.0, 0.0, 0.0);
        for &(t, d) in track {
            let t = t.since(t0).as_secs_f32();
            st += t;
            sd += d;
            stt += t * t;
            std += t * d;
            sdd += d * d;
        }
        let stt_c = stt - st * st / n;
        if n < 2.0 || stt_c <= 0.0 {
            return None;
        }
        let std_c = std - st * sd / n;
        let slope = std_c / stt_c;
        let rss = (sdd - sd * sd / n - slope * std_c).max(0.0);
        let sigma = if n > 2.0 {
            libm::sqrtf(rss / (n - 2.0) / stt_c)
        } else {
            f32::INFINITY
        };
        Some(TrackLine {
            t0,
            d0: (sd - slope * st) / n,
            slope,
            sigma,
        })
    }

    /// The closing speed of the track at `now`, when it holds [`MIN_READINGS`] over
    /// [`MIN_SPAN`] and its newest reading is within the window.
    pub fn closing(&self, now: Instant) -> Option<Closing> {
        let track = self.track.get(..self.len)?;
        let (first, last) = (track.first()?.0, track.last()?.0);
        if track.len() < MIN_READINGS || last.since(first) < MIN_SPAN || now.since(last) > WINDOW {
            return None;
        }
        let l = self.line?;
        (l.slope.is_finite() && l.sigma.is_finite()).then_some(Closing {
            mps: -l.slope,
            sigma_mps: l.sigma,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FRAME: Duration = Duration::from_millis(40);

    fn approach(rr: &mut RangeRate, from_m: f32, mps: f32, frames: u64, start: Instant) -> Instant {
        let mut t = start;
        for k in 0..frames {
            t = start + FRAME.saturating_mul(k);
            // Disparity quantisation: +-1 cm of noise.
            let wobble = if k % 2 == 0 { 0.01 } else { -0.01 };
            rr.on_distance(
                Some(from_m - mps * FRAME.saturating_mul(k).as_secs_f32() + wobble),
                0.0,
                t,
            );
        }
        t
    }

    #[test]
    fn a_steady_approach_gives_its_speed() {
        let mut rr = RangeRate::new();
        let t = approach(&mut rr, 1.5, 0.3, 12, Instant::ZERO);
        let c = rr.closing(t).unwrap();
        assert!((c.mps - 0.3).abs() < 3.0 * c.sigma_mps + 0.01, "{c:?}");
        assert!(c.sigma_mps < 0.05, "{c:?}");
        // Too few readings, and stale.
        let mut short = RangeRate::new();
        let t = approach(&mut short, 1.5, 0.3, 4, Instant::ZERO);
        assert_eq!(short.closing(t), None);
        assert_eq!(
            rr.closing(t + FRAME.saturating_mul(11) + WINDOW + Duration::from_micros(1)),
            None
        );
    }

    #[test]
    fn another_surface_a_turn_or_nothing_in_range_starts_a_new_track() {
        let mut rr = RangeRate::new();
        let t = approach(&mut rr, 1.5, 0.3, 12, Instant::ZERO);
        assert!(rr.closing(t).is_some());
        // The nearest surface jumps from 1.17 m to 0.6 m: not a closing speed of 14 m/s.
        rr.on_distance(Some(0.6), 0.0, t + FRAME);
        assert_eq!(rr.closing(t + FRAME), None);
        let t = approach(&mut rr, 0.6, 0.0, 12, t + FRAME.saturating_mul(2));
        assert!(rr.closing(t).unwrap().mps.abs() < 0.05);
        rr.on_distance(Some(0.6), 0.2, t + FRAME);
        assert_eq!(rr.closing(t + FRAME), None, "a turn");
        let t = approach(&mut rr, 0.6, 0.0, 12, t + FRAME.saturating_mul(2));
        rr.on_distance(None, 0.0, t + FRAME);
        assert_eq!(rr.closing(t + FRAME), None, "nothing in range");
        rr.on_distance(Some(f32::NAN), 0.0, t + FRAME.saturating_mul(2));
        assert_eq!(rr.closing(t + FRAME.saturating_mul(2)), None);
    }
}
