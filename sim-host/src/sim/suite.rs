//! The room suite: rooms generated from a seed (sides 3 to 8 m, 0 to 4 obstacles, textured,
//! mixed, low-contrast and plain walls, dim to bright light) for `sim-host fly --suite N`, and
//! the per-flight figures its table and CSV report.

use super::flight::FlightResult;
use super::scene_spec::{ObstacleSpec, SceneSpec, Shape, Surface, TextureKind};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What the walls of a generated room look like.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum RoomClass {
    /// Every wall textured (posters, stripes, bricks or wood) at full contrast.
    Textured,
    /// One to three walls plain, the others textured.
    Mixed,
    /// Textured walls at 10-35 % of the default contrast.
    LowContrast,
    /// Every wall and obstacle plain: nothing for stereo or flow but the floor and trims.
    Featureless,
}

impl RoomClass {
    /// All classes, in table order.
    pub const ALL: [RoomClass; 4] = [
        RoomClass::Textured,
        RoomClass::Mixed,
        RoomClass::LowContrast,
        RoomClass::Featureless,
    ];

    /// Name in tables and CSV.
    pub fn name(self) -> &'static str {
        match self {
            Self::Textured => "textured",
            Self::Mixed => "mixed",
            Self::LowContrast => "low-contrast",
            Self::Featureless => "featureless",
        }
    }
}

/// One generated room.
#[derive(Debug, Clone)]
pub struct SuiteRoom {
    /// Index in the suite (0-based).
    pub index: u64,
    /// The flight's seed (textures, heading, noise).
    pub seed: u64,
    /// Its class.
    pub class: RoomClass,
    /// The room.
    pub spec: SceneSpec,
}

const TEXTURED: [TextureKind; 4] = [
    TextureKind::Posters,
    TextureKind::Stripes,
    TextureKind::Bricks,
    TextureKind::Wood,
];

/// Room `index` of the suite seeded `seed` (the same pair always gives the same room). One
/// room in four of each class, in a seeded order.
pub fn room(seed: u64, index: u64) -> SuiteRoom {
    let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ index);
    let class = RoomClass::ALL[((index + seed) % 4) as usize];
    let sx = rng.random_range(3.0f32..=8.0);
    let sy = rng.random_range(3.0f32..=8.0);
    let h = rng.random_range(2.4f32..=3.0);
    // Light from 0.1 to 2 (log-uniform).
    let light = (rng.random_range(0.1f32.ln()..=2.0f32.ln())).exp();
    let textured = |rng: &mut ChaCha8Rng, contrast: f32| Surface {
        contrast,
        ..Surface::of(TEXTURED[rng.random_range(0..TEXTURED.len())])
    };
    let plain = |rng: &mut ChaCha8Rng| Surface {
        albedo: rng.random_range(0.3f32..=0.85),
        ..Surface::of(TextureKind::Plain)
    };
    let mut walls: Vec<Surface> = Vec::with_capacity(4);
    let n_plain = match class {
        RoomClass::Mixed => rng.random_range(1..=3usize),
        _ => 0,
    };
    for k in 0..4 {
        walls.push(match class {
            RoomClass::Textured => textured(&mut rng, 1.0),
            RoomClass::Mixed if k < n_plain => plain(&mut rng),
            RoomClass::Mixed => textured(&mut rng, 1.0),
            RoomClass::LowContrast => {
                let c = rng.random_range(0.1f32..=0.35);
                textured(&mut rng, c)
            }
            RoomClass::Featureless => plain(&mut rng),
        });
    }
    // Mixed: which walls are plain is seeded too.
    let shift = rng.random_range(0..4usize);
    walls.rotate_left(shift);
    let floor = match rng.random_range(0..3u32) {
        0 => Surface::of(TextureKind::Tiles),
        1 => Surface::of(TextureKind::Carpet),
        _ => Surface {
            albedo: rng.random_range(0.2f32..=0.6),
            ..Surface::of(TextureKind::Plain)
        },
    };
    let centre = [sx * 0.5, sy * 0.5];
    let mut obstacles: Vec<ObstacleSpec> = Vec::new();
    let wanted = rng.random_range(0..=4usize);
    let mut tries = 0;
    while obstacles.len() < wanted && tries < 100 {
        tries += 1;
        let surface = match class {
            RoomClass::Featureless => plain(&mut rng),
            RoomClass::LowContrast => {
                let c = rng.random_range(0.1f32..=0.35);
                textured(&mut rng, c)
            }
            _ if rng.random_bool(0.3) => plain(&mut rng),
            _ => textured(&mut rng, 1.0),
        };
        let x = rng.random_range(0.3..sx - 0.3);
        let y = rng.random_range(0.3..sy - 0.3);
        let shape = match rng.random_range(0..3u32) {
            0 => Shape::Cylinder {
                centre: [x, y],
                radius: rng.random_range(0.08f32..=0.4),
            },
            1 => {
                let len = rng.random_range(0.4f32..=1.5);
                let ang = rng.random_range(0.0..core::f32::consts::PI);
                let b = [x + len * ang.cos(), y + len * ang.sin()];
                if !(0.05..sx - 0.05).contains(&b[0]) || !(0.05..sy - 0.05).contains(&b[1]) {
                    continue;
                }
                Shape::Panel { a: [x, y], b }
            }
            _ => {
                let (w, d) = (
                    rng.random_range(0.3f32..=1.2),
                    rng.random_range(0.3f32..=1.2),
                );
                if x + d > sx - 0.05 || y + w > sy - 0.05 {
                    continue;
                }
                Shape::Box {
                    min: [x, y],
                    max: [x + d, y + w],
                }
            }
        };
        let o = ObstacleSpec {
            shape,
            height: rng.random_range(0.8f32..=h),
            surface,
        };
        // Keep the start free (0.8 m around the centre).
        let mut with = obstacles.clone();
        with.push(o.clone());
        if super::scene::clearance_of(&[sx, sy, h], &with, centre[0], centre[1], 0.05) >= 0.8 {
            obstacles.push(o);
        }
    }
    SuiteRoom {
        index,
        seed: seed.wrapping_add(index),
        class,
        spec: SceneSpec {
            name: format!("suite-{seed}-{index}"),
            size_m: [sx, sy, h],
            start_xy: centre,
            start_yaw_rad: None,
            light,
            walls: walls.try_into().expect("four walls"),
            floor,
            ceiling: Surface::of(TextureKind::Lamps),
            obstacles,
        },
    }
}

