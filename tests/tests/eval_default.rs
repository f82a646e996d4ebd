//! The `default` Edge-FS configuration's goal on the recorded takes, with the paper's protocol
//! (`--alignment paper`): a lower MSE than both the paper's Edge-FS and its Farnebäck baseline
//! on at least 80 % of the takes with published numbers, for both axes.

use integration_tests::shared_dataset_dir;
use sim_host::eval::{dataset::discover_takes, evaluate_take, wins, Alignment, Config};

#[test]
fn default_config_beats_both_published_methods_on_80_percent_of_takes() {
    let takes = discover_takes(&shared_dataset_dir()).expect("data set");
    let results: Vec<_> = takes
        .iter()
        .map(|t| evaluate_take(t, Config::Default, Alignment::Paper, &|| {}).expect("evaluate"))
        .collect();
    let w = wins(&results);
    assert_eq!(w.takes, 12);
    let need = (w.takes * 4).div_ceil(5);
    assert!(
        w.x_both >= need && w.y_both >= need,
        "forward wins {}/{}, sideways wins {}/{} (need {need})",
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
