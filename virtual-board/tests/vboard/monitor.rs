//! `sim-host monitor` against the virtual autopilot: the real image's telemetry UART served on
//! TCP ([`virtual_board::serve::TcpBridge`]) at the board's own pace, read by the ground tool
//! users run against a real board. Everything the firmware sent must reach the monitor, decode
//! without one rejected frame, and show the board's state by name; the MCAP log, read back by
//! the `mcap` crate's reader, must hold it: one record per message on each channel, in time
//! order, the flight mode and FSM state by name.
//!
//! The monitor binary is `VBOARD_SIM_HOST` (set by `cargo xtask vboard`, which builds it), else
//! the main workspace's `target/debug/sim-host`.

use std::net::TcpListener;
use std::path::PathBuf;
use std::process::Command;

use protocol::BoardToHost;
use virtual_board::bench::{Options, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::host;
use virtual_board::serve::TcpBridge;

fn sim_host() -> PathBuf {
    let path = std::env::var_os("VBOARD_SIM_HOST").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/debug/sim-host"),
        PathBuf::from,
    );
    assert!(
        path.is_file(),
        "{} is missing: build it (`cargo build -p sim-host`) or run `cargo xtask vboard`",
        path.display()
    );
    path
}

#[test]
fn the_monitor_shows_and_records_the_virtual_autopilots_telemetry() {
    let sim_host = sim_host();
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let listener = TcpListener::bind("127.0.0.1:0").expect("a local port");
    let port = listener.local_addr().unwrap().port();
    let mcap = std::env::temp_dir().join(format!("vboard-monitor-{}.mcap", std::process::id()));
    let monitor = Command::new(&sim_host)
        .args(["monitor", "--port", &format!("tcp:127.0.0.1:{port}")])
        .args(["--plain", "--duration", "120", "--mcap"])
        .arg(&mcap)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("sim-host monitor starts");

    let bridge = TcpBridge::accept(&listener, |b: &mut Autopilot| &mut b.telemetry, Some(1.0))
        .expect("the monitor connects");
    let outcome = run(
        Setup {
            board: Autopilot::new(3).expect("the board"),
            firmware,
            probe: bridge,
        },
        Options::seconds(3.0),
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    assert_eq!(
        outcome.probe.ended, None,
        "the bridge ended early\n{report}"
    );
    let sent = outcome.board().telemetry.tx.sent_bytes();
    assert_eq!(
        outcome.probe.bytes_out,
        sent.len() as u64,
        "every byte crossed"
    );
    let (messages, errors) = host::decode_board_to_host(&sent);
    assert_eq!(errors, 0, "the firmware's own frames decode\n{report}");
    let count = |f: fn(&BoardToHost) -> bool| messages.iter().filter(|m| f(m)).count();
    let telemetry = count(|m| matches!(m, BoardToHost::Telemetry(_)));
    let heartbeats = count(|m| matches!(m, BoardToHost::Heartbeat(_)));
    // Telemetry carries the MS5611's last reading once the firmware has read one (its first
    // conversions take about 20 ms after boot).
    let with_baro = count(|m| matches!(m, BoardToHost::Telemetry(t) if t.baro.is_some()));
    assert!(
        with_baro + 1 >= telemetry,
        "{with_baro} of {telemetry} telemetry messages carry a barometer reading\n{report}"
    );
    // ... and the supply voltage the real image reads at the telemetry's rate.
    let with_battery = count(|m| matches!(m, BoardToHost::Telemetry(t) if t.battery.is_some()));
    assert_eq!(
        with_battery, telemetry,
        "{with_battery} of {telemetry} telemetry messages carry the battery\n{report}"
    );
    assert!(
        telemetry >= 20,
        "10 Hz telemetry over 3 s: {telemetry}\n{report}"
    );
    drop(outcome); // closes the connection: the monitor ends

    let out = monitor.wait_with_output().expect("the monitor ends");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("monitor ended (the link closed)"),
        "{stdout}"
    );
    assert!(
        stdout.contains(&format!(
            "{} B, {telemetry} telemetry, {heartbeats} heartbeats",
            sent.len()
        )),
        "the firmware sent {} B, {telemetry} telemetry, {heartbeats} heartbeats:\n{stdout}",
        sent.len()
    );
    assert!(stdout.contains("host-link errors 0\n"), "{stdout}");
    assert!(stdout.contains("disarmed fsm inactive"), "{stdout}");
    assert!(!stdout.contains("rejected"), "{stdout}");
    // The log read back by the `mcap` crate's reader: every channel with one record per
    // message received, in time order, the board's state by name.
    let bytes = std::fs::read(&mcap).expect("the monitor leaves its log");
    let _ = std::fs::remove_file(&mcap);
    let mut counts = std::collections::BTreeMap::<String, usize>::new();
    let mut last = 0u64;
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("a readable message");
        assert!(
            m.log_time >= last,
            "time order: {} after {last}",
            m.log_time
        );
        last = m.log_time;
        *counts.entry(m.channel.topic.clone()).or_default() += 1;
        if ["/tf", "/camera/frustum", "/annotations", "/path"].contains(&m.channel.topic.as_str()) {
            // The 3D view of what the board believes: Foxglove's types in protobuf.
            assert_eq!(
                m.channel.message_encoding, "protobuf",
                "{}",
                m.channel.topic
            );
            continue;
        }
        assert_eq!(m.channel.message_encoding, "json");
        let value: serde_json::Value = serde_json::from_slice(&m.data).expect("JSON");
        if m.channel.topic == "/baro" {
            // The bench's room: sea-level pressure, 1.5 m ± the model's noise and drift.
            let p = value["pressure_pa"].as_f64().expect("a pressure");
            assert!((100_000.0..102_500.0).contains(&p), "{value}");
        }
        if m.channel.topic == "/battery" {
            // The bench's battery through the divider, to the ADC's 4.5 mV count.
            let v = value["voltage_v"].as_f64().expect("a voltage");
            let want = virtual_board::boards::autopilot::BATTERY_V;
            assert!((v - want).abs() < 0.01, "{value}");
        }
        if m.channel.topic == "/state" {
            assert_eq!(value["mode"], "disarmed", "{value}");
            assert_eq!(value["fsm_state"], "inactive", "{value}");
        }
    }
    assert_eq!(
        counts.get("/tf"),
        Some(&telemetry),
        "a pose per telemetry: {counts:?}"
    );
    assert_eq!(counts.get("/camera/frustum"), Some(&1), "{counts:?}");
    // Five records per telemetry message (state, attitude, setpoint, velocity, height) plus
    // its link, board-clock and link-authentication records, one more where it has a barometer reading, one more
    // where it has a battery reading, and one per heartbeat; then the 3D view (a pose per
    // telemetry, the frustum, and annotations and path pieces on the wall clock's rates).
    let view_3d: usize = ["/tf", "/camera/frustum", "/annotations", "/path"]
        .iter()
        .filter_map(|t| counts.get(*t))
        .sum();
    let logged = 8 * telemetry + with_baro + with_battery + heartbeats + view_3d;
    assert!(
        stdout.contains(&format!("({logged} messages on")),
        "{logged} records expected in the log:\n{stdout}"
    );
    for topic in [
        "/state",
        "/attitude",
        "/setpoint",
        "/velocity",
        "/height",
        "/link",
        "/board_clock",
    ] {
        assert_eq!(counts.get(topic), Some(&telemetry), "{topic}: {counts:?}");
    }
    assert_eq!(counts.get("/heartbeat"), Some(&heartbeats), "{counts:?}");
    assert_eq!(counts.get("/baro"), Some(&with_baro), "{counts:?}");
    assert_eq!(counts.get("/battery"), Some(&with_battery), "{counts:?}");
    println!(
        "monitor against the virtual autopilot: {telemetry} telemetry, {heartbeats} heartbeats, {} B",
        sent.len()
    );
}
