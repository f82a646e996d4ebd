//! Hardware in the loop in CI: both firmwares (qemu flavour) in two QEMUs under
//! `-icount shift=auto`, flown by `sim_host::hil` in lockstep on world time (see its docs):
//! the host streams rendered frames to the camera board and IMU samples plus height fixes to
//! the autopilot, applies the autopilot's motor commands to the simulated drone, and relays
//! the board-to-board UART (decoding it on the way).
//!
//! A short closed-loop flight in the paper's 4 x 4 m room: 8.5 s of world time, armed at 2.5 s
//! (as a user arms: once the camera board's estimates are valid; at 4 fps its flow history of
//! 9 frames takes 2.25 s to fill, and the autopilot's failsafe gives an armed drone 0.5 s to see
//! a valid estimate and 1.5 s more of blind hover before it lands), climb at 0.5 m/s to the
//! autopilot's 1 m target, then its avoidance flight starts (forward at 0.3 m/s). Passes when:
//! every one of the 4,352 IMU samples got its `Motors` reply; every frame
//! (4 fps of world time) its estimate; at least 3 estimates were valid; no decoding error on any
//! link (host side, relay, the autopilot's own counter); the drone climbed to 0.8..=1.4 m, was
//! airborne for at least 4 s and from 2.5 s after arming on stayed within 0.6..=1.4 m; no collision and at most
//! 1.6 m horizontal drift from the start; the autopilot still flying at the end; and each
//! board's stack kept at least 4 KiB never touched (`stack_free` of its last status line:
//! `board_support::stack` paints the stack at boot, and this flight, both boards in closed
//! loop, is the deepest realistic use).
//!
//! Measured (2-core machine): 8.5 s of world time in 45 s of wall time (frames hold the world
//! 32 s; IMU round trips 13 s in all), max height 1.07 m, drift 1.27 m (the avoidance flight's
//! forward leg), 24 of 33 estimates valid (the other 9 while the flow history filled). `HIL_SIM_S` and `HIL_FPS` override the duration
//! and the frame rate for experiments.

#[path = "qemu_support.rs"]
mod support;

use protocol::FlightMode;
use sim_host::hil::{HilConfig, Relay};
use sim_host::sim::flight::FlightConfig;
use std::time::{Duration, Instant};
use support::{last_field, qemu_firmwares, require_qemu, Port, Qemu};

/// World time flown, s.
const SIM_S: f64 = 8.5;
/// World time of the arm command, s: after the camera board's flow history has filled at
/// [`FPS`] (9 frames).
const ARM_AT_S: f64 = 2.5;
/// Camera frames per second of world time (what QEMU's USART carries in reasonable wall time:
/// a frame takes about 2.3 s; see `sim_host::hil`).
const FPS: f64 = 4.0;
/// Least stack headroom each board must have kept over the flight, bytes (the low-water mark
/// of its painted stack, `stack_free=` in its status log line).
const MIN_STACK_FREE: u64 = 4096;

#[test]
fn closed_loop_hover_with_both_firmwares_in_qemu() {
    require_qemu();
    let (stereo_elf, autopilot_elf) = qemu_firmwares();
    let (s_link, s_host, a_link, a_host) = (Port::bind(), Port::bind(), Port::bind(), Port::bind());
    let mut stereo = Qemu::start(
        &stereo_elf,
        &s_link.chardev("link"),
        &s_host.chardev("host"),
    );
    let mut autopilot = Qemu::start_autopilot(
        &autopilot_elf,
        &a_link.chardev("link"),
        &a_host.chardev("host"),
    );
    let timeout = Duration::from_secs(60);
    let s_link = s_link.accept(timeout);
    let a_link = a_link.accept(timeout);
    // Relay only once both boards receive: bytes reaching a USART before it is enabled are
    // lost, and a frame cut in half would count as a link error.
    stereo.wait_for_log("status", timeout);
    autopilot.wait_for_log("status", timeout);
    let relay = Relay::start(Box::new(s_link), Box::new(a_link)).expect("relay");
    let s_host = s_host.accept(timeout);
    let a_host = a_host.accept(timeout);

    let sim_s = std::env::var("HIL_SIM_S")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(SIM_S);
    let fps = std::env::var("HIL_FPS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(FPS);
    let cfg = HilConfig {
        world: FlightConfig {
            seed: 3,
            ..FlightConfig::default()
        },
        duration_s: sim_s,
        fps,
        arm_at_s: ARM_AT_S,
        ..HilConfig::default()
    };
    let wall = Instant::now();
    let result = sim_host::hil::run(
        &cfg,
        Box::new(s_host),
        Box::new(a_host),
        Some(&relay),
        &mut |t| {
            eprintln!(
                "hil: world {t:.0} s after {:.0} s wall",
                wall.elapsed().as_secs_f64()
            );
        },
    );
    stereo.assert_running();
    autopilot.assert_running();
    let slog = stereo.log();
    let alog = autopilot.log();
    drop(stereo);
    drop(autopilot);
    let r = result.unwrap_or_else(|e| {
        panic!("hil run failed: {e:#}\nstereo log:\n{slog}\nautopilot log:\n{alog}")
    });
    // Stack headroom: the low-water mark of each board's stack over the whole flight.
    let stack_free = [
        last_field(&slog, "status", "stack_free"),
        last_field(&alog, "status", "stack_free"),
    ];
    let report = format!(
        "{}\nstack_free: stereo board {} B, autopilot {} B\nstereo log tail:\n{}\nautopilot log tail:\n{}",
        r.summary(),
        show(stack_free[0]),
        show(stack_free[1]),
        tail(&slog),
        tail(&alog)
    );
    eprintln!("{report}");

    // Lockstep: every IMU sample answered, every frame answered, nothing lost or garbled.
    assert_eq!(r.imu_samples, (sim_s * 512.0).round() as u64, "{report}");
    assert_eq!(r.motor_replies, r.imu_samples, "{report}");
    assert_eq!(r.reply_timeouts, 0, "{report}");
    assert_eq!(r.frame_timeouts, 0, "{report}");
    assert!(r.estimates + 1 >= r.frames_sent, "{report}");
    assert!(
        r.valid_estimates >= 3,
        "the camera board's estimates were usable: {report}"
    );
    assert_eq!(r.total_link_errors(), 0, "{report}");
    for log in [&slog, &alog] {
        assert_eq!(last_field(log, "status", "rx_lost"), Some(0), "{report}");
    }
    assert!(
        r.relayed_messages[0] > 0 && r.relayed_messages[1] > 0,
        "{report}"
    );
    // Flight: took off to the 1 m target, stayed airborne in a band, stayed in the room.
    assert!(r.max_motor > 0.2, "motors ran: {report}");
    assert!(
        (0.8..=1.4).contains(&r.max_height_m),
        "climbed to about 1 m: {report}"
    );
    assert!(r.airborne_s >= sim_s - ARM_AT_S - 1.5, "{report}");
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
    for (board, free) in ["stereo board", "autopilot"].iter().zip(stack_free) {
        let free = free.unwrap_or_else(|| panic!("no stack_free in the {board}'s log: {report}"));
        assert!(
            free >= MIN_STACK_FREE,
            "{board}: only {free} bytes of stack never used (at least {MIN_STACK_FREE}): {report}"
        );
    }
}

fn show(v: Option<u64>) -> String {
    v.map_or_else(|| "?".into(), |v| v.to_string())
}

fn tail(log: &str) -> String {
    let lines: Vec<&str> = log.lines().collect();
    lines[lines.len().saturating_sub(4)..].join("\n")
}
