//! `sim-host fly --format csv` prints one summary row per flight whose columns a user's script
//! reads by name: the tracking figures among them (velocity against its setpoint in `Forward`,
//! speed and drift in `Hover`, height in level flight), measured from the true state, and why each
//! flight ended (`end_reason`).

use std::collections::HashMap;
use std::path::Path;
use std::process::Command;

/// Runs `sim-host fly ARGS --format csv --quiet --out OUT_DIR` and returns what it printed.
fn fly_csv(args: &[&str], out_dir: &Path) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_sim-host"))
        .arg("fly")
        .args(args)
        .args(["--format", "csv", "--quiet", "--out"])
        .arg(out_dir)
        .output()
        .expect("sim-host runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf-8")
}

#[test]
fn csv_summary_has_the_tracking_columns_with_measured_values() {
    let out_dir = std::env::temp_dir().join(format!("fly-csv-{}", std::process::id()));
    let text = fly_csv(
        &["--duration", "30", "--seed", "7", "--seeds", "1"],
        &out_dir,
    );
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let values: Vec<&str> = lines.next().expect("one row").split(',').collect();
    assert_eq!(header.len(), values.len(), "{text}");
    let fields: HashMap<&str, &str> = header.iter().copied().zip(values).collect();
    // 30 s in the paper's room with no battery model: flown to the end.
    assert_eq!(fields["end_reason"], "duration", "{text}");
    let row: HashMap<&str, f64> = fields
        .iter()
        .filter(|(k, _)| **k != "end_reason")
        .map(|(k, v)| (*k, v.parse().expect("a number")))
        .collect();
    for column in [
        "track_rmse_mps",
        "hover_speed_mps",
        "height_rmse_m",
        "tilt_rmse_deg",
        "vel_rmse_mps",
        "hover_drift_m",
    ] {
        assert!(row[column].is_finite(), "{column}: {text}");
    }
    // 30 s in the paper's room reach Forward and Hover; the figures are of a flying drone, not
    // zeros: it never tracks its setpoints perfectly.
    assert!((0.01..0.6).contains(&row["track_rmse_mps"]), "{text}");
    assert!((0.0..0.6).contains(&row["hover_speed_mps"]), "{text}");
    // A hover of a few seconds at a few cm/s: centimetres, not metres.
    assert!((0.0..0.5).contains(&row["hover_drift_m"]), "{text}");
    assert!((0.005..0.3).contains(&row["height_rmse_m"]), "{text}");
    // The attitude estimate is never exact (sensor noise, biases), and a degree and more is
    // what the velocity filter cannot live with.
    assert!((0.01..1.0).contains(&row["tilt_rmse_deg"]), "{text}");
    let _ = std::fs::remove_dir_all(&out_dir);
}

/// `--suite N --room-logs` keeps each flight's log beside the table, named by its room, so
/// that a flight the table counts as a contact can be studied.
#[test]
fn suite_room_logs_are_written_by_room_name() {
    let out_dir = std::env::temp_dir().join(format!("fly-suite-logs-{}", std::process::id()));
    let text = fly_csv(
        &[
            "--suite",
            "2",
            "--seed",
            "5",
            "--duration",
            "3",
            "--room-logs",
        ],
        &out_dir,
    );
    assert_eq!(text.lines().count(), 3, "header and two rows: {text}");
    assert!(
        text.lines().next().unwrap().contains("tilt_rmse_deg"),
        "{text}"
    );
    for room in ["suite-5-0", "suite-5-1"] {
        let path = out_dir.join(room).join("log.csv");
        let log = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
        let header = log.lines().next().expect("header");
        assert!(
            header.ends_with("roll_err_deg,pitch_err_deg,closing_mps,overrule_mps,contact_s"),
            "{header}"
        );
        // 3 s at 50 Hz.
        assert!(
            log.lines().count() > 140,
            "{path:?}: {} lines",
            log.lines().count()
        );
    }
    let _ = std::fs::remove_dir_all(&out_dir);
}

/// A battery too small for the flight: the autopilot reads it run low and lands, and the
/// summary says so.
#[test]
fn a_small_battery_ends_the_flight_in_a_low_battery_landing() {
    let out_dir = std::env::temp_dir().join(format!("fly-battery-{}", std::process::id()));
    let text = fly_csv(
        &["--duration", "40", "--seed", "3", "--battery-mah", "20"],
        &out_dir,
    );
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let values: Vec<&str> = lines.next().expect("one row").split(',').collect();
    let row: HashMap<&str, &str> = header.iter().copied().zip(values).collect();
    assert_eq!(row["end_reason"], "landed: low battery", "{text}");
    assert_eq!(row["collisions"], "0", "{text}");
    // The log shows the landing and the drone disarmed on the floor at the end.
    let log = std::fs::read_to_string(out_dir.join("log.csv")).expect("the flight's log");
    let last = log.lines().last().expect("rows");
    assert!(last.contains(",disarmed,"), "{last}");
    let _ = std::fs::remove_dir_all(&out_dir);
}
