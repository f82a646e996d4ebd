//! Test 5 (camera side): the camera board's fault paths, both boards joined and the autopilot
//! armed and flying. Every fault is injected from the bench into the unmodified `real` images:
//!
//! | fault | injection | what must follow |
//! |---|---|---|
//! | HardFault, for good | the camera board's next access to its DCMI is a bus error, and again after every reset (a board that faults at every boot) | the camera board's handler runs and its link goes silent (no estimate after the message in flight); the autopilot hovers blind, lands and stops its motors within [`autopilot::AutopilotConfig::link_loss_motors_off`] of the fault |
//! | panic | the camera board's logger "taken" flag set under the firmware: its next log line panics (defmt-rtt's re-entrancy check) | the link silent from the handler until the camera board's watchdog resets it (within [`WATCHDOG_MS`]); the autopilot hovers blind within its estimate timeout, and does not stop its motors before the camera board is back; the camera board boots again and its estimates resume |

use std::path::PathBuf;
use std::sync::Arc;

use protocol::{BoardToHost, Decoder, FlightMode, Message, StereoToAutopilot};
use virtual_board::bench::{At, Flow, OnBarrier, Options, Outcome, Probe, Setup, run_pair};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::boards::camera::{CameraBoard, LINK_BAUD};
use virtual_board::firmware::Firmware;
use virtual_board::frames::Recorded;
use virtual_board::link::{self, Line};
use virtual_board::pilot::{GroundStation, MS, Once};

const ARM_AT: u64 = 1_500 * MS;
/// Just after the camera board's status line at 2 s (its panic comes at its next log line),
/// while the recorded take still gives valid estimates (later in it the scene gives none).
const FAULT_AT: u64 = 2_030 * MS;
/// The height the drone reports once armed, m (the bench flies no world).
const HOVER_M: f64 = 0.5;
/// The camera board's DCMI registers (RM0090 table 1).
const DCMI: (u64, u64) = (0x5005_0000, 0x5005_0400);
/// The camera board's independent-watchdog period, ms (board_support::watchdog::HEARTBEAT_FED_MS:
/// fed by its 1 Hz task).
const WATCHDOG_MS: u64 = 2_000;
/// One largest camera-board message on the wire, ns (10 bits a byte at the link's baud): what
/// may still leave after the handler ran (a transfer the UART had begun).
fn one_message_ns() -> u64 {
    StereoToAutopilot::MAX_FRAME_BYTES as u64 * 10 * 1_000_000_000 / u64::from(LINK_BAUD)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Injection {
    HardFault,
    Panic,
}

/// The recorded take the test plays (see [`virtual_board::frames::data_set_take_1`]). Once its
/// frames are played the sensors keep seeing the last one.
fn take() -> PathBuf {
    virtual_board::frames::data_set_take_1()
}

/// The camera board's side: injects the fault.
struct CameraSide {
    fault: Injection,
    fault_at: Once,
    logger_taken: Option<u64>,
    /// Resets and fault arrivals when the bus error was last armed.
    armed_at: Option<(usize, usize)>,
}

impl Probe<CameraBoard> for CameraSide {
    fn at(&mut self, at: &mut At<'_, CameraBoard>) -> Flow {
        let due = self.fault_at.due(at.now);
        match self.fault {
            Injection::HardFault => {
                let (resets, faults) = (at.session.resets().len(), at.faults.len());
                // Armed at the fault, and again once the last one has struck and the board
                // has reset: it faults at every boot.
                let again = self.armed_at.is_some_and(|(r, f)| resets > r && faults > f);
                if due || again {
                    at.session.fail_next(DCMI.0, DCMI.1);
                    self.armed_at = Some((resets, faults));
                }
            }
            Injection::Panic => {
                if due {
                    let flag = self.logger_taken.expect("the logger's flag");
                    at.host
                        .write(flag, rigless::soc::Width::W8, 1)
                        .expect("RAM takes a byte");
                }
            }
        }
        Flow::Continue
    }
}

/// The autopilot's side: the user at the ground tool arms it, and once it lands the height it
/// is told follows its descent.
struct AutopilotSide {
    ground: GroundStation,
    telemetry: Decoder<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>,
    telemetry_read: usize,
    /// Flight modes as the telemetry reports them, with the stop they arrived at.
    modes: Vec<(u64, FlightMode)>,
    last_ns: u64,
    running_before: bool,
    /// First stop after the fault with every duty 0, and any later one with a duty not 0.
    off_at: Option<u64>,
    came_back_at: Option<u64>,
}

impl AutopilotSide {
    fn new() -> Self {
        Self {
            ground: GroundStation::arming_at(ARM_AT, HOVER_M),
            telemetry: Decoder::new_mid_stream(),
            telemetry_read: 0,
            modes: Vec::new(),
            last_ns: 0,
            running_before: false,
            off_at: None,
            came_back_at: None,
        }
    }

    fn mode_at(&self, at: u64) -> Option<FlightMode> {
        self.modes
            .iter()
            .take_while(|(t, _)| *t <= at)
            .last()
            .map(|(_, m)| *m)
    }
}

impl Probe<Autopilot> for AutopilotSide {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let board = at.board();
        let sent = board.telemetry.tx.sent_bytes_from(self.telemetry_read);
        self.telemetry_read += sent.len();
        for byte in sent {
            if let Some(BoardToHost::Telemetry(t)) = self.telemetry.push(byte)
                && self.modes.last().is_none_or(|(_, m)| *m != t.flight_mode)
            {
                self.modes.push((now, t.flight_mode));
            }
        }
        if self
            .modes
            .last()
            .is_some_and(|(_, m)| *m == FlightMode::Landing)
        {
            let rate = autopilot::AutopilotConfig::default()
                .setpoints
                .land_rate_mps;
            let dt = (now - self.last_ns) as f64 / 1e9;
            let height = (self.ground.height_m() - f64::from(rate) * dt).max(0.0);
            self.ground.set_height(height);
        }
        self.ground.step(now, &board.telemetry.rx);
        self.last_ns = now;
        let duties = board.motors().map(|m| m.duty);
        let all_off = duties.iter().all(|&d| d == 0.0);
        if (FAULT_AT - 100 * MS..FAULT_AT).contains(&now) && duties.iter().all(|&d| d > 0.0) {
            self.running_before = true;
        }
        if now > FAULT_AT {
            match (self.off_at, all_off) {
                (None, true) => self.off_at = Some(now),
                (Some(_), false) if self.came_back_at.is_none() => self.came_back_at = Some(now),
                _ => {}
            }
        }
        Flow::Continue
    }
}

