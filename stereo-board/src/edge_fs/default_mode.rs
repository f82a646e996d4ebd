//! The default mode's fit of one frame, [`EdgeFs::fit_default`].

use super::{
    coverage_u8, flow_row, histogram_steps, longest_run, median, pixel_noise_dn, robust_line_fit,
    stereo_row, window_sums, wrap_pi, EdgeFs, EdgeFsOutput, Slot, IMG_H, IMG_W, MEDIAN_MAX,
};
use protocol::{EstimateFlags, STEREO_FRAME_BYTES};

/// Disjoint windows of a frame that must not be noise
/// ([`EdgeFsParams::noise_texture_ratio`](super::EdgeFsParams::noise_texture_ratio),
/// [`EdgeFsParams::noise_structure_ratio`](super::EdgeFsParams::noise_structure_ratio)) for a
/// velocity.
const MIN_TEXTURED_WINDOWS: usize = 3;

/// The mean step between neighbouring histogram bins that pixel noise of 1 DN gives alone.
/// Each bin sums `IMG_H` absolute differences of two pixels, each of variance 2σ²(1 - 2/π);
/// neighbouring bins share no pixel, so their difference has variance 4·IMG_H·σ²(1 - 2/π),
/// and its absolute value averages √(2/π) of its spread: 0.798 · √(4 · 96 · 0.3634) = 9.43.
const NOISE_STEP_PER_SIGMA: f32 = 9.43;

