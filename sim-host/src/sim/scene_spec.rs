//! Scene files: the TOML format a user writes a room in (documented in `docs/scenes.md`), its
//! validation, and the presets shipped with sim-host (`sim-host/scenes/*.toml`).
//!
//! A [`SceneSpec`] is plain data: it says what the room looks like, not how its textures come
//! out for a given seed; [`super::scene::Scene::build`] turns it into a renderable scene.
//! Every problem found in a file is a [`SceneError`] that names the file, the key and the
//! problem.

use serde::Deserialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// The presets shipped with sim-host, `(name, TOML text)`; `--scenario NAME` picks one.
pub const PRESET_FILES: &[(&str, &str)] = &[
    ("room", include_str!("../../scenes/room.toml")),
    (
        "room-obstacles",
        include_str!("../../scenes/room-obstacles.toml"),
    ),
    ("corridor", include_str!("../../scenes/corridor.toml")),
    ("plain-room", include_str!("../../scenes/plain-room.toml")),
    ("office", include_str!("../../scenes/office.toml")),
];

/// Smallest and largest room side, m.
pub const ROOM_SIDE_M: (f32, f32) = (1.0, 50.0);
/// Lowest and highest ceiling, m.
pub const ROOM_HEIGHT_M: (f32, f32) = (1.0, 10.0);
/// Range of `light` (relative to the default lighting).
pub const LIGHT_RANGE: (f32, f32) = (0.01, 10.0);
/// Largest `contrast` (relative to a texture's default).
pub const MAX_CONTRAST: f32 = 5.0;

/// A problem with a scene file: which file, which key, what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SceneError {
    /// The file (or `preset NAME`).
    pub file: String,
    /// The key, as a dotted path (`walls.north.albedo`, `obstacles[1].radius`), or the line
    /// of a syntax error.
    pub key: String,
    /// What is wrong.
    pub problem: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "scene file {}: key `{}`: {}",
            self.file, self.key, self.problem
        )
    }
}

impl std::error::Error for SceneError {}

/// How a surface is painted. Walls and obstacles take `plain`, `stripes`, `posters`, `bricks`,
/// `wood` and `image`; the floor `tiles`, `plain`, `carpet` and `image`; the ceiling `lamps`,
/// `plain` and `image`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TextureKind {
    /// One grey (with the room's gentle illumination gradient).
    Plain,
    /// Vertical stripes of random width and grey.
    Stripes,
    /// Stripes with rectangular posters of finer stripes on them.
    Posters,
    /// Brickwork: 24 x 7 cm bricks in offset courses, 1 cm mortar joints.
    Bricks,
    /// Vertical wooden planks (9-20 cm) with seams and a faint grain.
    Wood,
    /// 30 cm floor tiles of random grey with fine grain.
    Tiles,
    /// Carpet: fine random grain with faint mottling, no edges.
    Carpet,
    /// Ceiling with rows of darker lamp fittings.
    Lamps,
    /// A grey picture (`image = "FILE"`) stretched over the surface.
    Image,
}

impl TextureKind {
    /// The name used in scene files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Plain => "plain",
            Self::Stripes => "stripes",
            Self::Posters => "posters",
            Self::Bricks => "bricks",
            Self::Wood => "wood",
            Self::Tiles => "tiles",
            Self::Carpet => "carpet",
            Self::Lamps => "lamps",
            Self::Image => "image",
        }
    }
}

/// Texture kinds a wall or an obstacle may have.
pub const WALL_TEXTURES: &[TextureKind] = &[
    TextureKind::Plain,
    TextureKind::Stripes,
    TextureKind::Posters,
    TextureKind::Bricks,
    TextureKind::Wood,
    TextureKind::Image,
];
/// Texture kinds the floor may have.
pub const FLOOR_TEXTURES: &[TextureKind] = &[
    TextureKind::Tiles,
    TextureKind::Plain,
    TextureKind::Carpet,
    TextureKind::Image,
];
/// Texture kinds the ceiling may have.
pub const CEILING_TEXTURES: &[TextureKind] =
    &[TextureKind::Lamps, TextureKind::Plain, TextureKind::Image];

