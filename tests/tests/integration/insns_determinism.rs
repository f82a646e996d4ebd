//! `cargo xtask insns` counts Cortex-M4 instructions in QEMU exactly: the same build must give
//! the same numbers run after run, every function the performance report names must be
//! measured, and every count must be within its budget (`xtask/budgets.toml`: this test is how
//! CI fails on a regression).

use std::process::Command;

#[test]
fn instruction_counts_are_deterministic_complete_and_within_budget() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let take =
        integration_tests::shared_dataset_dir().join("database_stereoboard_1/forward_camera/take1");
    let out = Command::new(env!("CARGO"))
        .current_dir(&root)
        .args(["xtask", "insns", "--runs", "2", "--take"])
        .arg(&take)
        .output()
        .expect("run cargo xtask insns");
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stdout}");
    assert!(
        out.status.success(),
        "cargo xtask insns failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("deterministic: 2 runs gave identical counts"));
    assert!(
        stdout.contains("budget insns.edge_fs_frame_default:"),
        "the budget comparison did not run"
    );
    for name in [
        "edge_fs_frame_default",
        "edge_fs_frame_paper",
        "edge_histograms",
        "stereo_match",
        "flow_match",
        "stereo_row",
        "flow_row",
        "line_fit",
        "line_fit_paper",
        "indi_step",
        "guidance_fsm_step",
        "estimate_encode",
        "estimate_decode",
        "gyro_decode",
        "camera_board_frame",
    ] {
        let count: u64 = stdout
            .lines()
            .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
            .unwrap_or_else(|| panic!("no count for {name}"));
        assert!(count > 0, "{name} measured as 0 instructions");
    }
}