/// The address of defmt-rtt's "taken" flag (see `autopilot_faults.rs`).
fn logger_taken_flag(firmware: &Firmware) -> u64 {
    firmware
        .symbols_containing("RTT_ENCODER")
        .filter(|(name, _)| name.ends_with(".1"))
        .map(|(_, address)| address)
        .min()
        .expect("defmt-rtt's encoder state in the image")
}

/// Every message on `line`, with the instant its last byte was sent, ns.
fn decode_timed<M: Message>(line: &Line) -> Vec<(u64, M)> {
    let mut decoder: Decoder<M, 256> = Decoder::new_mid_stream();
    let mut out = Vec::new();
    for (at, word) in line.sent() {
        decoder.feed(&[(word & 0xFF) as u8], |m| out.push((at, m)));
    }
    out
}

type Runs = (
    Outcome<CameraBoard, CameraSide>,
    Outcome<Autopilot, AutopilotSide>,
    Line,
);

fn run_fault(fault: Injection, seconds: f64) -> Runs {
    let (camera_end, autopilot_end) = link::join();
    let firmware = Firmware::real("stereo-board").expect("the camera-board image");
    let logger_taken = (fault == Injection::Panic).then(|| logger_taken_flag(&firmware));
    let recorded = Recorded::from_take(&take(), 120).expect("the data set's take 1");
    let camera = CameraBoard::with_link(Box::new(recorded), camera_end.clone()).expect("the board");
    let autopilot = Autopilot::with_link(3, autopilot_end.clone()).expect("the board");
    let camera_rx: Arc<dyn OnBarrier> = Arc::new(camera_end.rx.clone());
    let autopilot_rx: Arc<dyn OnBarrier> = Arc::new(autopilot_end.rx.clone());
    let (cam, ap) = run_pair(
        Setup {
            board: camera,
            firmware,
            probe: CameraSide {
                fault,
                fault_at: Once::at(FAULT_AT),
                logger_taken,
                armed_at: None,
            },
        },
        Setup {
            board: autopilot,
            firmware: Firmware::real("autopilot").expect("the autopilot image"),
            probe: AutopilotSide::new(),
        },
        Options::seconds(seconds),
        vec![camera_rx],
        vec![autopilot_rx],
    )
    .expect("the run");
    (cam, ap, camera_end.tx)
}

