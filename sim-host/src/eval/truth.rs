//! Ground-truth camera-frame velocities from the OptiTrack log (spec §1.5, §2).

use super::dataset::{read_table, read_tme, Take};
use anyhow::{ensure, Result};

/// How images are matched to motion-capture samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Alignment {
    /// The paper-era MATLAB rule (reproduces the published numbers; board 1 is one frame early,
    /// duplicate OptiTrack timestamps give Inf/NaN, first 4 frames zeroed).
    Paper,
    /// Physically correct: per-image `.tme` times (or the (k+1)-th flagged timing row),
    /// sentinel rows and duplicate timestamps removed, yaw unwrapped, central differences at
    /// the image time. Not comparable with the paper's table.
    Corrected,
}

/// Ground truth for images `1..=N-1` (index 0 = image 1).
#[derive(Debug, Clone, Default)]
pub struct Truth {
    /// Image time, s (logging clock).
    pub time_s: Vec<f64>,
    /// Forward velocity, m/s.
    pub fwd: Vec<f64>,
    /// Lateral velocity in the data set's convention (MATLAB `cam_Vx`), m/s.
    pub side: Vec<f64>,
    /// OptiTrack yaw, deg (data set convention: about the vertical axis, up).
    pub yaw_deg: Vec<f64>,
    /// Vertical velocity, m/s (OptiTrack Y: positive up).
    pub up: Vec<f64>,
}

/// MATLAB `smooth(x, span)`: centred moving average whose span shrinks at the ends.
pub fn matlab_smooth(x: &[f64], span: usize) -> Vec<f64> {
    let n = x.len();
    let h = (span.max(1) - 1) / 2;
    (0..n)
        .map(|k| {
            let r = h.min(k).min(n - 1 - k);
            let s: f64 = x[k - r..=k + r].iter().sum();
            s / (2 * r + 1) as f64
        })
        .collect()
}

/// Index of the sample nearest to `t` (first on ties), `ts` ascending or not.
fn nearest(ts: &[f64], t: f64) -> usize {
    let mut best = 0;
    let mut bd = f64::INFINITY;
    for (k, &s) in ts.iter().enumerate() {
        let d = (t - s).abs();
        if d < bd {
            bd = d;
            best = k;
        }
    }
    best
}

/// Ground truth for a take with `n_images` images.
pub fn ground_truth(take: &Take, n_images: usize, alignment: Alignment) -> Result<Truth> {
    match alignment {
        Alignment::Paper => paper_truth(take, n_images),
        Alignment::Corrected => corrected_truth(take, n_images),
    }
}

fn flagged_times(rows: &[Vec<f64>]) -> Vec<f64> {
    rows.iter().filter(|r| r[1] == 1.0).map(|r| r[0]).collect()
}

/// Paper-era alignment and ground truth (exact MATLAB replica, see the spec).
pub fn paper_truth(take: &Take, n_images: usize) -> Result<Truth> {
    let timing_path = take.dir.join("timing.dat");
    let timing = read_table(&timing_path, 2, true)?;
    let t_frame = flagged_times(&timing.rows);
    let m = n_images.saturating_sub(1);
    ensure!(
        t_frame.len() >= m,
        "{}: {} recorded-frame rows (flag 1) after line 1, need {m} for {n_images} images",
        timing_path.display(),
        t_frame.len()
    );
    let pos = read_table(&take.dir.join("position.dat"), 8, true)?;
    let t: Vec<f64> = pos.rows.iter().map(|r| r[0]).collect();
    let col = |c: usize| -> Vec<f64> { pos.rows.iter().map(|r| r[c]).collect() };
    let (x, y, z, yaw) = (
        matlab_smooth(&col(2), 5),
        matlab_smooth(&col(3), 5),
        matlab_smooth(&col(4), 5),
        matlab_smooth(&col(7), 15),
    );
    let n = t.len();
    let diff = |v: &[f64]| -> Vec<f64> {
        (0..n)
            .map(|k| {
                if k + 1 < n {
                    (v[k + 1] - v[k]) / (t[k + 1] - t[k])
                } else {
                    0.0
                }
            })
            .collect()
    };
    let (vx, vy, vz) = (diff(&x), diff(&y), diff(&z));
    let sign = if take.board == 2 { -1.0 } else { 1.0 };
    let mut truth = Truth::default();
    for (i, &tf) in t_frame.iter().take(m).enumerate() {
        let k = nearest(&t, tf);
        let psi = yaw[k] * std::f64::consts::PI / 180.0;
        let (c, s) = (psi.cos(), psi.sin());
        let zeroed = i < 4;
        truth.time_s.push(tf);
        truth
            .side
            .push(if zeroed { 0.0 } else { vx[k] * c - vz[k] * s });
        truth.fwd.push(if zeroed {
            0.0
        } else {
            sign * (vz[k] * c + vx[k] * s)
        });
        truth.yaw_deg.push(if zeroed { 0.0 } else { yaw[k] });
        truth.up.push(if zeroed { 0.0 } else { vy[k] });
    }
    Ok(truth)
}

