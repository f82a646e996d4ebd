//! Synthetic-scene tests of the whole pipeline: a textured fronto-parallel wall seen by the
//! stereo pair, with known depth and camera motion.

use super::*;

/// Smooth random texture along the wall: values every 3 cm, linearly interpolated.
fn texture(x_m: f32) -> f32 {
    let k = libm::floorf(x_m / 0.03);
    let t = x_m / 0.03 - k;
    let hash = |i: i64| {
        let mut v = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        v ^= v >> 29;
        v = v.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        ((v >> 40) % 200) as f32 + 25.0
    };
    hash(k as i64) * (1.0 - t) + hash(k as i64 + 1) * t
}

/// Renders the wall at depth `z` with the left camera at lateral position `pos` (m, positive
/// right) and the right camera `baseline` to its right; `shift` px of calibration error moves
/// the left image's content left.
fn render(z: f32, pos: f32, yaw_px: f32, params: &EdgeFsParams) -> [u8; STEREO_FRAME_BYTES] {
    let f = params.focal_px();
    let mut frame = [0u8; STEREO_FRAME_BYTES];
    for c in 0..IMG_W {
        let x = c as f32 - 63.5;
        let xl = x + params.stereo_shift_px as f32 + yaw_px;
        let (wl, wr) = (
            pos + xl * z / f,
            pos + params.baseline_m + (x + yaw_px) * z / f,
        );
        let (l, r) = (texture(wl) as u8, texture(wr) as u8);
        for row in 0..IMG_H {
            frame[2 * (row * IMG_W + c)] = l;
            frame[2 * (row * IMG_W + c) + 1] = r;
        }
    }
    frame
}

fn gyro(yaw: f32) -> GyroAttitude {
    GyroAttitude {
        timestamp_us: protocol::WireTime(0),
        rates_radps: [0.0; 3],
        attitude_rad: [0.0, 0.0, yaw],
    }
}

/// Flies `frames` frames at `fps` with forward/sideways velocity and yaw rate from a wall at
/// `z0`; returns the last output and the estimator.
fn fly(
    params: EdgeFsParams,
    z0: f32,
    vf: f32,
    vs: f32,
    yaw_rate: f32,
    frames: u32,
) -> (EdgeFsOutput, EdgeFs) {
    let mut fs = EdgeFs::new(params);
    let fps = 25.0;
    let f = params.focal_px();
    let mut out = EdgeFsOutput::EMPTY;
    for i in 0..frames {
        let t = i as f32 / fps;
        let yaw = yaw_rate * t;
        // Body yaw to the right moves the scene left: the camera looks at +yaw·f px.
        let frame = render(z0 - vf * t, vs * t, yaw * f, &params);
        out = fs.process(
            &frame,
            Instant::from_micros((t * 1e6) as u64),
            Some(&gyro(yaw)),
        );
    }
    (out, fs)
}

#[test]
fn stereo_depth_of_a_wall_is_recovered_per_column() {
    let mut params = EdgeFsParams::default_config();
    params.stereo_shift_px = 3;
    let (out, fs) = fly(params, 1.2, 0.0, 0.0, 0.0, 2);
    let diag = fs.diagnostics();
    let valid: heapless::Vec<f32, 128> =
        diag.depth_m.iter().copied().filter(|&z| z > 0.0).collect();
    assert!(valid.len() > 60, "only {} columns with depth", valid.len());
    let mean = valid.iter().sum::<f32>() / valid.len() as f32;
    assert!((mean - 1.2).abs() < 0.06, "mean depth {mean}");
    let obstacle = out.obstacle_m.expect("wall at 1.2 m is an obstacle");
    assert!((obstacle - 1.2).abs() < 0.1, "{obstacle}");
}

