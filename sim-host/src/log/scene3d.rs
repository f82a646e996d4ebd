//! The flight in 3D, as Foxglove's well-known types: the room and its obstacles
//! (`foxglove.SceneUpdate`), the drone's true and estimated poses and its cameras
//! (`foxglove.FrameTransforms`), its paths, the camera's frustum, the per-column stereo depths
//! (`foxglove.PointCloud`) and annotations (nearest obstacle, FSM state). Foxglove's and
//! Lichtblick's 3D panel shows them with no setup; `docs/foxglove-layout.json` arranges that
//! panel beside the cameras and the key plots.
//!
//! Frames (Foxglove's 3D panel is z-up and right-handed):
//!
//! * [`WORLD_FRAME`]: the room, x north, y west, z up, the floor at z = 0 (the simulator's
//!   x north, y east, z down, with y and z negated);
//! * [`DRONE_FRAME`]: the true body (x forward, y left, z up), and [`ESTIMATE_FRAME`]: what the
//!   autopilot believes (its attitude and height; its horizontal position dead-reckoned from
//!   its velocity estimate from the start, so the gap to [`DRONE_FRAME`] is the velocity
//!   estimate's integrated error);
//! * [`LEFT_CAMERA_FRAME`], [`RIGHT_CAMERA_FRAME`]: the cameras' optical frames on the true
//!   body (on the estimate for a real board, whose truth nobody knows): z along the optical
//!   axis, x right, y down, the images' frame.

use crate::sim::scene::{Obstacle, Scene, Surface};
use foxglove::schemas::{
    line_primitive, packed_element_field, Color, CubePrimitive, CylinderPrimitive, FrameTransform,
    FrameTransforms, LinePrimitive, PackedElementField, Point3, PointCloud, Pose, Quaternion,
    SceneEntity, SceneUpdate, SpherePrimitive, TextPrimitive, Timestamp, Vector3,
};
use stereo_board::edge_fs::{CAMERA_FOCAL_PX, IMG_H, IMG_W};

/// The room's frame.
pub const WORLD_FRAME: &str = "world";
/// The drone's true body frame.
pub const DRONE_FRAME: &str = "drone";
/// The autopilot's estimate of its body frame.
pub const ESTIMATE_FRAME: &str = "drone_estimate";
/// The left camera's optical frame (Edge-FS's reference camera).
pub const LEFT_CAMERA_FRAME: &str = "camera_left";
/// The right camera's optical frame.
pub const RIGHT_CAMERA_FRAME: &str = "camera_right";

/// Topic of the room and its obstacles (written once).
pub const SCENE_TOPIC: &str = "/scene";
/// Topic of the frame transforms.
pub const TF_TOPIC: &str = "/tf";
/// Topic of the true and estimated paths.
pub const PATH_TOPIC: &str = "/path";
/// Topic of the camera's frustum (written once, locked to the camera).
pub const FRUSTUM_TOPIC: &str = "/camera/frustum";
/// Topic of the per-column stereo depths.
pub const DEPTH_TOPIC: &str = "/stereo/depth";
/// Topic of the nearest-obstacle and FSM annotations.
pub const ANNOTATION_TOPIC: &str = "/annotations";

/// Camera placement on the body: forward of the centre of mass and half the baseline to each
/// side, m (the simulator's camera: 6 cm baseline, 2 cm forward).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraMount {
    /// Forward offset, m.
    pub forward_m: f32,
    /// Distance between the two cameras, m.
    pub baseline_m: f32,
}

/// A Foxglove timestamp of `t_ns` nanoseconds.
pub fn timestamp(t_ns: u64) -> Timestamp {
    Timestamp::new(
        u32::try_from(t_ns / 1_000_000_000).unwrap_or(u32::MAX),
        (t_ns % 1_000_000_000) as u32,
    )
}

fn v3(x: f64, y: f64, z: f64) -> Vector3 {
    Vector3 { x, y, z }
}

fn p3(x: f64, y: f64, z: f64) -> Point3 {
    Point3 { x, y, z }
}

fn grey(albedo: f32, alpha: f64) -> Color {
    let g = f64::from(albedo.clamp(0.0, 1.0));
    Color {
        r: g,
        g,
        b: g,
        a: alpha,
    }
}

const IDENTITY: Quaternion = Quaternion {
    x: 0.0,
    y: 0.0,
    z: 0.0,
    w: 1.0,
};

