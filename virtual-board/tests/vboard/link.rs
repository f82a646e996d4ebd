//! Test 4a: both unmodified `real` images together, their link UARTs (camera board UART4,
//! autopilot USART2) joined byte for byte at the baud each firmware configures, for 10 s of
//! virtual time: zero decode errors on either side, and the autopilot hears the camera board's
//! estimates and its heartbeat (whose protocol version it checks).
//!
//! Three witnesses of "zero errors": the bench's own decoders on every byte each board put on the
//! wire, the wire (no word garbled by a baud mismatch, none lost), and the counters each firmware
//! reports in its status log line.
//!
//! Test 5 (camera side, both boards joined): the camera stops (no VSYNC); the camera board
//! reports it in its status over the link within the time it promises, and sends no more
//! estimates.

use std::path::PathBuf;
use std::sync::Arc;

use protocol::{AutopilotToStereo, Decoder, Message, StereoToAutopilot};
use virtual_board::bench::{At, Closure, Flow, OnBarrier, Options, Setup, Watching, run_pair};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::boards::camera::CameraBoard;
use virtual_board::firmware::Firmware;
use virtual_board::frames::Recorded;
use virtual_board::link;

/// The link's configured baud (`board_support::link::LINK_BAUD`, which both firmwares take).
const LINK_BAUD: u32 = 115_200;

/// Virtual time the two boards run, s.
const SECONDS: f64 = 10.0;

/// The recorded take the test plays (see [`virtual_board::frames::data_set_take_1`]).
fn take() -> PathBuf {
    virtual_board::frames::data_set_take_1()
}

/// Every message in `bytes` (a capture from the line's start) and the decoder's error count.
fn decode<M: Message>(bytes: &[u8]) -> (Vec<M>, u32) {
    let mut decoder: Decoder<M, 256> = Decoder::new_mid_stream();
    let mut out = Vec::new();
    decoder.feed(bytes, |m| out.push(m));
    (out, decoder.errors().total())
}

#[test]
fn the_joined_link_runs_ten_seconds_without_a_decode_error() {
    let recorded = Recorded::from_take(&take(), 120).expect("the data set's take 1");
    let (camera_end, autopilot_end) = link::join();
    let camera = CameraBoard::with_link(Box::new(recorded), camera_end.clone()).expect("board");
    let autopilot = Autopilot::with_link(1, autopilot_end.clone()).expect("board");
    let camera_rx: Arc<dyn OnBarrier> = Arc::new(camera_end.rx.clone());
    let autopilot_rx: Arc<dyn OnBarrier> = Arc::new(autopilot_end.rx.clone());
    let (cam, ap) = run_pair(
        Setup {
            board: camera,
            firmware: Firmware::real("stereo-board").expect("the camera-board image"),
            probe: Watching,
        },
        Setup {
            board: autopilot,
            firmware: Firmware::real("autopilot").expect("the autopilot image"),
            probe: Watching,
        },
        Options::seconds(SECONDS),
        vec![camera_rx],
        vec![autopilot_rx],
    )
    .expect("the run");
    let report = || format!("{}\n{}", cam.report(), ap.report());
    cam.assert_clean();
    ap.assert_clean();
    assert!(
        cam.end_ns >= (SECONDS * 1e9) as u64 && ap.end_ns >= (SECONDS * 1e9) as u64,
        "both boards ran the whole time\n{}",
        report()
    );

    // The wire: each end at the configured baud (to the UART's divider rounding, well inside
    // the receivers' tolerance), nothing garbled or lost.
    for (name, line) in [("camera", &camera_end.tx), ("autopilot", &autopilot_end.tx)] {
        let (sender, receiver) = line.bauds();
        for baud in [sender, receiver] {
            let baud = f64::from(baud.unwrap_or(0));
            assert!(
                (baud - f64::from(LINK_BAUD)).abs() / f64::from(LINK_BAUD) < 0.01,
                "{name}'s line: sender {sender:?}, receiver {receiver:?} Bd, configured {LINK_BAUD}"
            );
        }
    }
    for (name, line) in [("camera", &camera_end.tx), ("autopilot", &autopilot_end.tx)] {
        assert_eq!(line.garbled(), 0, "{name}'s words garbled\n{}", report());
        assert_eq!(line.lost(), 0, "{name}'s words lost\n{}", report());
    }

    // The bench's decoders on every byte.
    let (to_autopilot, errors) = decode::<StereoToAutopilot>(&camera_end.tx.sent_bytes());
    assert_eq!(errors, 0, "camera -> autopilot decode errors\n{}", report());
    let estimates = to_autopilot
        .iter()
        .filter(|m| matches!(m, StereoToAutopilot::Estimate(_)))
        .count();
    let heartbeats = to_autopilot
        .iter()
        .filter(|m| matches!(m, StereoToAutopilot::Heartbeat(_)))
        .count();
    // 24.65 frames a second once the cameras stream (about 50 ms after boot).
    assert!(
        estimates >= 230,
        "{estimates} estimates in {SECONDS} s\n{}",
        report()
    );
    assert!(
        heartbeats >= 9,
        "{heartbeats} camera heartbeats\n{}",
        report()
    );
    let (to_camera, errors) = decode::<AutopilotToStereo>(&autopilot_end.tx.sent_bytes());
    assert_eq!(errors, 0, "autopilot -> camera decode errors\n{}", report());
    assert!(!to_camera.is_empty(), "the autopilot talks to the camera");

    // The firmwares' own counters.
    let field = |outcome: &dyn Fn(&str) -> Option<u64>, key: &str| {
        outcome(key).unwrap_or_else(|| panic!("no {key} in the status line\n{}", report()))
    };
    let ap_status = |key: &str| ap.log.status(key);
    let cam_status = |key: &str| cam.log.status(key);
    assert_eq!(
        field(&ap_status, "link_errors"),
        0,
        "autopilot's link errors\n{}",
        report()
    );
    assert_eq!(field(&ap_status, "version_mismatch"), 0, "{}", report());
    // Every byte the camera board sent after the autopilot's receivers were served arrived
    // (what came during its boot, before `init` ended, is discarded and not counted).
    assert_eq!(
        field(&ap_status, "rx_lost"),
        0,
        "autopilot's received bytes lost\n{}",
        report()
    );
    assert!(
        field(&ap_status, "estimates") >= 200,
        "the autopilot counts the camera's estimates\n{}",
        report()
    );
    assert!(
        field(&ap_status, "stereo_uptime_ms") < u64::from(u32::MAX),
        "the autopilot heard the camera board's heartbeat\n{}",
        report()
    );
    assert_eq!(
        field(&cam_status, "link_errors"),
        0,
        "camera's link errors\n{}",
        report()
    );
    assert_eq!(field(&cam_status, "rx_lost"), 0, "{}", report());
    assert_eq!(field(&cam_status, "link_tx_dropped"), 0, "{}", report());
    assert_eq!(
        field(&cam_status, "dropped"),
        0,
        "camera frames dropped\n{}",
        report()
    );
    assert!(
        field(&cam_status, "link_rx_ok") > 0,
        "the camera board decodes the autopilot's messages\n{}",
        report()
    );
    println!(
        "{SECONDS} s joined: {estimates} estimates, {} autopilot messages, {:.1} s wall",
        to_camera.len(),
        cam.wall_s
    );
}

