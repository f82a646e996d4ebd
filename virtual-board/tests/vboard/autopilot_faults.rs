//! Test 5 (autopilot side): armed and running, each fault ends with every motor duty at 0
//! within the time the failsafe promises, measured on the PWM outputs, and no motor runs again
//! without a new `Arm`.
//!
//! Every fault is injected from the bench; the image is the unmodified `real` flavour:
//!
//! | fault | injection | promise |
//! |---|---|---|
//! | IMU frozen | the MPU-6000's registers stop updating | [`autopilot::mpu6000::fault_motors_off`] |
//! | IMU unplugged | MISO pulled high: every byte 0xFF | the same |
//! | IMU at full scale | a body rate beyond the gyro's +-2000 deg/s range: one axis reads +32767 (the model saturates, RM 4.19), the others stay live | the same |
//! | IMU reset | the MPU-6000 resets (a brown-out): registers at their defaults, asleep, silent for its reset time; the firmware must configure it again | the same; the chip configured and sampling again within [`IMU_BACK_NS`], the motors off until a new `Arm` |
//! | bus fault | the next access to SPI2 is a bus error: HardFault | [`autopilot::board::FAULT_MOTORS_OFF`] |
//! | stack overflow | a runaway recursion: one function of the 512 Hz loop returns into two instructions that push without end ([`virtual_board::inject::Payload::RunawayRecursion`]) until the stack leaves SRAM (flip-link: the stack is the bottom of SRAM) | the same: the HardFault path stops the motors although the stack is used up |
//! | unbound interrupt | one function of the 512 Hz loop returns into instructions that enable and pend IRQ 0 (`WWDG`), which the image has no handler for ([`virtual_board::inject::Payload::UnboundInterrupt`]) | the same, from the `DefaultHandler`'s arrival; it names the vector |
//! | panic | the logger's "taken" flag set under the firmware: its next log line panics (defmt-rtt's re-entrancy check) | the same |
//! | hung task | SPI2's SPE cleared under the firmware (its register file, at a stop): the 512 Hz loop's blocking transfer never ends | [`autopilot::board::WATCHDOG_MS`] at every LSI (the watchdog resets the part; its programmed [`autopilot::board::WATCHDOG`] at the run's LSI) |
//!
//! The HardFault and panic paths' motor-off latency is measured to the instruction: after the
//! fault the bench watches every store to the motor timers and pins and reads the outputs at
//! each. The hard fault runs at both core rates ([`CoreRate`]), the hung loop at the typical,
//! slowest and fastest LSI (the watchdog's timeout scales with it).
//!
//! | link cut | the camera board's estimates stop | [`autopilot::AutopilotConfig::link_loss_motors_off`] (hover, land, touch down) |
//! | camera stopped | the camera board's estimates stop and its 1 Hz `Status` reports `camera_stopped` (heartbeats go on) | [`autopilot::AutopilotConfig::camera_stopped_motors_off`] from the report (hover at once, land, touch down) |
//! | telemetry link cut | flying on the barometer (no height fixes, as without motion capture), the host's heartbeats stop | [`autopilot::AutopilotConfig::host_loss_motors_off`] (`fs_host_timeout_us`, land, touch down), the landing reported as `telemetry-lost` |
//! | host kill | a `PilotCommand::Kill` on the telemetry port | [`KILL_AFTER_LAST_BYTE_NS`]: the next 512 Hz step after the command's last byte reached the board |
//! | frozen barometer | flying on the barometer (no height fixes), the MS5611 answers every conversion with its last word ([`virtual_board::ms5611::Barometer::set_frozen`]) | [`baro_frozen_promise_ns`]: `baro_stuck`, the height timeout, the blind landing; the landing reported as `baro-frozen` |

