//! Scenes: a box-shaped room (walls, floor, ceiling) with vertical obstacles (cylinders, panels,
//! boxes) standing on the floor, built from a [`SceneSpec`] (a scene file) with textures drawn
//! from a seed; ray intersection for the camera renderer, and clearance / collision queries.
//!
//! World frame: x north, y east, z down; the floor is `z = 0`, the room spans
//! `0..=size_x` in x and `0..=size_y` in y.

use super::scene_spec::{SceneSpec, Shape};
use super::texture::Texture;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A vertical obstacle standing on the floor.
#[derive(Debug, Clone, PartialEq)]
pub enum Obstacle {
    /// A vertical cylinder (a pillar, a person, a plant).
    Cylinder {
        /// Centre x, m.
        x: f32,
        /// Centre y, m.
        y: f32,
        /// Radius, m.
        radius: f32,
        /// Height, m.
        height: f32,
    },
    /// A thin vertical panel (a screen, a cupboard side) from `a` to `b`, seen from both sides.
    Panel {
        /// First end (x, y), m.
        a: [f32; 2],
        /// Second end (x, y), m.
        b: [f32; 2],
        /// Height, m.
        height: f32,
    },
    /// An axis-aligned box (a cupboard, a desk down to the floor) from `min` to `max`.
    Box {
        /// Corner with the smallest x and y, m.
        min: [f32; 2],
        /// Corner with the largest x and y, m.
        max: [f32; 2],
        /// Height, m.
        height: f32,
    },
}

impl Obstacle {
    fn from_shape(shape: Shape, height: f32) -> Self {
        match shape {
            Shape::Cylinder { centre, radius } => Self::Cylinder {
                x: centre[0],
                y: centre[1],
                radius,
                height,
            },
            Shape::Panel { a, b } => Self::Panel { a, b, height },
            Shape::Box { min, max } => Self::Box { min, max, height },
        }
    }

    /// Height above the floor, m.
    pub fn height(&self) -> f32 {
        match self {
            Self::Cylinder { height, .. }
            | Self::Panel { height, .. }
            | Self::Box { height, .. } => *height,
        }
    }

    /// Length of the surface a texture is wrapped around (circumference, panel length,
    /// box perimeter), m.
    fn surface_length(&self) -> f32 {
        match self {
            Self::Cylinder { radius, .. } => core::f32::consts::TAU * radius,
            Self::Panel { a, b, .. } => (a[0] - b[0]).hypot(a[1] - b[1]),
            Self::Box { min, max, .. } => 2.0 * ((max[0] - min[0]) + (max[1] - min[1])),
        }
    }

    /// Its footprint.
    fn footprint(&self) -> Shape {
        match *self {
            Self::Cylinder { x, y, radius, .. } => Shape::Cylinder {
                centre: [x, y],
                radius,
            },
            Self::Panel { a, b, .. } => Shape::Panel { a, b },
            Self::Box { min, max, .. } => Shape::Box { min, max },
        }
    }

    /// Signed horizontal distance from `(x, y)` to the obstacle's surface, m (negative inside).
    fn distance(&self, x: f32, y: f32) -> f32 {
        self.footprint().distance(x, y)
    }
}

/// Most rays [`Scene::trace_batch`] takes at once.
pub const TRACE_BATCH: usize = 256;
/// A ray direction component smaller than this is parallel to the planes it would cross.
const PARALLEL_EPS: f32 = 1e-9;
/// A ray whose horizontal extent (squared) is below this is vertical: it meets no pillar's
/// side.
const VERTICAL_RAY_EPS: f32 = 1e-12;
/// Hits nearer than this along a ray, m, are the ray's own start (a surface it leaves).
const MIN_HIT_M: f32 = 1e-4;
/// A point within this of a box's face, m, lies on that face (texture coordinates).
const ON_FACE_M: f32 = 1e-3;
/// The step of the clearance's numerical gradient, m.
const GRADIENT_STEP_M: f32 = 1e-3;

