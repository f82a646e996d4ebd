//! `sim-host replay`: the renderer's fidelity against the recorded takes.
//!
//! Per take:
//! 1. the recorded frames' texture statistics ([`FrameStats`], means over images `1..=N-1`)
//!    and the median stereo depth Edge-FS measures on them ([`real_depth_m`]);
//! 2. a scene built from those statistics alone ([`fit_scene`]; the take's velocity error is
//!    never looked at);
//! 3. the take's OptiTrack trajectory (position and attitude, smoothed as the ground truth is,
//!    interpolated to the image times) rendered in that scene by the simulator's stereo camera
//!    (its default model: exposure, gain, noise, motion blur; only the board's calibrated
//!    stereo shift is taken over, since Edge-FS is configured with it);
//! 4. Edge-FS (default configuration, the board's stereo shift) on the recorded and on the
//!    rendered frames under the evaluation's protocol ([`super::estimate_series`]), both scored
//!    with the evaluation's metrics against the same ground truth.
//!
//! Axes: the data set's X, Z are horizontal and Y is up; the simulator's world is x north,
//! y east, z down. A take is placed with `x = Z`, `y = -X`, `z = -Y`. The camera's forward
//! direction is the one the ground truth projects on (`(sin ψ, cos ψ)` in (X, Z), negated on
//! board 2), its heading the angle of that direction in the simulator's frame (so the rendered
//! yaw changes as the truth's yaw does). Roll and pitch are taken as rotations about the
//! camera's forward and right axes with the data set's sign (Motive's right-handed
//! convention): simulator roll = `s·roll`, pitch = `-s·pitch`, `s = ±1` the board's forward
//! sign.

use super::camera_calib::{disparity_error, flow_on_disparity, lr_shear};
use super::dataset::{discover_takes, load_frame, stereo_shift, Frame, Take};
use super::frame_stats::{FrameStats, TakeStats};
use super::metrics::{metrics, Metrics};
use super::truth::{ground_truth, image_times, Alignment, MocapTrack, RECORDER_LATENCY_S};
use super::{estimate_series, params_for, select_takes, Config};
use crate::sim::camera::{CameraModel, CameraParams, Motion, StereoCamera};
use crate::sim::math::{Quat, V3};
use crate::sim::scene::Scene;
use crate::sim::scene_spec::{ObstacleSpec, SceneSpec, Shape, Surface, TextureKind};
use anyhow::{bail, ensure, Context, Result};
use protocol::STEREO_FRAME_BYTES;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::PathBuf;
use stereo_board::edge_fs::{EdgeFs, IMG_H, IMG_W};

/// Output format of `sim-host replay`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ReplayFormat {
    /// Two rows per take (recorded, rendered) with the errors and statistics, and the scene.
    Table,
    /// One row per take, full precision (header names every column).
    Csv,
}

/// Command-line arguments of `sim-host replay`.
#[derive(Debug, Clone, clap::Args)]
pub struct ReplayArgs {
    /// Data set directory (layout of stereoboard_testing).
    #[arg(long)]
    pub dataset: PathBuf,
    /// Takes to replay, BOARD/TAKE (e.g. `--take 1/3 --take 2/3`, or `1/3,2/3`, or `1/*`);
    /// default all.
    #[arg(long = "take", value_name = "BOARD/TAKE")]
    pub takes: Vec<String>,
    /// Image-to-ground-truth alignment of the scoring (both the recorded and the rendered
    /// frames are scored against the same truth). The rendering always uses the images'
    /// recorded times.
    #[arg(long, value_enum, default_value_t = Alignment::Corrected)]
    pub alignment: Alignment,
    /// Seed of the rendered textures and the camera noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Renderings per take (textures and noise from their own seeds); the rendered error is
    /// their mean MSE.
    #[arg(long, default_value_t = 3)]
    pub renders: usize,
    /// Output format.
    #[arg(long, value_enum, default_value_t = ReplayFormat::Table)]
    pub format: ReplayFormat,
    /// Camera model: `calibrated` (every measured effect) or `ideal` (none of them).
    #[arg(long, value_enum, default_value_t = CameraModel::Calibrated)]
    pub camera: CameraModel,
    /// Only these measured effects on top of the ideal camera (repeatable; overrides
    /// `--camera`): to see what one effect does to the ratios on its own.
    #[arg(long = "only", value_enum, value_name = "EFFECT")]
    pub only: Vec<Effect>,
}

/// A measured effect of the calibrated camera and recorder (docs/replay.md, "Camera
/// effects").
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Effect {
    /// Column fixed-pattern offsets.
    ColumnFpn,
    /// Row fixed-pattern offsets.
    RowFpn,
    /// Pixel fixed-pattern offsets.
    PixelFpn,
    /// Vignetting.
    Vignetting,
    /// Rolling shutter.
    RollingShutter,
    /// The right camera's roll against the left.
    StereoRoll,
    /// The recorder's latency ([`RECORDER_LATENCY_S`]).
    Latency,
}

impl Effect {
    /// Every effect: the calibrated camera.
    pub const ALL: [Effect; 7] = [
        Effect::ColumnFpn,
        Effect::RowFpn,
        Effect::PixelFpn,
        Effect::Vignetting,
        Effect::RollingShutter,
        Effect::StereoRoll,
        Effect::Latency,
    ];
}

/// The scene parameters chosen for a take (see [`fit_scene`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SceneChoice {
    /// Texture of the walls.
    pub wall_texture: TextureKind,
    /// Contrast of the walls relative to the texture's default.
    pub wall_contrast: f32,
    /// Albedo of the walls.
    pub wall_albedo: f32,
    /// Texture of the floor.
    pub floor_texture: TextureKind,
    /// Scene light.
    pub light: f32,
    /// Room size, m (x, y, ceiling).
    pub size_m: [f32; 3],
    /// The take's obstacles in the room ([`take_obstacles`]): footprint and whether it is
    /// textured (then painted as the walls, else plain at the walls' albedo).
    pub obstacles: Vec<(Shape, bool)>,
    /// Statistics distance of the choice ([`FrameStats::texture_distance`]) on the fitting
    /// poses.
    pub distance: f64,
}

