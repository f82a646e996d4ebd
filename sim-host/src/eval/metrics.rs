//! The paper's quality metrics (spec §3): NMXM, MSE and VAR of the absolute error.

/// The three metrics of one axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metrics {
    /// Normalised maximum of the absolute full cross-correlation (any lag).
    pub nmxm: f64,
    /// Mean squared error, (m/s)².
    pub mse: f64,
    /// Unbiased variance of the absolute error, (m/s)².
    pub var: f64,
}

/// Computes the metrics of estimate `e` against ground truth `g` (same length), with the
/// reference's NaN/Inf behaviour: any NaN makes everything NaN; an Inf gives MSE = Inf and
/// NMXM = VAR = NaN.
pub fn metrics(e: &[f64], g: &[f64]) -> Metrics {
    let l = e.len().min(g.len());
    let (e, g) = (&e[..l], &g[..l]);
    let nan = Metrics {
        nmxm: f64::NAN,
        mse: f64::NAN,
        var: f64::NAN,
    };
    if l == 0 || e.iter().chain(g).any(|v| v.is_nan()) {
        return nan;
    }
    let mse = e.iter().zip(g).map(|(a, b)| (a - b) * (a - b)).sum::<f64>() / l as f64;
    if e.iter().chain(g).any(|v| v.is_infinite()) {
        return Metrics { mse, ..nan };
    }
    let abs: Vec<f64> = e.iter().zip(g).map(|(a, b)| (a - b).abs()).collect();
    let mean = abs.iter().sum::<f64>() / l as f64;
    let var = if l > 1 {
        abs.iter().map(|a| (a - mean) * (a - mean)).sum::<f64>() / (l - 1) as f64
    } else {
        0.0
    };
    let norm =
        e.iter().map(|v| v * v).sum::<f64>().sqrt() * g.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut best = 0.0f64;
    for lag in -(l as isize - 1)..=(l as isize - 1) {
        let mut r = 0.0;
        for n in 0..l as isize {
            let m = n + lag;
            if m >= 0 && (m as usize) < l {
                r += e[m as usize] * g[n as usize];
            }
        }
        best = best.max(r.abs());
    }
    Metrics {
        nmxm: best / norm,
        mse,
        var,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_of_known_series() {
        let g = [0.0, 1.0, 0.0, -1.0];
        let m = metrics(&g, &g);
        assert!((m.nmxm - 1.0).abs() < 1e-12);
        assert_eq!((m.mse, m.var), (0.0, 0.0));
        // Delayed copy: NMXM finds the lag; anti-correlation counts too.
        let e = [0.0, 0.0, 1.0, 0.0];
        assert!((metrics(&e, &[0.0, 1.0, 0.0, 0.0]).nmxm - 1.0).abs() < 1e-12);
        assert!((metrics(&[-1.0, 0.0], &[1.0, 0.0]).nmxm - 1.0).abs() < 1e-12);
        let m = metrics(&[1.0, 3.0], &[0.0, 0.0]);
        assert_eq!(m.mse, 5.0);
        assert_eq!(m.var, 2.0);
    }

    #[test]
    fn nan_and_inf_follow_the_reference() {
        let m = metrics(&[1.0, f64::NAN], &[0.0, 0.0]);
        assert!(m.mse.is_nan() && m.nmxm.is_nan() && m.var.is_nan());
        let m = metrics(&[1.0, 0.0], &[f64::INFINITY, 0.0]);
        assert_eq!(m.mse, f64::INFINITY);
        assert!(m.nmxm.is_nan() && m.var.is_nan());
    }
}
