//! Texture statistics of stereo frames, the quantities `sim-host replay` matches a rendered
//! scene to. Every statistic but the right/left ratios is computed on the left camera image (the even bytes of an
//! interleaved frame, [`protocol::STEREO_FRAME_BYTES`]) over its *valid rows*: the rows that are
//! not entirely zero (the recorder pads most data-set images from 94 to 96 rows with black rows).
//!
//! Definitions, with `I(x, y)` the grey level (DN) at column `x`, row `y`, and
//! `g(x, y) = I(x + 1, y) - I(x - 1, y)` the central horizontal difference for `x = 1..=126`
//! (the gradient Edge-FS sums into its column histograms):
//!
//! * **edge density of column `x`**: the fraction of the valid pixels of column `x` with
//!   `|g(x, y)| >= EDGE_THRESHOLD_DN` (0 for the two border columns, which have no `g`);
//! * **gradient histogram**: the fraction of all pixels with a `g` (valid rows, columns
//!   `1..=126`) whose `|g|` falls in each of the bins of [`GRADIENT_BINS_DN`]
//!   (`[0, 2), [2, 4), [4, 8), [8, 16), [16, 32), [32, 64), [64, 256)`); the fractions sum to 1;
//! * **noise level**: `median(|L(x, y)|) / (0.6745 * 6)` DN over the interior valid pixels,
//!   where `L` is the image filtered with the 3x3 mask `[1 -2 1; -2 4 -2; 1 -2 1]`. The mask
//!   removes planes and (largely) straight edges, its coefficients' squares sum to 36, so for
//!   white Gaussian noise of deviation `s` the response has deviation `6 s` and the median of
//!   its magnitude is `0.6745 * 6 s`; the median makes it robust to the texture's sparse edges;
//! * **mean level** and **contrast**: the mean and the standard deviation of `I`, DN;
//! * **textured columns**: the fraction of columns whose Edge-FS column histogram
//!   (`sum_y |g(x, y)|` over all 96 rows) reaches the default configuration's `min_texture`
//!   (the columns Edge-FS can match at all);
//! * **right/left level** and **right/left edges**: the right camera's mean grey level and
//!   summed `|g|` over the left camera's (the only statistics that read the right image).
//!
//! A take's statistics ([`TakeStats`]) are the means of its frames' statistics.

use protocol::STEREO_FRAME_BYTES;
use stereo_board::edge_fs::{EdgeFsParams, IMG_H, IMG_W};

/// Smallest |central horizontal difference| that counts as an edge, DN (about six times the
/// difference's noise deviation at the renderer's default shot noise).
pub const EDGE_THRESHOLD_DN: i32 = 16;

/// Lower bin edges of the gradient histogram, DN; the last bin runs to 255.
pub const GRADIENT_BINS_DN: [i32; 7] = [0, 2, 4, 8, 16, 32, 64];

/// Number of gradient-histogram bins.
pub const N_BINS: usize = GRADIENT_BINS_DN.len();

/// Texture statistics of one frame or the mean over a take's frames (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct FrameStats {
    /// Edge density of each column, 0..=1.
    pub edge_density: [f64; IMG_W],
    /// Gradient histogram, fractions per bin of [`GRADIENT_BINS_DN`] (sum 1).
    pub gradient_hist: [f64; N_BINS],
    /// Noise level, DN.
    pub noise_dn: f64,
    /// Mean grey level, DN.
    pub mean_dn: f64,
    /// Standard deviation of the grey level, DN.
    pub contrast_dn: f64,
    /// Fraction of columns with an Edge-FS histogram of at least `min_texture`.
    pub textured_columns: f64,
    /// Right over left camera: ratio of the mean grey levels.
    pub right_left_level: f64,
    /// Right over left camera: ratio of the summed `|g|` (edge energy).
    pub right_left_edges: f64,
}