/// Result of one replayed take.
#[derive(Debug, Clone)]
pub struct ReplayResult {
    /// Board number.
    pub board: u32,
    /// Take number.
    pub take: u32,
    /// Images in the take.
    pub frames: usize,
    /// Statistics of the recorded frames.
    pub real_stats: FrameStats,
    /// Statistics of the rendered frames.
    pub rendered_stats: FrameStats,
    /// Median Edge-FS stereo depth on the recorded frames, m.
    pub real_depth_m: f64,
    /// Median Edge-FS stereo depth on the rendered frames, m.
    pub rendered_depth_m: f64,
    /// Forward-velocity metrics on the recorded frames.
    pub real_x: Metrics,
    /// Sideways-velocity metrics on the recorded frames.
    pub real_y: Metrics,
    /// Forward-velocity metrics on the rendered frames (means over the renderings).
    pub rendered_x: Metrics,
    /// Sideways-velocity metrics on the rendered frames (means over the renderings).
    pub rendered_y: Metrics,
    /// Renderings of the take (each with its own texture and noise seed).
    pub renders: usize,
    /// Smallest and largest forward MSE ratio of a single rendering.
    pub ratio_x_range: (f64, f64),
    /// Smallest and largest sideways MSE ratio of a single rendering.
    pub ratio_y_range: (f64, f64),
    /// The scene.
    pub scene: SceneChoice,
    /// The disparity error (offset px, slope px/px) the recorded frames' image motion shows
    /// ([`disparity_error`]).
    pub real_disparity_error: (f64, f64),
    /// The same on the rendered frames (mean over the renderings), whose disparity error is
    /// zero: the estimator's bias on this trajectory and scene.
    pub rendered_disparity_error: (f64, f64),
    /// The left-right shear of the recorded frames ([`lr_shear`]), px.
    pub real_lr_shear_px: f64,
    /// The same on the rendered frames (mean over the renderings), px.
    pub rendered_lr_shear_px: f64,
}

impl ReplayResult {
    /// Rendered / recorded forward MSE.
    pub fn ratio_x(&self) -> f64 {
        self.rendered_x.mse / self.real_x.mse
    }

    /// Rendered / recorded sideways MSE.
    pub fn ratio_y(&self) -> f64 {
        self.rendered_y.mse / self.real_y.mse
    }
}

/// One image's camera pose in the simulator's world.
#[derive(Debug, Clone, Copy)]
pub struct Pose {
    /// Position, m.
    pub pos: V3,
    /// Attitude (body to world).
    pub att: Quat,
    /// Velocity and body rates over the exposure.
    pub motion: Motion,
}

/// The camera poses of images `1..=N-1` from the take's motion capture, interpolated at the
/// images' exposure times: their recorded times minus `latency_s` (see the module docs for
/// the axes).
pub fn trajectory(take: &Take, n_images: usize, latency_s: f64) -> Result<Vec<Pose>> {
    let times: Vec<f64> = image_times(take, n_images)?
        .iter()
        .map(|t| t - latency_s)
        .collect();
    let track = MocapTrack::read(take)?;
    let s = if take.board == 2 { -1.0 } else { 1.0 };
    let at = |t: f64| -> (V3, f64, f64, f64) {
        let pos = V3::new(
            track.at(&track.z, t),
            -track.at(&track.x, t),
            -track.at(&track.y, t),
        );
        let psi = track.at(&track.yaw, t).to_radians();
        // Forward (X, Z) = s (sin ψ, cos ψ) -> simulator (x, y) = (Z, -X).
        let heading = (-s * psi.sin()).atan2(s * psi.cos());
        let roll = s * track.at(&track.roll, t).to_radians();
        let pitch = -s * track.at(&track.pitch, t).to_radians();
        (pos, roll, pitch, heading)
    };
    let h = 0.05;
    Ok(times
        .iter()
        .map(|&t| {
            let (pos, roll, pitch, yaw) = at(t);
            let (p0, r0, q0, y0) = at(t - h);
            let (p1, r1, q1, y1) = at(t + h);
            let att = Quat::from_euler(roll, pitch, yaw);
            let d = |a: f64, b: f64| (b - a) / (2.0 * h);
            let wrap = |a: f64| a - std::f64::consts::TAU * (a / std::f64::consts::TAU).round();
            // Euler-angle rates as body rates (small roll and pitch).
            let rates = V3::new(d(r0, r1), d(q0, q1), wrap(y1 - y0) / (2.0 * h));
            Pose {
                pos,
                att,
                motion: Motion {
                    vel: (p1 - p0) * (1.0 / (2.0 * h)),
                    rates,
                },
            }
        })
        .collect())
}

/// Median over frames of the per-frame median depth of Edge-FS's confident stereo columns
/// (default configuration, the take's stereo shift), m; NaN if no frame has one.
pub fn real_depth_m(frames: &[Frame], stereo_shift_px: i32) -> f64 {
    let mut d = frame_depths_m(frames, stereo_shift_px);
    if d.is_empty() {
        f64::NAN
    } else {
        median(&mut d)
    }
}

