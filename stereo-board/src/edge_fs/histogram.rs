//! Edge histograms: horizontal intensity gradient summed down each column.

use super::{IMG_H, IMG_W};

/// The mean absolute difference of two pixels of white noise, in units of the noise's σ:
/// 2/√π = 1.128.
pub(super) const NOISE_DIFF_PER_SIGMA: f32 = 1.128;

/// Column edge histogram of one camera image, one bin per image column.
///
/// Bin `c` is `sum over rows r of |I(r, c+1) - I(r, c-1)|` with zero padding outside the image
/// (so the two border bins hold the plain column sums of their inner neighbour, as MATLAB's
/// `imfilter` does). The largest possible bin is `96 * 255 = 24_480`, so `u16` is exact.
pub type EdgeHistogram = [u16; IMG_W];

/// Computes the column edge histograms of the left and right images of an interleaved stereo
/// frame (`[L0 R0 L1 R1 ...]`, 128x96, row-major, top row first).
///
/// Integer only; one pass over the frame, four pixels of three rows at a time: the gradient of
/// column `c` compares the bytes `2c - 2` and `2c + 2` of a row, which are four bytes (one `u32`
/// word) apart, so the per-byte absolute difference of two neighbouring words yields the
/// gradients of columns `2j+1` and `2j+2` of both images at once (on the M4: `UQSUB8` both
/// ways + `ORR`). They are accumulated in two packed 16-bit lanes per word (`UXTAB16`; no lane
/// can overflow: at most `96 * 255`). The two border columns (zero padding) are handled
/// outside the loop.
pub fn edge_histograms(
    frame: &[u8; protocol::STEREO_FRAME_BYTES],
    left: &mut EdgeHistogram,
    right: &mut EdgeHistogram,
) {
    histogram_pass::<false>(frame, left, right);
}

/// [`edge_histograms`] and [`mean_intensity`] in one pass over the frame (the mean costs one
/// more `UXTAB16` per word the histogram pass loads anyway, instead of a second pass).
/// Returns the mean intensity of the left image (as [`mean_intensity`]). The default mode of
/// `EdgeFs` uses this.
pub fn edge_histograms_and_mean(
    frame: &[u8; protocol::STEREO_FRAME_BYTES],
    left: &mut EdgeHistogram,
    right: &mut EdgeHistogram,
) -> u8 {
    let sum = histogram_pass::<true>(frame, left, right);
    (sum / (IMG_W * IMG_H) as u32) as u8
}

/// The histogram pass; with `MEAN` it also returns the sum of the left image's pixels (else 0).
/// On the Cortex-M4 the word-packed [`packed_pass`]; elsewhere [`vector_pass`], written for
/// the host's SIMD units (the packed pass's portable byte code is about ten times slower
/// there). Both equal the per-pixel definition (tests).
#[inline(always)]
fn histogram_pass<const MEAN: bool>(
    frame: &[u8; protocol::STEREO_FRAME_BYTES],
    left: &mut EdgeHistogram,
    right: &mut EdgeHistogram,
) -> u32 {
    #[cfg(target_arch = "arm")]
    return packed_pass::<MEAN>(frame, left, right);
    #[cfg(not(target_arch = "arm"))]
    vector_pass::<MEAN>(frame, left, right)
}

