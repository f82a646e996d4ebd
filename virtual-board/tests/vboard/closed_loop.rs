//! Test 4b: the closed loop. The unmodified `real` autopilot image flies sim-host's world
//! ([`virtual_board::world::Plant`]): the world's true body rates and specific force on the
//! MPU-6000, its barometer's pressure on the MS5611, the four PWM duties on its dynamics, in
//! lockstep at every millisecond of virtual time.
//!
//! A user's flight: on the ground the ground tool sets `fsm_forward_speed` to 0 over the
//! telemetry port (a hover: the avoidance FSM holds zero velocity), sends the lab's height fixes
//! (motion capture, from the world with its noise) and arms
//! ([`virtual_board::pilot::GroundStation`]). The drone takes off to the firmware's target
//! height and must hold the hover point (the start position at the target height) within
//! [`BOUND_M`] for [`HOVER_S`] of virtual time.
//!
//! * `the_autopilot_hovers_in_the_world_on_a_truth_camera`: the camera board is played by the
//!   host ([`virtual_board::world::TruthCamera`]: the world's true velocity plus noise, no
//!   images).
//! * `both_boards_hover_in_the_world`: both real images, their links joined; the camera
//!   board's DCMI captures frames rendered from the world ([`virtual_board::world::Rendered`])
//!   and its Edge-FS estimates are what the autopilot flies on.

use std::sync::Arc;

use protocol::Heartbeat;
use protocol::{
    BoardToHost, Decoder, FlightMode, HostToBoard, Message, Node, ParamOp, ParamReply,
    ParamRequest, ParamValue, PilotCommand, StereoToAutopilot, Telemetry,
};
use virtual_board::bench::{At, Flow, OnBarrier, Options, Probe, Setup, Watching, run, run_pair};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::boards::camera::CameraBoard;
use virtual_board::firmware::Firmware;
use virtual_board::host;
use virtual_board::link;
use virtual_board::pilot::{Every, GroundStation, HEARTBEAT_PERIOD_NS, MS, Once};
use virtual_board::world::{FlightConfig, Plant, Truth, TruthCamera};

/// The parameter set on the ground, and when.
const PARAM_AT: u64 = 1_000 * MS;
/// When the user arms.
const ARM_AT: u64 = 1_500 * MS;
/// From the arm to the start of the hover window: the climb to the target height at the
/// firmware's climb rate (1 m at 0.5 m/s) and its settling.
const TAKE_OFF: u64 = 4_000 * MS;
/// The hover window, s.
const HOVER_S: f64 = 10.0;
/// How far from the hover point the drone may be during the window, m.
const BOUND_M: f64 = 0.3;
/// The bench's lockstep quantum (and the world's step), ns.
const QUANTUM_NS: u64 = MS;

fn hover_window() -> (u64, u64) {
    let from = ARM_AT + TAKE_OFF;
    (from, from + (HOVER_S * 1e9) as u64)
}

/// The user at the ground tool, flying the world.
struct Flight {
    plant: Plant,
    ground: GroundStation,
    /// The host playing the camera board, or `None` when the camera board runs.
    camera: Option<TruthCamera>,
    param: Once,
    /// The user's `Arm` when no height fixes are sent (the ground station arms otherwise),
    /// and the ground tool's heartbeat beside it.
    arm: Option<(Once, Every)>,
    telemetry: Decoder<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>,
    telemetry_read: usize,
    /// Every telemetry frame: (bench time of the stop it arrived by, ns; the frame).
    telemetries: Vec<(u64, Telemetry)>,
    param_replies: Vec<ParamReply>,
}

impl Flight {
    /// With the camera board played by a [`TruthCamera`] if `truth_camera`; with the lab's
    /// height fixes if `cfg.mocap`, else the autopilot flies on its barometer and
    /// accelerometer and the user only arms.
    fn new(cfg: &FlightConfig, truth_camera: bool) -> Self {
        let plant = Plant::new(cfg, QUANTUM_NS).expect("the world");
        let horizon_us = cfg.autopilot.estimation.estimate_horizon.as_micros();
        Self {
            plant,
            ground: GroundStation::arming_at(ARM_AT, 0.0),
            camera: truth_camera.then(|| TruthCamera::new(25.0, 0.05, 20, horizon_us, cfg.seed)),
            param: Once::at(PARAM_AT),
            arm: (!cfg.mocap).then(|| (Once::at(ARM_AT), Every::ns(HEARTBEAT_PERIOD_NS))),
            telemetry: Decoder::new_mid_stream(),
            telemetry_read: 0,
            telemetries: Vec::new(),
            param_replies: Vec::new(),
        }
    }
}

