//! Line fits of depth-scaled flow against the column index.

/// A fitted line `v = slope * x + intercept`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LineFit {
    /// Slope (for Edge-FS: forward velocity, m/s).
    pub slope: f64,
    /// Value at `x = 0`.
    pub intercept: f64,
    /// Points used (after rejection, for the robust fit).
    pub n: usize,
    /// Coefficient of determination R² of the (weighted) fit, 0..=1 (0 when undefined).
    pub r2: f32,
}

/// Ordinary least squares through `(x, v)` pairs with MATLAB `polyfit(x, v, 1)`'s degenerate
/// cases: no point gives `0, 0`; one point gives MATLAB's basic solution `slope = v/x`,
/// `intercept = 0` (or `0, v` when `x == 0`). f64 (the paper reproduction needs it).
pub fn line_fit(points: impl Iterator<Item = (f64, f64)> + Clone) -> LineFit {
    let (mut n, mut sx, mut sv) = (0usize, 0.0f64, 0.0f64);
    let mut single = (0.0, 0.0);
    for (x, v) in points.clone() {
        n += 1;
        sx += x;
        sv += v;
        single = (x, v);
    }
    match n {
        0 => return LineFit::default(),
        1 => {
            let (x, v) = single;
            let (slope, intercept) = if x != 0.0 { (v / x, 0.0) } else { (0.0, v) };
            return LineFit {
                slope,
                intercept,
                n,
                r2: 0.0,
            };
        }
        _ => {}
    }
    let (mx, mv) = (sx / n as f64, sv / n as f64);
    let (mut sxx, mut sxv, mut svv) = (0.0, 0.0, 0.0);
    for (x, v) in points {
        let (dx, dv) = (x - mx, v - mv);
        sxx += dx * dx;
        sxv += dx * dv;
        svv += dv * dv;
    }
    if sxx <= 0.0 {
        return LineFit {
            slope: 0.0,
            intercept: mv,
            n,
            r2: 0.0,
        };
    }
    let slope = sxv / sxx;
    let r2 = if svv > 0.0 {
        (sxv * sxv / (sxx * svv)) as f32
    } else {
        0.0
    };
    LineFit {
        slope,
        intercept: mv - slope * mx,
        n,
        r2,
    }
}

/// Weighted least squares in f32 over `(x, v, weight)` triples (weights >= 0).
pub fn weighted_line_fit(points: &[(f32, f32, f32)]) -> Option<LineFit> {
    let (mut sw, mut sx, mut sv) = (0.0f32, 0.0f32, 0.0f32);
    let mut n = 0;
    for &(x, v, w) in points {
        if w > 0.0 {
            sw += w;
            sx += w * x;
            sv += w * v;
            n += 1;
        }
    }
    if n < 2 || sw <= 0.0 {
        return None;
    }
    let (mx, mv) = (sx / sw, sv / sw);
    let (mut sxx, mut sxv, mut svv) = (0.0f32, 0.0f32, 0.0f32);
    for &(x, v, w) in points {
        if w > 0.0 {
            let (dx, dv) = (x - mx, v - mv);
            sxx += w * dx * dx;
            sxv += w * dx * dv;
            svv += w * dv * dv;
        }
    }
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxv / sxx;
    let r2 = if svv > 0.0 {
        (sxv * sxv / (sxx * svv)).clamp(0.0, 1.0)
    } else {
        1.0
    };
    Some(LineFit {
        slope: f64::from(slope),
        intercept: f64::from(mv - slope * mx),
        n,
        r2,
    })
}

