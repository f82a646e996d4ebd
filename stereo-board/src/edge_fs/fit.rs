//! Line fits of depth-scaled flow against the column index.

/// The robust residual scale is this many times the median absolute residual: for normal
/// errors, 1.4826 times their median absolute deviation is their σ.
pub(super) const MAD_TO_SIGMA: f32 = 1.4826;
/// Floor of a robust residual scale, so that a perfect fit does not divide by zero.
pub(super) const MIN_SCALE: f32 = 1e-6;

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

/// Groups of the resistant start: the x range is cut into this many equal bins.
const START_GROUPS: usize = 5;

/// A start for the reweighting that clustered outliers cannot drag: least median of squares
/// over a few candidate lines, the least-squares line `ls` and the lines through each pair of
/// group medians (the weighted points cut into [`START_GROUPS`] equal ranges of x, each
/// summarised by its median x and median v). A block of adjacent columns whose flow aliased to
/// a wrong stripe then spoils at most its groups, while a least-squares start would be pulled
/// by all of it and Huber weights only bound each point's pull. `scratch` holds at least
/// `points.len()` values. `None`: fewer than 2 groups with points (the caller keeps `ls`).
/// With `COUNT`, a candidate is first tested by counting its residuals below the best cost so
/// far, which settles most candidates without a selection (same result: tests).
fn resistant_start<const COUNT: bool>(
    points: &[(f32, f32, f32)],
    scratch: &mut [f32],
    ls: LineFit,
) -> Option<(f32, f32)> {
    let (lo, hi) = points
        .iter()
        .filter(|p| p.2 > 0.0)
        .fold((f32::MAX, f32::MIN), |(lo, hi), p| {
            (super::fmin(lo, p.0), super::fmax(hi, p.0))
        });
    if hi <= lo {
        return None;
    }
    let width = (hi - lo) / START_GROUPS as f32;
    let group_of = |x: f32| (((x - lo) / width) as usize).min(START_GROUPS - 1);
    let (centres, n_centres) = if points.len() <= GROUPED_MAX {
        group_centres(points, scratch, group_of)
    } else {
        group_centres_filtered(points, scratch, group_of)
    };
    if n_centres < 2 {
        return None;
    }
    let mut best = (ls.slope as f32, ls.intercept as f32);
    // The least-median-of-squares cost of a line: its median absolute residual.
    let lmeds = |scratch: &mut [f32], (a, b): (f32, f32)| {
        let residuals = points.iter().filter(|p| p.2 > 0.0);
        let residuals = residuals.map(|p| (p.1 - (a * p.0 + b)).abs());
        select_median(residuals, scratch, magnitude_key).unwrap_or(f32::MAX)
    };
    let mut best_cost = lmeds(scratch, best);
    // Residuals the median is taken over (`select_median` keeps at most `scratch.len()`).
    let counted = points
        .iter()
        .filter(|p| p.2 > 0.0)
        .count()
        .min(scratch.len());
    for i in 0..n_centres {
        for j in i + 1..n_centres {
            let ((x0, v0), (x1, v1)) = (centres[i], centres[j]);
            if x1 - x0 <= 0.0 || x1.is_nan() || x0.is_nan() {
                continue;
            }
            let a = (v1 - v0) / (x1 - x0);
            let line = (a, v0 - a * x0);
            // The median (sorted index `counted / 2`) is below the best cost exactly when more
            // than `counted / 2` residuals are: a count settles most lines without selecting.
            let below = if !COUNT {
                0
            } else {
                points
                    .iter()
                    .filter(|p| p.2 > 0.0)
                    .take(counted)
                    .filter(|p| (p.1 - (line.0 * p.0 + line.1)).abs() < best_cost)
                    .count()
            };
            if COUNT && below <= counted / 2 {
                continue;
            }
            let cost = lmeds(scratch, line);
            if cost < best_cost {
                (best, best_cost) = (line, cost);
            }
        }
    }
    best.0.is_finite().then_some(best)
}

/// Longest point set whose groups [`group_centres`] sorts (its indices are bytes); longer ones
/// take [`group_centres_filtered`].
const GROUPED_MAX: usize = 256;

