//! The autopilot's `real` image flies through its clock's wraps: the board's 32-bit
//! millisecond tick (the RTIC SysTick monotonic's counter, 49.7 days of uptime) and, at the same
//! instant, the 32-bit microsecond wire time (2^32 ms is exactly 1000 x 2^32 µs).
//!
//! No hours of waiting: during `init` (interrupts still masked, so the counter has not counted
//! yet and no task waits on the monotonic) the bench writes the monotonic's counter in RAM
//! (`rtic_monotonics::systick::SYSTICK_CNT`) as a board 49.7 days up would hold it, so that it
//! wraps [`TICKS_TO_WRAP`] ms after it starts counting, in flight. Then, measured on the image: the 512 Hz
//! loop keeps its rate and jitter across the wrap (on the bench's IMU reads and by the
//! firmware's own `loop_jitter_max_us`), the camera's estimates and the host's heartbeats stay
//! fresh (the telemetry never reports a hover without estimates, a landing or a failsafe), the
//! motors never all stop, the part is never reset, and a host `Kill` after the wrap
//! stops every motor within a loop period.

use protocol::{BoardToHost, Decoder, FlightMode, HostToBoard, Message, PilotCommand};
use virtual_board::bench::{At, Flow, Options, Probe, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::pilot::{CameraStandIn, GroundStation, MS, Once};

const ARM_AT: u64 = 1_500 * MS;
/// When the bench sets the counter (virtual ns): `.bss` is zeroed, `init` still runs.
const SET_AT: u64 = 10 * MS;
/// Milliseconds the counter counts before it wraps (it starts at the end of `init`).
const TICKS_TO_WRAP: u64 = 3_000;
/// The host's `Kill`, after the wrap.
const KILL_AT: u64 = 4_600 * MS;
/// The motors never all stop from here to the kill.
const RUNNING_FROM: u64 = ARM_AT + 500 * MS;
/// The loop's start-jitter bound, µs (as `autopilot_imu`: a tenth of the period).
const LOOP_JITTER_BOUND_US: f64 = 200.0;
/// A `Kill` stops the motors at the next 512 Hz step: a loop period and a bench stop.
const KILL_PROMISE_NS: u64 =
    1_000_000_000 / autopilot::board::LOOP_RATE_HZ as u64 + 1_000 * KILL_STEP_US;
/// The bench's stop period, µs.
const KILL_STEP_US: u64 = 100;

struct Pilot {
    /// The monotonic's counter (`SYSTICK_CNT`).
    counter: u64,
    /// When the counter was set (virtual ns), its value read then and the value written.
    set: Option<(u64, u64, u64)>,
    /// Whether the firmware had logged its end of `init` when the counter was set.
    init_done_at_set: bool,
    /// The counter's last value read, and when it wrapped (virtual ns).
    last_count: u64,
    wrapped_at: Option<u64>,
    ground: GroundStation,
    camera: CameraStandIn,
    kill: Once,
    telemetry: Decoder<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>,
    telemetry_read: usize,
    /// Telemetry frames decoded after the wrap, and every (time, mode, failsafe) seen while
    /// the motors must run that was not plain flying.
    telemetry_after_wrap: usize,
    not_flying: Vec<(u64, FlightMode, Option<protocol::FailsafeReason>)>,
    /// Stops between [`RUNNING_FROM`] and the kill with every motor at 0. (The bench flies no
    /// world: the IMU does not answer the motors, so single duties wander to their limits.)
    stopped: Vec<u64>,
    /// First stop after the kill with every duty at 0.
    off_at: Option<u64>,
}

impl Probe<Autopilot> for Pilot {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let count = at
            .host
            .read(self.counter, rigless::soc::Width::W32)
            .expect("the counter is in RAM");
        if self.set.is_none() {
            if now >= SET_AT {
                let to = (1u64 << 32) - TICKS_TO_WRAP;
                at.host
                    .write(self.counter, rigless::soc::Width::W32, to)
                    .expect("RAM takes a word");
                self.init_done_at_set = at
                    .log
                    .lines()
                    .iter()
                    .any(|l| l.text.contains("autopilot up"));
                self.set = Some((now, count, to));
                self.last_count = to;
            }
        } else {
            if self.wrapped_at.is_none() && count < self.last_count {
                self.wrapped_at = Some(now);
            }
            self.last_count = count;
        }
        if self.kill.due(now) {
            let kill = HostToBoard::Command(PilotCommand::Kill);
            at.board()
                .telemetry
                .rx
                .send_at(now, &virtual_board::host::frame(&kill));
        }
        let board = at.board();
        self.camera.step(now, &board.link.rx);
        self.ground.step(now, &board.telemetry.rx);
        let sent = board.telemetry.tx.sent_bytes();
        for &byte in sent.get(self.telemetry_read..).unwrap_or(&[]) {
            if let Some(BoardToHost::Telemetry(t)) = self.telemetry.push(byte) {
                if self.wrapped_at.is_some() {
                    self.telemetry_after_wrap += 1;
                }
                if (RUNNING_FROM..KILL_AT).contains(&now)
                    && (t.flight_mode != FlightMode::Flying || t.failsafe_reason.is_some())
                {
                    self.not_flying
                        .push((now, t.flight_mode, t.failsafe_reason));
                }
            }
        }
        self.telemetry_read = sent.len();
        let duties = board.motors().map(|m| m.duty);
        if (RUNNING_FROM..KILL_AT).contains(&now) && duties.iter().all(|&d| d <= 0.0) {
            self.stopped.push(now);
        }
        if now > KILL_AT && self.off_at.is_none() && duties.iter().all(|&d| d == 0.0) {
            self.off_at = Some(now);
        }
        Flow::Continue
    }
}

