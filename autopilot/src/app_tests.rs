//! Tests of the whole [`Autopilot`](super::Autopilot) against a small quadcopter model written
//! here (rigid body, first-order motors, linear drag, one wall), plus failsafe and robustness
//! tests of the public API.

#![allow(clippy::needless_range_loop)] // index loops read like the physics

extern crate std;

use super::*;
use crate::attitude::GRAVITY;
use crate::battery::BatteryState;
use crate::estimation::VelocitySource;
use crate::indi::IndiConfig;
use crate::setpoints::SetpointConfig;
use crate::tasks::{Task, TaskId, Trigger, IMU_PERIOD, TASKS};
use crate::test_support::{at, camera_status, forward_estimate};
use proptest::prelude::*;
use protocol::params::MemStore;
use protocol::{EstimateFlags, FrameFit, ParamOp};
use std::vec::Vec;
use timebase::WireTime;

const IMU_US: u64 = 1_953;

/// A 40 g X quad: motor `i` thrust `k * state_i`, state first-order towards the throttle.
/// Roll/pitch/yaw accelerations follow the mixer's differentials times the true G1.
struct Quad {
    pos: [f32; 3],
    vel: [f32; 3],
    q: Quat,
    w: [f32; 3],
    motor: [f32; 4],
    g1: [f32; 3],
    hover: f32,
    drag: f32,
    wall_x: f32,
    accel_body: [f32; 3],
}

impl Quad {
    fn new() -> Self {
        Self {
            pos: [0.0; 3],
            vel: [0.0; 3],
            q: Quat::IDENTITY,
            w: [0.0; 3],
            motor: [0.0; 4],
            g1: IndiConfig::default().g1,
            hover: 0.65,
            drag: 0.6,
            wall_x: 3.0,
            accel_body: [0.0, 0.0, -GRAVITY],
        }
    }

    fn height(&self) -> f32 {
        -self.pos[2]
    }

    fn rotate(q: Quat, v: [f32; 3]) -> [f32; 3] {
        let p = q
            .hamilton(Quat {
                w: 0.0,
                x: v[0],
                y: v[1],
                z: v[2],
            })
            .hamilton(q.conj());
        [p.x, p.y, p.z]
    }

    fn step(&mut self, throttle: [f32; 4], dt: f32) {
        let sub = 4;
        let h = dt / sub as f32;
        let k = -libm::logf(1.0 - 0.03) * 512.0;
        for _ in 0..sub {
            for (m, t) in self.motor.iter_mut().zip(throttle.iter()) {
                *m += k * (t - *m) * h;
            }
            let m = self.motor;
            let mut u = [0.0f32; 3];
            for i in 0..4 {
                u[0] += mixer::ROLL[i] * m[i] / 4.0;
                u[1] += mixer::PITCH[i] * m[i] / 4.0;
                u[2] += mixer::YAW[i] * m[i] / 4.0;
            }
            for i in 0..3 {
                self.w[i] += self.g1[i] * u[i] * h;
            }
            let dq = self.q.hamilton(Quat {
                w: 0.0,
                x: self.w[0],
                y: self.w[1],
                z: self.w[2],
            });
            self.q = Quat {
                w: self.q.w + 0.5 * dq.w * h,
                x: self.q.x + 0.5 * dq.x * h,
                y: self.q.y + 0.5 * dq.y * h,
                z: self.q.z + 0.5 * dq.z * h,
            }
            .normalized();
            // Specific force in body axes: thrust along -z plus drag.
            let thrust_acc = GRAVITY * (m.iter().sum::<f32>() / 4.0) / self.hover;
            let vb = Self::rotate(self.q.conj(), self.vel);
            let f_body = [
                -self.drag * vb[0],
                -self.drag * vb[1],
                -thrust_acc - self.drag * vb[2],
            ];
            self.accel_body = f_body;
            let f_world = Self::rotate(self.q, f_body);
            for i in 0..3 {
                let g = if i == 2 { GRAVITY } else { 0.0 };
                self.vel[i] += (f_world[i] + g) * h;
                self.pos[i] += self.vel[i] * h;
            }
            if self.pos[2] > 0.0 {
                // Floor.
                self.pos[2] = 0.0;
                self.vel = [0.0; 3];
                self.w = [0.0; 3];
                let [_, _, yaw] = self.q.to_euler();
                self.q = Quat::from_euler(0.0, 0.0, yaw);
                self.accel_body = [0.0, 0.0, -GRAVITY];
            }
        }
    }

    fn imu(&self, now: u64) -> ImuSample {
        ImuSample {
            timestamp_us: WireTime(now as u32),
            gyro_radps: self.w,
            accel_mps2: self.accel_body,
        }
    }

    fn estimate(&self, seq: u16) -> Estimate {
        let vb = Self::rotate(self.q.conj(), self.vel);
        let yaw = self.q.to_euler()[2];
        let c = libm::cosf(yaw);
        let obstacle = if c > 0.45 {
            let d = (self.wall_x - self.pos[0]) / c;
            (d < 4.0).then_some(d)
        } else {
            None
        };
        Estimate {
            seq,
            ..crate::test_support::estimate([vb[0], vb[1]], obstacle)
        }
    }

    fn position(&self, now: u64) -> ExternalPosition {
        ExternalPosition {
            timestamp_us: WireTime(now as u32),
            position_m: self.pos,
        }
    }
}

/// What the world hands the autopilot over time.
struct Run {
    ap: Autopilot,
    quad: Quad,
    now: u64,
    estimates: bool,
    imu: bool,
    /// The host sends its heartbeat (at the guidance rate here).
    host: bool,
    /// Added to the height the position fixes report, m (a biased height sensor).
    height_bias: f32,
    seq: u16,
    max_tilt: f32,
    min_wall_gap: f32,
    modes: Vec<(u64, FlightMode)>,
}

impl Run {
    fn new(cfg: AutopilotConfig) -> Self {
        Self {
            ap: Autopilot::new(cfg),
            quad: Quad::new(),
            now: 0,
            estimates: true,
            imu: true,
            host: true,
            height_bias: 0.0,
            seq: 0,
            max_tilt: 0.0,
            min_wall_gap: f32::MAX,
            modes: Vec::new(),
        }
    }

    fn fly(&mut self, seconds: f32) {
        let end = self.now + (seconds * 1e6) as u64;
        let mut motors = [0.0; 4];
        while self.now < end {
            let k = self.now / IMU_US;
            if self.imu {
                motors = self.ap.on_imu(&self.quad.imu(self.now), at(self.now));
            }
            if k.is_multiple_of(10) {
                if self.host {
                    self.ap.on_host_heartbeat(at(self.now));
                }
                self.ap.guidance_step(at(self.now));
                if let Some(m) = self.ap.motor_safety(at(self.now)) {
                    motors = m;
                }
                let mut fix = self.quad.position(self.now);
                fix.position_m[2] -= self.height_bias;
                self.ap.on_external_position(&fix, at(self.now));
                let mode = self.ap.mode();
                if self.modes.last().map(|m| m.1) != Some(mode) {
                    self.modes.push((self.now, mode));
                }
            }
            if k.is_multiple_of(17) && self.estimates {
                self.seq = self.seq.wrapping_add(1);
                self.ap
                    .on_estimate(&self.quad.estimate(self.seq), at(self.now));
            }
            for m in motors {
                assert!((0.0..=1.0).contains(&m), "motor {m}");
            }
            self.quad.step(motors, IMU_US as f32 * 1e-6);
            let [r, p, _] = self.quad.q.to_euler();
            self.max_tilt = self.max_tilt.max(r.abs()).max(p.abs());
            self.min_wall_gap = self.min_wall_gap.min(self.quad.wall_x - self.quad.pos[0]);
            self.now += IMU_US;
        }
    }

    fn takeoff(&mut self) {
        self.fly(0.5);
        self.ap.on_command(PilotCommand::Arm, at(self.now));
        assert_eq!(self.ap.mode(), FlightMode::Flying);
    }
}

#[test]
fn task_table_is_consistent() {
    assert!(task_table::is_indexed_by(TASKS, Task::ALL));
    assert_eq!(Task::ImuIndi.name(), "imu_indi");
    let top = TASKS.iter().map(|t| t.priority).max().unwrap();
    assert_eq!(
        TASKS[0].priority, top,
        "the 512 Hz loop has the highest priority"
    );
    for t in TASKS {
        if let Trigger::Periodic { period } = t.trigger {
            assert!(t.deadline <= period, "{}", t.name);
        }
    }
    let mut names: Vec<_> = TASKS.iter().map(|t| t.name).collect();
    names.sort_unstable();
    names.dedup();
    assert_eq!(names.len(), TASKS.len());
    assert_eq!(IMU_PERIOD.as_micros(), 1_000_000 / 512);
}

#[test]
fn disarmed_motors_stay_off() {
    let mut r = Run::new(AutopilotConfig::default());
    r.fly(2.0);
    assert_eq!(r.ap.motors(), [0.0; 4]);
    assert_eq!(r.ap.mode(), FlightMode::Disarmed);
    assert_eq!(r.quad.height(), 0.0);
}