/// The centres (median x, median v) of the non-empty groups of the weighted points, in group
/// order, and their number: each point's group computed once and the points sorted by group
/// (a counting sort of their indices), so that each median reads its group's points only.
/// The same centres as [`group_centres_filtered`] bit for bit: a median is the element a sort
/// under [`order_key`] puts in the middle, and elements of equal key have equal bits, so the
/// order in which a group's points arrive does not matter (tests).
fn group_centres(
    points: &[(f32, f32, f32)],
    scratch: &mut [f32],
    group_of: impl Fn(f32) -> usize,
) -> ([(f32, f32); START_GROUPS], usize) {
    let mut centres = [(0.0f32, 0.0f32); START_GROUPS];
    let mut n_centres = 0;
    // Group of each point (START_GROUPS: no weight), then the indices in group order.
    let mut group = [0u8; GROUPED_MAX];
    let mut count = [0usize; START_GROUPS + 1];
    for (g, p) in group.iter_mut().zip(points) {
        let k = if p.2 > 0.0 {
            group_of(p.0)
        } else {
            START_GROUPS
        };
        *g = k as u8;
        if let Some(c) = count.get_mut(k) {
            *c += 1;
        }
    }
    let mut next = [0usize; START_GROUPS + 1];
    let mut at = 0;
    for (n, &c) in next.iter_mut().zip(count.iter()) {
        *n = at;
        at += c;
    }
    let starts = next;
    let mut order = [0u8; GROUPED_MAX];
    for (i, &g) in group.iter().take(points.len()).enumerate() {
        if let Some(n) = next.get_mut(usize::from(g)) {
            if let Some(o) = order.get_mut(*n) {
                *o = i as u8;
            }
            *n += 1;
        }
    }
    for (&start, &c) in starts.iter().zip(count.iter()).take(START_GROUPS) {
        let members = order.get(start..start + c).unwrap_or(&[]);
        let member = |i: &u8| points.get(usize::from(*i));
        let centre = median_centre(members.iter().filter_map(member), scratch);
        if let (Some(centre), Some(slot)) = (centre, centres.get_mut(n_centres)) {
            *slot = centre;
            n_centres += 1;
        }
    }
    (centres, n_centres)
}

/// [`group_centres`] by filtering all points once per group and coordinate (any length).
fn group_centres_filtered(
    points: &[(f32, f32, f32)],
    scratch: &mut [f32],
    group_of: impl Fn(f32) -> usize,
) -> ([(f32, f32); START_GROUPS], usize) {
    let mut centres = [(0.0f32, 0.0f32); START_GROUPS];
    let mut n_centres = 0;
    for g in 0..START_GROUPS {
        let in_group = |p: &&(f32, f32, f32)| p.2 > 0.0 && group_of(p.0) == g;
        let centre = median_centre(points.iter().filter(in_group), scratch);
        if let (Some(centre), Some(slot)) = (centre, centres.get_mut(n_centres)) {
            *slot = centre;
            n_centres += 1;
        }
    }
    (centres, n_centres)
}

/// The median x and the median v of `members` (`None` when there are none).
fn median_centre<'a>(
    members: impl Iterator<Item = &'a (f32, f32, f32)> + Clone,
    scratch: &mut [f32],
) -> Option<(f32, f32)> {
    let x = select_median(members.clone().map(|p| p.0), scratch, order_key)?;
    let v = select_median(members.map(|p| p.1), scratch, order_key)?;
    Some((x, v))
}

/// Residuals beyond this many robust scales get no weight: Huber weights alone bound each
/// point's pull but not the sum of a block's, and a quarter of the points a stripe period off
/// drags a Huber fit most of the way to least squares.
pub(super) const REJECT_SCALES: f32 = 6.0;

/// The weight of a point of residual `r` and prior weight `w0`: Huber's (`w0` within `cut`,
/// `w0 · cut / r` beyond), none beyond `reject`.
#[inline]
pub(super) fn reweight(r: f32, w0: f32, cut: f32, reject: f32) -> f32 {
    if r <= cut {
        w0
    } else if r <= reject {
        w0 * cut / r
    } else {
        0.0
    }
}

/// The median (the upper one of an even count) of `values` in the order of `key`
/// ([`order_key`], or [`magnitude_key`] for values without a sign), by selection in `scratch`
/// (values beyond its length are ignored); `None` for none.
fn select_median(
    values: impl Iterator<Item = f32>,
    scratch: &mut [f32],
    key: impl FnMut(&f32) -> u32,
) -> Option<f32> {
    let mut m = 0;
    for (s, v) in scratch.iter_mut().zip(values) {
        *s = v;
        m += 1;
    }
    let s = scratch.get_mut(..m).filter(|s| !s.is_empty())?;
    Some(*s.select_nth_unstable_by_key(m / 2, key).1)
}

/// An integer key that orders floats as `total_cmp` does (cheaper to compare on the M4).
#[inline]
pub(super) fn order_key(v: &f32) -> u32 {
    let bits = v.to_bits();
    if bits >> 31 == 1 {
        !bits
    } else {
        bits | 0x8000_0000
    }
}

/// [`order_key`] for floats with the sign bit clear (absolute values, NaN included): their bit
/// patterns order as `total_cmp` does, at no cost. Edge-FS's selections order by these two
/// functions only, so the firmware carries two copies of the selection code.
#[inline]
fn magnitude_key(v: &f32) -> u32 {
    v.to_bits()
}

