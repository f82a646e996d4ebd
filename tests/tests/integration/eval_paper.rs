//! The proof of the Edge-FS implementation and of the evaluation: the `paper` configuration
//! with the paper-era alignment reproduces every published Edge-FS number of the 12 takes in
//! the shared data set (NMXM, MSE, VAR for x and y) to the printed 4 decimals.

use integration_tests::shared_dataset_dir;
use sim_host::eval::{dataset::discover_takes, evaluate_take, Alignment, Config};

#[test]
fn paper_config_reproduces_published_table_to_4_decimals() {
    let dataset = shared_dataset_dir();
    let table_path = dataset.join("../../spec/paper_table_dev.csv");
    let table = std::fs::read_to_string(&table_path).expect("paper_table_dev.csv");
    let takes = discover_takes(&dataset).expect("data set");
    let mut checked = 0;
    let mut mismatches = Vec::new();
    for line in table.lines().skip(1).filter(|l| !l.trim().is_empty()) {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let (board, take): (u32, u32) = (f[0].parse().unwrap(), f[1].parse().unwrap());
        // Edge-FS columns: nmxm_x, mse_x, var_x, nmxm_y, mse_y, var_y at 2, 4, 6, 8, 10, 12.
        let want: Vec<&str> = [2, 4, 6, 8, 10, 12].iter().map(|&i| f[i]).collect();
        let t = takes
            .iter()
            .find(|t| t.board == board && t.take == take)
            .unwrap_or_else(|| panic!("take {board}/{take} missing from the data set"));
        let r = evaluate_take(t, Config::Paper, Alignment::Paper, &|| {}).expect("evaluate");
        let got: Vec<String> = [r.x.nmxm, r.x.mse, r.x.var, r.y.nmxm, r.y.mse, r.y.var]
            .iter()
            .map(|v| format!("{v:.4}"))
            .collect();
        for (k, (g, w)) in got.iter().zip(&want).enumerate() {
            if g != w {
                mismatches.push(format!(
                    "board {board} take {take} metric {k}: got {g}, published {w}"
                ));
            }
        }
        checked += 1;
    }
    assert_eq!(checked, 12, "expected 12 published takes");
    assert!(
        mismatches.is_empty(),
        "mismatches:\n{}",
        mismatches.join("\n")
    );
}