#[test]
fn takes_off_flies_the_fsm_and_does_not_hit_the_wall() {
    let mut r = Run::new(AutopilotConfig::default());
    r.takeoff();
    r.fly(4.0);
    let h = r.quad.height();
    assert!((h - 1.0).abs() < 0.1, "height after take-off {h}");
    assert!(r.ap.fsm_active());
    r.fly(20.0);
    std::println!(
        "closed loop: height {:.2} m, max tilt {:.1} deg, closest to wall {:.2} m, FSM transitions {}, yaw {:.2}",
        r.quad.height(),
        r.max_tilt.to_degrees(),
        r.min_wall_gap,
        r.ap.fsm().transitions(),
        r.quad.q.to_euler()[2]
    );
    assert!(
        r.min_wall_gap > 0.3,
        "came within {} m of the wall",
        r.min_wall_gap
    );
    assert!(
        r.ap.fsm().transitions() >= 4,
        "flew forward, hovered, turned"
    );
    assert!(
        r.max_tilt < 20.0_f32.to_radians(),
        "max tilt {}",
        r.max_tilt
    );
    assert!((r.quad.height() - 1.0).abs() < 0.15);
    assert_eq!(r.ap.mode(), FlightMode::Flying);
}

#[test]
fn estimate_loss_hovers_then_lands_and_disarms() {
    let mut r = Run::new(AutopilotConfig::default());
    r.takeoff();
    r.fly(4.0);
    r.estimates = false;
    let lost_at = r.now;
    r.fly(12.0);
    let find = |m: FlightMode| r.modes.iter().find(|x| x.1 == m).map(|x| x.0);
    let hover = find(FlightMode::HoverNoEstimate).expect("hovered");
    let land = find(FlightMode::Landing).expect("landed");
    let disarm = r.modes.last().unwrap();
    std::println!(
        "hover after {} ms, land after {} ms",
        (hover - lost_at) / 1000,
        (land - lost_at) / 1000
    );
    assert!(hover - lost_at <= 560_000);
    let hover_time = AutopilotConfig::default()
        .failsafe
        .hover_before_land
        .as_micros();
    assert!((land - hover).abs_diff(hover_time) <= 40_000);
    assert_eq!(disarm.1, FlightMode::Disarmed);
    assert!(r.quad.height() < 0.02);
    assert_eq!(r.ap.motors(), [0.0; 4]);
}

#[test]
fn a_stopped_camera_reported_in_status_hovers_without_waiting_for_the_estimate_timeout() {
    let mut r = Run::new(AutopilotConfig::default());
    r.takeoff();
    r.fly(2.0);
    // The last estimate is fresh; then the camera board reports its camera stopped.
    r.ap.on_estimate(&r.quad.estimate(r.seq.wrapping_add(1)), at(r.now));
    r.estimates = false;
    let stopped_at = r.now;
    r.ap.on_stereo_message(StereoToAutopilot::Status(camera_status(true)), at(r.now));
    r.fly(0.1);
    let hover = r
        .modes
        .iter()
        .find(|m| m.1 == FlightMode::HoverNoEstimate && m.0 >= stopped_at)
        .map(|m| m.0)
        .expect("hovers as blind");
    assert!(
        hover - stopped_at < 50_000,
        "blind after {} us, not the 500 ms estimate timeout",
        hover - stopped_at
    );
}

#[test]
fn a_stopped_camera_lands_and_stops_the_motors_within_its_promise() {
    let cfg = AutopilotConfig::default();
    let mut r = Run::new(cfg);
    r.takeoff();
    r.fly(4.0);
    assert!((r.quad.height() - cfg.setpoints.target_height_m).abs() < 0.1);
    r.estimates = false;
    let stopped_at = r.now;
    r.ap.on_stereo_message(StereoToAutopilot::Status(camera_status(true)), at(r.now));
    let promise = cfg.camera_stopped_motors_off().as_micros();
    let mut off_at = None;
    while r.now < stopped_at + promise + 1_000_000 {
        r.fly(0.02);
        if off_at.is_none() && r.ap.motors() == [0.0; 4] && r.ap.motor_safety(at(r.now)).is_some() {
            off_at = Some(r.now);
        }
    }
    let off_at = off_at.expect("the motors stopped");
    let modes: Vec<FlightMode> = r
        .modes
        .iter()
        .filter(|m| m.0 >= stopped_at)
        .map(|m| m.1)
        .collect();
    std::println!(
        "camera stopped: motors 0 after {} ms (promised {} ms), modes {modes:?}",
        (off_at - stopped_at) / 1000,
        promise / 1000
    );
    assert_eq!(
        modes,
        [
            FlightMode::HoverNoEstimate,
            FlightMode::Landing,
            FlightMode::Disarmed
        ]
    );
    assert!(off_at - stopped_at <= promise);
    assert!(r.quad.height() < 0.02);
    // It stays down: nothing restarts the motors without an Arm.
    assert_eq!(r.ap.motors(), [0.0; 4]);
}

#[test]
fn a_silent_host_lands_the_drone_and_stops_the_motors_within_its_promise() {
    let cfg = AutopilotConfig::default();
    let mut r = Run::new(cfg);
    r.takeoff();
    r.fly(4.0);
    assert!((r.quad.height() - cfg.setpoints.target_height_m).abs() < 0.1);
    r.host = false;
    let last_heartbeat =
        r.ap.last_host_heartbeat()
            .expect("heartbeats came")
            .as_micros();
    let promise = cfg.host_loss_motors_off().as_micros();
    let mut off_at = None;
    while r.now < last_heartbeat + promise + 1_000_000 {
        r.fly(0.02);
        if off_at.is_none() && r.ap.motors() == [0.0; 4] && r.ap.motor_safety(at(r.now)).is_some() {
            off_at = Some(r.now);
        }
    }
    let off_at = off_at.expect("the motors stopped");
    let modes: Vec<(u64, FlightMode)> = r
        .modes
        .iter()
        .filter(|m| m.0 > last_heartbeat)
        .copied()
        .collect();
    std::println!(
        "host silent: motors 0 after {} ms (promised {} ms), modes {modes:?}",
        (off_at - last_heartbeat) / 1000,
        promise / 1000
    );
    assert_eq!(modes[0].1, FlightMode::Landing);
    assert!(modes[0].0 - last_heartbeat > cfg.failsafe.host_timeout.as_micros());
    assert_eq!(modes[1].1, FlightMode::Disarmed);
    assert!(off_at - last_heartbeat <= promise);
    assert!(r.quad.height() < 0.02);
    assert_eq!(
        r.ap.telemetry(at(r.now)).failsafe_reason,
        Some(FailsafeReason::TelemetryLost)
    );
}

/// A height sensor that reads the floor 0.3 m high never reaches the landed height: the
/// ground signature (thrust far below hover, yet 1 g of specific force) ends the landing.
#[test]
fn a_biased_height_still_touches_down_on_the_ground_signature() {
    let cfg = AutopilotConfig::default();
    let mut r = Run::new(cfg);
    r.takeoff();
    r.fly(4.0);
    r.height_bias = 0.3;
    r.ap.on_command(PilotCommand::Land, at(r.now));
    let land_at = r.now;
    r.fly(8.0);
    let down = r.modes.last().unwrap();
    assert_eq!(down.1, FlightMode::Disarmed);
    std::println!(
        "biased height: disarmed {} ms after Land",
        (down.0 - land_at) / 1000
    );
    assert!(
        down.0 - land_at < cfg.setpoints.land_timeout.as_micros(),
        "before the timeout"
    );
    assert_eq!(r.ap.failsafe_reason(), Some(FailsafeReason::Command));
    assert_eq!(r.ap.motors(), [0.0; 4]);
    assert!(r.quad.height() < 0.02);
}

/// Without the ground signature (turned off), a landing held above the landed height by a
/// biased height is cut after the land timeout, the height estimate being below the cut
/// height.
#[test]
fn a_landing_that_does_not_end_is_cut_after_its_timeout() {
    let cfg = AutopilotConfig {
        setpoints: SetpointConfig {
            ground_thrust_ratio: 0.0,
            ..SetpointConfig::default()
        },
        ..AutopilotConfig::default()
    };
    let mut r = Run::new(cfg);
    r.takeoff();
    r.fly(4.0);
    r.height_bias = 0.2;
    r.ap.on_command(PilotCommand::Land, at(r.now));
    let land_at = r.now;
    r.fly(cfg.setpoints.land_timeout.as_secs_f32() - 0.1);
    assert_eq!(r.ap.mode(), FlightMode::Landing, "still landing");
    r.fly(0.2);
    let down = r.modes.last().unwrap();
    assert_eq!(down.1, FlightMode::Disarmed);
    assert!(down.0 - land_at >= cfg.setpoints.land_timeout.as_micros());
    assert_eq!(r.ap.failsafe_reason(), Some(FailsafeReason::LandTimeout));
    assert_eq!(r.ap.motors(), [0.0; 4]);
}

