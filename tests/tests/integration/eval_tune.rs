//! Parameter selection for the `default` Edge-FS configuration (ignored: a tool, not a check).
//!
//! Protocol: parameters are chosen on the tuning takes only (board 1 takes 1, 5, 9, 13, 17, 21),
//! with `--alignment paper`, on the estimator's raw output (what the camera board sends); the
//! objective is the mean over tuning takes and both axes of
//! `ln(MSE / min(published Edge-FS MSE, published Farnebäck MSE))`. The held-out takes
//! (1/3, 1/7, 1/11, 1/15, 1/19, 2/3) are only reported. Run with e.g.
//! `EDGEFS_TUNE="w=6 fa=0.3" cargo test --release -p integration-tests --test integration eval_tune -- --ignored --nocapture`
//! (keys: w d h mind sc fc tex hk rms minc ds hs med dw fa fg ff fs ft fov_deg; unset keys keep
//! the default configuration). `EDGEFS_DUMP=DIR` writes each take's evaluated series as CSV;
//! `EDGEFS_FLAGS=1` prints how often each flag was set.

use integration_tests::shared_dataset_dir;
use sim_host::eval::{
    dataset::{discover_takes, stereo_shift},
    evaluate_take_with,
    paper_table::paper_row,
    Alignment,
};
use stereo_board::edge_fs::EdgeFsParams;

const TUNING: [(u32, u32); 6] = [(1, 1), (1, 5), (1, 9), (1, 13), (1, 17), (1, 21)];

#[test]
#[ignore = "parameter-selection tool; run explicitly"]
fn tune_default_config() {
    let mut p = EdgeFsParams::default_config();
    let spec = std::env::var("EDGEFS_TUNE").unwrap_or_default();
    for kv in spec.split_whitespace() {
        let (k, v) = kv.split_once('=').expect("key=value");
        let f: f32 = v.parse().expect("number");
        match k {
            "w" => p.half_window = f as u8,
            "d" => p.search_range = f as u8,
            "h" => p.max_horizon = f as u8,
            "mind" => p.min_disparity_px = f,
            "sc" => p.min_stereo_confidence = f,
            "fc" => p.min_flow_confidence = f,
            "tex" => p.min_texture = f as u32,
            "hk" => p.huber_k = f,
            "rms" => p.max_fit_rms_mps = f,
            "minc" => p.min_fit_columns = f as u8,
            "ds" => p.stereo_range = f as u8,
            "hs" => p.horizon_s = f,
            "med" => p.output_median = f as u8,
            "dw" => p.depth_weight_exp = f,
            "fa" => p.filter_accel_mps2 = f,
            "fg" => p.filter_gate = f,
            "ff" => p.filter_noise_floor_mps = f,
            "fs" => p.filter_noise_scale = f,
            "ft" => p.filter_accel_tau_s = f,
            "fov_deg" => p.fov_x_rad = f.to_radians(),
            _ => panic!("unknown key {k}"),
        }
    }
    let takes = discover_takes(&shared_dataset_dir()).unwrap();
    let (mut obj_tune, mut obj_hold) = (0.0, 0.0);
    let (mut wins_tune, mut wins_hold) = ((0, 0), (0, 0));
    for t in &takes {
        let Some(pr) = paper_row(t.board, t.take) else {
            continue;
        };
        let mut params = p;
        params.stereo_shift_px = stereo_shift(t).unwrap();
        let r = evaluate_take_with(t, params, false, Alignment::Paper, &|| {}).unwrap();
        if std::env::var("EDGEFS_FLAGS").is_ok() {
            let mut hist = [0usize; 8];
            for f in &r.series.flags {
                for (b, h) in hist.iter_mut().enumerate() {
                    *h += usize::from(f & (1 << b) != 0);
                }
            }
            println!(
                "flags {}/{}: {hist:?} of {}",
                t.board,
                t.take,
                r.series.flags.len()
            );
        }
        if let Ok(dir) = std::env::var("EDGEFS_DUMP") {
            let mut out = String::from("i,t,est_x,gt_x,est_y,gt_y,flags\n");
            let s = &r.series;
            for i in s.window.0..=s.window.1 {
                out += &format!(
                    "{},{},{},{},{},{},{}\n",
                    i, s.time_s[i], s.est_x[i], s.gt_x[i], s.est_y[i], s.gt_y[i], s.flags[i]
                );
            }
            std::fs::write(format!("{dir}/b{}t{}.csv", t.board, t.take), out).unwrap();
        }
        let bx = pr.edgefs[1].min(pr.farneback[1]);
        let by = pr.edgefs[4].min(pr.farneback[4]);
        let o = 0.5 * ((r.x.mse / bx).ln() + (r.y.mse / by).ln());
        let tuning = TUNING.contains(&(t.board, t.take));
        let (obj, wins) = if tuning {
            (&mut obj_tune, &mut wins_tune)
        } else {
            (&mut obj_hold, &mut wins_hold)
        };
        *obj += o / 6.0;
        wins.0 += usize::from(r.x.mse < bx);
        wins.1 += usize::from(r.y.mse < by);
        println!(
            "{} {}/{:<2} mse_x {:.4} (best paper {:.4})  mse_y {:.4} (best paper {:.4})",
            if tuning { "tune" } else { "hold" },
            t.board,
            t.take,
            r.x.mse,
            bx,
            r.y.mse,
            by
        );
    }
    println!(
        "RESULT [{spec}] tuning objective {obj_tune:.4} wins x {}/6 y {}/6 | held-out objective {obj_hold:.4} wins x {}/6 y {}/6",
        wins_tune.0, wins_tune.1, wins_hold.0, wins_hold.1
    );
}