#[test]
fn the_left_right_check_keeps_a_wall_and_changes_nothing_else() {
    // A fronto-parallel textured wall: every confident column comes back the other way, and
    // the check's stage gives the stage without it's disparities, depths and confidences.
    let mut params = EdgeFsParams::default_config();
    params.stereo_shift_px = 3;
    assert!(!params.lr_check && !EdgeFsParams::paper().lr_check);
    let (_, off) = fly(params, 1.2, 0.3, 0.1, 0.0, 12);
    params.lr_check = true;
    let (_, on) = fly(params, 1.2, 0.3, 0.1, 0.0, 12);
    let (a, b) = (off.diagnostics(), on.diagnostics());
    let kept = b.depth_m.iter().filter(|&&z| z > 0.0).count();
    assert!(kept > 60, "{kept}");
    assert!(
        usize::from(b.lr_dropped) * 50 <= kept,
        "dropped {}",
        b.lr_dropped
    );
    assert_eq!(a.disparity_px, b.disparity_px);
    for c in 0..IMG_W {
        if b.depth_m[c] > 0.0 || a.depth_m[c] == 0.0 {
            assert_eq!(a.depth_m[c], b.depth_m[c], "column {c}");
            assert_eq!(a.confidence[c], b.confidence[c], "column {c}");
        }
    }
}

#[test]
fn forward_motion_towards_a_wall() {
    let (out, fs) = fly(EdgeFsParams::default_config(), 1.5, 0.5, 0.0, 0.0, 12);
    assert!(out.flags.is_valid(), "{:?}", out.flags);
    let d = fs.diagnostics();
    let used = d.used.iter().filter(|&&u| u).count();
    assert_eq!(used, usize::from(d.fit_columns));
    assert!(used > 40, "{used} columns used");
    // Used columns carry a depth near the wall's and a finite flow.
    for c in (0..IMG_W).filter(|&c| d.used[c]) {
        assert!(
            (d.depth_m[c] - 1.5).abs() < 0.4,
            "column {c}: {}",
            d.depth_m[c]
        );
        assert!(d.flow_pxps[c].is_finite());
    }
    assert!(
        (out.forward_mps - 0.5).abs() < 0.08,
        "forward {}",
        out.forward_mps
    );
    assert!(
        out.sideways_mps.abs() < 0.08,
        "sideways {}",
        out.sideways_mps
    );
    assert!(out.quality > 100, "quality {}", out.quality);
}

/// Default mode sends each valid frame's own fit beside the filtered output; a frame without
/// a valid fit and the paper's estimator send none.
#[test]
fn a_valid_frame_carries_its_own_fit() {
    let (out, _) = fly(EdgeFsParams::default_config(), 1.5, 0.5, 0.0, 0.0, 12);
    let fit = out.fit.expect("a valid frame has its fit");
    assert!((fit.forward_mps - 0.5).abs() < 0.1, "fit {fit:?}");
    assert!(fit.quality > 0);
    let mut fs = EdgeFs::new(EdgeFsParams::default_config());
    let blank = [0u8; STEREO_FRAME_BYTES];
    for i in 0..3u64 {
        let out = fs.process(&blank, Instant::from_micros(i * 40_000), Some(&gyro(0.0)));
        assert!(!out.flags.is_valid());
        assert_eq!(out.fit, None);
    }
    let (out, _) = fly(EdgeFsParams::paper(), 1.5, 0.5, 0.0, 0.0, 12);
    assert_eq!(out.fit, None);
}

#[test]
fn sideways_motion_to_the_right_is_positive() {
    let (out, _) = fly(EdgeFsParams::default_config(), 1.5, 0.0, 0.3, 0.0, 12);
    assert!(
        (out.sideways_mps - 0.3).abs() < 0.05,
        "sideways {}",
        out.sideways_mps
    );
    assert!(out.forward_mps.abs() < 0.1, "forward {}", out.forward_mps);
}

#[test]
fn yaw_rotation_is_removed_with_the_gyro_and_flagged_without() {
    // 0.5 rad/s yaw while hovering: 2.6 px/frame of pure rotational flow.
    let (out, _) = fly(EdgeFsParams::default_config(), 1.5, 0.0, 0.0, 0.5, 12);
    assert!(
        out.sideways_mps.abs() < 0.05,
        "sideways {}",
        out.sideways_mps
    );
    assert!(out.forward_mps.abs() < 0.1, "forward {}", out.forward_mps);

    let mut fs = EdgeFs::new(EdgeFsParams::default_config());
    let frame = render(1.5, 0.0, 0.0, fs.params());
    let out = fs.process(&frame, Instant::from_micros(0), None);
    assert!(out.flags.contains(EstimateFlags::NO_GYRO));
    assert!(out.flags.contains(EstimateFlags::HISTORY_FILLING));
}