/// The texture keys of one surface as written (absent keys fall back to the defaults).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SurfaceKeys {
    /// Texture kind.
    pub texture: Option<TextureKind>,
    /// Mean grey level (albedo), 0..=1.
    pub albedo: Option<f32>,
    /// Contrast relative to the texture's default (0: flat).
    pub contrast: Option<f32>,
    /// Picture for `texture = "image"` (relative to the scene file's directory).
    pub image: Option<PathBuf>,
    /// Walls only: skirting board and ceiling trim (10 cm bands), default on.
    pub trim: Option<bool>,
}

impl SurfaceKeys {
    /// `self` with the keys it lacks taken from `base`.
    fn over(&self, base: &SurfaceKeys) -> SurfaceKeys {
        SurfaceKeys {
            texture: self.texture.or(base.texture),
            albedo: self.albedo.or(base.albedo),
            contrast: self.contrast.or(base.contrast),
            image: self.image.clone().or_else(|| base.image.clone()),
            trim: self.trim.or(base.trim),
        }
    }
}

/// `[walls]`: defaults for all four walls and per-wall overrides.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallsKeys {
    /// Texture kind of every wall without its own.
    pub texture: Option<TextureKind>,
    /// Mean grey level, 0..=1.
    pub albedo: Option<f32>,
    /// Contrast relative to the texture's default.
    pub contrast: Option<f32>,
    /// Picture for `texture = "image"`.
    pub image: Option<PathBuf>,
    /// Skirting board and ceiling trim.
    pub trim: Option<bool>,
    /// The wall at x = size_x.
    pub north: Option<SurfaceKeys>,
    /// The wall at x = 0.
    pub south: Option<SurfaceKeys>,
    /// The wall at y = size_y.
    pub east: Option<SurfaceKeys>,
    /// The wall at y = 0.
    pub west: Option<SurfaceKeys>,
}

/// `start = { x, y, yaw_deg }`.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartKeys {
    /// North, m.
    pub x: f32,
    /// East, m.
    pub y: f32,
    /// Heading, degrees from north towards east; absent: a heading drawn from the seed.
    pub yaw_deg: Option<f32>,
}

/// One `[[obstacles]]` entry as written.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleKeys {
    /// `cylinder`, `panel` or `box`.
    pub kind: String,
    /// Cylinder centre north, m.
    pub x: Option<f32>,
    /// Cylinder centre east, m.
    pub y: Option<f32>,
    /// Cylinder radius, m.
    pub radius: Option<f32>,
    /// Panel end (x, y), m.
    pub a: Option<[f32; 2]>,
    /// Panel end (x, y), m.
    pub b: Option<[f32; 2]>,
    /// Box corner with the smallest x and y, m.
    pub min: Option<[f32; 2]>,
    /// Box corner with the largest x and y, m.
    pub max: Option<[f32; 2]>,
    /// Height above the floor, m.
    pub height: f32,
    /// Texture kind (default `plain`).
    pub texture: Option<TextureKind>,
    /// Mean grey level, 0..=1.
    pub albedo: Option<f32>,
    /// Contrast relative to the texture's default.
    pub contrast: Option<f32>,
    /// Picture for `texture = "image"`.
    pub image: Option<PathBuf>,
}

/// A scene file as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// Name of the room.
    pub name: String,
    /// x (north) extent, y (east) extent, ceiling height, m.
    pub size_m: [f32; 3],
    /// Start pose; absent: the centre and a seeded heading.
    pub start: Option<StartKeys>,
    /// Brightness relative to the default lighting (0.1: dim).
    pub light: Option<f32>,
    /// Walls.
    #[serde(default)]
    pub walls: WallsKeys,
    /// Floor.
    #[serde(default)]
    pub floor: SurfaceKeys,
    /// Ceiling.
    #[serde(default)]
    pub ceiling: SurfaceKeys,
    /// Obstacles standing on the floor.
    #[serde(default)]
    pub obstacles: Vec<ObstacleKeys>,
}