/// Robust line fit: a resistant start (least median of squares over lines through group
/// medians), then `iterations` rounds of Huber reweighting with the residual scale from the
/// median absolute deviation (`k = huber_k` scale units; beyond 6 scales no weight). Points are
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
    if let Some((slope, intercept)) = resistant_start::<true>(points, scratch, fit) {
        fit.slope = f64::from(slope);
        fit.intercept = f64::from(intercept);
    }
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
        // Under the total order the element is unique, so the result is the sort's bit for bit.
        let mad = if m == 0 {
            0.0
        } else {
            *res.select_nth_unstable_by_key(m / 2, magnitude_key).1
        };
        let scale = (MAD_TO_SIGMA * mad).max(MIN_SCALE);
        let cut = huber_k * scale;
        let reject = REJECT_SCALES * scale;
        for (p, &w0) in points.iter_mut().zip(prior.iter()) {
            p.2 = reweight(p.2, w0, cut, reject);
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

    /// The robust fit as first written: the MAD from a full sort of the residuals (from the
    /// same resistant start).
    fn robust_line_fit_sorting(
        points: &mut [(f32, f32, f32)],
        iterations: usize,
        huber_k: f32,
    ) -> Option<LineFit> {
        let prior: [f32; 128] = core::array::from_fn(|i| points.get(i).map_or(0.0, |p| p.2));
        let mut fit = weighted_line_fit(points)?;
        let mut scratch = [0.0f32; 128];
        if let Some((slope, intercept)) = resistant_start::<false>(points, &mut scratch, fit) {
            fit.slope = f64::from(slope);
            fit.intercept = f64::from(intercept);
        }
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
            let scale = (MAD_TO_SIGMA * mad).max(1e-6);
            let cut = huber_k * scale;
            for (p, &w0) in points.iter_mut().zip(prior.iter()) {
                let r = (p.1 - (a * p.0 + b)).abs();
                p.2 = reweight(r, w0, cut, REJECT_SCALES * scale);
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
            // The counting shortcut of the resistant start changes nothing.
            if let Some(ls) = weighted_line_fit(&pts[..n]) {
                let mut scratch = [0.0f32; 128];
                let counted = resistant_start::<true>(&pts[..n], &mut scratch, ls);
                let plain = resistant_start::<false>(&pts[..n], &mut scratch, ls);
                prop_assert_eq!(
                    counted.map(|(a, b)| (a.to_bits(), b.to_bits())),
                    plain.map(|(a, b)| (a.to_bits(), b.to_bits()))
                );
            }
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

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        /// The group centres from the counting sort equal those of filtering per group, bit
        /// for bit (ties, zero weights, NaN and infinities included).
        #[test]
        fn sorted_group_centres_equal_filtered(
            raw in proptest::collection::vec(
                (
                    prop_oneof![
                        6 => (-64i32..64).prop_map(|x| x as f32 + 0.5),
                        1 => Just(f32::NAN),
                        1 => Just(f32::INFINITY),
                    ],
                    prop_oneof![
                        4 => -50.0f32..50.0,
                        2 => (-3i32..3).prop_map(|v| v as f32),
                        1 => Just(f32::NAN),
                        1 => Just(-0.0f32),
                    ],
                    prop_oneof![4 => Just(1.0f32), 1 => Just(0.0f32), 2 => 0.0f32..3.0],
                ),
                0..=GROUPED_MAX,
            ),
            lo in -70.0f32..0.0,
            width in 0.5f32..30.0,
        ) {
            let group_of = |x: f32| (((x - lo) / width) as usize).min(START_GROUPS - 1);
            let mut scratch = [0.0f32; GROUPED_MAX];
            let (a, na) = group_centres(&raw, &mut scratch, group_of);
            let (b, nb) = group_centres_filtered(&raw, &mut scratch, group_of);
            prop_assert_eq!(na, nb);
            for (p, q) in a.iter().zip(b.iter()).take(na) {
                prop_assert_eq!((p.0.to_bits(), p.1.to_bits()), (q.0.to_bits(), q.1.to_bits()));
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

    /// A block of adjacent columns aliased to a wrong stripe (a quarter of the points, all on
    /// one side) pulls a least-squares start far enough that Huber weights keep it; the
    /// resistant start does not let it.
    #[test]
    fn robust_fit_ignores_a_clustered_block_of_outliers() {
        let mut pts = [(0.0f32, 0.0f32, 1.0f32); 48];
        for (i, p) in pts.iter_mut().enumerate() {
            let x = -47.0 + 2.0 * i as f32;
            let mut v = 0.4 * x - 3.0 + if i % 2 == 0 { 0.5 } else { -0.5 };
            if (34..46).contains(&i) {
                v -= 30.0; // one stripe period off
            }
            *p = (x, v, 1.0);
        }
        let (mut prior, mut scratch) = ([0.0; 48], [0.0; 48]);
        let f = robust_line_fit(&mut pts, &mut prior, &mut scratch, 4, 1.0).unwrap();
        assert!((f.slope - 0.4).abs() < 0.02, "slope {}", f.slope);
        assert!((f.intercept + 3.0).abs() < 1.0, "intercept {}", f.intercept);
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