/// The nearest of a room's six planes along `o + t d` (room `sx` x `sy`, ceiling at
/// `z = top`), as [`Scene::intersect`] finds it without obstacles, in branch-free form (the
/// same divisions and comparisons, selected instead of branched): `t` and the surface's code
/// (0 to 3 the walls, 4 the floor, 5 the ceiling).
#[inline(always)]
fn room_planes(o: [f32; 3], d: [f32; 3], sx: f32, sy: f32, top: f32) -> (f32, u8) {
    const EPS: f32 = PARALLEL_EPS;
    let (px, py, pz) = (d[0] > EPS, d[1] > EPS, d[2] > EPS);
    let (nx, ny, nz) = (d[0] < -EPS, d[1] < -EPS, d[2] < -EPS);
    let tx = if px { sx - o[0] } else { -o[0] } / d[0];
    let ty = if py { sy - o[1] } else { -o[1] } / d[1];
    let tz = if pz { -o[2] } else { top - o[2] } / d[2];
    let mut t = if px || nx { tx } else { f32::INFINITY };
    let mut code = if px {
        1
    } else if nx {
        0
    } else {
        4
    };
    let y_nearer = (py || ny) && ty < t;
    t = if y_nearer { ty } else { t };
    code = if y_nearer { 2 + u8::from(py) } else { code };
    let z_nearer = (pz || nz) && tz < t;
    t = if z_nearer { tz } else { t };
    code = if z_nearer { 5 - u8::from(pz) } else { code };
    (t, code)
}

/// The surface of a [`room_planes`] code.
#[inline(always)]
fn surface_of_code(code: u8) -> Surface {
    match code {
        0..=3 => Surface::Wall(code),
        4 => Surface::Floor,
        _ => Surface::Ceiling,
    }
}

/// Which surface a ray hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    /// A wall (0: x = 0, 1: x = size_x, 2: y = 0, 3: y = size_y).
    Wall(u8),
    /// The floor.
    Floor,
    /// The ceiling.
    Ceiling,
    /// Obstacle number `n`.
    Obstacle(u16),
}

/// A room with obstacles and textures.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Name (the scene file's `name`).
    pub name: String,
    /// Room extent along x (north), m.
    pub size_x: f32,
    /// Room extent along y (east), m.
    pub size_y: f32,
    /// Ceiling height, m.
    pub height: f32,
    /// Obstacles.
    pub obstacles: Vec<Obstacle>,
    /// Start position (x, y), m.
    pub start_xy: [f32; 2],
    /// Start heading, rad; `None`: each flight draws one from its seed.
    pub start_yaw_rad: Option<f32>,
    /// Brightness relative to the default lighting (the camera's exposure and gain act on it).
    pub light: f32,
    walls: [Texture; 4],
    floor: Texture,
    ceiling: Texture,
    obstacle_tex: Vec<Texture>,
}

impl Scene {
    /// Builds the room a spec describes, its textures drawn from `texture_seed`. Fails only
    /// if a picture cannot be read (the error names it).
    pub fn build(spec: &SceneSpec, texture_seed: u64) -> anyhow::Result<Self> {
        let mut rng = ChaCha8Rng::seed_from_u64(texture_seed ^ 0x5ce1e);
        let [sx, sy, h] = spec.size_m;
        let ctx = |what: &str| format!("scene {:?}: {what}", spec.name);
        let mut walls = Vec::with_capacity(4);
        for (k, w) in spec.walls.iter().enumerate() {
            let len = if k < 2 { sy } else { sx };
            walls.push(
                Texture::vertical(w, len, h, &mut rng)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", ctx("walls")))?,
            );
        }
        let obstacles: Vec<Obstacle> = spec
            .obstacles
            .iter()
            .map(|o| Obstacle::from_shape(o.shape, o.height))
            .collect();
        let mut obstacle_tex = Vec::with_capacity(obstacles.len());
        for (o, os) in obstacles.iter().zip(&spec.obstacles) {
            obstacle_tex.push(
                Texture::vertical(&os.surface, o.surface_length(), o.height(), &mut rng)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", ctx("obstacles")))?,
            );
        }
        let floor = Texture::floor(&spec.floor, sx, sy, &mut rng)
            .map_err(|e| anyhow::anyhow!("{}: {e}", ctx("floor")))?;
        let ceiling = Texture::ceiling(&spec.ceiling, sx, sy)
            .map_err(|e| anyhow::anyhow!("{}: {e}", ctx("ceiling")))?;
        Ok(Self {
            name: spec.name.clone(),
            size_x: sx,
            size_y: sy,
            height: h,
            obstacles,
            start_xy: spec.start_xy,
            start_yaw_rad: spec.start_yaw_rad,
            light: spec.light,
            walls: walls.try_into().expect("four walls"),
            floor,
            ceiling,
            obstacle_tex,
        })
    }

    /// A preset shipped with sim-host (see [`SceneSpec::preset_names`]): `room` is the
    /// paper's empty 4 x 4 m room (2.5 m ceiling); `room-obstacles` adds a pillar and a panel;
    /// `corridor` is 12 x 1.8 m; `plain-room` is `room` painted plain grey; `office` mixes
    /// every texture and obstacle kind.
    pub fn preset(name: &str, texture_seed: u64) -> Option<Self> {
        let spec = SceneSpec::preset(name)?;
        Some(Self::build(&spec, texture_seed).expect("presets have no pictures"))
    }