/// How one surface is painted, resolved (every key has a value).
#[derive(Debug, Clone, PartialEq)]
pub struct Surface {
    /// Texture kind.
    pub texture: TextureKind,
    /// Mean grey level, 0..=1.
    pub albedo: f32,
    /// Contrast relative to the texture's default.
    pub contrast: f32,
    /// Picture (an absolute or working-directory-relative path) for [`TextureKind::Image`].
    pub image: Option<PathBuf>,
    /// Skirting board and ceiling trim (walls).
    pub trim: bool,
}

impl Surface {
    /// A surface of `texture` with its default albedo and contrast.
    pub fn of(texture: TextureKind) -> Self {
        Self {
            texture,
            albedo: default_albedo(texture),
            contrast: 1.0,
            image: None,
            trim: true,
        }
    }
}

/// The mean grey level a texture kind has when `albedo` is absent.
pub fn default_albedo(kind: TextureKind) -> f32 {
    match kind {
        TextureKind::Plain => 0.6,
        TextureKind::Stripes | TextureKind::Posters => 0.525,
        TextureKind::Bricks => 0.5,
        TextureKind::Wood => 0.45,
        TextureKind::Tiles => 0.5,
        TextureKind::Carpet => 0.4,
        TextureKind::Lamps => 0.75,
        // The picture's own mean (resolved when the picture is loaded).
        TextureKind::Image => f32::NAN,
    }
}

/// An obstacle's shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// A vertical cylinder: centre (x, y) and radius, m.
    Cylinder {
        /// Centre (x, y), m.
        centre: [f32; 2],
        /// Radius, m.
        radius: f32,
    },
    /// A thin vertical panel from `a` to `b` (x, y), m, seen from both sides.
    Panel {
        /// First end, m.
        a: [f32; 2],
        /// Second end, m.
        b: [f32; 2],
    },
    /// An axis-aligned box from `min` to `max` (x, y), m.
    Box {
        /// Corner with the smallest x and y, m.
        min: [f32; 2],
        /// Corner with the largest x and y, m.
        max: [f32; 2],
    },
}

impl Shape {
    /// Signed horizontal distance from `(x, y)` to the shape's surface, m (negative inside).
    pub fn distance(&self, x: f32, y: f32) -> f32 {
        match self {
            Self::Cylinder { centre, radius } => (x - centre[0]).hypot(y - centre[1]) - radius,
            Self::Panel { a, b } => {
                let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                let l2 = (ex * ex + ey * ey).max(1e-12);
                let u = (((x - a[0]) * ex + (y - a[1]) * ey) / l2).clamp(0.0, 1.0);
                (x - a[0] - u * ex).hypot(y - a[1] - u * ey)
            }
            Self::Box { min, max } => {
                let dx = (min[0] - x).max(x - max[0]);
                let dy = (min[1] - y).max(y - max[1]);
                if dx <= 0.0 && dy <= 0.0 {
                    dx.max(dy)
                } else {
                    dx.max(0.0).hypot(dy.max(0.0))
                }
            }
        }
    }
}

/// Horizontal clearance from `(x, y)` at height `h` to the walls of a room of `size` and to
/// the given obstacles that reach above `h`, m.
pub fn clearance_of(size: &[f32; 3], obstacles: &[ObstacleSpec], x: f32, y: f32, h: f32) -> f32 {
    let walls = x.min(size[0] - x).min(y).min(size[1] - y);
    obstacles
        .iter()
        .filter(|o| h <= o.height)
        .map(|o| o.shape.distance(x, y))
        .fold(walls, f32::min)
}

/// One obstacle, resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct ObstacleSpec {
    /// Footprint.
    pub shape: Shape,
    /// Height above the floor, m.
    pub height: f32,
    /// Paint.
    pub surface: Surface,
}