/// A barometer whose readings freeze is refused after `baro_stuck` (its heights no longer
/// reach the height loop); a reading that moves again is used again.
#[test]
fn a_frozen_barometer_is_refused_and_counted() {
    let cfg = AutopilotConfig::default();
    let mut ap = Autopilot::new(cfg);
    let reading = |p: f32| BaroReading {
        pressure_pa: p,
        temperature_c: 25.0,
    };
    let mut t = 0;
    for k in 0..50 {
        ap.on_baro(&reading(101_325.0 + (k % 3) as f32), at(t));
        t += 20_000;
    }
    assert!(!ap.baro_is_frozen());
    assert_eq!(ap.baro_frozen(), 0);
    let frozen_from = t;
    while t <= frozen_from + cfg.vertical.baro_stuck.as_micros() + 100_000 {
        ap.on_baro(&reading(101_330.0), at(t));
        t += 20_000;
    }
    assert!(ap.baro_is_frozen());
    assert!(ap.baro_frozen() >= 4);
    let last_height = ap.height.last_measurement();
    assert!(last_height
        .is_none_or(|h| h.as_micros() <= frozen_from + cfg.vertical.baro_stuck.as_micros()));
    assert!(ap.freshness().baro_frozen);
    ap.on_baro(&reading(101_331.0), at(t));
    assert!(!ap.baro_is_frozen());
}

/// A frozen barometer in flight without other height fixes: its heights stop, and the height
/// failsafe lands for it.
#[test]
fn a_barometer_frozen_in_flight_lands_the_drone_and_says_why() {
    let cfg = AutopilotConfig::default();
    let mut ap = Autopilot::new(cfg);
    let mut f = Failsafe::new(cfg.failsafe);
    let fresh = Freshness {
        last_valid_estimate: Some(at(0)),
        last_imu: Some(at(0)),
        last_height: Some(at(0)),
        last_host: Some(at(0)),
        baro_frozen: false,
    };
    f.command(PilotCommand::Arm, &fresh, at(0));
    let t = at(cfg.failsafe.height_timeout.as_micros() + 1);
    let stale = Freshness {
        last_valid_estimate: Some(t),
        last_imu: Some(t),
        last_host: Some(t),
        baro_frozen: true,
        ..fresh
    };
    assert_eq!(f.update(&stale, t), FlightMode::Landing);
    assert_eq!(f.reason(), Some(FailsafeReason::BaroFrozen));
    // The autopilot hands the failsafe its barometer's state.
    ap.on_baro(
        &BaroReading {
            pressure_pa: 1.0e5,
            temperature_c: 20.0,
        },
        at(0),
    );
    ap.on_baro(
        &BaroReading {
            pressure_pa: 1.0e5,
            temperature_c: 20.0,
        },
        at(cfg.vertical.baro_stuck.as_micros() + 1),
    );
    assert!(ap.freshness().baro_frozen);
}

#[test]
fn an_arm_without_a_host_heartbeat_is_refused_and_counted() {
    let mut r = Run::new(AutopilotConfig::default());
    r.host = false;
    r.fly(0.5);
    r.ap.on_command(PilotCommand::Arm, at(r.now));
    assert_eq!(r.ap.mode(), FlightMode::Disarmed);
    assert_eq!(r.ap.arm_refused(), 1);
    r.host = true;
    r.fly(0.1);
    r.ap.on_command(PilotCommand::Arm, at(r.now));
    assert_eq!(r.ap.mode(), FlightMode::Flying);
}

#[test]
fn arm_is_refused_until_the_attitude_is_initialised() {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let pos = ExternalPosition {
        timestamp_us: WireTime(0),
        position_m: [0.0; 3],
    };
    // Accelerometer reading 2 g (the board being shaken): no attitude yet.
    for k in 0..100u64 {
        let imu = ImuSample {
            timestamp_us: WireTime(0),
            gyro_radps: [0.0; 3],
            accel_mps2: [0.0, 0.0, -2.0 * GRAVITY],
        };
        ap.on_imu(&imu, at(k * IMU_US));
        ap.on_external_position(&pos, at(k * IMU_US));
    }
    ap.on_host_heartbeat(at(100 * IMU_US));
    ap.on_command(PilotCommand::Arm, at(100 * IMU_US));
    assert_eq!(ap.mode(), FlightMode::Disarmed);
    let imu = ImuSample {
        timestamp_us: WireTime(0),
        gyro_radps: [0.0; 3],
        accel_mps2: [0.0, 0.0, -GRAVITY],
    };
    ap.on_imu(&imu, at(101 * IMU_US));
    ap.on_command(PilotCommand::Arm, at(101 * IMU_US));
    assert_eq!(ap.mode(), FlightMode::Flying);
}

/// An autopilot told (a stream of motion-capture fixes, the fewest the height loop takes) that
/// it is at 1 m, above [`AutopilotConfig::min_vision_height_m`], so that it uses the estimates
/// for its velocity.
fn autopilot_at_height() -> Autopilot {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    for _ in 0..FIXES_TO_LEAD {
        ap.on_external_position(
            &ExternalPosition {
                timestamp_us: WireTime(0),
                position_m: [0.0, 0.0, -1.0],
            },
            at(0),
        );
    }
    ap
}

/// A climb over a floor seen in perspective looks like forward flight to Edge-FS: estimates
/// taken while the height changes fast over a view with little depth keep the failsafe quiet
/// but do not reach the velocity.
#[test]
fn estimates_during_a_fast_climb_keep_the_failsafe_quiet_but_are_not_fused() {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let mut t = 0u64;
    let mut h = 0.8f32;
    // Motion-capture fixes at 100 Hz of a drone climbing at 0.5 m/s from 0.8 m; estimates
    // once the climb rate has settled.
    for k in 0..80 {
        t += 10_000;
        h += 0.005;
        ap.on_external_position(
            &ExternalPosition {
                timestamp_us: WireTime(t as u32),
                position_m: [0.0, 0.0, -h],
            },
            at(t),
        );
        if k >= 40 && t.is_multiple_of(40_000) {
            let floor_only = Estimate {
                depth_coverage: 40,
                ..forward_estimate(1.1)
            };
            ap.on_estimate(&floor_only, at(t));
        }
    }
    assert!(ap.height.climb_mps() > AutopilotConfig::default().estimation.max_vision_climb_mps);
    assert_eq!(ap.freshness().last_valid_estimate, Some(at(t)));
    assert_eq!(ap.velocity(), None);
    assert_eq!(ap.velocity_estimate(), None);
    // Level again: the same estimates are fused.
    for _ in 0..100 {
        t += 10_000;
        ap.on_external_position(
            &ExternalPosition {
                timestamp_us: WireTime(t as u32),
                position_m: [0.0, 0.0, -h],
            },
            at(t),
        );
        if t.is_multiple_of(40_000) {
            ap.on_estimate(&forward_estimate(0.4), at(t));
        }
    }
    assert_eq!(ap.velocity(), Some([0.4, 0.0]));
}

#[test]
fn gyro_offset_is_calibrated_on_the_ground_and_motion_restarts_it() {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let bias = [0.008, -0.006, 0.004];
    let mut t = 0;
    let mut imu = |ap: &mut Autopilot, gyro: [f32; 3]| {
        t += IMU_US;
        ap.on_imu(
            &ImuSample {
                timestamp_us: WireTime(t as u32),
                gyro_radps: gyro,
                accel_mps2: [0.0, 0.0, -GRAVITY],
            },
            at(t),
        );
    };
    for _ in 0..200 {
        imu(&mut ap, bias);
    }
    // Picked up and turned: the average restarts.
    imu(&mut ap, [0.0, 0.0, 0.5]);
    for _ in 0..200 {
        imu(&mut ap, bias);
    }
    assert_eq!(ap.gyro_offset(), None, "256 still samples in a row needed");
    for _ in 0..56 {
        imu(&mut ap, bias);
    }
    let off = ap.gyro_offset().expect("calibrated");
    for i in 0..3 {
        assert!((off[i] - bias[i]).abs() < 1e-6, "{off:?}");
    }
    // The corrected gyro goes to the camera board and the attitude stays level.
    for _ in 0..512 {
        imu(&mut ap, bias);
    }
    assert!(ap
        .gyro_attitude(at(t))
        .rates_radps
        .iter()
        .all(|w| w.abs() < 1e-6));
    assert!(ap.attitude()[..2].iter().all(|a| a.abs() < 1e-3));
}

/// The yaw gate sees the gyro of the 512 Hz loop (the gates themselves are tested in
/// [`crate::estimation`]).
#[test]
fn an_estimate_under_fast_yaw_is_gated() {
    let mut ap = autopilot_at_height();
    let imu = |yaw_rate: f32| ImuSample {
        timestamp_us: WireTime(0),
        gyro_radps: [0.0, 0.0, yaw_rate],
        accel_mps2: [0.0, 0.0, -GRAVITY],
    };
    let mut t = 0;
    for yaw_rate in [0.0, 0.0, 1.5] {
        t += 40_000;
        ap.on_imu(&imu(yaw_rate), at(t));
        ap.on_estimate(&forward_estimate(0.1), at(t));
    }
    assert_eq!(ap.yaw_gated_estimates(), 1);
    assert_eq!(ap.freshness().last_valid_estimate, Some(at(t)));
    assert_eq!(ap.velocity(), None);
}