use protocol::{
    BoardToHost, Decoder, FailsafeReason, FlightMode, HostToBoard, Message, PilotCommand,
};
use virtual_board::bench::{At, Flow, Options, Probe, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::inject::{Payload, ReturnHijack, UNBOUND_IRQ_VECTOR};
use virtual_board::pilot::{CameraStandIn, GroundStation, MS, Once};
use virtual_board::timing::{CoreRate, LSI_HZ_FASTEST, LSI_HZ_SLOWEST, LSI_HZ_TYPICAL};

const ARM_AT: u64 = 1_500 * MS;
const FAULT_AT: u64 = 2_500 * MS;
/// The height the drone reports once armed, m (the bench flies no world).
const HOVER_M: f64 = 0.5;
/// How long the motors must stay off after they stopped (longer than a reboot, 0.3 s).
const STAY_OFF: u64 = 600 * MS;
/// An IMU reset: the chip silent for its reset time, then found asleep at the next 512 Hz step
/// and configured again, then its gyro's start-up (30 ms, PS-MPU-6000A-00 table 6.1) before
/// valid samples; 10 ms of slack for the bench's stops.
const IMU_BACK_NS: u64 = virtual_board::mpu6000::RESET_TIME_NS + 2 * MS + 30 * MS + 10 * MS;
/// The IMU-reset and full-scale runs watch this long after the motors stopped: two status
/// lines (1 Hz) after the fault, so that the samples' verdicts are seen in them.
const IMU_RESET_STAY_OFF: u64 = 2_100 * MS;
/// The full-scale injection's rate in the chip's axes, rad/s: 40 rad/s (2292 deg/s) about the
/// chip's z, beyond the +-2000 deg/s range the firmware sets.
const FULL_SCALE_RATE: [f64; 3] = [0.0, 0.0, 40.0];
/// The MPU-6000's GYRO_ZOUT_H (RM 4.19).
const GYRO_ZOUT_H: u8 = 0x47;
/// SPI2's registers (RM0090 table 1) and its CR1's SPE bit (section 28.5.1).
const SPI2: (u64, u64) = (0x4000_3800, 0x4000_3C00);
const SPI_CR1_SPE: u64 = 1 << 6;
/// A host `Kill` stops every motor at the next 512 Hz step (the library's promise,
/// `kill_stops_motors_at_once`: the step after the command gives 0): one loop period after the
/// command's last byte reached the board, and the bench's stop of [`KILL_STEP_US`].
const KILL_AFTER_LAST_BYTE_NS: u64 =
    1_000_000_000 / autopilot::board::LOOP_RATE_HZ as u64 + KILL_STEP_US * 1_000;
/// The bench's stop period of the kill run, µs (finer than the 1 ms of the others: the
/// promise is a few ms).
const KILL_STEP_US: u64 = 100;
/// What a store can stop a motor with (RM0090 table 1): TIM3's and TIM5's registers (CCMR1,
/// CCR1, CCR2) and the motor pins' ports' MODER to BSRR (GPIOA, GPIOC).
const MOTOR_REGISTERS: [(u64, u64); 4] = [
    (0x4000_0400, 0x40),
    (0x4000_0C00, 0x40),
    (0x4002_0000, 0x1C),
    (0x4002_0800, 0x1C),
];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fault {
    ImuFrozen,
    ImuUnplugged,
    ImuFullScale,
    ImuReset,
    BusError,
    StackOverflow,
    UnboundInterrupt,
    Panic,
    Hang,
    LinkCut,
    CameraStopped,
    TelemetryCut,
    HostKill,
    BaroFrozen,
}

struct Pilot {
    fault: Fault,
    ground: GroundStation,
    camera: CameraStandIn,
    fault_at: Once,
    /// Where the logger's "taken" flag lives (the panic injection).
    logger_taken: Option<u64>,
    /// The stack-overflow injection.
    runaway: Option<ReturnHijack>,
    /// The word 32 bytes above the bottom of the stack region at the first stop after a fault
    /// handler ran (the stack-overflow run: the runaway's pushes reached it).
    stack_bottom_word: Option<u64>,
    /// The firmware's telemetry, decoded as it arrives (the link-cut world follows the flight
    /// mode).
    telemetry: Decoder<BoardToHost, { BoardToHost::MAX_FRAME_BYTES }>,
    telemetry_read: usize,
    landing: bool,
    /// The first telemetry (its last byte's stop) reporting the blind hover after the fault.
    hover_seen_at: Option<u64>,
    /// The first telemetry after the fault reporting a landing, and its failsafe reason.
    landing_seen: Option<(u64, Option<FailsafeReason>)>,
    /// The stop at which the fault was injected (the kill's last byte went on the wire).
    injected_at: Option<u64>,
    last_ns: u64,
    running_before: bool,
    /// First stop after the fault with every duty 0, and the first after that with one not 0.
    off_at: Option<u64>,
    /// The first store after the fault that left every duty at 0, ns (the motor registers are
    /// watched from the fault on).
    off_exact: Option<u64>,
    came_back_at: Option<u64>,
    /// The first stop after the fault at which the MPU-6000 is awake with the firmware's
    /// gyro range again.
    imu_back_at: Option<u64>,
}

impl Pilot {
    fn new(fault: Fault, logger_taken: Option<u64>, runaway: Option<ReturnHijack>) -> Self {
        Self {
            fault,
            ground: if matches!(fault, Fault::BaroFrozen | Fault::TelemetryCut) {
                GroundStation::arming_at(ARM_AT, HOVER_M).without_fixes()
            } else {
                GroundStation::arming_at(ARM_AT, HOVER_M)
            },
            camera: CameraStandIn::new(),
            fault_at: Once::at(FAULT_AT),
            logger_taken,
            runaway,
            stack_bottom_word: None,
            telemetry: Decoder::new_mid_stream(),
            telemetry_read: 0,
            landing: false,
            hover_seen_at: None,
            landing_seen: None,
            injected_at: None,
            last_ns: 0,
            running_before: false,
            off_at: None,
            off_exact: None,
            came_back_at: None,
            imu_back_at: None,
        }
    }

    /// The estimate-loss runs' world: once the firmware reports it is landing, the height it
    /// is told follows its descent setpoint (the land rate) down to the floor.
    fn follow_the_landing(&mut self, now: u64, board: &mut Autopilot) {
        let sent = board.telemetry.tx.sent_bytes();
        for &byte in sent.get(self.telemetry_read..).unwrap_or(&[]) {
            if let Some(BoardToHost::Telemetry(t)) = self.telemetry.push(byte) {
                self.landing = t.flight_mode == FlightMode::Landing;
                if self.landing && now > FAULT_AT && self.landing_seen.is_none() {
                    self.landing_seen = Some((now, t.failsafe_reason));
                }
                if t.flight_mode == FlightMode::HoverNoEstimate
                    && now > FAULT_AT
                    && self.hover_seen_at.is_none()
                {
                    self.hover_seen_at = Some(now);
                }
            }
        }
        self.telemetry_read = sent.len();
        if self.landing {
            // No estimates: the autopilot descends at its blind rate.
            let rate = autopilot::AutopilotConfig::default()
                .setpoints
                .blind_land_rate_mps;
            let dt = (now - self.last_ns) as f64 / 1e9;
            let height = (self.ground.height_m() - f64::from(rate) * dt).max(0.0);
            self.ground.set_height(height);
        }
    }
}

impl Probe<Autopilot> for Pilot {
    fn hit(
        &mut self,
        hit: &rigless::emulator::Hit,
        session: &mut rigless::session::Session<Autopilot>,
        host: &mut dyn rigless::emulator::Host,
    ) {
        if let Some(runaway) = &mut self.runaway {
            runaway.hit(hit, session, host);
        }
        if hit.kind == rigless::emulator::HitKind::Write
            && self.off_exact.is_none()
            && MOTOR_REGISTERS
                .iter()
                .any(|&(base, len)| (base..base + len).contains(&hit.address))
            && session.board().motors().iter().all(|m| m.duty == 0.0)
        {
            self.off_exact = Some(hit.at.0);
        }
    }

    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        if let Some(runaway) = &self.runaway
            && self.fault == Fault::StackOverflow
            && !at.faults.is_empty()
            && self.stack_bottom_word.is_none()
        {
            // The runaway's last whole push ends at least 32 bytes up from the bottom (the
            // push that would cross it faults before it stores).
            let bottom = runaway.stack().0 + 32;
            self.stack_bottom_word = at.host.read(bottom, rigless::soc::Width::W32).ok();
        }
        if self.fault_at.due(now) {
            self.injected_at = Some(now);
            for (address, length) in MOTOR_REGISTERS {
                at.session
                    .watch(rigless::emulator::Watch::Writes { address, length });
            }
            match self.fault {
                Fault::ImuFrozen => at.board().imu().set_frozen(true),
                Fault::ImuUnplugged => at.board().imu().set_unplugged(true),
                Fault::ImuFullScale => at.board().imu().set_rate(FULL_SCALE_RATE),
                Fault::ImuReset => at.board().imu().power_reset(now),
                Fault::BusError => at.session.fail_next(SPI2.0, SPI2.1),
                Fault::StackOverflow | Fault::UnboundInterrupt => {
                    if let Some(runaway) = &mut self.runaway {
                        runaway.arm(at.session);
                    }
                }
                Fault::Panic => {
                    let flag = self.logger_taken.expect("the logger's flag");
                    at.host
                        .write(flag, rigless::soc::Width::W8, 1)
                        .expect("RAM takes a byte");
                }
                Fault::Hang => {
                    use rigless::mcu::Mcu as _;
                    use rigless::soc::stm32f427::generated::spi1::Register;
                    let soc = &mut at.board().soc;
                    let slot = soc.bus().slot("SPI2").expect("SPI2 on the bus");
                    let (registers, _) =
                        soc.bus_mut().drive(rigless::time::VirtualNanos(now), slot);
                    let cr1 = registers.get(Register::Cr1);
                    registers.set(Register::Cr1, cr1 & !SPI_CR1_SPE);
                }
                Fault::LinkCut => {}
                Fault::CameraStopped => self.camera.stop_camera(),
                Fault::TelemetryCut => self.ground.set_silent(true),
                Fault::BaroFrozen => at.board().barometer().set_frozen(true),
                Fault::HostKill => {
                    let kill = HostToBoard::Command(PilotCommand::Kill);
                    let line = &at.board().telemetry.rx;
                    line.send_at(now, &virtual_board::host::frame(&kill));
                }
            }
        }
        let board = at.board();
        if self.fault == Fault::ImuReset && now > FAULT_AT && self.imu_back_at.is_none() {
            let imu = board.imu();
            if imu.awake() && imu.register(autopilot::mpu6000::GYRO_CONFIG) == 0x18 {
                self.imu_back_at = Some(now);
            }
        }
        if !(self.fault == Fault::LinkCut && now >= FAULT_AT) {
            self.camera.step(now, &board.link.rx);
        }
        if matches!(
            self.fault,
            Fault::LinkCut | Fault::CameraStopped | Fault::TelemetryCut | Fault::BaroFrozen
        ) {
            self.follow_the_landing(now, board);
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
        // Watched for long enough after the stop (a reset's reboot included).
        let stay_off = if matches!(self.fault, Fault::ImuReset | Fault::ImuFullScale) {
            IMU_RESET_STAY_OFF
        } else {
            STAY_OFF
        };
        match self.off_at {
            Some(off) if now > off + stay_off => Flow::Stop,
            _ => Flow::Continue,
        }
    }
}

/// The address of defmt-rtt's "taken" flag: the byte `_defmt_acquire` tests first. defmt-rtt
/// keeps it as the first field of its `RTT_ENCODER` static, which the compiler splits into
/// one symbol per field (`RTT_ENCODER.1` is that flag: the lowest-addressed byte field).
fn logger_taken_flag(firmware: &Firmware) -> u64 {
    firmware
        .symbols_containing("RTT_ENCODER")
        .filter(|(name, _)| name.ends_with(".1"))
        .map(|(_, address)| address)
        .min()
        .expect("defmt-rtt's encoder state in the image")
}

/// board_support::stack::PATTERN: the word the firmware paints its unused stack with.
const STACK_PAINT: u32 = 0x57AC_C0DE;

/// The function the stack-overflow and unbound-interrupt injections return from: the MPU-6000
/// sample check, called once per 512 Hz step (`autopilot::mpu6000::SampleCheck::check`, not
/// inlined: it is a library function the loop calls).
fn hijack_in_the_loop(firmware: &Firmware, payload: Payload) -> ReturnHijack {
    let mut tried = Vec::new();
    for (name, _) in firmware.symbols_containing("SampleCheck") {
        match ReturnHijack::new(firmware, name, payload) {
            Ok(runaway) if name.contains("5check") => return runaway,
            Ok(_) => {}
            Err(e) => tried.push(e),
        }
    }
    panic!("no function of the loop to return from: {tried:?}");
}

/// What a fault run saw: the outcome's report, the time to stop, ns, when the telemetry first
/// reported the blind hover after the fault, and when it first reported a landing and why.
type FaultRun = (
    String,
    u64,
    Option<u64>,
    Option<(u64, Option<FailsafeReason>)>,
);

/// Runs `fault` and checks the motors stop within `promise_ns` of it and stay stopped.
/// Returns what the run saw ([`FaultRun`]).
fn fault_stops_the_motors(fault: Fault, promise_ns: u64, run_s: f64) -> FaultRun {
    fault_stops_the_motors_at(fault, promise_ns, run_s, CoreRate::Default, LSI_HZ_TYPICAL)
}

/// [`fault_stops_the_motors`] with the core at `rate` and the LSI at `lsi_hz`.
fn fault_stops_the_motors_at(
    fault: Fault,
    promise_ns: u64,
    run_s: f64,
    rate: CoreRate,
    lsi_hz: u64,
) -> FaultRun {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let logger = (fault == Fault::Panic).then(|| logger_taken_flag(&firmware));
    let runaway = match fault {
        Fault::StackOverflow => Some(hijack_in_the_loop(&firmware, Payload::RunawayRecursion)),
        Fault::UnboundInterrupt => Some(hijack_in_the_loop(&firmware, Payload::UnboundInterrupt)),
        _ => None,
    };
    let mut board = Autopilot::new(11).expect("the board");
    board.soc.set_core_rate(rate);
    board.soc.set_lsi_hz(lsi_hz);
    let mut outcome = run(
        Setup {
            board,
            firmware,
            probe: Pilot::new(fault, logger, runaway),
        },
        if fault == Fault::HostKill {
            Options::seconds(run_s).step_us(KILL_STEP_US)
        } else {
            Options::seconds(run_s)
        },
    )
    .expect("the run");
    let report = outcome.report();
    let pilot = &outcome.probe;
    assert!(
        pilot.running_before,
        "{fault:?}: the motors were not running before the fault\n{report}"
    );
    let off_at = pilot
        .off_at
        .unwrap_or_else(|| panic!("{fault:?}: the motors never all stopped\n{report}"));
    // From the stop the fault went in at (the kill's last byte on the wire), else its instant.
    let took = if fault == Fault::HostKill {
        off_at - pilot.injected_at.expect("the kill went out")
    } else {
        off_at - FAULT_AT
    };
    println!(
        "{fault:?} ({}, LSI {lsi_hz} Hz): every motor at 0 {:.1} ms after the fault (promised \
         {:.1} ms)",
        rate.label(),
        took as f64 / 1e6,
        promise_ns as f64 / 1e6
    );
    assert!(
        outcome.session.resets().iter().all(|r| r.at.0 > FAULT_AT),
        "{fault:?}: the part was reset before the fault\n{report}"
    );
    assert!(
        took <= promise_ns,
        "{fault:?}: motors off after {:.1} ms, promised {:.1} ms\n{report}",
        took as f64 / 1e6,
        promise_ns as f64 / 1e6
    );
    assert_eq!(
        pilot.came_back_at, None,
        "{fault:?}: a motor ran again without a new arm\n{report}"
    );
    match fault {
        Fault::BusError | Fault::Panic | Fault::StackOverflow | Fault::UnboundInterrupt => {
            if fault == Fault::UnboundInterrupt {
                assert!(
                    pilot
                        .runaway
                        .as_ref()
                        .and_then(ReturnHijack::installed_at)
                        .is_some(),
                    "{fault:?}: the injection never ran\n{report}"
                );
                let named =
                    format!("unhandled exception or interrupt: vector {UNBOUND_IRQ_VECTOR}");
                assert!(
                    outcome.logged(&named),
                    "{fault:?}: the DefaultHandler did not report vector {UNBOUND_IRQ_VECTOR}\n{report}"
                );
            }
            if fault == Fault::StackOverflow {
                let runaway = pilot.runaway.as_ref().expect("the injection");
                assert!(
                    runaway.installed_at().is_some(),
                    "{fault:?}: the runaway was never installed\n{report}"
                );
                // The runaway's pushes reached the bottom of the stack region (the paint
                // pattern there is gone), and the firmware says so: the fault is the overflow's.
                assert!(
                    outcome.logged("HardFault: stack overflow"),
                    "{fault:?}: the HardFault path did not report a stack overflow\n{report}"
                );
                assert!(
                    pilot
                        .stack_bottom_word
                        .is_some_and(|w| w != u64::from(STACK_PAINT)),
                    "{fault:?}: the stack's bottom word {:x?} is still the paint: no overflow\n{report}",
                    pilot.stack_bottom_word
                );
            }
            let handler = match fault {
                Fault::Panic => "rust_begin_unwind",
                Fault::UnboundInterrupt => "DefaultHandler",
                _ => "HardFault",
            };
            let first = outcome
                .faults
                .first()
                .unwrap_or_else(|| panic!("{fault:?}: no fault handler ran\n{report}"));
            assert!(
                first.handler.contains(handler),
                "{fault:?}: the first fault was {first:?}\n{report}"
            );
            // The handler stops the motors first: every output off within the promise of its
            // arrival, to the instruction.
            let off_exact = pilot.off_exact.unwrap_or_else(|| {
                panic!("{fault:?}: no store after the fault stopped the motors\n{report}")
            });
            let latency_ns = off_exact.saturating_sub(first.at_ns);
            println!(
                "{fault:?} ({}): {} reached at {:.6} ms, every motor at 0 {:.2} us later \
                 (promised {} us)",
                rate.label(),
                first.handler,
                first.at_ns as f64 / 1e6,
                latency_ns as f64 / 1e3,
                autopilot::board::FAULT_MOTORS_OFF.as_micros()
            );
            assert!(
                off_exact >= first.at_ns
                    && latency_ns <= autopilot::board::FAULT_MOTORS_OFF.as_micros() * 1_000,
                "{fault:?}: handler at {:.6} ms, motors off at {:.6} ms\n{report}",
                first.at_ns as f64 / 1e6,
                off_exact as f64 / 1e6
            );
        }
        Fault::Hang => {
            let reset = outcome.session.resets().first().unwrap_or_else(|| {
                panic!("{fault:?}: the watchdog never reset the part\n{report}")
            });
            assert_eq!(
                reset.cause,
                rigless::device::ResetCause::Model("IWDG"),
                "{fault:?}: the reset is the watchdog's\n{report}"
            );
            println!(
                "{fault:?} (LSI {lsi_hz} Hz): the watchdog reset the part {:.2} ms after the \
                 hang",
                (reset.at.0 - FAULT_AT) as f64 / 1e6
            );
            assert!(
                outcome
                    .log
                    .lines()
                    .iter()
                    .any(|l| l.text.contains("reset cause: Watchdog")),
                "{fault:?}: the firmware did not boot again after a watchdog reset\n{report}"
            );
        }
        _ => outcome.assert_clean(),
    }
    if fault == Fault::ImuFullScale {
        // The injection did what it says: the chip's z rate register sits at +32767, the other
        // axes still move (not a frozen sensor), and the firmware counted the samples invalid.
        let imu = outcome.session.board_mut().imu();
        let z = i16::from_be_bytes([imu.register(GYRO_ZOUT_H), imu.register(GYRO_ZOUT_H + 1)]);
        assert_eq!(
            z,
            i16::MAX,
            "{fault:?}: the gyro's z is not at full scale\n{report}"
        );
        let invalid: Vec<u64> = outcome
            .log
            .lines()
            .iter()
            .filter_map(|l| {
                let at = l.text.find("imu_invalid=")?;
                l.text[at + "imu_invalid=".len()..]
                    .split(' ')
                    .next()?
                    .parse()
                    .ok()
            })
            .collect();
        let (Some(&first), Some(&last)) = (invalid.first(), invalid.last()) else {
            panic!("{fault:?}: no status lines\n{report}");
        };
        assert_eq!(
            first, 0,
            "{fault:?}: samples rejected before the fault\n{report}"
        );
        // 512 Hz for the rest of the run after the fault, a status line a second: at least the
        // samples up to the last status line (a few hundred).
        assert!(
            last >= 100,
            "{fault:?}: only {last} samples counted invalid\n{report}"
        );
        println!("{fault:?}: {last} samples counted invalid by the last status line");
    }
    if fault == Fault::ImuReset {
        let back = pilot.imu_back_at.unwrap_or_else(|| {
            panic!("{fault:?}: the MPU-6000 was never configured again\n{report}")
        });
        println!(
            "{fault:?}: the MPU-6000 configured again {:.1} ms after its reset (bound {:.1} ms)",
            (back - FAULT_AT) as f64 / 1e6,
            IMU_BACK_NS as f64 / 1e6
        );
        assert!(
            back - FAULT_AT <= IMU_BACK_NS,
            "{fault:?}: configured again after {:.1} ms\n{report}",
            (back - FAULT_AT) as f64 / 1e6
        );
        // Its samples are valid again: the last two status lines (both after the chip came
        // back) count the same rejected samples, and one re-configuration.
        let statuses: Vec<&str> = outcome
            .log
            .lines()
            .iter()
            .map(|l| l.text.as_str())
            .filter(|t| t.contains("status uptime_ms="))
            .collect();
        let field = |line: &str, key: &str| -> u64 {
            line.split_whitespace()
                .find_map(|f| f.strip_prefix(key).and_then(|v| v.strip_prefix('=')))
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("no {key} in {line}\n{report}"))
        };
        let [.., before, last] = statuses.as_slice() else {
            panic!("{fault:?}: fewer than two status lines\n{report}");
        };
        assert!(
            field(before, "uptime_ms") * MS > back + 30 * MS,
            "{fault:?}: the status line before the last is from after the chip came back\n{report}"
        );
        assert_eq!(
            field(before, "imu_invalid"),
            field(last, "imu_invalid"),
            "{fault:?}: samples still rejected a second after the chip came back\n{report}"
        );
        assert!(
            field(last, "imu_invalid") > 0,
            "{fault:?}: the reset's samples were rejected\n{report}"
        );
        // At least once: a reset that lands between a step's reads is seen, and configured
        // for, before the chip answers again; that attempt reads back wrong and is repeated.
        assert!(field(last, "imu_reconfigured") >= 1, "{report}");
        assert!(
            outcome
                .log
                .lines()
                .iter()
                .any(|l| l.text.contains("configured again, read back right: true")),
            "{fault:?}: no re-configuration read back right\n{report}"
        );
    }
    (report, took, pilot.hover_seen_at, pilot.landing_seen)
}

