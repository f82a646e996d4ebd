//! Scenes: a box-shaped room (walls, floor, ceiling) with optional vertical cylinders and
//! panels, procedurally textured from a seed with textures rich in vertical edges (what
//! Edge-FS needs), ray intersection for the camera renderer, and clearance / collision queries.
//!
//! World frame: x north, y east, z down; the floor is `z = 0`, the room spans
//! `0..=size_x` in x and `0..=size_y` in y.

use rand::{Rng, SeedableRng};
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
}

/// A gray-level texture on a regular grid (nearest-neighbour lookup, clamped).
#[derive(Debug, Clone)]
pub struct Texture {
    nx: usize,
    ny: usize,
    /// Cells per metre along s and h.
    res: [f32; 2],
    data: Vec<f32>,
}

impl Texture {
    /// Albedo 0..1 at surface coordinates `s` (along) and `h` (up), m.
    #[inline]
    pub fn sample(&self, s: f32, h: f32) -> f32 {
        let i = ((s * self.res[0]).max(0.0) as usize).min(self.nx - 1);
        let j = ((h * self.res[1]).max(0.0) as usize).min(self.ny - 1);
        self.data[j * self.nx + i]
    }

    /// Wall texture: vertical stripes of random width and gray level, some "posters" with
    /// their own finer stripes, a mild vertical shading and horizontal trim near floor/ceiling.
    fn wall(length: f32, height: f32, rng: &mut ChaCha8Rng) -> Self {
        let res = [100.0f32, 25.0];
        let nx = (length * res[0]).ceil() as usize + 1;
        let ny = (height * res[1]).ceil() as usize + 1;
        let mut col = vec![0.0f32; nx];
        let mut i = 0;
        while i < nx {
            let w = 2 + (rng.random::<f32>().powi(2) * 25.0) as usize;
            let v = 0.15 + 0.75 * rng.random::<f32>();
            for c in col.iter_mut().skip(i).take(w) {
                *c = v;
            }
            i += w;
        }
        let mut data = vec![0.0f32; nx * ny];
        for j in 0..ny {
            let h = j as f32 / res[1];
            let shade = 0.9 + 0.1 * (h / height.max(0.1));
            let trim = h < 0.1 || h > height - 0.1;
            for i in 0..nx {
                data[j * nx + i] = if trim { 0.35 } else { col[i] * shade };
            }
        }
        // Posters: rectangles with their own stripe pattern.
        let n_posters = (length / 1.2) as usize + 1;
        for _ in 0..n_posters {
            let w = 0.3 + 0.6 * rng.random::<f32>();
            let hgt = 0.4 + 0.6 * rng.random::<f32>();
            let s0 = rng.random::<f32>() * (length - w).max(0.0);
            let h0 = 0.3 + rng.random::<f32>() * (height - hgt - 0.6).max(0.0);
            let period = 3 + rng.random_range(0..8usize);
            let (lo, hi) = (
                0.1 + 0.2 * rng.random::<f32>(),
                0.7 + 0.25 * rng.random::<f32>(),
            );
            let i0 = (s0 * res[0]) as usize;
            let i1 = (((s0 + w) * res[0]) as usize).min(nx);
            let j0 = (h0 * res[1]) as usize;
            let j1 = (((h0 + hgt) * res[1]) as usize).min(ny);
            for j in j0..j1 {
                for i in i0..i1 {
                    data[j * nx + i] = if ((i - i0) / period).is_multiple_of(2) {
                        lo
                    } else {
                        hi
                    };
                }
            }
        }
        Self { nx, ny, res, data }
    }