/// The `q`-quantile of the frames' median stereo depths (see [`real_depth_m`]), m; NaN if no
/// frame has one.
pub fn depth_quantile_m(frames: &[Frame], stereo_shift_px: i32, q: f64) -> f64 {
    let mut d = frame_depths_m(frames, stereo_shift_px);
    if d.is_empty() {
        return f64::NAN;
    }
    d.sort_by(f64::total_cmp);
    d[((d.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize]
}

/// Per frame with confident stereo columns: the median of their depths, m.
fn frame_depths_m(frames: &[Frame], stereo_shift_px: i32) -> Vec<f64> {
    let mut p = stereo_board::edge_fs::EdgeFsParams::default_config();
    p.stereo_shift_px = stereo_shift_px;
    let mut fs = EdgeFs::new(p);
    let mut per_frame = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        fs.process(f, timebase::Instant::from_micros(143_000 * i as u64), None);
        let d = fs.diagnostics();
        let mut v: Vec<f64> = d
            .depth_m
            .iter()
            .zip(&d.confidence)
            .filter(|(z, c)| **z > 0.0 && **c > 0.0)
            .map(|(z, _)| f64::from(*z))
            .collect();
        if !v.is_empty() {
            per_frame.push(median(&mut v));
        }
    }
    per_frame
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

/// Rows that are black in most recorded frames (the recorder's padding); the rendered frames
/// get the same black rows.
fn black_rows(frames: &[Frame]) -> Vec<usize> {
    (0..IMG_H)
        .filter(|&y| {
            let black = frames
                .iter()
                .filter(|f| (0..IMG_W).all(|x| f[2 * (y * IMG_W + x)] == 0))
                .count();
            2 * black > frames.len()
        })
        .collect()
}

/// The camera the rendered frames come from: the simulator's default model with the board's
/// stereo shift, and the right camera's gain and offset set to the recorded right/left
/// mismatch: gain = the recorded right/left edge-energy ratio (edges scale with the gain),
/// offset = (recorded level ratio - gain) x the auto-exposure target, so the levels' ratio
/// matches too.
///
/// The camera's own effects are those of `effects` (each at its calibrated value, see
/// [`CameraParams::default`]), the others off.
pub fn camera_for(take: &Take, real: &FrameStats, effects: &[Effect]) -> Result<CameraParams> {
    let calibrated = CameraParams::default();
    let mut d = CameraParams::ideal();
    for e in effects {
        match e {
            Effect::ColumnFpn => d.column_fpn_dn = calibrated.column_fpn_dn,
            Effect::RowFpn => d.row_fpn_dn = calibrated.row_fpn_dn,
            Effect::PixelFpn => d.pixel_fpn_dn = calibrated.pixel_fpn_dn,
            Effect::Vignetting => d.vignetting_k = calibrated.vignetting_k,
            Effect::RollingShutter => d.rolling_shutter_s = calibrated.rolling_shutter_s,
            Effect::StereoRoll => d.stereo_roll_rad = calibrated.stereo_roll_rad,
            Effect::Latency => {}
        }
    }
    let gain = real.right_left_edges.clamp(0.5, 2.0) as f32;
    let level = real.right_left_level.clamp(0.5, 2.0) as f32;
    Ok(CameraParams {
        misalign_px: stereo_shift(take)? as f32,
        gain_right: gain,
        offset_right_dn: (level - gain) * d.target_dn,
        ..d
    })
}

/// Renders the poses in `scene`, the camera's auto-exposure running from the first pose on.
pub fn render(
    scene: &Scene,
    camera: &CameraParams,
    poses: &[Pose],
    black: &[usize],
    seed: u64,
) -> Vec<Frame> {
    let mut cam = StereoCamera::new(camera.clone());
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4e9a1);
    poses
        .iter()
        .map(|p| {
            let mut f = Box::new([0u8; STEREO_FRAME_BYTES]);
            cam.render_moving(scene, p.pos, p.att, p.motion, &mut rng, &mut f);
            for &y in black {
                f[2 * y * IMG_W..2 * (y + 1) * IMG_W].fill(0);
            }
            f
        })
        .collect()
}

/// The room around a trajectory and the obstacles' points: their horizontal bounding box grown
/// by `margin` m on every side, 3 m high.
fn room_around(poses: &[Pose], extra: &[[f64; 2]], margin: f64) -> ([f32; 3], V3) {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    let points = poses
        .iter()
        .map(|p| [p.pos.x, p.pos.y])
        .chain(extra.iter().copied());
    for p in points {
        for (k, v) in p.into_iter().enumerate() {
            lo[k] = lo[k].min(v);
            hi[k] = hi[k].max(v);
        }
    }
    let size = [
        (hi[0] - lo[0] + 2.0 * margin) as f32,
        (hi[1] - lo[1] + 2.0 * margin) as f32,
        3.0,
    ];
    (size, V3::new(lo[0] - margin, lo[1] - margin, 0.0))
}

/// The scene a [`SceneChoice`] describes, and the offset that moves the take's positions into
/// it.
fn build_scene(c: &SceneChoice, seed: u64) -> Result<Scene> {
    let wall = Surface {
        contrast: c.wall_contrast,
        albedo: c.wall_albedo,
        ..Surface::of(c.wall_texture)
    };
    let spec = SceneSpec {
        name: "replay".into(),
        size_m: c.size_m,
        start_xy: [c.size_m[0] * 0.5, c.size_m[1] * 0.5],
        start_yaw_rad: Some(0.0),
        light: c.light,
        walls: [wall.clone(), wall.clone(), wall.clone(), wall.clone()],
        floor: Surface::of(c.floor_texture),
        ceiling: Surface::of(TextureKind::Plain),
        obstacles: c
            .obstacles
            .iter()
            .map(|&(shape, textured)| ObstacleSpec {
                shape,
                height: OBSTACLE_HEIGHT_M,
                surface: if textured {
                    Surface {
                        trim: false,
                        ..wall.clone()
                    }
                } else {
                    Surface {
                        albedo: c.wall_albedo,
                        trim: false,
                        ..Surface::of(TextureKind::Plain)
                    }
                },
            })
            .collect(),
    };
    Scene::build(&spec, seed)
}

/// Height of the replayed obstacles, m (the READMEs give footprints only).
pub const OBSTACLE_HEIGHT_M: f32 = 2.0;
/// Radius of the data set's cylinders (50 cm diameter), m.
const CYLINDER_RADIUS_M: f64 = 0.25;
/// Width of the data set's screens, m.
const SCREEN_WIDTH_M: f64 = 1.0;

/// An obstacle the data set's READMEs list for a take.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DatasetObstacle {
    /// A 50 cm cylinder at (X, Z), m.
    Cylinder([f64; 2]),
    /// A 1 m screen at (X, Z), m, facing the camera (perpendicular to the take's mean
    /// forward direction) or, with `along`, parallel to it (the corridor takes).
    Screen {
        /// Centre (X, Z), m.
        at: [f64; 2],
        /// Parallel to the direction of travel.
        along: bool,
        /// Textured (else plain).
        textured: bool,
    },
    /// A textured 1 m screen whose position the README does not give, turned by `angle_deg`
    /// from facing the camera: placed ahead of the take's last position at the 10th percentile
    /// of the recorded frames' median stereo depths (board 2).
    ScreenAhead {
        /// Orientation relative to facing the camera, degrees.
        angle_deg: f64,
    },
}