/// No valid IMU sample for this long while armed -> motors off.
/// Measured at the bench's 1 ms stops: one stop of slack.
fn imu_promise_ns() -> u64 {
    autopilot::mpu6000::fault_motors_off(&autopilot::failsafe::FailsafeConfig::default())
        .as_micros()
        * 1_000
        + MS
}

#[test]
fn a_frozen_imu_stops_the_motors() {
    fault_stops_the_motors(Fault::ImuFrozen, imu_promise_ns(), 3.0);
}

#[test]
fn an_unplugged_imu_stops_the_motors() {
    fault_stops_the_motors(Fault::ImuUnplugged, imu_promise_ns(), 3.0);
}

/// A sample with an axis at full scale is a bound, not a measurement: counted
/// invalid, and the IMU failsafe stops the motors within its promise.
#[test]
fn an_imu_at_full_scale_stops_the_motors() {
    fault_stops_the_motors(Fault::ImuFullScale, imu_promise_ns(), 5.0);
}

/// The MPU-6000 resets in flight: the IMU failsafe stops the motors within
/// its promise, the firmware configures the chip again (it comes back asleep with its
/// registers at their defaults), and the motors stay off without a new `Arm`.
#[test]
fn a_reset_imu_stops_the_motors_and_is_configured_again() {
    fault_stops_the_motors(Fault::ImuReset, imu_promise_ns(), 5.0);
}