/// The histogram pass for hosts with SIMD units: per row, the byte-wise gradient
/// `|row[i + 4] - row[i]|` (bytes `i` and `i + 4` are columns two apart of the same image) is
/// added to one 16-bit accumulator per byte position, in plain loops the compiler vectorises;
/// the accumulators are split into the two images at the end.
#[cfg(any(test, not(target_arch = "arm")))]
fn vector_pass<const MEAN: bool>(
    frame: &[u8; protocol::STEREO_FRAME_BYTES],
    left: &mut EdgeHistogram,
    right: &mut EdgeHistogram,
) -> u32 {
    const ROW: usize = 2 * IMG_W;
    // grad[i]: gradient sums of byte position i + 2 (column i / 2 + 1 of image i % 2);
    // col[i]: plain sums of byte position i (the borders and the mean). At most 96 * 255.
    let mut grad = [0u16; ROW - 4];
    let mut col = [0u16; ROW];
    for row in frame.as_chunks::<ROW>().0 {
        let (ahead, behind) = (&row[4..], &row[..ROW - 4]);
        for ((g, &a), &b) in grad.iter_mut().zip(ahead).zip(behind) {
            *g += u16::from(a.abs_diff(b));
        }
        for (c, &p) in col.iter_mut().zip(row) {
            *c += u16::from(p);
        }
    }
    // Border columns (zero padding): |I(1) - 0| and |0 - I(126)|.
    left[0] = col[2];
    right[0] = col[3];
    left[IMG_W - 1] = col[ROW - 4];
    right[IMG_W - 1] = col[ROW - 3];
    let inner = left[1..IMG_W - 1].iter_mut().zip(&mut right[1..IMG_W - 1]);
    for ((l, r), g) in inner.zip(grad.as_chunks::<2>().0) {
        *l = g[0];
        *r = g[1];
    }
    if MEAN {
        col.iter().step_by(2).map(|&c| u32::from(c)).sum()
    } else {
        0
    }
}

/// The word-packed histogram pass of the Cortex-M4 (see [`edge_histograms`]); built on every
/// target (portable byte code off ARM) so the host tests check it too.
#[cfg_attr(not(target_arch = "arm"), allow(dead_code))]
#[inline(always)]
fn packed_pass<const MEAN: bool>(
    frame: &[u8; protocol::STEREO_FRAME_BYTES],
    left: &mut EdgeHistogram,
    right: &mut EdgeHistogram,
) -> u32 {
    const PAIRS: usize = IMG_W / 2 - 1;
    const ROW: usize = 2 * IMG_W;
    // acc[j] = (left cols 2j+1 | 2j+2 << 16, right cols 2j+1 | 2j+2 << 16).
    let mut acc = [(0u32, 0u32); PAIRS];
    let mut sum = 0u32;
    // A row as its 64 little-endian words (fixed size: no bounds checks in the loop).
    fn words(r: &[u8]) -> Option<&[[u8; 4]; ROW / 4]> {
        r.as_chunks::<4>().0.try_into().ok()
    }
    // Three rows at a time, so the accumulators are loaded and stored once per three rows
    // (four rows' worth of carried words would not fit the M4's registers).
    for rows in frame.chunks_exact(3 * ROW).take(IMG_H / 3) {
        let (a, rest) = rows.split_at(ROW);
        let (b, c) = rest.split_at(ROW);
        let (Some(a), Some(b), Some(c)) = (words(a), words(b), words(c)) else {
            continue;
        };
        let w = |r: &[[u8; 4]; ROW / 4], j: usize| u32::from_le_bytes(r[j]);
        // Left-pixel sum of words 1..=63 of the three rows in two 16-bit lanes (at most
        // 3 * 63 * 255 per lane); word 0 is added with the border columns.
        let mut m = 0u32;
        let mut step = |(l, r): &mut (u32, u32), j: usize| {
            let g = |row: &[[u8; 4]; ROW / 4]| absdiff_u8x4(w(row, j + 1), w(row, j));
            let (ga, gb, gc) = (g(a), g(b), g(c));
            *l = add_bytes02(add_bytes02(add_bytes02(*l, ga), gb), gc);
            *r = add_bytes13(add_bytes13(add_bytes13(*r, ga), gb), gc);
            if MEAN {
                m = add_bytes02(
                    add_bytes02(add_bytes02(m, w(a, j + 1)), w(b, j + 1)),
                    w(c, j + 1),
                );
            }
        };
        // Two word columns per iteration (unrolled by hand: the compiler does not unroll
        // around `asm!`, and carrying the words in rotated registers costs moves otherwise).
        let (two, rest) = acc.as_chunks_mut::<2>();
        for (k, [x, y]) in two.iter_mut().enumerate() {
            step(x, 2 * k);
            step(y, 2 * k + 1);
        }
        for x in rest.iter_mut() {
            step(x, PAIRS - 1);
        }
        sum += (m & 0xFFFF) + (m >> 16);
    }
    // Border columns: |I(1) - 0| and |0 - I(126)|.
    let (mut first, mut last) = ([0u16; 2], [0u16; 2]);
    for row in frame.chunks_exact(ROW).take(IMG_H) {
        if let (Some(&[l1, r1]), Some(&[l126, r126])) = (
            row.get(2..4).and_then(|b| <&[u8; 2]>::try_from(b).ok()),
            row.get(ROW - 4..ROW - 2)
                .and_then(|b| <&[u8; 2]>::try_from(b).ok()),
        ) {
            first[0] += u16::from(l1);
            first[1] += u16::from(r1);
            last[0] += u16::from(l126);
            last[1] += u16::from(r126);
        }
        if MEAN {
            // Left pixels 0 and 1 (bytes 0 and 2).
            if let Some(&[l0, _, l1, _]) = row.first_chunk::<4>() {
                sum += u32::from(l0) + u32::from(l1);
            }
        }
    }
    left[0] = first[0];
    right[0] = first[1];
    left[IMG_W - 1] = last[0];
    right[IMG_W - 1] = last[1];
    let inner = left[1..IMG_W - 1]
        .chunks_exact_mut(2)
        .zip(right[1..IMG_W - 1].chunks_exact_mut(2));
    for ((l, r), &(al, ar)) in inner.zip(acc.iter()) {
        l[0] = al as u16;
        l[1] = (al >> 16) as u16;
        r[0] = ar as u16;
        r[1] = (ar >> 16) as u16;
    }
    sum
}

