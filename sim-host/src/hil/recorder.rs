//! The flight's records: [`HilRecorder`] writes the MCAP flight log on world time during the
//! lockstep (estimates, telemetry beside the truth, motor duties, the true pose, the 3D view
//! and a few camera images a second), and [`write_log_csv`] writes a finished run's 50 Hz log
//! rows as CSV.

use super::board_rx::BoardRx;
use super::relay::add_errors;
use super::result::HilResult;
use crate::log::records::{EstimateRecord, LinkRecord, MotorsRecord, StateRecord, TruthRecord};
use crate::log::scene3d::{self, BodyPose, CameraMount};
use crate::log::view3d::{View3d, ViewRates, ViewSample};
use crate::log::{ns as log_ns, write_telemetry, FlightLog, TelemetryExtras, Thinner};
use crate::sim::dynamics::Drone;
use crate::sim::world::World;
use anyhow::Context as _;
use protocol::{Estimate, FlightMode, Telemetry, STEREO_FRAME_BYTES};
use timebase::WorldTime;

/// What `sim-host hil` records into its MCAP flight log, on world time: every estimate the
/// camera board mirrors, the autopilot's telemetry (state and mode by name, attitude with the
/// gyro sample last sent, velocity and its setpoint, height, link counters of the board and of
/// this host) with the true velocity and height beside it, the motor duties at 128 Hz, the true
/// pose at 50 Hz, and the left and right images of the frames sent, about 5 per second.
pub struct HilRecorder<'a> {
    log: Option<&'a mut FlightLog>,
    pub(super) error: Option<anyhow::Error>,
    images: Thinner,
    motors: Thinner,
    view: View3d,
    /// The autopilot's last telemetry, what the 3D view shows it believes.
    last_telemetry: Option<Telemetry>,
}

impl<'a> HilRecorder<'a> {
    /// Records into `log` (if any) a flight in `world`, starting with the room in 3D.
    pub(super) fn new(log: Option<&'a mut FlightLog>, world: &World) -> Self {
        let mount = CameraMount {
            forward_m: world.camera.params.forward_offset_m,
            baseline_m: world.camera.params.baseline_m,
        };
        let mut recorder = Self {
            log,
            error: None,
            images: Thinner::new(5.0),
            motors: Thinner::new(128.0),
            view: View3d::new(ViewRates::default(), mount),
            last_telemetry: None,
        };
        recorder.with_view(|view, log| view.start(log, 0, Some(&world.scene)));
        recorder
    }

    fn with_view(&mut self, f: impl FnOnce(&mut View3d, &mut FlightLog) -> anyhow::Result<()>) {
        if let Some(log) = self.log.as_deref_mut() {
            if let Err(e) = f(&mut self.view, log) {
                self.error = Some(e);
                self.log = None;
            }
        }
    }

    fn with(&mut self, f: impl FnOnce(&mut FlightLog) -> anyhow::Result<()>) {
        if let Some(log) = self.log.as_deref_mut() {
            if let Err(e) = f(log) {
                self.error = Some(e);
                self.log = None;
            }
        }
    }

    pub(super) fn estimate(&mut self, t: WorldTime, e: &Estimate) {
        let t_us = t.as_micros();
        self.with(|log| log.write(log_ns(t_us), &EstimateRecord::from(e)));
    }

    pub(super) fn frame(&mut self, t: WorldTime, frame: &[u8; STEREO_FRAME_BYTES]) {
        let t_us = t.as_micros();
        if self.images.take(t_us) {
            self.with(|log| log.stereo_frame(log_ns(t_us), frame));
        }
    }

    pub(super) fn motors(&mut self, t: WorldTime, motors: [f32; 4]) {
        let t_us = t.as_micros();
        if self.motors.take(t_us) {
            self.with(|log| log.write(log_ns(t_us), &MotorsRecord::from(motors)));
        }
    }

    pub(super) fn truth(&mut self, t: WorldTime, drone: &Drone, collisions: u32) {
        let t_us = t.as_micros();
        let s = &drone.state;
        let (roll, pitch, yaw) = s.att.to_euler();
        if let Some(tel) = self.last_telemetry {
            let state = StateRecord::new(tel.fsm_state, tel.flight_mode);
            let label = format!("{} / {}", state.fsm_state, state.mode);
            let sample = ViewSample {
                truth: Some(BodyPose {
                    position: scene3d::world_point(s.pos.x as f32, s.pos.y as f32, -s.pos.z as f32),
                    orientation: scene3d::body_orientation(roll as f32, pitch as f32, yaw as f32),
                }),
                attitude_rad: tel.attitude_rad,
                velocity_mps: tel.velocity_mps,
                height_m: tel.height_m,
                obstacle_m: tel.obstacle_m,
                state: &label,
            };
            self.with_view(|view, log| view.step(log, t_us, &sample));
        }
        self.with(|log| {
            log.write(
                log_ns(t_us),
                &TruthRecord {
                    x_m: s.pos.x as f32,
                    y_m: s.pos.y as f32,
                    height_m: -s.pos.z as f32,
                    yaw_rad: Some(yaw as f32),
                    clearance_m: None,
                    collisions,
                },
            )
        });
    }

    pub(super) fn telemetry(
        &mut self,
        t: WorldTime,
        tel: &Telemetry,
        gyro_radps: [f32; 3],
        drone: &Drone,
        r: &HilResult,
        host: [&BoardRx; 2],
    ) {
        let s = &drone.state;
        let (_, _, yaw) = s.att.to_euler();
        let (sy, cy) = yaw.sin_cos();
        let true_v = [
            (s.vel.x * cy + s.vel.y * sy) as f32,
            (-s.vel.x * sy + s.vel.y * cy) as f32,
        ];
        let host_errors = add_errors(host[0].errors(), host[1].errors());
        let t = log_ns(t.as_micros());
        self.last_telemetry = Some(*tel);
        self.with(|log| {
            write_telemetry(
                log,
                t,
                tel,
                &TelemetryExtras {
                    gyro_radps: Some(gyro_radps),
                    true_velocity_mps: Some(true_v),
                    true_height_m: Some(-s.pos.z as f32),
                },
            )?;
            log.write(
                t,
                &LinkRecord {
                    camera_link_errors: tel.link_errors.into(),
                    host_link_errors: Some(host_errors.into()),
                    estimates_received: r.estimates,
                    estimates_valid: r.valid_estimates,
                    frames_dropped: None,
                    camera_to_autopilot_bytes_lost: None,
                    camera_to_autopilot_bytes_corrupted: None,
                    autopilot_to_camera_bytes_lost: None,
                    timeouts: Some(r.reply_timeouts + r.frame_timeouts),
                },
            )
        });
    }
}

/// Writes the log as CSV.
pub fn write_log_csv(r: &HilResult, path: &std::path::Path) -> anyhow::Result<()> {
    let mut s = String::from("t_s,x_m,y_m,h_m,vx_mps,vy_mps,m1,m2,m3,m4,mode\n");
    for row in &r.log {
        s.push_str(&format!(
            "{:.3},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{}\n",
            row.t_s,
            row.pos[0],
            row.pos[1],
            row.pos[2],
            row.vel[0],
            row.vel[1],
            row.motors[0],
            row.motors[1],
            row.motors[2],
            row.motors[3],
            row.mode.map_or("none", FlightMode::name)
        ));
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}