/// The obstacles of a forward take as the data set's READMEs list them (board 1: positions in
/// mm of X/Z; board 2 takes 1-6: a textured screen at 0, 30 or 60 degrees); none for the
/// takes the READMEs do not describe.
pub fn take_obstacles(board: u32, take: u32) -> Vec<DatasetObstacle> {
    use DatasetObstacle::{Cylinder, Screen, ScreenAhead};
    let screen = |x: f64, z: f64, along: bool, textured: bool| Screen {
        at: [x, z],
        along,
        textured,
    };
    match (board, take) {
        (1, 1 | 2) => vec![Cylinder([0.870, -1.706])],
        (1, 3) => vec![Cylinder([-2.237, 2.776])],
        (1, 4 | 5) => vec![Cylinder([-2.237, 2.776]), Cylinder([-1.637, 3.322])],
        (1, 6..=8) => vec![screen(-1.588, 2.083, false, true)],
        (1, 9..=12) => vec![Cylinder([-3.013, 3.768])],
        (1, 13..=18) => vec![screen(-2.696, 3.619, false, take >= 16)],
        (1, 19..=22) => vec![
            screen(-3.388, 3.342, true, take >= 21),
            screen(-2.049, 3.298, true, take >= 21),
        ],
        (2, 1..=6) => vec![ScreenAhead {
            angle_deg: [0.0, 30.0, 60.0][((take - 1) / 2) as usize],
        }],
        _ => Vec::new(),
    }
}

/// The take's obstacles as footprints in the simulator's world (before the room offset):
/// data set (X, Z) -> (Z, -X); `ahead_m` places [`DatasetObstacle::ScreenAhead`].
fn place_obstacles(
    obstacles: &[DatasetObstacle],
    poses: &[Pose],
    ahead_m: f64,
) -> Vec<(Shape, bool)> {
    let n = poses.len().max(1) as f64;
    let (mut fx, mut fy) = (0.0, 0.0);
    for p in poses {
        let f = p.att.rotate(V3::new(1.0, 0.0, 0.0));
        fx += f.x / n;
        fy += f.y / n;
    }
    let norm = fx.hypot(fy).max(1e-9);
    let (fx, fy) = (fx / norm, fy / norm);
    let sim = |xz: [f64; 2]| [xz[1], -xz[0]];
    let panel = |c: [f64; 2], d: [f64; 2]| {
        let h = 0.5 * SCREEN_WIDTH_M;
        Shape::Panel {
            a: [(c[0] - h * d[0]) as f32, (c[1] - h * d[1]) as f32],
            b: [(c[0] + h * d[0]) as f32, (c[1] + h * d[1]) as f32],
        }
    };
    obstacles
        .iter()
        .map(|o| match *o {
            DatasetObstacle::Cylinder(xz) => {
                let c = sim(xz);
                (
                    Shape::Cylinder {
                        centre: [c[0] as f32, c[1] as f32],
                        radius: CYLINDER_RADIUS_M as f32,
                    },
                    true,
                )
            }
            DatasetObstacle::Screen {
                at,
                along,
                textured,
            } => {
                let d = if along { [fx, fy] } else { [-fy, fx] };
                (panel(sim(at), d), textured)
            }
            DatasetObstacle::ScreenAhead { angle_deg } => {
                let last = poses.last().map_or(V3::new(0.0, 0.0, 0.0), |p| p.pos);
                let c = [last.x + ahead_m * fx, last.y + ahead_m * fy];
                let (s, k) = angle_deg.to_radians().sin_cos();
                // The facing direction (-fy, fx) turned by the angle.
                let d = [-fy * k - fx * s, fx * k - fy * s];
                (panel(c, d), true)
            }
        })
        .collect()
}

/// Every corner or extreme point of the footprints (to size the room around them).
fn footprint_points(obstacles: &[(Shape, bool)]) -> Vec<[f64; 2]> {
    let mut v = Vec::new();
    for (s, _) in obstacles {
        match *s {
            Shape::Cylinder { centre, radius } => {
                for (dx, dy) in [(-1.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.0, 1.0)] {
                    v.push([
                        f64::from(centre[0] + dx * radius),
                        f64::from(centre[1] + dy * radius),
                    ]);
                }
            }
            Shape::Panel { a, b } => {
                v.push([f64::from(a[0]), f64::from(a[1])]);
                v.push([f64::from(b[0]), f64::from(b[1])]);
            }
            Shape::Box { min, max } => {
                v.push([f64::from(min[0]), f64::from(min[1])]);
                v.push([f64::from(max[0]), f64::from(max[1])]);
            }
        }
    }
    v
}

/// Moves a footprint by `-origin`.
fn shifted(shape: Shape, origin: V3) -> Shape {
    let m = |p: [f32; 2]| [p[0] - origin.x as f32, p[1] - origin.y as f32];
    match shape {
        Shape::Cylinder { centre, radius } => Shape::Cylinder {
            centre: m(centre),
            radius,
        },
        Shape::Panel { a, b } => Shape::Panel { a: m(a), b: m(b) },
        Shape::Box { min, max } => Shape::Box {
            min: m(min),
            max: m(max),
        },
    }
}

