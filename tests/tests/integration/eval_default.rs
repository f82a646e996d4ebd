//! The `default` Edge-FS configuration's goal on the recorded takes, with the paper's protocol
//! (`--alignment paper`): the estimator exactly as the camera board emits it
//! (`EdgeFsParams::default_config()`, no filter outside the estimator) has a lower MSE than
//! both the paper's Edge-FS and its Farnebäck baseline on at least 10 of the 12 takes with
//! published numbers, for the forward and for the sideways velocity.

use integration_tests::shared_dataset_dir;
use sim_host::eval::{
    dataset::{discover_takes, stereo_shift},
    evaluate_take, evaluate_take_with, params_for, wins, Alignment, Config,
};
use stereo_board::edge_fs::EdgeFsParams;

#[test]
fn raw_board_output_beats_both_published_methods_on_10_of_12_takes() {
    let takes = discover_takes(&shared_dataset_dir()).expect("data set");
    let mut results = Vec::new();
    for t in &takes {
        // The evaluation runs the board's configuration untouched (only the calibration).
        let p = params_for(Config::Default, t).expect("params");
        let board = EdgeFsParams {
            stereo_shift_px: stereo_shift(t).expect("calibration"),
            ..EdgeFsParams::default_config()
        };
        assert_eq!(p, board);
        let r = evaluate_take(t, Config::Default, Alignment::Paper, &|| {}).expect("evaluate");
        // Same numbers when driven directly with the board's parameters.
        let direct = evaluate_take_with(t, board, false, Alignment::Paper, &|| {}).unwrap();
        assert_eq!(r.series.est_x, direct.series.est_x);
        results.push(r);
    }
    let w = wins(&results);
    assert_eq!(w.takes, 12);
    assert!(
        w.x_both >= 10 && w.y_both >= 10,
        "forward wins {}/{}, sideways wins {}/{} (need 10)",
        w.x_both,
        w.takes,
        w.y_both,
        w.takes
    );
    // Every estimate is finite (the default mode never outputs NaN/inf).
    for r in &results {
        assert!(r
            .series
            .est_x
            .iter()
            .chain(&r.series.est_y)
            .all(|v| v.is_finite()));
    }
}