/// A HardFault: its handler sets every motor output to 0 first.
#[test]
fn a_hard_fault_stops_the_motors_at_once() {
    fault_stops_the_motors(
        Fault::BusError,
        autopilot::board::FAULT_MOTORS_OFF.as_micros() * 1_000 + MS,
        3.0,
    );
}

/// The same at 1.5 cycles per instruction: the handler's few dozen instructions still stop the
/// motors within its 10 µs of its arrival. The bus error comes at SPI2's next access, which
/// the 512 Hz loop makes within a loop period of the injection (at this rate, the loop's phase
/// against the bench's stops differs).
#[test]
fn a_hard_fault_stops_the_motors_at_once_on_a_slow_core() {
    let loop_period_ns = 1_000_000_000u64.div_ceil(u64::from(autopilot::board::LOOP_RATE_HZ));
    fault_stops_the_motors_at(
        Fault::BusError,
        loop_period_ns + autopilot::board::FAULT_MOTORS_OFF.as_micros() * 1_000 + MS,
        3.0,
        CoreRate::Pessimistic,
        LSI_HZ_TYPICAL,
    );
}

/// A stack overflow (flip-link): a runaway recursion uses up the stack, the
/// push that leaves SRAM faults, and the HardFault path stops the motors first, on a stack
/// that has no room left.
#[test]
fn a_stack_overflow_faults_and_stops_the_motors_at_once() {
    fault_stops_the_motors(
        Fault::StackOverflow,
        autopilot::board::FAULT_MOTORS_OFF.as_micros() * 1_000 + MS,
        3.0,
    );
}