/// Wall textures and contrasts the fit tries.
const WALL_KINDS: [TextureKind; 5] = [
    TextureKind::Plain,
    TextureKind::Stripes,
    TextureKind::Posters,
    TextureKind::Bricks,
    TextureKind::Wood,
];
const CONTRASTS: [f32; 6] = [0.15, 0.3, 0.5, 0.8, 1.2, 1.8];
const FLOOR_KINDS: [TextureKind; 3] = [TextureKind::Tiles, TextureKind::Carpet, TextureKind::Plain];
/// Poses rendered per candidate scene.
const FIT_POSES: usize = 8;

/// Light that gives the rendered frames the recorded noise: the camera's noise at its
/// auto-exposure target with gain `g` is `sqrt(target·g/e + (r·g/e)²)` DN (`e` electrons per
/// DN, `r` read noise); the gain that gives `noise_dn` (at least 1) is reached when the
/// longest exposure no longer suffices, i.e. at `light = target / (response · max_exposure ·
/// g · albedo)`. Noise at or below the camera's floor (gain 1) keeps the default light.
pub fn light_for_noise(camera: &CameraParams, noise_dn: f64, albedo: f64) -> f32 {
    let e = f64::from(camera.electrons_per_dn);
    let r = f64::from(camera.read_noise_e);
    let target = f64::from(camera.target_dn);
    // (r/e)² g² + (target/e) g - noise² = 0.
    let a = (r / e).powi(2);
    let b = target / e;
    let c = -noise_dn * noise_dn;
    let g =
        ((-b + (b * b - 4.0 * a * c).sqrt()) / (2.0 * a)).clamp(1.0, f64::from(camera.max_gain));
    if g <= 1.0 {
        return 1.0;
    }
    let response = f64::from(camera.dn_per_albedo_s);
    let light = target / (response * f64::from(camera.max_exposure_s) * g * albedo.max(0.05));
    light.clamp(0.01, 1.0) as f32
}

/// Room margins the depth fit tries, m.
const MARGINS_M: [f64; 7] = [0.8, 1.5, 2.5, 3.5, 5.0, 6.5, 8.0];

/// Chooses the scene of a take from the recorded frames alone (their statistics and the
/// stereo depth Edge-FS measures on them):
/// * obstacles: those of the take's README ([`take_obstacles`]), given as `obstacles`;
/// * wall albedo: the recorded mean level / 255; light: [`light_for_noise`] of the recorded
///   noise level;
/// * wall texture and contrast: the candidates (`WALL_KINDS` x `CONTRASTS`) are rendered
///   at `FIT_POSES` poses spread over the take, and the one whose statistics are nearest
///   the recorded ones ([`FrameStats::texture_distance`]) is kept;
/// * room: the bounding box of the trajectory and the obstacles grown on every side by the
///   margin (`MARGINS_M`) whose rendered median stereo depth at those poses is nearest (in
///   ratio) the recorded frames' at the same images, 3 m high;
/// * floor: as the walls, from `FLOOR_KINDS`.
#[allow(clippy::too_many_arguments)]
pub fn fit_scene(
    real_frames: &[Frame],
    real: &FrameStats,
    obstacles: &[(Shape, bool)],
    poses: &[Pose],
    camera: &CameraParams,
    black: &[usize],
    seed: u64,
) -> Result<(SceneChoice, V3)> {
    let step = (poses.len() / FIT_POSES).max(1);
    let idx: Vec<usize> = (0..poses.len()).step_by(step).collect();
    let shift = camera.misalign_px.round() as i32;
    let real_sample: Vec<Frame> = idx.iter().map(|&i| real_frames[i].clone()).collect();
    let real_depth = real_depth_m(&real_sample, shift);
    let points = footprint_points(obstacles);
    // The room for a margin: size, origin, obstacles and sample poses moved into it.
    let layout = |margin: f64| {
        let (size_m, origin) = room_around(poses, &points, margin);
        let obs: Vec<(Shape, bool)> = obstacles
            .iter()
            .map(|&(sh, t)| (shifted(sh, origin), t))
            .collect();
        let sample: Vec<Pose> = idx
            .iter()
            .map(|&i| Pose {
                pos: poses[i].pos - origin,
                ..poses[i]
            })
            .collect();
        (size_m, origin, obs, sample)
    };
    let albedo = (real.mean_dn / 255.0).clamp(0.05, 0.95) as f32;
    let light = light_for_noise(camera, real.noise_dn, f64::from(albedo));
    let render_sample = |c: &SceneChoice, sample: &[Pose]| -> Result<Vec<Frame>> {
        Ok(render(&build_scene(c, seed)?, camera, sample, black, seed))
    };
    let texture_score = |frames: &[Frame]| {
        let mut st = TakeStats::default();
        for f in frames {
            st.add(f);
        }
        st.mean()
            .map_or(f64::INFINITY, |m| m.texture_distance(real))
    };
    let (size_m, mut origin, obs, mut sample) = layout(3.5);
    let mut best: Option<SceneChoice> = None;
    for kind in WALL_KINDS {
        let contrasts: &[f32] = if kind == TextureKind::Plain {
            &[1.0]
        } else {
            &CONTRASTS
        };
        for &contrast in contrasts {
            let mut c = SceneChoice {
                wall_texture: kind,
                wall_contrast: contrast,
                wall_albedo: albedo,
                floor_texture: TextureKind::Tiles,
                light,
                size_m,
                obstacles: obs.clone(),
                distance: 0.0,
            };
            c.distance = texture_score(&render_sample(&c, &sample)?);
            if best.as_ref().is_none_or(|b| c.distance < b.distance) {
                best = Some(c);
            }
        }
    }
    let mut best = best.context("no candidate scene")?;
    if real_depth.is_finite() {
        let mut best_err = f64::INFINITY;
        for m in MARGINS_M {
            let (size_m, o, obs, smp) = layout(m);
            let c = SceneChoice {
                size_m,
                obstacles: obs,
                ..best.clone()
            };
            let d = real_depth_m(&render_sample(&c, &smp)?, shift);
            let err = if d.is_finite() {
                (d / real_depth).ln().abs()
            } else {
                f64::INFINITY
            };
            if err < best_err {
                (best_err, origin, sample) = (err, o, smp);
                best = SceneChoice {
                    distance: texture_score(&render_sample(&c, &sample)?),
                    ..c
                };
            }
        }
    }
    for floor in FLOOR_KINDS.into_iter().skip(1) {
        let mut c = SceneChoice {
            floor_texture: floor,
            ..best.clone()
        };
        c.distance = texture_score(&render_sample(&c, &sample)?);
        if c.distance < best.distance {
            best = c;
        }
    }
    Ok((best, origin))
}

