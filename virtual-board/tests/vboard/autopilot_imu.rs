//! Test 3: the autopilot samples its IMU at its loop rate, and once armed as a user arms it
//! (the ground tool's height fixes and an `Arm` command over the telemetry port,
//! [`virtual_board::pilot::GroundStation`]), its motor duties respond with the right sign to a
//! body rate on each axis.
//!
//! The timing half runs at both core rates ([`CoreRate`]): the loop's start jitter, its worst
//! step (the loop's interrupt to its last motor register write) against its period, and the
//! telemetry port's queues (nothing lost or dropped). The slow core runs with the fastest LSI
//! (47 kHz): the watchdog at its shortest timeout with the feeding task at its slowest.

use virtual_board::bench::{At, Flow, Options, Probe, Setup, run};
use virtual_board::boards::autopilot::{Autopilot, MOTOR_PWM_HZ, MOTORS};
use virtual_board::firmware::Firmware;
use virtual_board::host;
use virtual_board::pilot::{GroundStation, MS};
use virtual_board::timing::{CoreRate, LSI_HZ_FASTEST, LSI_HZ_TYPICAL};

/// The autopilot's control loop rate, Hz (autopilot::board::LOOP_RATE_HZ).
const LOOP_HZ: f64 = autopilot::board::LOOP_RATE_HZ as f64;

/// The firmware's flight height, m: the ground station's drone climbs to it at the firmware's
/// climb rate, as the height setpoint does, so that the height loop holds a steady thrust
/// through the baseline and the test windows (they compare duties).
fn flight_height_m() -> f64 {
    f64::from(
        autopilot::AutopilotConfig::default()
            .setpoints
            .target_height_m,
    )
}

/// When the test arms, and the phases after it.
const ARM_AT: u64 = 1_500 * MS;
const BASELINE: (u64, u64) = (2_200 * MS, 2_400 * MS);
/// Each axis gets a body rate of +`RATE` rad/s for this window (after a settle), then rest.
const AXIS_START: [u64; 3] = [2_500 * MS, 3_000 * MS, 3_500 * MS];
const AXIS_SETTLE: u64 = 30 * MS;
const AXIS_HOLD: u64 = 150 * MS;
const RATE: f64 = 1.0;
/// Bound on the 512 Hz loop's start jitter, µs: a tenth of its 1953 µs period. The loop runs
/// at priority 5, above every task but the UART interrupts (a few µs per byte); what delays it
/// is a lower task's lock of a resource it shares (the autopilot state, the motors, the SPI
/// bus: the guidance step, the barometer's one transfer) and those interrupts. INDI integrates
/// with the measured step, so a tenth of a period costs no accuracy; more would mean a task
/// holds a shared lock too long.
const LOOP_JITTER_BOUND_US: f64 = 200.0;
/// Bound on the loop's worst step (its interrupt's entry to its last motor register write), µs:
/// half its period, leaving the other half to every lower-priority task.
const LOOP_STEP_BOUND_US: f64 = 976.0;
/// The motor outputs' duty registers: TIM3 and TIM5 CCR1..CCR2 (RM0090 table 1 and 18.4).
const MOTOR_CCRS: [u64; 2] = [0x4000_0400 + 0x34, 0x4000_0C00 + 0x34];

/// Motor duty registers a step writes (`Motors::set`: four channels).
const MOTOR_WRITES_PER_STEP: u32 = 4;
/// The loop's rate, jitter and steps are measured from here on: after the boot (0.6 s at the
/// slow core rate, whose start-up delays are counted in instructions) and the gyro's start-up
/// samples (rejected, they write no motors).
const STEPS_FROM: u64 = 1_000 * MS;

/// The 512 Hz loop's steps as the bench sees them: its interrupt's entry (the `TIM2` handler
/// RTIC binds it to) and the four motor register writes that end it. A lower task's writes
/// (the guidance task's motors-off) come after the loop returns, beyond a step's four.
#[derive(Default)]
struct Steps {
    /// The `TIM2` handler's address; watches are armed at the first stop.
    entry: u64,
    armed: bool,
    /// The current step's entry (virtual time, ns, and instruction count), and its motor
    /// writes so far.
    started: Option<(u64, u64)>,
    writes: u32,
    /// The worst step (ns, instructions) and how many steps wrote the motors.
    worst: (u64, u64),
    count: u64,
}

