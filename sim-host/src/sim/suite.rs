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
        if super::scene_spec::clearance_of(&[sx, sy, h], &with, centre[0], centre[1], 0.05) >= 0.8 {
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

/// One flight of a suite as its CSV row reports it (`sim-host fly --suite N --format csv`):
/// the text of the row and the figures the table by class is computed from. A whole run and
/// merged shards both build their table from these rows, so the two print the same table.
#[derive(Debug, Clone, PartialEq)]
pub struct SuiteRow {
    /// The row as printed, without its line end.
    pub line: String,
    /// The suite's seed (`--seed`), from the room's name.
    pub suite_seed: u64,
    /// Index of the room in the suite, from the room's name.
    pub index: u64,
    /// Class of the room.
    pub class: RoomClass,
    /// Simulated duration, s.
    pub duration_s: f64,
    /// Flight time until the first collision, s.
    pub flight_time_s: f64,
    /// Number of collisions.
    pub collisions: u64,
    /// Smallest clearance, m (not finite: never measured).
    pub min_clearance_m: f64,
    /// Mean horizontal speed while airborne, m/s.
    pub mean_speed_mps: f64,
    /// Time hovering, s.
    pub hovering_s: f64,
    /// Time on the floor, s.
    pub landed_s: f64,
}

/// A suite CSV that cannot be read or merged.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SuiteCsvError {
    /// The file's first line is not the suite header.
    #[error("{file}: the first line is not the suite CSV header `{expected}`")]
    Header {
        /// The file.
        file: String,
        /// The header a suite CSV starts with.
        expected: String,
    },
    /// A row that does not parse.
    #[error("{file}:{line}: {reason}")]
    Row {
        /// The file.
        file: String,
        /// Its line number (1-based).
        line: usize,
        /// What is wrong with it.
        reason: String,
    },
    /// The same room in two rows.
    #[error("room {room} appears twice ({first} and {second})")]
    Duplicate {
        /// The room's name.
        room: String,
        /// Where it was first seen.
        first: String,
        /// Where it was seen again.
        second: String,
    },
    /// Rows of different suites.
    #[error("rows of two suites: seed {a} and seed {b} (merge the shards of one suite)")]
    Seeds {
        /// One suite's seed.
        a: u64,
        /// The other's.
        b: u64,
    },
    /// A room below the highest index is missing (a shard left out).
    #[error(
        "room {index} of the suite is missing (rooms 0 to {last} are expected; a shard left out?)"
    )]
    Missing {
        /// The first missing index.
        index: u64,
        /// The highest index present.
        last: u64,
    },
    /// No rows at all.
    #[error("no rows to merge")]
    Empty,
}

impl RoomClass {
    /// The class named `name` (as [`RoomClass::name`] prints it).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }
}

impl SuiteRow {
    /// Parses one data row of a suite CSV whose header is `header` (columns found by name).
    pub fn parse(header: &str, line: &str) -> Result<Self, String> {
        let names: Vec<&str> = header.split(',').collect();
        let values: Vec<&str> = line.split(',').collect();
        if names.len() != values.len() {
            return Err(format!(
                "{} columns, the header has {}",
                values.len(),
                names.len()
            ));
        }
        let get = |name: &str| -> Result<&str, String> {
            names
                .iter()
                .position(|n| *n == name)
                .map(|k| values[k])
                .ok_or_else(|| format!("no column {name}"))
        };
        let num = |name: &str| -> Result<f64, String> {
            let v = get(name)?;
            v.parse::<f64>().map_err(|e| format!("{name} = {v:?}: {e}"))
        };
        let room = get("room")?;
        let (suite_seed, index) = room
            .strip_prefix("suite-")
            .and_then(|r| r.rsplit_once('-'))
            .and_then(|(s, i)| Some((s.parse().ok()?, i.parse().ok()?)))
            .ok_or_else(|| format!("room {room:?} is not named suite-SEED-INDEX"))?;
        let class = get("class")?;
        let collisions = get("collisions")?;
        Ok(Self {
            line: line.to_string(),
            suite_seed,
            index,
            class: RoomClass::from_name(class).ok_or_else(|| format!("unknown class {class:?}"))?,
            duration_s: num("duration_s")?,
            flight_time_s: num("flight_time_s")?,
            collisions: collisions
                .parse()
                .map_err(|e| format!("collisions = {collisions:?}: {e}"))?,
            min_clearance_m: num("min_clearance_m")?,
            mean_speed_mps: num("mean_speed_mps")?,
            hovering_s: num("hovering_s")?,
            landed_s: num("landed_s")?,
        })
    }
}

/// Reads the rows of one suite CSV (`text`, named `file` in errors) whose header must be
/// `header`.
pub fn parse_csv(file: &str, text: &str, header: &str) -> Result<Vec<SuiteRow>, SuiteCsvError> {
    let mut lines = text.lines();
    if lines.next().map(str::trim_end) != Some(header) {
        return Err(SuiteCsvError::Header {
            file: file.to_string(),
            expected: header.to_string(),
        });
    }
    lines
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(k, l)| {
            SuiteRow::parse(header, l.trim_end()).map_err(|reason| SuiteCsvError::Row {
                file: file.to_string(),
                line: k + 2,
                reason,
            })
        })
        .collect()
}