#[test]
fn a_heading_crossing_pi_is_a_small_turn() {
    // Sideways flight with a slow right turn, once around heading 0 and once through +-pi
    // (the attitude yaw wraps from +pi to -pi): the estimates must be the same.
    let params = EdgeFsParams::default_config();
    let f = params.focal_px();
    let run = |heading0: f32| {
        let mut fs = EdgeFs::new(params);
        let mut outs = heapless::Vec::<EdgeFsOutput, 16>::new();
        for i in 0..16u32 {
            let t = i as f32 / 25.0;
            let turned = 0.2 * t;
            let frame = render(1.5, 0.3 * t, turned * f, &params);
            let yaw = heading0 + turned;
            let wrapped = yaw - core::f32::consts::TAU * libm::roundf(yaw / core::f32::consts::TAU);
            let out = fs.process(
                &frame,
                Instant::from_micros((t * 1e6) as u64),
                Some(&gyro(wrapped)),
            );
            outs.push(out).unwrap();
        }
        outs
    };
    let around_zero = run(-0.05);
    let through_pi = run(core::f32::consts::PI - 0.05);
    let valid = through_pi.iter().filter(|o| o.flags.is_valid()).count();
    // The history fills for the first 9 frames; the 7 after must all be valid.
    assert_eq!(valid, 7, "through pi: {through_pi:?}");
    for (a, b) in around_zero.iter().zip(&through_pi) {
        assert_eq!(a.flags, b.flags);
        assert!(
            (a.sideways_mps - b.sideways_mps).abs() < 1e-3,
            "{a:?} vs {b:?}"
        );
        assert!(
            (a.forward_mps - b.forward_mps).abs() < 1e-3,
            "{a:?} vs {b:?}"
        );
    }
}

/// Hovers in front of a wall at 1.5 m while yawing at `rate` rad/s (25 fps); the attitude
/// sent with each frame is `latency_s` old (the board uses the latest sample, not one taken at
/// the exposure). Returns the outputs after the history has filled.
fn spin(rate: impl Fn(f32) -> f32, latency_s: f32, frames: u32) -> heapless::Vec<EdgeFsOutput, 64> {
    let params = EdgeFsParams::default_config();
    let mut fs = EdgeFs::new(params);
    let f = params.focal_px();
    let fps = 25.0;
    let mut outs = heapless::Vec::new();
    let (mut yaw, mut yaw_at) = (0.0f32, [0.0f32; 64]);
    for i in 0..frames {
        let t = i as f32 / fps;
        if i > 0 {
            yaw += 0.5 * (rate(t) + rate(t - 1.0 / fps)) / fps;
        }
        yaw_at[i as usize] = yaw;
        let frame = render(1.5, 0.0, yaw * f, &params);
        // Attitude and rate as of `latency_s` before the exposure (linear interpolation).
        let back = latency_s * fps;
        let k = i as f32 - back;
        let (k0, fr) = (libm::floorf(k).max(0.0) as usize, k - libm::floorf(k));
        let old = yaw_at[k0] * (1.0 - fr) + yaw_at[(k0 + 1).min(i as usize)] * fr;
        let g = GyroAttitude {
            timestamp_us: protocol::WireTime(0),
            rates_radps: [0.0, 0.0, rate(t - latency_s)],
            attitude_rad: [0.0, 0.0, old],
        };
        let out = fs.process(&frame, Instant::from_micros((t * 1e6) as u64), Some(&g));
        if i >= 10 {
            let _ = outs.push(out);
        }
    }
    outs
}

#[test]
fn fast_yaw_is_derotated_or_flagged_never_valid_and_absurd() {
    // 1-2 rad/s (the simulator's avoidance turns) and far beyond: 8 rad/s is 41 px of
    // rotation per frame, outside any search.
    for rate in [1.0f32, 2.0, 3.0, 8.0] {
        let outs = spin(|_| rate, 0.0, 40);
        let mut valid = 0;
        for o in &outs {
            assert!(o.forward_mps.is_finite() && o.sideways_mps.is_finite());
            if o.flags.is_valid() {
                valid += 1;
                assert!(
                    o.forward_mps.abs() < 0.15 && o.sideways_mps.abs() < 0.15,
                    "{rate} rad/s: valid but absurd {o:?}"
                );
            }
        }
        if rate <= 3.0 {
            assert!(valid * 2 > outs.len(), "{rate} rad/s: only {valid} valid");
        } else {
            assert_eq!(
                valid, 0,
                "{rate} rad/s: rotation beyond the search must be flagged"
            );
        }
    }
}