/// Adds bytes 0 and 2 of `g` to the low and high 16-bit lanes of `acc` (lanes never carry:
/// each holds at most `96 * 255`).
#[cfg(not(target_arch = "arm"))]
#[inline(always)]
fn add_bytes02(acc: u32, g: u32) -> u32 {
    acc + (g & 0x00FF_00FF)
}

/// Adds bytes 1 and 3 of `g` to the low and high 16-bit lanes of `acc`.
#[cfg(not(target_arch = "arm"))]
#[inline(always)]
fn add_bytes13(acc: u32, g: u32) -> u32 {
    acc + ((g >> 8) & 0x00FF_00FF)
}

/// Adds bytes 0 and 2 of `g` to the two 16-bit lanes of `acc`: one `UXTAB16` (DSP extension).
#[cfg(target_arch = "arm")]
#[inline(always)]
fn add_bytes02(acc: u32, g: u32) -> u32 {
    let r: u32;
    // SAFETY: register arithmetic only, no flags.
    unsafe {
        core::arch::asm!(
            "uxtab16 {r}, {a}, {g}",
            a = in(reg) acc,
            g = in(reg) g,
            r = lateout(reg) r,
            options(pure, nomem, nostack, preserves_flags),
        );
    }
    r
}

/// Adds bytes 1 and 3 of `g` to the two 16-bit lanes of `acc`: `UXTAB16` with `ROR #8`.
#[cfg(target_arch = "arm")]
#[inline(always)]
fn add_bytes13(acc: u32, g: u32) -> u32 {
    let r: u32;
    // SAFETY: register arithmetic only, no flags.
    unsafe {
        core::arch::asm!(
            "uxtab16 {r}, {a}, {g}, ror #8",
            a = in(reg) acc,
            g = in(reg) g,
            r = lateout(reg) r,
            options(pure, nomem, nostack, preserves_flags),
        );
    }
    r
}

/// Per-byte absolute difference of four packed bytes.
#[cfg(not(target_arch = "arm"))]
#[inline(always)]
fn absdiff_u8x4(a: u32, b: u32) -> u32 {
    let (a, b) = (a.to_le_bytes(), b.to_le_bytes());
    u32::from_le_bytes([
        a[0].abs_diff(b[0]),
        a[1].abs_diff(b[1]),
        a[2].abs_diff(b[2]),
        a[3].abs_diff(b[3]),
    ])
}