/// The rooms of shard `shard` of `of` (0-based) of an `n`-room suite: every `of`-th room.
pub fn shard_indices(n: u64, shard: u64, of: u64) -> impl Iterator<Item = u64> {
    (0..n).filter(move |i| i % of.max(1) == shard)
}

/// Horizontal speed below which a log row counts as hovering, m/s.
pub const HOVER_SPEED_MPS: f32 = 0.05;
/// Height below which a log row counts as landed (or not yet airborne), m.
pub const LANDED_M: f32 = 0.05;

/// Figures of one flight for the suite's table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlightFigures {
    /// Mean horizontal speed while airborne, m/s.
    pub mean_speed_mps: f64,
    /// Time hovering (airborne, slower than [`HOVER_SPEED_MPS`]), s.
    pub hovering_s: f64,
    /// Time on the floor (below [`LANDED_M`]), s, the time before take-off included.
    pub landed_s: f64,
}

/// Figures from a flight's 50 Hz log.
pub fn figures(r: &FlightResult) -> FlightFigures {
    let dt = 0.02;
    let (mut hover, mut landed, mut air) = (0.0, 0.0, 0.0);
    for row in &r.log {
        if row.pos[2] < LANDED_M {
            landed += dt;
        } else {
            air += dt;
            if row.vel_true[0].hypot(row.vel_true[1]) < HOVER_SPEED_MPS {
                hover += dt;
            }
        }
    }
    FlightFigures {
        mean_speed_mps: if air > 0.0 { r.distance_m / air } else { 0.0 },
        hovering_s: hover,
        landed_s: landed,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rooms_are_reproducible_valid_and_cover_every_class() {
        let mut classes = std::collections::BTreeSet::new();
        for i in 0..40 {
            let a = room(7, i);
            let b = room(7, i);
            assert_eq!(a.spec, b.spec);
            let [sx, sy, _] = a.spec.size_m;
            assert!((3.0..=8.0).contains(&sx) && (3.0..=8.0).contains(&sy));
            assert!(a.spec.obstacles.len() <= 4);
            assert!((0.1..=2.0).contains(&a.spec.light));
            if a.class == RoomClass::Featureless {
                assert!(a.spec.walls.iter().all(|w| w.texture == TextureKind::Plain));
            }
            // Builds, and the start is clear.
            super::super::scene::Scene::build(&a.spec, a.seed).unwrap();
            let c = super::super::scene::clearance_of(
                &a.spec.size_m,
                &a.spec.obstacles,
                a.spec.start_xy[0],
                a.spec.start_xy[1],
                0.05,
            );
            assert!(c >= 0.8, "room {i}: start clearance {c}");
            classes.insert(a.class);
        }
        assert_eq!(classes.len(), 4);
        assert_ne!(room(7, 1).spec, room(8, 1).spec);
    }

    #[test]
    fn shards_partition_the_suite() {
        let mut all: Vec<u64> = (0..3).flat_map(|s| shard_indices(10, s, 3)).collect();
        all.sort();
        assert_eq!(all, (0..10).collect::<Vec<_>>());
    }
}
