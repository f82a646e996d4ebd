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
    for (k, cost) in costs.iter_mut().enumerate() {
        *cost = sad(reference, rc, target, tc0 + k as isize, w);
        if *cost == u32::MAX {
            return None;
        }
    }
    best_match(costs)
}

/// The match of one column from its candidate costs: first minimum, parabola sub-pixel offset
/// and peak-ratio confidence (see [`ColumnMatch`]). `None` only for an empty slice.
pub fn best_match(costs: &[u32]) -> Option<ColumnMatch> {
    let (best, c0) = first_min(costs)?;
    Some(finish_match(costs, best, c0))
}

/// Index and value of the first minimum of `costs` (ties keep the earlier, as MATLAB's
/// `min`); `None` for an empty slice.
#[inline]
fn first_min(costs: &[u32]) -> Option<(usize, u32)> {
    let mut best = 0;
    let mut c0 = *costs.first()?;
    for (k, &c) in costs.iter().enumerate().skip(1) {
        if c < c0 {
            best = k;
            c0 = c;
        }
    }
    Some((best, c0))
}

/// [`best_match`] given its first minimum: `costs[best] == c0`, the first minimum of `costs`.
#[inline]
fn finish_match(costs: &[u32], best: usize, c0: u32) -> ColumnMatch {
    ColumnMatch {
        best,
        subpixel: subpixel_at(costs, best, c0),
        confidence: peak_ratio(costs, best, c0),
        cost: c0,
    }
}

/// The parabola's sub-pixel offset around the first minimum `costs[best] == c0` (0 at either
/// end of the range).
#[inline]
fn subpixel_at(costs: &[u32], best: usize, c0: u32) -> f32 {
    match (
        best.checked_sub(1).and_then(|k| costs.get(k)),
        costs.get(best + 1),
    ) {
        (Some(&l), Some(&r)) => parabola(l, c0, r),
        _ => 0.0,
    }
}

/// The peak ratio of the first minimum `costs[best] == c0` (see [`ColumnMatch::confidence`]).
#[inline]
fn peak_ratio(costs: &[u32], best: usize, c0: u32) -> f32 {
    let n = costs.len();
    // Smallest cost at least two candidates away from the minimum (c0 when there is none;
    // real costs are far below u32::MAX).
    let before = costs.get(..best.saturating_sub(1)).unwrap_or(&[]);
    let after = costs.get((best + 2).min(n)..).unwrap_or(&[]);
    let min = |s: &[u32]| s.iter().fold(u32::MAX, |m, &c| m.min(c));
    let second = match min(before).min(min(after)) {
        u32::MAX => c0,
        s => s,
    };
    if c0 == 0 {
        if second == 0 {
            1.0
        } else {
            f32::INFINITY
        }
    } else {
        second as f32 / c0 as f32
    }
}

/// One column's match from a whole-row search ([`stereo_row`], [`flow_row`],
/// `column_matches`): the first minimum, with the sub-pixel offset and the peak ratio
/// computed only when asked for (the peak ratio scans every candidate again, which a caller
/// that discards the column, untextured say, need not pay for). The values equal
/// [`ColumnMatch`]'s of the same costs.
#[derive(Debug, Clone, Copy)]
pub struct RowMatch<'a> {
    /// Index of the first minimum among the candidates (0-based), as [`ColumnMatch::best`].
    pub best: usize,
    /// The minimum cost.
    pub cost: u32,
    costs: &'a [u32],
}

impl<'a> RowMatch<'a> {
    /// [`ColumnMatch::subpixel`].
    #[inline]
    pub fn subpixel(&self) -> f32 {
        subpixel_at(self.costs, self.best, self.cost)
    }

    /// [`ColumnMatch::confidence`] (the peak ratio).
    #[inline]
    pub fn confidence(&self) -> f32 {
        peak_ratio(self.costs, self.best, self.cost)
    }

    /// The match among the candidates `lo..=hi` only (clamped to the search), as a search of
    /// that window alone would find it: its first minimum, with indices, sub-pixel offset and
    /// peak ratio relative to the window (add `lo` for the search's index). `None` when the
    /// window holds no candidate.
    #[inline]
    pub fn within(&self, lo: usize, hi: usize) -> Option<RowMatch<'a>> {
        let costs = self
            .costs
            .get(lo..=hi.min(self.costs.len().checked_sub(1)?))?;
        let (best, cost) = first_min(costs)?;
        Some(RowMatch { best, cost, costs })
    }

    /// Number of candidates of the search.
    #[inline]
    pub fn candidates(&self) -> usize {
        self.costs.len()
    }

    /// Everything, as [`best_match`] of the same costs returns it.
    #[inline]
    pub fn finish(&self) -> ColumnMatch {
        finish_match(self.costs, self.best, self.cost)
    }
}