/// Per-byte absolute difference of four packed bytes: the Cortex-M4 DSP extension's saturating
/// byte subtraction both ways (one of the two is 0 in each byte), then OR. Three instructions;
/// needs a core with the DSP extension (thumbv7em, the only ARM target of this crate).
#[cfg(target_arch = "arm")]
#[inline(always)]
fn absdiff_u8x4(a: u32, b: u32) -> u32 {
    let (ab, ba): (u32, u32);
    // SAFETY: pure register arithmetic, no memory access, no flags.
    unsafe {
        core::arch::asm!(
            "uqsub8 {ab}, {a}, {b}",
            "uqsub8 {ba}, {b}, {a}",
            a = in(reg) a,
            b = in(reg) b,
            ab = out(reg) ab,
            ba = out(reg) ba,
            options(pure, nomem, nostack, preserves_flags),
        );
    }
    ab | ba
}

/// Computes the row edge histogram of a stereo frame into the first [`IMG_H`] bins of `rows`
/// (the rest are 0), for the vertical flow.
///
/// Bin `r` is `sum over the columns c ≡ 0, 1 (mod 4) of both images of |I(r+1, c) -
/// I(r-1, c)|`: the vertical gradient summed along the row over half of its pixels (the
/// stereo pair shares the vertical motion, so both images add texture; 128 pixels per bin
/// are more than the 96 of a column bin, at half the cost of all 256). The border rows and
/// the rows next to a dead (all-zero) sensor row get 0: a dead row is a fixed edge that would
/// read as "no vertical motion". At most `128 * 255`, so `u16` is exact.
///
/// One `USADA8` (sum of four absolute byte differences) per word of every other word pair on
/// the Cortex-M4.
pub fn row_histogram(frame: &[u8; protocol::STEREO_FRAME_BYTES], rows: &mut EdgeHistogram) {
    const ROW: usize = 2 * IMG_W;
    *rows = [0; IMG_W];
    let row = |r: usize| -> Option<&[[u8; 4]; ROW / 4]> {
        frame
            .get(r * ROW..(r + 1) * ROW)?
            .as_chunks::<4>()
            .0
            .try_into()
            .ok()
    };
    let mut dead = [false; IMG_H];
    for (r, d) in dead.iter_mut().enumerate() {
        // Short-circuits at the first lit pixel: a few instructions for a live row.
        *d = row(r).is_some_and(|w| w.iter().all(|&b| b == [0; 4]));
    }
    for r in 1..IMG_H - 1 {
        if dead[r - 1] || dead[r] || dead[r + 1] {
            continue;
        }
        let (Some(up), Some(down)) = (row(r - 1), row(r + 1)) else {
            continue;
        };
        let mut acc = 0u32;
        // Words 4k and 4k + 2: columns 8k, 8k + 1 and 8k + 4, 8k + 5 of both images.
        for (u, d) in up.as_chunks::<4>().0.iter().zip(down.as_chunks::<4>().0) {
            acc = sad_u8x4_acc(acc, u32::from_le_bytes(u[0]), u32::from_le_bytes(d[0]));
            acc = sad_u8x4_acc(acc, u32::from_le_bytes(u[2]), u32::from_le_bytes(d[2]));
        }
        if let Some(bin) = rows.get_mut(r) {
            *bin = acc.min(u32::from(u16::MAX)) as u16;
        }
    }
}

/// `acc` plus the sum of the four absolute byte differences of `a` and `b`.
#[cfg(not(target_arch = "arm"))]
#[inline(always)]
fn sad_u8x4_acc(acc: u32, a: u32, b: u32) -> u32 {
    let (a, b) = (a.to_le_bytes(), b.to_le_bytes());
    acc + a
        .iter()
        .zip(b.iter())
        .map(|(&x, &y)| u32::from(x.abs_diff(y)))
        .sum::<u32>()
}