impl Steps {
    fn arm(&mut self, session: &mut rigless::session::Session<Autopilot>) {
        use rigless::emulator::Watch;
        if !self.armed {
            self.armed = true;
            session.watch(Watch::Instruction(self.entry));
            for ccr in MOTOR_CCRS {
                session.watch(Watch::Writes {
                    address: ccr,
                    length: 8,
                });
            }
        }
    }

    fn hit(&mut self, hit: &rigless::emulator::Hit) {
        let (at, count) = (hit.at.0, hit.instruction_count);
        if hit.kind == rigless::emulator::HitKind::Instruction && hit.address == self.entry {
            self.started = (at >= STEPS_FROM).then_some((at, count));
            self.writes = 0;
        } else if let Some((t0, c0)) = self.started {
            self.writes += 1;
            if self.writes == MOTOR_WRITES_PER_STEP {
                self.count += 1;
                self.worst = (self.worst.0.max(at - t0), self.worst.1.max(count - c0));
                self.started = None;
            }
        }
    }
}

struct Pilot {
    steps: Steps,
    ground: GroundStation,
    baseline: Vec<[f64; 4]>,
    /// The four outputs' PWM periods (ns, `None`: no PWM) at each baseline stop, in
    /// [`virtual_board::boards::autopilot::MOTORS`] order.
    periods: Vec<[Option<u64>; 4]>,
    during: [Vec<[f64; 4]>; 3],
}

fn mean(samples: &[[f64; 4]]) -> [f64; 4] {
    let n = samples.len().max(1) as f64;
    std::array::from_fn(|i| samples.iter().map(|s| s[i]).sum::<f64>() / n)
}

impl Pilot {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let board = at.board();
        self.ground.step(now, &board.telemetry.rx);
        // In the mixer's order, to compare with its pattern.
        let duties = board.duties_in_mixer_order();
        if (BASELINE.0..BASELINE.1).contains(&now) {
            self.baseline.push(duties);
            self.periods.push(board.motors().map(|m| m.period_ns));
        }
        let mut rate = [0.0; 3];
        for (axis, &start) in AXIS_START.iter().enumerate() {
            if (start..start + AXIS_SETTLE + AXIS_HOLD).contains(&now) {
                rate[axis] = RATE;
                if now >= start + AXIS_SETTLE {
                    self.during[axis].push(duties);
                }
            }
        }
        board.set_body_rate(rate);
        Flow::Continue
    }
}

impl Probe<Autopilot> for Pilot {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        self.steps.arm(at.session);
        Pilot::at(self, at)
    }

    fn hit(
        &mut self,
        hit: &rigless::emulator::Hit,
        _session: &mut rigless::session::Session<Autopilot>,
        _host: &mut dyn rigless::emulator::Host,
    ) {
        self.steps.hit(hit);
    }
}

#[test]
fn the_imu_is_sampled_at_the_loop_rate_and_the_motors_oppose_a_body_rate() {
    the_loop_at(CoreRate::Default, LSI_HZ_TYPICAL);
}

/// The same at 1.5 cycles per instruction, the watchdog on the fastest LSI.
#[test]
fn the_loop_keeps_its_rate_and_margins_on_a_slow_core_and_a_fast_watchdog() {
    the_loop_at(CoreRate::Pessimistic, LSI_HZ_FASTEST);
}