/// An interrupt the image has no handler for (IRQ 0, enabled and pended from the 512 Hz loop):
/// the `DefaultHandler` stops the motors first, names the vector, and leaves the part to the
/// watchdog.
#[test]
fn an_unbound_interrupt_stops_the_motors_at_once() {
    fault_stops_the_motors(
        Fault::UnboundInterrupt,
        autopilot::board::FAULT_MOTORS_OFF.as_micros() * 1_000 + MS,
        3.0,
    );
}

/// A panic: its handler sets every motor output to 0 first. The panic comes
/// at the firmware's next log line (the 1 Hz status line), so the promise counts from the
/// handler's arrival, and the run is long enough for a status line.
#[test]
fn a_panic_stops_the_motors_at_once() {
    fault_stops_the_motors(Fault::Panic, 1_100 * MS, 4.0);
}

/// A hung task: the watchdog resets the part, the motors are off from the reset on and stay off
/// (the board boots disarmed and nobody arms it again).
#[test]
fn a_hung_loop_is_reset_by_the_watchdog_and_the_motors_stay_off() {
    hung_loop_at(LSI_HZ_TYPICAL);
}

/// The same on the slowest LSI the datasheet allows (17 kHz), where the firmware's programmed
/// timeout is longest (24.9 ms).
#[test]
fn a_hung_loop_is_reset_by_the_watchdog_on_the_slowest_lsi() {
    hung_loop_at(LSI_HZ_SLOWEST);
}

