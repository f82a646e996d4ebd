//! `sim-host hil` flies both `hil`-flavour images on the virtual boards, through the same
//! lockstep contract it keeps with two boards on serial ports (`sim_host::hil`, in this process):
//! each board's host UART is served on a loopback socket ([`serve::hil`], what `vboard serve
//! hil` runs), the boards' link UARTs are joined byte for byte as in the drone, and the host
//! streams rendered frames to the camera board, IMU samples and height fixes to the autopilot,
//! and flies the simulated drone on the autopilot's motor commands.
//!
//! A short closed-loop flight in the paper's 4 x 4 m room, world seed [`SEED`] (the bench's IMU
//! noise seed is 1; the hil image does not read its IMU): [`SIM_S`] of world time, armed at
//! [`ARM_AT_S`] (as a user arms: once the camera board's estimates are valid; at [`FPS`] its flow
//! history of 9 frames fills by 2.35 s, the autopilot counts estimates from the third valid one
//! in a row, at 2.85 s, and its failsafe lands an armed drone that has seen none 0.5 s after
//! arming), climb at 0.5 m/s to the autopilot's 1 m target, then its avoidance flight (forward
//! at 0.3 m/s).
//!
//! The camera rate: a frame is 25.2 kB framed, 0.27 s of the host UART at 921,600 Bd
//! (`board_support::link::HOST_BAUD`), and the bench times every word at that baud. The
//! autopilot's lockstep costs about 1 ms of virtual time per 1.95 ms IMU period (the sample and
//! its reply on the wire, within one bench quantum), so the frames set the pace: the world waits
//! at each exposure time for the previous frame's estimate. [`FPS`] = 4 takes 1.09 s of the link
//! per world second; it is the lowest rate at which one invalid estimate (a gap of two frame
//! periods, 0.5 s) stays within the autopilot's 0.5 s estimate timeout (at 3 fps a single one
//! sends the drone into its no-estimate hover), and each frame more costs 0.27 s of virtual
//! time. Measured (2-core machine, shared): 8.5 s of world time in 9.4 s of virtual time and
//! 12 s of wall time, max height 1.07 m, drift 1.27 m (the avoidance flight's forward leg), 24
//! of 33 estimates valid (the other 9 while the flow history filled), stack never touched:
//! 50,152 B on the camera board, 110,416 B on the autopilot.
//!
//! Passes when: every IMU sample got its `Motors` reply; every frame its estimate; at least
//! [`MIN_VALID`] estimates were valid; no decoding error on any link (the host's decoders on
//! both host links, the bench's on both directions of the board-to-board link, which carried
//! the estimates one way and the 128 Hz gyro samples the other, nothing garbled or lost on it,
//! the boards' own counters); the drone climbed to 0.8..=1.4 m, was airborne for at least
//! [`SIM_S`] - [`ARM_AT_S`] - 1.5 s and from 2.5 s after arming on stayed within 0.6..=1.4 m; no
//! collision and at most 1.6 m horizontal drift from the start; the autopilot still flying (or
//! hovering without estimates) at the end; neither board faulted, reset, reached what its part
//! lacks or lost a received byte; each board kept at least [`MIN_STACK_FREE`] bytes of stack
//! never touched (`stack_free` of its last status line: `board_support::stack` paints the stack
//! at boot, and this flight, both boards in closed loop, is the deepest realistic use); both
//! host UARTs at 921,600 Bd; and each image configured only pins of its board's wiring, as that
//! wiring gives them.

use std::net::{Shutdown, TcpListener, TcpStream};
use std::time::Instant;

use protocol::{AutopilotToStereo, Decoder, FlightMode, Message, StereoToAutopilot};
use sim_host::hil::{HilConfig, HilResult};
use virtual_board::bench::Options;
use virtual_board::boards::{autopilot, camera};
use virtual_board::pins::{self, Wired};
use virtual_board::serve::{self, HilOutcome, TcpBridge};
use virtual_board::world::FlightConfig;

