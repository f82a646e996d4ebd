//! Fast standard normal deviates for the camera's per-pixel noise: a table of
//! [`NORMAL_TABLE_LEN`] values indexed by 12 random bits.
//!
//! The real line is cut into `NORMAL_TABLE_LEN` intervals of equal probability, and entry `i` is
//! the mean of a standard normal variable conditioned on falling into interval `i`, so a
//! uniformly drawn entry has mean 0 exactly (the table is symmetric) and the normal
//! distribution's shape at a resolution of 1/4096 in probability; the table is scaled to unit
//! variance (the conditioning loses about 1e-4 of it, in the tails). The largest deviate is
//! the mean of the outermost interval, 3.62. One draw costs a table read instead of Box-Muller's
//! logarithm, cosine and square root in double precision.

use std::sync::OnceLock;

/// Number of entries (a power of two: an index is the top bits of a random word).
pub const NORMAL_TABLE_LEN: usize = 1 << NORMAL_TABLE_BITS;
/// Random bits per index.
pub const NORMAL_TABLE_BITS: u32 = 12;

/// The table, built on first use (a few milliseconds).
pub fn normal_table() -> &'static [f32; NORMAL_TABLE_LEN] {
    static TABLE: OnceLock<Box<[f32; NORMAL_TABLE_LEN]>> = OnceLock::new();
    TABLE.get_or_init(build)
}

/// The standard normal density.
fn pdf(z: f64) -> f64 {
    (-0.5 * z * z).exp() / (2.0 * core::f64::consts::PI).sqrt()
}

fn build() -> Box<[f32; NORMAL_TABLE_LEN]> {
    // The distribution function on a fine grid over [-Z_MAX, Z_MAX] (Simpson's rule per step),
    // then each equal-probability edge by linear interpolation in it.
    const Z_MAX: f64 = 9.0;
    const STEPS: usize = 36_864;
    let h = 2.0 * Z_MAX / STEPS as f64;
    let mut cdf = Vec::with_capacity(STEPS + 1);
    let mut acc = 0.0f64;
    cdf.push(0.0);
    for k in 0..STEPS {
        let a = -Z_MAX + k as f64 * h;
        acc += h / 6.0 * (pdf(a) + 4.0 * pdf(a + 0.5 * h) + pdf(a + h));
        cdf.push(acc);
    }
    let quantile = |p: f64| -> f64 {
        let k = cdf.partition_point(|&c| c < p).clamp(1, STEPS);
        let (c0, c1) = (cdf[k - 1], cdf[k]);
        let frac = if c1 > c0 { (p - c0) / (c1 - c0) } else { 0.0 };
        -Z_MAX + (k as f64 - 1.0 + frac) * h
    };
    // Density at each edge; the outermost edges are at minus and plus infinity.
    let n = NORMAL_TABLE_LEN;
    let edge_pdf: Vec<f64> = (0..=n)
        .map(|i| {
            if i == 0 || i == n {
                0.0
            } else {
                pdf(quantile(i as f64 / n as f64))
            }
        })
        .collect();
    // E[Z | interval i] = (pdf(a) - pdf(b)) / P(interval), with P = 1 / n.
    let mut means: Vec<f64> = (0..n)
        .map(|i| (edge_pdf[i] - edge_pdf[i + 1]) * n as f64)
        .collect();
    // Exact symmetry (the grid's rounding otherwise leaves a mean of about 1e-12).
    for i in 0..n / 2 {
        let m = 0.5 * (means[i] - means[n - 1 - i]);
        means[i] = m;
        means[n - 1 - i] = -m;
    }
    let var = means.iter().map(|m| m * m).sum::<f64>() / n as f64;
    let scale = 1.0 / var.sqrt();
    let mut table = Box::new([0.0f32; NORMAL_TABLE_LEN]);
    for (t, m) in table.iter_mut().zip(&means) {
        *t = (m * scale) as f32;
    }
    table
}

/// A standard normal deviate from a 16-bit random word (its top [`NORMAL_TABLE_BITS`] bits).
#[inline]
pub fn normal_from_u16(table: &[f32; NORMAL_TABLE_LEN], word: u16) -> f32 {
    table[usize::from(word >> (16 - NORMAL_TABLE_BITS))]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngCore, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn table_has_the_normal_moments() {
        let t = normal_table();
        let n = NORMAL_TABLE_LEN as f64;
        let moment = |k: i32| t.iter().map(|&v| (v as f64).powi(k)).sum::<f64>() / n;
        assert!(moment(1).abs() < 1e-7, "mean {}", moment(1));
        assert!((moment(2) - 1.0).abs() < 1e-6, "variance {}", moment(2));
        assert!(moment(3).abs() < 1e-6, "third moment {}", moment(3));
        // A normal's fourth moment is 3; the table's tails end at 3.6 sigma.
        assert!(
            (moment(4) - 3.0).abs() < 0.01,
            "fourth moment {}",
            moment(4)
        );
        assert!(t.windows(2).all(|w| w[0] < w[1]), "the table is increasing");
        assert!((3.5..3.8).contains(&t[NORMAL_TABLE_LEN - 1]), "{}", t[4095]);
    }

    /// Share of the table within one, two and three sigma: the normal's 68.27, 95.45, 99.73 %.
    #[test]
    fn table_has_the_normal_shape() {
        let t = normal_table();
        for (k, want) in [(1.0f32, 0.6827), (2.0, 0.9545), (3.0, 0.9973)] {
            let share = t.iter().filter(|v| v.abs() < k).count() as f64 / t.len() as f64;
            assert!((share - want).abs() < 0.001, "within {k} sigma: {share}");
        }
    }

    /// Drawn through the random words a flight uses: mean 0 and unit variance within the
    /// sampling error of a million draws, and the same stream for the same seed.
    #[test]
    fn drawn_deviates_are_standard_normal_and_deterministic() {
        let t = normal_table();
        let draw = |seed: u64| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let mut bytes = vec![0u8; 2_000_000];
            rng.fill_bytes(&mut bytes);
            bytes
                .chunks_exact(2)
                .map(|b| normal_from_u16(t, u16::from_le_bytes([b[0], b[1]])))
                .collect::<Vec<f32>>()
        };
        let z = draw(7);
        let n = z.len() as f64;
        let mean = z.iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = z.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
        // Standard errors: 0.001 for the mean, 0.0014 for the variance.
        assert!(mean.abs() < 0.004, "mean {mean}");
        assert!((var - 1.0).abs() < 0.006, "variance {var}");
        assert_eq!(z, draw(7));
        assert_ne!(z, draw(8));
    }
}