/// The same on the fastest LSI (47 kHz): the timeout shrinks to 9.0 ms, still above the
/// 512 Hz loop's 1.95 ms feeding period, so the flight before the hang is not reset.
#[test]
fn a_hung_loop_is_reset_by_the_watchdog_on_the_fastest_lsi() {
    hung_loop_at(LSI_HZ_FASTEST);
}

/// The programmed timeout at `lsi_hz` from the hang, which begins at the loop's next SPI
/// transfer (within a loop period of the injection; the loop fed the watchdog last before it),
/// plus a stop of the bench; and within the design's [`autopilot::board::WATCHDOG_MS`] of the
/// injection at every LSI.
fn hung_loop_at(lsi_hz: u64) {
    let lsi = u32::try_from(lsi_hz).expect("an LSI in hertz");
    let timeout_ns = u64::from(autopilot::board::WATCHDOG.us_at(lsi)) * 1_000;
    let loop_period_ns = 1_000_000_000u64.div_ceil(u64::from(autopilot::board::LOOP_RATE_HZ));
    let promise_ns = timeout_ns + loop_period_ns + MS;
    assert!(
        promise_ns <= u64::from(autopilot::board::WATCHDOG_MS) * MS,
        "LSI {lsi_hz} Hz: a {:.1} ms timeout does not meet the design's {} ms",
        timeout_ns as f64 / 1e6,
        autopilot::board::WATCHDOG_MS
    );
    fault_stops_the_motors_at(Fault::Hang, promise_ns, 3.5, CoreRate::Default, lsi_hz);
}