/// Largest SAD half-window of the packed kernel (the protocol's limit); wider windows take the
/// scalar path of [`column_costs`].
const MAX_W: usize = protocol::EdgeFsConfig::MAX_HALF_WINDOW as usize;
/// Candidate pairs (two 16-bit lanes per word) of the packed kernel.
const MAX_PAIRS: usize = MAX_CANDIDATES.div_ceil(2);

/// Candidate costs of every column at once, for a search whose target offset is the same for
/// all columns: for each reference column `c` whose `n` candidate windows all fit, in
/// increasing `c`, calls `f(c, costs)` with `costs[k] == sad(reference, c, target,
/// c + delta0 + k, w)` (`n` clamped to `MAX_CANDIDATES`). Columns with a window outside the
/// histograms (where [`match_column`] returns `None`) are skipped.
///
/// Running-sum SAD: each column's costs are the previous column's plus the bin entering and
/// minus the bin leaving each window, so a whole row costs `O(IMG_W · n)` instead of
/// `O(IMG_W · n · (2w+1))`. Each absolute difference is computed once: the differences of the
/// last `2w+1` bins are kept in a ring and the leaving one is read back. Two candidates are
/// handled per 32-bit word (bins are at most `96 · 255 < 2^15`, so differences and their
/// changes fit 16-bit lanes; on the Cortex-M4 `USUB16`/`SEL` and `SSUB16`/`SXTAH`). Integer-exact,
/// so the costs (and [`best_match`] of them) equal the per-column search bit for bit.
pub fn column_costs(
    reference: &EdgeHistogram,
    target: &EdgeHistogram,
    delta0: isize,
    n: usize,
    w: usize,
    mut f: impl FnMut(usize, &[u32]),
) {
    let n = n.min(MAX_CANDIDATES);
    let Some((lo, hi)) = valid_columns(delta0, n, w) else {
        return;
    };
    if w > MAX_W {
        return column_costs_scalar(reference, target, delta0, n, w, lo, hi, f);
    }
    packed_rows::<false, false>(
        reference,
        target,
        delta0,
        n,
        w,
        lo,
        hi,
        &mut [],
        |c, costs, _, _, _| f(c, costs),
    );
}

/// Valid reference columns `lo..=hi` of a whole-row search (see [`column_costs`]), `None` when
/// there is none or nothing to search.
fn valid_columns(delta0: isize, n: usize, w: usize) -> Option<(usize, usize)> {
    valid_columns_in(delta0, n, w, 0, IMG_W - 1)
}

/// [`valid_columns`] for windows within the bins `first..=last` (`last < IMG_W`).
fn valid_columns_in(
    delta0: isize,
    n: usize,
    w: usize,
    first: usize,
    last: usize,
) -> Option<(usize, usize)> {
    let (first, last) = (first as isize, last.min(IMG_W - 1) as isize);
    let (wi, ni) = (w.min(IMG_W) as isize, n as isize);
    // Valid columns: c - w >= first, c + w <= last, c + delta0 - w >= first,
    // c + delta0 + (n - 1) + w <= last.
    let lo = (first + wi).max(first + wi - delta0);
    let hi = (last - wi).min(last - wi - delta0 - (ni - 1));
    (n > 0 && lo <= hi).then_some((lo as usize, hi as usize))
}