/// Every message in the bytes `line` carried, with the instant its last byte was sent, ns.
fn decode_timed<M: Message>(line: &link::Line) -> (Vec<(u64, M)>, u32) {
    let mut decoder: Decoder<M, 256> = Decoder::new_mid_stream();
    let mut out = Vec::new();
    for (at, word) in line.sent() {
        decoder.feed(&[(word & 0xFF) as u8], |m| out.push((at, m)));
    }
    (out, decoder.errors().total())
}

#[test]
fn a_stopped_camera_is_reported_over_the_link() {
    const MS: u64 = 1_000_000;
    const STOP_AT: u64 = 2_000 * MS;
    // The camera board's promise: stopped after 5 frame periods without a VSYNC (202.8 ms),
    // reported at its next 1 Hz status; 50 ms of slack for the status line's transmission.
    const REPORTED_BY: u64 = STOP_AT + 203 * MS + 1_000 * MS + 50 * MS;
    let recorded = Recorded::from_take(&take(), 60).expect("the data set's take 1");
    let (camera_end, autopilot_end) = link::join();
    let camera = CameraBoard::with_link(Box::new(recorded), camera_end.clone()).expect("board");
    let autopilot = Autopilot::with_link(1, autopilot_end.clone()).expect("board");
    let camera_rx: Arc<dyn OnBarrier> = Arc::new(camera_end.rx.clone());
    let autopilot_rx: Arc<dyn OnBarrier> = Arc::new(autopilot_end.rx.clone());
    // A stop lands at the first instruction boundary at or after the instant asked for.
    let mut stopped = false;
    let stop = Closure(move |at: &mut At<'_, CameraBoard>| {
        if !stopped && at.now >= STOP_AT {
            at.board().stop_camera();
            stopped = true;
        }
        Flow::Continue
    });
    let (cam, ap) = run_pair(
        Setup {
            board: camera,
            firmware: Firmware::real("stereo-board").expect("the camera-board image"),
            probe: stop,
        },
        Setup {
            board: autopilot,
            firmware: Firmware::real("autopilot").expect("the autopilot image"),
            probe: Watching,
        },
        Options::seconds(3.5),
        vec![camera_rx],
        vec![autopilot_rx],
    )
    .expect("the run");
    let report = || format!("{}\n{}", cam.report(), ap.report());
    cam.assert_clean();
    ap.assert_clean();
    let (messages, errors) = decode_timed::<StereoToAutopilot>(&camera_end.tx);
    assert_eq!(errors, 0, "camera -> autopilot decode errors\n{}", report());
    let statuses: Vec<(u64, bool)> = messages
        .iter()
        .filter_map(|(at, m)| match m {
            StereoToAutopilot::Status(s) => Some((*at, s.camera_stopped)),
            _ => None,
        })
        .collect();
    assert!(
        statuses
            .iter()
            .filter(|(at, _)| *at < STOP_AT)
            .all(|(_, stopped)| !stopped),
        "no camera stop reported while it ran: {statuses:?}"
    );
    let reported = statuses
        .iter()
        .find(|(_, stopped)| *stopped)
        .map(|(at, _)| *at);
    assert!(
        reported.is_some_and(|at| at > STOP_AT && at <= REPORTED_BY),
        "camera_stopped reported at {reported:?} ns (stopped at {STOP_AT}, promised by \
         {REPORTED_BY}): {statuses:?}\n{}",
        report()
    );
    let before = messages
        .iter()
        .filter(|(at, m)| *at < STOP_AT && matches!(m, StereoToAutopilot::Estimate(_)))
        .count();
    // A frame being processed when the camera stopped may still go out (Edge-FS takes a few ms).
    let late = messages
        .iter()
        .filter(|(at, m)| *at > STOP_AT + 50 * MS && matches!(m, StereoToAutopilot::Estimate(_)))
        .count();
    assert!(
        before >= 40,
        "{before} estimates while the camera ran\n{}",
        report()
    );
    assert_eq!(late, 0, "estimates after the camera stopped\n{}", report());
    assert_eq!(
        ap.log.status("link_errors"),
        Some(0),
        "the autopilot decodes the link cleanly throughout\n{}",
        report()
    );
}
