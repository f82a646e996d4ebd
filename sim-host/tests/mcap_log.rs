//! `sim-host fly` writes an MCAP flight log that an independent reader understands: the `mcap`
//! package from PyPI (what PlotJuggler's and Foxglove's users script with) reads it back, and
//! its channels, schemas, message counts and time order are checked against the flight, and
//! against this crate's own reader. `cargo xtask test` installs the Python package.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// Reads the log with the PyPI `mcap` package; prints one JSON object with what it found.
const READER: &str = r#"
import base64, json, sys
from mcap.reader import make_reader

with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    summary = reader.get_summary()
    stats = summary.statistics
    channels = {}
    for c in summary.channels.values():
        schema = summary.schemas[c.schema_id]
        channels[c.topic] = {
            "schema": schema.name,
            "schema_encoding": schema.encoding,
            "message_encoding": c.message_encoding,
            "schema_is_json": isinstance(json.loads(schema.data), dict),
        }
    counts, ordered, last = {}, True, -1
    states, modes, flags, image_bytes = set(), set(), set(), set()
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        if message.log_time < last:
            ordered = False
        last = message.log_time
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
        value = json.loads(message.data)
        if channel.topic == "/state":
            states.add(value["fsm_state"])
            modes.add(value["mode"])
        elif channel.topic == "/estimate":
            flags.update(value["flag_names"])
        elif channel.topic.startswith("/camera/"):
            assert value["encoding"] == "mono8" and value["step"] == value["width"]
            image_bytes.add(len(base64.b64decode(value["data"])))
    print(json.dumps({
        "channels": channels,
        "counts": counts,
        "statistics_counts": {summary.channels[k].topic: v
                              for k, v in stats.channel_message_counts.items()},
        "message_count": stats.message_count,
        "time_ordered": ordered,
        "start_ns": stats.message_start_time,
        "end_ns": stats.message_end_time,
        "states": sorted(states),
        "modes": sorted(modes),
        "flags": sorted(flags),
        "image_bytes": sorted(image_bytes),
    }))
"#;

fn python_reads(path: &Path) -> serde_json::Value {
    let out = Command::new("python3")
        .arg("-c")
        .arg(READER)
        .arg(path)
        .output()
        .expect("python3 runs (cargo xtask test installs python3 and the mcap package)");
    assert!(
        out.status.success(),
        "the Python mcap reader failed (install it with `python3 -m pip install mcap`, which \
         cargo xtask test does):\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("the reader prints JSON")
}

fn crate_counts(path: &Path) -> BTreeMap<String, u64> {
    let bytes = std::fs::read(path).unwrap();
    let mut counts = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        *counts.entry(m.unwrap().channel.topic.clone()).or_insert(0) += 1;
    }
    counts
}

#[test]
fn fly_writes_an_mcap_log_the_python_reader_understands() {
    let dir = std::env::temp_dir().join(format!("fly-mcap-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = Command::new(env!("CARGO_BIN_EXE_sim-host"))
        .args(["fly", "--duration", "6", "--quiet", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let path = dir.join("flight.mcap");
    assert!(stdout.contains("flight.mcap"), "{stdout}");
    assert!(dir.join("log.csv").is_file(), "the CSV stays");

    let v = python_reads(&path);
    let channels = v["channels"].as_object().unwrap();
    let topics: Vec<&str> = channels.keys().map(String::as_str).collect();
    assert_eq!(
        topics,
        [
            "/attitude",
            "/baro",
            "/camera/left",
            "/camera/right",
            "/estimate",
            "/height",
            "/link",
            "/motors",
            "/setpoint",
            "/state",
            "/stereo_status",
            "/truth",
            "/velocity"
        ]
    );
    for (topic, c) in channels {
        assert_eq!(c["message_encoding"], "json", "{topic}");
        assert_eq!(c["schema_encoding"], "jsonschema", "{topic}");
        assert_eq!(c["schema_is_json"], true, "{topic}");
    }
    assert_eq!(channels["/camera/left"]["schema"], "foxglove.RawImage");
    assert_eq!(channels["/estimate"]["schema"], "pocket_drone.Estimate");

    let counts: BTreeMap<String, u64> = serde_json::from_value(v["counts"].clone()).unwrap();
    let n = |t: &str| counts.get(t).copied().unwrap_or(0);
    // 6 s of flight: guidance and the barometer at 50 Hz, control logged at 128 Hz, images at
    // 5 Hz (the first exposure at 0.1 s), estimates at up to 25 Hz.
    for t in [
        "/baro",
        "/state",
        "/setpoint",
        "/velocity",
        "/height",
        "/truth",
        "/link",
    ] {
        assert!((299..=301).contains(&n(t)), "{t}: {counts:?}");
    }
    for t in ["/attitude", "/motors"] {
        assert!((767..=769).contains(&n(t)), "{t}: {counts:?}");
    }
    assert_eq!(n("/camera/left"), 30, "{counts:?}");
    assert_eq!(n("/camera/right"), 30);
    assert!((120..=150).contains(&n("/estimate")), "{counts:?}");
    assert!((4..=7).contains(&n("/stereo_status")), "1 Hz: {counts:?}");

    let stats: BTreeMap<String, u64> =
        serde_json::from_value(v["statistics_counts"].clone()).unwrap();
    assert_eq!(
        stats, counts,
        "the summary's statistics agree with the messages"
    );
    assert_eq!(v["message_count"], counts.values().sum::<u64>());
    assert_eq!(
        crate_counts(&path),
        counts,
        "both readers see the same messages"
    );
    assert_eq!(
        v["time_ordered"], true,
        "messages are written in time order"
    );
    let (start, end) = (
        v["start_ns"].as_u64().unwrap(),
        v["end_ns"].as_u64().unwrap(),
    );
    assert!(start < 20_000_000 && (5_900_000_000..=6_000_000_000).contains(&end));

    // The drone took off: the mode went from disarmed to flying, and the FSM started.
    let names = |k: &str| -> Vec<String> { serde_json::from_value(v[k].clone()).unwrap() };
    assert_eq!(names("modes"), ["disarmed", "flying"]);
    assert!(names("states").contains(&"inactive".to_string()));
    assert!(
        names("states").iter().any(|s| s != "inactive"),
        "{:?}",
        names("states")
    );
    assert!(names("flags").contains(&"history_filling".to_string()));
    assert_eq!(v["image_bytes"], serde_json::json!([128 * 96]));
    let _ = std::fs::remove_dir_all(&dir);
}
