//! `sim-host monitor` against a board on a TCP port: the autopilot's own library produces the
//! telemetry and heartbeats at the real firmware's rates (10 Hz, 1 Hz), framed as on the wire,
//! with one corrupted frame and a silence in the middle. The monitor must show the board's
//! mode and FSM state by name, count the rejected frame, report the silence as a lost link,
//! and leave an MCAP log (the barometer's reading included) that the `mcap` crate's reader
//! reads back with one record per message received, in time order.

use autopilot::app::Autopilot;
use autopilot::AutopilotConfig;
use protocol::{BoardToHost, Heartbeat, Message, Node};
use std::collections::BTreeMap;
use std::io::Write as _;
use std::net::TcpListener;
use std::process::Command;
use std::time::{Duration, Instant};

fn frame(m: &BoardToHost) -> Vec<u8> {
    let mut buf = vec![0u8; BoardToHost::MAX_FRAME_BYTES + 8];
    let n = protocol::encode(m, &mut buf).expect("a board message fits its frame");
    buf.truncate(n);
    buf
}

/// What the board sent.
#[derive(Debug, Default)]
struct Sent {
    telemetry: u64,
    heartbeats: u64,
    corrupted: u64,
}

/// Serves one connection as the autopilot's telemetry port does, for `seconds` of wall time,
/// silent from 1.0 s to 2.0 s; drops a byte of the fifth telemetry frame.
fn board(listener: TcpListener, seconds: f64) -> Sent {
    let (mut s, _) = listener.accept().expect("the monitor connects");
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let baro = autopilot::ms5611::BaroReading {
        pressure_pa: 101_200.0,
        temperature_c: 24.5,
    };
    ap.on_baro(&baro, timebase::Instant::from_micros(0));
    ap.on_battery(3.95, timebase::Instant::from_micros(0));
    let start = Instant::now();
    let mut sent = Sent::default();
    let mut tick = 0u64;
    let mut frames = 0u64;
    loop {
        let t = start.elapsed().as_secs_f64();
        if t >= seconds {
            break;
        }
        let now_us = (t * 1e6) as u64;
        if !(1.0..2.0).contains(&t) {
            if tick.is_multiple_of(10) {
                let hb = Heartbeat::new(Node::Autopilot, (now_us / 1000) as u32);
                if s.write_all(&frame(&BoardToHost::Heartbeat(hb))).is_err() {
                    break;
                }
                sent.heartbeats += 1;
            }
            let mut bytes = frame(&BoardToHost::Telemetry(
                ap.telemetry(timebase::Instant::from_micros(now_us)),
            ));
            frames += 1;
            sent.telemetry += 1;
            if frames == 5 {
                // One byte lost inside the frame: whatever the decoder makes of it (a COBS or a
                // CRC error), it is one rejected frame.
                bytes.remove(bytes.len() / 2);
                sent.corrupted += 1;
                sent.telemetry -= 1;
            }
            if s.write_all(&bytes).is_err() {
                break;
            }
        }
        tick += 1;
        std::thread::sleep(Duration::from_millis(100));
    }
    sent
}

/// The 3D view's channels (Foxglove's types, protobuf).
const VIEW_3D: [&str; 4] = ["/tf", "/camera/frustum", "/annotations", "/path"];

#[test]
fn monitor_shows_a_board_and_records_what_it_received() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let server = std::thread::spawn(move || board(listener, 3.0));
    let dir = std::env::temp_dir().join(format!("monitor-test-{}", std::process::id()));
    let mcap = dir.join("monitor.mcap");
    let out = Command::new(env!("CARGO_BIN_EXE_sim-host"))
        .args(["monitor", "--port", &format!("tcp:127.0.0.1:{port}")])
        .args(["--duration", "5", "--plain", "--mcap"])
        .arg(&mcap)
        .output()
        .expect("sim-host runs");
    let sent = server.join().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The board closed the connection after 3 s: the monitor ends there, not at --duration.
    assert!(
        stdout.contains("monitor ended (the link closed)"),
        "{stdout}"
    );
    assert!(stdout.contains("disarmed fsm inactive"), "{stdout}");
    assert!(stdout.contains("LINK LOST"), "the 1 s silence: {stdout}");
    assert!(
        stdout.contains(&format!(
            "{} telemetry, {} heartbeats",
            sent.telemetry, sent.heartbeats
        )),
        "sent {sent:?}: {stdout}"
    );
    assert!(stdout.contains("host-link errors 1 ("), "{stdout}");

    let bytes = std::fs::read(&mcap).expect("the monitor leaves its log");
    let mut counts = BTreeMap::<String, u64>::new();
    let mut last = 0u64;
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("a readable message");
        assert!(m.log_time >= last, "time order");
        last = m.log_time;
        *counts.entry(m.channel.topic.clone()).or_default() += 1;
        if VIEW_3D.contains(&m.channel.topic.as_str()) {
            assert_eq!(
                m.channel.message_encoding, "protobuf",
                "{}",
                m.channel.topic
            );
            continue;
        }
        assert_eq!(m.channel.message_encoding, "json");
        let value: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        if m.channel.topic == "/state" {
            assert_eq!(value["mode"], "disarmed");
        }
        if m.channel.topic == "/baro" {
            assert_eq!(value["pressure_pa"], 101_200.0);
        }
        if m.channel.topic == "/link" {
            assert!(value["host_link_errors"]["total"].as_u64().unwrap() <= 1);
        }
        if m.channel.topic == "/battery" {
            assert_eq!(value["voltage_v"], 3.95);
            assert_eq!(value["state"], "ok");
        }
    }
    // The 3D view of what the board believes: its pose at each telemetry, the camera.
    assert_eq!(counts.get("/tf"), Some(&sent.telemetry), "{counts:?}");
    assert_eq!(counts.get("/camera/frustum"), Some(&1), "{counts:?}");
    assert_eq!(
        counts.get("/scene"),
        None,
        "a real board's room is not known"
    );
    for topic in [
        "/state",
        "/attitude",
        "/velocity",
        "/height",
        "/baro",
        "/battery",
        "/link",
        "/link_auth",
        "/board_clock",
    ] {
        assert_eq!(
            counts.get(topic),
            Some(&sent.telemetry),
            "{topic}: {counts:?}"
        );
    }
    assert_eq!(
        counts.get("/heartbeat"),
        Some(&sent.heartbeats),
        "{counts:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
