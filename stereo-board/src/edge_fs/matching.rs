//! SAD block matching of edge histograms: per-column stereo disparity and temporal flow.

use super::{EdgeHistogram, IMG_W};

/// Largest number of candidate shifts of one search (`2 * MAX_SEARCH_RANGE + 1`).
pub const MAX_CANDIDATES: usize = 2 * protocol::EdgeFsConfig::MAX_SEARCH_RANGE as usize + 1;

/// Sum of absolute differences between the `2w+1`-bin window of `a` centred at `ca` and the one
/// of `b` centred at `cb`. Returns `u32::MAX` when either window leaves the histogram (never
/// panics). Largest real value: `25 * 24_480`, far below `u32::MAX`.
#[inline]
pub fn sad(a: &EdgeHistogram, ca: isize, b: &EdgeHistogram, cb: isize, w: usize) -> u32 {
    let w = w as isize;
    let (Some(wa), Some(wb)) = (window(a, ca - w, ca + w), window(b, cb - w, cb + w)) else {
        return u32::MAX;
    };
    wa.iter()
        .zip(wb)
        .map(|(&x, &y)| u32::from(x.abs_diff(y)))
        .sum()
}

#[inline]
fn window(h: &EdgeHistogram, lo: isize, hi: isize) -> Option<&[u16]> {
    if lo < 0 || hi >= IMG_W as isize {
        return None;
    }
    h.get(lo as usize..=hi as usize)
}

/// Result of one column's search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColumnMatch {
    /// Index of the first minimum among the candidates (0-based).
    pub best: usize,
    /// Sub-pixel offset from a parabola through the minimum and its neighbours, px in
    /// `-0.5..=0.5` (0 at either end of the range or on a flat minimum).
    pub subpixel: f32,
    /// Peak ratio: the smallest cost at least two candidates away from the minimum divided by
    /// the minimum (>= 1; large = distinct match). `f32::INFINITY` for a perfect unique match.
    pub confidence: f32,
    /// The minimum cost.
    pub cost: u32,
}

/// Searches `n` candidate shifts: candidate `k` compares `reference` at column `rc` with `target`
/// at column `tc0 + k`. Ties resolve to the first (smallest `k`), as MATLAB's `min`.
/// Returns `None` when `n` is 0 or any candidate window leaves the histograms.
pub fn match_column(
    reference: &EdgeHistogram,
    rc: isize,
    target: &EdgeHistogram,
    tc0: isize,
    n: usize,
    w: usize,
) -> Option<ColumnMatch> {
    let mut costs = [0u32; MAX_CANDIDATES];
    let n = n.min(MAX_CANDIDATES);
    let costs = costs.get_mut(..n)?;
    let mut best = 0;
    for (k, cost) in costs.iter_mut().enumerate() {
        *cost = sad(reference, rc, target, tc0 + k as isize, w);
        if *cost == u32::MAX {
            return None;
        }
    }
    for (k, &c) in costs.iter().enumerate() {
        if c < costs[best] {
            best = k;
        }
    }
    let c0 = costs[best];
    let subpixel = if best > 0 && best + 1 < n {
        parabola(costs[best - 1], c0, costs[best + 1])
    } else {
        0.0
    };
    let second = costs
        .iter()
        .enumerate()
        .filter(|(k, _)| k.abs_diff(best) >= 2)
        .map(|(_, &c)| c)
        .min()
        .unwrap_or(c0);
    let confidence = if c0 == 0 {
        if second == 0 {
            1.0
        } else {
            f32::INFINITY
        }
    } else {
        second as f32 / c0 as f32
    };
    Some(ColumnMatch {
        best,
        subpixel,
        confidence,
        cost: c0,
    })
}

/// Vertex offset of the parabola through `(−1, l)`, `(0, m)`, `(1, r)`, clamped to ±0.5 px.
#[inline]
pub fn parabola(l: u32, m: u32, r: u32) -> f32 {
    let (l, m, r) = (l as f32, m as f32, r as f32);
    let denom = l - 2.0 * m + r;
    if denom <= 0.0 {
        return 0.0;
    }
    (0.5 * (l - r) / denom).clamp(-0.5, 0.5)
}

