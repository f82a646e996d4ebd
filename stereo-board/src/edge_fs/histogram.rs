//! Edge histograms: horizontal intensity gradient summed down each column.

use super::{IMG_H, IMG_W};

/// Column edge histogram of one camera image, one bin per image column.
///
/// Bin `c` is `sum over rows r of |I(r, c+1) - I(r, c-1)|` with zero padding outside the image
/// (so the two border bins hold the plain column sums of their inner neighbour, as MATLAB's
/// `imfilter` does). The largest possible bin is `96 * 255 = 24_480`, so `u16` is exact.
pub type EdgeHistogram = [u16; IMG_W];

/// Computes the column edge histograms of the left and right images of an interleaved stereo
/// frame (`[L0 R0 L1 R1 ...]`, 128x96, row-major, top row first).
///
/// Integer only; one pass over the frame.
pub fn edge_histograms(
    frame: &[u8; protocol::STEREO_FRAME_BYTES],
    left: &mut EdgeHistogram,
    right: &mut EdgeHistogram,
) {
    *left = [0; IMG_W];
    *right = [0; IMG_W];
    for row in frame.chunks_exact(2 * IMG_W).take(IMG_H) {
        // Pixel (c) of this row: left = row[2c], right = row[2c + 1].
        for c in 0..IMG_W {
            let (l_prev, r_prev) = if c == 0 {
                (0, 0)
            } else {
                (row[2 * c - 2], row[2 * c - 1])
            };
            let (l_next, r_next) = if c + 1 == IMG_W {
                (0, 0)
            } else {
                (row[2 * c + 2], row[2 * c + 3])
            };
            left[c] += u16::from(l_next.abs_diff(l_prev));
            right[c] += u16::from(r_next.abs_diff(r_prev));
        }
    }
}

/// Mean intensity of the left image (0..=255), for the too-dark / too-bright flags.
pub fn mean_intensity(frame: &[u8; protocol::STEREO_FRAME_BYTES]) -> u8 {
    let sum: u32 = frame.iter().step_by(2).map(|&p| u32::from(p)).sum();
    (sum / (IMG_W * IMG_H) as u32) as u8
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::STEREO_FRAME_BYTES;

    fn frame_from(f: impl Fn(usize, usize) -> (u8, u8)) -> [u8; STEREO_FRAME_BYTES] {
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
}