impl Probe<Autopilot> for Flight {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let board = at.board();
        self.plant.step(now, board);
        if let Some((arm, heartbeats)) = &mut self.arm {
            if heartbeats.due(now) {
                let hb = HostToBoard::Heartbeat(Heartbeat::new(Node::Host, (now / MS) as u32));
                board.telemetry.rx.send_at(now, &host::frame(&hb));
            }
            if arm.due(now) {
                let arm = HostToBoard::Command(PilotCommand::Arm);
                board.telemetry.rx.send_at(now, &host::frame(&arm));
            }
        } else {
            // The lab's motion capture, through the ground tool.
            let fix = self
                .plant
                .world_mut()
                .height_fix(timebase::WorldTime::from_micros(now / 1_000));
            self.ground.set_height(-f64::from(fix.position_m[2]));
            self.ground.step(now, &board.telemetry.rx);
        }
        if self.param.due(now) {
            let set = HostToBoard::Param(ParamRequest {
                board: Node::Autopilot,
                op: ParamOp::Set(
                    "fsm_forward_speed".try_into().expect("a short name"),
                    ParamValue::F32(0.0),
                ),
            });
            board.telemetry.rx.send_at(now, &host::frame(&set));
        }
        if let Some(camera) = &mut self.camera {
            camera.step(now, &self.plant, &board.link.rx);
        }
        let bytes = board.telemetry.tx.sent_bytes_from(self.telemetry_read);
        self.telemetry_read += bytes.len();
        let (telemetries, replies) = (&mut self.telemetries, &mut self.param_replies);
        self.telemetry.feed(&bytes, |m| match m {
            BoardToHost::Telemetry(t) => telemetries.push((now, t)),
            BoardToHost::Param(p) => replies.push(p.reply),
            _ => {}
        });
        Flow::Continue
    }
}

/// The hover point: the start position at the firmware's target height.
fn hover_point(cfg: &FlightConfig, plant: &Plant) -> [f64; 3] {
    let start = plant.world().start;
    [
        start[0],
        start[1],
        f64::from(cfg.autopilot.setpoints.target_height_m),
    ]
}

fn deviation(point: [f64; 3], truth: &Truth) -> f64 {
    let p = truth.state.pos;
    ((p.x - point[0]).powi(2) + (p.y - point[1]).powi(2) + (truth.height_m() - point[2]).powi(2))
        .sqrt()
}

/// What a flight showed, printed and checked against the bound.
fn judge(name: &str, cfg: &FlightConfig, flight: &Flight, end_ns: u64, wall_s: f64, report: &str) {
    let (from, to) = hover_window();
    assert!(
        flight.param_replies.iter().any(|r| matches!(
            r,
            ParamReply::Entry(e) if e.name.as_str() == "fsm_forward_speed"
                && e.value == ParamValue::F32(0.0)
        )),
        "the firmware took fsm_forward_speed = 0: {:?}\n{report}",
        flight.param_replies
    );
    let point = hover_point(cfg, &flight.plant);
    let window: Vec<&Truth> = flight
        .plant
        .trace()
        .iter()
        .filter(|t| (from..to).contains(&t.at_ns))
        .collect();
    let worst = window
        .iter()
        .map(|t| (deviation(point, t), **t))
        .max_by(|a, b| a.0.total_cmp(&b.0));
    let modes: Vec<FlightMode> = flight
        .telemetries
        .iter()
        .filter(|(at, _)| (from..to).contains(at))
        .map(|(_, t)| t.flight_mode)
        .collect();
    let trace = flight.plant.trace();
    // The firmware's attitude (telemetry) against the world's, roll and pitch, over the window.
    let attitude_error = flight
        .telemetries
        .iter()
        .filter(|(at, _)| (from..to).contains(at))
        .filter_map(|(at, t)| {
            let i = trace.partition_point(|s| s.at_ns <= *at).checked_sub(1)?;
            let truth = trace[i].euler();
            Some(
                (0..2)
                    .map(|k| (f64::from(t.attitude_rad[k]) - truth[k]).abs())
                    .fold(0.0, f64::max),
            )
        })
        .fold(0.0, f64::max);
    let max_height = trace.iter().map(Truth::height_m).fold(0.0, f64::max);
    let rms = (window
        .iter()
        .map(|t| deviation(point, t).powi(2))
        .sum::<f64>()
        / window.len().max(1) as f64)
        .sqrt();
    println!(
        "closed loop ({name}): {:.1} s virtual in {wall_s:.1} s wall; hover point \
         {point:.2?}; over the {HOVER_S} s window max deviation {:.3} m (at {:.2} s, at \
         {:.2?}), RMS {rms:.3} m; max height {max_height:.2} m; collisions {}; telemetry roll/pitch \
         within {:.2} deg of the world's",
        end_ns as f64 / 1e9,
        worst.map_or(f64::NAN, |w| w.0),
        worst.map_or(f64::NAN, |w| w.1.at_ns as f64 / 1e9),
        worst.map(|w| w.1.state.pos),
        flight.plant.world().collisions,
        attitude_error.to_degrees(),
    );
    assert!(
        window.len() as f64 >= HOVER_S * 1e3 * 0.99,
        "the world was stepped through the window: {} samples\n{report}",
        window.len()
    );
    assert!(
        !modes.is_empty() && modes.iter().all(|m| *m == FlightMode::Flying),
        "flying the whole window: {modes:?}\n{report}"
    );
    let (worst_m, worst_at) = worst.expect("a window");
    assert!(
        worst_m <= BOUND_M,
        "the drone left the hover point {point:.2?} by {worst_m:.3} m at {:.2} s ({:?}), \
         bound {BOUND_M} m\n{report}",
        worst_at.at_ns as f64 / 1e9,
        worst_at.state.pos
    );
}