    /// Mean albedo 0..1 of a surface's texture (the ceiling for an obstacle that does not
    /// exist).
    pub fn mean_albedo(&self, surface: Surface) -> f32 {
        let texture = match surface {
            Surface::Wall(k) => &self.walls[usize::from(k.min(3))],
            Surface::Floor => &self.floor,
            Surface::Ceiling => &self.ceiling,
            Surface::Obstacle(n) => self
                .obstacle_tex
                .get(usize::from(n))
                .unwrap_or(&self.ceiling),
        };
        texture.mean_albedo()
    }

    /// Albedo seen along the ray `o + t d` (t > 0), and the hit distance `t`. The origin must
    /// be inside the room.
    #[inline]
    pub fn trace(&self, o: [f32; 3], d: [f32; 3]) -> (f32, f32) {
        let (t, surf) = self.intersect(o, d);
        (self.albedo_at(o, d, t, surf), t)
    }

    /// Albedo of each of a batch of rays from one origin `o` along the world directions
    /// `(dx[i], dy[i], dz[i])`, into `albedo[i]`: the same values as [`trace`](Self::trace),
    /// bit for bit. The room's planes are intersected for the whole batch in lane-wise,
    /// branch-free code the compiler vectorises; obstacles and texture look-ups per ray. All
    /// slices must have the same length, at most [`TRACE_BATCH`].
    pub fn trace_batch(&self, o: [f32; 3], dx: &[f32], dy: &[f32], dz: &[f32], albedo: &mut [f32]) {
        let n = albedo.len();
        assert!(n <= TRACE_BATCH && dx.len() == n && dy.len() == n && dz.len() == n);
        let mut ts = [0.0f32; TRACE_BATCH];
        let mut codes = [0u8; TRACE_BATCH];
        let (sx, sy, top) = (self.size_x, self.size_y, -self.height);
        for i in 0..n {
            let (t, code) = room_planes(o, [dx[i], dy[i], dz[i]], sx, sy, top);
            ts[i] = t;
            codes[i] = code;
        }
        for i in 0..n {
            let d = [dx[i], dy[i], dz[i]];
            let mut hit = (ts[i], surface_of_code(codes[i]));
            if !self.obstacles.is_empty() {
                hit = self.intersect_obstacles(o, d, hit);
            }
            albedo[i] = self.albedo_at(o, d, hit.0, hit.1);
        }
    }

    /// Albedo of the surface `surf` a ray `o + t d` hit at `t`.
    #[inline]
    fn albedo_at(&self, o: [f32; 3], d: [f32; 3], t: f32, surf: Surface) -> f32 {
        let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
        match surf {
            Surface::Wall(0) => self.walls[0].sample(p[1], -p[2]),
            Surface::Wall(1) => self.walls[1].sample(self.size_y - p[1], -p[2]),
            Surface::Wall(2) => self.walls[2].sample(self.size_x - p[0], -p[2]),
            Surface::Wall(_) => self.walls[3].sample(p[0], -p[2]),
            Surface::Floor => self.floor.sample(p[0], p[1]),
            Surface::Ceiling => self.ceiling.sample(p[0], p[1]),
            Surface::Obstacle(n) => self.obstacle_albedo(n as usize, p),
        }
    }

    fn obstacle_albedo(&self, n: usize, p: [f32; 3]) -> f32 {
        let tex = &self.obstacle_tex[n];
        match &self.obstacles[n] {
            Obstacle::Cylinder { x, y, radius, .. } => {
                let ang = (p[1] - y).atan2(p[0] - x) + core::f32::consts::PI;
                tex.sample(ang * radius, -p[2])
            }
            Obstacle::Panel { a, .. } => {
                let s = ((p[0] - a[0]).powi(2) + (p[1] - a[1]).powi(2)).sqrt();
                tex.sample(s, -p[2])
            }
            Obstacle::Box { min, max, .. } => {
                // Around the perimeter: south side (x = min), east, north, west.
                let (w, d) = (max[1] - min[1], max[0] - min[0]);
                let s = if (p[0] - min[0]).abs() < ON_FACE_M {
                    p[1] - min[1]
                } else if (p[1] - max[1]).abs() < ON_FACE_M {
                    w + p[0] - min[0]
                } else if (p[0] - max[0]).abs() < ON_FACE_M {
                    w + d + max[1] - p[1]
                } else {
                    2.0 * w + d + max[0] - p[0]
                };
                tex.sample(s, -p[2])
            }
        }
    }