/// A room, resolved and validated: what [`super::scene::Scene::build`] builds from.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneSpec {
    /// Name.
    pub name: String,
    /// x (north), y (east) extent and ceiling height, m.
    pub size_m: [f32; 3],
    /// Start position (x, y), m.
    pub start_xy: [f32; 2],
    /// Start heading, rad; `None`: drawn from the flight's seed.
    pub start_yaw_rad: Option<f32>,
    /// Brightness relative to the default lighting.
    pub light: f32,
    /// Walls: south (x = 0), north (x = size_x), west (y = 0), east (y = size_y).
    pub walls: [Surface; 4],
    /// Floor.
    pub floor: Surface,
    /// Ceiling.
    pub ceiling: Surface,
    /// Obstacles.
    pub obstacles: Vec<ObstacleSpec>,
}

/// Index of each wall in [`SceneSpec::walls`] and its name in scene files.
pub const WALL_NAMES: [&str; 4] = ["south", "north", "west", "east"];

/// The clearance a start position needs from every wall and obstacle, m (the drone's radius
/// with a margin).
pub const START_CLEARANCE_M: f32 = 0.15;

impl SceneSpec {
    /// Reads and validates a scene file. Pictures are found relative to the file's directory.
    pub fn load(path: &Path) -> Result<Self, SceneError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| SceneError {
            file: file.clone(),
            key: "(file)".into(),
            problem: format!("cannot read it: {e}"),
        })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        Self::parse(&text, &file, dir)
    }

    /// A preset by name (see [`PRESET_FILES`]).
    pub fn preset(name: &str) -> Option<Self> {
        let (_, text) = PRESET_FILES.iter().find(|(n, _)| *n == name)?;
        Some(
            Self::parse(text, &format!("preset {name}"), Path::new("."))
                .expect("shipped presets are valid (tested)"),
        )
    }

    /// The preset names.
    pub fn preset_names() -> Vec<&'static str> {
        PRESET_FILES.iter().map(|(n, _)| *n).collect()
    }

    /// `--scene FILE.toml` or `--scenario NAME`: a file if `scene` is given, else the preset.
    pub fn from_cli(scene: Option<&Path>, scenario: &str) -> anyhow::Result<Self> {
        match scene {
            Some(p) => Ok(Self::load(p)?),
            None => Self::preset(scenario).ok_or_else(|| {
                anyhow::anyhow!(
                    "unknown --scenario {scenario:?} (one of {:?}; or --scene FILE.toml)",
                    Self::preset_names()
                )
            }),
        }
    }

    /// Parses and validates scene-file text; `file` names it in errors, `dir` is where its
    /// pictures are.
    pub fn parse(text: &str, file: &str, dir: &Path) -> Result<Self, SceneError> {
        let raw: SceneFile = toml::from_str(text).map_err(|e| syntax_error(&e, text, file))?;
        resolve(raw, file, dir)
    }
}

/// A TOML or type error: the key from the message if it names one, else the line.
fn syntax_error(e: &toml::de::Error, text: &str, file: &str) -> SceneError {
    let msg = e.message().trim().to_string();
    let (line_no, line) = match e.span() {
        Some(span) => {
            let start = span.start.min(text.len());
            let line_no = text[..start].matches('\n').count() + 1;
            let line = text.lines().nth(line_no - 1).unwrap_or("").trim();
            (line_no, line.to_string())
        }
        None => (0, String::new()),
    };
    // "unknown field `x`" and "missing field `x`" name the key; otherwise the key is on the
    // line the error points at (`albedo = "grey"`) or it is the table header there.
    let named = msg
        .split('`')
        .nth(1)
        .filter(|_| msg.starts_with("unknown field") || msg.starts_with("missing field"));
    let key = match named {
        Some(k) => k.to_string(),
        None => match line.split_once('=') {
            Some((k, _)) => k.trim().to_string(),
            None if !line.is_empty() => line.clone(),
            None => "(file)".into(),
        },
    };
    let at = if line_no > 0 {
        format!(" (line {line_no}: {line})")
    } else {
        String::new()
    };
    SceneError {
        file: file.to_string(),
        key,
        problem: format!("{msg}{at}"),
    }
}