#[test]
fn yaw_acceleration_with_a_stale_attitude_is_flagged() {
    // The yaw rate swings between -2 and +2 rad/s (1.25 Hz) and the attitude is 20 ms old:
    // the derotation is then off by up to 2 px; such frames are flagged, never passed valid
    // with a large error.
    let rate = |t: f32| 2.0 * libm::sinf(2.0 * core::f32::consts::PI * 1.25 * t);
    let outs = spin(rate, 0.02, 60);
    for o in &outs {
        if o.flags.is_valid() {
            assert!(
                o.forward_mps.abs() < 0.15 && o.sideways_mps.abs() < 0.15,
                "valid but absurd {o:?}"
            );
        }
    }
}

#[test]
fn blank_and_dark_frames_are_flagged_not_panicking() {
    let mut fs = EdgeFs::new(EdgeFsParams::default_config());
    for (i, v) in [0u8, 0, 255, 255].into_iter().enumerate() {
        let out = fs.process(
            &[v; STEREO_FRAME_BYTES],
            Instant::from_micros(i as u64 * 40_000),
            Some(&gyro(f32::NAN)),
        );
        assert!(out.flags.contains(EstimateFlags::NO_TEXTURE));
        assert!(!out.flags.is_valid());
        assert!(out.forward_mps.is_finite() && out.sideways_mps.is_finite());
    }
}

#[test]
fn paper_mode_fills_history_for_h_plus_one_frames() {
    let mut params = EdgeFsParams::paper();
    params.stereo_shift_px = 5;
    let mut fs = EdgeFs::new(params);
    for i in 0..7u64 {
        let frame = render(1.5 - 0.02 * i as f32, 0.0, 0.0, &params);
        let out = fs.process(&frame, Instant::from_micros(i * 140_000), Some(&gyro(0.0)));
        if i < 6 {
            assert!(out.flags.contains(EstimateFlags::HISTORY_FILLING));
            assert_eq!(out.forward_mps, 0.0);
        } else {
            assert!(!out.flags.contains(EstimateFlags::HISTORY_FILLING));
            assert_eq!(fs.diagnostics().horizon, 2);
        }
    }
}

#[test]
fn config_roundtrip_and_rejection() {
    let mut p = EdgeFsParams::default_config();
    let mut cfg = p.to_config();
    cfg.half_window = 4;
    cfg.stereo_shift = -2;
    p.apply(&cfg).unwrap();
    assert_eq!(p.to_config(), cfg);
    cfg.search_range = 0;
    assert_eq!(p.apply(&cfg), Err(ConfigError::SearchRange));
    assert_eq!(p.half_window, 4);
}

#[test]
fn estimator_is_small_and_const_constructible() {
    static _FS: EdgeFs = EdgeFs::new(EdgeFsParams::default_config());
    assert!(size_of::<EdgeFs>() < 16 * 1024);
}

mod no_panic {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Arbitrary frames, timestamps (also repeated or going backwards), attitudes (NaN,
        /// inf) and parameters never panic and never produce non-finite velocities.
        #[test]
        fn process_never_panics(
            seed in any::<u64>(),
            paper in any::<bool>(),
            w in 0u8..30, d in 0u8..30, h in 0u8..12, shift in -40i32..40,
            times in proptest::collection::vec(0u64..2_000_000, 12),
            yaws in proptest::collection::vec(prop_oneof![Just(f32::NAN), Just(f32::INFINITY), -10.0f32..10.0], 12),
        ) {
            let mut p = if paper { EdgeFsParams::paper() } else { EdgeFsParams::default_config() };
            p.half_window = w;
            p.search_range = d;
            p.max_horizon = h;
            p.stereo_shift_px = shift;
            let mut fs = EdgeFs::new(p);
            let mut x = seed;
            let mut frame = [0u8; STEREO_FRAME_BYTES];
            for (t, yaw) in times.iter().zip(&yaws) {
                for b in frame.iter_mut() {
                    x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                    *b = (x >> 56) as u8;
                }
                let out = fs.process(&frame, Instant::from_micros(*t), Some(&gyro(*yaw)));
                prop_assert!(out.forward_mps.is_finite() && out.sideways_mps.is_finite());
                prop_assert!(out.obstacle_m.is_none_or(|z| z.is_finite() && z > 0.0));
            }
        }
    }
}