/// Replays one take (see the module docs), rendering it `renders` times (seeds `seed`,
/// `seed + 1000`, ...; the scene is fitted with `seed`) with the camera effects `effects`
/// ([`Effect::ALL`]: the calibrated camera); the rendered error is the mean MSE.
pub fn replay_take(
    take: &Take,
    alignment: Alignment,
    seed: u64,
    renders: usize,
    effects: &[Effect],
) -> Result<ReplayResult> {
    let n = take.image_count();
    ensure!(
        n >= 22,
        "{}: only {n} images; the evaluation window 10..N-11 needs at least 22",
        take.dir.display()
    );
    let real: Vec<Frame> = (1..n)
        .map(|i| load_frame(&take.image_path(i)))
        .collect::<Result<_>>()?;
    let mut real_st = TakeStats::default();
    for f in &real {
        real_st.add(f);
    }
    let real_stats = real_st.mean().context("no frames")?;
    let shift = stereo_shift(take)?;
    let depth = real_depth_m(&real, shift);
    let latency = if effects.contains(&Effect::Latency) {
        RECORDER_LATENCY_S
    } else {
        0.0
    };
    let poses = trajectory(take, n, latency)?;
    let camera = camera_for(take, &real_stats, effects)?;
    let black = black_rows(&real);
    let ahead = depth_quantile_m(&real, shift, 0.1);
    let ahead = if ahead.is_finite() {
        ahead.clamp(0.5, 8.0)
    } else {
        2.0
    };
    let obstacles = place_obstacles(&take_obstacles(take.board, take.take), &poses, ahead);
    let (scene_choice, origin) = fit_scene(
        &real,
        &real_stats,
        &obstacles,
        &poses,
        &camera,
        &black,
        seed,
    )?;
    let placed: Vec<Pose> = poses
        .iter()
        .map(|p| Pose {
            pos: p.pos - origin,
            ..*p
        })
        .collect();
    let truth = ground_truth(take, n, alignment)?;
    let params = params_for(Config::Default, take)?;
    let score = |frames: &[Frame]| -> Result<(Metrics, Metrics)> {
        let s = estimate_series(
            &truth,
            params,
            false,
            &mut |i| Ok(frames[i - 1].clone()),
            &|| {},
        )?;
        let (a, b) = s.window;
        Ok((
            metrics(&s.est_x[a..=b], &s.gt_x[a..=b]),
            metrics(&s.est_y[a..=b], &s.gt_y[a..=b]),
        ))
    };
    let (real_x, real_y) = score(&real)?;
    let times = image_times(take, n)?;
    let real_disparity_error = disparity_error(&flow_on_disparity(&real, shift, &times));
    let mut rendered_disparity_error = (0.0, 0.0);
    let real_lr_shear_px = lr_shear(&real);
    let mut rendered_lr_shear_px = 0.0;
    // Several renderings (textures and noise drawn from their own seeds) of the same scene.
    let mut ren_st = TakeStats::default();
    let (mut depths, mut xs, mut ys) = (Vec::new(), Vec::new(), Vec::new());
    for r in 0..renders.max(1) {
        let s = seed.wrapping_add(1000 * r as u64);
        let rendered = render(&build_scene(&scene_choice, s)?, &camera, &placed, &black, s);
        for f in &rendered {
            ren_st.add(f);
        }
        depths.push(real_depth_m(&rendered, shift));
        let (offset, slope) = disparity_error(&flow_on_disparity(&rendered, shift, &times));
        rendered_disparity_error.0 += offset / renders.max(1) as f64;
        rendered_disparity_error.1 += slope / renders.max(1) as f64;
        rendered_lr_shear_px += lr_shear(&rendered) / renders.max(1) as f64;
        let (x, y) = score(&rendered)?;
        xs.push(x);
        ys.push(y);
    }
    let rendered_stats = ren_st.mean().context("no frames")?;
    let rendered_depth = depths.iter().sum::<f64>() / depths.len() as f64;
    let mean_metrics = |v: &[Metrics]| {
        let k = 1.0 / v.len() as f64;
        Metrics {
            nmxm: v.iter().map(|m| m.nmxm).sum::<f64>() * k,
            mse: v.iter().map(|m| m.mse).sum::<f64>() * k,
            var: v.iter().map(|m| m.var).sum::<f64>() * k,
        }
    };
    let range = |v: &[Metrics], real: f64| {
        v.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), m| {
                (lo.min(m.mse / real), hi.max(m.mse / real))
            })
    };
    let (ratio_x_range, ratio_y_range) = (range(&xs, real_x.mse), range(&ys, real_y.mse));
    let (rendered_x, rendered_y) = (mean_metrics(&xs), mean_metrics(&ys));
    Ok(ReplayResult {
        board: take.board,
        take: take.take,
        frames: n,
        real_stats,
        rendered_stats,
        real_depth_m: depth,
        rendered_depth_m: rendered_depth,
        real_x,
        real_y,
        rendered_x,
        rendered_y,
        renders: renders.max(1),
        ratio_x_range,
        ratio_y_range,
        scene: scene_choice,
        real_disparity_error,
        rendered_disparity_error,
        real_lr_shear_px,
        rendered_lr_shear_px,
    })
}