#[test]
fn kill_stops_motors_at_once() {
    let mut r = Run::new(AutopilotConfig::default());
    r.takeoff();
    r.fly(3.0);
    r.ap.on_command(PilotCommand::Kill, at(r.now));
    let m = r.ap.on_imu(&r.quad.imu(r.now), at(r.now));
    assert_eq!(m, [0.0; 4]);
    assert_eq!(r.ap.motor_safety(at(r.now)), Some([0.0; 4]));
    // Arm/land cannot be confused with a kill: land does not restart anything.
    r.ap.on_command(PilotCommand::Land, at(r.now));
    assert_eq!(r.ap.mode(), FlightMode::Killed);
}

#[test]
fn an_rc_kill_latches_until_released_and_no_arm_overrides_it() {
    let mut r = Run::new(AutopilotConfig::default());
    r.takeoff();
    r.fly(1.0);
    r.ap.set_rc_kill(true, at(r.now));
    assert_eq!(r.ap.mode(), FlightMode::Killed);
    assert_eq!(r.ap.arm_blocker(), Some(ArmBlock::RcKill));
    r.fly(0.2);
    // A host (or RC) Arm while the switch is on is refused and counted.
    r.ap.on_command(PilotCommand::Arm, at(r.now));
    r.ap.set_rc_kill(true, at(r.now));
    r.ap.on_command(PilotCommand::Arm, at(r.now));
    assert_eq!(r.ap.mode(), FlightMode::Killed);
    assert_eq!(r.ap.arm_refused(), 2);
    assert_eq!(r.ap.on_imu(&r.quad.imu(r.now), at(r.now)), [0.0; 4]);
    // Releasing the switch does not arm; an explicit Arm afterwards does.
    r.ap.set_rc_kill(false, at(r.now));
    r.fly(0.1);
    assert_eq!(r.ap.mode(), FlightMode::Killed);
    assert_eq!(r.ap.arm_blocker(), None);
    r.ap.on_command(PilotCommand::Arm, at(r.now));
    assert_eq!(r.ap.mode(), FlightMode::Flying);
}

#[test]
fn every_refused_arm_is_counted() {
    let level = |t: u64| ImuSample {
        timestamp_us: WireTime(t as u32),
        gyro_radps: [0.0; 3],
        accel_mps2: [0.0, 0.0, -GRAVITY],
    };
    let floor = |t: u64| ExternalPosition {
        timestamp_us: WireTime(t as u32),
        position_m: [0.0; 3],
    };
    let mut ap = Autopilot::new(AutopilotConfig::default());
    ap.on_host_heartbeat(at(0));
    // Not initialised (no IMU sample yet): refused before the failsafe.
    ap.on_command(PilotCommand::Arm, at(0));
    assert_eq!(ap.arm_refused(), 1);
    // The attitude initialised, but no height measurement: the failsafe refuses.
    let mut t = 0;
    for _ in 0..50 {
        t += IMU_US;
        ap.on_imu(&level(t), at(t));
    }
    ap.on_command(PilotCommand::Arm, at(t));
    assert_eq!(ap.mode(), FlightMode::Disarmed);
    assert_eq!(ap.arm_refused(), 2);
    // Height fresh (a stream of fixes), IMU stale (its last sample 21 ms ago, the timeout
    // 20 ms): refused.
    for _ in 0..FIXES_TO_LEAD {
        ap.on_external_position(&floor(t), at(t));
    }
    let stale = t + AutopilotConfig::default().failsafe.imu_timeout.as_micros() + 1_000;
    ap.on_external_position(&floor(stale), at(stale));
    ap.on_command(PilotCommand::Arm, at(stale));
    assert_eq!(ap.mode(), FlightMode::Disarmed);
    assert_eq!(ap.arm_refused(), 3);
    // Everything fresh: accepted, not counted; a second Arm while flying changes nothing and
    // is not counted either.
    t = stale + IMU_US;
    ap.on_imu(&level(t), at(t));
    ap.on_command(PilotCommand::Arm, at(t));
    assert_eq!(ap.mode(), FlightMode::Flying);
    ap.on_command(PilotCommand::Arm, at(t));
    assert_eq!(ap.arm_refused(), 3);
    // Landing: not on the ground, so an Arm is refused (it would cancel the landing).
    ap.on_command(PilotCommand::Land, at(t));
    assert_eq!(ap.mode(), FlightMode::Landing);
    ap.on_command(PilotCommand::Arm, at(t));
    assert_eq!(ap.mode(), FlightMode::Landing);
    assert_eq!(ap.arm_refused(), 4);
}

/// COBS-decodes one frame (without its delimiter).
fn cobs_decode(frame: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < frame.len() {
        let code = usize::from(frame[i]);
        out.extend_from_slice(&frame[i + 1..i + code]);
        i += code;
        if code < 0xFF && i < frame.len() {
            out.push(0);
        }
    }
    out
}

/// COBS-encodes `raw` and appends the delimiter.
fn cobs_encode(raw: &[u8]) -> Vec<u8> {
    let mut out = std::vec![0u8];
    let mut code_at = 0;
    for &b in raw {
        if b == 0 {
            out[code_at] = (out.len() - code_at) as u8;
            code_at = out.len();
            out.push(0);
        } else {
            out.push(b);
            if out.len() - code_at == 0xFF {
                out[code_at] = 0xFF;
                code_at = out.len();
                out.push(0);
            }
        }
    }
    out[code_at] = (out.len() - code_at) as u8;
    out.push(0);
    out
}

#[test]
fn a_camera_board_of_another_protocol_version_blocks_arming() {
    let mut r = Run::new(AutopilotConfig::default());
    r.fly(0.5);
    // A heartbeat framed as protocol version + 1 (valid CRC): the camera board's estimates
    // would all be rejected, so the drone must not take off.
    let hb = StereoToAutopilot::Heartbeat(Heartbeat::new(Node::StereoBoard, 5));
    let mut buf = [0u8; 64];
    let n = protocol::encode(&hb, &mut buf).unwrap();
    let mut raw = cobs_decode(&buf[..n - 1]);
    let body = raw.len() - 2;
    raw[0] = protocol::PROTOCOL_VERSION.wrapping_add(1);
    let crc = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740).checksum(&raw[..body]);
    raw[body..].copy_from_slice(&crc.to_le_bytes());
    let mut wire = buf[..n].to_vec(); // one good frame first (the decoder joins mid-stream)
    wire.extend(cobs_encode(&raw));
    assert_eq!(r.ap.on_stereo_bytes(&wire, at(r.now)), 1);
    assert_eq!(r.ap.link_errors().version_mismatch, 1);
    let theirs = protocol::PROTOCOL_VERSION.wrapping_add(1);
    assert_eq!(r.ap.arm_blocker(), Some(ArmBlock::PeerVersion(theirs)));
    r.ap.on_command(PilotCommand::Arm, at(r.now));
    assert_eq!(r.ap.mode(), FlightMode::Disarmed);
    assert_eq!(r.ap.arm_refused(), 1);
    // Reported to the host: telemetry carries the link's error counters.
    assert_eq!(r.ap.telemetry(at(r.now)).link_errors.version_mismatch, 1);
}

#[test]
fn barometer_readings_are_kept_and_garbage_is_dropped() {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    assert_eq!(ap.baro(), None);
    let good = BaroReading {
        pressure_pa: 100_009.0,
        temperature_c: 20.07,
    };
    ap.on_baro(&good, at(5));
    ap.on_baro(
        &BaroReading {
            pressure_pa: f32::NAN,
            temperature_c: 20.0,
        },
        at(6),
    );
    assert_eq!(ap.baro(), Some((at(5), good)));
}

#[test]
fn stale_imu_makes_motors_safe() {
    let mut r = Run::new(AutopilotConfig::default());
    r.takeoff();
    r.fly(3.0);
    assert_eq!(r.ap.motor_safety(at(r.now)), None);
    r.imu = false;
    r.fly(0.05);
    assert_eq!(r.ap.motor_safety(at(r.now)), Some([0.0; 4]));
    assert_eq!(r.ap.mode(), FlightMode::ImuFault);
    // The IMU coming back does not restart the motors.
    r.imu = true;
    r.fly(0.1);
    assert_eq!(r.ap.motors(), [0.0; 4]);
}

#[test]
fn land_command_lands_and_disarms() {
    let mut r = Run::new(AutopilotConfig::default());
    r.takeoff();
    r.fly(4.0);
    r.ap.on_command(PilotCommand::Land, at(r.now));
    r.fly(6.0);
    assert_eq!(r.ap.mode(), FlightMode::Disarmed);
    assert!(r.quad.height() < 0.02);
}

#[test]
fn telemetry_and_gyro_attitude_reflect_state() {
    let mut r = Run::new(AutopilotConfig::default());
    r.takeoff();
    r.fly(4.0);
    let t = r.ap.telemetry(at(r.now));
    assert_eq!(t.flight_mode, FlightMode::Flying);
    assert!(t.fsm_state.is_some());
    assert!((t.height_m - r.quad.height()).abs() < 0.05);
    let g = r.ap.gyro_attitude(at(r.now));
    assert_eq!(g.timestamp_us, WireTime(r.now as u32));
    let truth = r.quad.q.to_euler();
    for i in 0..2 {
        assert!((g.attitude_rad[i] - truth[i]).abs() < 0.05);
    }
}