impl FrameStats {
    /// Statistics of one interleaved stereo frame (left image).
    pub fn of_frame(frame: &[u8; STEREO_FRAME_BYTES]) -> Self {
        let px = |x: usize, y: usize| i32::from(frame[2 * (y * IMG_W + x)]);
        let valid: Vec<usize> = (0..IMG_H)
            .filter(|&y| (0..IMG_W).any(|x| px(x, y) != 0))
            .collect();
        let mut edge_density = [0.0; IMG_W];
        let mut counts = [0u64; N_BINS];
        let mut col_sum = [0u32; IMG_W];
        for y in 0..IMG_H {
            for (x, s) in col_sum.iter_mut().enumerate().take(IMG_W - 1).skip(1) {
                *s += px(x + 1, y).abs_diff(px(x - 1, y));
            }
        }
        for &y in &valid {
            for (x, d) in edge_density.iter_mut().enumerate().take(IMG_W - 1).skip(1) {
                let g = (px(x + 1, y) - px(x - 1, y)).abs();
                if g >= EDGE_THRESHOLD_DN {
                    *d += 1.0;
                }
                let bin = GRADIENT_BINS_DN
                    .iter()
                    .rposition(|&lo| g >= lo)
                    .unwrap_or(0);
                counts[bin] += 1;
            }
        }
        let rows = valid.len().max(1) as f64;
        for d in &mut edge_density {
            *d /= rows;
        }
        let total = counts.iter().sum::<u64>().max(1) as f64;
        let gradient_hist = counts.map(|c| c as f64 / total);
        // Noise: median |3x3 Laplacian-like response| over interior pixels whose 3 rows are valid.
        let mut resp: Vec<i32> = Vec::with_capacity(IMG_W * IMG_H);
        for w in valid.windows(3) {
            let (a, b, c) = (w[0], w[1], w[2]);
            if b != a + 1 || c != b + 1 {
                continue;
            }
            for x in 1..IMG_W - 1 {
                let r = px(x - 1, a) - 2 * px(x, a) + px(x + 1, a) - 2 * px(x - 1, b)
                    + 4 * px(x, b)
                    - 2 * px(x + 1, b)
                    + px(x - 1, c)
                    - 2 * px(x, c)
                    + px(x + 1, c);
                resp.push(r.abs());
            }
        }
        let noise_dn = if resp.is_empty() {
            0.0
        } else {
            let m = resp.len() / 2;
            let (_, med, _) = resp.select_nth_unstable(m);
            f64::from(*med) / (0.6745 * 6.0)
        };
        let n = (valid.len() * IMG_W).max(1) as f64;
        let (mut sum, mut sq) = (0.0, 0.0);
        for &y in &valid {
            for x in 0..IMG_W {
                let v = f64::from(px(x, y));
                sum += v;
                sq += v * v;
            }
        }
        let mean_dn = sum / n;
        let contrast_dn = (sq / n - mean_dn * mean_dn).max(0.0).sqrt();
        let (mut lsum, mut rsum, mut le, mut re) = (0.0, 0.0, 0.0, 0.0);
        for &y in &valid {
            for x in 0..IMG_W {
                let i = 2 * (y * IMG_W + x);
                lsum += f64::from(frame[i]);
                rsum += f64::from(frame[i + 1]);
                if (1..IMG_W - 1).contains(&x) {
                    let (a, b) = (i - 2, i + 2);
                    le += f64::from(frame[b].abs_diff(frame[a]));
                    re += f64::from(frame[b + 1].abs_diff(frame[a + 1]));
                }
            }
        }
        let min_texture = EdgeFsParams::default_config().min_texture;
        let textured = col_sum.iter().filter(|&&s| s >= min_texture).count();
        Self {
            edge_density,
            gradient_hist,
            noise_dn,
            mean_dn,
            contrast_dn,
            textured_columns: textured as f64 / IMG_W as f64,
            right_left_level: if lsum > 0.0 { rsum / lsum } else { 1.0 },
            right_left_edges: if le > 0.0 { re / le } else { 1.0 },
        }
    }