/// The world's seed (textures, sensor noise).
const SEED: u64 = 3;
/// World time flown, s.
const SIM_S: f64 = 8.5;
/// World time of the arm command, s: once the autopilot counts the camera board's estimates.
const ARM_AT_S: f64 = 3.0;
/// Camera frames per second of world time (see the module docs).
const FPS: f64 = 4.0;
/// Valid estimates at least: 20 of the 24 frames after the flow history filled (9 frames).
const MIN_VALID: u64 = 20;
/// Least stack headroom each board must have kept over the flight, bytes.
const MIN_STACK_FREE: u64 = 4096;
/// The bench's limit of virtual time, s: far more than the flight needs, so that a board that
/// stops answering ends the run (the host's links close) instead of hanging it.
const LIMIT_S: f64 = 60.0;
/// The host link's baud of the hil flavour (`board_support::link::HOST_BAUD`).
const HOST_BAUD: u32 = 921_600;

/// Messages and decoding errors of everything sent on a line.
fn decode<M: Message>(bytes: &[u8]) -> (usize, u32) {
    let mut decoder: Decoder<M, 256> = Decoder::new_mid_stream();
    let mut n = 0;
    decoder.feed(bytes, |_| n += 1);
    (n, decoder.errors().total())
}

/// The two host links as `sim-host hil --stereo tcp:.. --autopilot tcp:..` opens them, and the
/// bench's bridges on the other ends.
fn connect() -> (
    [TcpStream; 2],
    TcpBridge<camera::CameraBoard>,
    TcpBridge<autopilot::Autopilot>,
) {
    let stereo = TcpListener::bind("127.0.0.1:0").expect("a local port");
    let autopilot = TcpListener::bind("127.0.0.1:0").expect("a local port");
    let connect = |l: &TcpListener| {
        let s = TcpStream::connect(l.local_addr().expect("bound")).expect("connects");
        s.set_nodelay(true).expect("nodelay");
        s
    };
    let clients = [connect(&stereo), connect(&autopilot)];
    let camera = TcpBridge::accept(&stereo, serve::camera_host, None).expect("accepts");
    let autopilot = TcpBridge::accept(&autopilot, serve::autopilot_host, None).expect("accepts");
    (clients, camera, autopilot)
}

/// Flies `cfg` against the bench; the host's result (or its error) and the bench's runs.
fn fly(cfg: &HilConfig) -> (Result<HilResult, String>, HilOutcome) {
    let ([stereo, autopilot], camera_bridge, autopilot_bridge) = connect();
    let bench = std::thread::spawn(move || {
        serve::hil(
            camera_bridge,
            autopilot_bridge,
            1,
            Options::seconds(LIMIT_S),
        )
    });
    let closers = [
        stereo.try_clone().expect("a handle"),
        autopilot.try_clone().expect("a handle"),
    ];
    let wall = Instant::now();
    let result = sim_host::hil::run(cfg, Box::new(stereo), Box::new(autopilot), None, &mut |t| {
        eprintln!(
            "hil: world {t:.0} s after {:.0} s wall",
            wall.elapsed().as_secs_f64()
        );
    });
    // The host is done: its leaving ends the bench's run.
    for closer in closers {
        let _ = closer.shutdown(Shutdown::Both);
    }
    let outcomes = bench
        .join()
        .expect("the bench's thread")
        .expect("the bench runs the hil images");
    (result.map_err(|e| format!("{e:#}")), outcomes)
}

/// The autopilot's flight mode over the flight: each change and its world time.
fn modes(r: &HilResult) -> String {
    let mut out = Vec::new();
    let mut last = None;
    for row in &r.log {
        if row.mode != last {
            last = row.mode;
            let name = row.mode.map_or("none", FlightMode::name);
            out.push(format!("{:.2} s {name}", row.t_s));
        }
    }
    out.join(", ")
}