#[test]
fn stereo_bytes_are_decoded_in_any_chunking() {
    let mut ap = autopilot_at_height();
    let quad = Quad::new();
    let mut wire = Vec::new();
    let mut buf = [0u8; 128];
    let mut first_frame_len = 0;
    for seq in 0..3u16 {
        let mut e = quad.estimate(seq);
        e.forward_mps = 0.1 * seq as f32;
        e.fit = e.fit.map(|f| FrameFit {
            forward_mps: e.forward_mps,
            ..f
        });
        let n = protocol::encode(&StereoToAutopilot::Estimate(e), &mut buf).unwrap();
        wire.extend_from_slice(&buf[..n]);
        first_frame_len = first_frame_len.max(n * usize::from(seq == 0));
    }
    let hb = Heartbeat::new(Node::StereoBoard, 5);
    let n = protocol::encode(&StereoToAutopilot::Heartbeat(hb), &mut buf).unwrap();
    wire.extend_from_slice(&buf[..n]);
    // Garbage in the middle: counted, and the decoder resynchronises. (Garbage before the
    // first frame would not be counted: the link decoder joins the stream mid-frame.)
    let mut bad = wire.clone();
    bad.splice(first_frame_len..first_frame_len, [1u8, 2, 3, 0]);
    let mut decoded = 0;
    for chunk in bad.chunks(7) {
        decoded += ap.on_stereo_bytes(chunk, at(1_000));
    }
    assert_eq!(decoded, 4);
    assert_eq!(ap.estimates_received(), 3);
    assert_eq!(ap.stereo_heartbeat(), Some((at(1_000), hb)));
    // Only the third of a run of valid estimates counts (`min_valid_run`).
    assert_eq!(ap.velocity(), Some([0.2, 0.0]));
    let errors = ap.link_errors();
    assert_eq!(
        errors.crc + errors.cobs + errors.too_short + errors.malformed,
        1
    );
    assert_eq!(ap.telemetry(at(0)).link_errors, errors);
}

fn arb_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        any::<f32>(),
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        -20.0f32..20.0,
    ]
}

#[derive(Debug, Clone)]
enum Input {
    Imu([f32; 3], [f32; 3]),
    Est(f32, f32, Option<f32>, u8),
    Pos(f32),
    Cmd(u8),
    Guidance,
    Wait(u32),
}

fn arb_input() -> impl Strategy<Value = Input> {
    prop_oneof![
        4 => ([arb_f32(), arb_f32(), arb_f32()], [arb_f32(), arb_f32(), arb_f32()])
            .prop_map(|(g, a)| Input::Imu(g, a)),
        2 => (arb_f32(), arb_f32(), proptest::option::of(arb_f32()), any::<u8>())
            .prop_map(|(f, s, o, fl)| Input::Est(f, s, o, fl)),
        2 => arb_f32().prop_map(Input::Pos),
        1 => (0u8..3).prop_map(Input::Cmd),
        2 => Just(Input::Guidance),
        1 => (0u32..200_000).prop_map(Input::Wait),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, ..ProptestConfig::default() })]

    /// No panic, and every output finite and in range, for any input sequence including NaN
    /// and infinities.
    #[test]
    fn outputs_always_finite_and_in_range(inputs in proptest::collection::vec(arb_input(), 1..300)) {
        let mut ap = Autopilot::new(AutopilotConfig::default());
        let mut now = 0u64;
        for input in inputs {
            now += 1_953;
            match input {
                Input::Imu(g, a) => {
                    let m = ap.on_imu(&ImuSample { timestamp_us: WireTime(now as u32), gyro_radps: g, accel_mps2: a }, at(now));
                    for x in m {
                        prop_assert!(x.is_finite() && (0.0..=1.0).contains(&x), "{:?}", m);
                    }
                }
                Input::Est(f, s, o, fl) => ap.on_estimate(&Estimate {
                    seq: 0, capture_us: WireTime(0), forward_mps: f, sideways_mps: s, obstacle_m: o,
                    quality: 255, flags: EstimateFlags(fl & 0x01), processing_us: 0,
                    depth_coverage: 255, near_columns: 0,
                    fit: (fl & 0x01 == 0).then_some(FrameFit { forward_mps: f, sideways_mps: s, quality: 255 }),
                    up_mps: 0.0,
                    up_flags: EstimateFlags::NO_FLOW_MATCH,
                    fit_r2: 0,
                    divergence: None,
                }, at(now)),
                Input::Pos(z) => ap.on_external_position(&ExternalPosition {
                    timestamp_us: WireTime(now as u32), position_m: [0.0, 0.0, z],
                }, at(now)),
                Input::Cmd(c) => ap.on_command(
                    [PilotCommand::Arm, PilotCommand::Land, PilotCommand::Kill][c as usize], at(now)),
                Input::Guidance => {
                    ap.on_host_heartbeat(at(now));
                    ap.guidance_step(at(now));
                }
                Input::Wait(us) => now += us as u64,
            }
            let sp = ap.setpoints();
            prop_assert!(sp.attitude_rad.iter().all(|x| x.is_finite()));
            prop_assert!(sp.thrust.is_finite() && (0.0..=1.0).contains(&sp.thrust));
            prop_assert!(sp.attitude_rad[0].abs() <= 15.0f32.to_radians() + 1e-5);
            prop_assert!(sp.attitude_rad[1].abs() <= 15.0f32.to_radians() + 1e-5);
            let t = ap.telemetry(at(now));
            prop_assert!(t.attitude_rad.iter().all(|x| x.is_finite()));
            prop_assert!(t.velocity_mps.iter().all(|x| x.is_finite()));
            prop_assert!(t.height_m.is_finite());
            let g = ap.gyro_attitude(at(now));
            prop_assert!(g.rates_radps.iter().chain(g.attitude_rad.iter()).all(|x| x.is_finite()));
            prop_assert!(ap.indi().g1().iter().all(|g| g.is_finite() && *g > 0.0));
        }
    }

    /// INDI commands stay finite and within their bounds, and G1/G2 positive and finite, for
    /// any gyro, error and thrust sequence.
    #[test]
    fn indi_bounded_for_any_input(steps in proptest::collection::vec(
        ([arb_f32(), arb_f32(), arb_f32()], [arb_f32(), arb_f32(), arb_f32()], arb_f32()), 1..200)) {
        let cfg = IndiConfig::default();
        let mut indi = Indi::new(cfg);
        for (err, gyro, thrust) in steps {
            let u = indi.control(err, gyro, thrust);
            for i in 0..3 {
                prop_assert!(u[i].is_finite() && u[i].abs() <= cfg.max_cmd[i]);
            }
            indi.actuator_update(u, gyro);
            prop_assert!(indi.g1().iter().all(|g| g.is_finite() && *g >= cfg.g1_min));
            prop_assert!(indi.g2().is_finite() && indi.g2() >= 0.0);
            prop_assert!(indi.actuator_state().iter().all(|a| a.is_finite()));
        }
    }

    /// The median output is always one of (or between two of) the finite inputs held.
    #[test]
    fn median_output_within_input_range(xs in proptest::collection::vec(arb_f32(), 1..40)) {
        let mut m = crate::median::Median5::new();
        let mut finite = Vec::new();
        for x in xs {
            let out = m.push(x);
            if x.is_finite() {
                finite.push(x);
            }
            let last5 = &finite[finite.len().saturating_sub(5)..];
            match out {
                None => prop_assert!(last5.is_empty()),
                Some(o) => {
                    let lo = last5.iter().cloned().fold(f32::INFINITY, f32::min);
                    let hi = last5.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
                    prop_assert!(o >= lo && o <= hi, "{o} not in [{lo}, {hi}]");
                }
            }
        }
    }

    /// The mixer never leaves [0, 1] whatever it is asked.
    #[test]
    fn mixer_outputs_in_range(t in arb_f32(), r in arb_f32(), p in arb_f32(), y in arb_f32()) {
        let m = mixer::mix(t, r, p, y);
        for x in m.throttle {
            prop_assert!(x.is_finite() && (0.0..=1.0).contains(&x));
        }
        prop_assert!(m.achieved.iter().all(|x| x.is_finite()));
    }
}

fn param_request(ap: &mut Autopilot, board: Node, op: ParamOp) -> ParamReply {
    let resp = ap.on_param_request(&ParamRequest { board, op }, None);
    assert_eq!(resp.board, board);
    resp.reply
}

fn set_param(ap: &mut Autopilot, name: &str, value: protocol::ParamValue) -> ParamReply {
    let op = ParamOp::Set(protocol::ParamName::try_from(name).unwrap(), value);
    param_request(ap, Node::Autopilot, op)
}