fn resolve(raw: SceneFile, file: &str, dir: &Path) -> Result<SceneSpec, SceneError> {
    let err = |key: &str, problem: String| SceneError {
        file: file.to_string(),
        key: key.to_string(),
        problem,
    };
    let [sx, sy, sh] = raw.size_m;
    for (v, axis) in [(sx, "x"), (sy, "y")] {
        if !(v.is_finite() && (ROOM_SIDE_M.0..=ROOM_SIDE_M.1).contains(&v)) {
            return Err(err(
                "size_m",
                format!(
                    "the {axis} side must be {} to {} m, got {v}",
                    ROOM_SIDE_M.0, ROOM_SIDE_M.1
                ),
            ));
        }
    }
    if !(sh.is_finite() && (ROOM_HEIGHT_M.0..=ROOM_HEIGHT_M.1).contains(&sh)) {
        return Err(err(
            "size_m",
            format!(
                "the ceiling height must be {} to {} m, got {sh}",
                ROOM_HEIGHT_M.0, ROOM_HEIGHT_M.1
            ),
        ));
    }
    if raw.name.trim().is_empty() {
        return Err(err("name", "must not be empty".into()));
    }
    let light = raw.light.unwrap_or(1.0);
    if !(light.is_finite() && (LIGHT_RANGE.0..=LIGHT_RANGE.1).contains(&light)) {
        return Err(err(
            "light",
            format!(
                "must be {} to {} (1 = the default lighting), got {light}",
                LIGHT_RANGE.0, LIGHT_RANGE.1
            ),
        ));
    }

    let base = SurfaceKeys {
        texture: raw.walls.texture,
        albedo: raw.walls.albedo,
        contrast: raw.walls.contrast,
        image: raw.walls.image.clone(),
        trim: raw.walls.trim,
    };
    let overrides = [
        &raw.walls.south,
        &raw.walls.north,
        &raw.walls.west,
        &raw.walls.east,
    ];
    let mut walls = Vec::with_capacity(4);
    for (name, o) in WALL_NAMES.iter().zip(overrides) {
        let keys = match o {
            Some(o) => o.over(&base),
            None => base.clone(),
        };
        let key = if o.is_some() {
            format!("walls.{name}")
        } else {
            "walls".to_string()
        };
        walls.push(surface(
            &keys,
            TextureKind::Plain,
            WALL_TEXTURES,
            &key,
            file,
            dir,
        )?);
    }
    let walls: [Surface; 4] = walls.try_into().expect("four walls");
    let floor = surface(
        &raw.floor,
        TextureKind::Tiles,
        FLOOR_TEXTURES,
        "floor",
        file,
        dir,
    )?;
    let ceiling = surface(
        &raw.ceiling,
        TextureKind::Lamps,
        CEILING_TEXTURES,
        "ceiling",
        file,
        dir,
    )?;
    if raw.floor.trim.is_some() {
        return Err(err("floor.trim", "only walls have a trim".into()));
    }
    if raw.ceiling.trim.is_some() {
        return Err(err("ceiling.trim", "only walls have a trim".into()));
    }

    let mut obstacles = Vec::new();
    for (i, o) in raw.obstacles.iter().enumerate() {
        obstacles.push(obstacle(o, i, [sx, sy, sh], file, dir)?);
    }

    let (start_xy, start_yaw_rad) = match raw.start {
        Some(s) => {
            if let Some(y) = s.yaw_deg {
                if !y.is_finite() {
                    return Err(err("start.yaw_deg", format!("must be finite, got {y}")));
                }
            }
            ([s.x, s.y], s.yaw_deg.map(f32::to_radians))
        }
        None => ([sx * 0.5, sy * 0.5], None),
    };
    let spec = SceneSpec {
        name: raw.name,
        size_m: [sx, sy, sh],
        start_xy,
        start_yaw_rad,
        light,
        walls,
        floor,
        ceiling,
        obstacles,
    };
    let [x, y] = spec.start_xy;
    let inside = x.is_finite() && y.is_finite() && x > 0.0 && y > 0.0 && x < sx && y < sy;
    let clear =
        inside && clearance_of(&spec.size_m, &spec.obstacles, x, y, 0.05) >= START_CLEARANCE_M;
    if !clear {
        return Err(err(
            "start",
            format!(
                "({x}, {y}) must be inside the room and at least {START_CLEARANCE_M} m from \
                 every wall and obstacle"
            ),
        ));
    }
    Ok(spec)
}