/// The flight's world: the paper's room, seeded, with the lab's height fixes.
fn world(seed: u64) -> FlightConfig {
    FlightConfig {
        seed,
        mocap: true,
        ..FlightConfig::default()
    }
}

#[test]
fn the_autopilot_hovers_on_its_barometer_on_a_truth_camera() {
    let cfg = FlightConfig {
        mocap: false,
        ..world(13)
    };
    let outcome = run(
        Setup {
            board: Autopilot::new(cfg.seed).expect("the board"),
            firmware: Firmware::real("autopilot").expect("the autopilot image"),
            probe: Flight::new(&cfg, true),
        },
        Options {
            until_ns: hover_window().1,
            step_ns: QUANTUM_NS,
        },
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    judge(
        "autopilot image, barometer only, truth camera",
        &cfg,
        &outcome.probe,
        outcome.end_ns,
        outcome.wall_s,
        &report,
    );
}

#[test]
fn the_autopilot_hovers_in_the_world_on_a_truth_camera() {
    let cfg = world(11);
    let outcome = run(
        Setup {
            board: Autopilot::new(cfg.seed).expect("the board"),
            firmware: Firmware::real("autopilot").expect("the autopilot image"),
            probe: Flight::new(&cfg, true),
        },
        Options {
            until_ns: hover_window().1,
            step_ns: QUANTUM_NS,
        },
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    let flight = &outcome.probe;
    println!(
        "truth camera: {} estimates sent",
        flight.camera.as_ref().map_or(0, TruthCamera::sent)
    );
    judge(
        "autopilot image, truth camera",
        &cfg,
        flight,
        outcome.end_ns,
        outcome.wall_s,
        &report,
    );
}

#[test]
fn both_boards_hover_in_the_world() {
    let cfg = world(12);
    let flight = Flight::new(&cfg, false);
    let frames = flight.plant.rendered();
    let (camera_end, autopilot_end) = link::join();
    let camera = CameraBoard::with_link(Box::new(frames), camera_end.clone()).expect("board");
    let autopilot = Autopilot::with_link(cfg.seed, autopilot_end.clone()).expect("board");
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
            probe: flight,
        },
        Options {
            until_ns: hover_window().1,
            step_ns: QUANTUM_NS,
        },
        vec![camera_rx],
        vec![autopilot_rx],
    )
    .expect("the run");
    let report = format!("{}\n{}", cam.report(), ap.report());
    cam.assert_clean();
    ap.assert_clean();
    let (estimates, valid, errors) = decode_estimates(&camera_end.tx.sent_bytes());
    println!(
        "camera board: {} frames captured, {estimates} estimates sent, {valid} valid ({errors} \
         decode errors)",
        cam.board().captured().len()
    );
    assert_eq!(errors, 0, "the camera board's link decodes\n{report}");
    // Edge-FS sees the rendered room: most estimates are valid (the hover flies on them).
    assert!(
        valid as f64 >= 0.8 * estimates as f64 && estimates as f64 >= 0.9 * 24.0 * 15.0,
        "{valid} of {estimates} estimates valid\n{report}"
    );
    judge(
        "both images, rendered frames",
        &cfg,
        &ap.probe,
        ap.end_ns,
        ap.wall_s,
        &report,
    );
}

/// The estimates among the camera board's link bytes, how many are valid, and the decoder's
/// errors.
fn decode_estimates(bytes: &[u8]) -> (usize, usize, u32) {
    let mut decoder: Decoder<StereoToAutopilot, { StereoToAutopilot::MAX_FRAME_BYTES }> =
        Decoder::new_mid_stream();
    let (mut estimates, mut valid) = (0, 0);
    decoder.feed(bytes, |m| {
        if let StereoToAutopilot::Estimate(e) = m {
            estimates += 1;
            valid += usize::from(e.is_valid());
        }
    });
    (estimates, valid, decoder.errors().total())
}
