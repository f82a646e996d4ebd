//! The divergence of the horizontal flow: how fast the view expands, and so the time to contact
//! with the scene ahead, from the flow alone (no stereo range needed).
//!
//! The flow of a column `x` px from the image centre is `u = D·x + c`: `D` the divergence (for a
//! surface facing the camera at distance `Z` approached at speed `F`, `D = F/Z`) and `c` the
//! uniform part of sideways motion and derotation errors, which therefore cannot bias `D`.
//! Every textured column with a flow match counts, with or without a stereo depth: the columns
//! nearer than the stereo search or beyond its range, and the textured edges of a plain object,
//! give flow where they give no depth. The fit is least squares, then again without the points
//! more than [`TRIM_SIGMAS`] residual σ from the first line (a mismatched column).

use super::IMG_W;
use protocol::Divergence;

/// Fewest flow columns for a divergence (after the outliers are dropped).
const MIN_COLUMNS: usize = 8;
/// A point further than this many residual σ from the first fit is an outlier.
const TRIM_SIGMAS: f32 = 2.5;
/// The outlier cut never falls below this, px/s (a noise-free flow has a zero residual).
const MIN_TRIM_PXPS: f32 = 1.0;
/// Smallest standard deviation of the columns' positions, px: the slope of a narrower patch of
/// flow is mostly noise.
const MIN_SPREAD_PX: f32 = 12.0;

/// One frame's flow samples: `(x, u)`, `x` px from the image centre, `u` derotated flow, px/s.
pub(super) struct FlowSamples {
    pts: [(f32, f32); IMG_W],
    n: usize,
}

/// Sums of a least-squares line `u = slope·x + intercept`.
#[derive(Clone, Copy)]
struct Sums {
    n: f32,
    x: f32,
    u: f32,
    xx: f32,
    xu: f32,
    uu: f32,
}

/// A least-squares line and its residual.
struct Line {
    slope: f32,
    intercept: f32,
    /// Residual standard deviation (`n - 2` degrees of freedom), px/s.
    sigma: f32,
    /// Sum of the squared deviations of `x` from its mean, px².
    sxx: f32,
}

impl Sums {
    const ZERO: Self = Self {
        n: 0.0,
        x: 0.0,
        u: 0.0,
        xx: 0.0,
        xu: 0.0,
        uu: 0.0,
    };

    /// Adds (`sign` 1) or removes (`sign` -1) the point `(x, u)`.
    #[inline(always)]
    fn add(&mut self, x: f32, u: f32, sign: f32) {
        self.n += sign;
        self.x += sign * x;
        self.u += sign * u;
        self.xx += sign * x * x;
        self.xu += sign * x * u;
        self.uu += sign * u * u;
    }

    /// The line, when there are at least [`MIN_COLUMNS`] points spread over
    /// [`MIN_SPREAD_PX`].
    #[inline(always)]
    fn line(&self) -> Option<Line> {
        if self.n < MIN_COLUMNS as f32 {
            return None;
        }
        let sxx = self.xx - self.x * self.x / self.n;
        if sxx.is_nan() || sxx < MIN_SPREAD_PX * MIN_SPREAD_PX * self.n {
            return None;
        }
        let sxu = self.xu - self.x * self.u / self.n;
        let suu = self.uu - self.u * self.u / self.n;
        let slope = sxu / sxx;
        let rss = (suu - slope * sxu).max(0.0);
        Some(Line {
            slope,
            intercept: (self.u - slope * self.x) / self.n,
            sigma: libm::sqrtf(rss / (self.n - 2.0)),
            sxx,
        })
    }
}

impl FlowSamples {
    /// No samples.
    pub(super) const EMPTY: Self = Self {
        pts: [(0.0, 0.0); IMG_W],
        n: 0,
    };

    /// Adds the flow `u` (px/s) of the column `x` px from the image centre.
    #[inline(always)]
    pub(super) fn push(&mut self, x: f32, u: f32) {
        if let Some(p) = self.pts.get_mut(self.n) {
            *p = (x, u);
            self.n += 1;
        }
    }

    /// The divergence of the samples, `None` when too few of them, over too narrow a patch,
    /// remain or the result is not finite.
    pub(super) fn divergence(&self) -> Option<Divergence> {
        let pts = self.pts.get(..self.n)?;
        let mut all = Sums::ZERO;
        for &(x, u) in pts {
            all.add(x, u, 1.0);
        }
        let first = all.line()?;
        let cut = (TRIM_SIGMAS * first.sigma).max(MIN_TRIM_PXPS);
        // Outliers are few: taking them out of the sums is cheaper than summing the rest again.
        let mut kept = all;
        for &(x, u) in pts {
            let r = (u - (first.slope * x + first.intercept)).abs();
            if r.is_nan() || r > cut {
                kept.add(x, u, -1.0);
            }
        }
        let line = kept.line()?;
        let d = Divergence {
            rate_hz: line.slope,
            sigma_hz: line.sigma / libm::sqrtf(line.sxx),
        };
        (d.rate_hz.is_finite() && d.sigma_hz.is_finite()).then_some(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(points: impl Iterator<Item = (f32, f32)>) -> FlowSamples {
        let mut s = FlowSamples::EMPTY;
        for (x, u) in points {
            s.push(x, u);
        }
        s
    }

    #[test]
    fn a_facing_wall_gives_speed_over_distance() {
        // 0.5 m/s towards a wall 2 m ahead, while sliding sideways (a uniform flow).
        let s = samples((0..IMG_W).map(|c| {
            let x = c as f32 - 63.5;
            (x, x * 0.5 / 2.0 - 30.0)
        }));
        let d = s.divergence().unwrap();
        assert!((d.rate_hz - 0.25).abs() < 1e-5, "{d:?}");
        assert!(d.sigma_hz < 1e-4);
        assert!((d.time_to_contact_s().unwrap() - 4.0).abs() < 1e-3);
    }

    #[test]
    fn mismatched_columns_do_not_move_it() {
        // Noisy flow of a receding view, with a block of gross mismatches.
        let mut state = 12345u32;
        let mut noise = || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32 - 0.5
        };
        let s = samples((0..100).map(|c| {
            let x = c as f32 - 50.0;
            let u = if (20..26).contains(&c) {
                400.0
            } else {
                -0.1 * x + 4.0 * noise()
            };
            (x, u)
        }));
        let d = s.divergence().unwrap();
        assert!((d.rate_hz + 0.1).abs() < 3.0 * d.sigma_hz + 0.01, "{d:?}");
        assert!(d.sigma_hz < 0.02, "{d:?}");
        assert_eq!(
            d.time_to_contact_s(),
            None,
            "a receding view has no contact"
        );
    }

    #[test]
    fn too_few_or_too_narrow_gives_none() {
        assert_eq!(
            samples((0..7).map(|c| (c as f32 * 10.0, 1.0))).divergence(),
            None
        );
        // 40 columns within +-10 px of the centre: spread below 12 px.
        let narrow = samples((0..40).map(|c| ((c % 21) as f32 - 10.0, 1.0)));
        assert_eq!(narrow.divergence(), None);
    }
}