fn surface(
    keys: &SurfaceKeys,
    default: TextureKind,
    allowed: &[TextureKind],
    key: &str,
    file: &str,
    dir: &Path,
) -> Result<Surface, SceneError> {
    let err = |k: &str, problem: String| SceneError {
        file: file.to_string(),
        key: format!("{key}.{k}"),
        problem,
    };
    let texture = keys.texture.unwrap_or(default);
    if !allowed.contains(&texture) {
        let names: Vec<&str> = allowed.iter().map(|k| k.name()).collect();
        return Err(err(
            "texture",
            format!(
                "`{}` is not allowed here (one of {})",
                texture.name(),
                names.join(" | ")
            ),
        ));
    }
    let contrast = keys.contrast.unwrap_or(1.0);
    if !(contrast.is_finite() && (0.0..=MAX_CONTRAST).contains(&contrast)) {
        return Err(err(
            "contrast",
            format!("must be 0 to {MAX_CONTRAST}, got {contrast}"),
        ));
    }
    if let Some(a) = keys.albedo {
        if !(a.is_finite() && (0.0..=1.0).contains(&a)) {
            return Err(err("albedo", format!("must be 0 to 1, got {a}")));
        }
    }
    let image = match (&keys.image, texture) {
        (Some(p), TextureKind::Image) => {
            let p = dir.join(p);
            super::picture::GreyImage::load(&p).map_err(|e| err("image", e))?;
            Some(p)
        }
        (None, TextureKind::Image) => {
            return Err(err(
                "image",
                "texture = \"image\" needs image = \"FILE\" (a picture)".into(),
            ))
        }
        (Some(_), _) => {
            return Err(err(
                "image",
                format!(
                    "only texture = \"image\" takes a picture (texture is `{}`)",
                    texture.name()
                ),
            ))
        }
        (None, _) => None,
    };
    Ok(Surface {
        texture,
        albedo: keys.albedo.unwrap_or(default_albedo(texture)),
        contrast,
        image,
        trim: keys.trim.unwrap_or(true),
    })
}