mod median_selection {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        /// The selection median equals the median of a full sort bit for bit (ties, signed
        /// zeros, NaN and infinities included), for odd, even and empty lengths.
        #[test]
        fn selection_median_equals_sorted_median(
            v in proptest::collection::vec(
                prop_oneof![
                    4 => -10.0f32..10.0,
                    2 => (-2i32..3).prop_map(|x| x as f32),
                    1 => Just(-0.0f32),
                    1 => Just(f32::NAN),
                    1 => Just(f32::INFINITY),
                ],
                0..=128,
            ),
        ) {
            let mut sorted = v.clone();
            sorted.sort_unstable_by(|a, b| a.total_cmp(b));
            let m = sorted.len() / 2;
            let want = match sorted.len() {
                0 => 0.0,
                n if n % 2 == 1 => sorted[m],
                _ => 0.5 * (sorted[m - 1] + sorted[m]),
            };
            let mut w = v.clone();
            prop_assert_eq!(median(&mut w).to_bits(), want.to_bits());
        }
    }
}

mod window_sums {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]
        /// The running window sums equal the per-window sums (0 where the window leaves the
        /// image) for every half window, saturated bins included.
        #[test]
        fn running_sums_equal_per_window_sums(
            bins in proptest::collection::vec(prop_oneof![0u16..=24_480, Just(24_480u16)], IMG_W),
            w in 0usize..70,
        ) {
            let mut h: EdgeHistogram = [0; IMG_W];
            h.copy_from_slice(&bins);
            let mut got = [1u32; IMG_W];
            window_sums(&h, w, &mut got);
            for (c, &g) in got.iter().enumerate() {
                let want = if c < w || c + w >= IMG_W {
                    0
                } else {
                    h[c - w..=c + w].iter().map(|&v| u32::from(v)).sum()
                };
                prop_assert_eq!(g, want, "column {}", c);
            }
        }
    }
}

#[test]
fn nearest_obstacle_counts_runs_of_five_including_one_at_the_image_edge() {
    let mut fs = EdgeFs::new(EdgeFsParams::default_config());
    let depth = &mut fs.diag.depth_m;
    depth[10..14].fill(0.5); // 4 columns: too short
    depth[40..45].fill(3.0); // 5 columns
    depth[50..56].copy_from_slice(&[4.0, 4.1, 1.0, 4.0, 4.1, 4.2]); // broken by a jump
    depth[IMG_W - 6..].fill(2.0); // 6 columns ending at the image edge
    assert_eq!(fs.nearest_obstacle(), Some(2.0));
    fs.diag.depth_m[IMG_W - 6..].fill(0.0);
    assert_eq!(fs.nearest_obstacle(), Some(3.0));
    fs.diag.depth_m[40..45].fill(6.0);
    assert_eq!(fs.nearest_obstacle(), None, "beyond max_obstacle_m");
}

/// A wall at `z` textured only in image columns `band` (plain mid-grey elsewhere), the camera
/// moving forward at `vf`: `frames` frames at 25 Hz; the last output.
fn fly_banded(
    params: EdgeFsParams,
    z0: f32,
    vf: f32,
    band: core::ops::Range<usize>,
    frames: u32,
) -> EdgeFsOutput {
    let mut fs = EdgeFs::new(params);
    let mut out = EdgeFsOutput::EMPTY;
    for i in 0..frames {
        let t = i as f32 / 25.0;
        let mut frame = render(z0 - vf * t, 0.0, 0.0, &params);
        for row in 0..IMG_H {
            for c in (0..IMG_W).filter(|c| !band.contains(c)) {
                frame[2 * (row * IMG_W + c)] = 128;
                frame[2 * (row * IMG_W + c) + 1] = 128;
            }
        }
        out = fs.process(
            &frame,
            Instant::from_micros((t * 1e6) as u64),
            Some(&gyro(0.0)),
        );
    }
    out
}