/// A rotation about z by `angle` rad.
fn yaw_quaternion(angle: f64) -> Quaternion {
    let (s, c) = (angle * 0.5).sin_cos();
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: s,
        w: c,
    }
}

/// The orientation of a body (x forward, y left, z up) in [`WORLD_FRAME`] from the simulator's
/// Euler angles (roll, pitch, yaw of a forward-right-down body in a north-east-down room,
/// rad): negating y and z turns pitch and yaw around, roll stays.
pub fn body_orientation(roll: f32, pitch: f32, yaw: f32) -> Quaternion {
    let (r, p, y) = (f64::from(roll), -f64::from(pitch), -f64::from(yaw));
    let (sr, cr) = (r * 0.5).sin_cos();
    let (sp, cp) = (p * 0.5).sin_cos();
    let (sy, cy) = (y * 0.5).sin_cos();
    // q = Rz(y) * Ry(p) * Rx(r)
    Quaternion {
        w: cr * cp * cy + sr * sp * sy,
        x: sr * cp * cy - cr * sp * sy,
        y: cr * sp * cy + sr * cp * sy,
        z: cr * cp * sy - sr * sp * cy,
    }
}

/// A point of the simulator's room (x north, y east, height up), in [`WORLD_FRAME`].
pub fn world_point(x: f32, y: f32, height: f32) -> Point3 {
    p3(f64::from(x), -f64::from(y), f64::from(height))
}

fn pose(position: Vector3, orientation: Quaternion) -> Option<Pose> {
    Some(Pose {
        position: Some(position),
        orientation: Some(orientation),
    })
}

fn entity(t_ns: u64, frame_id: &str, id: &str) -> SceneEntity {
    SceneEntity {
        timestamp: Some(timestamp(t_ns)),
        frame_id: frame_id.to_string(),
        id: id.to_string(),
        ..Default::default()
    }
}

/// Walls are drawn this thick, m.
const WALL_THICKNESS_M: f64 = 0.02;
/// Opacity of the walls and the ceiling-less room: see-through, so the flight inside shows.
const WALL_ALPHA: f64 = 0.25;

/// The room: the floor, the four walls (see-through) and the obstacles, each painted with its
/// texture's mean grey.
pub fn room(scene: &Scene, t_ns: u64) -> SceneUpdate {
    let (sx, sy, h) = (
        f64::from(scene.size_x),
        f64::from(scene.size_y),
        f64::from(scene.height),
    );
    let mut room = entity(t_ns, WORLD_FRAME, "room");
    room.cubes.push(CubePrimitive {
        pose: pose(v3(sx / 2.0, -sy / 2.0, -0.005), IDENTITY),
        size: Some(v3(sx, sy, 0.01)),
        color: Some(grey(scene.mean_albedo(Surface::Floor), 1.0)),
    });
    // Walls: 0 at x = 0, 1 at x = size_x, 2 at y = 0, 3 at y = size_y.
    let walls = [
        (v3(0.0, -sy / 2.0, h / 2.0), v3(WALL_THICKNESS_M, sy, h)),
        (v3(sx, -sy / 2.0, h / 2.0), v3(WALL_THICKNESS_M, sy, h)),
        (v3(sx / 2.0, 0.0, h / 2.0), v3(sx, WALL_THICKNESS_M, h)),
        (v3(sx / 2.0, -sy, h / 2.0), v3(sx, WALL_THICKNESS_M, h)),
    ];
    for (k, (centre, size)) in walls.into_iter().enumerate() {
        room.cubes.push(CubePrimitive {
            pose: pose(centre, IDENTITY),
            size: Some(size),
            color: Some(grey(scene.mean_albedo(Surface::Wall(k as u8)), WALL_ALPHA)),
        });
    }
    let mut obstacles = entity(t_ns, WORLD_FRAME, "obstacles");
    for (n, o) in scene.obstacles.iter().enumerate() {
        let color = Some(grey(
            scene.mean_albedo(Surface::Obstacle(n.min(usize::from(u16::MAX)) as u16)),
            1.0,
        ));
        let height = f64::from(o.height());
        match *o {
            Obstacle::Cylinder { x, y, radius, .. } => {
                let d = 2.0 * f64::from(radius);
                obstacles.cylinders.push(CylinderPrimitive {
                    pose: pose(v3(f64::from(x), -f64::from(y), height / 2.0), IDENTITY),
                    size: Some(v3(d, d, height)),
                    bottom_scale: 1.0,
                    top_scale: 1.0,
                    color,
                });
            }
            Obstacle::Panel { a, b, .. } => {
                let (ax, ay) = (f64::from(a[0]), -f64::from(a[1]));
                let (bx, by) = (f64::from(b[0]), -f64::from(b[1]));
                let length = (bx - ax).hypot(by - ay);
                obstacles.cubes.push(CubePrimitive {
                    pose: pose(
                        v3((ax + bx) / 2.0, (ay + by) / 2.0, height / 2.0),
                        yaw_quaternion((by - ay).atan2(bx - ax)),
                    ),
                    size: Some(v3(length, WALL_THICKNESS_M, height)),
                    color,
                });
            }
            Obstacle::Box { min, max, .. } => {
                let (x0, x1) = (f64::from(min[0]), f64::from(max[0]));
                let (y0, y1) = (f64::from(min[1]), f64::from(max[1]));
                obstacles.cubes.push(CubePrimitive {
                    pose: pose(
                        v3((x0 + x1) / 2.0, -(y0 + y1) / 2.0, height / 2.0),
                        IDENTITY,
                    ),
                    size: Some(v3(x1 - x0, y1 - y0, height)),
                    color,
                });
            }
        }
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![room, obstacles],
    }
}

