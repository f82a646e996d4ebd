//! The autopilot: adaptive INDI attitude control, height control, velocity guidance, median-5
//! filter, wall force field, avoidance FSM and failsafes. `no_std`, no heap, time passed in: the
//! firmware and `sim-host` run exactly this code.
//!
//! Modules, bottom up:
//!
//! * [`attitude`]: gyro + accelerometer complementary filter, quaternion helpers.
//! * [`gyro_calibration`]: the gyro offset, averaged while the drone stands still on the ground.
//! * [`indi`]: adaptive INDI rate/attitude control at 512 Hz.
//! * [`mixer`]: X-quad mixer for four brushed motors, attitude before thrust.
//! * [`height`]: vertical loop from the height estimate.
//! * [`vertical`]: height, climb rate and barometer offset from the accelerometer, the
//!   barometer and an external height fix (a Kalman filter); the height loop flies on it.
//! * [`median`]: median-5 over the Edge-FS velocities.
//! * [`estimation`]: the horizontal velocity stage: the estimate gates, the median-5 and
//!   observer (paper mode) or the Kalman filter, predicted at 512 Hz.
//! * [`guidance`]: velocity PI to roll/pitch setpoints.
//! * [`setpoints`]: the guidance stage: height setpoint (take-off climb, landing descent,
//!   touchdown), velocity loop and heading make the setpoints the 512 Hz loop flies.
//! * [`velocity_kf`]: horizontal velocity Kalman filter (IMU-driven model, Edge-FS
//!   measurements weighted by quality at the time window they describe).
//! * [`velocity_model`]: the horizontal model and prediction history both velocity estimators
//!   share.
//! * [`force_field`]: backward velocity near walls.
//! * [`fsm`]: the paper's 4-state avoidance FSM and the turn-until-clear variant.
//! * [`range_rate`]: the closing speed on the nearest obstacle from its stereo distances.
//! * [`avoidance`]: the avoidance stage: obstacle readings, the FSM and the force field make
//!   guidance's velocity and heading request; the range rate checks the velocity estimate.
//! * [`failsafe`]: flight modes, kill, estimate/IMU/height timeouts, why a landing began.
//! * [`battery`]: the supply voltage filtered and compensated for its sag under thrust, the
//!   arming, landing and critical thresholds.
//! * [`app`]: [`Autopilot`], the board's task logic: the stages composed.
//! * [`config`]: [`AutopilotConfig`], every stage's configuration composed.
//! * [`tasks`]: the task periods and the task table [`TASKS`].
//! * [`camera_link`]: the camera board's link: decoder, last heartbeat, status and answers.
//! * [`link_auth`]: which host messages must be signed, the link key and the refusal counts.
//! * [`host`]: [`Autopilot::on_host_message`], the one dispatch of host messages that the
//!   firmware, the simulator and every HIL board call.
//! * [`params`]: the parameter table: every [`AutopilotConfig`] field by name, kind, unit
//!   and bounds, read, written and validated, and its flash record (CRC, format version).
//! * [`rc`]: SBUS receiver decoding and the RC switches mapped to pilot commands.
//! * [`lockstep`]: the world clock and task releases of the hardware-in-the-loop flavours.
//! * [`board`]: the Lisa/MX 2.1 board definition (pins, peripherals, clocks, rates, IMU axes,
//!   mounting), from the original sources.
//! * [`mpu6000`], [`ms5611`]: the IMU's set-up and sample checks, the barometer's PROM check
//!   and compensation (the firmware does the SPI transfers).
#![no_std]
#![warn(missing_docs)]

pub mod app;
pub mod attitude;
pub mod avoidance;
pub mod battery;
pub mod board;
pub mod camera_link;
pub mod config;
pub mod estimation;
pub mod failsafe;
pub mod force_field;
pub mod fsm;
pub mod guidance;
pub mod gyro_calibration;
pub mod height;
pub mod host;
pub mod indi;
pub mod link_auth;
pub mod lockstep;
pub mod median;
pub mod mixer;
pub mod mpu6000;
pub mod ms5611;
pub mod params;
pub mod range_rate;
pub mod rc;
pub mod setpoints;
pub mod tasks;
#[cfg(test)]
mod test_support;
pub mod velocity_kf;
pub mod velocity_model;
pub mod vertical;

pub use app::{ArmBlock, Autopilot, Setpoints};
pub use config::AutopilotConfig;
pub use failsafe::FlightMode;
pub use fsm::{FsmState, FsmVariant};
pub use host::HostOutcome;
pub use tasks::{TaskSpec, Trigger, TASKS};
