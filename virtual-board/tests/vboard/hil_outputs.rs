//! The unmodified `hil` autopilot image keeps its PWM outputs safe, measured on the outputs.
//!
//! The bench is the HIL host here, as `sim-host hil` is: a host `Heartbeat` a second, IMU
//! samples at 512 Hz stamped with the bench's time (the drone at rest, level), height fixes at
//! 50 Hz, an `Arm` at [`ARM_AT`]; a camera board stand-in sends an estimate per 25 fps frame
//! and a heartbeat a second, so that no failsafe of the flight lands the drone.
//!
//! * Never enabled: the outputs stay at 0 for the whole flight, while the motor commands the
//!   image sends back (`Motors`) fly the drone.
//! * Enabled (`PilotCommand::HilOutputs(true)` before the arm), then the host goes silent at
//!   [`SILENT_AT`]: the outputs followed the commands, and every duty is 0 within
//!   [`PROMISE_NS`] (100 ms) of board time after the last sample, and stays 0. World time, and
//!   with it every failsafe of the library, stops with the samples: only the board clock's
//!   check (`SAMPLES_TIMEOUT_US` 50 ms, checked every 10 ms) stops them.

use protocol::{
    BoardToHost, Decoder, ExternalPosition, Heartbeat, HostToBoard, ImuSample, Message, Node,
    PilotCommand, WireTime,
};
use virtual_board::bench::{At, Flow, Options, Probe, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::host;
use virtual_board::pilot::{CameraStandIn, Every, MS, Once};

/// The host enables the outputs (in the enabled run), ns.
const ENABLE_AT: u64 = 200 * MS;
/// The host arms, ns.
const ARM_AT: u64 = 1_500 * MS;
/// The host goes silent (the enabled run), ns.
const SILENT_AT: u64 = 2_500 * MS;
/// The height the fixes report once armed, m.
const HOVER_M: f32 = 0.5;
/// The promise: every output at 0 within 100 ms of board time after the host's last sample.
const PROMISE_NS: u64 = 100 * MS;
/// How long the outputs must stay at 0 after they stopped.
const STAY_OFF: u64 = 500 * MS;
/// The IMU period of the host, ns (512 Hz).
const IMU_PERIOD_NS: u64 = 1_953_125;

/// The HIL host and the camera board stand-in, and what the outputs did.
struct Host {
    enable: bool,
    heartbeats: Every,
    samples: Every,
    fixes: Every,
    camera: CameraStandIn,
    enable_at: Once,
    arm_at: Once,
    /// The stop at which the last IMU sample went out.
    last_sample_at: Option<u64>,
    replies: Decoder<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>,
    replies_read: usize,
    /// Largest throttle in the image's `Motors` replies, and how many replies.
    max_command: f32,
    motor_replies: u32,
    /// Largest PWM duty seen on any output, and the first stop with one above 0.
    max_duty: f64,
    first_duty_at: Option<u64>,
    /// Every duty above 0 at a stop in the 100 ms before the silence.
    running_before: bool,
    /// First stop after the silence with every duty 0, and the first after it with one not 0.
    off_at: Option<u64>,
    came_back_at: Option<u64>,
}

impl Host {
    fn new(enable: bool) -> Self {
        Self {
            enable,
            heartbeats: Every::ns(1_000 * MS),
            samples: Every::ns(IMU_PERIOD_NS),
            fixes: Every::ns(20 * MS),
            camera: CameraStandIn::new(),
            enable_at: Once::at(ENABLE_AT),
            arm_at: Once::at(ARM_AT),
            last_sample_at: None,
            replies: Decoder::new_mid_stream(),
            replies_read: 0,
            max_command: 0.0,
            motor_replies: 0,
            max_duty: 0.0,
            first_duty_at: None,
            running_before: false,
            off_at: None,
            came_back_at: None,
        }
    }

    fn silent(&self, now: u64) -> bool {
        self.enable && now >= SILENT_AT
    }

    /// The host's messages due at `now` on the image's telemetry port.
    fn send(&mut self, now: u64, board: &Autopilot) {
        let line = &board.telemetry.rx;
        let send = |m: &HostToBoard| line.send_at(now, &host::frame(m));
        if self.heartbeats.due(now) {
            send(&HostToBoard::Heartbeat(Heartbeat::new(
                Node::Host,
                (now / MS) as u32,
            )));
        }
        if self.enable && self.enable_at.due(now) {
            send(&HostToBoard::Command(PilotCommand::HilOutputs(true)));
        }
        let armed = self.arm_at.fired() || now >= ARM_AT;
        if self.fixes.due(now) {
            let height = if armed { HOVER_M } else { 0.0 };
            send(&HostToBoard::ExternalPosition(ExternalPosition {
                timestamp_us: WireTime((now / 1_000) as u32),
                position_m: [0.0, 0.0, -height],
            }));
        }
        if self.arm_at.due(now) {
            send(&HostToBoard::Command(PilotCommand::Arm));
        }
        if self.samples.due(now) {
            send(&HostToBoard::Imu(ImuSample {
                timestamp_us: WireTime((now / 1_000) as u32),
                gyro_radps: [0.0; 3],
                accel_mps2: [0.0, 0.0, -9.81],
            }));
            self.last_sample_at = Some(now);
        }
    }

    /// The `Motors` replies the image sent since the last stop.
    fn read_replies(&mut self, board: &Autopilot) {
        let sent = board.telemetry.tx.sent_bytes();
        for &byte in sent.get(self.replies_read..).unwrap_or(&[]) {
            if let Some(BoardToHost::Motors(m)) = self.replies.push(byte) {
                self.motor_replies += 1;
                self.max_command = m.throttle.iter().fold(self.max_command, |a, &t| a.max(t));
            }
        }
        self.replies_read = sent.len();
    }
}

impl Probe<Autopilot> for Host {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let board = at.board();
        if !self.silent(now) {
            self.send(now, board);
            self.camera.step(now, &board.link.rx);
        }
        self.read_replies(board);

        let duties = board.motors().map(|m| m.duty);
        let all_off = duties.iter().all(|&d| d == 0.0);
        self.max_duty = duties.iter().fold(self.max_duty, |a, &d| a.max(d));
        if !all_off && self.first_duty_at.is_none() {
            self.first_duty_at = Some(now);
        }
        if !self.enable {
            return Flow::Continue;
        }
        if (SILENT_AT - 100 * MS..SILENT_AT).contains(&now) && duties.iter().all(|&d| d > 0.0) {
            self.running_before = true;
        }
        if now >= SILENT_AT {
            match (self.off_at, all_off) {
                (None, true) => self.off_at = Some(now),
                (Some(_), false) if self.came_back_at.is_none() => self.came_back_at = Some(now),
                _ => {}
            }
        }
        match self.off_at {
            Some(off) if now > off + STAY_OFF => Flow::Stop,
            _ => Flow::Continue,
        }
    }
}