/// Merges the rows of a suite's shards (`(file, rows)` in any order) into the suite's rows in
/// room order. Fails on rows of two suites, a room twice, or a room missing below the highest
/// index.
pub fn merge(parts: Vec<(String, Vec<SuiteRow>)>) -> Result<Vec<SuiteRow>, SuiteCsvError> {
    let mut seen: std::collections::BTreeMap<u64, (String, SuiteRow)> = Default::default();
    let mut seed: Option<u64> = None;
    for (file, rows) in parts {
        for row in rows {
            match seed {
                Some(s) if s != row.suite_seed => {
                    return Err(SuiteCsvError::Seeds {
                        a: s,
                        b: row.suite_seed,
                    })
                }
                _ => seed = Some(row.suite_seed),
            }
            if let Some((first, _)) = seen.get(&row.index) {
                return Err(SuiteCsvError::Duplicate {
                    room: format!("suite-{}-{}", row.suite_seed, row.index),
                    first: first.clone(),
                    second: file.clone(),
                });
            }
            seen.insert(row.index, (file.clone(), row));
        }
    }
    let last = *seen.keys().next_back().ok_or(SuiteCsvError::Empty)?;
    if let Some(index) = (0..=last).find(|i| !seen.contains_key(i)) {
        return Err(SuiteCsvError::Missing { index, last });
    }
    Ok(seen.into_values().map(|(_, row)| row).collect())
}

/// The suite's table by class of room (a row per class present, then "all") and its legend,
/// each line ending in a newline.
pub fn table(rows: &[SuiteRow]) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<13} {:>7} {:>9} {:>13} {:>11} {:>10} {:>10} {:>9}",
        "class", "flights", "contact", "first_contact", "min_clr", "speed", "hovering", "landed"
    );
    let mut groups: Vec<(&str, Vec<&SuiteRow>)> = RoomClass::ALL
        .iter()
        .map(|c| (c.name(), rows.iter().filter(|r| r.class == *c).collect()))
        .collect();
    groups.push(("all", rows.iter().collect()));
    for (name, group) in groups {
        if group.is_empty() {
            continue;
        }
        let k = group.len() as f64;
        let contact: Vec<&&SuiteRow> = group.iter().filter(|r| r.collisions > 0).collect();
        let first = if contact.is_empty() {
            "-".to_string()
        } else {
            let min = contact
                .iter()
                .map(|r| r.flight_time_s)
                .fold(f64::INFINITY, f64::min);
            format!("{min:.1} s")
        };
        let min_clr = group
            .iter()
            .map(|r| r.min_clearance_m)
            .filter(|c| c.is_finite())
            .fold(f64::INFINITY, f64::min);
        let mean = |f: &dyn Fn(&SuiteRow) -> f64| group.iter().map(|r| f(r)).sum::<f64>() / k;
        let _ = writeln!(
            out,
            "{:<13} {:>7} {:>9} {:>13} {:>9.3} m {:>6.2} m/s {:>8.1} s {:>7.1} s",
            name,
            group.len(),
            contact.len(),
            first,
            min_clr,
            mean(&|r| r.mean_speed_mps),
            mean(&|r| r.hovering_s),
            mean(&|r| r.landed_s),
        );
    }
    out.push_str(
        "contact = flights with a wall or obstacle contact; first_contact = earliest; min_clr = \
         smallest clearance; speed, hovering, landed = means per flight.\n",
    );
    out
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
            let c = super::super::scene_spec::clearance_of(
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

    const HEADER: &str = "seed,duration_s,flight_time_s,collisions,min_clearance_m,room,class,\
                          mean_speed_mps,hovering_s,landed_s";

    fn row(seed: u64, index: u64, class: &str, collisions: u64) -> String {
        format!(
            "{},10.0,9.50,{collisions},0.3000,suite-{seed}-{index},{class},0.400,1.0,0.5",
            seed + index
        )
    }

    #[test]
    fn merge_orders_rooms_and_refuses_mixed_suites() {
        let parse = |lines: &[String]| {
            let text = format!("{HEADER}\n{}\n", lines.join("\n"));
            parse_csv("f.csv", &text, HEADER).unwrap()
        };
        let a = parse(&[row(4, 1, "mixed", 0), row(4, 3, "textured", 2)]);
        let b = parse(&[row(4, 0, "featureless", 0), row(4, 2, "mixed", 1)]);
        let merged = merge(vec![("a".into(), a), ("b".into(), b.clone())]).unwrap();
        assert_eq!(
            merged.iter().map(|r| r.index).collect::<Vec<_>>(),
            [0, 1, 2, 3]
        );
        assert_eq!(merged[3].class, RoomClass::Textured);
        assert_eq!(merged[3].collisions, 2);
        let table = table(&merged);
        assert!(
            table
                .lines()
                .any(|l| l.starts_with("all") && l.contains(" 4 ")),
            "{table}"
        );
        let other = parse(&[row(5, 1, "mixed", 0)]);
        assert_eq!(
            merge(vec![("b".into(), b), ("o".into(), other)]),
            Err(SuiteCsvError::Seeds { a: 4, b: 5 })
        );
        assert_eq!(merge(vec![]), Err(SuiteCsvError::Empty));
    }

    #[test]
    fn a_bad_row_or_header_names_the_file_and_line() {
        let text = format!("{HEADER}\n{}\n1,2,3\n", row(1, 0, "mixed", 0));
        match parse_csv("s.csv", &text, HEADER) {
            Err(SuiteCsvError::Row { file, line, .. }) => {
                assert_eq!((file.as_str(), line), ("s.csv", 3))
            }
            other => panic!("{other:?}"),
        }
        let text = format!("{HEADER}\n{}\n", row(1, 0, "bright", 0));
        assert!(matches!(
            parse_csv("s.csv", &text, HEADER),
            Err(SuiteCsvError::Row { line: 2, .. })
        ));
        assert!(matches!(
            parse_csv("s.csv", "seed,room\n", HEADER),
            Err(SuiteCsvError::Header { .. })
        ));
    }
}
