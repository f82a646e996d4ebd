//! A suite split over machines: `sim-host fly --suite N --shard I/N --format csv` run as
//! separate processes, then `sim-host suite merge`, gives exactly the CSV and the table that
//! one `sim-host fly --suite N` prints.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs `sim-host ARGS` and returns what it printed; panics with its stderr on failure.
fn sim_host(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_sim-host"))
        .args(args)
        .output()
        .expect("sim-host runs");
    assert!(
        out.status.success(),
        "sim-host {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf-8")
}

/// `sim-host fly --suite 5 --seed 3 --duration 2 EXTRA --quiet --out OUT`.
fn suite(out: &Path, extra: &[&str]) -> String {
    let out = out.to_str().expect("utf-8 path");
    let mut args = vec![
        "fly",
        "--suite",
        "5",
        "--seed",
        "3",
        "--duration",
        "2",
        "--quiet",
        "--out",
        out,
    ];
    args.extend_from_slice(extra);
    sim_host(&args)
}

/// Every line but the last (the timing line, which says how the rows were made).
fn without_last_line(text: &str) -> Vec<&str> {
    let lines: Vec<&str> = text.lines().collect();
    lines[..lines.len() - 1].to_vec()
}

#[test]
fn shards_merged_give_the_whole_suites_csv_and_table() {
    let dir = std::env::temp_dir().join(format!("suite-merge-{}", std::process::id()));
    let whole_csv = suite(&dir.join("whole"), &["--format", "csv"]);
    let whole_table = suite(&dir.join("whole"), &[]);
    // Five rooms in two shards: rooms 0, 2, 4 and 1, 3, each in its own process.
    let mut shard_files: Vec<PathBuf> = Vec::new();
    for shard in ["1/2", "0/2"] {
        let text = suite(
            &dir.join(shard.replace('/', "-of-")),
            &["--shard", shard, "--format", "csv"],
        );
        let file = dir.join(format!("shard-{}.csv", shard.replace('/', "-of-")));
        std::fs::write(&file, &text).unwrap();
        shard_files.push(file);
    }
    let files: Vec<&str> = shard_files.iter().map(|f| f.to_str().unwrap()).collect();
    let merged_dir = dir.join("merged");
    let mut merge_csv = vec!["suite", "merge", "--format", "csv", "--out"];
    merge_csv.push(merged_dir.to_str().unwrap());
    merge_csv.extend_from_slice(&files);
    let merged_csv = sim_host(&merge_csv);
    assert_eq!(merged_csv, whole_csv);
    assert_eq!(
        whole_csv.lines().count(),
        6,
        "header and five rows: {whole_csv}"
    );
    assert_eq!(
        std::fs::read_to_string(merged_dir.join("suite.csv")).unwrap(),
        whole_csv
    );
    let mut merge_table = vec!["suite", "merge"];
    merge_table.extend_from_slice(&files);
    let merged_table = sim_host(&merge_table);
    assert_eq!(
        without_last_line(&merged_table),
        without_last_line(&whole_table)
    );
    assert!(
        whole_table.lines().any(|l| l.starts_with("all ")),
        "{whole_table}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_shard_or_a_room_twice_is_an_error() {
    let dir = std::env::temp_dir().join(format!("suite-merge-bad-{}", std::process::id()));
    // Rooms 1 and 4 of five.
    let text = suite(&dir, &["--shard", "1/3", "--format", "csv"]);
    let file = dir.join("shard-1.csv");
    std::fs::write(&file, &text).unwrap();
    let file = file.to_str().unwrap();
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_sim-host"))
            .args(args)
            .output()
            .expect("sim-host runs")
    };
    let missing = run(&["suite", "merge", file]);
    assert!(!missing.status.success());
    let err = String::from_utf8_lossy(&missing.stderr);
    assert!(err.contains("room 0 of the suite is missing"), "{err}");
    let twice = run(&["suite", "merge", file, file]);
    assert!(!twice.status.success());
    let err = String::from_utf8_lossy(&twice.stderr);
    assert!(err.contains("appears twice"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