impl EdgeFs {
    /// The frame's own estimate (no temporal filter) and the standard errors of its forward,
    /// sideways and vertical velocity (m/s), `None` when nothing was fitted.
    pub(super) fn fit_default(
        &mut self,
        frame: &[u8; STEREO_FRAME_BYTES],
        has_gyro: bool,
    ) -> (EdgeFsOutput, Option<[f32; 3]>) {
        let p = self.params;
        let (w, d, h) = (
            p.half_window as usize,
            p.search_range as usize,
            p.max_horizon as usize,
        );
        let s = p.stereo_shift_px;
        let f = p.focal_px();
        let mut out = EdgeFsOutput::EMPTY;
        if !has_gyro {
            out.flags.insert(EstimateFlags::NO_GYRO);
        }
        let mean = self.compute_histograms(frame);
        if mean < 12 {
            out.flags.insert(EstimateFlags::TOO_DARK);
        } else if mean > 243 {
            out.flags.insert(EstimateFlags::TOO_BRIGHT);
        }

        // Stereo with sub-pixel refinement and confidence masking.
        let mut stereo_ok = [false; IMG_W];
        let mut n_stereo = 0;
        let mut near = [false; IMG_W];
        let mut n_near = 0usize;
        let mut texture = [0u32; IMG_W];
        // A window's edge sum from noise alone: (2w+1) bins of IMG_H absolute differences of
        // two pixels, each 2σ/√π = 1.128σ on average.
        let (noise_window, noise_step) = if p.noise_texture_ratio > 0.0 {
            let sigma = pixel_noise_dn(frame);
            (
                sigma * 1.128 * (IMG_H * (2 * w + 1)) as f32,
                sigma * NOISE_STEP_PER_SIGMA,
            )
        } else {
            (0.0, 0.0)
        };
        self.diag.noise_window = noise_window;
        let cur = &self.ring[self.idx(0)].hist;
        window_sums(cur, w, &mut texture);
        // A column window is not noise when its edge sum stands out of the noise's, or when
        // its histogram has more shape than noise gives it: a fine, faint texture (wood grain)
        // sums little more than noise, but the matcher compares shapes, and its shape matches.
        // Noise's depths are not depth, nor its flow motion.
        let clear_of_noise = (p.noise_texture_ratio * noise_window) as u32;
        let mut shape = [0u32; IMG_W];
        let shaped = if p.noise_texture_ratio > 0.0 && p.noise_structure_ratio > 0.0 {
            window_sums(&histogram_steps(cur), w, &mut shape);
            (p.noise_structure_ratio * noise_step * (2 * w + 1) as f32) as u32
        } else {
            u32::MAX
        };
        let not_noise = |c: usize| texture[c] >= clear_of_noise || shape[c] >= shaped;
        {
            let ds = usize::from(p.stereo_range);
            let diag = &mut self.diag;
            stereo_row(&self.other, cur, ds, s, w, |c, m| {
                let disp = m.best as f32 + m.subpixel();
                diag.disparity_px[c] = disp;
                if m.best >= ds && texture[c] >= p.min_texture {
                    // Textured, best match at the end of the search: nearer than the range.
                    near[c] = true;
                    n_near += 1;
                    return;
                }
                // The peak ratio (a scan of all candidates) only where the rest holds.
                let usable = m.best > 0
                    && m.best < ds
                    && disp >= p.min_disparity_px
                    && texture[c] >= p.min_texture
                    && not_noise(c);
                if !usable {
                    return;
                }
                let confidence = m.confidence();
                if confidence >= p.min_stereo_confidence {
                    diag.depth_m[c] = f * p.baseline_m / disp;
                    diag.confidence[c] = confidence.min(100.0);
                    stereo_ok[c] = true;
                    n_stereo += 1;
                }
            });
        }
        out.obstacle_m = self.nearest_obstacle();
        let run = usize::from(p.min_near_run);
        if run > 0 && longest_run(&near) >= run {
            // Something nearer than the stereo range fills part of the view.
            let min_range_m = f * p.baseline_m / f32::from(p.stereo_range.max(1));
            out.obstacle_m = Some(out.obstacle_m.map_or(min_range_m, |d| d.min(min_range_m)));
        }
        out.near_columns = n_near.min(usize::from(u8::MAX)) as u8;
        let searchable = IMG_W.saturating_sub(2 * w);
        out.depth_coverage = coverage_u8(n_stereo, searchable);
        // Over disjoint windows: the texture, and the windows that are not noise (a plain
        // room's lone corner is not a view to measure velocity on).
        let (mut total_texture, mut textured_windows) = (0u32, 0usize);
        for (c, &t) in texture.iter().enumerate().step_by(2 * w + 1) {
            total_texture = total_texture.saturating_add(t);
            textured_windows += usize::from(not_noise(c));
        }
        if total_texture < p.min_texture.saturating_mul(4)
            || textured_windows < MIN_TEXTURED_WINDOWS
        {
            out.flags.insert(EstimateFlags::NO_TEXTURE);
        }
        if n_stereo < usize::from(p.min_fit_columns).max(2)
            || (n_stereo as f32) < p.min_depth_coverage * searchable as f32
        {
            out.flags.insert(EstimateFlags::NO_STEREO_MATCH);
        }

        // Flow against the frame `n` back, searched around the predicted rotation.
        let avail = (self.frames as usize).saturating_sub(1);
        let mut n = (self.horizon as usize).clamp(1, h).min(avail);
        if p.horizon_s > 0.0 {
            // Time-based horizon: the fewest frames spanning `horizon_s`, within the cap.
            let now = self.ring[self.idx(0)].capture_us;
            if let Some(k) = (1..=n).find(|&k| {
                now.saturating_sub(self.ring[self.idx(k)].capture_us) as f32 * 1e-6 >= p.horizon_s
            }) {
                n = k;
            }
        }
        if n == 0 {
            out.flags.insert(EstimateFlags::HISTORY_FILLING);
            return (out, None);
        }
        // Rotation over the horizon from the attitude (the scene moves left when the yaw
        // grows); shorten the horizon until it fits the search. The yaw change is wrapped:
        // a heading crossing +-pi is a small turn, not a full one.
        let cur = &self.ring[self.idx(0)];
        let rotation = |older: &Slot| {
            if cur.has_yaw && older.has_yaw {
                -wrap_pi(cur.yaw_rad - older.yaw_rad) * f
            } else {
                0.0
            }
        };
        let mut rot_px = rotation(&self.ring[self.idx(n)]);
        let too_fast = |r: f32| r.is_nan() || r.abs() > p.max_rotation_px;
        while n > 1 && too_fast(rot_px) {
            n -= 1;
            rot_px = rotation(&self.ring[self.idx(n)]);
        }
        self.diag.horizon = n as u8;
        if too_fast(rot_px) {
            // Rotating faster than the search can follow even over one frame.
            out.flags.insert(EstimateFlags::NO_FLOW_MATCH);
            return (out, None);
        }
        let older = &self.ring[self.idx(n)];
        let offset = libm::roundf(rot_px) as i32;
        let dt_s = cur.capture_us.saturating_sub(older.capture_us) as f32 * 1e-6;
        if dt_s.is_nan() || dt_s <= 1e-4 {
            out.flags.insert(EstimateFlags::NO_FLOW_MATCH);
            return (out, None);
        }
        // Derotation uncertainty from a stale attitude sample while the yaw rate changes.
        let derot_err_px = (cur.yaw_rate - older.yaw_rate).abs() * p.gyro_age_s * f;
        if derot_err_px > p.max_derotation_error_px {
            out.flags.insert(EstimateFlags::POOR_FIT);
        }
        let mut pts = [(0.0f32, 0.0f32, 0.0f32); IMG_W];
        let mut np = 0;
        let mut edge_hits = 0;
        let mut textured = 0;
        let mut prior_misses = 0;
        let prior = self.flow_prior();
        {
            let (cur_h, old_h) = (&cur.hist, &older.hist);
            let diag = &mut self.diag;
            // `flow_row`: the first minimum is found while the costs are updated (same
            // matches as `best_match` of `column_costs`' costs, bit for bit); the parabola
            // only for textured columns, the peak ratio only where the stereo depth is valid.
            flow_row(old_h, cur_h, d, offset, w, |c, m| {
                if texture[c] < p.min_texture {
                    return;
                }
                textured += 1;
                let mut base = 0;
                let mut m = m;
                if let (Some(pr), true) = (prior, stereo_ok[c]) {
                    // The motion the filter's velocity predicts here, as a candidate index.
                    let (x, z) = (c as f32 - 63.5, diag.depth_m[c]);
                    let u = (pr.forward_mps * x - f * pr.sideways_mps) / z;
                    let k = rot_px + u * dt_s - offset as f32 + d as f32;
                    let spread = (x.abs() * pr.forward_sigma + f * pr.sideways_sigma) / z;
                    let r = (p.prior_window_px + spread * dt_s).min(2.0 * p.prior_window_px);
                    let (lo, hi) = (libm::floorf(k - r), libm::ceilf(k + r));
                    if lo > 0.0 || hi < (2 * d) as f32 {
                        let lo = lo.clamp(0.0, (2 * d) as f32) as usize;
                        let hi = hi.clamp(0.0, (2 * d) as f32) as usize;
                        let Some(w) = m.within(lo, hi) else {
                            prior_misses += 1;
                            return;
                        };
                        let at_edge = |i: usize, end: usize| i == end && end != 0 && end != 2 * d;
                        if at_edge(lo + w.best, lo) || at_edge(lo + w.best, hi) {
                            // The best match in the window lies beyond it: not what was
                            // predicted.
                            prior_misses += 1;
                            return;
                        }
                        (base, m) = (lo, w);
                    }
                }
                let best = base + m.best;
                if best == 0 || best == 2 * d {
                    edge_hits += 1;
                    return;
                }
                let motion = offset as f32 + best as f32 - d as f32 + m.subpixel();
                let u = (motion - rot_px) / dt_s;
                diag.flow_pxps[c] = u;
                if stereo_ok[c] && m.confidence() >= p.min_flow_confidence {
                    let z = diag.depth_m[c];
                    if let Some(pt) = pts.get_mut(np) {
                        let wgt = if p.depth_weight_exp == 0.0 {
                            1.0
                        } else {
                            libm::powf(z.max(0.05), -p.depth_weight_exp)
                        };
                        *pt = (c as f32 - 63.5, z * u, wgt);
                        np += 1;
                    }
                }
            });
        }
        // Most columns disagreeing with the filter: it may have lost the motion, so the next
        // frame searches the whole range (a real change then restarts the filter).
        self.prior_doubted = prior.is_some() && prior_misses * 4 > textured;
        self.diag.guided = prior.is_some();
        self.diag.prior_misses = prior_misses.min(255) as u8;
        // Adaptive horizon: shorten when many searches hit the range end, lengthen when none.
        if edge_hits * 8 > textured && self.horizon > 1 {
            self.horizon -= 1;
        } else if edge_hits * 32 <= textured && (self.horizon as usize) < h {
            self.horizon += 1;
        }
        if n < h && (self.frames as usize) <= h {
            out.flags.insert(EstimateFlags::HISTORY_FILLING);
        }
        let (mut prior, mut scratch) = ([0.0f32; IMG_W], [0.0f32; IMG_W]);
        let pts = pts.get_mut(..np).unwrap_or(&mut []);
        let fit = if np >= usize::from(p.min_fit_columns).max(2) {
            robust_line_fit(pts, &mut prior, &mut scratch, 4, p.huber_k)
        } else {
            None
        };
        let Some(fit) = fit else {
            out.flags.insert(EstimateFlags::NO_FLOW_MATCH);
            return (out, None);
        };
        let (a, b) = (fit.slope as f32, fit.intercept as f32);
        // Robust residual scale (1.4826 · median |residual|), converted to m/s.
        let mut m = 0;
        for pt in pts.iter() {
            if let Some(r) = scratch.get_mut(m) {
                *r = (pt.1 - (a * pt.0 + b)).abs();
                m += 1;
            }
            // `pt.0` is `c - 63.5` for an integer column `c`: exactly `c` again, no rounding.
            let col = pt.0 + 63.5;
            if (0.0..IMG_W as f32).contains(&col) {
                if let Some(u) = self.diag.used.get_mut(col as usize) {
                    *u = true;
                }
            }
        }
        let res = scratch.get_mut(..m).unwrap_or(&mut []);
        let rms_mps = 1.4826 * median(res) / f;
        self.diag.fit_columns = np as u8;
        out.forward_mps = a;
        out.sideways_mps = -b / f;
        if !(out.forward_mps.is_finite() && out.sideways_mps.is_finite()) {
            out.forward_mps = 0.0;
            out.sideways_mps = 0.0;
            out.flags.insert(EstimateFlags::POOR_FIT);
            return (out, None);
        }
        if rms_mps > p.max_fit_rms_mps {
            out.flags.insert(EstimateFlags::POOR_FIT);
        }
        let (lo, hi) = pts.iter().fold((f32::MAX, f32::MIN), |(lo, hi), pt| {
            (lo.min(pt.0), hi.max(pt.0))
        });
        if hi - lo < p.min_fit_spread_px {
            out.flags.insert(EstimateFlags::POOR_FIT);
        }
        let k = usize::from(p.output_median).clamp(1, MEDIAN_MAX);
        if k > 1 {
            self.recent.rotate_right(1);
            self.recent[0] = (out.forward_mps, out.sideways_mps);
            self.recent_len = (self.recent_len + 1).min(k);
            let m = self.recent_len;
            let (mut fw, mut sw) = ([0.0f32; MEDIAN_MAX], [0.0f32; MEDIAN_MAX]);
            for (j, &(a, b)) in self.recent.iter().take(m).enumerate() {
                fw[j] = a;
                sw[j] = b;
            }
            out.forward_mps = median(&mut fw[..m]);
            out.sideways_mps = median(&mut sw[..m]);
        }
        let cover = (np as f32 / 32.0).min(1.0);
        out.quality = (255.0 * cover * libm::expf(-rms_mps / 0.3)) as u8;
        // Standard errors of the slope and of the centre value (x is centred on the image).
        let (mut sx, mut sxx) = (0.0f32, 0.0f32);
        for pt in pts.iter() {
            sx += pt.0;
            sxx += pt.0 * pt.0;
        }
        let n = np as f32;
        let spread = (sxx - sx * sx / n).max(1.0);
        let sigma_res = rms_mps * f;
        // A derotation error of `e` px over `dt_s` biases every column's flow by `e/dt_s`,
        // i.e. the sideways velocity by `mean(Z)·e/(dt_s·f)`.
        let mut z_sum = 0.0f32;
        for (c, &u) in self.diag.used.iter().enumerate() {
            if u {
                z_sum += self.diag.depth_m.get(c).copied().unwrap_or(0.0);
            }
        }
        let rot_sigma = z_sum / n * derot_err_px / (dt_s * f);
        let side = rms_mps / libm::sqrtf(n);
        let mut sigma = [
            sigma_res / libm::sqrtf(spread),
            libm::sqrtf(side * side + rot_sigma * rot_sigma),
            f32::INFINITY,
        ];
        let coupled = self.coupled_fit(pts, &fit, sigma[0], dt_s);
        out.fit_r2 = (coupled.r2.clamp(0.0, 1.0) * 255.0) as u8;
        out.up_flags = out.flags | coupled.up_flags;
        if coupled.up_flags.is_valid() && k == 1 {
            out.forward_mps = coupled.forward_mps;
            out.sideways_mps = coupled.sideways_mps;
            out.up_mps = coupled.up_mps;
            sigma[0] = coupled.forward_sigma;
            sigma[2] = coupled.up_sigma;
        }
        (out, Some(sigma))
    }
}