/// `table` with every row the image does not need made optional: a pin it configures must be
/// configured as the board wires it, a pin it leaves alone may stay at reset.
fn needing(table: &[Wired], needed: &[(&str, u8)]) -> Vec<Wired> {
    table
        .iter()
        .map(|row| Wired {
            optional: !needed.contains(&(row.port, row.pin)),
            ..*row
        })
        .collect()
}

#[test]
fn sim_host_hil_flies_the_hil_images_on_the_virtual_boards() {
    let cfg = HilConfig {
        world: FlightConfig {
            seed: SEED,
            ..FlightConfig::default()
        },
        duration_s: SIM_S,
        fps: FPS,
        arm_at_s: ARM_AT_S,
        ..HilConfig::default()
    };
    let (result, (cam, ap)) = fly(&cfg);
    let boards = format!(
        "{}\n{}\nbridges: camera board {} B out, {} B in ({:?}); autopilot {} B out, {} B in ({:?})",
        cam.report(),
        ap.report(),
        cam.probe.bytes_out,
        cam.probe.bytes_in,
        cam.probe.ended,
        ap.probe.bytes_out,
        ap.probe.bytes_in,
        ap.probe.ended
    );
    let r = result.unwrap_or_else(|e| panic!("the hil run failed: {e}\n{boards}"));
    let stack_free = [cam.log.status("stack_free"), ap.log.status("stack_free")];
    let summary = format!(
        "{}\nmodes             {}\nbench: {:.2} s virtual in {:.1} s wall; stack_free: camera board {:?} B, autopilot {:?} B",
        r.summary(),
        modes(&r),
        ap.end_ns as f64 / 1e9,
        ap.wall_s,
        stack_free[0],
        stack_free[1],
    );
    println!("{summary}");
    let report = format!("{summary}\n{boards}");

    // The boards: no fault, no reset, nothing the parts lack; the run ended because the host
    // left, not at the bench's limit.
    cam.assert_clean();
    ap.assert_clean();
    for (name, resets) in [
        ("camera board", cam.session.resets().len()),
        ("autopilot", ap.session.resets().len()),
    ] {
        assert_eq!(resets, 0, "the {name} reset: {report}");
    }
    assert!(
        ap.end_ns < (LIMIT_S * 1e9) as u64
            && (cam.probe.ended.is_some() || ap.probe.ended.is_some()),
        "the bench ran into its {LIMIT_S} s limit: {report}"
    );

    // Lockstep: every IMU sample answered, every frame answered, nothing lost or garbled.
    assert_eq!(r.imu_samples, (SIM_S * 512.0).round() as u64, "{report}");
    assert_eq!(r.motor_replies, r.imu_samples, "{report}");
    assert_eq!(r.reply_timeouts, 0, "{report}");
    assert_eq!(r.frame_timeouts, 0, "{report}");
    assert!(r.estimates + 1 >= r.frames_sent, "{report}");
    assert!(
        r.valid_estimates >= MIN_VALID,
        "the camera board's estimates were usable: {report}"
    );
    assert_eq!(r.total_link_errors(), 0, "{report}");
    let camera_link = &cam.board().link;
    let autopilot_link = &ap.board().link;
    let (to_autopilot, s2a_errors) = decode::<StereoToAutopilot>(&camera_link.tx.sent_bytes());
    let (to_camera, a2s_errors) = decode::<AutopilotToStereo>(&autopilot_link.tx.sent_bytes());
    assert_eq!(
        (s2a_errors, a2s_errors),
        (0, 0),
        "board-to-board decode errors: {report}"
    );
    assert!(
        to_autopilot as u64 >= r.estimates && to_camera as f64 >= SIM_S * 128.0,
        "the link carried the estimates ({to_autopilot} messages) and the 128 Hz gyro samples ({to_camera}): {report}"
    );
    for line in [&camera_link.tx, &autopilot_link.tx] {
        assert_eq!((line.garbled(), line.lost()), (0, 0), "{report}");
    }
    for (name, outcome_rx_lost) in [
        ("camera board", cam.log.status("rx_lost")),
        ("autopilot", ap.log.status("rx_lost")),
    ] {
        assert_eq!(outcome_rx_lost, Some(0), "the {name} lost bytes: {report}");
    }
    for key in ["link_errors", "host_errors", "dropped", "link_tx_dropped"] {
        assert_eq!(cam.log.status(key), Some(0), "camera board {key}: {report}");
    }
    for key in ["link_errors", "tx_dropped", "host_sensor_rejected"] {
        assert_eq!(ap.log.status(key), Some(0), "autopilot {key}: {report}");
    }

    // Flight: took off to the 1 m target, stayed airborne in a band, stayed in the room.
    assert!(r.max_motor > 0.2, "motors ran: {report}");
    assert!(
        (0.8..=1.4).contains(&r.max_height_m),
        "climbed to about 1 m: {report}"
    );
    assert!(r.airborne_s >= SIM_S - ARM_AT_S - 1.5, "{report}");
    for row in r.log.iter().filter(|row| row.t_s >= ARM_AT_S + 2.5) {
        assert!(
            (0.6..=1.4).contains(&row.pos[2]),
            "height {:.2} m at {:.2} s outside 0.6..=1.4 m: {report}",
            row.pos[2],
            row.t_s
        );
    }
    assert_eq!(r.collisions, 0, "{report}");
    assert!(r.max_drift_m <= 1.6, "{report}");
    // Still flying or hovering without estimates at the end: not landing or killed.
    let mode = r.last_telemetry.map(|t| t.flight_mode);
    assert!(
        matches!(mode, Some(FlightMode::Flying | FlightMode::HoverNoEstimate)),
        "{report}"
    );

    // Stack: each board kept a margin (an overflow would corrupt statics silently).
    for (board, free) in ["camera board", "autopilot"].iter().zip(stack_free) {
        let free = free.unwrap_or_else(|| panic!("no stack_free in the {board}'s log: {report}"));
        assert!(
            free >= MIN_STACK_FREE,
            "{board}: only {free} bytes of stack never used (at least {MIN_STACK_FREE}): {report}"
        );
    }

    // The host UARTs at the hil flavour's baud (to the divider's rounding, well inside what a
    // receiver at the nominal rate takes).
    let bauds = [
        (
            "camera board USART2",
            cam.board()
                .clocks
                .and_then(|c| c.usart_baud(&cam.board().soc, "USART2")),
        ),
        (
            "autopilot USART1",
            ap.board()
                .clocks
                .and_then(|c| c.usart_baud(&ap.board().soc, "USART1")),
        ),
    ];
    for (uart, baud) in bauds {
        let baud = f64::from(baud.unwrap_or(0));
        assert!(
            (baud - f64::from(HOST_BAUD)).abs() / f64::from(HOST_BAUD) < 0.01,
            "{uart} at {baud} Bd, the host link runs at {HOST_BAUD}: {report}"
        );
    }

    // Pins: the hil images configure only pins of their boards, as the boards wire them. The
    // autopilot's is the real one's set-up; the camera board's the link, its spare USART2 for
    // the host, the cameras' reset (held) and the LED, the camera's other pins left at reset.
    let problems = pins::check(&ap.board().soc, &autopilot::WIRING);
    assert!(
        problems.is_empty(),
        "the autopilot's pins:\n  {}\n{report}",
        problems.join("\n  ")
    );
    let used = [
        camera::LINK_PINS[0],
        camera::LINK_PINS[1],
        camera::HOST_PINS[0],
        camera::HOST_PINS[1],
        camera::SENSOR_RESET,
    ]
    .map(|p| (p.port, p.pin));
    let problems = pins::check(&cam.board().soc, &needing(&camera::WIRING, &used));
    assert!(
        problems.is_empty(),
        "the camera board's pins:\n  {}\n{report}",
        problems.join("\n  ")
    );
    assert_eq!(
        cam.board().output_level(camera::SENSOR_RESET),
        Some(false),
        "the cameras held in reset: {report}"
    );
}
