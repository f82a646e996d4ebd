//! `sim-host replay` on two recorded takes: the frame statistics are computed for the recorded
//! and the rendered frames, both Edge-FS errors are finite, the table and the CSV carry every
//! take, the rendered error is within 0.5x-2x of the recorded one where the replay reaches
//! that band (board 1 take 19 on both axes, take 11 sideways, on seeds 1 to 4; see
//! docs/replay.md), and the calibrated cameras' relative roll gives the renderings the recorded
//! frames' left-right shear.

use integration_tests::shared_dataset_dir;
use sim_host::eval::camera_calib::{board_calib, measure_take, LAGS_S};
use sim_host::eval::dataset::discover_takes;
use sim_host::eval::frame_stats::N_BINS;
use sim_host::eval::replay::{csv, replay_take, table, Effect, ReplayResult};
use sim_host::eval::{select_takes, Alignment};
use sim_host::sim::camera::{CameraParams, CALIBRATED_COLUMN_FPN_DN};

fn replay(list: &str) -> Vec<ReplayResult> {
    let takes = select_takes(discover_takes(&shared_dataset_dir()).unwrap(), Some(list)).unwrap();
    takes
        .iter()
        .map(|t| replay_take(t, Alignment::Corrected, 1, 3, &Effect::ALL).expect("replay"))
        .collect()
}

#[test]
fn replay_prints_both_errors_and_statistics() {
    let results = replay("1/19,1/11");
    assert_eq!(results.len(), 2);
    for r in &results {
        let name = format!("board {} take {}", r.board, r.take);
        for st in [&r.real_stats, &r.rendered_stats] {
            assert!(st.mean_edge_density() > 0.01, "{name}: edge density {st:?}");
            assert!((st.gradient_hist.iter().sum::<f64>() - 1.0).abs() < 1e-9);
            assert_eq!(st.gradient_hist.len(), N_BINS);
            assert!(
                st.noise_dn > 0.5 && st.noise_dn < 20.0,
                "{name}: noise {}",
                st.noise_dn
            );
            assert!(st.mean_dn > 20.0 && st.mean_dn < 235.0);
        }
        for m in [r.real_x, r.real_y, r.rendered_x, r.rendered_y] {
            assert!(m.mse.is_finite() && m.mse > 0.0, "{name}: {m:?}");
        }
        assert!(r.ratio_x().is_finite() && r.ratio_y().is_finite());
        // Both takes' recorded frames shear by about 0.25 px (the cameras' roll and the floor);
        // the renderings with the calibrated roll do too.
        assert!(
            r.real_lr_shear_px < -0.15
                && (r.rendered_lr_shear_px - r.real_lr_shear_px).abs() < 0.12,
            "{name}: left-right shear recorded {} px, rendered {} px",
            r.real_lr_shear_px,
            r.rendered_lr_shear_px
        );
        // The scene was chosen from the statistics: it is nearer to them than a plain room.
        assert!(
            r.scene.distance < 1.0,
            "{name}: fit distance {}",
            r.scene.distance
        );
    }
    let t = table(&results, Alignment::Corrected);
    for take in [
        "    1   19 recorded",
        "    1   19 rendered",
        "    1   11 recorded",
    ] {
        assert!(t.contains(take), "{take:?} missing in\n{t}");
    }
    assert!(t.contains("ratio") && t.contains("scene: walls"), "{t}");
    let c = csv(&results);
    let lines: Vec<&str> = c.lines().collect();
    assert_eq!(lines.len(), 3, "{c}");
    let cols = lines[0].split(',').count();
    assert!(lines[0].starts_with("board,take,frames,real_mse_x"));
    assert!(lines[1..].iter().all(|l| l.split(',').count() == cols));

    for r in &results {
        let axes: &[(&str, f64)] = match r.take {
            19 => &[("forward", r.ratio_x()), ("sideways", r.ratio_y())],
            _ => &[("sideways", r.ratio_y())],
        };
        for &(axis, ratio) in axes {
            assert!(
                (0.5..=2.0).contains(&ratio),
                "board {} take {} {axis} ratio {ratio}",
                r.board,
                r.take
            );
        }
    }
}

/// The measurement behind the calibrated camera: on board 1's takes the left camera has a
/// column pattern common to the takes and the right one nearly none, both are vignetted, and
/// the images' shift follows the yaw best about 0.2 s before their recorded times; the
/// calibrated camera's defaults are those values.
#[test]
fn camera_calib_measures_the_calibrated_defaults() {
    let takes = select_takes(discover_takes(&shared_dataset_dir()).unwrap(), Some("1/*")).unwrap();
    let calibs: Vec<_> = takes.iter().map(|t| measure_take(t).unwrap()).collect();
    let refs: Vec<_> = calibs.iter().collect();
    let c = board_calib(&refs);
    let d = CameraParams::default();
    let left = c.column_fixed_dn[0];
    assert!(
        (f64::from(CALIBRATED_COLUMN_FPN_DN[0]) - left).abs() < 0.1 && c.column_corr[0] > 0.2,
        "left column pattern {left} DN, corr {}",
        c.column_corr[0]
    );
    assert!(c.column_fixed_dn[1] < 0.5, "right {}", c.column_fixed_dn[1]);
    for k in c.vignetting_k {
        assert!(
            (k - f64::from(d.vignetting_k)).abs() < 0.1 * f64::from(-d.vignetting_k),
            "vignetting {k}"
        );
    }
    let readout = c.readout_s[0];
    assert!(
        (readout - f64::from(d.rolling_shutter_s)).abs() < 0.005 && readout > 2.0 * c.readout_s[1],
        "readout {readout} +- {}",
        c.readout_s[1]
    );
    let best = (0..LAGS_S.len())
        .max_by(|&i, &j| c.lag_corr[i].total_cmp(&c.lag_corr[j]))
        .unwrap();
    assert!(
        (-0.30..=-0.10).contains(&LAGS_S[best]),
        "best lag {} s",
        LAGS_S[best]
    );
}
