//! `sim-host fly` writes an MCAP flight log that an independent reader understands: the `mcap`
//! package from PyPI (what PlotJuggler's and Foxglove's users script with) reads it back, with
//! `mcap-protobuf-support` decoding Foxglove's protobuf messages from the schemas in the file,
//! and its channels, schemas, message counts, time order and the 3D view's content are
//! checked against the flight, and against this crate's own reader. `cargo xtask test`
//! installs the Python packages.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// Reads the log with the PyPI `mcap` package; prints one JSON object with what it found.
const READER: &str = r#"
import json, sys
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

protobuf = DecoderFactory()
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    summary = reader.get_summary()
    stats = summary.statistics
    channels = {}
    for c in summary.channels.values():
        schema = summary.schemas[c.schema_id]
        is_json = c.message_encoding == "json"
        channels[c.topic] = {
            "schema": schema.name,
            "schema_encoding": schema.encoding,
            "message_encoding": c.message_encoding,
            "schema_is_json": is_json and isinstance(json.loads(schema.data), dict),
        }
    counts, ordered, last = {}, True, -1
    states, modes, flags, image_bytes = set(), set(), set(), set()
    scene, frames, depth_points, path_entities, notes = None, set(), 0, set(), set()
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        if message.log_time < last:
            ordered = False
        last = message.log_time
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
        if channel.message_encoding == "json":
            value = json.loads(message.data)
        else:
            value = protobuf.decoder_for(channel.message_encoding, schema)(message.data)
        if channel.topic == "/state":
            states.add(value["fsm_state"])
            modes.add(value["mode"])
        elif channel.topic == "/estimate":
            flags.update(value["flag_names"])
        elif channel.topic.startswith("/camera/") and channel.topic != "/camera/frustum":
            # A grey PNG: its signature, then IHDR's width and height and 8-bit grey.
            png = bytes(value.data)
            assert value.format == "png" and png[:8] == b"\x89PNG\r\n\x1a\n", png[:8]
            width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
            assert png[24:26] == b"\x08\x00", png[24:26]
            image_bytes.add(width * height)
        elif channel.topic == "/scene":
            scene = {e.id: {"cubes": len(e.cubes), "cylinders": len(e.cylinders)}
                     for e in value.entities}
        elif channel.topic == "/tf":
            frames.update((t.parent_frame_id, t.child_frame_id) for t in value.transforms)
        elif channel.topic == "/stereo/depth":
            assert value.point_stride == 12 and value.frame_id == "camera_left"
            depth_points = max(depth_points, len(value.data) // 12)
        elif channel.topic == "/path":
            path_entities.update(e.id.split("/")[0] for e in value.entities)
        elif channel.topic == "/annotations":
            notes.update(e.id for e in value.entities)
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
        "scene": scene,
        "frames": sorted(f"{p}>{c}" for p, c in frames),
        "depth_points": depth_points,
        "path_entities": sorted(path_entities),
        "notes": sorted(notes),
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
        "the Python mcap reader failed (install it with `python3 -m pip install mcap \
         mcap-protobuf-support`, which cargo xtask test does):\n{}",
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
            "/annotations",
            "/attitude",
            "/baro",
            "/camera/frustum",
            "/camera/left",
            "/camera/right",
            "/estimate",
            "/height",
            "/link",
            "/motors",
            "/path",
            "/scene",
            "/setpoint",
            "/state",
            "/stereo/depth",
            "/stereo_status",
            "/tf",
            "/truth",
            "/velocity"
        ]
    );
    let foxglove = [
        ("/annotations", "foxglove.SceneUpdate"),
        ("/camera/frustum", "foxglove.SceneUpdate"),
        ("/camera/left", "foxglove.CompressedImage"),
        ("/camera/right", "foxglove.CompressedImage"),
        ("/path", "foxglove.SceneUpdate"),
        ("/scene", "foxglove.SceneUpdate"),
        ("/stereo/depth", "foxglove.PointCloud"),
        ("/tf", "foxglove.FrameTransforms"),
    ];
    for (topic, c) in channels {
        match foxglove.iter().find(|(t, _)| t == topic) {
            Some((_, schema)) => {
                assert_eq!(c["schema"], *schema, "{topic}");
                assert_eq!(c["message_encoding"], "protobuf", "{topic}");
                assert_eq!(c["schema_encoding"], "protobuf", "{topic}");
            }
            None => {
                assert_eq!(c["message_encoding"], "json", "{topic}");
                assert_eq!(c["schema_encoding"], "jsonschema", "{topic}");
                assert_eq!(c["schema_is_json"], true, "{topic}");
            }
        }
    }
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

    // The 3D view: the paper's room (a floor and four walls, no obstacles), the true and
    // estimated bodies and both cameras, paths, stereo depths and the FSM state.
    assert_eq!(
        v["scene"],
        serde_json::json!({"room": {"cubes": 5, "cylinders": 0},
                           "obstacles": {"cubes": 0, "cylinders": 0}})
    );
    assert_eq!(
        names("frames"),
        [
            "drone>camera_left",
            "drone>camera_right",
            "world>drone",
            "world>drone_estimate"
        ]
    );
    assert_eq!(n("/scene"), 1);
    assert!((149..=151).contains(&n("/tf")), "25 Hz: {counts:?}");
    assert!(
        (4..=6).contains(&n("/path")),
        "a piece a second: {counts:?}"
    );
    assert_eq!(names("path_entities"), ["path_estimate", "path_true"]);
    assert!(
        v["depth_points"].as_u64().unwrap() > 20,
        "the room's walls are in stereo range: {}",
        v["depth_points"]
    );
    assert!(names("notes").contains(&"state".to_string()));

    layout_matches_the_log(&path);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Every topic and message field `docs/foxglove-layout.json` shows is in a flown log: the
/// shipped layout does not drift from the log it is for.
fn layout_matches_the_log(log: &Path) {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/foxglove-layout.json");
    let layout: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&file).expect("the layout file"))
            .expect("the layout is JSON");
    let panels = layout["configById"].as_object().expect("panels");
    let mut topics = Vec::new();
    let mut fields = Vec::new();
    for panel in panels.values() {
        if let Some(t) = panel["imageMode"]["imageTopic"].as_str() {
            topics.push(t.to_string());
        }
        if let Some(t) = panel["topics"].as_object() {
            topics.extend(t.keys().cloned());
        }
        for p in panel["paths"].as_array().into_iter().flatten() {
            let value = p["value"].as_str().expect("a message path");
            let (topic, field) = value.split_once('.').expect("topic.field");
            topics.push(topic.to_string());
            fields.push((topic.to_string(), field.to_string()));
        }
    }
    assert!(topics.len() > 8 && fields.len() > 8, "{topics:?}");
    let bytes = std::fs::read(log).unwrap();
    let mut seen: BTreeMap<String, serde_json::Value> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let value = if m.channel.message_encoding == "json" {
            serde_json::from_slice(&m.data).unwrap()
        } else {
            serde_json::Value::Null
        };
        seen.entry(m.channel.topic.clone()).or_insert(value);
    }
    for t in &topics {
        assert!(
            seen.contains_key(t),
            "the layout shows {t}, which the log lacks"
        );
    }
    for (topic, field) in &fields {
        assert!(
            seen[topic].get(field).is_some(),
            "the layout plots {topic}.{field}, which {topic}'s records lack: {}",
            seen[topic]
        );
    }
}