/// The packed running-sum kernel of [`column_costs`] (`w <= MAX_W`, `1 <= n <=
/// MAX_CANDIDATES`, `lo..=hi` from [`valid_columns`]): calls `f(c, costs, c0, best, kept)` per
/// column. With `MIN`, `(c0, best)` is the first minimum of `costs` (value, index), found while
/// the costs are updated; without, it is `(0, 0)`. With `MIN` and `KEEP`, column `c`'s cost
/// pairs are also written to row `c % rows` of `keep` (rows of `n.div_ceil(2)` pairs, `rows =
/// keep.len() / n.div_ceil(2)`, at least 1) before `f` is called, and `kept` is `keep`;
/// otherwise `kept` is empty.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn packed_rows<const MIN: bool, const KEEP: bool>(
    reference: &EdgeHistogram,
    target: &EdgeHistogram,
    delta0: isize,
    n: usize,
    w: usize,
    lo: usize,
    hi: usize,
    keep: &mut [[u32; 2]],
    mut f: impl FnMut(usize, &[u32], u32, usize, &[[u32; 2]]),
) {
    let pairs = n.div_ceil(2);
    let rows = keep.len() / pairs.max(1);
    if KEEP && rows == 0 {
        return;
    }
    let mut row = if KEEP { lo % rows } else { 0 };
    // The target as word pairs starting at even (`even[m] = t[2m] | t[2m+1] << 16`) and odd
    // (`odd[m] = t[2m+1] | t[2m+2] << 16`, `t[IMG_W] = 0`) bins: candidates `k`, `k+1` of a
    // bin are one aligned word of either.
    let mut even = [0u32; IMG_W / 2];
    let mut odd = [0u32; IMG_W / 2];
    let mut next = 0u32;
    for ((e, o), t) in even
        .iter_mut()
        .zip(odd.iter_mut())
        .zip(target.chunks_exact(2))
        .rev()
    {
        let (a, b) = (u32::from(t[0]), u32::from(t[1]));
        *e = a | b << 16;
        *o = b | next << 16;
        next = a;
    }
    // costs[p] = (cost of candidate 2p, cost of candidate 2p+1); the ring holds the packed
    // differences of the last 2w+1 entering bins (zero before the first: nothing to remove).
    // With an odd `n` the high lane of the last pair is a spare (a real, in-range bin that is
    // not a candidate): computed, never reported.
    let mut costs = [[0u32; 2]; MAX_PAIRS];
    let mut ring = [[0u32; MAX_PAIRS]; 2 * MAX_W + 1];
    let span = 2 * w + 1;
    let (Some(costs_p), Some(ring)) = (costs.get_mut(..pairs), ring.get_mut(..span)) else {
        return;
    };
    let full = n / 2;
    let mut slot = 0;
    // Bin `j` enters; after bin `c + w` has entered, column `c`'s window is complete.
    for j in lo - w..=hi + w {
        let (Some(&r), Some(old)) = (reference.get(j), ring.get_mut(slot)) else {
            return;
        };
        let rr = u32::from(r) * 0x0001_0001;
        let tb = (j as isize + delta0) as usize;
        let words = if tb.is_multiple_of(2) { &even } else { &odd };
        let Some(words) = words.get(tb / 2..tb / 2 + pairs) else {
            return;
        };
        slot += 1;
        if slot == span {
            slot = 0;
        }
        let emit = j >= lo + w;
        let (mut c0, mut best) = (u32::MAX, 0usize);
        if MIN && emit {
            // Update and track the first minimum (strict `<`: ties keep the earlier). The
            // spare lane of an odd `n` is updated but not searched.
            let (cf, ct) = costs_p.split_at_mut(full);
            let (of, ot) = old.split_at_mut(full);
            let (wf, wt) = words.split_at(full);
            let mut k = 0;
            for ((c, old), &t) in cf.iter_mut().zip(of.iter_mut()).zip(wf) {
                let d = absdiff_u16x2(t, rr);
                accumulate_u16x2(c, d, *old);
                *old = d;
                let [a, b] = *c;
                if a < c0 {
                    c0 = a;
                    best = k;
                }
                if b < c0 {
                    c0 = b;
                    best = k + 1;
                }
                k += 2;
            }
            if let (Some(c), Some(old), Some(&t)) = (ct.first_mut(), ot.first_mut(), wt.first()) {
                let d = absdiff_u16x2(t, rr);
                accumulate_u16x2(c, d, *old);
                *old = d;
                if c[0] < c0 {
                    c0 = c[0];
                    best = k;
                }
            }
            if KEEP {
                // The column's costs, also kept for the left-right check.
                let (Some(kept), Some(costs)) = (
                    keep.get_mut(row * pairs..row * pairs + pairs),
                    costs_p.get(..pairs),
                ) else {
                    return;
                };
                kept.copy_from_slice(costs);
            }
        } else {
            for ((c, old), &t) in costs_p.iter_mut().zip(old.iter_mut()).zip(words) {
                let d = absdiff_u16x2(t, rr);
                accumulate_u16x2(c, d, *old);
                *old = d;
            }
        }
        if emit {
            if let Some(costs) = costs_p.as_flattened().get(..n) {
                f(j - w, costs, c0, best, if KEEP { keep } else { &[] });
            }
            if KEEP {
                row += 1;
                if row == rows {
                    row = 0;
                }
            }
        }
    }
}

/// [`column_costs`] for windows wider than the packed kernel's ring (`w > MAX_W`): plain
/// running sums, both differences computed per column. `lo..=hi` are the valid columns.
#[allow(clippy::too_many_arguments)]
fn column_costs_scalar(
    reference: &EdgeHistogram,
    target: &EdgeHistogram,
    delta0: isize,
    n: usize,
    w: usize,
    lo: usize,
    hi: usize,
    mut f: impl FnMut(usize, &[u32]),
) {
    let mut buf = [0u32; MAX_CANDIDATES];
    let Some(costs) = buf.get_mut(..n) else {
        return;
    };
    // Full sums for the first column.
    let t0 = (lo as isize + delta0) as usize - w;
    let Some(rw) = reference.get(lo - w..=lo + w) else {
        return;
    };
    for (k, cost) in costs.iter_mut().enumerate() {
        let Some(tw) = target.get(t0 + k..=t0 + k + 2 * w) else {
            return;
        };
        *cost = rw
            .iter()
            .zip(tw)
            .map(|(&x, &y)| u32::from(x.abs_diff(y)))
            .sum();
    }
    f(lo, costs);
    // Slide: column c enters bin c + w, drops bin c - w - 1.
    for c in lo + 1..=hi {
        let (add, sub) = (c + w, c - w - 1);
        let ta0 = (add as isize + delta0) as usize;
        let ts0 = (sub as isize + delta0) as usize;
        let (Some(&ra), Some(&rs), Some(ta), Some(ts)) = (
            reference.get(add),
            reference.get(sub),
            target.get(ta0..ta0 + n),
            target.get(ts0..ts0 + n),
        ) else {
            return;
        };
        for ((cost, &a), &s) in costs.iter_mut().zip(ta).zip(ts) {
            // The leaving term is part of the sum: no underflow.
            *cost = *cost + u32::from(ra.abs_diff(a)) - u32::from(rs.abs_diff(s));
        }
        f(c, costs);
    }
}