    /// Nearest intersection of the ray `o + t d` with the scene: distance `t` and surface.
    #[inline]
    pub fn intersect(&self, o: [f32; 3], d: [f32; 3]) -> (f32, Surface) {
        let mut t = f32::INFINITY;
        let mut surf = Surface::Floor;
        if d[0] > PARALLEL_EPS {
            t = (self.size_x - o[0]) / d[0];
            surf = Surface::Wall(1);
        } else if d[0] < -PARALLEL_EPS {
            t = -o[0] / d[0];
            surf = Surface::Wall(0);
        }
        if d[1] > PARALLEL_EPS {
            let ty = (self.size_y - o[1]) / d[1];
            if ty < t {
                t = ty;
                surf = Surface::Wall(3);
            }
        } else if d[1] < -PARALLEL_EPS {
            let ty = -o[1] / d[1];
            if ty < t {
                t = ty;
                surf = Surface::Wall(2);
            }
        }
        if d[2] > PARALLEL_EPS {
            let tz = -o[2] / d[2];
            if tz < t {
                t = tz;
                surf = Surface::Floor;
            }
        } else if d[2] < -PARALLEL_EPS {
            let tz = (-self.height - o[2]) / d[2];
            if tz < t {
                t = tz;
                surf = Surface::Ceiling;
            }
        }
        self.intersect_obstacles(o, d, (t, surf))
    }

    /// The nearer of the hit `(t, surf)` and the ray's nearest obstacle hit.
    #[inline]
    fn intersect_obstacles(
        &self,
        o: [f32; 3],
        d: [f32; 3],
        (mut t, mut surf): (f32, Surface),
    ) -> (f32, Surface) {
        for (n, ob) in self.obstacles.iter().enumerate() {
            let (to, h) = match ob {
                Obstacle::Cylinder {
                    x,
                    y,
                    radius,
                    height,
                } => {
                    let (ox, oy) = (o[0] - x, o[1] - y);
                    let a = d[0] * d[0] + d[1] * d[1];
                    let b = ox * d[0] + oy * d[1];
                    let c = ox * ox + oy * oy - radius * radius;
                    let disc = b * b - a * c;
                    if a < VERTICAL_RAY_EPS || disc < 0.0 {
                        continue;
                    }
                    ((-b - disc.sqrt()) / a, *height)
                }
                Obstacle::Panel { a, b, height } => {
                    // Solve o + t d = a + u (b - a) in the horizontal plane.
                    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                    let den = d[0] * ey - d[1] * ex;
                    if den.abs() < PARALLEL_EPS {
                        continue;
                    }
                    let (wx, wy) = (a[0] - o[0], a[1] - o[1]);
                    let tt = (wx * ey - wy * ex) / den;
                    let u = (wx * d[1] - wy * d[0]) / den;
                    if !(0.0..=1.0).contains(&u) {
                        continue;
                    }
                    (tt, *height)
                }
                Obstacle::Box { min, max, height } => {
                    // Slabs in x and y: the entry distance where the ray is inside both.
                    let mut t0 = f32::NEG_INFINITY;
                    let mut t1 = f32::INFINITY;
                    let mut hit = true;
                    for k in 0..2 {
                        if d[k].abs() < PARALLEL_EPS {
                            if o[k] < min[k] || o[k] > max[k] {
                                hit = false;
                            }
                        } else {
                            let (a, b) = ((min[k] - o[k]) / d[k], (max[k] - o[k]) / d[k]);
                            t0 = t0.max(a.min(b));
                            t1 = t1.min(a.max(b));
                        }
                    }
                    if !hit || t0 > t1 {
                        continue;
                    }
                    (t0, *height)
                }
            };
            if to > MIN_HIT_M && to < t {
                let z = o[2] + to * d[2];
                if z <= 0.0 && -z <= h {
                    t = to;
                    surf = Surface::Obstacle(n as u16);
                }
            }
        }
        (t, surf)
    }

    /// Horizontal distance from `(x, y)` to the nearest wall or obstacle surface, m (for a point
    /// at height `h` m: obstacles lower than `h` do not count).
    pub fn clearance(&self, x: f32, y: f32, h: f32) -> f32 {
        let walls = x.min(self.size_x - x).min(y).min(self.size_y - y);
        self.obstacles
            .iter()
            .filter(|o| h <= o.height())
            .map(|o| o.distance(x, y))
            .fold(walls, f32::min)
    }