#[test]
fn depth_coverage_says_how_much_of_the_view_has_depth() {
    let p = EdgeFsParams::default_config();
    let full = fly_banded(p, 1.5, 0.3, 0..IMG_W, 12);
    assert!(full.flags.is_valid(), "{:?}", full.flags);
    assert!(
        full.depth_coverage > 200,
        "coverage {}",
        full.depth_coverage
    );
    // A plain wall with one textured strip of 7 columns (the matching window spreads it over
    // a few more): some depth, far too little of the view for a velocity.
    let strip = fly_banded(p, 1.5, 0.3, 60..67, 12);
    assert!(
        strip.depth_coverage > 0,
        "coverage {}",
        strip.depth_coverage
    );
    assert!(
        strip.depth_coverage < 26,
        "coverage {}",
        strip.depth_coverage
    );
    assert!(
        strip.flags.contains(EstimateFlags::NO_STEREO_MATCH),
        "{:?}",
        strip.flags
    );
    // A plain wall: no depth at all.
    let plain = fly_banded(p, 1.5, 0.3, 0..0, 12);
    assert_eq!(plain.depth_coverage, 0);
    assert!(!plain.flags.is_valid());
}

#[test]
fn a_textured_wall_nearer_than_the_stereo_range_is_an_obstacle_at_the_minimum_range() {
    let p = EdgeFsParams::default_config();
    let min_range = p.focal_px() * p.baseline_m / f32::from(p.stereo_range);
    // Beyond the range: measured, not flagged near.
    let (far, _) = fly(p, 0.9, 0.0, 0.0, 0.0, 3);
    assert!(
        matches!(far.obstacle_m, Some(d) if (d - 0.9).abs() < 0.15),
        "{:?}",
        far.obstacle_m
    );
    // Nearer than the range (its disparity beyond the search): the minimum range, not None.
    let (near, _) = fly(p, 0.6 * min_range, 0.0, 0.0, 0.0, 3);
    assert!(
        near.near_columns >= 12,
        "{} near columns",
        near.near_columns
    );
    assert_eq!(near.obstacle_m, Some(min_range));
    // Off (`min_near_run` 0): a run of near columns is not reported as the minimum range.
    let (off, _) = fly(
        EdgeFsParams {
            min_near_run: 0,
            ..p
        },
        0.6 * min_range,
        0.0,
        0.0,
        0.0,
        3,
    );
    assert_ne!(off.obstacle_m, Some(min_range));
}

/// Renders a wall textured along both axes at depth `z`, the cameras at lateral position `pos`
/// and height `up` (m), pitched `pitch_px` px nose up (the scene moves down the image).
fn render_2d(
    z: f32,
    pos: f32,
    up: f32,
    pitch_px: f32,
    params: &EdgeFsParams,
) -> [u8; STEREO_FRAME_BYTES] {
    let f = params.focal_px();
    let mut frame = [0u8; STEREO_FRAME_BYTES];
    for row in 0..IMG_H {
        let height = up + (47.5 - row as f32 + pitch_px) * z / f;
        let across = texture(height + 17.0);
        for c in 0..IMG_W {
            let x = c as f32 - 63.5;
            let xl = x + params.stereo_shift_px as f32;
            let (wl, wr) = (pos + xl * z / f, pos + params.baseline_m + x * z / f);
            let i = 2 * (row * IMG_W + c);
            frame[i] = (0.5 * (texture(wl) + across)) as u8;
            frame[i + 1] = (0.5 * (texture(wr) + across)) as u8;
        }
    }
    frame
}