/// Per-lane absolute difference of two packed `u16` pairs.
#[cfg(not(target_arch = "arm"))]
#[inline(always)]
fn absdiff_u16x2(a: u32, b: u32) -> u32 {
    let lo = (a as u16).abs_diff(b as u16);
    let hi = ((a >> 16) as u16).abs_diff((b >> 16) as u16);
    u32::from(lo) | u32::from(hi) << 16
}

/// Per-lane absolute difference of two packed `u16` pairs: `USUB16` both ways, then `SEL`
/// picks, per lane, the one that did not borrow. Three instructions (DSP extension).
#[cfg(target_arch = "arm")]
#[inline(always)]
fn absdiff_u16x2(a: u32, b: u32) -> u32 {
    let r: u32;
    // SAFETY: register arithmetic only (writes the APSR.GE flags, which nothing else reads).
    unsafe {
        core::arch::asm!(
            "usub16 {t}, {a}, {b}",
            "usub16 {r}, {b}, {a}",
            "sel {r}, {r}, {t}",
            a = in(reg) a,
            b = in(reg) b,
            t = out(reg) _,
            r = lateout(reg) r,
            options(pure, nomem, nostack),
        );
    }
    r
}

/// `cost[0] += new.lo - old.lo`, `cost[1] += new.hi - old.hi` for packed `u16` differences
/// (each below `2^15`, so the per-lane change fits `i16`; the costs never go negative because
/// the leaving difference is part of the sum).
#[cfg(not(target_arch = "arm"))]
#[inline(always)]
fn accumulate_u16x2(cost: &mut [u32; 2], new: u32, old: u32) {
    let lo = i32::from(new as u16) - i32::from(old as u16);
    let hi = i32::from((new >> 16) as u16) - i32::from((old >> 16) as u16);
    cost[0] = cost[0].wrapping_add_signed(lo);
    cost[1] = cost[1].wrapping_add_signed(hi);
}

/// Packed form of the portable `accumulate_u16x2`: `SSUB16` gives both lane changes, `SXTAH`
/// adds the low one sign-extended, `ADD ..., ASR #16` the high one. Three instructions.
#[cfg(target_arch = "arm")]
#[inline(always)]
fn accumulate_u16x2(cost: &mut [u32; 2], new: u32, old: u32) {
    let [mut lo, mut hi] = *cost;
    // SAFETY: register arithmetic only (writes the APSR.GE flags, which nothing else reads).
    unsafe {
        core::arch::asm!(
            "ssub16 {d}, {n}, {o}",
            "sxtah {lo}, {lo}, {d}",
            "add {hi}, {hi}, {d}, asr #16",
            n = in(reg) new,
            o = in(reg) old,
            d = out(reg) _,
            lo = inout(reg) lo,
            hi = inout(reg) hi,
            options(pure, nomem, nostack),
        );
    }
    *cost = [lo, hi];
}