#[test]
fn parameters_set_on_the_ground_take_effect_and_are_refused_in_flight() {
    use protocol::{ParamName, ParamValue};
    let mut r = Run::new(AutopilotConfig::default());
    // Height and failsafe timing changed over the protocol while disarmed.
    match set_param(&mut r.ap, "target_height", ParamValue::F32(0.6)) {
        ParamReply::Entry(e) => {
            assert_eq!(e.value, ParamValue::F32(0.6));
            assert_eq!(e.default, ParamValue::F32(1.0));
        }
        other => panic!("{other:?}"),
    }
    let hover_land = ParamValue::U32(1_000_000);
    assert!(matches!(
        set_param(&mut r.ap, "fs_hover_land_us", hover_land),
        ParamReply::Entry(_)
    ));
    r.takeoff();
    r.fly(4.0);
    let h = r.quad.height();
    assert!(
        (h - 0.6).abs() < 0.1,
        "height after take-off {h}, target 0.6"
    );
    // Refused while the motors may run; nothing changes.
    assert_eq!(
        set_param(&mut r.ap, "target_height", ParamValue::F32(1.5)),
        ParamReply::Error(ParamError::Armed)
    );
    assert_eq!(r.ap.config().setpoints.target_height_m, 0.6);
    assert_eq!(
        param_request(&mut r.ap, Node::Autopilot, ParamOp::Save),
        ParamReply::Error(ParamError::NoStorage)
    );
    // A camera-board change is refused here too, not passed on; a camera read is.
    let mut camera = |op| {
        r.ap.on_host_message(
            protocol::HostToBoard::Param(ParamRequest {
                board: Node::StereoBoard,
                op,
            }),
            at(0),
            None,
        )
    };
    let shift = ParamOp::Set(
        ParamName::try_from("stereo_shift").unwrap(),
        ParamValue::I32(3),
    );
    assert_eq!(
        camera(shift),
        crate::host::HostOutcome::Reply(protocol::BoardToHost::Param(ParamResponse {
            board: Node::StereoBoard,
            reply: ParamReply::Error(ParamError::Armed),
        }))
    );
    assert!(matches!(
        camera(ParamOp::List(0)),
        crate::host::HostOutcome::ToCamera(_)
    ));
    // Reads still answer in flight.
    let get = ParamOp::Get(ParamName::try_from("target_height").unwrap());
    assert!(matches!(
        param_request(&mut r.ap, Node::Autopilot, get),
        ParamReply::Entry(e) if e.value == ParamValue::F32(0.6)
    ));
    // The shorter hover before landing is the one flown.
    r.estimates = false;
    let lost_at = r.now;
    r.fly(6.0);
    let find = |m: FlightMode| r.modes.iter().find(|x| x.1 == m).map(|x| x.0);
    let hover = find(FlightMode::HoverNoEstimate).expect("hovered");
    let land = find(FlightMode::Landing).expect("landed");
    assert!(hover - lost_at <= 560_000);
    assert!(
        (land - hover).abs_diff(1_000_000) <= 40_000,
        "landing {} ms after the hover began",
        (land - hover) / 1000
    );
}

/// A flash sector in RAM with the flash's rules (`refuse` fails the next writes as a flash
/// error would).
type Sector = MemStore<1024>;

fn stored_request(ap: &mut Autopilot, store: &mut Sector, op: ParamOp) -> ParamReply {
    let req = ParamRequest {
        board: Node::Autopilot,
        op,
    };
    ap.on_param_request(&req, Some(store)).reply
}

#[test]
fn parameters_saved_on_the_ground_load_at_the_next_boot() {
    use protocol::ParamValue;
    let mut sector = Sector::blank();
    let (mut ap, loaded) = Autopilot::from_store(&sector);
    assert_eq!(loaded, Err(RecordError::Blank));
    assert_eq!(ap.config(), &AutopilotConfig::default());
    let op = ParamOp::Set(
        protocol::ParamName::try_from("guid_kp").unwrap(),
        ParamValue::F32(0.3),
    );
    assert!(matches!(
        stored_request(&mut ap, &mut sector, op),
        ParamReply::Entry(_)
    ));
    assert_eq!(
        stored_request(&mut ap, &mut sector, ParamOp::Save),
        ParamReply::Saved
    );
    assert_eq!(
        stored_request(&mut ap, &mut sector, ParamOp::Storage),
        ParamReply::Storage(StorageStatus {
            loaded: Err(RecordError::Blank),
            saves: 1,
            failed_saves: 0,
            acknowledged: false,
        })
    );

    // The next boot runs on the saved value and says so.
    let (mut next, loaded) = Autopilot::from_store(&sector);
    assert_eq!(loaded, Ok(()));
    assert_eq!(next.config().guidance.kp, 0.3);
    assert!(matches!(
        stored_request(&mut next, &mut sector, ParamOp::Storage),
        ParamReply::Storage(StorageStatus {
            loaded: Ok(()),
            saves: 0,
            ..
        })
    ));

    // A flash that refuses, or reads back other bytes, is a failed save, counted.
    sector.refuse = true;
    assert_eq!(
        stored_request(&mut next, &mut sector, ParamOp::Save),
        ParamReply::Error(ParamError::SaveFailed)
    );
    assert!(matches!(
        next.storage(),
        Some(StorageStatus {
            saves: 0,
            failed_saves: 1,
            acknowledged: false,
            ..
        })
    ));

    // A corrupted record: the defaults, and why.
    let mut corrupt = sector.clone();
    corrupt.bytes[40] ^= 0x04;
    let (ap, loaded) = Autopilot::from_store(&corrupt);
    assert_eq!(loaded, Err(RecordError::BadCrc));
    assert_eq!(ap.config(), &AutopilotConfig::default());
    assert_eq!(
        ap.storage().map(|s| s.loaded),
        Some(Err(RecordError::BadCrc))
    );
}

/// Flies a take-off and a hover whose clock starts `before_s` before `wrap_us`, so that the
/// flight crosses it; returns the run.
fn fly_across(wrap_us: u64, before_s: u64) -> Run {
    let mut r = Run::new(AutopilotConfig::default());
    // On the IMU's and the loops' cadence (`Run::fly` schedules by `now / IMU_US`).
    let period = IMU_US * 10 * 17;
    r.now = (wrap_us - before_s * 1_000_000) / period * period;
    r.takeoff();
    r.fly(before_s as f32 + 4.0);
    assert!(r.now > wrap_us, "the flight crossed the wrap");
    r
}

#[test]
fn a_flight_continues_across_the_clock_wraps() {
    // The 32-bit wire timestamp wraps at 2^32 us (71.6 min of uptime), the board's 32-bit
    // millisecond tick at 2^32 ms (49.7 days); the library's clock is 64-bit and each input is
    // stamped on it, so a flight across either wrap sees no stale input, no failsafe and
    // holds its height.
    for wrap_us in [1u64 << 32, (1u64 << 32) * 1_000] {
        let r = fly_across(wrap_us, 8);
        let modes: Vec<FlightMode> = r.modes.iter().map(|m| m.1).collect();
        assert_eq!(
            modes,
            [FlightMode::Disarmed, FlightMode::Flying],
            "wrap at {wrap_us} us: {:?}",
            r.modes
        );
        let target = AutopilotConfig::default().setpoints.target_height_m;
        let h = r.quad.height();
        assert!((h - target).abs() < 0.1, "wrap at {wrap_us} us: height {h}");
        assert!(
            r.max_tilt < 0.3,
            "wrap at {wrap_us} us: tilt {}",
            r.max_tilt
        );
    }
}

#[test]
fn a_failed_parameter_load_blocks_arming_until_acknowledged_or_saved() {
    use protocol::params::MemSlots;
    // Two slots, one saved record, then corrupted: nothing good to boot on.
    let mut slots = MemSlots::<1024>::blank();
    let (mut ap, _) = Autopilot::from_store(&slots);
    let req = |op| ParamRequest {
        board: Node::Autopilot,
        op,
    };
    assert_eq!(
        ap.on_param_request(&req(ParamOp::Save), Some(&mut slots))
            .reply,
        ParamReply::Saved
    );
    slots.bytes[0][40] ^= 0x04;
    for clear_by_save in [false, true] {
        let mut r = Run::new(AutopilotConfig::default());
        let (ap, loaded) = Autopilot::from_store(&slots.clone());
        assert_eq!(loaded, Err(RecordError::BadCrc));
        r.ap = ap;
        r.fly(0.5);
        assert_eq!(
            r.ap.arm_blocker(),
            Some(ArmBlock::ParamsNotLoaded(RecordError::BadCrc))
        );
        r.ap.on_command(PilotCommand::Arm, at(r.now));
        assert_eq!(r.ap.mode(), FlightMode::Disarmed);
        assert_eq!(r.ap.arm_refused(), 1);
        let mut store = slots.clone();
        let op = if clear_by_save {
            ParamOp::Save
        } else {
            ParamOp::Acknowledge
        };
        let reply = r.ap.on_param_request(&req(op), Some(&mut store)).reply;
        assert!(
            matches!(reply, ParamReply::Saved | ParamReply::Storage(_)),
            "{reply:?}"
        );
        assert_eq!(r.ap.arm_blocker(), None);
        r.takeoff();
    }
    // A board never saved (blank slots) is not blocked.
    let (ap, loaded) = Autopilot::from_store(&MemSlots::<1024>::blank());
    assert_eq!(loaded, Err(RecordError::Blank));
    assert_eq!(ap.arm_blocker(), None);
}

#[test]
fn a_save_is_refused_while_the_motors_may_run() {
    let mut sector = Sector::blank();
    let mut r = Run::new(AutopilotConfig::default());
    r.ap = Autopilot::from_store(&sector).0;
    r.takeoff();
    assert_eq!(
        stored_request(&mut r.ap, &mut sector, ParamOp::Save),
        ParamReply::Error(ParamError::Armed)
    );
    assert_eq!(sector.writes, 0, "the flash is not touched");
    // Without storage, a save and a storage query say so.
    let mut plain = Autopilot::new(AutopilotConfig::default());
    assert_eq!(
        param_request(&mut plain, Node::Autopilot, ParamOp::Storage),
        ParamReply::Error(ParamError::NoStorage)
    );
}