/// A pose of the drone: position in [`WORLD_FRAME`] and orientation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyPose {
    /// Position, m.
    pub position: Point3,
    /// Orientation of the body (x forward, y left, z up).
    pub orientation: Quaternion,
}

fn transform(t_ns: u64, parent: &str, child: &str, at: Vector3, q: Quaternion) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp(t_ns)),
        parent_frame_id: parent.to_string(),
        child_frame_id: child.to_string(),
        translation: Some(at),
        rotation: Some(q),
    }
}

/// The optical frame (z forward, x right, y down) in the body (x forward, y left, z up).
const OPTICAL_IN_BODY: Quaternion = Quaternion {
    x: -0.5,
    y: 0.5,
    z: -0.5,
    w: 0.5,
};

/// The transforms of one instant: the true body (where known) and the estimate in the room,
/// the two cameras on the true body (on the estimate where the truth is not known).
pub fn transforms(
    t_ns: u64,
    truth: Option<&BodyPose>,
    estimate: &BodyPose,
    mount: &CameraMount,
) -> FrameTransforms {
    let at = |p: &Point3| v3(p.x, p.y, p.z);
    let mut transforms = Vec::with_capacity(4);
    if let Some(truth) = truth {
        transforms.push(transform(
            t_ns,
            WORLD_FRAME,
            DRONE_FRAME,
            at(&truth.position),
            truth.orientation,
        ));
    }
    transforms.push(transform(
        t_ns,
        WORLD_FRAME,
        ESTIMATE_FRAME,
        at(&estimate.position),
        estimate.orientation,
    ));
    let body = if truth.is_some() {
        DRONE_FRAME
    } else {
        ESTIMATE_FRAME
    };
    let half = f64::from(mount.baseline_m) / 2.0;
    let forward = f64::from(mount.forward_m);
    for (child, side) in [(LEFT_CAMERA_FRAME, half), (RIGHT_CAMERA_FRAME, -half)] {
        transforms.push(transform(
            t_ns,
            body,
            child,
            v3(forward, side, 0.0),
            OPTICAL_IN_BODY,
        ));
    }
    FrameTransforms { transforms }
}

/// Colour of the true path.
const TRUE_PATH: Color = Color {
    r: 0.1,
    g: 0.8,
    b: 0.2,
    a: 1.0,
};
/// Colour of the estimated path.
const ESTIMATED_PATH: Color = Color {
    r: 1.0,
    g: 0.55,
    b: 0.0,
    a: 1.0,
};