/// `acc` plus the sum of the four absolute byte differences of `a` and `b`: one `USADA8`.
#[cfg(target_arch = "arm")]
#[inline(always)]
fn sad_u8x4_acc(acc: u32, a: u32, b: u32) -> u32 {
    let r: u32;
    // SAFETY: register arithmetic only, no flags.
    unsafe {
        core::arch::asm!(
            "usada8 {r}, {a}, {b}, {acc}",
            a = in(reg) a,
            b = in(reg) b,
            acc = in(reg) acc,
            r = lateout(reg) r,
            options(pure, nomem, nostack, preserves_flags),
        );
    }
    r
}

/// Block grid of [`pixel_noise_dn`]: columns per block and rows per block (one sampled row,
/// the middle one, per block).
const NOISE_BLOCK_W: usize = 16;
const NOISE_BLOCK_H: usize = 16;
/// Blocks of the grid: 8 across, 6 down.
const NOISE_BLOCKS: usize = (IMG_W / NOISE_BLOCK_W) * (IMG_H / NOISE_BLOCK_H);

/// The right camera's pixel noise, DN (1σ), estimated where the image is flat.
///
/// The image is cut into 8 x 6 blocks of 16 x 16 pixels; in one row of each block the mean
/// absolute horizontal difference of pixels two apart (the edge histograms' gradient, of the
/// block's columns shifted one right: 1..=16, 17..=32, ..., the last block stopping at the last
/// inner column) and the mean absolute vertical difference of pixels two rows apart are taken,
/// and the block's value is the smaller (vertical stripes leave the vertical one to noise,
/// horizontal edges the horizontal one). The estimate is the fifth-smallest block (a tenth)
/// over 1.128 (the mean absolute difference of two pixels of white noise σ is 2σ/√π): a frame
/// needs only a tenth of its blocks flat somewhere (a poster's field, the floor, the ceiling),
/// where a median over all pixels reads a dense texture as noise. It errs low by about a fifth
/// (the low end of noisy block means). 0 for a flat, noiseless image.
///
/// Word-packed as the histogram pass: a word holds two columns of both images, and one
/// per-byte absolute difference of two words gives two right-image differences (bytes 1 and
/// 3), summed in two 16-bit lanes (at most 8 · 255 per lane).
pub fn pixel_noise_dn(frame: &[u8; protocol::STEREO_FRAME_BYTES]) -> f32 {
    const ROW: usize = 2 * IMG_W;
    const WORDS: usize = ROW / 4;
    const BLOCK_WORDS: usize = NOISE_BLOCK_W / 2;
    let words = |r: usize| -> Option<&[[u8; 4]; WORDS]> {
        frame
            .get(r * ROW..(r + 1) * ROW)?
            .as_chunks::<4>()
            .0
            .try_into()
            .ok()
    };
    let lanes = |acc: u32| (acc & 0xFFFF) + (acc >> 16);
    let mut blocks = [0u32; NOISE_BLOCKS];
    for (by, out) in blocks.chunks_exact_mut(IMG_W / NOISE_BLOCK_W).enumerate() {
        // The block's middle row and its neighbours.
        let r = by * NOISE_BLOCK_H + NOISE_BLOCK_H / 2;
        let (Some(up), Some(mid), Some(down)) = (words(r - 1), words(r), words(r + 1)) else {
            continue;
        };
        let word = |w: &[u8; 4]| u32::from_le_bytes(*w);
        for (bx, o) in out.iter_mut().enumerate() {
            let j0 = bx * BLOCK_WORDS;
            // Words j and j + 1 give the gradients of columns 2j + 1 and 2j + 2.
            let jx = (j0 + BLOCK_WORDS).min(WORDS - 1);
            let across = mid.get(j0..=jx).unwrap_or(&[]);
            let dx = across.windows(2).fold(0, |acc, p| {
                add_bytes13(acc, absdiff_u8x4(word(&p[1]), word(&p[0])))
            });
            let (ups, downs) = (
                up.get(j0..j0 + BLOCK_WORDS).unwrap_or(&[]),
                down.get(j0..j0 + BLOCK_WORDS).unwrap_or(&[]),
            );
            let dy = ups.iter().zip(downs).fold(0, |acc, (u, d)| {
                add_bytes13(acc, absdiff_u8x4(word(u), word(d)))
            });
            let columns = (2 * (jx - j0)).max(1) as u32;
            *o = (lanes(dx) * NOISE_BLOCK_W as u32 / columns).min(lanes(dy));
        }
    }
    tenth_smallest(&blocks) as f32 / (NOISE_BLOCK_W as f32 * NOISE_DIFF_PER_SIGMA)
}