#[test]
fn parameter_requests_that_cannot_be_answered_say_why() {
    use protocol::{ParamName, ParamValue};
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let n = params::COUNT as u16;
    assert!(matches!(
        param_request(&mut ap, Node::Autopilot, ParamOp::List(n - 1)),
        ParamReply::Entry(e) if e.index == n - 1 && e.count == n
    ));
    assert_eq!(
        param_request(&mut ap, Node::Autopilot, ParamOp::List(n)),
        ParamReply::Error(ParamError::UnknownIndex)
    );
    let nothing = ParamOp::Get(ParamName::try_from("no_such").unwrap());
    assert_eq!(
        param_request(&mut ap, Node::Autopilot, nothing),
        ParamReply::Error(ParamError::UnknownName)
    );
    assert_eq!(
        param_request(&mut ap, Node::StereoBoard, ParamOp::List(0)),
        ParamReply::Error(ParamError::NoSuchBoard)
    );
    for (name, value, why) in [
        (
            "target_height",
            ParamValue::F32(9.0),
            ParamError::OutOfBounds,
        ),
        ("target_height", ParamValue::U32(1), ParamError::WrongKind),
        ("indi_rate_hz", ParamValue::F32(512.0), ParamError::ReadOnly),
        (
            "height_min_thrust",
            ParamValue::F32(0.9),
            ParamError::Inconsistent,
        ),
    ] {
        assert_eq!(
            set_param(&mut ap, name, value),
            ParamReply::Error(why),
            "{name}"
        );
    }
    assert_eq!(*ap.config(), AutopilotConfig::default());
    // A whole configuration is checked too.
    let mut bad = AutopilotConfig::default();
    bad.height.max_thrust = 1.5;
    let r = ap.set_config(bad).unwrap_err();
    assert_eq!(
        (r.name(), r.error),
        ("height_max_thrust", ParamError::OutOfBounds)
    );
    assert!(Autopilot::try_new(bad).is_err());
}

/// `VelocitySource::KalmanFits` flies on each frame's own fit, also when the board's filter
/// flagged the frame (its track disagreed), and ignores frames without a fit; the default
/// source takes the board's output.
#[test]
fn the_fit_source_takes_each_frames_own_fit() {
    let frame = |t: u64| {
        let mut e = forward_estimate(0.1);
        e.flags = EstimateFlags::POOR_FIT;
        e.fit = Some(FrameFit {
            forward_mps: 0.3,
            sideways_mps: 0.0,
            quality: 200,
        });
        (e, t)
    };
    let mut fits = autopilot_at_height();
    let mut cfg = *fits.config();
    cfg.estimation.velocity_source = VelocitySource::KalmanFits;
    fits.set_config(cfg).unwrap();
    let mut output = autopilot_at_height();
    for k in 1..=10u64 {
        let (e, t) = frame(k * 40_000);
        fits.on_estimate(&e, at(t));
        output.on_estimate(&e, at(t));
    }
    assert_eq!(fits.freshness().last_valid_estimate, Some(at(400_000)));
    assert_eq!(fits.velocity(), Some([0.3, 0.0]));
    assert_eq!(output.freshness().last_valid_estimate, None);
    // Without a fit, the fit source has nothing.
    let mut e = forward_estimate(0.3);
    e.fit = None;
    let mut fits = autopilot_at_height();
    fits.set_config(cfg).unwrap();
    for k in 1..=10u64 {
        fits.on_estimate(&e, at(k * 40_000));
    }
    assert_eq!(fits.freshness().last_valid_estimate, None);
}

/// Flies `seconds` on a battery resting at `resting_v` with 0.1 Ω of internal resistance, read
/// at 10 Hz under the current the motors draw.
fn fly_on_battery(r: &mut Run, resting_v: f32, seconds: f32) {
    for _ in 0..(seconds * 10.0).round() as u32 {
        let sag = 0.1 * r.ap.battery().current_a(&r.ap.motors(), resting_v);
        r.ap.on_battery(resting_v - sag, at(r.now));
        r.fly(0.1);
    }
}

#[test]
fn a_flat_battery_refuses_to_arm_and_a_low_one_lands_the_flight() {
    let mut r = Run::new(AutopilotConfig::default());
    fly_on_battery(&mut r, 3.6, 2.0);
    assert_eq!(r.ap.arm_blocker(), Some(ArmBlock::BatteryLow));
    r.ap.on_command(PilotCommand::Arm, at(r.now));
    assert_eq!(r.ap.mode(), FlightMode::Disarmed);
    assert_eq!(r.ap.arm_refused(), 1);
    // Charged: arms. Under hover thrust a 3.8 V battery reads about 3.5 V, below the landing
    // threshold (3.6 V); the sag compensation keeps the flight going.
    fly_on_battery(&mut r, 3.8, 5.0);
    r.takeoff();
    fly_on_battery(&mut r, 3.8, 5.0);
    let reading = r.ap.battery().last_reading().unwrap().1;
    assert!(reading < 3.55, "reads {reading} V under thrust");
    assert_eq!(r.ap.mode(), FlightMode::Flying);
    assert_eq!(
        r.ap.telemetry(at(r.now)).battery.unwrap().state,
        BatteryState::Ok
    );
    // Discharged below the low threshold: lands, and stays landed as the voltage recovers.
    fly_on_battery(&mut r, 3.4, 3.0);
    assert_eq!(r.ap.mode(), FlightMode::Landing);
    assert_eq!(r.ap.failsafe_reason(), Some(FailsafeReason::BatteryLow));
    fly_on_battery(&mut r, 3.4, 6.0);
    assert_eq!(r.ap.mode(), FlightMode::Disarmed);
    assert!(r.quad.height() < 0.02);
    assert_eq!(r.ap.failsafe_reason(), Some(FailsafeReason::BatteryLow));
    let tel = r.ap.telemetry(at(r.now)).battery.unwrap();
    assert_eq!(tel.state, BatteryState::Low);
    assert!((tel.resting_v - 3.4).abs() < 0.02, "{tel:?}");
}

#[test]
fn a_critical_battery_lands_at_once_at_the_fast_descent_rate() {
    let cfg = AutopilotConfig::default();
    let mut r = Run::new(cfg);
    fly_on_battery(&mut r, 3.9, 1.0);
    r.takeoff();
    fly_on_battery(&mut r, 3.9, 5.0);
    assert_eq!(r.ap.mode(), FlightMode::Flying);
    // A step down: the filter passes the low threshold first (the landing's reason), then
    // the critical one, which hurries the descent.
    fly_on_battery(&mut r, 3.1, 2.0);
    assert_eq!(r.ap.mode(), FlightMode::Landing);
    assert_eq!(r.ap.failsafe_reason(), Some(FailsafeReason::BatteryLow));
    assert_eq!(r.ap.battery().state(), BatteryState::Critical);
    let h0 = r.ap.setpoints().height_m;
    fly_on_battery(&mut r, 3.1, 0.5);
    let rate = (h0 - r.ap.setpoints().height_m) / 0.5;
    assert!(
        (rate - cfg.setpoints.blind_land_rate_mps).abs() < 0.05,
        "descends at {rate} m/s"
    );
    fly_on_battery(&mut r, 3.1, 4.0);
    assert_eq!(r.ap.mode(), FlightMode::Disarmed);
}

#[test]
fn hil_outputs_are_off_at_boot_and_enabled_only_with_the_motors_off() {
    let mut r = Run::new(AutopilotConfig::default());
    assert!(!r.ap.hil_outputs(), "off at boot");
    r.ap.on_command(PilotCommand::HilOutputs(true), at(r.now));
    assert!(r.ap.hil_outputs());
    r.ap.on_command(PilotCommand::HilOutputs(false), at(r.now));
    assert!(!r.ap.hil_outputs());
    r.takeoff();
    r.fly(1.0);
    // Flying: enabling is refused (the outputs would jump to the flight's duty), the flight
    // goes on untouched.
    r.ap.on_command(PilotCommand::HilOutputs(true), at(r.now));
    assert!(!r.ap.hil_outputs());
    assert_eq!(r.ap.mode(), FlightMode::Flying);
    // Disabling is always taken.
    r.ap.on_command(PilotCommand::Kill, at(r.now));
    r.ap.on_command(PilotCommand::HilOutputs(true), at(r.now));
    assert!(r.ap.hil_outputs(), "the motors are off again");
    r.takeoff();
    r.fly(0.5);
    r.ap.on_command(PilotCommand::HilOutputs(false), at(r.now));
    assert!(!r.ap.hil_outputs());
    assert_eq!(r.ap.mode(), FlightMode::Flying, "the gate is not a kill");
}

/// A motion-capture fix of height `h` m taken at `t` µs.
fn height_fix(h: f32, t: u64) -> ExternalPosition {
    ExternalPosition {
        timestamp_us: WireTime(t as u32),
        position_m: [0.0, 0.0, -h],
    }
}