fn the_loop_at(rate: CoreRate, lsi_hz: u64) {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let entry = firmware.symbol("TIM2").expect("the 512 Hz loop's handler");
    let mut board = Autopilot::new(7).expect("the board");
    board.soc.set_core_rate(rate);
    board.soc.set_lsi_hz(lsi_hz);
    let mut outcome = run(
        Setup {
            board,
            firmware,
            probe: Pilot {
                steps: Steps {
                    entry,
                    ..Steps::default()
                },
                // As if taking off to the flight height once armed (the rate test flies no
                // world): the height follows the firmware's own setpoint ramp.
                ground: GroundStation::arming_at(ARM_AT, flight_height_m()),
                baseline: Vec::new(),
                periods: Vec::new(),
                during: Default::default(),
            },
        },
        Options::seconds(4.0),
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    assert!(
        outcome.session.resets().is_empty(),
        "{}, LSI {lsi_hz} Hz: the part was reset\n{report}",
        rate.label()
    );

    // The loop rate: sensor reads per second over a second after the boot.
    let reads = outcome.session.board_mut().imu().sensor_reads().to_vec();
    let window = |from: u64, to: u64| reads.iter().filter(|(t, _)| (from..to).contains(t)).count();
    let per_second = window(STEPS_FROM, STEPS_FROM + 1_000 * MS) as f64;
    assert!(
        (per_second - LOOP_HZ).abs() <= 0.02 * LOOP_HZ,
        "IMU reads per second {per_second}, loop rate {LOOP_HZ}\n{report}"
    );
    // The loop's start jitter with telemetry running: how far each IMU read lands from the
    // period after the one before.
    let period_ns = 1e9 / LOOP_HZ;
    let worst_ns = reads
        .windows(2)
        .filter(|w| w[0].0 >= STEPS_FROM)
        .map(|w| ((w[1].0 - w[0].0) as f64 - period_ns).abs())
        .fold(0.0, f64::max);
    // The firmware's own figure (the status line's `loop_jitter_max_us`, the largest deviation
    // of the loop's start from its period since boot), with telemetry running at 10 Hz.
    let firmware_us: u32 = outcome
        .log
        .lines()
        .iter()
        .rev()
        .find_map(|l| {
            let at = l.text.find("loop_jitter_max_us=")?;
            let digits = &l.text[at + "loop_jitter_max_us=".len()..];
            digits.split(' ').next()?.parse().ok()
        })
        .unwrap_or_else(|| panic!("no loop_jitter_max_us in the status lines\n{report}"));
    let (sent, errors) = host::decode_board_to_host(&outcome.board().telemetry.tx.sent_bytes());
    let telemetry = sent
        .iter()
        .filter(|m| matches!(m, protocol::BoardToHost::Telemetry(_)))
        .count();
    let steps = &outcome.probe.steps;
    let (step_ns, step_insns) = steps.worst;
    println!(
        "{}: 512 Hz loop: {per_second} IMU reads/s, worst start jitter {:.1} us measured on the \
         bench (IMU read to IMU read against the {:.1} us period, {} reads), {firmware_us} us by \
         the firmware; worst step {:.1} us ({step_insns} instructions, {} steps; bound \
         {LOOP_STEP_BOUND_US} us); {telemetry} telemetry frames sent meanwhile",
        rate.label(),
        worst_ns / 1e3,
        period_ns / 1e3,
        reads.len(),
        step_ns as f64 / 1e3,
        steps.count
    );
    assert!(
        steps.count as f64 >= 0.9 * 3.0 * LOOP_HZ,
        "{} steps wrote the motors over 3 s\n{report}",
        steps.count
    );
    assert!(
        (step_ns as f64) / 1e3 < LOOP_STEP_BOUND_US,
        "worst loop step {:.1} us, bound {LOOP_STEP_BOUND_US} us\n{report}",
        step_ns as f64 / 1e3
    );
    // The telemetry port's queues: no received byte lost, no frame dropped for a full queue.
    for queue in ["rx_lost", "tx_dropped"] {
        assert_eq!(
            outcome.log.status(queue),
            Some(0),
            "{queue} in the last status line\n{report}"
        );
    }
    assert_eq!(errors, 0, "the telemetry decodes\n{report}");
    assert!(
        telemetry >= 30,
        "telemetry ran (10 Hz from the boot, 0.4 to 0.6 s, to 4 s): {telemetry} frames\n{report}"
    );
    assert!(
        worst_ns / 1e3 < LOOP_JITTER_BOUND_US && f64::from(firmware_us) < LOOP_JITTER_BOUND_US,
        "loop start jitter {:.1} us (bench) / {firmware_us} us (firmware), bound \
         {LOOP_JITTER_BOUND_US} us\n{report}",
        worst_ns / 1e3
    );

    // Each read sees a fresh sample (the chip runs at least as fast as the loop).
    let fresh = reads.windows(2).filter(|w| w[1].1 != w[0].1).count();
    assert!(
        fresh as f64 >= 0.98 * (reads.len() - 1) as f64,
        "{fresh} of {} reads saw a new sample\n{report}",
        reads.len()
    );

    // Armed: the motors run, and a body rate on each axis moves them the way the airframe's
    // mixer opposes it (a positive rate asks for a negative torque about that axis).
    let pilot = &outcome.probe;
    let baseline = mean(&pilot.baseline);
    assert!(
        baseline.iter().all(|&d| d > 0.05),
        "armed, the motors should run: baseline duties {baseline:?}\n{report}"
    );
    // Each motor output is a PWM at the airframe's 36 kHz, on its pin and
    // timer channel (PC6 TIM3 CH1, PC7 TIM3 CH2, PA0 TIM5 CH1, PA1 TIM5 CH2), at every stop.
    let want_ns = 1e9 / MOTOR_PWM_HZ as f64;
    assert!(!pilot.periods.is_empty(), "no baseline stops\n{report}");
    for periods in &pilot.periods {
        for (motor, period) in MOTORS.iter().zip(periods) {
            let period = period.unwrap_or_else(|| {
                panic!(
                    "{} {} CH{}: not a PWM output while armed\n{report}",
                    virtual_board::pins::name(motor.port, motor.pin),
                    motor.timer,
                    motor.channel
                )
            });
            assert!(
                (period as f64 - want_ns).abs() / want_ns < 0.01,
                "{} {} CH{}: PWM period {period} ns ({:.0} Hz), the airframe's {MOTOR_PWM_HZ} Hz\n{report}",
                virtual_board::pins::name(motor.port, motor.pin),
                motor.timer,
                motor.channel,
                1e9 / period as f64
            );
        }
    }
    println!(
        "motor PWM: {:?} ns periods ({:.0} Hz wanted)",
        pilot.periods[0], MOTOR_PWM_HZ as f64
    );
    for axis in 0..3 {
        let during = mean(&pilot.during[axis]);
        let mut torque = [0.0f32; 3];
        torque[axis] = -0.2;
        let expected = autopilot::mixer::mix(0.5, torque[0], torque[1], torque[2]).throttle;
        let neutral = autopilot::mixer::mix(0.5, 0.0, 0.0, 0.0).throttle;
        let response: f64 = (0..4)
            .map(|m| (during[m] - baseline[m]) * f64::from(expected[m] - neutral[m]))
            .sum();
        assert!(
            response > 0.0,
            "axis {axis}: duties {during:?} against baseline {baseline:?} do not oppose a \
             positive body rate (mixer pattern {expected:?})\n{report}"
        );
    }
}

/// The host-link test's phases: the baseline, a window of host IMU samples claiming a roll
/// rate, a window of the same roll rate on the real sensor, each held after a settle.
const HOST_BASELINE: (u64, u64) = (2_100 * MS, 2_400 * MS);
const HOST_WINDOW: u64 = 2_500 * MS;
const REAL_WINDOW: u64 = 3_000 * MS;
const WINDOW_HOLD: u64 = 300 * MS;
/// One host IMU sample this often: a frame is about 40 bytes, 3.5 ms at the telemetry port's
/// 115,200 Bd, beside the height fixes.
const HOST_SAMPLE_PERIOD: u64 = 10 * MS;
/// The claimed (and, in the second window, real) roll rate, rad/s.
const HOST_RATE: f64 = 1.0;

struct HostImuPilot {
    ground: GroundStation,
    samples: virtual_board::pilot::Every,
    sent: u64,
    baseline: Vec<[f64; 4]>,
    host: Vec<[f64; 4]>,
    real: Vec<[f64; 4]>,
}

fn in_window(now: u64, start: u64) -> bool {
    (start + AXIS_SETTLE..start + WINDOW_HOLD).contains(&now)
}

impl Probe<Autopilot> for HostImuPilot {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        let board = at.board();
        self.ground.step(now, &board.telemetry.rx);
        let duties = board.duties_in_mixer_order();
        if (HOST_BASELINE.0..HOST_BASELINE.1).contains(&now) {
            self.baseline.push(duties);
        }
        // Host samples: a level, still accelerometer and a roll rate, as `sim-host hil` sends
        // them to a lockstep board.
        if (HOST_WINDOW..HOST_WINDOW + WINDOW_HOLD).contains(&now) && self.samples.due(now) {
            let sample = protocol::HostToBoard::Imu(protocol::ImuSample {
                timestamp_us: protocol::WireTime((now / 1_000) as u32),
                gyro_radps: [HOST_RATE as f32, 0.0, 0.0],
                accel_mps2: [0.0, 0.0, -9.81],
            });
            board.telemetry.rx.send_at(now, &host::frame(&sample));
            self.sent += 1;
        }
        if in_window(now, HOST_WINDOW) {
            self.host.push(duties);
        }
        let real = (REAL_WINDOW..REAL_WINDOW + WINDOW_HOLD).contains(&now);
        board.set_body_rate([if real { HOST_RATE } else { 0.0 }, 0.0, 0.0]);
        if in_window(now, REAL_WINDOW) {
            self.real.push(duties);
        }
        Flow::Continue
    }
}