/// The first fault handler the camera board reached after the injection, and what it was.
fn first_fault(cam: &Outcome<CameraBoard, CameraSide>, report: &str) -> (u64, String) {
    let fault = cam
        .faults
        .iter()
        .find(|f| f.at_ns >= FAULT_AT)
        .unwrap_or_else(|| panic!("the camera board reached no fault handler\n{report}"));
    (fault.at_ns, fault.handler.clone())
}

/// The camera board faults at every boot: its link goes silent, and the autopilot, finding no
/// estimate, hovers, lands and stops its motors within its link-loss promise.
#[test]
fn a_camera_board_that_hard_faults_goes_silent_and_the_autopilot_lands() {
    let promise = autopilot::AutopilotConfig::default()
        .link_loss_motors_off()
        .as_micros()
        * 1_000;
    let seconds = (FAULT_AT + promise) as f64 / 1e9 + 0.8;
    let (cam, ap, camera_tx) = run_fault(Injection::HardFault, seconds);
    let report = format!("{}\n{}", cam.report(), ap.report());
    ap.assert_clean();
    let (handler_at, handler) = first_fault(&cam, &report);
    assert!(
        handler.contains("HardFault"),
        "the camera board's first fault was {handler}\n{report}"
    );
    let messages = decode_timed::<StereoToAutopilot>(&camera_tx);
    let estimates_before = messages
        .iter()
        .filter(|(t, m)| *t < FAULT_AT && matches!(m, StereoToAutopilot::Estimate(_)))
        .count();
    assert!(
        estimates_before >= 20,
        "{estimates_before} estimates before the fault\n{report}"
    );
    let late: Vec<u64> = messages
        .iter()
        .filter(|(t, m)| {
            *t > handler_at + one_message_ns() && matches!(m, StereoToAutopilot::Estimate(_))
        })
        .map(|(t, _)| *t)
        .collect();
    assert!(
        late.is_empty(),
        "estimates after the camera board's HardFault at {:.1} ms: {late:?}\n{report}",
        handler_at as f64 / 1e6
    );
    let resets = cam.session.resets().len();
    assert!(
        resets >= 1 && cam.faults.len() > resets,
        "the camera board faulted again at its boot: {} faults, {resets} resets\n{report}",
        cam.faults.len()
    );

    let pilot = &ap.probe;
    assert!(
        pilot.running_before,
        "the motors ran before the fault\n{report}"
    );
    let off = pilot.off_at.unwrap_or_else(|| {
        panic!(
            "the motors never stopped: modes {:?}\n{report}",
            pilot.modes
        )
    });
    let took = off - FAULT_AT;
    println!(
        "camera HardFault at {:.1} ms (injected at {:.1} ms): link silent, {} resets; the \
         autopilot's motors all 0 {:.2} s after the fault (promised {:.2} s); modes {:?}",
        handler_at as f64 / 1e6,
        FAULT_AT as f64 / 1e6,
        resets,
        took as f64 / 1e9,
        promise as f64 / 1e9,
        pilot.modes
    );
    assert!(
        took <= promise,
        "motors off {:.2} s after the fault, promised {:.2} s\n{report}",
        took as f64 / 1e9,
        promise as f64 / 1e9
    );
    assert_eq!(pilot.came_back_at, None, "a motor ran again\n{report}");
    let modes: Vec<FlightMode> = pilot
        .modes
        .iter()
        .filter(|(t, _)| *t > FAULT_AT)
        .map(|(_, m)| *m)
        .collect();
    // Blind hover once the estimates stop (their timeout, then the next telemetry frame).
    let estimate_timeout = autopilot::failsafe::FailsafeConfig::default()
        .estimate_timeout
        .as_micros();
    let hover_by = handler_at
        + estimate_timeout * 1_000
        + 2 * autopilot::tasks::TELEMETRY_PERIOD.as_micros() * 1_000;
    assert_eq!(
        pilot.mode_at(hover_by),
        Some(FlightMode::HoverNoEstimate),
        "the autopilot hovers blind by {:.1} ms: {:?}\n{report}",
        hover_by as f64 / 1e6,
        pilot.modes
    );
    let landing = modes.iter().position(|m| *m == FlightMode::Landing);
    assert!(
        landing.is_some_and(|at| !modes[at..].contains(&FlightMode::Flying)),
        "after the fault the autopilot lands, and does not fly again: {modes:?}\n{report}"
    );
}