/// Runs `sim-host replay`.
pub fn run(args: &ReplayArgs) -> Result<()> {
    let list = args.takes.join(",");
    // The selection's errors name eval's `--takes`; this command's flag is `--take`.
    let takes = select_takes(
        discover_takes(&args.dataset)?,
        (!list.is_empty()).then_some(list.as_str()),
    )
    .map_err(|e| anyhow::anyhow!("{}", format!("{e:#}").replace("--takes", "--take")))?;
    let effects: &[Effect] = match (args.only.is_empty(), args.camera) {
        (false, _) => &args.only,
        (true, CameraModel::Calibrated) => &Effect::ALL,
        (true, CameraModel::Ideal) => &[],
    };
    let results: Vec<(Take, Result<ReplayResult>)> = takes
        .par_iter()
        .map(|t| {
            (
                t.clone(),
                replay_take(t, args.alignment, args.seed, args.renders, effects),
            )
        })
        .collect();
    let mut ok = Vec::new();
    let mut failed = 0;
    for (take, r) in results {
        match r {
            Ok(r) => ok.push(r),
            Err(e) => {
                failed += 1;
                eprintln!("error: board {} take {}: {e:#}", take.board, take.take);
            }
        }
    }
    match args.format {
        ReplayFormat::Table => print!("{}", table(&ok, args.alignment)),
        ReplayFormat::Csv => print!("{}", csv(&ok)),
    }
    if failed > 0 {
        bail!("{failed} take(s) could not be replayed (see above)");
    }
    Ok(())
}

/// The table output: per take a recorded and a rendered row (MSE of both axes, then the
/// statistics), the ratios, and the scene; a summary of the ratios at the end.
pub fn table(results: &[ReplayResult], alignment: Alignment) -> String {
    let mut s = format!(
        "Edge-FS default config, alignment {alignment:?}; ratio = rendered MSE / recorded MSE (goal 0.5..2)\n"
    );
    s += "board take source   |   mse_x   mse_y | edge_dens p10..p90    textured |g|>=4 |g|>=16 | noise  mean  contr | depth\n";
    let stats_cols = |st: &FrameStats, depth: f64| {
        format!(
            "{:>9.4} {:.3}..{:.3} {:>8.3} {:>6.3} {:>6.3} | {:>5.2} {:>5.1} {:>6.1} | {:>5.2}",
            st.mean_edge_density(),
            st.edge_density_quantile(0.1),
            st.edge_density_quantile(0.9),
            st.textured_columns,
            st.gradient_fraction_above(4),
            st.gradient_fraction_above(16),
            st.noise_dn,
            st.mean_dn,
            st.contrast_dn,
            depth
        )
    };
    let mut in_band = 0;
    for r in results {
        s += &format!(
            "{:>5} {:>4} recorded | {:>7.4} {:>7.4} | {}\n",
            r.board,
            r.take,
            r.real_x.mse,
            r.real_y.mse,
            stats_cols(&r.real_stats, r.real_depth_m)
        );
        s += &format!(
            "{:>5} {:>4} rendered | {:>7.4} {:>7.4} | {}\n",
            r.board,
            r.take,
            r.rendered_x.mse,
            r.rendered_y.mse,
            stats_cols(&r.rendered_stats, r.rendered_depth_m)
        );
        let c = &r.scene;
        s += &format!(
            "           ratio    | {:>7.2} {:>7.2} | per rendering x {:.2}..{:.2}, y {:.2}..{:.2} ({})\n                     scene: walls {} contrast {} albedo {:.2}, floor {}, light {:.2}, room {:.1} x {:.1} m, {} obstacle(s) (distance {:.3})\n                     disparity error from the image motion: recorded {:+.2} px {:+.4} px/px, rendered {:+.2} px {:+.4} px/px\n                     left-right shear (bottom minus top half): recorded {:+.2} px, rendered {:+.2} px\n",
            r.ratio_x(),
            r.ratio_y(),
            r.ratio_x_range.0,
            r.ratio_x_range.1,
            r.ratio_y_range.0,
            r.ratio_y_range.1,
            r.renders,
            c.wall_texture.name(),
            c.wall_contrast,
            c.wall_albedo,
            c.floor_texture.name(),
            c.light,
            c.size_m[0],
            c.size_m[1],
            c.obstacles.len(),
            c.distance,
            r.real_disparity_error.0,
            r.real_disparity_error.1,
            r.rendered_disparity_error.0,
            r.rendered_disparity_error.1,
            r.real_lr_shear_px,
            r.rendered_lr_shear_px,
        );
        let band = |v: f64| (0.5..=2.0).contains(&v);
        if band(r.ratio_x()) && band(r.ratio_y()) {
            in_band += 1;
        }
    }
    s += &format!(
        "takes with both ratios within 0.5..2: {in_band}/{}\n",
        results.len()
    );
    s
}