/// Matches of every column of a whole-row search: [`column_costs`] followed by [`best_match`]
/// per column, with the first minimum found while the costs are updated. Calls `f(c, match)`
/// for each valid column, in increasing `c`.
pub fn column_matches(
    reference: &EdgeHistogram,
    target: &EdgeHistogram,
    delta0: isize,
    n: usize,
    w: usize,
    f: impl FnMut(usize, RowMatch<'_>),
) {
    column_matches_in(reference, target, delta0, n, w, 0, IMG_W - 1, f);
}

/// [`column_matches`] of the columns whose windows (reference and every candidate) lie
/// within the bins `first..=last`.
#[allow(clippy::too_many_arguments)]
fn column_matches_in(
    reference: &EdgeHistogram,
    target: &EdgeHistogram,
    delta0: isize,
    n: usize,
    w: usize,
    first: usize,
    last: usize,
    mut f: impl FnMut(usize, RowMatch<'_>),
) {
    let n = n.min(MAX_CANDIDATES);
    let Some((lo, hi)) = valid_columns_in(delta0, n, w, first, last) else {
        return;
    };
    if w > MAX_W {
        return column_costs_scalar(reference, target, delta0, n, w, lo, hi, |c, costs| {
            let Some((best, c0)) = first_min(costs) else {
                return;
            };
            f(
                c,
                RowMatch {
                    best,
                    cost: c0,
                    costs,
                },
            );
        });
    }
    packed_rows::<true, false>(
        reference,
        target,
        delta0,
        n,
        w,
        lo,
        hi,
        &mut [],
        |c, costs, c0, best, _| {
            f(
                c,
                RowMatch {
                    best,
                    cost: c0,
                    costs,
                },
            );
        },
    );
}

/// Stereo matches of every right-image column at once (same candidates and results as
/// [`stereo_match`] per column); calls `f(c, match)` for each column where it is `Some`.
pub fn stereo_row(
    left: &EdgeHistogram,
    right: &EdgeHistogram,
    max_d: usize,
    shift: i32,
    w: usize,
    f: impl FnMut(usize, RowMatch<'_>),
) {
    column_matches(
        right,
        left,
        -(shift as isize),
        max_d.saturating_add(1),
        w,
        f,
    );
}

/// Cost words [`stereo_row_checked`] keeps for the left-right check (2 KiB): the last
/// `2n - 1` columns' costs of a search of `n` candidates, `n.div_ceil(2)` pairs each, fit up to
/// `n = 16` (the default 15 px stereo range); wider searches recompute the reverse costs.
pub const LR_KEEP_PAIRS: usize = 256;

/// [`stereo_row`] with a left-right consistency check of the columns `f` keeps.
///
/// `f(c, match)` is called for each right-image column as by [`stereo_row`]; it returns whether
/// the column is used (then it is checked). The check searches the other way: the left-image
/// content matched at disparity `d` (left bin `c + d - shift`) against the right-image columns
/// `c + d - d'` for every candidate `d'` of the search whose own search is valid, and the first
/// minimum `d'` of those costs must lie within ±1 px of `d`. The right-to-left costs are not
/// searched again: candidate `d'` of left bin `c + d - shift` is candidate `d'` of right column
/// `c + d - d'`, a cost the search computed, so they are the diagonal of the kept cost rows
/// (`keep`, a ring of the last `2n - 1` columns' costs, see [`LR_KEEP_PAIRS`]). A column is
/// checked once the columns up to `c + n - 1` are searched (so all of its diagonal is kept),
/// and `dropped(c)` is called, in increasing `c`, for each used column that fails. When `keep`
/// cannot hold the ring (or the window is wider than the packed kernel's), the diagonal costs
/// are recomputed by [`sad`] instead, with the same result.
#[allow(clippy::too_many_arguments)]
pub fn stereo_row_checked(
    left: &EdgeHistogram,
    right: &EdgeHistogram,
    max_d: usize,
    shift: i32,
    w: usize,
    keep: &mut [[u32; 2]],
    mut f: impl FnMut(usize, RowMatch<'_>) -> bool,
    mut dropped: impl FnMut(usize),
) {
    let n = max_d.saturating_add(1).min(MAX_CANDIDATES);
    let delta0 = -(shift as isize);
    let Some((lo, hi)) = valid_columns(delta0, n, w) else {
        return;
    };
    // Best candidate of each used column awaiting its check.
    let mut pending = [UNUSED_COLUMN; IMG_W];
    let pairs = n.div_ceil(2);
    let rows = 2 * n - 1;
    let stride = 2 * pairs;
    match keep.get_mut(..rows * pairs) {
        Some(keep) if w <= MAX_W => {
            packed_rows::<true, true>(
                right,
                left,
                delta0,
                n,
                w,
                lo,
                hi,
                keep,
                |c, costs, c0, best, kept| {
                    let m = RowMatch {
                        best,
                        cost: c0,
                        costs,
                    };
                    if f(c, m) {
                        if let Some(p) = pending.get_mut(c) {
                            *p = best as u8;
                        }
                    }
                    // Column `c - (n - 1)` now has its whole diagonal.
                    if let Some(x) = (c + 1).checked_sub(n).filter(|&x| x >= lo) {
                        if lr_failed(&pending, x, n, lo, hi, kept.as_flattened(), rows, stride) {
                            dropped(x);
                        }
                    }
                },
            );
            let kept = keep.as_flattened();
            for x in (hi + 2).saturating_sub(n).max(lo)..=hi {
                if lr_failed(&pending, x, n, lo, hi, kept, rows, stride) {
                    dropped(x);
                }
            }
        }
        _ => {
            column_matches(right, left, delta0, n, w, |c, m| {
                if f(c, m) {
                    if let Some(p) = pending.get_mut(c) {
                        *p = m.best as u8;
                    }
                }
            });
            for (x, &d) in pending.iter().enumerate() {
                if d == UNUSED_COLUMN {
                    continue;
                }
                let target = |r: usize, k: usize| {
                    sad(right, r as isize, left, r as isize + delta0 + k as isize, w)
                };
                if !lr_consistent(x, usize::from(d), n, lo, hi, target) {
                    dropped(x);
                }
            }
        }
    }
}

/// A column [`stereo_row_checked`] does not check: its `f` did not use it.
const UNUSED_COLUMN: u8 = u8::MAX;

/// Whether pending column `x` fails the left-right check, from the kept ring of cost rows
/// (row `r` at `(r % rows) * stride`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn lr_failed(
    pending: &[u8; IMG_W],
    x: usize,
    n: usize,
    lo: usize,
    hi: usize,
    kept: &[u32],
    rows: usize,
    stride: usize,
) -> bool {
    match pending.get(x) {
        Some(&d) if d != UNUSED_COLUMN => !lr_consistent(x, usize::from(d), n, lo, hi, |r, k| {
            kept.get((r % rows) * stride + k).copied().unwrap_or(0)
        }),
        _ => false,
    }
}

/// The left-right check of column `x` (in `lo..=hi`) whose best candidate is `d` (`< n`):
/// over the candidates `k` of the reverse search, the diagonal `cost(x + d - k, k)` of the
/// rows `lo..=hi`, the first minimum lies within ±1 of `d`. That is: no earlier candidate
/// reaches the near candidates' minimum and no later one goes below it.
#[inline(always)]
fn lr_consistent(
    x: usize,
    d: usize,
    n: usize,
    lo: usize,
    hi: usize,
    cost: impl Fn(usize, usize) -> u32,
) -> bool {
    let l = x + d;
    // Candidates whose row `l - k` is a searched column.
    let k_lo = l.saturating_sub(hi);
    let k_hi = (l - lo).min(n - 1);
    let near_lo = d.saturating_sub(1).max(k_lo);
    let near_hi = (d + 1).min(k_hi);
    let mut m = u32::MAX;
    for k in near_lo..=near_hi {
        m = m.min(cost(l - k, k));
    }
    (k_lo..near_lo).all(|k| cost(l - k, k) > m) && (near_hi + 1..=k_hi).all(|k| cost(l - k, k) >= m)
}

/// Flow matches of every column of `older` at once (same candidates and results as
/// [`flow_match`] per column); calls `f(c, match)` for each column where it is `Some`.
pub fn flow_row(
    older: &EdgeHistogram,
    current: &EdgeHistogram,
    d: usize,
    offset: i32,
    w: usize,
    f: impl FnMut(usize, RowMatch<'_>),
) {
    column_matches(
        older,
        current,
        offset as isize - d as isize,
        d.saturating_mul(2).saturating_add(1),
        w,
        f,
    );
}

/// [`flow_row`] of the bins `first..=last` only: the positions whose windows, in `older` and
/// at every candidate in `current`, lie within them (for row histograms, whose bins beyond
/// the image height and at its border hold no gradient).
#[allow(clippy::too_many_arguments)]
pub fn flow_row_within(
    older: &EdgeHistogram,
    current: &EdgeHistogram,
    d: usize,
    offset: i32,
    w: usize,
    first: usize,
    last: usize,
    f: impl FnMut(usize, RowMatch<'_>),
) {
    column_matches_in(
        older,
        current,
        offset as isize - d as isize,
        d.saturating_mul(2).saturating_add(1),
        w,
        first,
        last,
        f,
    );
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
// The reference implementations index plainly on purpose.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Plain reference search (spec form): explicit SAD per candidate, first minimum, no
    /// shared code with the optimised kernels.
    fn reference_match(
        r: &EdgeHistogram,
        rc: isize,
        t: &EdgeHistogram,
        tc0: isize,
        n: usize,
        w: usize,
    ) -> Option<ColumnMatch> {
        let w = w as isize;
        let mut costs = [0u32; MAX_CANDIDATES];
        if n == 0 || n > MAX_CANDIDATES {
            return None;
        }
        for k in 0..n {
            let tc = tc0 + k as isize;
            if rc - w < 0 || tc - w < 0 || rc + w >= IMG_W as isize || tc + w >= IMG_W as isize {
                return None;
            }
            let mut sum = 0u32;
            for j in -w..=w {
                let a = i64::from(r[(rc + j) as usize]);
                let b = i64::from(t[(tc + j) as usize]);
                sum += (a - b).unsigned_abs() as u32;
            }
            costs[k] = sum;
        }
        let mut best = 0;
        for k in 1..n {
            if costs[k] < costs[best] {
                best = k;
            }
        }
        let c0 = costs[best];
        let subpixel = if best > 0 && best + 1 < n {
            parabola(costs[best - 1], c0, costs[best + 1])
        } else {
            0.0
        };
        let mut second = c0;
        let mut found = false;
        for k in 0..n {
            if k.abs_diff(best) >= 2 && (!found || costs[k] < second) {
                second = costs[k];
                found = true;
            }
        }
        let confidence = match (c0, second) {
            (0, 0) => 1.0,
            (0, _) => f32::INFINITY,
            _ => second as f32 / c0 as f32,
        };
        Some(ColumnMatch {
            best,
            subpixel,
            confidence,
            cost: c0,
        })
    }

    /// Histograms with plateaus and repeats (ties) as well as full-range values.
    /// A row match finished, after checking that its lazy parts equal the eager ones.
    fn finished(m: &RowMatch<'_>) -> ColumnMatch {
        let full = m.finish();
        assert_eq!((m.best, m.cost), (full.best, full.cost));
        assert_eq!(m.subpixel().to_bits(), full.subpixel.to_bits());
        assert_eq!(m.confidence().to_bits(), full.confidence.to_bits());
        full
    }

    fn hist_strategy() -> impl Strategy<Value = EdgeHistogram> {
        (
            proptest::collection::vec(0u16..=24_480, IMG_W),
            0u16..=3,
            any::<u64>(),
        )
            .prop_map(|(v, q, seed)| {
                let mut h = [0u16; IMG_W];
                for (c, (o, x)) in h.iter_mut().zip(v).enumerate() {
                    // q > 0: coarse values (many equal costs); some runs of zeros.
                    let x = if q > 0 {
                        x / (4096 >> (q * 3)).max(1)
                    } else {
                        x
                    };
                    *o = if (seed >> (c % 64)) & 1 == 1 && q == 2 {
                        0
                    } else {
                        x
                    };
                }
                h
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Every optimised entry point equals the plain reference, column by column.
        #[test]
        fn optimised_matching_equals_reference(
            a in hist_strategy(),
            b in hist_strategy(),
            w in 0usize..=30,
            d in 0usize..=20,
            shift in -20i32..=20,
            offset in -40i32..=40,
        ) {
            // Stereo: per column and whole row.
            let mut row: [Option<ColumnMatch>; IMG_W] = [None; IMG_W];
            stereo_row(&a, &b, d, shift, w, |c, m| row[c] = Some(finished(&m)));
            for c in 0..IMG_W {
                let want = reference_match(&b, c as isize, &a, c as isize - shift as isize, d + 1, w);
                prop_assert_eq!(stereo_match(&a, &b, c, d, shift, w), want, "stereo col {}", c);
                prop_assert_eq!(row[c], want, "stereo row col {}", c);
            }
            // Flow.
            let mut row: [Option<ColumnMatch>; IMG_W] = [None; IMG_W];
            flow_row(&a, &b, d, offset, w, |c, m| row[c] = Some(finished(&m)));
            for c in 0..IMG_W {
                let tc0 = c as isize + offset as isize - d as isize;
                let want = reference_match(&a, c as isize, &b, tc0, 2 * d + 1, w);
                prop_assert_eq!(flow_match(&a, &b, c, d, offset, w), want, "flow col {}", c);
                prop_assert_eq!(row[c], want, "flow row col {}", c);
            }
        }
    }

    /// Columns `stereo_row_checked` drops when every column is used, with `keep` words kept.
    fn lr_dropped(
        left: &EdgeHistogram,
        right: &EdgeHistogram,
        d: usize,
        shift: i32,
        w: usize,
        keep: &mut [[u32; 2]],
    ) -> heapless::Vec<usize, IMG_W> {
        let mut out = heapless::Vec::new();
        stereo_row_checked(
            left,
            right,
            d,
            shift,
            w,
            keep,
            |_, _| true,
            |c| out.push(c).unwrap(),
        );
        out
    }

    /// Plain reference of the left-right check (spec form): each column's best disparity
    /// `d` from the per-column search; the left bin it matched searched against every right
    /// column whose own search is valid, by explicit SADs; dropped when that search's first
    /// minimum is more than 1 px from `d`.
    fn reference_lr_dropped(
        left: &EdgeHistogram,
        right: &EdgeHistogram,
        max_d: usize,
        shift: i32,
        w: usize,
    ) -> heapless::Vec<usize, IMG_W> {
        let n = max_d + 1;
        let valid = |c: usize| stereo_match(left, right, c, max_d, shift, w).is_some();
        let mut out = heapless::Vec::new();
        for x in 0..IMG_W {
            let Some(m) = stereo_match(left, right, x, max_d, shift, w) else {
                continue;
            };
            let lb = (x + m.best) as isize - shift as isize;
            let mut best: Option<(usize, u32)> = None;
            for k in 0..n {
                let Some(r) = (x + m.best).checked_sub(k).filter(|&r| valid(r)) else {
                    continue;
                };
                let cost = reference_match(right, r as isize, left, lb, 1, w)
                    .unwrap()
                    .cost;
                if best.is_none_or(|(_, b)| cost < b) {
                    best = Some((k, cost));
                }
            }
            let (k, _) = best.unwrap();
            if k.abs_diff(m.best) > 1 {
                out.push(x).unwrap();
            }
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// The left-right check from the kept cost rows equals the one that recomputes the
        /// reverse costs, and both equal the plain reference; the matches `f` sees are
        /// `stereo_row`'s.
        #[test]
        fn lr_check_equals_reference(
            a in hist_strategy(),
            b in hist_strategy(),
            w in 1usize..=12,
            d in 0usize..=20,
            shift in -20i32..=20,
        ) {
            let mut keep = [[0u32; 2]; LR_KEEP_PAIRS];
            let want = reference_lr_dropped(&a, &b, d, shift, w);
            let kept = lr_dropped(&a, &b, d, shift, w, &mut keep);
            let recomputed = lr_dropped(&a, &b, d, shift, w, &mut []);
            prop_assert_eq!(&kept, &want);
            prop_assert_eq!(&recomputed, &want);
            let mut row: [Option<ColumnMatch>; IMG_W] = [None; IMG_W];
            stereo_row(&a, &b, d, shift, w, |c, m| row[c] = Some(m.finish()));
            let mut checked: [Option<ColumnMatch>; IMG_W] = [None; IMG_W];
            stereo_row_checked(&a, &b, d, shift, w, &mut keep, |c, m| {
                checked[c] = Some(finished(&m));
                c % 2 == 0
            }, |c| assert!(c % 2 == 0, "column {c} was not used"));
            prop_assert_eq!(checked, row);
        }
    }

    #[test]
    fn lr_check_keeps_a_fronto_parallel_wall() {
        // A textured wall at one distance: disparity 7 everywhere (shift 0).
        let (right, left) = (texture(0), texture(7));
        let mut keep = [[0u32; 2]; LR_KEEP_PAIRS];
        let mut used = 0;
        let mut dropped = 0;
        stereo_row_checked(
            &left,
            &right,
            15,
            0,
            6,
            &mut keep,
            |_, m| {
                used += 1;
                assert_eq!(m.best, 7);
                true
            },
            |_| dropped += 1,
        );
        assert!(used > 90, "{used}");
        assert_eq!(dropped, 0);
    }

    #[test]
    fn lr_check_drops_the_columns_occluded_in_the_left_image() {
        // A textured background at disparity 2 and a near object at disparity 10 in front of
        // it in the right image's columns 60..80. The left image sees the object at 70..90,
        // so the background the right image sees at 80..88 is hidden in the left one.
        let (bg, obj) = (texture(0), texture(-30));
        let mut right = [0u16; IMG_W];
        let mut left = [0u16; IMG_W];
        for x in 0..IMG_W {
            right[x] = if (60..80).contains(&x) { obj[x] } else { bg[x] };
            left[x] = if (70..90).contains(&x) {
                obj[x - 10]
            } else {
                bg[x.saturating_sub(2)]
            };
        }
        let w = 2;
        let mut keep = [[0u32; 2]; LR_KEEP_PAIRS];
        let mut best = [usize::MAX; IMG_W];
        let mut dropped = heapless::Vec::<usize, IMG_W>::new();
        stereo_row_checked(
            &left,
            &right,
            15,
            0,
            w,
            &mut keep,
            |c, m| {
                best[c] = m.best;
                true
            },
            |c| dropped.push(c).unwrap(),
        );
        // Away from the edges both surfaces match at their disparity and are kept.
        for c in (20..56).chain(64..76).chain(95..110) {
            let want = if (60..80).contains(&c) { 10 } else { 2 };
            assert_eq!(best[c], want, "column {c}");
            assert!(!dropped.contains(&c), "column {c} dropped");
        }
        // The columns that see background hidden in the left image match something else,
        // and the check drops them.
        let occluded: heapless::Vec<usize, IMG_W> = (80 + w..88 - w).collect();
        for &c in &occluded {
            assert!(
                dropped.contains(&c),
                "occluded column {c} kept, best {}",
                best[c]
            );
        }
        assert_eq!(lr_dropped(&left, &right, 15, 0, w, &mut []), dropped);
    }

    #[test]
    fn column_costs_visits_columns_in_order_and_handles_degenerate_input() {
        let h = texture(0);
        let mut seen = heapless::Vec::<usize, IMG_W>::new();
        column_costs(&h, &h, -3, 7, 4, |c, costs| {
            assert_eq!(costs.len(), 7);
            assert_eq!(costs[3], 0);
            seen.push(c).unwrap();
        });
        let want: heapless::Vec<usize, IMG_W> = (7..=IMG_W - 8).collect();
        assert_eq!(seen, want);
        // Nothing fits / nothing to search: no calls, no panic.
        column_costs(&h, &h, 0, 0, 3, |_, _| panic!("n = 0"));
        column_costs(&h, &h, 0, 5, 200, |_, _| {
            panic!("window wider than the image")
        });
        column_costs(&h, &h, 500, 5, 3, |_, _| panic!("offset beyond the image"));
        column_costs(&h, &h, -500, 5, 3, |_, _| panic!("offset beyond the image"));
        assert!(match_column(&h, 60, &h, 60, 0, 3).is_none());
        assert!(best_match(&[]).is_none());
    }

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