/// The camera board panics once: its link is silent until its watchdog resets it, then it
/// boots and its estimates come back. The autopilot hovers blind within its estimate timeout and
/// does not stop its motors before the camera board is back.
#[test]
fn a_camera_board_that_panics_goes_silent_until_its_watchdog_resets_it() {
    // The panic comes at the camera board's next log line (its 1 Hz status), the watchdog
    // within 2 s of its last feed, the boot and the first frames after.
    let seconds = FAULT_AT as f64 / 1e9 + 1.0 + WATCHDOG_MS as f64 / 1e3 + 1.5;
    let (cam, ap, camera_tx) = run_fault(Injection::Panic, seconds);
    let report = format!("{}\n{}", cam.report(), ap.report());
    ap.assert_clean();
    let (handler_at, handler) = first_fault(&cam, &report);
    assert!(
        handler.contains("rust_begin_unwind"),
        "the camera board's first fault was {handler}\n{report}"
    );
    let reset = cam
        .session
        .resets()
        .iter()
        .find(|r| r.at.0 > handler_at)
        .unwrap_or_else(|| panic!("the camera board's watchdog never reset it\n{report}"));
    assert_eq!(
        reset.cause,
        rigless::device::ResetCause::Model("IWDG"),
        "the reset after the panic is the watchdog's\n{report}"
    );
    let reset_at = reset.at.0;
    assert!(
        reset_at - handler_at <= (WATCHDOG_MS + 50) * MS,
        "reset {:.1} ms after the panic, the watchdog's period is {WATCHDOG_MS} ms\n{report}",
        (reset_at - handler_at) as f64 / 1e6
    );
    let words_silent = camera_tx
        .sent()
        .iter()
        .filter(|(t, _)| (handler_at + one_message_ns()..reset_at).contains(t))
        .count();
    assert_eq!(
        words_silent, 0,
        "the camera board sent after its panic, before its reset\n{report}"
    );
    let messages = decode_timed::<StereoToAutopilot>(&camera_tx);
    let back = messages
        .iter()
        .find(|(t, m)| *t > reset_at && matches!(m, StereoToAutopilot::Estimate(_)))
        .map(|(t, _)| *t)
        .unwrap_or_else(|| panic!("no estimate after the camera board's reboot\n{report}"));

    let pilot = &ap.probe;
    assert!(
        pilot.running_before,
        "the motors ran before the fault\n{report}"
    );
    // Whether the estimates are valid once they are back is the scene's business (the recorded
    // take ends, and a still scene gives none); the reboot itself must not stop the motors.
    assert!(
        pilot.off_at.is_none_or(|off| off > back),
        "the autopilot stopped its motors at {:?} ns, before the camera board was back at {back}\n{report}",
        pilot.off_at
    );
    let estimate_timeout = autopilot::failsafe::FailsafeConfig::default()
        .estimate_timeout
        .as_micros();
    let hover_by = handler_at
        + estimate_timeout * 1_000
        + 2 * autopilot::tasks::TELEMETRY_PERIOD.as_micros() * 1_000;
    println!(
        "camera panic at {:.1} ms: silent, watchdog reset {:.1} ms later, estimates back at \
         {:.1} ms; the autopilot's modes {:?}",
        handler_at as f64 / 1e6,
        (reset_at - handler_at) as f64 / 1e6,
        back as f64 / 1e6,
        pilot.modes
    );
    assert_eq!(
        pilot.mode_at(hover_by),
        Some(FlightMode::HoverNoEstimate),
        "the autopilot hovers blind by {:.1} ms, with the camera board silent: {:?}\n{report}",
        hover_by as f64 / 1e6,
        pilot.modes
    );
}
