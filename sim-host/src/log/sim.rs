//! The simulator's flight log: a [`FlightObserver`] writing a [`FlightLog`].

use super::records::*;
use super::scene3d::{self, BodyPose, CameraMount};
use super::view3d::{View3d, ViewRates, ViewSample};
use super::{ns, FlightLog, Thinner};
use crate::sim::battery::Battery;
use crate::sim::camera::CameraParams;
use crate::sim::flight::{FlightCounters, FlightObserver, LogRow};
use crate::sim::scene::Scene;
use autopilot::app::Autopilot;
use autopilot::ms5611::BaroReading;
use protocol::{Estimate, STEREO_FRAME_BYTES};
use std::io::{Seek, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use stereo_board::edge_fs::Diagnostics;
use timebase::WorldTime;

/// Rates of the channels that are thinned out.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogRates {
    /// Attitude, body rates and motor duties, Hz (the control loop runs at 512 Hz).
    pub control_hz: f64,
    /// Camera images (left and right), about this many per second (see [`Thinner`]).
    pub image_hz: f64,
    /// The 3D view.
    pub view: ViewRates,
}

impl Default for LogRates {
    fn default() -> Self {
        Self {
            control_hz: 128.0,
            image_hz: 5.0,
            view: ViewRates::default(),
        }
    }
}

/// Records a simulated flight. Write errors stop the recording; [`SimRecorder::finish`]
/// reports the first.
pub struct SimRecorder<W: Write + Seek> {
    log: Option<FlightLog<W>>,
    error: Option<anyhow::Error>,
    control: Thinner,
    images: Thinner,
    last_status_uptime: Option<u32>,
    view: View3d,
    /// Wall-clock instant of world time 0, when the flight is paced to real time.
    pace: Option<std::time::Instant>,
    /// Set (by a Ctrl-C handler) to end the flight early; the log is still finished.
    interrupt: Option<Arc<AtomicBool>>,
}

impl<W: Write + Seek> SimRecorder<W> {
    /// Records into `log` at `rates`.
    pub fn new(log: FlightLog<W>, rates: LogRates) -> Self {
        Self {
            log: Some(log),
            error: None,
            control: Thinner::new(rates.control_hz),
            images: Thinner::new(rates.image_hz),
            last_status_uptime: None,
            pace: None,
            interrupt: None,
            view: View3d::new(
                rates.view,
                CameraMount {
                    forward_m: 0.0,
                    baseline_m: 0.0,
                },
            ),
        }
    }

    fn with_log(&mut self, f: impl FnOnce(&mut FlightLog<W>) -> anyhow::Result<()>) {
        if let Some(log) = self.log.as_mut() {
            if let Err(e) = f(log) {
                self.error = Some(e);
                self.log = None;
            }
        }
    }

    /// Holds the flight back to real time (for a live view): each guidance step waits until
    /// the wall clock has caught up with world time.
    pub fn pace_to_wall_clock(&mut self) {
        self.pace = Some(std::time::Instant::now());
    }

    /// Ends the flight at the next event once `flag` is set (a Ctrl-C handler sets it): the
    /// flight returns what it flew, and [`SimRecorder::finish`] closes the log as usual.
    pub fn interrupt_on(&mut self, flag: Arc<AtomicBool>) {
        self.interrupt = Some(flag);
    }

    fn with_view(&mut self, f: impl FnOnce(&mut View3d, &mut FlightLog<W>) -> anyhow::Result<()>) {
        if let Some(log) = self.log.as_mut() {
            if let Err(e) = f(&mut self.view, log) {
                self.error = Some(e);
                self.log = None;
            }
        }
    }

    /// Closes the log; the first write error, if any.
    pub fn finish(self) -> anyhow::Result<super::LogSummary> {
        if let Some(e) = self.error {
            return Err(e);
        }
        self.log
            .ok_or_else(|| anyhow::anyhow!("the flight log was not written"))?
            .finish()
    }
}

fn finite(v: f32) -> Option<f32> {
    v.is_finite().then_some(v)
}

/// The true body pose of a log row, with the true roll and pitch (the estimate less its
/// error).
fn true_pose(ap: &Autopilot, row: &LogRow) -> BodyPose {
    let [roll_est, pitch_est, _] = ap.attitude();
    let roll = roll_est - row.tilt_err_deg[0].to_radians();
    let pitch = pitch_est - row.tilt_err_deg[1].to_radians();
    BodyPose {
        position: scene3d::world_point(row.pos[0], row.pos[1], row.pos[2]),
        orientation: scene3d::body_orientation(roll, pitch, row.yaw),
    }
}