/// Which smallest block [`pixel_noise_dn`] takes (0-based): a tenth of the blocks.
const NOISE_RANK: usize = NOISE_BLOCKS / 10;

/// The [`NOISE_RANK`]-th smallest of `values` (0-based; `u32::MAX` with fewer values), the
/// element `select_nth_unstable(NOISE_RANK)` finds: the `NOISE_RANK + 1` smallest so far kept
/// sorted by insertion, so most values take one compare.
fn tenth_smallest(values: &[u32]) -> u32 {
    let mut low = [u32::MAX; NOISE_RANK + 1];
    for &v in values {
        if v >= low[NOISE_RANK] {
            continue;
        }
        // Insert `v`; the largest kept leaves.
        let mut i = NOISE_RANK;
        while i > 0 && low[i - 1] > v {
            low[i] = low[i - 1];
            i -= 1;
        }
        low[i] = v;
    }
    low[NOISE_RANK]
}

/// Mean intensity of the left image (0..=255), for the too-dark / too-bright flags.
///
/// Sums four rows' words at a time in two packed 16-bit lanes (bytes 0 and 2 of each
/// little-endian word are left pixels; `UXTAB16` on the M4; a lane's total over four rows is at
/// most `256 * 255 < 2^16`), then folds the lanes.
pub fn mean_intensity(frame: &[u8; protocol::STEREO_FRAME_BYTES]) -> u8 {
    let mut sum = 0u32;
    for rows in frame.chunks_exact(4 * 2 * IMG_W) {
        // Eight words per step (unrolled by hand: the compiler does not unroll around `asm!`).
        let acc = rows.as_chunks::<32>().0.iter().fold(0u32, |acc, c| {
            c.as_chunks::<4>()
                .0
                .iter()
                .fold(acc, |acc, w| add_bytes02(acc, u32::from_le_bytes(*w)))
        });
        sum += (acc & 0xFFFF) + (acc >> 16);
    }
    (sum / (IMG_W * IMG_H) as u32) as u8
}