/// Issue 12 item 7: the `real` flavour takes no sensor data from the host link. Armed, it is
/// sent IMU samples on its telemetry port claiming a roll rate: it counts every one refused,
/// its loop goes on sampling its own IMU at the loop rate, and the motors do not answer the
/// claimed rate, while the same rate on the real sensor moves them.
#[test]
fn the_real_flavour_refuses_imu_samples_from_the_host_link() {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let mut outcome = run(
        Setup {
            board: Autopilot::new(9).expect("the board"),
            firmware,
            probe: HostImuPilot {
                ground: GroundStation::arming_at(ARM_AT, flight_height_m()),
                samples: virtual_board::pilot::Every::ns(HOST_SAMPLE_PERIOD),
                sent: 0,
                baseline: Vec::new(),
                host: Vec::new(),
                real: Vec::new(),
            },
        },
        Options::seconds(3.6),
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();
    let pilot = &outcome.probe;
    let rejected = outcome
        .log
        .status("host_sensor_rejected")
        .unwrap_or_else(|| panic!("no host_sensor_rejected in the status lines\n{report}"));
    assert!(pilot.sent >= 25, "{} host samples sent", pilot.sent);
    // The ground station's fixes (a motion-capture take-off) pass the vertical filter's gate
    // until the real sensor's roll (which the still accelerometer contradicts) tilts the
    // estimate's vertical axis.
    assert_eq!(
        outcome.log.status_before("fixes_refused", REAL_WINDOW),
        Some(0),
        "height fixes refused by the gate\n{report}"
    );
    assert_eq!(
        rejected, pilot.sent,
        "host IMU samples sent {}, refused {rejected}\n{report}",
        pilot.sent
    );
    // The loop kept its own clock and its own sensor through the host samples.
    let reads = outcome.session.board_mut().imu().sensor_reads().to_vec();
    let in_host_window = reads
        .iter()
        .filter(|(t, _)| (HOST_WINDOW..HOST_WINDOW + WINDOW_HOLD).contains(t))
        .count() as f64;
    let expected = LOOP_HZ * WINDOW_HOLD as f64 / 1e9;
    assert!(
        (in_host_window - expected).abs() <= 0.03 * expected + 1.0,
        "{in_host_window} IMU reads in the host window, {expected} at the loop rate\n{report}"
    );
    // No sample of the real IMU rejected from before the host samples to the end (the gyro's
    // start-up after boot is rejected, and counted, before that).
    assert_eq!(
        outcome.log.status("imu_invalid"),
        outcome.log.status_before("imu_invalid", HOST_WINDOW),
        "the real IMU's samples stayed valid\n{report}"
    );
    // The roll pattern of the mixer: how far the duties moved the way a positive roll rate
    // makes them move.
    let baseline = mean(&pilot.baseline);
    let expected = autopilot::mixer::mix(0.5, -0.2, 0.0, 0.0).throttle;
    let neutral = autopilot::mixer::mix(0.5, 0.0, 0.0, 0.0).throttle;
    let response = |samples: &[[f64; 4]]| -> f64 {
        let during = mean(samples);
        (0..4)
            .map(|m| (during[m] - baseline[m]) * f64::from(expected[m] - neutral[m]))
            .sum()
    };
    let (host, real) = (response(&pilot.host), response(&pilot.real));
    println!(
        "host IMU samples: {} sent, {rejected} refused; roll response to the host's rate {host:.2e}, \
         to the sensor's {real:.2e}",
        pilot.sent
    );
    assert!(
        real > 0.0,
        "the real sensor's roll rate moved the motors ({real:.2e})\n{report}"
    );
    assert!(
        host.abs() < 0.2 * real,
        "the motors answered the host's samples: {host:.2e} against the sensor's {real:.2e}\n{report}"
    );
}