/// Flies at `vf` forward and `vu` up (m/s) with a pitch rate (rad/s) from a 2-D textured wall
/// at `z0`; the attitude gives the pitch when `pitch_known`. Returns the last output.
fn fly_2d(z0: f32, vf: f32, vu: f32, pitch_rate: f32, pitch_known: bool) -> EdgeFsOutput {
    let params = EdgeFsParams {
        vertical_search_px: EdgeFsParams::VERTICAL_SEARCH_PX,
        ..EdgeFsParams::default_config()
    };
    let mut fs = EdgeFs::new(params);
    let f = params.focal_px();
    let mut out = EdgeFsOutput::EMPTY;
    for i in 0..30 {
        let t = i as f32 / 25.0;
        let pitch = pitch_rate * t;
        let frame = render_2d(z0 - vf * t, 0.0, vu * t, pitch * f, &params);
        let motion = GyroAttitude {
            timestamp_us: protocol::WireTime(0),
            rates_radps: [0.0; 3],
            attitude_rad: [0.0, if pitch_known { pitch } else { 0.0 }, 0.0],
        };
        out = fs.process(
            &frame,
            Instant::from_micros((t * 1e6) as u64),
            Some(&motion),
        );
    }
    out
}

#[test]
fn climbing_and_sinking_give_the_vertical_velocity_up_positive() {
    for vu in [0.3f32, -0.3] {
        let out = fly_2d(1.5, 0.0, vu, 0.0, true);
        assert!(out.up_flags.is_valid(), "{vu}: {:?}", out.up_flags);
        assert!(
            (out.up_mps - vu).abs() < 0.06,
            "climbing {vu} m/s read {}",
            out.up_mps
        );
        assert!(out.forward_mps.abs() < 0.1, "forward {}", out.forward_mps);
    }
}

#[test]
fn forward_and_climb_together_are_both_recovered() {
    let out = fly_2d(2.0, 0.4, 0.2, 0.0, true);
    assert!(out.flags.is_valid() && out.up_flags.is_valid());
    assert!(
        (out.forward_mps - 0.4).abs() < 0.08,
        "forward {}",
        out.forward_mps
    );
    assert!((out.up_mps - 0.2).abs() < 0.06, "up {}", out.up_mps);
    // The flow model explains the divergence and the climb.
    assert!(out.fit_r2 > 128, "R² {}", out.fit_r2);
}

#[test]
fn pitch_rotation_is_removed_with_the_attitude() {
    // Pitching at 0.3 rad/s without climbing: the scene sweeps 1.5 px per frame.
    let known = fly_2d(1.5, 0.0, 0.0, 0.3, true);
    assert!(known.up_flags.is_valid(), "{:?}", known.up_flags);
    assert!(known.up_mps.abs() < 0.06, "derotated: {}", known.up_mps);
    // Without the pitch the same sweep reads as a climb: the derotation is what removes it.
    // (0.15 rad/s: the sweep over the horizon stays within the vertical search.)
    let unknown = fly_2d(1.5, 0.0, 0.0, 0.15, false);
    assert!(unknown.up_mps > 0.12, "not derotated: {}", unknown.up_mps);
}

#[test]
fn paper_mode_estimates_no_vertical_velocity() {
    let out = fly_2d_paper();
    assert_eq!(out.up_mps, 0.0);
    assert!(out.up_flags.contains(EstimateFlags::NO_FLOW_MATCH));
    assert_eq!(out.fit_r2, 0);
}

fn fly_2d_paper() -> EdgeFsOutput {
    let params = EdgeFsParams::paper();
    let mut fs = EdgeFs::new(params);
    let mut out = EdgeFsOutput::EMPTY;
    for i in 0..12 {
        let t = i as f32 / 25.0;
        let frame = render_2d(1.5, 0.0, 0.3 * t, 0.0, &params);
        out = fs.process(
            &frame,
            Instant::from_micros((t * 1e6) as u64),
            Some(&gyro(0.0)),
        );
    }
    out
}

/// The inline `fmax`/`fmin` are `f32::max`/`min` (NaN gives the other argument), up to the
/// sign of an equal zero, which `f32::max` leaves open.
#[test]
fn inline_min_max_equal_the_library_ones() {
    let values = [
        f32::NAN,
        f32::NEG_INFINITY,
        -3.5,
        -1.0,
        -f32::MIN_POSITIVE,
        -0.0,
        0.0,
        1e-30,
        1.0,
        2.5,
        f32::MAX,
        f32::INFINITY,
    ];
    let same = |a: f32, b: f32| (a.is_nan() && b.is_nan()) || a == b;
    for &a in &values {
        for &b in &values {
            assert!(same(fmax(a, b), a.max(b)), "max({a}, {b})");
            assert!(same(fmin(a, b), a.min(b)), "min({a}, {b})");
        }
    }
}