/// One piece of the paths, `index` numbering the pieces: each piece is an entity of its own
/// that stays, so the whole path builds up without being sent again. A piece should start
/// with the previous piece's last point, so that the path has no gaps.
pub fn path_piece(t_ns: u64, index: u32, truth: &[Point3], estimate: &[Point3]) -> SceneUpdate {
    let mut entities = Vec::new();
    for (name, points, color) in [
        ("path_true", truth, TRUE_PATH),
        ("path_estimate", estimate, ESTIMATED_PATH),
    ] {
        if points.len() < 2 {
            continue;
        }
        let mut e = entity(t_ns, WORLD_FRAME, &format!("{name}/{index}"));
        e.lines.push(LinePrimitive {
            r#type: line_primitive::Type::LineStrip as i32,
            pose: pose(v3(0.0, 0.0, 0.0), IDENTITY),
            thickness: 2.0,
            scale_invariant: true,
            points: points.to_vec(),
            color: Some(color),
            colors: Vec::new(),
            indices: Vec::new(),
        });
        entities.push(e);
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

/// How far the frustum is drawn, m.
const FRUSTUM_DEPTH_M: f64 = 1.0;

/// The left camera's field of view as a pyramid `FRUSTUM_DEPTH_M` deep, locked to the camera.
pub fn frustum(t_ns: u64) -> SceneUpdate {
    let f = f64::from(CAMERA_FOCAL_PX);
    let (hx, hy) = (
        IMG_W as f64 / 2.0 / f * FRUSTUM_DEPTH_M,
        IMG_H as f64 / 2.0 / f * FRUSTUM_DEPTH_M,
    );
    let d = FRUSTUM_DEPTH_M;
    let corners = [
        p3(-hx, -hy, d),
        p3(hx, -hy, d),
        p3(hx, hy, d),
        p3(-hx, hy, d),
    ];
    let mut points = Vec::new();
    for (k, c) in corners.iter().enumerate() {
        points.extend([p3(0.0, 0.0, 0.0), *c, *c, corners[(k + 1) % 4]]);
    }
    let mut e = entity(t_ns, LEFT_CAMERA_FRAME, "frustum");
    e.frame_locked = true;
    e.lines.push(LinePrimitive {
        r#type: line_primitive::Type::LineList as i32,
        pose: pose(v3(0.0, 0.0, 0.0), IDENTITY),
        thickness: 1.5,
        scale_invariant: true,
        points,
        color: Some(Color {
            r: 0.3,
            g: 0.6,
            b: 1.0,
            a: 0.8,
        }),
        colors: Vec::new(),
        indices: Vec::new(),
    });
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![e],
    }
}

/// Bytes of one point of [`stereo_depths`]: x, y, z as `f32`.
const POINT_STRIDE: u32 = 12;

/// The per-column stereo depths of one frame (m, 0 where a column has none) as points in the
/// left camera's optical frame, on the image's middle row.
pub fn stereo_depths(t_ns: u64, depth_m: &[f32; IMG_W]) -> PointCloud {
    let f = CAMERA_FOCAL_PX;
    let cx = (IMG_W as f32 - 1.0) / 2.0;
    let mut data = Vec::with_capacity(IMG_W * POINT_STRIDE as usize);
    for (c, &z) in depth_m.iter().enumerate() {
        if !(z.is_finite() && z > 0.0) {
            continue;
        }
        for v in [(c as f32 - cx) / f * z, 0.0, z] {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    let field = |name: &str, offset: u32| PackedElementField {
        name: name.to_string(),
        offset,
        r#type: packed_element_field::NumericType::Float32 as i32,
    };
    PointCloud {
        timestamp: Some(timestamp(t_ns)),
        frame_id: LEFT_CAMERA_FRAME.to_string(),
        pose: pose(v3(0.0, 0.0, 0.0), IDENTITY),
        point_stride: POINT_STRIDE,
        fields: vec![field("x", 0), field("y", 4), field("z", 8)],
        data: data.into(),
    }
}

/// How long an annotation stays without a newer one, s.
const ANNOTATION_LIFETIME_S: f64 = 0.5;

/// The nearest obstacle the autopilot holds (a sphere that far ahead of the body, with its
/// distance) and the FSM state and flight mode (text above the drone), locked to the body
/// frame `body`.
pub fn annotations(t_ns: u64, body: &str, obstacle_m: Option<f32>, state: &str) -> SceneUpdate {
    let lifetime = foxglove::schemas::Duration::new(0, (ANNOTATION_LIFETIME_S * 1e9) as u32);
    let text = |at: Vector3, text: String, size: f64| TextPrimitive {
        pose: pose(at, IDENTITY),
        billboard: true,
        font_size: size,
        scale_invariant: true,
        color: Some(Color {
            r: 1.0,
            g: 1.0,
            b: 1.0,
            a: 1.0,
        }),
        text,
    };
    let mut label = entity(t_ns, body, "state");
    label.frame_locked = true;
    label.lifetime = Some(lifetime);
    label
        .texts
        .push(text(v3(0.0, 0.0, 0.25), state.to_string(), 14.0));
    let mut entities = vec![label];
    if let Some(d) = obstacle_m.filter(|d| d.is_finite() && *d > 0.0) {
        let mut e = entity(t_ns, body, "obstacle");
        e.frame_locked = true;
        e.lifetime = Some(lifetime);
        let ahead = v3(f64::from(d), 0.0, 0.0);
        e.spheres.push(SpherePrimitive {
            pose: pose(ahead, IDENTITY),
            size: Some(v3(0.08, 0.08, 0.08)),
            color: Some(Color {
                r: 1.0,
                g: 0.15,
                b: 0.1,
                a: 0.9,
            }),
        });
        e.texts.push(text(
            v3(f64::from(d), 0.0, 0.12),
            format!("obstacle {d:.2} m"),
            12.0,
        ));
        entities.push(e);
    }
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `v` turned by `q`, with the simulator's quaternion.
    fn rotate(q: &Quaternion, v: [f64; 3]) -> [f64; 3] {
        let q = crate::sim::math::Quat {
            w: q.w,
            x: q.x,
            y: q.y,
            z: q.z,
        };
        let m = q.to_matrix();
        [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
    }

    fn close(a: [f64; 3], b: [f64; 3]) -> bool {
        a.iter().zip(b).all(|(a, b)| (a - b).abs() < 1e-9)
    }

    #[test]
    fn the_optical_frame_looks_forward_with_x_right_and_y_down() {
        assert!(close(
            rotate(&OPTICAL_IN_BODY, [0.0, 0.0, 1.0]),
            [1.0, 0.0, 0.0]
        ));
        assert!(close(
            rotate(&OPTICAL_IN_BODY, [1.0, 0.0, 0.0]),
            [0.0, -1.0, 0.0]
        ));
        assert!(close(
            rotate(&OPTICAL_IN_BODY, [0.0, 1.0, 0.0]),
            [0.0, 0.0, -1.0]
        ));
    }

    #[test]
    fn a_heading_east_points_the_nose_east_in_the_room() {
        // Yaw +90 deg (north to east, clockwise from above) in the simulator; east is -y in
        // the world frame.
        let q = body_orientation(0.0, 0.0, core::f32::consts::FRAC_PI_2);
        let nose = rotate(&q, [1.0, 0.0, 0.0]);
        assert!(
            close(nose.map(|v| (v * 1e6).round() / 1e6), [0.0, -1.0, 0.0]),
            "{nose:?}"
        );
        // Pitch up (nose up) in the simulator raises the nose in the world frame.
        let q = body_orientation(0.0, 0.3, 0.0);
        assert!(rotate(&q, [1.0, 0.0, 0.0])[2] > 0.29);
        // Roll right (right side down) lowers the body's left... i.e. raises its left side.
        let q = body_orientation(0.3, 0.0, 0.0);
        assert!(rotate(&q, [0.0, 1.0, 0.0])[2] > 0.29);
    }

    #[test]
    fn the_room_has_a_floor_four_walls_and_every_obstacle() {
        let scene = Scene::preset("room-obstacles", 1).unwrap();
        let update = room(&scene, 0);
        let room = &update.entities[0];
        assert_eq!(room.cubes.len(), 5);
        let floor = room.cubes[0].size.unwrap();
        assert_eq!(
            (floor.x, floor.y),
            (f64::from(scene.size_x), f64::from(scene.size_y))
        );
        let obstacles = &update.entities[1];
        assert_eq!(
            obstacles.cubes.len() + obstacles.cylinders.len(),
            scene.obstacles.len()
        );
        for c in room.cubes.iter().chain(&obstacles.cubes) {
            let g = c.color.unwrap().r;
            assert!((0.0..=1.0).contains(&g) && g > 0.0, "{g}");
        }
    }

    #[test]
    fn depths_become_points_ahead_of_the_camera() {
        let mut depth = [0.0f32; IMG_W];
        depth[0] = 2.0;
        depth[IMG_W - 1] = 1.0;
        depth[64] = f32::NAN;
        let cloud = stereo_depths(5, &depth);
        assert_eq!(cloud.data.len(), 2 * POINT_STRIDE as usize);
        let f = |k: usize| f32::from_le_bytes(cloud.data[k * 4..k * 4 + 4].try_into().unwrap());
        // The first column is left of the axis (x < 0) at z = 2.
        assert!(f(0) < 0.0 && f(2) == 2.0);
        assert!(f(3) > 0.0 && f(5) == 1.0);
    }
}