impl<W: Write + Seek> FlightObserver for SimRecorder<W> {
    fn interrupted(&self) -> bool {
        self.interrupt
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed))
    }

    fn on_scene(&mut self, scene: &Scene, camera: &CameraParams) {
        let mount = CameraMount {
            forward_m: camera.forward_offset_m,
            baseline_m: camera.baseline_m,
        };
        self.view.set_mount(mount);
        self.with_view(|view, log| view.start(log, 0, Some(scene)));
    }

    fn on_edge_fs(&mut self, t: WorldTime, diagnostics: &Diagnostics) {
        // The log stamps records in µs of world time.
        let t_us = t.as_micros();
        self.with_view(|view, log| view.depths(log, t_us, &diagnostics.depth_m));
    }

    fn on_estimate(&mut self, t: WorldTime, estimate: &Estimate) {
        // The log stamps records in µs of world time.
        let t_us = t.as_micros();
        self.with_log(|log| log.write(ns(t_us), &EstimateRecord::from(estimate)));
    }

    fn on_baro(&mut self, t: WorldTime, reading: &BaroReading) {
        // The log stamps records in µs of world time.
        let t_us = t.as_micros();
        let record = BaroRecord {
            pressure_pa: reading.pressure_pa,
            temperature_c: reading.temperature_c,
        };
        self.with_log(|log| log.write(ns(t_us), &record));
    }

    fn on_battery(&mut self, t: WorldTime, ap: &Autopilot, battery: &Battery) {
        // The log stamps records in µs of world time.
        let t_us = t.as_micros();
        let Some(report) = ap.battery().telemetry() else {
            return;
        };
        let record = BatteryRecord {
            true_resting_v: Some(battery.open_circuit_v() as f32),
            true_current_a: Some(battery.current_a() as f32),
            true_charge: Some(battery.charge() as f32),
            ..BatteryRecord::new(&report)
        };
        self.with_log(|log| log.write(ns(t_us), &record));
    }

    fn on_frame(&mut self, t: WorldTime, frame: &[u8; STEREO_FRAME_BYTES]) {
        // The log stamps records in µs of world time.
        let t_us = t.as_micros();
        if !self.images.take(t_us) {
            return;
        }
        self.with_log(|log| log.stereo_frame(ns(t_us), frame));
    }

    fn on_control(&mut self, t: WorldTime, ap: &Autopilot, gyro_radps: [f32; 3], motors: [f32; 4]) {
        // The log stamps records in µs of world time.
        let t_us = t.as_micros();
        if !self.control.take(t_us) {
            return;
        }
        let [roll, pitch, yaw] = ap.attitude();
        self.with_log(|log| {
            log.write(
                ns(t_us),
                &AttitudeRecord {
                    roll_rad: roll,
                    pitch_rad: pitch,
                    yaw_rad: yaw,
                    roll_rate_radps: Some(gyro_radps[0]),
                    pitch_rate_radps: Some(gyro_radps[1]),
                    yaw_rate_radps: Some(gyro_radps[2]),
                },
            )?;
            log.write(ns(t_us), &MotorsRecord::from(motors))
        });
    }

    fn on_guidance(&mut self, t: WorldTime, ap: &Autopilot, row: &LogRow, c: &FlightCounters) {
        // The log stamps records in µs of world time.
        let t_us = t.as_micros();
        if let Some(start) = self.pace {
            let due = start + std::time::Duration::from_micros(t_us);
            if let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
                std::thread::sleep(wait);
            }
        }
        let tel = ap.telemetry(t.as_flight_clock());
        let t = ns(t_us);
        let sp = ap.setpoints();
        let status = ap.stereo_status();
        let new_status = status.filter(|s| self.last_status_uptime != Some(s.uptime_ms));
        if let Some(s) = new_status {
            self.last_status_uptime = Some(s.uptime_ms);
        }
        self.with_log(|log| {
            log.write(t, &StateRecord::new(tel.fsm_state, tel.flight_mode))?;
            log.write(
                t,
                &SetpointRecord {
                    forward_mps: sp.velocity_mps[0],
                    sideways_mps: sp.velocity_mps[1],
                    roll_rad: Some(sp.attitude_rad[0]),
                    pitch_rad: Some(sp.attitude_rad[1]),
                    yaw_rad: Some(sp.attitude_rad[2]),
                    height_m: Some(sp.height_m),
                    thrust: Some(sp.thrust),
                },
            )?;
            log.write(
                t,
                &VelocityRecord {
                    forward_mps: finite(row.vel_est[0]),
                    sideways_mps: finite(row.vel_est[1]),
                    true_forward_mps: finite(row.vel_true[0]),
                    true_sideways_mps: finite(row.vel_true[1]),
                },
            )?;
            log.write(
                t,
                &HeightRecord {
                    height_m: tel.height_m,
                    setpoint_m: Some(sp.height_m),
                    true_m: Some(row.pos[2]),
                },
            )?;
            log.write(
                t,
                &TruthRecord {
                    x_m: row.pos[0],
                    y_m: row.pos[1],
                    height_m: row.pos[2],
                    yaw_rad: Some(row.yaw),
                    clearance_m: finite(row.clearance_m),
                    collisions: c.collisions,
                },
            )?;
            log.write(
                t,
                &LinkRecord {
                    camera_link_errors: tel.link_errors.into(),
                    host_link_errors: None,
                    estimates_received: c.estimates[0],
                    estimates_valid: c.estimates[1],
                    frames_dropped: Some(c.frames_dropped),
                    camera_to_autopilot_bytes_lost: Some(c.uart[0].bytes_lost),
                    camera_to_autopilot_bytes_corrupted: Some(c.uart[0].bytes_corrupted),
                    autopilot_to_camera_bytes_lost: Some(c.uart[1].bytes_lost),
                    timeouts: None,
                },
            )?;
            if let Some(s) = new_status {
                log.write(t, &StereoStatusRecord::from(&s))?;
            }
            Ok(())
        });
        let state = StateRecord::new(tel.fsm_state, tel.flight_mode);
        let label = format!("{} / {}", state.fsm_state, state.mode);
        let sample = ViewSample {
            truth: Some(true_pose(ap, row)),
            attitude_rad: ap.attitude(),
            velocity_mps: row.vel_est,
            height_m: tel.height_m,
            obstacle_m: row.obstacle_m.is_finite().then_some(row.obstacle_m),
            state: &label,
        };
        self.with_view(|view, log| view.step(log, t_us, &sample));
    }
}
