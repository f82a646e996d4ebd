//! `sim-host param` against the virtual autopilot: the real image's telemetry UART served on
//! TCP ([`virtual_board::serve::TcpBridge`]), the ground tool run as a user runs it against a
//! board on a serial port. The firmware lists its whole table, takes a value within bounds
//! (answering with the value now in use) and refuses one outside them, and every frame it sent
//! decodes. With both images joined on their link, `--board camera` reaches the camera-board
//! firmware through the autopilot.
//!
//! The tool is `VBOARD_SIM_HOST` (set by `cargo xtask vboard`, which builds it), else the main
//! workspace's `target/debug/sim-host`.

use std::net::TcpListener;
use std::path::PathBuf;
use std::process::Command;

use autopilot::params::TABLE;
use protocol::{BoardToHost, ParamReply};
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

/// Boots the autopilot image, runs `sim-host param --port tcp:... ARGS` against its telemetry
/// UART until the tool disconnects; returns whether it succeeded, its output, and the
/// parameter answers the firmware sent.
fn param(args: &[&str]) -> (bool, String, Vec<ParamReply>) {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let listener = TcpListener::bind("127.0.0.1:0").expect("a local port");
    let port = listener.local_addr().unwrap().port();
    let tool = Command::new(sim_host())
        .args(["param", "--port", &format!("tcp:127.0.0.1:{port}")])
        .args(["--timeout", "5"])
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("sim-host param starts");
    let bridge = TcpBridge::accept(&listener, |b: &mut Autopilot| &mut b.telemetry, Some(1.0))
        .expect("the tool connects");
    let outcome = run(
        Setup {
            board: Autopilot::new(3).expect("the board"),
            firmware,
            probe: bridge,
        },
        Options::seconds(60.0),
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    let sent = outcome.board().telemetry.tx.sent_bytes();
    let (messages, errors) = host::decode_board_to_host(&sent);
    assert_eq!(errors, 0, "the firmware's own frames decode\n{report}");
    assert_eq!(
        outcome.probe.ended.as_deref(),
        Some("the client disconnected"),
        "the tool ended the run\n{report}"
    );
    drop(outcome);
    let out = tool.wait_with_output().expect("the tool ends");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let replies = messages
        .into_iter()
        .filter_map(|m| match m {
            BoardToHost::Param(r) => Some(r.reply),
            _ => None,
        })
        .collect();
    (out.status.success(), text, replies)
}

#[test]
fn the_virtual_autopilot_lists_its_parameters() {
    let (ok, out, replies) = param(&["list"]);
    assert!(ok, "{out}");
    assert_eq!(out.lines().count(), TABLE.len(), "{out}");
    for (line, spec) in out.lines().zip(TABLE) {
        assert!(
            line.contains(&format!(" {} ", spec.name)),
            "{line} / {}",
            spec.name
        );
    }
    // One answer per entry (more only if a request was retried).
    assert!(replies.len() >= TABLE.len(), "{} answers", replies.len());
    println!(
        "param list against the virtual autopilot: {} entries",
        TABLE.len()
    );
}

#[test]
fn the_virtual_autopilot_takes_a_value_in_bounds_and_refuses_one_outside() {
    let (ok, out, replies) = param(&["set", "target_height", "0.8"]);
    assert!(ok, "{out}");
    assert!(
        out.contains("target_height") && out.contains(" 0.8 "),
        "{out}"
    );
    assert!(
        replies.iter().any(|r| matches!(r, ParamReply::Entry(e)
            if e.name == "target_height" && e.value == protocol::ParamValue::F32(0.8))),
        "{replies:?}"
    );
    let (ok, out, _) = param(&["set", "target_height", "9"]);
    assert!(!ok, "{out}");
    assert!(out.contains("outside [0.2 ..= 3]"), "{out}");
}

/// `sim-host param --board camera` against both real images joined on their link: the
/// autopilot passes the request on over the board-to-board UART, the camera-board firmware
/// answers, and the answer comes back on the telemetry port.
#[test]
fn the_virtual_camera_board_takes_a_parameter_through_the_autopilot() {
    use protocol::{Decoder, ParamValue, StereoToAutopilot};
    use std::sync::Arc;
    use virtual_board::bench::{OnBarrier, Watching, run_pair};
    use virtual_board::boards::camera::CameraBoard;
    use virtual_board::frames::Recorded;

    let recorded = Recorded::from_take(&virtual_board::frames::data_set_take_1(), 40)
        .expect("the data set's take 1");
    let (camera_end, autopilot_end) = virtual_board::link::join();
    let camera = CameraBoard::with_link(Box::new(recorded), camera_end.clone()).expect("board");
    let autopilot = Autopilot::with_link(1, autopilot_end.clone()).expect("board");
    let camera_rx: Arc<dyn OnBarrier> = Arc::new(camera_end.rx.clone());
    let autopilot_rx: Arc<dyn OnBarrier> = Arc::new(autopilot_end.rx.clone());

    let listener = TcpListener::bind("127.0.0.1:0").expect("a local port");
    let port = listener.local_addr().unwrap().port();
    let tool = Command::new(sim_host())
        .args(["param", "--port", &format!("tcp:127.0.0.1:{port}")])
        .args(["--timeout", "5", "--board", "camera"])
        .args(["set", "stereo_shift", "-4"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("sim-host param starts");
    let bridge = TcpBridge::accept(&listener, |b: &mut Autopilot| &mut b.telemetry, Some(1.0))
        .expect("the tool connects");
    let (cam, ap) = run_pair(
        Setup {
            board: camera,
            firmware: Firmware::real("stereo-board").expect("the camera-board image"),
            probe: Watching,
        },
        Setup {
            board: autopilot,
            firmware: Firmware::real("autopilot").expect("the autopilot image"),
            probe: bridge,
        },
        Options::seconds(8.0),
        vec![camera_rx],
        vec![autopilot_rx],
    )
    .expect("the run");
    let report = format!("{}\n{}", cam.report(), ap.report());
    cam.assert_clean();
    ap.assert_clean();
    assert_eq!(
        ap.probe.ended.as_deref(),
        Some("the client disconnected"),
        "the tool ended the run\n{report}"
    );
    let out = tool.wait_with_output().expect("the tool ends");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{text}\n{report}");
    assert!(
        text.contains("stereo_shift") && text.contains(" -4 "),
        "{text}"
    );
    // The camera-board firmware itself answered on the link, with the value now in use.
    let mut decoder: Decoder<StereoToAutopilot, 256> = Decoder::new_mid_stream();
    let mut answers = Vec::new();
    decoder.feed(&camera_end.tx.sent_bytes(), |m| {
        if let StereoToAutopilot::Param(r) = m {
            answers.push(r.reply);
        }
    });
    assert_eq!(decoder.errors().total(), 0, "{report}");
    assert!(
        answers.iter().any(|r| matches!(r, ParamReply::Entry(e)
            if e.name == "stereo_shift" && e.value == ParamValue::I32(-4))),
        "{answers:?}"
    );
    // And the autopilot passed it back to the tool.
    let (messages, errors) = host::decode_board_to_host(&ap.board().telemetry.tx.sent_bytes());
    assert_eq!(errors, 0, "{report}");
    let camera_answers = messages
        .iter()
        .filter(|m| matches!(m, BoardToHost::Param(r) if r.board == protocol::Node::StereoBoard))
        .count();
    assert!(camera_answers >= 2, "get then set: {camera_answers}");
    println!(
        "camera param through the autopilot on the bench: {} link answers, wall {:.1} s",
        answers.len(),
        ap.wall_s
    );
}