    /// Floor texture: 30 cm tiles of random gray with fine grain.
    fn floor(size_x: f32, size_y: f32, rng: &mut ChaCha8Rng) -> Self {
        let res = [50.0f32, 50.0];
        let nx = (size_x * res[0]).ceil() as usize + 1;
        let ny = (size_y * res[1]).ceil() as usize + 1;
        let tiles_x = nx / 15 + 1;
        let tiles: Vec<f32> = (0..tiles_x * (ny / 15 + 1))
            .map(|_| 0.3 + 0.4 * rng.random::<f32>())
            .collect();
        let mut data = vec![0.0; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                data[j * nx + i] =
                    tiles[(j / 15) * tiles_x + i / 15] + 0.08 * (rng.random::<f32>() - 0.5);
            }
        }
        Self { nx, ny, res, data }
    }

    /// Ceiling: light, with darker lamp rows.
    fn ceiling(size_x: f32, size_y: f32) -> Self {
        let res = [10.0f32, 10.0];
        let nx = (size_x * res[0]).ceil() as usize + 1;
        let ny = (size_y * res[1]).ceil() as usize + 1;
        let data = (0..nx * ny)
            .map(|k| if (k % nx) % 10 < 2 { 0.55 } else { 0.8 })
            .collect();
        Self { nx, ny, res, data }
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
    /// Preset name.
    pub name: String,
    /// Room extent along x (north), m.
    pub size_x: f32,
    /// Room extent along y (east), m.
    pub size_y: f32,
    /// Ceiling height, m.
    pub height: f32,
    /// Obstacles.
    pub obstacles: Vec<Obstacle>,
    /// Start position (x, y), m, and heading, rad.
    pub start: [f32; 3],
    /// Whether flights start at a seed-dependent heading (rooms) or at `start`'s (corridor).
    pub random_heading: bool,
    walls: [Texture; 4],
    floor: Texture,
    ceiling: Texture,
    obstacle_tex: Vec<Texture>,
}

/// Names accepted by [`Scene::preset`].
pub const PRESETS: &[&str] = &["room", "room-obstacles", "corridor"];

impl Scene {
    /// A room of the given size with seeded textures.
    pub fn new(
        name: &str,
        size: [f32; 3],
        obstacles: Vec<Obstacle>,
        start: [f32; 3],
        texture_seed: u64,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(texture_seed ^ 0x5ce1e);
        let [sx, sy, h] = size;
        let walls = [
            Texture::wall(sy, h, &mut rng),
            Texture::wall(sy, h, &mut rng),
            Texture::wall(sx, h, &mut rng),
            Texture::wall(sx, h, &mut rng),
        ];
        let obstacle_tex = obstacles
            .iter()
            .map(|o| match o {
                Obstacle::Cylinder { radius, height, .. } => {
                    Texture::wall(core::f32::consts::TAU * radius, *height, &mut rng)
                }
                Obstacle::Panel { a, b, height } => {
                    let len = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
                    Texture::wall(len, *height, &mut rng)
                }
            })
            .collect();
        Self {
            name: name.to_string(),
            size_x: sx,
            size_y: sy,
            height: h,
            obstacles,
            start,
            random_heading: true,
            walls,
            floor: Texture::floor(sx, sy, &mut rng),
            ceiling: Texture::ceiling(sx, sy),
            obstacle_tex,
        }
    }

    /// A named preset (see [`PRESETS`]): `room` is the paper's empty 4 x 4 m room (2.5 m
    /// ceiling); `room-obstacles` adds a pillar and a panel; `corridor` is 12 x 1.8 m.
    pub fn preset(name: &str, texture_seed: u64) -> Option<Self> {
        Some(match name {
            "room" => Self::new(
                "room",
                [4.0, 4.0, 2.5],
                vec![],
                [2.0, 2.0, 0.0],
                texture_seed,
            ),
            "room-obstacles" => Self::new(
                "room-obstacles",
                [4.0, 4.0, 2.5],
                vec![
                    Obstacle::Cylinder {
                        x: 3.0,
                        y: 1.0,
                        radius: 0.15,
                        height: 2.5,
                    },
                    Obstacle::Panel {
                        a: [1.0, 3.0],
                        b: [1.6, 3.4],
                        height: 1.8,
                    },
                ],
                [2.0, 2.0, 0.0],
                texture_seed,
            ),
            "corridor" => Self {
                random_heading: false,
                ..Self::new(
                    "corridor",
                    [12.0, 1.8, 2.5],
                    vec![],
                    [1.0, 0.9, 0.0],
                    texture_seed,
                )
            },
            _ => return None,
        })
    }