    /// Mean edge density over the columns that have a gradient (`1..=126`).
    pub fn mean_edge_density(&self) -> f64 {
        self.edge_density[1..IMG_W - 1].iter().sum::<f64>() / (IMG_W - 2) as f64
    }

    /// The `q`-quantile (0..=1) of the column edge densities (columns `1..=126`).
    pub fn edge_density_quantile(&self, q: f64) -> f64 {
        let mut v: Vec<f64> = self.edge_density[1..IMG_W - 1].to_vec();
        v.sort_by(f64::total_cmp);
        let k = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
        v[k]
    }

    /// Fraction of gradients of at least `lo` DN (`lo` one of [`GRADIENT_BINS_DN`]).
    pub fn gradient_fraction_above(&self, lo: i32) -> f64 {
        GRADIENT_BINS_DN
            .iter()
            .zip(&self.gradient_hist)
            .filter(|(&b, _)| b >= lo)
            .map(|(_, f)| f)
            .sum()
    }

    /// Distance between two sets of statistics used to match a scene to a take: the L1
    /// distance of the gradient histograms (0..=2) plus the L1 distance of the column edge
    /// densities sorted by value (the shape of the per-column distribution, independent of
    /// where in the image the edges are), averaged over the columns (0..=1).
    pub fn texture_distance(&self, other: &Self) -> f64 {
        let hist: f64 = self
            .gradient_hist
            .iter()
            .zip(&other.gradient_hist)
            .map(|(a, b)| (a - b).abs())
            .sum();
        let sorted = |s: &Self| {
            let mut v = s.edge_density[1..IMG_W - 1].to_vec();
            v.sort_by(f64::total_cmp);
            v
        };
        let (a, b) = (sorted(self), sorted(other));
        let cols = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64;
        hist + cols
    }
}

/// Mean statistics over frames.
#[derive(Debug, Clone, Default)]
pub struct TakeStats {
    sum: Option<FrameStats>,
    n: usize,
}

impl TakeStats {
    /// Adds one frame.
    pub fn add(&mut self, frame: &[u8; STEREO_FRAME_BYTES]) {
        self.add_stats(&FrameStats::of_frame(frame));
    }

    /// Adds the statistics of one frame.
    pub fn add_stats(&mut self, s: &FrameStats) {
        self.n += 1;
        match &mut self.sum {
            None => self.sum = Some(s.clone()),
            Some(t) => {
                for (a, b) in t.edge_density.iter_mut().zip(&s.edge_density) {
                    *a += b;
                }
                for (a, b) in t.gradient_hist.iter_mut().zip(&s.gradient_hist) {
                    *a += b;
                }
                t.noise_dn += s.noise_dn;
                t.mean_dn += s.mean_dn;
                t.contrast_dn += s.contrast_dn;
                t.textured_columns += s.textured_columns;
                t.right_left_level += s.right_left_level;
                t.right_left_edges += s.right_left_edges;
            }
        }
    }

    /// Frames added.
    pub fn frames(&self) -> usize {
        self.n
    }