    /// Outward unit normal (x, y) of the nearest surface at `(x, y)`: the direction that pushes
    /// a point away from it (used to resolve collisions).
    pub fn push_out_dir(&self, x: f32, y: f32, h: f32) -> [f32; 2] {
        let eps = GRADIENT_STEP_M;
        let gx = self.clearance(x + eps, y, h) - self.clearance(x - eps, y, h);
        let gy = self.clearance(x, y + eps, h) - self.clearance(x, y - eps, h);
        let n = (gx * gx + gy * gy).sqrt();
        if n > 0.0 {
            [gx / n, gy / n]
        } else {
            [0.0, 0.0]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_hits_the_wall_ahead_and_obstacles() {
        let s = Scene::preset("room-obstacles", 1).unwrap();
        let (t, surf) = s.intersect([2.0, 2.0, -1.0], [1.0, 0.0, 0.0]);
        assert_eq!(surf, Surface::Wall(1));
        assert!((t - 2.0).abs() < 1e-6);
        // Towards the pillar at (3, 1), radius 0.15.
        let d = [
            std::f32::consts::FRAC_1_SQRT_2,
            -std::f32::consts::FRAC_1_SQRT_2,
            0.0,
        ];
        let (t, surf) = s.intersect([2.0, 2.0, -1.0], d);
        assert_eq!(surf, Surface::Obstacle(0));
        assert!((t - (2f32.sqrt() - 0.15)).abs() < 1e-4, "{t}");
        assert!((s.clearance(2.0, 2.0, 1.0) - (2f32.sqrt() - 0.15)).abs() < 1e-4);
        assert!((s.clearance(0.5, 2.0, 1.0) - 0.5).abs() < 1e-6);
        let n = s.push_out_dir(0.1, 2.0, 1.0);
        assert!((n[0] - 1.0).abs() < 1e-3);
    }

    #[test]
    fn wall_textures_have_vertical_edges() {
        let s = Scene::preset("room", 7).unwrap();
        let mut edges = 0;
        let mut prev = s.walls[1].sample(0.0, 1.0);
        for i in 1..400 {
            let v = s.walls[1].sample(i as f32 * 0.01, 1.0);
            if (v - prev).abs() > 0.1 {
                edges += 1;
            }
            prev = v;
        }
        assert!(edges > 20, "{edges} edges along 4 m");
        let plain = Scene::preset("plain-room", 7).unwrap();
        assert!(plain.walls[1].edge_energy(4.0, 1.0, 0.01) < 1e-6);
    }

    #[test]
    fn boxes_are_hit_from_every_side_and_push_out() {
        let spec = SceneSpec::parse(
            "name = \"b\"\nsize_m = [6.0, 6.0, 2.5]\nstart = { x = 1.0, y = 1.0 }\n\
             [[obstacles]]\nkind = \"box\"\nmin = [2.0, 2.0]\nmax = [3.0, 4.0]\nheight = 1.0\n",
            "b.toml",
            std::path::Path::new("."),
        )
        .unwrap();
        let s = Scene::build(&spec, 1).unwrap();
        // From the south, west, north and east, at 0.5 m height.
        for (o, d, t_exp) in [
            ([1.0, 3.0, -0.5], [1.0, 0.0, 0.0], 1.0),
            ([2.5, 1.0, -0.5], [0.0, 1.0, 0.0], 1.0),
            ([5.0, 3.0, -0.5], [-1.0, 0.0, 0.0], 2.0),
            ([2.5, 5.5, -0.5], [0.0, -1.0, 0.0], 1.5),
        ] {
            let (t, surf) = s.intersect(o, d);
            assert_eq!(surf, Surface::Obstacle(0), "{o:?}");
            assert!((t - t_exp).abs() < 1e-5, "{o:?}: {t}");
            let v = s.trace(o, d).0;
            assert!((0.0..=1.0).contains(&v));
        }
        // Over the top (1 m high) the ray reaches the far wall.
        assert_eq!(
            s.intersect([1.0, 3.0, -1.5], [1.0, 0.0, 0.0]).1,
            Surface::Wall(1)
        );
        assert!((s.clearance(1.5, 3.0, 0.5) - 0.5).abs() < 1e-6);
        assert!((s.clearance(3.5, 4.5, 0.5) - 0.5f32.hypot(0.5)).abs() < 1e-5);
        assert!(s.clearance(2.1, 3.0, 0.5) < 0.0, "inside is negative");
        assert!(
            (s.clearance(1.5, 3.0, 1.5) - 1.5).abs() < 1e-6,
            "above the box"
        );
        let n = s.push_out_dir(2.05, 3.0, 0.5);
        assert!((n[0] + 1.0).abs() < 1e-3, "{n:?}");
    }
}