/// A level, still IMU sample at `t` µs.
fn still_imu(t: u64) -> ImuSample {
    ImuSample {
        timestamp_us: WireTime(t as u32),
        gyro_radps: [0.0; 3],
        accel_mps2: [0.0, 0.0, -GRAVITY],
    }
}

/// A height fix goes through the vertical filter's innovation gate: one it refuses (a spoofed
/// jump) reaches neither the height loop nor the arming check's freshness, and is counted;
/// with `ext_pos_enable` off no fix is used at all.
#[test]
fn external_fixes_pass_the_vertical_gate_or_go_nowhere() {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let mut t = 0;
    for _ in 0..50 {
        t += 10_000;
        ap.on_external_position(&height_fix(0.0, t), at(t));
    }
    assert_eq!(ap.fixes_refused(), 0);
    assert_eq!(ap.height.last_measurement(), Some(at(t)));
    let taken = t;
    t += 10_000;
    ap.on_external_position(&height_fix(3.0, t), at(t));
    assert_eq!(ap.fixes_refused(), 1);
    assert!(
        ap.vertical.height_m().abs() < 0.01,
        "{}",
        ap.vertical.height_m()
    );
    assert!(
        ap.height.height_m().abs() < 0.01,
        "{}",
        ap.height.height_m()
    );
    assert_eq!(ap.height.last_measurement(), Some(at(taken)));
    assert_eq!(ap.freshness().last_height, Some(at(taken)));

    let mut cfg = AutopilotConfig::default();
    cfg.vertical.external_fixes = false;
    let mut ap = Autopilot::new(cfg);
    for k in 1..=50 {
        ap.on_external_position(&height_fix(0.5, k * 20_000), at(k * 20_000));
    }
    assert_eq!(ap.fixes_refused(), 50);
    assert_eq!(ap.vertical.height_m(), 0.0, "the estimator never saw them");
    assert_eq!(ap.height.last_measurement(), None);
    assert_eq!(ap.freshness().last_height, None);
}

/// What a motion-capture system reports of a drone taking off: 50 Hz fixes on the floor, then
/// climbing at the take-off climb rate to 1 m and holding, while the IMU (512 Hz) feels no
/// vertical acceleration (the worst case for the filter: the climb starts and stops at once).
/// Every fix passes the gate, and the height loop flies on them.
#[test]
fn a_motion_capture_take_off_passes_the_gate_fix_by_fix() {
    let cfg = AutopilotConfig::default();
    let mut ap = Autopilot::new(cfg);
    let (mut t, mut next_fix, mut h) = (0u64, 0u64, 0.0f32);
    let mut worst = 0.0f32;
    while t < 6_000_000 {
        t += IMU_US;
        ap.on_imu(&still_imu(t), at(t));
        if t >= next_fix {
            next_fix += 20_000;
            let climbing = t > 1_000_000;
            if climbing {
                h = (h + cfg.setpoints.climb_rate_mps * 0.02).min(1.0);
            }
            ap.on_external_position(&height_fix(h, t), at(t));
            worst = worst.max((ap.height.height_m() - h).abs());
        }
    }
    std::println!(
        "motion-capture take-off: {} fixes refused, height loop within {worst:.4} m of the fixes",
        ap.fixes_refused()
    );
    assert_eq!(ap.fixes_refused(), 0);
    assert!(worst < 1e-6, "the height loop flies on the fixes: {worst}");
    assert!((ap.vertical.height_m() - 1.0).abs() < 0.01);
}

/// One fix (even one the gate takes) does not make the height fresh for arming on a drone
/// with no other height source; a stream of [`FIXES_TO_LEAD`] does.
#[test]
fn a_single_fix_does_not_satisfy_the_arming_check() {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let mut t = 0;
    for _ in 0..100 {
        t += IMU_US;
        ap.on_imu(&still_imu(t), at(t));
    }
    ap.on_host_heartbeat(at(t));
    ap.on_external_position(&height_fix(0.0, t), at(t));
    assert_eq!(ap.fixes_refused(), 0, "the gate took it");
    assert_eq!(ap.freshness().last_height, None);
    ap.on_command(PilotCommand::Arm, at(t));
    assert_eq!(ap.mode(), FlightMode::Disarmed);
    assert_eq!(ap.arm_refused(), 1);
    for k in 1..FIXES_TO_LEAD {
        let until = t + u64::from(k) * 20_000;
        while t < until {
            t += IMU_US;
            ap.on_imu(&still_imu(t), at(t));
        }
        ap.on_external_position(&height_fix(0.0, t), at(t));
    }
    assert_eq!(ap.freshness().last_height, Some(at(t)));
    ap.on_command(PilotCommand::Arm, at(t));
    assert_eq!(ap.mode(), FlightMode::Flying);
    assert_eq!(ap.arm_refused(), 1);
}

/// A fix stream that pauses longer than the estimator's fix hold time starts again: its first
/// fix after the pause does not refresh the height loop.
#[test]
fn a_fix_stream_that_pauses_must_build_up_again() {
    let mut ap = Autopilot::new(AutopilotConfig::default());
    let mut t = 0;
    let fix_every = |ap: &mut Autopilot, t: &mut u64, fixes: u32, period: u64| {
        for _ in 0..fixes {
            for _ in 0..period / IMU_US {
                *t += IMU_US;
                ap.on_imu(&still_imu(*t), at(*t));
            }
            ap.on_external_position(&height_fix(0.0, *t), at(*t));
        }
    };
    fix_every(&mut ap, &mut t, 10, 20_000);
    assert_eq!(ap.height.last_measurement(), Some(at(t)));
    let before_pause = t;
    fix_every(&mut ap, &mut t, 1, 1_000_000);
    assert_eq!(ap.height.last_measurement(), Some(at(before_pause)));
    fix_every(&mut ap, &mut t, u32::from(FIXES_TO_LEAD) - 1, 20_000);
    assert_eq!(ap.height.last_measurement(), Some(at(t)));
    assert_eq!(ap.fixes_refused(), 0);
}

#[test]
fn a_valid_camera_climb_rate_moves_the_climb_rate_and_an_invalid_one_does_not() {
    let mut cfg = AutopilotConfig::default();
    cfg.vertical.camera_climb = true;
    let mut ap = Autopilot::new(cfg);
    let mut est = forward_estimate(0.0);
    est.up_mps = 0.3;
    assert!(!est.up_flags.is_valid());
    for k in 1..=10 {
        ap.on_estimate(&est, at(k * 40_000));
    }
    assert_eq!(ap.vertical.climb_mps(), 0.0, "up_flags invalid: not used");

    est.up_flags = EstimateFlags::NONE;
    est.processing_us = u16::MAX;
    ap.on_estimate(&est, at(440_000));
    assert_eq!(ap.vertical.climb_mps(), 0.0, "65 ms or older: not used");

    est.processing_us = 20_000;
    for k in 12..=20 {
        ap.on_estimate(&est, at(k * 40_000));
    }
    let climb = ap.vertical.climb_mps();
    assert!(climb > 0.1 && climb <= 0.3, "{climb}");
    assert_eq!(ap.vertical.rejected(), 0);

    let mut ap = Autopilot::new(AutopilotConfig::default());
    ap.on_estimate(&est, at(40_000));
    assert_eq!(ap.vertical.climb_mps(), 0.0, "off by default");
}

/// The camera's velocity (forward, sideways, up in its body axes) to the world's climb rate:
/// level it is the up velocity; pitched nose-up a forward velocity climbs, banked right a
/// rightward one sinks; without a valid forward and sideways velocity only near level.
#[test]
fn the_cameras_velocity_turns_to_the_climb_rate_with_the_attitude() {
    let mut est = forward_estimate(1.0);
    est.up_mps = 0.2;
    est.up_flags = EstimateFlags::NONE;
    let level = camera_climb_mps(&est, Quat::IDENTITY).unwrap();
    assert!((level - 0.2).abs() < 1e-6, "{level}");
    let pitch = 0.2f32;
    let nose_up = camera_climb_mps(&est, Quat::from_euler(0.0, pitch, 0.0)).unwrap();
    let expected = 1.0 * libm::sinf(pitch) + 0.2 * libm::cosf(pitch);
    assert!((nose_up - expected).abs() < 1e-4, "{nose_up} vs {expected}");
    est.forward_mps = 0.0;
    est.sideways_mps = 1.0;
    let roll = 0.2f32;
    let banked = camera_climb_mps(&est, Quat::from_euler(roll, 0.0, 0.0)).unwrap();
    let expected = -libm::sinf(roll) + 0.2 * libm::cosf(roll);
    assert!((banked - expected).abs() < 1e-4, "{banked} vs {expected}");

    est.flags = EstimateFlags::NO_STEREO_MATCH;
    assert_eq!(
        camera_climb_mps(&est, Quat::from_euler(roll, 0.0, 0.0)),
        None
    );
    let near_level = camera_climb_mps(&est, Quat::from_euler(0.05, 0.0, 0.0)).unwrap();
    assert!(
        (near_level - 0.2 * libm::cosf(0.05)).abs() < 1e-4,
        "{near_level}"
    );
    est.up_mps = f32::NAN;
    assert_eq!(camera_climb_mps(&est, Quat::IDENTITY), None);
}