    /// The mean over the frames added (`None` before the first).
    pub fn mean(&self) -> Option<FrameStats> {
        let mut m = self.sum.clone()?;
        let k = 1.0 / self.n as f64;
        for a in &mut m.edge_density {
            *a *= k;
        }
        for a in &mut m.gradient_hist {
            *a *= k;
        }
        m.noise_dn *= k;
        m.mean_dn *= k;
        m.contrast_dn *= k;
        m.textured_columns *= k;
        m.right_left_level *= k;
        m.right_left_edges *= k;
        Some(m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn frame(f: impl Fn(usize, usize) -> u8) -> Box<[u8; STEREO_FRAME_BYTES]> {
        let mut fr = Box::new([0u8; STEREO_FRAME_BYTES]);
        for y in 0..IMG_H {
            for x in 0..IMG_W {
                fr[2 * (y * IMG_W + x)] = f(x, y);
                fr[2 * (y * IMG_W + x) + 1] = f(x, y);
            }
        }
        fr
    }

    #[test]
    fn a_single_step_edge_has_known_density_and_histogram() {
        // Left half 50, right half 150: only columns 63 and 64 see the step (|g| = 100).
        let s = FrameStats::of_frame(&frame(|x, _| if x < 64 { 50 } else { 150 }));
        for (x, &d) in s.edge_density.iter().enumerate() {
            let want = if x == 63 || x == 64 { 1.0 } else { 0.0 };
            assert_eq!(d, want, "column {x}");
        }
        assert!((s.mean_edge_density() - 2.0 / 126.0).abs() < 1e-12);
        assert!((s.gradient_hist[6] - 2.0 / 126.0).abs() < 1e-12);
        assert!((s.gradient_hist[0] - 124.0 / 126.0).abs() < 1e-12);
        assert!((s.gradient_hist.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert_eq!(s.noise_dn, 0.0, "a straight edge is not noise");
        assert!((s.mean_dn - 100.0).abs() < 1e-9);
        assert!((s.contrast_dn - 50.0).abs() < 1e-9);
        // Column sums: 96 * 100 = 9600 >= min_texture on the two edge columns only.
        assert!((s.textured_columns - 2.0 / 128.0).abs() < 1e-12);
    }

    #[test]
    fn stripes_every_fourth_column_and_black_rows() {
        // Period-8 square wave: every column next to a step sees |g| = 80; rows 94 and 95 are
        // black padding and do not count.
        let s = FrameStats::of_frame(&frame(|x, y| {
            if y >= 94 {
                0
            } else if (x / 4) % 2 == 0 {
                60
            } else {
                140
            }
        }));
        // Steps between x = 4k - 1 and 4k: columns 4k - 1 and 4k have |g| = 80 (half of all).
        let expect = (1..IMG_W - 1).filter(|x| x % 4 == 0 || x % 4 == 3).count() as f64 / 126.0;
        assert!((s.mean_edge_density() - expect).abs() < 1e-12);
        assert_eq!(s.edge_density[3], 1.0);
        assert_eq!(s.edge_density[5], 0.0);
        assert!((s.mean_dn - 100.0).abs() < 1e-9, "black rows excluded");
    }

    #[test]
    fn noise_estimate_recovers_the_added_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for sigma in [2.0f64, 5.0, 10.0] {
            // Noise over a ramp with a few strong edges: the median ignores the edges.
            let noise: Vec<f64> = (0..IMG_W * IMG_H)
                .map(|_| {
                    // Box-Muller.
                    let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-12), rng.random());
                    sigma * (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
                })
                .collect();
            let s = FrameStats::of_frame(&frame(|x, y| {
                let base = 60.0 + 0.5 * x as f64 + if x % 16 < 8 { 0.0 } else { 60.0 };
                (base + noise[y * IMG_W + x]).round().clamp(1.0, 255.0) as u8
            }));
            // Rounding to integers adds 1/12 DN² of variance.
            let want = (sigma * sigma + 1.0 / 12.0).sqrt();
            assert!(
                (s.noise_dn / want - 1.0).abs() < 0.15,
                "sigma {sigma}: estimated {}",
                s.noise_dn
            );
        }
    }

    #[test]
    fn take_means_and_distance() {
        let a = FrameStats::of_frame(&frame(|x, _| if x < 64 { 50 } else { 150 }));
        let b = FrameStats::of_frame(&frame(|_, _| 100));
        let mut t = TakeStats::default();
        t.add_stats(&a);
        t.add_stats(&b);
        let m = t.mean().unwrap();
        assert_eq!(t.frames(), 2);
        assert_eq!(m.edge_density[63], 0.5);
        assert!((m.mean_dn - 100.0).abs() < 1e-9);
        assert_eq!(a.texture_distance(&a), 0.0);
        let d = a.texture_distance(&b);
        // Histograms differ by 2 x 2/126, sorted densities by 2/126.
        assert!((d - 6.0 / 126.0).abs() < 1e-12, "{d}");
        assert!(TakeStats::default().mean().is_none());
    }
}
