//! The 3D view of a flight as it is recorded: [`View3d`] turns what a recorder knows at each
//! step (the true pose where there is one, the autopilot's attitude, velocity, height,
//! obstacle and state) into the [`scene3d`] messages at their rates. The simulator's, the HIL
//! bridge's and the monitor's recorders share it.

use super::scene3d::{self, BodyPose, CameraMount};
use super::{ns, FlightLog, Thinner};
use crate::sim::scene::Scene;
use foxglove::schemas::Point3;
use std::io::{Seek, Write};
use stereo_board::edge_fs::IMG_W;

/// Rates of the 3D view's channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewRates {
    /// The drone's transforms, Hz.
    pub pose_hz: f64,
    /// Stereo depth points and annotations, Hz.
    pub view_hz: f64,
    /// Points of the paths, Hz (sent in pieces of one second).
    pub path_hz: f64,
}

impl Default for ViewRates {
    fn default() -> Self {
        Self {
            pose_hz: 25.0,
            view_hz: 10.0,
            path_hz: 10.0,
        }
    }
}

/// What the autopilot believes at one instant, with the truth where the recorder has it.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSample<'a> {
    /// The true body pose (simulator and HIL), `None` for a real board.
    pub truth: Option<BodyPose>,
    /// The autopilot's attitude estimate: roll, pitch, yaw, rad (the simulator's sense).
    pub attitude_rad: [f32; 3],
    /// The autopilot's velocity estimate in its heading frame: forward, sideways, m/s (NaN:
    /// none).
    pub velocity_mps: [f32; 2],
    /// The autopilot's height estimate, m.
    pub height_m: f32,
    /// The nearest obstacle the autopilot holds, m.
    pub obstacle_m: Option<f32>,
    /// FSM state and flight mode, as text.
    pub state: &'a str,
}

/// Length of one path piece, µs.
const PATH_PIECE_US: u64 = 1_000_000;

/// The 3D view's state between steps.
pub struct View3d {
    mount: CameraMount,
    poses: Thinner,
    depths: Thinner,
    annotations: Thinner,
    path: Thinner,
    /// The path pieces being collected (true, estimated).
    piece: (Vec<Point3>, Vec<Point3>),
    /// Number of the next piece.
    piece_index: u32,
    /// Start of the current piece, µs.
    piece_start_us: u64,
    /// Dead-reckoned position (north, east, m) and the time of its last update, µs.
    dead_reckoned: Option<([f64; 2], u64)>,
}

impl View3d {
    /// A view at `rates` of a drone whose cameras sit at `mount`.
    pub fn new(rates: ViewRates, mount: CameraMount) -> Self {
        Self {
            mount,
            poses: Thinner::new(rates.pose_hz),
            depths: Thinner::new(rates.view_hz),
            annotations: Thinner::new(rates.view_hz),
            path: Thinner::new(rates.path_hz),
            piece: (Vec::new(), Vec::new()),
            piece_index: 0,
            piece_start_us: 0,
            dead_reckoned: None,
        }
    }

    /// Places the cameras at `mount`.
    pub fn set_mount(&mut self, mount: CameraMount) {
        self.mount = mount;
    }

    /// Writes the room (where it is known) and the camera's frustum, once, at `t_us`.
    pub fn start<W: Write + Seek>(
        &mut self,
        log: &mut FlightLog<W>,
        t_us: u64,
        scene: Option<&Scene>,
    ) -> anyhow::Result<()> {
        let t = ns(t_us);
        if let Some(scene) = scene {
            log.write_foxglove(scene3d::SCENE_TOPIC, t, &scene3d::room(scene, t))?;
        }
        log.write_foxglove(scene3d::FRUSTUM_TOPIC, t, &scene3d::frustum(t))
    }

    /// The estimated pose: the autopilot's attitude and height, its horizontal position
    /// integrated from the velocity estimate (heading frame, turned by the estimated yaw),
    /// starting at the true position where there is one.
    fn estimate(&mut self, t_us: u64, s: &ViewSample) -> BodyPose {
        let [roll, pitch, yaw] = s.attitude_rad;
        let start = s
            .truth
            .map_or([0.0, 0.0], |t| [t.position.x, -t.position.y]);
        let (p, last) = self.dead_reckoned.get_or_insert((start, t_us));
        let dt = t_us.saturating_sub(*last) as f64 * 1e-6;
        *last = t_us;
        let [f, side] = s.velocity_mps.map(f64::from);
        if f.is_finite() && side.is_finite() {
            let (sy, cy) = f64::from(yaw).sin_cos();
            p[0] += (f * cy - side * sy) * dt;
            p[1] += (f * sy + side * cy) * dt;
        }
        BodyPose {
            position: scene3d::world_point(p[0] as f32, p[1] as f32, s.height_m),
            orientation: scene3d::body_orientation(roll, pitch, yaw),
        }
    }

    /// The view's messages of one step at `t_us`.
    pub fn step<W: Write + Seek>(
        &mut self,
        log: &mut FlightLog<W>,
        t_us: u64,
        s: &ViewSample,
    ) -> anyhow::Result<()> {
        let t = ns(t_us);
        let estimate = self.estimate(t_us, s);
        if self.poses.take(t_us) {
            let tf = scene3d::transforms(t, s.truth.as_ref(), &estimate, &self.mount);
            log.write_foxglove(scene3d::TF_TOPIC, t, &tf)?;
        }
        if self.annotations.take(t_us) {
            let body = if s.truth.is_some() {
                scene3d::DRONE_FRAME
            } else {
                scene3d::ESTIMATE_FRAME
            };
            let note = scene3d::annotations(t, body, s.obstacle_m, s.state);
            log.write_foxglove(scene3d::ANNOTATION_TOPIC, t, &note)?;
        }
        if self.path.take(t_us) {
            if let Some(truth) = &s.truth {
                self.piece.0.push(truth.position);
            }
            self.piece.1.push(estimate.position);
            if t_us.saturating_sub(self.piece_start_us) >= PATH_PIECE_US {
                let (truth, estimate) = &mut self.piece;
                let update = scene3d::path_piece(t, self.piece_index, truth, estimate);
                log.write_foxglove(scene3d::PATH_TOPIC, t, &update)?;
                self.piece_index += 1;
                // The next piece starts where this one ended.
                truth.drain(..truth.len().saturating_sub(1));
                estimate.drain(..estimate.len().saturating_sub(1));
                self.piece_start_us = t_us;
            }
        }
        Ok(())
    }

    /// The per-column stereo depths of a frame Edge-FS processed at `t_us`, m (0: none).
    pub fn depths<W: Write + Seek>(
        &mut self,
        log: &mut FlightLog<W>,
        t_us: u64,
        depth_m: &[f32; IMG_W],
    ) -> anyhow::Result<()> {
        if !self.depths.take(t_us) {
            return Ok(());
        }
        let cloud = scene3d::stereo_depths(ns(t_us), depth_m);
        log.write_foxglove(scene3d::DEPTH_TOPIC, ns(t_us), &cloud)
    }
}