fn obstacle(
    o: &ObstacleKeys,
    i: usize,
    size: [f32; 3],
    file: &str,
    dir: &Path,
) -> Result<ObstacleSpec, SceneError> {
    let here = format!("obstacles[{i}]");
    let err = |k: &str, problem: String| SceneError {
        file: file.to_string(),
        key: format!("{here}.{k}"),
        problem,
    };
    let need = |v: Option<f32>, k: &str| {
        v.filter(|v| v.is_finite())
            .ok_or_else(|| err(k, format!("a {} needs a finite `{k}`", o.kind)))
    };
    let need2 = |v: Option<[f32; 2]>, k: &str| {
        v.filter(|v| v.iter().all(|c| c.is_finite()))
            .ok_or_else(|| err(k, format!("a {} needs `{k} = [x, y]`", o.kind)))
    };
    let refuse = |present: bool, k: &str| {
        if present {
            Err(err(k, format!("a {} has no `{k}`", o.kind)))
        } else {
            Ok(())
        }
    };
    let inside = |p: [f32; 2], k: &str| {
        if p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= size[0] && p[1] <= size[1] {
            Ok(())
        } else {
            Err(err(
                k,
                format!(
                    "({}, {}) is outside the {} x {} m room",
                    p[0], p[1], size[0], size[1]
                ),
            ))
        }
    };
    let shape = match o.kind.as_str() {
        "cylinder" => {
            refuse(o.a.is_some(), "a")?;
            refuse(o.b.is_some(), "b")?;
            refuse(o.min.is_some(), "min")?;
            refuse(o.max.is_some(), "max")?;
            let (x, y, r) = (need(o.x, "x")?, need(o.y, "y")?, need(o.radius, "radius")?);
            if !(0.01..=5.0).contains(&r) {
                return Err(err("radius", format!("must be 0.01 to 5 m, got {r}")));
            }
            inside([x, y], "x")?;
            Shape::Cylinder {
                centre: [x, y],
                radius: r,
            }
        }
        "panel" => {
            refuse(o.x.is_some(), "x")?;
            refuse(o.y.is_some(), "y")?;
            refuse(o.radius.is_some(), "radius")?;
            refuse(o.min.is_some(), "min")?;
            refuse(o.max.is_some(), "max")?;
            let (a, b) = (need2(o.a, "a")?, need2(o.b, "b")?);
            inside(a, "a")?;
            inside(b, "b")?;
            if (a[0] - b[0]).hypot(a[1] - b[1]) < 0.05 {
                return Err(err("b", "a panel must be at least 5 cm long".into()));
            }
            Shape::Panel { a, b }
        }
        "box" => {
            refuse(o.x.is_some(), "x")?;
            refuse(o.y.is_some(), "y")?;
            refuse(o.radius.is_some(), "radius")?;
            refuse(o.a.is_some(), "a")?;
            refuse(o.b.is_some(), "b")?;
            let (min, max) = (need2(o.min, "min")?, need2(o.max, "max")?);
            inside(min, "min")?;
            inside(max, "max")?;
            if !(max[0] - min[0] >= 0.02 && max[1] - min[1] >= 0.02) {
                return Err(err(
                    "max",
                    "must exceed `min` by at least 2 cm in x and in y".into(),
                ));
            }
            Shape::Box { min, max }
        }
        other => {
            return Err(err(
                "kind",
                format!("unknown obstacle kind {other:?} (cylinder | panel | box)"),
            ))
        }
    };
    if !(o.height.is_finite() && o.height > 0.0 && o.height <= size[2]) {
        return Err(err(
            "height",
            format!(
                "must be above 0 and at most the ceiling height {} m",
                size[2]
            ),
        ));
    }
    let keys = SurfaceKeys {
        texture: o.texture,
        albedo: o.albedo,
        contrast: o.contrast,
        image: o.image.clone(),
        trim: Some(false),
    };
    let surface = surface(&keys, TextureKind::Plain, WALL_TEXTURES, &here, file, dir)?;
    Ok(ObstacleSpec {
        shape,
        height: o.height,
        surface,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<SceneSpec, SceneError> {
        SceneSpec::parse(text, "test.toml", Path::new("."))
    }

    const MINIMAL: &str = "name = \"r\"\nsize_m = [5.0, 4.0, 2.6]\n";

    #[test]
    fn presets_parse_and_keep_their_rooms() {
        for name in SceneSpec::preset_names() {
            let s = SceneSpec::preset(name).unwrap();
            assert_eq!(s.name, name);
        }
        let room = SceneSpec::preset("room").unwrap();
        assert_eq!(room.size_m, [4.0, 4.0, 2.5]);
        assert_eq!(room.start_xy, [2.0, 2.0]);
        assert_eq!(room.start_yaw_rad, None);
        assert!(room.walls.iter().all(|w| w.texture == TextureKind::Posters));
        let corridor = SceneSpec::preset("corridor").unwrap();
        assert_eq!(corridor.start_yaw_rad, Some(0.0));
        assert_eq!(
            SceneSpec::preset("room-obstacles").unwrap().obstacles.len(),
            2
        );
        assert!(SceneSpec::preset("nope").is_none());
    }

    #[test]
    fn defaults_and_overrides() {
        let s = parse(&format!(
            "{MINIMAL}[walls]\ntexture = \"bricks\"\nalbedo = 0.4\n[walls.north]\n\
             texture = \"plain\"\n"
        ))
        .unwrap();
        assert_eq!(s.start_xy, [2.5, 2.0]);
        assert_eq!(s.light, 1.0);
        assert_eq!(s.walls[1].texture, TextureKind::Plain);
        assert_eq!(s.walls[1].albedo, 0.4, "north inherits the [walls] albedo");
        for w in [0, 2, 3] {
            assert_eq!(s.walls[w].texture, TextureKind::Bricks);
        }
        assert_eq!(s.floor.texture, TextureKind::Tiles);
        let plain = parse(MINIMAL).unwrap();
        assert!(plain.walls.iter().all(|w| w.texture == TextureKind::Plain));
    }

    /// Each bad file names the file, the key and the problem.
    #[test]
    fn bad_files_name_file_key_and_problem() {
        let cases: &[(&str, &str, &str)] = &[
            ("name = \"r\"\n", "size_m", "missing field"),
            (
                &format!("{MINIMAL}[walls]\ntexure = \"plain\"\n"),
                "texure",
                "unknown field",
            ),
            (
                &format!("{MINIMAL}[walls]\nalbedo = \"grey\"\n"),
                "albedo",
                "invalid type",
            ),
            (
                &format!("{MINIMAL}[walls.north]\nalbedo = 1.5\n"),
                "walls.north.albedo",
                "0 to 1",
            ),
            (
                &format!("{MINIMAL}[walls]\ntexture = \"marble\"\n"),
                "texture",
                "unknown variant",
            ),
            (
                &format!("{MINIMAL}[floor]\ntexture = \"bricks\"\n"),
                "floor.texture",
                "not allowed",
            ),
            (
                "name = \"r\"\nsize_m = [0.5, 4.0, 2.6]\n",
                "size_m",
                "x side",
            ),
            (&format!("{MINIMAL}light = -1.0\n"), "light", "0.01 to 10"),
            (
                &format!("{MINIMAL}start = {{ x = 9.0, y = 1.0 }}\n"),
                "start",
                "inside the room",
            ),
            (
                &format!(
                    "{MINIMAL}[[obstacles]]\nkind = \"cylinder\"\nx = 1.0\nheight = 2.0\n\
                     radius = 0.2\n"
                ),
                "obstacles[0].y",
                "needs",
            ),
            (
                &format!("{MINIMAL}[[obstacles]]\nkind = \"cone\"\nheight = 1.0\n"),
                "obstacles[0].kind",
                "unknown obstacle kind",
            ),
            (
                &format!(
                    "{MINIMAL}[[obstacles]]\nkind = \"box\"\nmin = [1.0, 1.0]\n\
                     max = [1.5, 9.0]\nheight = 1.0\n"
                ),
                "obstacles[0].max",
                "outside",
            ),
            (
                &format!(
                    "{MINIMAL}[[obstacles]]\nkind = \"panel\"\na = [1.0, 1.0]\n\
                     b = [2.0, 1.0]\nheight = 1.0\nradius = 0.1\n"
                ),
                "obstacles[0].radius",
                "has no",
            ),
            (
                &format!("{MINIMAL}[walls]\ntexture = \"image\"\n"),
                "walls.image",
                "needs image",
            ),
            (
                &format!("{MINIMAL}[walls]\ntexture = \"image\"\nimage = \"no-such.png\"\n"),
                "walls.image",
                "no-such.png",
            ),
            (
                &format!(
                    "{MINIMAL}[[obstacles]]\nkind = \"cylinder\"\nx = 2.5\ny = 2.0\n\
                     radius = 0.3\nheight = 2.0\n"
                ),
                "start",
                "from every wall and obstacle",
            ),
            ("name = \"r\"\nsize_m = [5.0, 4.0\n", "size_m", "line 2"),
        ];
        for (text, key, problem) in cases {
            let e = parse(text).expect_err(text);
            let shown = e.to_string();
            assert!(shown.contains("test.toml"), "{shown}");
            assert_eq!(e.key, *key, "{shown}");
            assert!(shown.contains(problem), "{shown}");
        }
    }

    #[test]
    fn load_names_a_missing_file() {
        let e = SceneSpec::load(Path::new("/nonexistent/room.toml")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/room.toml"), "{e}");
        assert!(e.to_string().contains("cannot read"), "{e}");
    }
}
