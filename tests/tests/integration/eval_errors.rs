//! `sim-host eval` on broken input: each bad take fails with an error naming the file and the
//! problem, while the good takes still evaluate.

use integration_tests::shared_dataset_dir;
use sim_host::eval::{
    dataset::{discover_takes, Take},
    evaluate_take, select_takes, Alignment, Config,
};
use std::fs;
use std::path::{Path, PathBuf};

fn copy_take(src: &Path, dst: &Path, images: usize) {
    fs::create_dir_all(dst).unwrap();
    for name in ["timing.dat", "position.dat", "%i.bmp.tme"] {
        fs::copy(src.join(name), dst.join(name)).unwrap();
    }
    for i in 1..=images {
        fs::copy(src.join(format!("{i}.bmp")), dst.join(format!("{i}.bmp"))).unwrap();
    }
}

fn scratch_dataset() -> PathBuf {
    let root = std::env::temp_dir().join(format!("edgefs-eval-errors-{}", std::process::id()));
    let _ = fs::remove_dir_all(&root);
    let src_board = shared_dataset_dir().join("database_stereoboard_1");
    let board = root.join("database_stereoboard_1");
    let fwd = board.join("forward_camera");
    fs::create_dir_all(&fwd).unwrap();
    fs::copy(
        src_board.join("calibration_data.txt"),
        board.join("calibration_data.txt"),
    )
    .unwrap();
    let src = src_board.join("forward_camera/take1");
    for t in 1..=5 {
        copy_take(&src, &fwd.join(format!("take{t}")), 40);
    }
    // take2: a BMP whose header claims 24 bits per pixel (byte 28) over 8-bit pixel data.
    let bmp = fwd.join("take2/7.bmp");
    let mut b = fs::read(&bmp).unwrap();
    b[28] = 24;
    fs::write(&bmp, b).unwrap();
    // take3: no position.dat.
    fs::remove_file(fwd.join("take3/position.dat")).unwrap();
    // take4: malformed timing.dat.
    fs::write(fwd.join("take4/timing.dat"), "%time\t0\r\n1.0\tone\r\n").unwrap();
    // take5: no images.
    for i in 1..=40 {
        fs::remove_file(fwd.join(format!("take5/{i}.bmp"))).unwrap();
    }
    root
}

fn eval(t: &Take) -> Result<(), String> {
    evaluate_take(t, Config::Default, Alignment::Paper, &|| {})
        .map(|_| ())
        .map_err(|e| format!("{e:#}"))
}

#[test]
fn bad_takes_fail_with_clear_errors_and_good_ones_still_evaluate() {
    let root = scratch_dataset();
    let takes = discover_takes(&root).unwrap();
    assert_eq!(takes.len(), 5);
    let errs: Vec<Result<(), String>> = takes.iter().map(eval).collect();
    assert!(errs[0].is_ok(), "{:?}", errs[0]);
    let e = errs[1].as_ref().unwrap_err();
    assert!(e.contains("7.bmp") && e.contains("truncated"), "{e}");
    let e = errs[2].as_ref().unwrap_err();
    assert!(e.contains("position.dat"), "{e}");
    let e = errs[3].as_ref().unwrap_err();
    assert!(
        e.contains("timing.dat") && e.contains("not a number"),
        "{e}"
    );
    let e = errs[4].as_ref().unwrap_err();
    assert!(e.contains("no images"), "{e}");

    let sel = select_takes(takes, Some("1/1,1/4")).unwrap();
    assert_eq!(sel.iter().map(|t| t.take).collect::<Vec<_>>(), [1, 4]);
    let _ = fs::remove_dir_all(&root);
}