/// The camera link goes silent: the estimate failsafe hovers, then lands, then stops the motors
/// on touchdown.
#[test]
fn a_cut_camera_link_lands_and_stops_the_motors() {
    let promise = autopilot::AutopilotConfig::default()
        .link_loss_motors_off()
        .as_micros()
        * 1_000;
    let run_s = (FAULT_AT + promise) as f64 / 1e9 + 0.5;
    fault_stops_the_motors(Fault::LinkCut, promise, run_s);
}

/// The camera board reports its camera stopped: the autopilot hovers blind at
/// once, without waiting out the estimate timeout, then lands and stops the motors on
/// touchdown. The stand-in reports at the fault; the real camera board reports within 1.2 s of
/// its camera's last VSYNC (`tests/vboard/link.rs`), which is the camera board's promise, not this one.
#[test]
fn a_stopped_camera_reported_by_the_camera_board_lands_and_stops_the_motors() {
    let cfg = autopilot::AutopilotConfig::default();
    let promise = cfg.camera_stopped_motors_off().as_micros() * 1_000;
    let run_s = (FAULT_AT + promise) as f64 / 1e9 + 0.5;
    let (report, _, hover_seen_at, _) =
        fault_stops_the_motors(Fault::CameraStopped, promise, run_s);
    // Telemetry goes out at 10 Hz: the hover is seen within two of its periods (the mode
    // changes at the next 50 Hz guidance step), well inside the estimate timeout.
    let hover_by = FAULT_AT + 2 * autopilot::tasks::TELEMETRY_PERIOD.as_micros() * 1_000;
    assert!(
        hover_by < FAULT_AT + cfg.failsafe.estimate_timeout.as_micros() * 1_000,
        "the bound tells the report from the timeout"
    );
    assert!(
        hover_seen_at.is_some_and(|at| at <= hover_by),
        "blind hover reported at {hover_seen_at:?} ns, expected by {hover_by}\n{report}"
    );
}