/// Stereo disparity of right-image column `c` (0-based): candidates `d = 0..=max_d` compare
/// `right[c]` with `left[c + d - shift]`, so `d = x_left - x_right + shift` (the data set's
/// MATLAB convention: with the calibrated shift, 0 means infinitely far). First minimum wins.
pub fn stereo_match(
    left: &EdgeHistogram,
    right: &EdgeHistogram,
    c: usize,
    max_d: usize,
    shift: i32,
    w: usize,
) -> Option<ColumnMatch> {
    let c = c as isize;
    match_column(right, c, left, c - shift as isize, max_d + 1, w)
}

/// Temporal flow of column `c` (0-based) of an older histogram: candidates `r = -d..=d` around
/// `offset` compare `older[c]` with `current[c + offset + r]`. The returned `best` indexes
/// `r + d`, so the integer image motion is `offset + best - d` px (content at column `c` then is
/// at `c + motion` now). First minimum wins (ties: most negative motion).
pub fn flow_match(
    older: &EdgeHistogram,
    current: &EdgeHistogram,
    c: usize,
    d: usize,
    offset: i32,
    w: usize,
) -> Option<ColumnMatch> {
    let c = c as isize;
    match_column(
        older,
        c,
        current,
        c + offset as isize - d as isize,
        2 * d + 1,
        w,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured histogram: pseudo-random bins from a small LCG, shifted by `s` px.
    fn texture(s: isize) -> EdgeHistogram {
        let mut base = [0u16; IMG_W + 64];
        let mut x: u32 = 12345;
        for b in base.iter_mut() {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            *b = ((x >> 16) % 2000) as u16;
        }
        let mut h = [0u16; IMG_W];
        for (c, v) in h.iter_mut().enumerate() {
            *v = base[(c as isize + 32 - s) as usize];
        }
        h
    }

    #[test]
    fn stereo_finds_known_disparity_with_shift() {
        // Left image content sits 7 px right of the right image's; calibration shift 3.
        let right = texture(0);
        let left = texture(7);
        for c in 30..90 {
            let m = stereo_match(&left, &right, c, 15, 3, 8).unwrap();
            assert_eq!(m.best, 10, "column {c}");
            assert!(m.confidence > 2.0);
            assert_eq!(m.cost, 0);
        }
    }

    #[test]
    fn flow_finds_known_motion_around_offset() {
        let older = texture(0);
        let current = texture(-4);
        for offset in [-3, 0, 2] {
            let m = flow_match(&older, &current, 60, 10, offset, 5).unwrap();
            assert_eq!(offset + m.best as i32 - 10, -4);
        }
    }

    #[test]
    fn windows_outside_the_image_are_rejected_not_panicking() {
        let h = texture(0);
        assert_eq!(sad(&h, 2, &h, 2, 5), u32::MAX);
        assert!(flow_match(&h, &h, 120, 15, 0, 8).is_none());
        assert!(stereo_match(&h, &h, 0, 15, 0, 8).is_none());
    }

    #[test]
    fn parabola_recovers_subpixel_minimum() {
        // Samples of (x - 0.3)^2 * 100 at -1, 0, 1.
        let f = |x: f32| ((x - 0.3) * (x - 0.3) * 100.0) as u32;
        let p = parabola(f(-1.0), f(0.0), f(1.0));
        assert!((p - 0.3).abs() < 0.02, "{p}");
        assert_eq!(parabola(5, 5, 5), 0.0);
    }

    #[test]
    fn ties_resolve_to_first_candidate() {
        let flat = [100u16; IMG_W];
        let m = flow_match(&flat, &flat, 60, 5, 0, 3).unwrap();
        assert_eq!(m.best, 0);
        assert_eq!(m.confidence, 1.0);
    }
}
