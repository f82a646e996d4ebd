//! Ctrl-C (SIGINT) sent to a running `sim-host fly` and `sim-host monitor`: each stops, finishes
//! its MCAP file (summary and footer, every message readable by the `mcap` crate) and, for `fly`,
//! writes the CSV of the flight so far with a whole last line, and exits successfully.

use protocol::{BoardToHost, Heartbeat, Message, Node};
use std::io::Write as _;
use std::net::TcpListener;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Waits until `path` exists (the command is running and past its set-up), then a little more.
fn wait_for(path: &Path, child: &mut Child) {
    let start = Instant::now();
    while !path.exists() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "sim-host ended before writing {}",
            path.display()
        );
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no {}",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(1500));
}

/// Sends SIGINT, as a terminal's Ctrl-C does, and collects the output.
fn interrupt(child: Child) -> Output {
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success());
    let start = Instant::now();
    let mut child = child;
    while child.try_wait().unwrap().is_none() {
        assert!(
            start.elapsed() < Duration::from_secs(300),
            "sim-host did not end after Ctrl-C"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    child.wait_with_output().unwrap()
}

/// The file has the summary section and footer of a finished MCAP file, and every message
/// reads; returns the messages' topics.
fn finished_mcap(path: &Path) -> Vec<String> {
    let bytes = std::fs::read(path).expect("the MCAP file");
    let summary = mcap::Summary::read(&bytes).expect("a finished MCAP file");
    assert!(
        summary.is_some_and(|s| !s.channels.is_empty()),
        "a summary with channels"
    );
    mcap::MessageStream::new(&bytes)
        .expect("an MCAP file")
        .map(|m| m.expect("a whole message").channel.topic.clone())
        .collect()
}

#[test]
fn ctrl_c_during_fly_leaves_a_finished_mcap_and_a_whole_csv() {
    let dir = std::env::temp_dir().join(format!("fly-interrupt-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut child = Command::new(env!("CARGO_BIN_EXE_sim-host"))
        .args([
            "fly",
            "--duration",
            "300",
            "--seed",
            "3",
            "--quiet",
            "--out",
        ])
        .arg(&dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("sim-host runs");
    wait_for(&dir.join("flight.mcap"), &mut child);
    let out = interrupt(child);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("interrupted at"), "{stderr}");

    let csv = std::fs::read_to_string(dir.join("log.csv")).expect("the CSV");
    assert!(csv.ends_with('\n'), "the last line is whole");
    let mut lines = csv.lines();
    let columns = lines.next().expect("a header").split(',').count();
    let rows: Vec<&str> = lines.collect();
    assert!(!rows.is_empty(), "rows of the flight so far");
    let last = rows.last().unwrap();
    assert_eq!(last.split(',').count(), columns, "{last}");
    let t: f64 = last.split(',').next().unwrap().parse().unwrap();
    assert!(t < 300.0, "stopped before the end: {t}");
    let topics = finished_mcap(&dir.join("flight.mcap"));
    assert!(topics.iter().any(|t| t == "/truth"), "{topics:?}");
    println!("fly: Ctrl-C at {t:.2} s of flight, {} CSV rows", rows.len());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ctrl_c_during_monitor_leaves_a_finished_mcap() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    // A board that sends its heartbeat every 100 ms until the monitor goes away.
    let board = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().expect("the monitor connects");
        let start = Instant::now();
        let mut sent = 0u32;
        loop {
            let ms = start.elapsed().as_millis() as u32;
            let hb = BoardToHost::Heartbeat(Heartbeat::new(Node::Autopilot, ms));
            let mut buf = vec![0u8; BoardToHost::MAX_FRAME_BYTES + 8];
            let n = protocol::encode(&hb, &mut buf).unwrap();
            if s.write_all(&buf[..n]).is_err() || start.elapsed() > Duration::from_secs(120) {
                return sent;
            }
            sent += 1;
            std::thread::sleep(Duration::from_millis(100));
        }
    });
    let dir = std::env::temp_dir().join(format!("monitor-interrupt-{}", std::process::id()));
    let mcap = dir.join("monitor.mcap");
    let mut child = Command::new(env!("CARGO_BIN_EXE_sim-host"))
        .args(["monitor", "--port", &format!("tcp:127.0.0.1:{port}")])
        .args(["--duration", "100", "--plain", "--mcap"])
        .arg(&mcap)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("sim-host runs");
    wait_for(&mcap, &mut child);
    let out = interrupt(child);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("monitor ended (interrupted)"), "{stdout}");
    let sent = board.join().unwrap();
    let topics = finished_mcap(&mcap);
    let logged = topics.iter().filter(|t| *t == "/heartbeat").count();
    assert!(logged > 0 && logged <= sent as usize, "{logged} of {sent}");
    println!("monitor: Ctrl-C after {sent} heartbeats sent, {logged} logged");
    let _ = std::fs::remove_dir_all(&dir);
}