    /// Albedo seen along the ray `o + t d` (t > 0), and the hit distance `t`. The origin must
    /// be inside the room.
    #[inline]
    pub fn trace(&self, o: [f32; 3], d: [f32; 3]) -> (f32, f32) {
        let (t, surf) = self.intersect(o, d);
        let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
        let v = match surf {
            Surface::Wall(0) => self.walls[0].sample(p[1], -p[2]),
            Surface::Wall(1) => self.walls[1].sample(self.size_y - p[1], -p[2]),
            Surface::Wall(2) => self.walls[2].sample(self.size_x - p[0], -p[2]),
            Surface::Wall(_) => self.walls[3].sample(p[0], -p[2]),
            Surface::Floor => self.floor.sample(p[0], p[1]),
            Surface::Ceiling => self.ceiling.sample(p[0], p[1]),
            Surface::Obstacle(n) => self.obstacle_albedo(n as usize, p),
        };
        (v, t)
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
        }
    }

    /// Nearest intersection of the ray `o + t d` with the scene: distance `t` and surface.
    #[inline]
    pub fn intersect(&self, o: [f32; 3], d: [f32; 3]) -> (f32, Surface) {
        let mut t = f32::INFINITY;
        let mut surf = Surface::Floor;
        if d[0] > 1e-9 {
            t = (self.size_x - o[0]) / d[0];
            surf = Surface::Wall(1);
        } else if d[0] < -1e-9 {
            t = -o[0] / d[0];
            surf = Surface::Wall(0);
        }
        if d[1] > 1e-9 {
            let ty = (self.size_y - o[1]) / d[1];
            if ty < t {
                t = ty;
                surf = Surface::Wall(3);
            }
        } else if d[1] < -1e-9 {
            let ty = -o[1] / d[1];
            if ty < t {
                t = ty;
                surf = Surface::Wall(2);
            }
        }
        if d[2] > 1e-9 {
            let tz = -o[2] / d[2];
            if tz < t {
                t = tz;
                surf = Surface::Floor;
            }
        } else if d[2] < -1e-9 {
            let tz = (-self.height - o[2]) / d[2];
            if tz < t {
                t = tz;
                surf = Surface::Ceiling;
            }
        }
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
                    if a < 1e-12 || disc < 0.0 {
                        continue;
                    }
                    ((-b - disc.sqrt()) / a, *height)
                }
                Obstacle::Panel { a, b, height } => {
                    // Solve o + t d = a + u (b - a) in the horizontal plane.
                    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                    let den = d[0] * ey - d[1] * ex;
                    if den.abs() < 1e-9 {
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
            };
            if to > 1e-4 && to < t {
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
        let mut c = x.min(self.size_x - x).min(y).min(self.size_y - y);
        for ob in &self.obstacles {
            let dist = match ob {
                Obstacle::Cylinder {
                    x: cx,
                    y: cy,
                    radius,
                    height,
                } => {
                    if h > *height {
                        continue;
                    }
                    ((x - cx).powi(2) + (y - cy).powi(2)).sqrt() - radius
                }
                Obstacle::Panel { a, b, height } => {
                    if h > *height {
                        continue;
                    }
                    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                    let l2 = (ex * ex + ey * ey).max(1e-12);
                    let u = (((x - a[0]) * ex + (y - a[1]) * ey) / l2).clamp(0.0, 1.0);
                    ((x - a[0] - u * ex).powi(2) + (y - a[1] - u * ey).powi(2)).sqrt()
                }
            };
            c = c.min(dist);
        }
        c
    }

    /// Outward unit normal (x, y) of the nearest surface at `(x, y)`: the direction that pushes
    /// a point away from it (used to resolve collisions).
    pub fn push_out_dir(&self, x: f32, y: f32, h: f32) -> [f32; 2] {
        let eps = 1e-3;
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
    }
}