/// Linear interpolation of `v` at `t` (clamped at the ends; `ts` strictly increasing).
fn interp(ts: &[f64], v: &[f64], t: f64) -> f64 {
    let k = ts.partition_point(|&s| s <= t);
    if k == 0 {
        return v[0];
    }
    if k >= ts.len() {
        return v[ts.len() - 1];
    }
    let a = (t - ts[k - 1]) / (ts[k] - ts[k - 1]);
    v[k - 1] + a * (v[k] - v[k - 1])
}

/// The recorder's latency: an image shows the scene this long before its recorded time, s.
/// Measured by `sim-host camera-calib` (the lag at which the images' global horizontal shift
/// correlates best with the motion capture's yaw change: 0.16 to 0.22 s on the takes where
/// that correlation is at least 0.45, 1/3, 1/5, 1/9, 1/19, 1/21 and 2/3; docs/replay.md).
pub const RECORDER_LATENCY_S: f64 = 0.19;

/// Image times of images `1..=n_images-1`, s (logging clock): the `%i.bmp.tme` file, or
/// where there is none the (k+1)-th recorded-frame row of timing.dat for image k.
pub fn image_times(take: &Take, n_images: usize) -> Result<Vec<f64>> {
    let m = n_images.saturating_sub(1);
    let mut times = match read_tme(take)? {
        Some(t) => {
            ensure!(
                t.len() >= m,
                "{}: {} times for {n_images} images",
                take.dir.join("%i.bmp.tme").display(),
                t.len()
            );
            t
        }
        None => {
            let path = take.dir.join("timing.dat");
            let timing = read_table(&path, 2, false)?;
            let flagged = flagged_times(&timing.rows);
            ensure!(
                flagged.len() > m,
                "{}: {} recorded-frame rows, need {} (image k is the (k+1)-th)",
                path.display(),
                flagged.len(),
                m + 1
            );
            flagged[1..].to_vec()
        }
    };
    times.truncate(m);
    Ok(times)
}

/// The motion-capture track of a take with sentinel rows, duplicate timestamps and
/// non-finite rows removed, the yaw unwrapped, and smoothed as the ground truth is (MATLAB
/// `smooth`: positions span 5, yaw span 15, roll and pitch span 19). Data-set axes: X, Z
/// horizontal, Y up, m; angles in degrees.
#[derive(Debug, Clone, Default)]
pub struct MocapTrack {
    /// Logging-clock time, s (strictly increasing).
    pub t: Vec<f64>,
    /// X, m.
    pub x: Vec<f64>,
    /// Y (up), m.
    pub y: Vec<f64>,
    /// Z, m.
    pub z: Vec<f64>,
    /// Roll, deg.
    pub roll: Vec<f64>,
    /// Pitch, deg.
    pub pitch: Vec<f64>,
    /// Yaw (unwrapped), deg.
    pub yaw: Vec<f64>,
}

impl MocapTrack {
    /// Reads and cleans a take's position.dat.
    pub fn read(take: &Take) -> Result<Self> {
        let path = take.dir.join("position.dat");
        let pos = read_table(&path, 8, false)?;
        let mut rows: Vec<&Vec<f64>> = Vec::new();
        for r in &pos.rows {
            let sentinel = r[2].abs() > 1e5 || r[3].abs() > 1e5 || r[4].abs() > 1e5;
            let dup = rows.last().is_some_and(|p| r[0] <= p[0]);
            if !sentinel && !dup && r.iter().all(|v| v.is_finite()) {
                rows.push(r);
            }
        }
        ensure!(
            rows.len() >= 16,
            "{}: only {} valid motion-capture rows",
            path.display(),
            rows.len()
        );
        let mut yaw_unwrapped: Vec<f64> = Vec::with_capacity(rows.len());
        for r in &rows {
            let y = r[7];
            let y = match yaw_unwrapped.last() {
                Some(&p) => p + (y - p + 180.0).rem_euclid(360.0) - 180.0,
                None => y,
            };
            yaw_unwrapped.push(y);
        }
        let col = |c: usize| -> Vec<f64> { rows.iter().map(|r| r[c]).collect() };
        Ok(Self {
            t: col(0),
            x: matlab_smooth(&col(2), 5),
            y: matlab_smooth(&col(3), 5),
            z: matlab_smooth(&col(4), 5),
            roll: matlab_smooth(&col(5), 19),
            pitch: matlab_smooth(&col(6), 19),
            yaw: matlab_smooth(&yaw_unwrapped, 15),
        })
    }

    /// `v` (one of the track's columns) linearly interpolated at `t`, clamped at the ends.
    pub fn at(&self, v: &[f64], t: f64) -> f64 {
        interp(&self.t, v, t)
    }
}