fn fly(enable: bool, seconds: f64) -> (virtual_board::bench::Outcome<Autopilot, Host>, String) {
    let outcome = run(
        Setup {
            board: Autopilot::new(5).expect("the board"),
            firmware: Firmware::hil("autopilot").expect("the hil autopilot image"),
            probe: Host::new(enable),
        },
        Options::seconds(seconds),
    )
    .expect("the run");
    let h = &outcome.probe;
    let report = format!(
        "{}\nmotor replies {}, largest command {:.3}, largest duty {:.3} (first at {:?} ns), last sample at {:?} ns, outputs off at {:?} ns",
        outcome.report(),
        h.motor_replies,
        h.max_command,
        h.max_duty,
        h.first_duty_at,
        h.last_sample_at,
        h.off_at
    );
    (outcome, report)
}

/// Flown by the host and never enabled: every output stays at 0 while the image's commands
/// fly the drone.
#[test]
fn a_hil_image_never_enabled_keeps_every_output_at_zero() {
    let (outcome, report) = fly(false, 3.0);
    outcome.assert_clean();
    let h = &outcome.probe;
    // About 512 replies a second of samples.
    assert!(h.motor_replies >= 1_200, "the lockstep ran: {report}");
    assert!(
        h.max_command > 0.2,
        "the image commanded the motors (armed and flying): {report}"
    );
    assert_eq!(h.first_duty_at, None, "an output ran: {report}");
    assert_eq!(h.max_duty, 0.0, "{report}");
    println!(
        "never enabled: {} motor replies, largest command {:.3}, every duty 0 at every 1 ms stop",
        h.motor_replies, h.max_command
    );
}

/// Enabled, flying, then the host goes silent: every output at 0 within 100 ms of board time
/// of the last sample, and no output runs again.
#[test]
fn a_hil_image_whose_host_goes_silent_stops_the_motors_within_100_ms() {
    let (outcome, report) = fly(true, 3.5);
    outcome.assert_clean();
    let h = &outcome.probe;
    assert!(
        h.first_duty_at.is_some_and(|t| t >= ARM_AT),
        "the outputs ran only once armed: {report}"
    );
    assert!(
        h.running_before,
        "the outputs followed the commands before the silence: {report}"
    );
    let last = h.last_sample_at.expect("samples went out");
    assert!(last < SILENT_AT, "{report}");
    let off = h
        .off_at
        .unwrap_or_else(|| panic!("the outputs never all stopped: {report}"));
    let took = off - last;
    println!(
        "host silent: every output at 0 {:.1} ms of board time after the last sample (promised {:.0} ms)",
        took as f64 / 1e6,
        PROMISE_NS as f64 / 1e6
    );
    assert!(
        took <= PROMISE_NS,
        "outputs off {:.1} ms after the last sample: {report}",
        took as f64 / 1e6
    );
    assert_eq!(h.came_back_at, None, "an output ran again: {report}");
}