/// The telemetry link is cut in flight, the drone flying on its barometer (with height fixes
/// over the same link, their loss lands it first, as `height-lost`): after
/// `fs_host_timeout_us` the autopilot lands, reporting `telemetry-lost`, and every motor is at 0
/// within the host-loss promise (the timeout, the landing at the slower landing rate from the
/// target height, the touchdown confirmation, one guidance period).
#[test]
fn a_cut_telemetry_link_lands_and_stops_the_motors() {
    let cfg = autopilot::AutopilotConfig::default();
    let promise = cfg.host_loss_motors_off().as_micros() * 1_000;
    let run_s = (FAULT_AT + promise) as f64 / 1e9 + 0.5;
    let (report, took, _, landing) = fault_stops_the_motors(Fault::TelemetryCut, promise, run_s);
    let (landing_at, reason) =
        landing.unwrap_or_else(|| panic!("no landing reported after the cut\n{report}"));
    assert_eq!(
        reason,
        Some(FailsafeReason::TelemetryLost),
        "the landing's reason\n{report}"
    );
    // Not before the host timeout from the last heartbeat (one a second): the link's silence,
    // not another failsafe, landed it.
    let period = virtual_board::pilot::HEARTBEAT_PERIOD_NS;
    let last_heartbeat = (FAULT_AT - 1) / period * period;
    let timeout = cfg.failsafe.host_timeout.as_micros() * 1_000;
    assert!(
        landing_at >= last_heartbeat + timeout,
        "landing reported {:.2} s after the last heartbeat, before the {:.1} s timeout\n{report}",
        (landing_at - last_heartbeat) as f64 / 1e9,
        timeout as f64 / 1e9
    );
    println!(
        "TelemetryCut: landing reported {:.2} s after the cut, motors at 0 after {:.2} s (promised {:.2} s)",
        (landing_at - FAULT_AT) as f64 / 1e9,
        took as f64 / 1e9,
        promise as f64 / 1e9
    );
}

/// Time on the telemetry line of what the kill run sends at the kill's stop, ns: the height fix
/// due at the same instant, then the kill (the kill's last byte reaches the board after both).
fn kill_wire_ns() -> u64 {
    let wire = |m: &HostToBoard| {
        virtual_board::host::frame(m).len() as u64 * 10 * 1_000_000_000
            / u64::from(autopilot::board::TELEMETRY_BAUD)
    };
    let fix = HostToBoard::ExternalPosition(protocol::ExternalPosition {
        timestamp_us: protocol::WireTime((FAULT_AT / 1_000) as u32),
        position_m: [0.0, 0.0, -HOVER_M as f32],
    });
    wire(&fix) + wire(&HostToBoard::Command(PilotCommand::Kill))
}

/// A host `Kill` on the telemetry port: every motor at 0 within one 512 Hz step of the
/// command's last byte reaching the board (at the telemetry baud, after the height fix sent at
/// the same instant).
#[test]
fn a_host_kill_stops_the_motors_within_a_loop_period() {
    let wire = kill_wire_ns();
    let (_, took, _, _) =
        fault_stops_the_motors(Fault::HostKill, wire + KILL_AFTER_LAST_BYTE_NS, 3.0);
    println!(
        "HostKill: every motor at 0 {:.2} ms after the kill was sent (bound: {:.2} ms on the line, then {:.2} ms)",
        took as f64 / 1e6,
        wire as f64 / 1e6,
        KILL_AFTER_LAST_BYTE_NS as f64 / 1e6
    );
}

/// A frozen barometer is caught after `baro_stuck`, its readings are no longer fused, the
/// height goes stale after the height timeout and the drone lands blind; one guidance period,
/// and a barometer cycle (two OSR 4096 conversions) and a bench stop of slack.
fn baro_frozen_promise_ns() -> u64 {
    let cfg = autopilot::AutopilotConfig::default();
    let cycle = autopilot::ms5611::Osr::X4096
        .conversion_time()
        .saturating_mul(2);
    (cfg.vertical.baro_stuck
        + cfg.failsafe.height_timeout
        + cfg.setpoints.blind_land_time
        + autopilot::tasks::GUIDANCE_PERIOD
        + cycle)
        .as_micros()
        * 1_000
        + MS
}

/// The barometer freezes while the drone flies on it: caught, the landing reported as
/// `baro-frozen`, every motor at 0 within [`baro_frozen_promise_ns`].
#[test]
fn a_frozen_barometer_lands_and_stops_the_motors() {
    let promise = baro_frozen_promise_ns();
    let run_s = (FAULT_AT + promise) as f64 / 1e9 + 0.5;
    let (report, took, _, landing) = fault_stops_the_motors(Fault::BaroFrozen, promise, run_s);
    let (landing_at, reason) =
        landing.unwrap_or_else(|| panic!("no landing reported after the freeze\n{report}"));
    assert_eq!(
        reason,
        Some(FailsafeReason::BaroFrozen),
        "the landing's reason\n{report}"
    );
    println!(
        "BaroFrozen: landing reported {:.2} s after the freeze, motors at 0 after {:.2} s (promised {:.2} s)",
        (landing_at - FAULT_AT) as f64 / 1e9,
        took as f64 / 1e9,
        promise as f64 / 1e9
    );
}