/// Robust line fit: weighted least squares, then `iterations` rounds of Huber reweighting with
/// the residual scale from the median absolute deviation (`k = huber_k` scale units). Points are
/// `(x, v, prior_weight)`; `scratch` must be at least as long as `points` (residual buffer, no
/// heap). Returns `None` with fewer than 2 weighted points or no spread in x.
pub fn robust_line_fit(
    points: &mut [(f32, f32, f32)],
    prior: &mut [f32],
    scratch: &mut [f32],
    iterations: usize,
    huber_k: f32,
) -> Option<LineFit> {
    let n = points.len();
    if prior.len() < n || scratch.len() < n {
        return None;
    }
    for (p, w) in points.iter().zip(prior.iter_mut()) {
        *w = p.2;
    }
    let mut fit = weighted_line_fit(points)?;
    for _ in 0..iterations {
        let (a, b) = (fit.slope as f32, fit.intercept as f32);
        // Residuals of this round: those of the weighted points into `scratch` for the MAD,
        // and every point's in its weight slot until the reweighting below (which only needs
        // the residual and the prior weight), so each residual is computed once.
        let mut m = 0;
        for p in points.iter_mut() {
            let r = (p.1 - (a * p.0 + b)).abs();
            if p.2 > 0.0 {
                if let Some(s) = scratch.get_mut(m) {
                    *s = r;
                    m += 1;
                }
            }
            p.2 = r;
        }
        let res = scratch.get_mut(..m)?;
        // The element a full sort would put at `m / 2`, found by selection: O(m), not a sort.
        // The residuals have their sign bit clear (`abs`, NaN included), so ordering their
        // bit patterns as integers is `total_cmp`'s order (cheaper to compare); under that
        // total order the element is unique, so the result is the sort's bit for bit.
        let mad = if m == 0 {
            0.0
        } else {
            *res.select_nth_unstable_by_key(m / 2, |x| x.to_bits()).1
        };
        let scale = (1.4826 * mad).max(1e-6);
        let cut = huber_k * scale;
        for (p, &w0) in points.iter_mut().zip(prior.iter()) {
            let r = p.2;
            p.2 = if r <= cut { w0 } else { w0 * cut / r };
        }
        fit = weighted_line_fit(points)?;
    }
    // Restore the prior weights for the caller.
    for (p, &w0) in points.iter_mut().zip(prior.iter()) {
        p.2 = w0;
    }
    Some(fit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The robust fit as first written: the MAD from a full sort of the residuals.
    fn robust_line_fit_sorting(
        points: &mut [(f32, f32, f32)],
        iterations: usize,
        huber_k: f32,
    ) -> Option<LineFit> {
        let prior: [f32; 128] = core::array::from_fn(|i| points.get(i).map_or(0.0, |p| p.2));
        let mut fit = weighted_line_fit(points)?;
        for _ in 0..iterations {
            let (a, b) = (fit.slope as f32, fit.intercept as f32);
            let mut res = [0.0f32; 128];
            let mut m = 0;
            for p in points.iter().filter(|p| p.2 > 0.0) {
                res[m] = (p.1 - (a * p.0 + b)).abs();
                m += 1;
            }
            res[..m].sort_unstable_by(|x, y| x.total_cmp(y));
            let mad = res[..m].get(m / 2).copied().unwrap_or(0.0);
            let cut = huber_k * (1.4826 * mad).max(1e-6);
            for (p, &w0) in points.iter_mut().zip(prior.iter()) {
                let r = (p.1 - (a * p.0 + b)).abs();
                p.2 = if r <= cut { w0 } else { w0 * cut / r };
            }
            fit = weighted_line_fit(points)?;
        }
        Some(fit)
    }

    fn bits(f: Option<LineFit>) -> Option<(u64, u64, usize, u32)> {
        f.map(|f| {
            (
                f.slope.to_bits(),
                f.intercept.to_bits(),
                f.n,
                f.r2.to_bits(),
            )
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// Selecting the MAD gives exactly the fit of sorting for it (ties, zero weights,
        /// exact lines, gross outliers and non-finite values included).
        #[test]
        fn selected_mad_equals_sorted_mad(
            raw in proptest::collection::vec(
                (
                    -64i32..64,
                    prop_oneof![
                        4 => -50.0f32..50.0,
                        2 => (-3i32..3).prop_map(|v| v as f32),
                        1 => Just(f32::NAN),
                        1 => Just(f32::INFINITY),
                        1 => -1000.0f32..1000.0,
                    ],
                    prop_oneof![4 => Just(1.0f32), 1 => Just(0.0f32), 2 => 0.0f32..3.0],
                ),
                0..=128,
            ),
            line in any::<bool>(),
            iterations in 0usize..6,
            huber_k in prop_oneof![Just(0.0f32), Just(1.0f32), 0.5f32..3.0],
        ) {
            let mut pts: [(f32, f32, f32); 128] = [(0.0, 0.0, 0.0); 128];
            for (p, &(x, v, w)) in pts.iter_mut().zip(raw.iter()) {
                let v = if line { 0.25 * x as f32 - 2.0 } else { v };
                *p = (x as f32 + 0.5, v, w);
            }
            let n = raw.len();
            let mut want_pts = pts;
            let want = robust_line_fit_sorting(&mut want_pts[..n], iterations, huber_k);
            let (mut prior, mut scratch) = ([0.0f32; 128], [0.0f32; 128]);
            let before = pts;
            let got = robust_line_fit(&mut pts[..n], &mut prior, &mut scratch, iterations, huber_k);
            prop_assert_eq!(bits(got), bits(want));
            if got.is_some() {
                // The caller's prior weights are restored.
                for (a, b) in pts.iter().zip(before.iter()) {
                    prop_assert_eq!(a.2.to_bits(), b.2.to_bits());
                }
            }
        }
    }

    #[test]
    fn ols_recovers_line_and_handles_degenerate_cases() {
        let pts = [(1.0, 3.0), (2.0, 5.0), (4.0, 9.0)];
        let f = line_fit(pts.iter().copied());
        assert!((f.slope - 2.0).abs() < 1e-12 && (f.intercept - 1.0).abs() < 1e-12);
        assert!((f.r2 - 1.0).abs() < 1e-6);
        let f = line_fit(core::iter::empty());
        assert_eq!((f.slope, f.intercept), (0.0, 0.0));
        let f = line_fit([(40.0, 8.0)].into_iter());
        assert_eq!((f.slope, f.intercept), (0.2, 0.0));
    }

    #[test]
    fn robust_fit_ignores_outliers_that_break_ols() {
        let mut pts = [(0.0f32, 0.0f32, 1.0f32); 40];
        for (i, p) in pts.iter_mut().enumerate() {
            let x = 20.0 + 2.0 * i as f32;
            let mut v = 0.5 * x - 30.0;
            if i % 10 == 3 {
                v += 200.0; // gross outliers
            }
            *p = (x, v, 1.0);
        }
        let ols = weighted_line_fit(&pts).unwrap();
        assert!((ols.slope - 0.5).abs() > 0.05);
        let (mut prior, mut scratch) = ([0.0; 40], [0.0; 40]);
        let f = robust_line_fit(&mut pts, &mut prior, &mut scratch, 5, 1.5).unwrap();
        assert!((f.slope - 0.5).abs() < 0.02, "{}", f.slope);
        assert!((f.intercept + 30.0).abs() < 1.0, "{}", f.intercept);
    }
}