/// The value of `key=` in a status line.
fn field(line: &str, key: &str) -> Option<u64> {
    line.split_whitespace()
        .find_map(|f| f.strip_prefix(key)?.strip_prefix('='))?
        .parse()
        .ok()
}

#[test]
fn the_autopilot_flies_through_its_clock_wraps() {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let counters: Vec<(String, u64)> = firmware
        .symbols_containing("SYSTICK_CNT")
        .map(|(name, address)| (name.to_string(), address))
        .collect();
    let [(_, counter)] = counters.as_slice() else {
        panic!("one SysTick monotonic counter in the image: {counters:?}");
    };
    let board = Autopilot::new(5).expect("the board");
    let mut outcome = run(
        Setup {
            board,
            firmware,
            probe: Pilot {
                counter: *counter,
                set: None,
                init_done_at_set: false,
                last_count: 0,
                wrapped_at: None,
                ground: GroundStation::arming_at(ARM_AT, 0.5),
                camera: CameraStandIn::new(),
                kill: Once::at(KILL_AT),
                telemetry: Decoder::new_mid_stream(),
                telemetry_read: 0,
                telemetry_after_wrap: 0,
                not_flying: Vec::new(),
                stopped: Vec::new(),
                off_at: None,
            },
        },
        Options::seconds(5.0).step_us(KILL_STEP_US),
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    let pilot = &outcome.probe;
    let (set_at, from, to) = pilot
        .set
        .unwrap_or_else(|| panic!("the bench never set the counter\n{report}"));
    let wrap_at = pilot
        .wrapped_at
        .unwrap_or_else(|| panic!("the counter never wrapped\n{report}"));
    println!(
        "the monotonic's counter set from {from} to {to} at {:.1} ms; it wrapped at {:.1} ms",
        set_at as f64 / 1e6,
        wrap_at as f64 / 1e6
    );
    assert!(
        from == 0 && !pilot.init_done_at_set,
        "the counter was set after init (it read {from})\n{report}"
    );
    assert!(
        (RUNNING_FROM + 500 * MS..KILL_AT - 500 * MS).contains(&wrap_at),
        "the wrap at {wrap_at} ns is not in flight\n{report}"
    );
    assert!(
        outcome.session.resets().is_empty(),
        "the part was reset\n{report}"
    );

    // The firmware's own clock wrapped: its status lines' uptime (ms, 32 bits) is just below
    // 2^32 before the wrap and small after it.
    let uptimes: Vec<u64> = outcome
        .log
        .lines()
        .iter()
        .filter(|l| l.text.contains("status uptime_ms="))
        .filter_map(|l| field(&l.text, "uptime_ms"))
        .collect();
    println!("status uptime_ms: {uptimes:?}");
    let near_wrap = u64::from(u32::MAX) - 10_000;
    assert!(
        uptimes.iter().any(|&u| u > near_wrap) && uptimes.last().is_some_and(|&u| u < 10_000),
        "no wrap in the status lines' uptime: {uptimes:?}\n{report}"
    );

    // The loop's rate and jitter across the wrap: on the bench's IMU reads in the second
    // around it, and by the firmware's figure since boot.
    let reads = outcome.session.board_mut().imu().sensor_reads().to_vec();
    let around: Vec<u64> = reads
        .iter()
        .map(|&(t, _)| t)
        .filter(|t| (wrap_at - 500 * MS..wrap_at + 500 * MS).contains(t))
        .collect();
    let hz = autopilot::board::LOOP_RATE_HZ as f64;
    assert!(
        (around.len() as f64 - hz).abs() <= 0.02 * hz,
        "{} IMU reads in the second around the wrap, loop rate {hz}\n{report}",
        around.len()
    );
    let period_ns = 1e9 / hz;
    let worst_us = around
        .windows(2)
        .map(|w| ((w[1] - w[0]) as f64 - period_ns).abs())
        .fold(0.0, f64::max)
        / 1e3;
    let firmware_us = outcome
        .log
        .status("loop_jitter_max_us")
        .unwrap_or_else(|| panic!("no loop_jitter_max_us\n{report}"));
    println!(
        "around the wrap: {} IMU reads/s, worst start jitter {worst_us:.1} us (bench), \
         {firmware_us} us since boot (firmware)",
        around.len()
    );
    assert!(
        worst_us < LOOP_JITTER_BOUND_US && (firmware_us as f64) < LOOP_JITTER_BOUND_US,
        "loop jitter {worst_us:.1} us (bench) / {firmware_us} us (firmware)\n{report}"
    );

    // Flying on fresh estimates and heartbeats throughout, the motors never stopped.
    assert!(
        pilot.not_flying.is_empty(),
        "not flying (time ns, mode, failsafe): {:?}\n{report}",
        pilot.not_flying
    );
    assert!(
        pilot.telemetry_after_wrap >= 10,
        "{} telemetry frames after the wrap\n{report}",
        pilot.telemetry_after_wrap
    );
    assert!(
        pilot.stopped.is_empty(),
        "every motor at 0 while flying, first at {:?} ns\n{report}",
        pilot.stopped.first()
    );
    let off_at = pilot
        .off_at
        .unwrap_or_else(|| panic!("the kill after the wrap did not stop the motors\n{report}"));
    println!(
        "the kill after the wrap: every motor at 0 {:.2} ms after it (promised {:.2} ms)",
        (off_at - KILL_AT) as f64 / 1e6,
        KILL_PROMISE_NS as f64 / 1e6
    );
    assert!(
        off_at - KILL_AT <= KILL_PROMISE_NS,
        "motors off {:.2} ms after the kill\n{report}",
        (off_at - KILL_AT) as f64 / 1e6
    );
}