/// Corrected alignment (see [`Alignment::Corrected`]).
pub fn corrected_truth(take: &Take, n_images: usize) -> Result<Truth> {
    let times = image_times(take, n_images)?;
    let track = MocapTrack::read(take)?;
    let (t, x, y, z, yaw) = (&track.t, &track.x, &track.y, &track.z, &track.yaw);
    let sign = if take.board == 2 { -1.0 } else { 1.0 };
    let h = 0.05;
    let mut truth = Truth::default();
    for &tf in &times {
        let vx = (interp(t, x, tf + h) - interp(t, x, tf - h)) / (2.0 * h);
        let vz = (interp(t, z, tf + h) - interp(t, z, tf - h)) / (2.0 * h);
        let vy = (interp(t, y, tf + h) - interp(t, y, tf - h)) / (2.0 * h);
        let yd = interp(t, yaw, tf);
        let psi = yd.to_radians();
        let (c, s) = (psi.cos(), psi.sin());
        truth.time_s.push(tf);
        truth.side.push(vx * c - vz * s);
        truth.fwd.push(sign * (vz * c + vx * s));
        truth.yaw_deg.push(yd);
        truth.up.push(vy);
    }
    Ok(truth)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smooth_matches_matlab_end_behaviour() {
        let x = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0];
        let s = matlab_smooth(&x, 5);
        assert_eq!(s[0], 1.0);
        assert!((s[1] - 7.0 / 3.0).abs() < 1e-12);
        assert!((s[2] - 31.0 / 5.0).abs() < 1e-12);
        assert!((s[4] - 56.0 / 3.0).abs() < 1e-12);
        assert_eq!(s[5], 32.0);
    }

    /// A board-2 style take (no header lines) moving at 0.5 m/s along +Z with yaw 0, with
    /// sentinel rows, a duplicated timestamp and a `.tme` file.
    fn synthetic_take(board: u32) -> Take {
        let dir = std::env::temp_dir().join(format!("edgefs-truth-{}-{board}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut pos = String::new();
        for _ in 0..2 {
            pos += "10.000000\t-431602080\t-431602080\t-431602080\t-431602080\t135\t-0\t135\r\n";
        }
        for k in 0..200 {
            let t = 10.0 + 0.05 * k as f64;
            let z = 0.5 * (t - 10.0);
            pos += &format!("{t:.6}\t0\t0.1\t1.0\t{z:.6}\t0\t0\t0\r\n");
            if k == 50 {
                pos += &format!("{t:.6}\t0\t0.1\t1.0\t{z:.6}\t0\t0\t0\r\n");
            }
        }
        std::fs::write(dir.join("position.dat"), pos).unwrap();
        let (mut timing, mut tme) = (String::new(), String::new());
        for k in 0..40 {
            let t = 10.5 + 0.125 * k as f64;
            timing += &format!("{t:.6}\t1.000000\r\n");
            if k > 0 {
                tme += &format!("{t:.6}\r\n");
            }
        }
        std::fs::write(dir.join("timing.dat"), timing).unwrap();
        std::fs::write(dir.join("%i.bmp.tme"), tme).unwrap();
        Take {
            board,
            take: 1,
            dir,
        }
    }

    #[test]
    fn corrected_truth_survives_sentinels_and_duplicate_timestamps() {
        let take = synthetic_take(1);
        let t = corrected_truth(&take, 39).unwrap();
        assert_eq!(t.fwd.len(), 38);
        for (k, (&f, &s)) in t.fwd.iter().zip(&t.side).enumerate() {
            assert!((f - 0.5).abs() < 1e-6, "image {}: fwd {f}", k + 1);
            assert!(s.abs() < 1e-6);
        }
        // Image k is at the (k+1)-th flagged time.
        assert!((t.time_s[0] - 10.625).abs() < 1e-9);
        // Paper-era rule on the same files: first 4 zeroed, duplicate timestamp -> Inf/NaN
        // only where an image lands on it.
        let p = paper_truth(&take, 39).unwrap();
        assert_eq!(&p.fwd[..4], &[0.0; 4]);
        assert!(p.fwd[4..]
            .iter()
            .all(|v| !v.is_finite() || (v - 0.5).abs() < 1e-6));
        let _ = std::fs::remove_dir_all(&take.dir);
    }

    #[test]
    fn nearest_takes_first_on_ties_and_interp_clamps() {
        assert_eq!(nearest(&[0.0, 1.0, 2.0], 0.5), 0);
        assert_eq!(nearest(&[0.0, 1.0, 2.0], 1.6), 2);
        assert_eq!(interp(&[0.0, 1.0], &[2.0, 4.0], 0.25), 2.5);
        assert_eq!(interp(&[0.0, 1.0], &[2.0, 4.0], 9.0), 4.0);
    }
}