/// The CSV output: one row per take, full precision.
pub fn csv(results: &[ReplayResult]) -> String {
    let stat_names = [
        "edge_density",
        "edge_density_p10",
        "edge_density_p90",
        "textured_columns",
        "grad_ge4",
        "grad_ge16",
        "noise_dn",
        "mean_dn",
        "contrast_dn",
        "right_left_level",
        "right_left_edges",
        "depth_m",
    ];
    let mut s = String::from(
        "board,take,frames,real_mse_x,real_mse_y,rendered_mse_x,rendered_mse_y,ratio_x,ratio_y,renders,ratio_x_min,ratio_x_max,ratio_y_min,ratio_y_max",
    );
    for src in ["real", "rendered"] {
        for n in stat_names {
            s += &format!(",{src}_{n}");
        }
        for b in super::frame_stats::GRADIENT_BINS_DN {
            s += &format!(",{src}_hist_{b}");
        }
    }
    s += ",wall_texture,wall_contrast,wall_albedo,floor_texture,light,room_x_m,room_y_m,obstacles,fit_distance,real_disparity_offset_px,real_disparity_slope,rendered_disparity_offset_px,rendered_disparity_slope,real_lr_shear_px,rendered_lr_shear_px\n";
    let stats = |st: &FrameStats, depth: f64| {
        let mut v = vec![
            st.mean_edge_density(),
            st.edge_density_quantile(0.1),
            st.edge_density_quantile(0.9),
            st.textured_columns,
            st.gradient_fraction_above(4),
            st.gradient_fraction_above(16),
            st.noise_dn,
            st.mean_dn,
            st.contrast_dn,
            st.right_left_level,
            st.right_left_edges,
            depth,
        ];
        v.extend(st.gradient_hist);
        v.iter().map(|x| format!(",{x}")).collect::<String>()
    };
    for r in results {
        let c = &r.scene;
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{}{}{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.board,
            r.take,
            r.frames,
            r.real_x.mse,
            r.real_y.mse,
            r.rendered_x.mse,
            r.rendered_y.mse,
            r.ratio_x(),
            r.ratio_y(),
            r.renders,
            r.ratio_x_range.0,
            r.ratio_x_range.1,
            r.ratio_y_range.0,
            r.ratio_y_range.1,
            stats(&r.real_stats, r.real_depth_m),
            stats(&r.rendered_stats, r.rendered_depth_m),
            c.wall_texture.name(),
            c.wall_contrast,
            c.wall_albedo,
            c.floor_texture.name(),
            c.light,
            c.size_m[0],
            c.size_m[1],
            c.obstacles.len(),
            c.distance,
            r.real_disparity_error.0,
            r.real_disparity_error.1,
            r.rendered_disparity_error.0,
            r.rendered_disparity_error.1,
            r.real_lr_shear_px,
            r.rendered_lr_shear_px,
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn light_follows_the_noise_the_camera_must_show() {
        let cam = CameraParams::default();
        // At or below the camera's noise at unity gain (about 2.3 DN): the default light.
        assert_eq!(light_for_noise(&cam, 1.5, 0.5), 1.0);
        assert_eq!(light_for_noise(&cam, 2.2, 0.5), 1.0);
        // More noise needs more gain, i.e. less light; the gain that light forces gives the
        // noise back.
        let light = light_for_noise(&cam, 6.0, 0.5);
        assert!(light < 1.0);
        let product = cam.target_dn / (cam.dn_per_albedo_s * light * 0.5);
        let gain = f64::from(product / cam.max_exposure_s);
        let e = f64::from(cam.electrons_per_dn) / gain;
        let noise =
            (f64::from(cam.target_dn) / e + (f64::from(cam.read_noise_e) / e).powi(2)).sqrt();
        assert!((noise - 6.0).abs() < 0.05, "{noise}");
        assert!(light_for_noise(&cam, 7.0, 0.5) < light);
    }

    fn pose(x: f64, y: f64, yaw: f64) -> Pose {
        Pose {
            pos: V3::new(x, y, -0.9),
            att: Quat::from_euler(0.0, 0.0, yaw),
            motion: Motion::default(),
        }
    }

    #[test]
    fn readme_obstacles_are_placed_in_the_simulator_frame() {
        // Board 1 take 3: a cylinder at X = -2.237, Z = 2.776 -> x = Z, y = -X.
        let obs = take_obstacles(1, 3);
        let poses = [pose(0.0, 2.2, 0.0), pose(1.0, 2.2, 0.0)];
        let placed = place_obstacles(&obs, &poses, 2.0);
        let Shape::Cylinder { centre, radius } = placed[0].0 else {
            panic!("{placed:?}")
        };
        assert!((centre[0] - 2.776).abs() < 1e-5 && (centre[1] - 2.237).abs() < 1e-5);
        assert_eq!(radius, 0.25);
        // A facing screen is across the direction of travel (here x), 1 m wide.
        let placed = place_obstacles(&take_obstacles(1, 16), &poses, 2.0);
        let (Shape::Panel { a, b }, true) = placed[0] else {
            panic!("{placed:?}")
        };
        assert!((a[0] - b[0]).abs() < 1e-5 && ((a[1] - b[1]).abs() - 1.0).abs() < 1e-5);
        // Untextured screens of takes 13-15; corridor screens along the travel direction.
        assert!(!place_obstacles(&take_obstacles(1, 13), &poses, 2.0)[0].1);
        let corridor = place_obstacles(&take_obstacles(1, 19), &poses, 2.0);
        assert_eq!(corridor.len(), 2);
        let Shape::Panel { a, b } = corridor[0].0 else {
            panic!()
        };
        assert!((a[1] - b[1]).abs() < 1e-5 && ((a[0] - b[0]).abs() - 1.0).abs() < 1e-5);
        // Board 2: a screen ahead of the last pose, turned by 30 degrees.
        let ahead = place_obstacles(&take_obstacles(2, 3), &poses, 2.0);
        let Shape::Panel { a, b } = ahead[0].0 else {
            panic!()
        };
        let c = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
        assert!(
            (c[0] - 3.0).abs() < 1e-5 && (c[1] - 2.2).abs() < 1e-5,
            "{c:?}"
        );
        let turn = (b[0] - a[0]).atan2(b[1] - a[1]).abs().to_degrees();
        assert!(
            (turn - 30.0).abs() < 1e-3 || (turn - 150.0).abs() < 1e-3,
            "{turn}"
        );
        assert!(take_obstacles(2, 7).is_empty());
    }
}