#[cfg(test)]
// The reference implementations index plainly on purpose.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use protocol::STEREO_FRAME_BYTES;

    /// Plain per-pixel reference (the spec's definition, zero padding).
    fn reference(frame: &[u8; STEREO_FRAME_BYTES]) -> (EdgeHistogram, EdgeHistogram) {
        let (mut l, mut r) = ([0u16; IMG_W], [0u16; IMG_W]);
        let px = |row: usize, c: isize, k: usize| -> i32 {
            if (0..IMG_W as isize).contains(&c) {
                i32::from(frame[2 * (row * IMG_W + c as usize) + k])
            } else {
                0
            }
        };
        for row in 0..IMG_H {
            for c in 0..IMG_W as isize {
                l[c as usize] += (px(row, c + 1, 0) - px(row, c - 1, 0)).unsigned_abs() as u16;
                r[c as usize] += (px(row, c + 1, 1) - px(row, c - 1, 1)).unsigned_abs() as u16;
            }
        }
        (l, r)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]

        /// The packed pass equals the per-pixel definition on random frames (full range,
        /// saturated and low-contrast).
        #[test]
        fn packed_pass_equals_reference(seed in any::<u64>(), mode in 0u8..3) {
            let mut x = seed | 1;
            let mut frame = [0u8; STEREO_FRAME_BYTES];
            for v in frame.iter_mut() {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let b = (x >> 24) as u8;
                *v = match mode {
                    0 => b,
                    1 => if b & 1 == 0 { 0 } else { 255 },
                    _ => 100 + b % 4,
                };
            }
            let (mut l, mut r) = ([1; IMG_W], [1; IMG_W]);
            edge_histograms(&frame, &mut l, &mut r);
            let (wl, wr) = reference(&frame);
            prop_assert_eq!(l, wl);
            prop_assert_eq!(r, wr);
            let plain: u32 = frame.iter().step_by(2).map(|&p| u32::from(p)).sum();
            prop_assert_eq!(mean_intensity(&frame), (plain / (IMG_W * IMG_H) as u32) as u8);
            let (mut l2, mut r2) = ([1; IMG_W], [1; IMG_W]);
            prop_assert_eq!(edge_histograms_and_mean(&frame, &mut l2, &mut r2), mean_intensity(&frame));
            prop_assert_eq!(l2, wl);
            prop_assert_eq!(r2, wr);
            // Both implementations, whichever this target runs.
            for pass in [packed_pass::<true>, vector_pass::<true>] {
                let (mut l3, mut r3) = ([1; IMG_W], [1; IMG_W]);
                prop_assert_eq!(pass(&frame, &mut l3, &mut r3), plain);
                prop_assert_eq!(l3, wl);
                prop_assert_eq!(r3, wr);
            }
            for pass in [packed_pass::<false>, vector_pass::<false>] {
                let (mut l3, mut r3) = ([1; IMG_W], [1; IMG_W]);
                prop_assert_eq!(pass(&frame, &mut l3, &mut r3), 0);
                prop_assert_eq!(l3, wl);
                prop_assert_eq!(r3, wr);
            }
        }
    }

    #[test]
    fn mean_of_saturated_and_dark_frames() {
        // All-255 fills every packed lane to its largest value (256 * 255): no carry.
        let (mut l, mut r) = ([0; IMG_W], [0; IMG_W]);
        let mut both = |f: &[u8; STEREO_FRAME_BYTES]| {
            let m = mean_intensity(f);
            assert_eq!(edge_histograms_and_mean(f, &mut l, &mut r), m);
            m
        };
        assert_eq!(both(&[255; STEREO_FRAME_BYTES]), 255);
        assert_eq!(both(&[0; STEREO_FRAME_BYTES]), 0);
        let mut f = [255u8; STEREO_FRAME_BYTES];
        f.iter_mut().skip(1).step_by(2).for_each(|p| *p = 0);
        assert_eq!(both(&f), 255, "right-image pixels must not count");
        // Only the first two left pixels of each row bright: the border word counts.
        let mut f = [0u8; STEREO_FRAME_BYTES];
        for row in f.chunks_exact_mut(2 * IMG_W) {
            row[0] = 255;
            row[2] = 255;
        }
        assert_eq!(both(&f), (2 * 255 / IMG_W) as u8);
    }

    #[test]
    fn absdiff_u8x4_is_per_byte() {
        assert_eq!(absdiff_u8x4(0x00FF_10FF, 0xFF00_2001), 0xFFFF_10FE);
    }

    fn frame_from(mut f: impl FnMut(usize, usize) -> (u8, u8)) -> [u8; STEREO_FRAME_BYTES] {
        let mut frame = [0u8; STEREO_FRAME_BYTES];
        for r in 0..IMG_H {
            for c in 0..IMG_W {
                let (l, rr) = f(r, c);
                frame[2 * (r * IMG_W + c)] = l;
                frame[2 * (r * IMG_W + c) + 1] = rr;
            }
        }
        frame
    }

    /// Gaussian noise of `sigma` DN around `level` (a small LCG and the sum of four uniforms).
    fn noisy(seed: &mut u64, level: f32, sigma: f32) -> u8 {
        let mut sum = 0.0;
        for _ in 0..4 {
            *seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            sum += (*seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
        }
        // Four uniforms on [-0.5, 0.5] have variance 1/3.
        (level + sum * sigma * 3.0f32.sqrt())
            .round()
            .clamp(0.0, 255.0) as u8
    }

    /// The noise estimate reads the sensor noise on a flat image and on one covered in dense
    /// stripes (where most pixels are on an edge and a median of all gradients reads ~30 DN).
    #[test]
    fn pixel_noise_reads_noise_not_texture() {
        for sigma in [1.5f32, 3.0, 6.0] {
            let mut seed = 7u64;
            let flat = frame_from(|_, _| (0, noisy(&mut seed, 120.0, sigma)));
            let stripes = frame_from(|_, c| {
                let level = if (c / 3) % 2 == 0 { 70.0 } else { 170.0 };
                (0, noisy(&mut seed, level, sigma))
            });
            for (what, frame) in [("flat", flat), ("stripes", stripes)] {
                let est = pixel_noise_dn(&frame);
                assert!(
                    (0.6 * sigma..=1.2 * sigma).contains(&est),
                    "{what}, sigma {sigma}: estimate {est}"
                );
            }
        }
        assert_eq!(pixel_noise_dn(&frame_from(|_, _| (0, 90))), 0.0);
    }

    #[test]
    fn vertical_step_edge_lands_in_the_two_columns_around_it() {
        // Left: step at column 40 (0 -> 100); right: step at column 35.
        let frame =
            frame_from(|_, c| (if c >= 40 { 100 } else { 0 }, if c >= 35 { 50 } else { 0 }));
        let (mut l, mut r) = ([0; IMG_W], [0; IMG_W]);
        edge_histograms(&frame, &mut l, &mut r);
        for c in 1..IMG_W - 1 {
            let want_l = if c == 39 || c == 40 { 9600 } else { 0 };
            let want_r = if c == 34 || c == 35 { 4800 } else { 0 };
            assert_eq!(l[c], want_l, "left bin {c}");
            assert_eq!(r[c], want_r, "right bin {c}");
        }
        // Zero padding: the last bin sees |0 - I(126)|.
        assert_eq!(l[127], 9600);
        assert_eq!(l[0], 0);
    }

    #[test]
    fn saturated_checkerboard_does_not_overflow() {
        let frame = frame_from(|r, c| if (r + c) % 2 == 0 { (255, 255) } else { (0, 0) });
        let (mut l, mut r) = ([0; IMG_W], [0; IMG_W]);
        edge_histograms(&frame, &mut l, &mut r);
        // Neighbours two apart have equal values: no interior gradient.
        assert!(l[1..IMG_W - 1].iter().all(|&v| v == 0));
        assert_eq!(mean_intensity(&frame), 127);
    }

    proptest! {
        /// The insertion selection equals `select_nth_unstable`'s element (ties included).
        #[test]
        fn tenth_smallest_equals_select_nth(
            v in proptest::collection::vec(
                prop_oneof![0u32..16, any::<u32>()],
                NOISE_RANK + 1..=NOISE_BLOCKS,
            ),
        ) {
            let mut sorted = [0u32; NOISE_BLOCKS];
            sorted[..v.len()].copy_from_slice(&v);
            let want = *sorted[..v.len()].select_nth_unstable(NOISE_RANK).1;
            prop_assert_eq!(tenth_smallest(&v), want);
        }
    }

    /// The row histogram equals its per-pixel definition, and a dead row blanks its
    /// neighbours (a fixed black band is no texture that stands still).
    #[test]
    fn row_histogram_equals_definition_and_skips_dead_rows() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut frame = [0u8; STEREO_FRAME_BYTES];
        for v in frame.iter_mut() {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *v = (x >> 24) as u8;
        }
        // Rows 94 and 95 black, as in board 1's forward takes.
        frame[94 * 2 * IMG_W..].fill(0);
        let mut rows = [1; IMG_W];
        row_histogram(&frame, &mut rows);
        let px = |r: usize, k: usize| i32::from(frame[r * 2 * IMG_W + k]);
        for r in 0..IMG_W {
            let want = if (1..93).contains(&r) {
                (0..2 * IMG_W)
                    .filter(|k| k % 8 < 4)
                    .map(|k| (px(r + 1, k) - px(r - 1, k)).unsigned_abs())
                    .sum::<u32>() as u16
            } else {
                0
            };
            assert_eq!(rows[r], want, "row {r}");
        }
        assert!(rows[50] > 0);
    }
}
