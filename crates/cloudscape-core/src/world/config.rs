//! The TOML configuration: parsing, validation and world lookup.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Read;

use serde::Deserialize;

use super::authored::{Area, Front, Influence, Polygon, Shape, Storm};
use super::clock::WorldClock;
use super::warm::{DEFAULT_WARM_PRODUCTS, DEFAULT_WARM_QUALITY, Margin, WarmArea};
use super::{Ellipsoid, EpochSpec, FieldSpec, Layer, MAX_TIME, Preset, World};

/// The embedded default configuration, the text of `config/default.toml`: the one
/// place it is compiled in (the binary, benches, examples and tests all read this).
pub const DEFAULT_CONFIG: &str = include_str!("../../../../config/default.toml");

/// A configuration that could not be used. The message names the offending key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The config file cannot be read.
    #[error("cannot read config file {path}: {source}")]
    Read {
        /// The file's path.
        path: String,
        /// Why it cannot be read.
        source: std::io::Error,
    },
    /// The TOML does not parse (the message says where).
    #[error("invalid config: {0}")]
    Parse(String),
    /// A value is invalid.
    #[error("invalid config: {key}: {message}")]
    Invalid {
        /// The offending key, dotted (e.g. `sun.day_of_year`).
        key: String,
        /// What is wrong with its value.
        message: String,
    },
}

impl ConfigError {
    /// A value that parsed but is not allowed: `key` is its dotted path.
    pub fn invalid(key: impl Into<String>, message: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            key: key.into(),
            message: message.into(),
        }
    }

    /// TOML `text` that does not parse, as one line: where (line, column and the
    /// line's first 60 characters) and why. Not toml's own display, which quotes the
    /// offending line whole (a 1 MiB line of brackets, for one) over several lines.
    pub fn toml(text: &str, e: &toml::de::Error) -> ConfigError {
        let reason: String = e.message().trim().replace('\n', " ").chars().take(300).collect();
        let Some((before, _)) = e.span().and_then(|span| text.split_at_checked(span.start)) else {
            return ConfigError::Parse(reason);
        };
        let line = before.matches('\n').count() + 1;
        let start = before.rsplit('\n').next().unwrap_or("");
        let column = start.chars().count() + 1;
        let whole = text.lines().nth(line - 1).unwrap_or("").trim();
        let mut shown: String = whole.chars().take(60).collect();
        if whole.chars().nth(60).is_some() {
            shown.push('…');
        }
        ConfigError::Parse(format!("line {line}, column {column} (`{shown}`): {reason}"))
    }
}

/// The largest config file read, bytes: 80 times the embedded config. A larger file
/// (or a device such as /dev/zero) is refused after this many bytes, not read whole.
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// The text of the config file `path`, read up to [`MAX_CONFIG_BYTES`] (refused
/// beyond). Pipes and process substitution (`--config <(…)`) work; a device that
/// never ends is refused once the limit is read.
pub fn read_config_text(path: &str) -> Result<String, ConfigError> {
    let failed = |source: std::io::Error| ConfigError::Read {
        path: path.to_string(),
        source,
    };
    let too_large = || {
        failed(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "it is larger than {} KiB, the most a config may be",
                MAX_CONFIG_BYTES >> 10
            ),
        ))
    };
    let file = std::fs::File::open(path).map_err(failed)?;
    if file.metadata().is_ok_and(|m| m.is_file() && m.len() > MAX_CONFIG_BYTES) {
        return Err(too_large());
    }
    let mut bytes = Vec::new();
    file.take(MAX_CONFIG_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(failed)?;
    if bytes.len() as u64 > MAX_CONFIG_BYTES {
        return Err(too_large());
    }
    String::from_utf8(bytes).map_err(|_| {
        failed(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "it is not UTF-8 text",
        ))
    })
}

/// The most entries of each list a config may hold, checked before any entry is
/// looked at: enough for any world we can imagine, few enough that checking them (and
/// evaluating the authored weather in every cell) stays cheap.
mod most {
    /// `[worlds.NAME]` tables.
    pub const WORLDS: usize = 1024;
    /// `[presets.NAME]` tables.
    pub const PRESETS: usize = 1024;
    /// Layers of one world.
    pub const LAYERS: usize = 64;
    /// Events and regions of one world together (each is evaluated in every cell of
    /// the layers it drives).
    pub const AUTHORED: usize = 256;
    /// Points of a storm's path.
    pub const PATH_POINTS: usize = 1024;
    /// Ellipsoids of one layer.
    pub const ELLIPSOIDS: usize = 1024;
    /// Play areas of one world kept warm.
    pub const WARM_AREAS: usize = 4096;
}

/// Refuses a list at `key` of `len` entries over `max`.
fn at_most(key: &str, len: usize, max: usize, what: &str) -> Result<(), ConfigError> {
    if len > max {
        return Err(invalid(key, format!("has {len} {what}; the most is {max}")));
    }
    Ok(())
}

fn invalid(key: impl Into<String>, message: impl Into<String>) -> ConfigError {
    ConfigError::invalid(key, message)
}

/// Request limits, checked before any work starts.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Largest region side in columns.
    pub max_columns: u64,
    /// Largest number of cells (columns × depth) one request may produce.
    pub max_cells: u64,
    /// Highest level.
    pub max_level: u32,
    /// Largest estimated working memory of one request, bytes (grids, metaballs,
    /// images it will allocate); a request over it is refused with 413.
    #[serde(default = "default_max_request_bytes")]
    pub max_request_bytes: u64,
    /// Largest response body, bytes; a request whose answer is larger gets 413
    /// (billboards.json points to billboards.bin).
    #[serde(default = "default_max_response_bytes")]
    pub max_response_bytes: u64,
    /// Largest samples per pixel × pixels of one `reference` (path-traced) render.
    #[serde(default = "default_max_path_samples")]
    pub max_path_samples: u64,
}

fn default_max_request_bytes() -> u64 {
    2 << 30
}

fn default_max_response_bytes() -> u64 {
    64 << 20
}

/// 640×360 pixels at 64 samples, and a little more: about a minute on two cores.
fn default_max_path_samples() -> u64 {
    1 << 24
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_columns: 2048,
            max_cells: 8 << 20,
            max_level: 16,
            max_request_bytes: default_max_request_bytes(),
            max_response_bytes: default_max_response_bytes(),
            max_path_samples: default_max_path_samples(),
        }
    }
}

impl Limits {
    /// Checks each limit against the range the machine's arithmetic and the request
    /// paths hold: positive, and no larger than the bounds below (whatever the memory,
    /// `max_request_bytes` refuses the requests that would not fit it).
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (key, value, least, most) in [
            ("limits.max_columns", self.max_columns, 1, 1 << 24),
            ("limits.max_cells", self.max_cells, 1, 1 << 40),
            ("limits.max_level", self.max_level as u64, 0, 40),
            ("limits.max_request_bytes", self.max_request_bytes, 1 << 20, 1 << 44),
            ("limits.max_response_bytes", self.max_response_bytes, 1 << 10, 1 << 40),
            ("limits.max_path_samples", self.max_path_samples, 1, 1 << 40),
        ] {
            if !(least..=most).contains(&value) {
                return Err(invalid(key, format!("must be within [{least}, {most}], got {value}")));
            }
        }
        Ok(())
    }
}

/// Where the sun is when a request does not say.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SunConfig {
    /// Latitude of the world clock's sun, degrees (north positive).
    pub latitude: f64,
    /// Day of the year (1..=366) of the world clock's sun.
    pub day_of_year: u32,
}

impl Default for SunConfig {
    fn default() -> Self {
        SunConfig {
            latitude: 45.0,
            day_of_year: 172,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    /// `[server]` belongs to cloudscape-server (`cloudscape_server::ServerConfig`
    /// parses and validates it from the same text); here it is only allowed.
    #[serde(default, rename = "server")]
    _server: serde::de::IgnoredAny,
    #[serde(default)]
    limits: Limits,
    #[serde(default)]
    sun: SunConfig,
    presets: BTreeMap<String, Preset>,
    worlds: BTreeMap<String, RawWorld>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWorld {
    seed: u64,
    #[serde(default = "default_freezing_level")]
    freezing_level: f64,
    layers: Vec<RawLayer>,
    #[serde(default)]
    events: Vec<RawEvent>,
    #[serde(default)]
    regions: Vec<RawRegion>,
    /// `[worlds.NAME.clock]`: how world time follows real time (`world::clock`).
    #[serde(default)]
    clock: WorldClock,
    /// `[[worlds.NAME.warm]]`: play areas kept warm (`world::warm`).
    #[serde(default)]
    warm: Vec<RawWarm>,
}

/// `[[worlds.NAME.warm]]`: a play area the server keeps warm.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawWarm {
    name: String,
    bbox: Option<[f64; 4]>,
    polygon: Option<Vec<[f64; 2]>>,
    /// Metres, or `"view"`.
    margin: Option<toml::Value>,
    #[serde(default = "default_warm_levels")]
    levels: Vec<u32>,
    products: Option<Vec<String>>,
    qualities: Option<Vec<String>>,
    layers: Option<Vec<String>>,
}

fn default_warm_levels() -> Vec<u32> {
    vec![0]
}

/// `[[worlds.NAME.events]]`: a storm or a front (see `world::authored`).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEvent {
    kind: String,
    preset: String,
    start: Option<f64>,
    end: Option<f64>,
    #[serde(default = "default_ramp")]
    ramp: f64,
    #[serde(default = "default_intensity")]
    intensity: f64,
    // Storm.
    centre: Option<[f64; 3]>,
    radii: Option<[f64; 3]>,
    velocity: Option<[f64; 2]>,
    path: Option<Vec<[f64; 3]>>,
    // Front.
    origin: Option<[f64; 2]>,
    width: Option<f64>,
    #[serde(default)]
    behind: f64,
    length: Option<f64>,
}

/// `[[worlds.NAME.regions]]`: a regional override of the preset mix.
#[derive(Deserialize)]
#[serde(deny_unknown_fields, rename_all = "snake_case")]
struct RawRegion {
    #[serde(rename = "box")]
    bbox: Option<[f64; 4]>,
    polygon: Option<Vec<[f64; 2]>>,
    #[serde(default = "default_blend")]
    blend: f64,
    mix: BTreeMap<String, f64>,
    start: Option<f64>,
    end: Option<f64>,
    #[serde(default = "default_ramp")]
    ramp: f64,
}

fn default_ramp() -> f64 {
    600.0
}
fn default_intensity() -> f64 {
    1.0
}
fn default_blend() -> f64 {
    2000.0
}

/// Largest anvil radius in cells of its layer: the margin every field window of the
/// layer grows by on each side (`automaton::run`).
const MAX_ANVIL_CELLS: usize = 256;

/// Largest coordinate (metres) or speed (m/s) an authored event may name.
const MAX_AUTHORED: f64 = 1e9;

/// The freezing level of a world that does not set one, metres: a mid-latitude
/// summer's 0 °C isotherm.
pub const DEFAULT_FREEZING_LEVEL: f64 = 3000.0;

fn default_freezing_level() -> f64 {
    DEFAULT_FREEZING_LEVEL
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLayer {
    name: String,
    preset: String,
    base: f64,
    cell_size: f64,
    cell_height: f64,
    depth: u32,
    dt: f64,
    #[serde(default)]
    wind: [f64; 2],
    #[serde(default)]
    shear: [f64; 2],
    #[serde(default)]
    epoch: EpochSpec,
    #[serde(default)]
    extent: Option<[f64; 4]>,
    #[serde(default)]
    ellipsoids: Vec<Ellipsoid>,
}

/// The whole, validated configuration.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Config {
    /// Bounds on the work one request may cause.
    pub limits: Limits,
    /// The world clock's sun.
    pub sun: SunConfig,
    /// Cloud types by name.
    pub presets: BTreeMap<String, Preset>,
    /// Named worlds; `default` is always present.
    pub worlds: BTreeMap<String, World>,
}

impl Config {
    /// The embedded default configuration.
    pub fn embedded() -> Config {
        Config::parse(DEFAULT_CONFIG).expect("the embedded default config is valid")
    }

    /// Reads and validates a config file.
    pub fn from_file(path: &str) -> Result<Config, ConfigError> {
        Config::parse(&read_config_text(path)?)
    }

    /// Parses and validates TOML text.
    pub fn parse(text: &str) -> Result<Config, ConfigError> {
        // toml's message names the key ("unknown field `x`"), ours the place.
        let raw: RawConfig = toml::from_str(text).map_err(|e| ConfigError::toml(text, &e))?;
        at_most("worlds", raw.worlds.len(), most::WORLDS, "worlds")?;
        at_most("presets", raw.presets.len(), most::PRESETS, "presets")?;
        for (name, preset) in &raw.presets {
            validate_preset(&format!("presets.{name}"), preset)?;
        }
        let limits = raw.limits;
        limits.validate()?;
        if !(-90.0..=90.0).contains(&raw.sun.latitude) {
            return Err(invalid("sun.latitude", "must be within [-90, 90]"));
        }
        if !(1..=366).contains(&raw.sun.day_of_year) {
            return Err(invalid("sun.day_of_year", "must be within [1, 366]"));
        }
        let mut worlds = BTreeMap::new();
        for (wname, rw) in raw.worlds {
            if wname.is_empty() || wname.bytes().all(|b| b.is_ascii_digit()) {
                return Err(invalid(
                    format!("worlds.{wname}"),
                    "world names must not be decimal numbers (those mean seeds)",
                ));
            }
            if rw.layers.is_empty() {
                return Err(invalid(
                    format!("worlds.{wname}.layers"),
                    "a world needs at least one layer",
                ));
            }
            at_most(
                &format!("worlds.{wname}.layers"),
                rw.layers.len(),
                most::LAYERS,
                "layers",
            )?;
            at_most(
                &format!("worlds.{wname}.events"),
                rw.events.len() + rw.regions.len(),
                most::AUTHORED,
                "events and regions together",
            )?;
            at_most(
                &format!("worlds.{wname}.warm"),
                rw.warm.len(),
                most::WARM_AREAS,
                "play areas",
            )?;
            if !(rw.freezing_level.is_finite() && (-1e4..=1e5).contains(&rw.freezing_level)) {
                return Err(invalid(
                    format!("worlds.{wname}.freezing_level"),
                    "must be within [-1e4, 1e5] metres",
                ));
            }
            let mut layers = Vec::new();
            for (i, rl) in rw.layers.into_iter().enumerate() {
                let key = format!("worlds.{wname}.layers[{i}]");
                let preset = raw
                    .presets
                    .get(&rl.preset)
                    .ok_or_else(|| invalid(format!("{key}.preset"), format!("unknown preset `{}`", rl.preset)))?
                    .clone();
                if layers.iter().any(|l: &Layer| l.name == rl.name) {
                    return Err(invalid(
                        format!("{key}.name"),
                        format!("duplicate layer name `{}`", rl.name),
                    ));
                }
                let layer = Layer {
                    name: rl.name,
                    preset_name: rl.preset,
                    preset,
                    base: rl.base,
                    cell_size: rl.cell_size,
                    cell_height: rl.cell_height,
                    depth: rl.depth,
                    dt: rl.dt,
                    wind: rl.wind,
                    shear: rl.shear,
                    epoch: rl.epoch,
                    extent: rl.extent,
                    ellipsoids: rl.ellipsoids,
                    authored: Vec::new(),
                    freezing_level: rw.freezing_level,
                };
                validate_layer(&key, &layer)?;
                layers.push(layer);
            }
            let drives = |key: &str, preset: &str, layers: &[Layer]| {
                if layers.iter().any(|l| l.preset_name == preset) {
                    Ok(())
                } else {
                    Err(invalid(key, format!("no layer of this world places preset `{preset}`")))
                }
            };
            let mut authored = Vec::new();
            for (i, re) in rw.events.into_iter().enumerate() {
                let key = format!("worlds.{wname}.events[{i}]");
                drives(&format!("{key}.preset"), &re.preset, &layers)?;
                let preset = re.preset.clone();
                let influence = event(&key, re)?;
                for l in layers.iter_mut().filter(|l| l.preset_name == preset) {
                    l.authored.push(influence.clone());
                }
                authored.push((preset, influence));
            }
            for (i, rr) in rw.regions.into_iter().enumerate() {
                let key = format!("worlds.{wname}.regions[{i}]");
                for preset in rr.mix.keys() {
                    drives(&format!("{key}.mix.{preset}"), preset, &layers)?;
                }
                for (preset, influence) in region(&key, rr)? {
                    for l in layers.iter_mut().filter(|l| l.preset_name == preset) {
                        l.authored.push(influence.clone());
                    }
                    authored.push((preset, influence));
                }
            }
            if let Err((field, message)) = rw.clock.check() {
                return Err(invalid(format!("worlds.{wname}.clock.{field}"), message));
            }
            let mut warm: Vec<WarmArea> = Vec::new();
            let mut names = BTreeSet::new();
            for (i, rw) in rw.warm.into_iter().enumerate() {
                let key = format!("worlds.{wname}.warm[{i}]");
                let area = warm_area(&key, rw, &layers, &limits)?;
                if !names.insert(area.name.clone()) {
                    return Err(invalid(
                        format!("{key}.name"),
                        format!("duplicate play area name `{}`", area.name),
                    ));
                }
                warm.push(area);
            }
            worlds.insert(
                wname.clone(),
                World {
                    name: wname,
                    seed: rw.seed,
                    layers,
                    authored,
                    clock: rw.clock,
                    warm,
                },
            );
        }
        if !worlds.contains_key("default") {
            return Err(invalid("worlds.default", "the `default` world must be defined"));
        }
        Ok(Config {
            limits,
            sun: raw.sun,
            presets: raw.presets,
            worlds,
        })
    }

    /// Resolves a world name: a configured name, or a decimal `u64` meaning that
    /// seed with the default world's climate.
    pub fn world(&self, name: &str) -> Option<World> {
        if let Some(w) = self.worlds.get(name) {
            return Some(w.clone());
        }
        if !name.is_empty() && name.len() <= 20 && name.bytes().all(|b| b.is_ascii_digit()) {
            let seed: u64 = name.parse().ok()?;
            let mut w = self.worlds["default"].clone();
            w.name = name.to_string();
            w.seed = seed;
            // The default world's climate and clock, not its play areas: those are the
            // places of one configured world.
            w.warm.clear();
            return Some(w);
        }
        None
    }
}

fn finite(key: &str, v: f64) -> Result<(), ConfigError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(invalid(key, "must be a finite number"))
    }
}

fn bounded(key: &str, values: &[f64], max: f64, what: &str) -> Result<(), ConfigError> {
    if values.iter().all(|v| v.is_finite() && v.abs() <= max) {
        Ok(())
    } else {
        Err(invalid(key, format!("must be finite {what} within ±{max:e}")))
    }
}

/// The timing of an event or region: `start`, `end`, `ramp` and `intensity`, checked.
fn timing(
    key: &str,
    start: Option<f64>,
    end: Option<f64>,
    ramp: f64,
    intensity: f64,
    shape: Shape,
) -> Result<Influence, ConfigError> {
    if let Some(s) = start
        && !(s.is_finite() && (0.0..=MAX_TIME).contains(&s))
    {
        return Err(invalid(format!("{key}.start"), "must be within [0, 1e12] seconds"));
    }
    if let Some(e) = end
        && !(e.is_finite() && e > start.unwrap_or(0.0) && e <= MAX_TIME)
    {
        return Err(invalid(
            format!("{key}.end"),
            "must be after start and at most 1e12 seconds",
        ));
    }
    if !(ramp.is_finite() && (0.0..=MAX_TIME).contains(&ramp)) {
        return Err(invalid(format!("{key}.ramp"), "must be within [0, 1e12] seconds"));
    }
    if !(intensity.is_finite() && (-1.0..=1.0).contains(&intensity)) {
        return Err(invalid(format!("{key}.intensity"), "must be within [-1, 1]"));
    }
    Ok(Influence {
        shape,
        intensity,
        start,
        end,
        ramp,
    })
}

/// A checked `[[worlds.NAME.events]]` entry.
fn event(key: &str, e: RawEvent) -> Result<Influence, ConfigError> {
    // The shape fields given; each kind names those it requires and those it refuses
    // (it may take or leave the others).
    let given = [
        ("centre", e.centre.is_some()),
        ("radii", e.radii.is_some()),
        ("velocity", e.velocity.is_some()),
        ("path", e.path.is_some()),
        ("origin", e.origin.is_some()),
        ("width", e.width.is_some()),
        ("behind", e.behind != 0.0),
        ("length", e.length.is_some()),
    ];
    let fields = |required: &[&str], refused: &[&str]| {
        let is_given = |name: &str| given.iter().any(|&(n, present)| n == name && present);
        if let Some(name) = required.iter().find(|n| !is_given(n)) {
            return Err(invalid(
                format!("{key}.{name}"),
                format!("is required for a {}", e.kind),
            ));
        }
        if let Some(name) = refused.iter().find(|n| is_given(n)) {
            return Err(invalid(
                format!("{key}.{name}"),
                format!("does not apply to a {}", e.kind),
            ));
        }
        Ok(())
    };
    let shape = match e.kind.as_str() {
        "storm" => {
            fields(&["centre", "radii"], &["origin", "width", "length", "behind"])?;
            let (centre, radii) = (e.centre.unwrap_or_default(), e.radii.unwrap_or_default());
            bounded(&format!("{key}.centre"), &centre, MAX_AUTHORED, "metres")?;
            if !radii.iter().all(|r| r.is_finite() && *r >= 1.0 && *r <= MAX_AUTHORED) {
                return Err(invalid(format!("{key}.radii"), "must be within [1, 1e9] metres"));
            }
            let path = e.path.unwrap_or_default();
            at_most(&format!("{key}.path"), path.len(), most::PATH_POINTS, "points")?;
            if !path.is_empty() && e.velocity.is_some() {
                return Err(invalid(
                    format!("{key}.velocity"),
                    "give a path or a velocity, not both",
                ));
            }
            let velocity = e.velocity.unwrap_or_default();
            bounded(&format!("{key}.velocity"), &velocity, 1000.0, "m/s")?;
            for (j, p) in path.iter().enumerate() {
                bounded(&format!("{key}.path[{j}]"), &p[1..], MAX_AUTHORED, "metres")?;
                if !(p[0].is_finite() && (0.0..=MAX_TIME).contains(&p[0])) {
                    return Err(invalid(
                        format!("{key}.path[{j}]"),
                        "its time must be within [0, 1e12] seconds",
                    ));
                }
                if j > 0 && p[0] <= path[j - 1][0] {
                    return Err(invalid(format!("{key}.path[{j}]"), "times must ascend"));
                }
            }
            Shape::Storm(Storm {
                centre,
                radii,
                velocity,
                path,
            })
        }
        "front" => {
            fields(&["origin", "velocity", "width"], &["centre", "radii", "path"])?;
            let (origin, velocity, width) = (
                e.origin.unwrap_or_default(),
                e.velocity.unwrap_or_default(),
                e.width.unwrap_or_default(),
            );
            bounded(&format!("{key}.origin"), &origin, MAX_AUTHORED, "metres")?;
            bounded(&format!("{key}.velocity"), &velocity, 1000.0, "m/s")?;
            if velocity[0].hypot(velocity[1]) < 1e-3 {
                return Err(invalid(
                    format!("{key}.velocity"),
                    "a front must move (at least 1 mm/s): its line is perpendicular to its velocity",
                ));
            }
            if !(width.is_finite() && (1.0..=MAX_AUTHORED).contains(&width)) {
                return Err(invalid(format!("{key}.width"), "must be within [1, 1e9] metres"));
            }
            if !(e.behind.is_finite() && (-1.0..=1.0).contains(&e.behind)) {
                return Err(invalid(format!("{key}.behind"), "must be within [-1, 1]"));
            }
            if let Some(l) = e.length
                && !(l.is_finite() && (1.0..=MAX_AUTHORED).contains(&l))
            {
                return Err(invalid(format!("{key}.length"), "must be within [1, 1e9] metres"));
            }
            Shape::Front(Front {
                origin,
                velocity,
                width,
                behind: e.behind,
                length: e.length,
            })
        }
        other => {
            return Err(invalid(
                format!("{key}.kind"),
                format!("unknown kind `{other}` (storm or front)"),
            ));
        }
    };
    timing(key, e.start, e.end, e.ramp, e.intensity, shape)
}

/// A checked `[[worlds.NAME.regions]]` entry: one influence per preset of its mix.
fn region(key: &str, r: RawRegion) -> Result<Vec<(String, Influence)>, ConfigError> {
    let area = match (r.bbox, r.polygon) {
        (Some(b), None) => {
            bounded(&format!("{key}.box"), &b, MAX_AUTHORED, "metres")?;
            if !(b[0] < b[2] && b[1] < b[3]) {
                return Err(invalid(
                    format!("{key}.box"),
                    "must be [x0, y0, x1, y1] with x0 < x1, y0 < y1",
                ));
            }
            Area::Box(b)
        }
        (None, Some(p)) => {
            if !(3..=1024).contains(&p.len()) {
                return Err(invalid(format!("{key}.polygon"), "needs 3 to 1024 vertices"));
            }
            bounded(&format!("{key}.polygon"), p.as_flattened(), MAX_AUTHORED, "metres")?;
            Area::Polygon(Polygon::new(p))
        }
        _ => return Err(invalid(key, "needs exactly one of `box` and `polygon`")),
    };
    if !(r.blend.is_finite() && (0.0..=MAX_AUTHORED).contains(&r.blend)) {
        return Err(invalid(format!("{key}.blend"), "must be within [0, 1e9] metres"));
    }
    if r.mix.is_empty() {
        return Err(invalid(format!("{key}.mix"), "names no preset"));
    }
    let base = timing(key, r.start, r.end, r.ramp, 1.0, Shape::Region { area, blend: r.blend })?;
    r.mix
        .iter()
        .map(|(preset, &push)| {
            if !(push.is_finite() && (-1.0..=1.0).contains(&push)) {
                return Err(invalid(format!("{key}.mix.{preset}"), "must be within [-1, 1]"));
            }
            Ok((
                preset.clone(),
                Influence {
                    intensity: push,
                    ..base.clone()
                },
            ))
        })
        .collect()
}

/// A checked `[[worlds.NAME.warm]]` entry of a world with `layers`. Product and quality
/// names are checked by the server, which owns the catalogue.
fn warm_area(key: &str, w: RawWarm, layers: &[Layer], limits: &Limits) -> Result<WarmArea, ConfigError> {
    if w.name.is_empty()
        || w.name.len() > 64
        || !w
            .name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
    {
        return Err(invalid(
            format!("{key}.name"),
            "must be 1 to 64 ASCII letters, digits, '-' or '_'",
        ));
    }
    let area = match (w.bbox, w.polygon) {
        (Some(b), None) => {
            bounded(&format!("{key}.bbox"), &b, MAX_AUTHORED, "metres")?;
            if !(b[0] < b[2] && b[1] < b[3]) {
                return Err(invalid(
                    format!("{key}.bbox"),
                    "must be [x0, y0, x1, y1] with x0 < x1, y0 < y1",
                ));
            }
            Area::Box(b)
        }
        (None, Some(p)) => {
            if !(3..=1024).contains(&p.len()) {
                return Err(invalid(format!("{key}.polygon"), "needs 3 to 1024 vertices"));
            }
            bounded(&format!("{key}.polygon"), p.as_flattened(), MAX_AUTHORED, "metres")?;
            let polygon = Polygon::new(p);
            let [x0, y0, x1, y1] = polygon.bounds();
            if !(x0 < x1 && y0 < y1) {
                return Err(invalid(
                    format!("{key}.polygon"),
                    "has no area (its vertices are on one line)",
                ));
            }
            Area::Polygon(polygon)
        }
        _ => return Err(invalid(key, "needs exactly one of `bbox` and `polygon`")),
    };
    let margin = match w.margin {
        None => Margin::Metres(0.0),
        Some(toml::Value::String(s)) if s == "view" => Margin::View,
        Some(v) => {
            let m = v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
            match m {
                Some(m) if m.is_finite() && (0.0..=MAX_AUTHORED).contains(&m) => Margin::Metres(m),
                _ => {
                    return Err(invalid(
                        format!("{key}.margin"),
                        "must be metres within [0, 1e9] or \"view\"",
                    ));
                }
            }
        }
    };
    let mut levels = w.levels;
    levels.sort_unstable();
    if levels.is_empty() {
        return Err(invalid(format!("{key}.levels"), "names no level"));
    }
    if let Some(z) = levels.iter().find(|&&z| z > limits.max_level) {
        return Err(invalid(
            format!("{key}.levels"),
            format!("level {z} is over limits.max_level ({})", limits.max_level),
        ));
    }
    if let Some(pair) = levels.windows(2).find(|p| p[0] == p[1]) {
        return Err(invalid(
            format!("{key}.levels"),
            format!("lists level {} twice", pair[0]),
        ));
    }
    let names = |field: &str, given: Option<Vec<String>>, default: &[&str]| {
        let list = given.unwrap_or_else(|| default.iter().map(|s| s.to_string()).collect());
        if list.is_empty() {
            return Err(invalid(format!("{key}.{field}"), "is empty"));
        }
        if let Some((i, n)) = list.iter().enumerate().find(|(i, n)| list[..*i].contains(n)) {
            return Err(invalid(format!("{key}.{field}[{i}]"), format!("lists `{n}` twice")));
        }
        Ok(list)
    };
    let products = names("products", w.products, &DEFAULT_WARM_PRODUCTS)?;
    let qualities = names("qualities", w.qualities, &[DEFAULT_WARM_QUALITY])?;
    let all: Vec<&str> = layers.iter().map(|l| l.name.as_str()).collect();
    let layer_names = names("layers", w.layers, &all)?;
    let mut indices = Vec::new();
    for (i, n) in layer_names.iter().enumerate() {
        let Some(index) = layers.iter().position(|l| &l.name == n) else {
            return Err(invalid(
                format!("{key}.layers[{i}]"),
                format!("unknown layer `{n}` (this world's layers: {})", all.join(", ")),
            ));
        };
        indices.push(index);
    }
    indices.sort_unstable();
    Ok(WarmArea {
        name: w.name,
        area,
        margin,
        levels,
        products,
        qualities,
        layers: indices,
    })
}

fn validate_field(key: &str, f: &FieldSpec) -> Result<(), ConfigError> {
    if !(f.frequency.is_finite() && f.frequency > 0.0 && f.frequency <= 1e4) {
        return Err(invalid(format!("{key}.frequency"), "must be in (0, 1e4] cycles per km"));
    }
    if f.octaves == 0 || f.octaves > 16 {
        return Err(invalid(format!("{key}.octaves"), "must be within [1, 16]"));
    }
    if !(f.lacunarity.is_finite() && (1.0..=8.0).contains(&f.lacunarity)) {
        return Err(invalid(format!("{key}.lacunarity"), "must be within [1, 8]"));
    }
    if !(f.gain.is_finite() && f.gain > 0.0 && f.gain <= 1.0) {
        return Err(invalid(format!("{key}.gain"), "must be in (0, 1]"));
    }
    for v in f.offset {
        finite(&format!("{key}.offset"), v)?;
        if v.abs() > 1e9 {
            return Err(invalid(format!("{key}.offset"), "must be within ±1e9"));
        }
    }
    let [lo, hi] = f.cutoff;
    if !(lo.is_finite() && hi.is_finite() && (0.0..=1.0).contains(&lo) && (0.0..=1.0).contains(&hi) && lo < hi) {
        return Err(invalid(
            format!("{key}.cutoff"),
            "must be [low, high] with 0 <= low < high <= 1",
        ));
    }
    for p in f.range {
        if !(p.is_finite() && (0.0..=1.0).contains(&p)) {
            return Err(invalid(format!("{key}.range"), "probabilities must be within [0, 1]"));
        }
    }
    if let Some(fe) = &f.feather {
        if !(fe.start.is_finite() && fe.depth.is_finite() && fe.start >= 0.0 && fe.depth > fe.start) {
            return Err(invalid(format!("{key}.feather"), "needs 0 <= start < depth (metres)"));
        }
        if !(fe.falloff.is_finite() && (0.0..=1.0).contains(&fe.falloff)) {
            return Err(invalid(format!("{key}.feather.falloff"), "must be within [0, 1]"));
        }
    }
    Ok(())
}

fn validate_preset(key: &str, p: &Preset) -> Result<(), ConfigError> {
    validate_field(&format!("{key}.humidity"), &p.humidity)?;
    validate_field(&format!("{key}.activation"), &p.activation)?;
    validate_field(&format!("{key}.extinction"), &p.extinction)?;
    if !(p.top_narrowing.is_finite() && (0.0..1.0).contains(&p.top_narrowing)) {
        return Err(invalid(format!("{key}.top_narrowing"), "must be within [0, 1)"));
    }
    if !(p.evolve.is_finite() && p.evolve >= 0.0) {
        return Err(invalid(format!("{key}.evolve"), "must be >= 0 seconds"));
    }
    if p.rosa_iterations == 0 || p.rosa_iterations > 256 {
        return Err(invalid(format!("{key}.rosa_iterations"), "must be within [1, 256]"));
    }
    for v in p.rosa_thresholds {
        if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
            return Err(invalid(format!("{key}.rosa_thresholds"), "must be within [0, 1]"));
        }
    }
    if !(p.lightning.is_finite() && (0.0..=1000.0).contains(&p.lightning)) {
        return Err(invalid(format!("{key}.lightning"), "must be within [0, 1000]"));
    }
    if let Some(a) = &p.anvil {
        if !(a.start.is_finite() && a.start > 0.0 && a.start < 1.0) {
            return Err(invalid(format!("{key}.anvil.start"), "must be within (0, 1)"));
        }
        if !(a.radius.is_finite() && (0.0..=50_000.0).contains(&a.radius)) {
            return Err(invalid(
                format!("{key}.anvil.radius"),
                "must be within [0, 50000] metres",
            ));
        }
    }
    let r = &p.precipitation;
    let key = format!("{key}.precipitation");
    if !(r.liquid_water.is_finite() && (0.0..=10.0).contains(&r.liquid_water)) {
        return Err(invalid(format!("{key}.liquid_water"), "must be within [0, 10] g/m³"));
    }
    if !(r.droplets.is_finite() && (1.0..=10_000.0).contains(&r.droplets)) {
        return Err(invalid(format!("{key}.droplets"), "must be within [1, 10000] per cm³"));
    }
    if !(r.onset.is_finite() && (0.0..=1e5).contains(&r.onset)) {
        return Err(invalid(format!("{key}.onset"), "must be within [0, 1e5] g/m²"));
    }
    if !(r.efficiency.is_finite() && (0.0..=1.0).contains(&r.efficiency)) {
        return Err(invalid(format!("{key}.efficiency"), "must be within [0, 1]"));
    }
    Ok(())
}

fn validate_layer(key: &str, l: &Layer) -> Result<(), ConfigError> {
    if l.name.is_empty()
        || !l
            .name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
    {
        return Err(invalid(
            format!("{key}.name"),
            "must be non-empty ASCII letters, digits, '-' or '_'",
        ));
    }
    if !(l.base.is_finite() && (-1e4..=1e5).contains(&l.base)) {
        return Err(invalid(format!("{key}.base"), "must be within [-1e4, 1e5] metres"));
    }
    if !(l.cell_size.is_finite() && (1.0..=1e4).contains(&l.cell_size)) {
        return Err(invalid(format!("{key}.cell_size"), "must be within [1, 10000] metres"));
    }
    if !(l.cell_height.is_finite() && (1.0..=1e4).contains(&l.cell_height)) {
        return Err(invalid(
            format!("{key}.cell_height"),
            "must be within [1, 10000] metres",
        ));
    }
    if l.depth == 0 || l.depth > 64 {
        return Err(invalid(format!("{key}.depth"), "must be within [1, 64] cells"));
    }
    if !(l.dt.is_finite() && (0.01..=86400.0).contains(&l.dt)) {
        return Err(invalid(format!("{key}.dt"), "must be within [0.01, 86400] seconds"));
    }
    for (name, v) in [("wind", l.wind), ("shear", l.shear)] {
        for c in v {
            finite(&format!("{key}.{name}"), c)?;
        }
    }
    for k in 0..l.depth {
        let w = l.wind_at_level(k);
        if w[0].abs() > 300.0 || w[1].abs() > 300.0 {
            return Err(invalid(
                format!("{key}.wind"),
                "wind (with shear) must stay within ±300 m/s",
            ));
        }
    }
    let e = l.epoch;
    if e.length == 0 || e.length > 4096 || e.warmup > 4096 || e.fade > e.length {
        return Err(invalid(
            format!("{key}.epoch"),
            "needs 1 <= length <= 4096, warmup <= 4096 and fade <= length",
        ));
    }
    if let Some(x) = l.extent
        && !(x.iter().all(|v| v.is_finite()) && x[0] < x[2] && x[1] < x[3])
    {
        return Err(invalid(
            format!("{key}.extent"),
            "must be [x0, y0, x1, y1] with x0 < x1, y0 < y1",
        ));
    }
    if let Some(a) = &l.preset.anvil
        && a.cells(l.cell_size) > MAX_ANVIL_CELLS
    {
        return Err(invalid(
            format!("{key}.preset"),
            format!(
                "its anvil radius {} m is over {MAX_ANVIL_CELLS} cells of {} m",
                a.radius, l.cell_size
            ),
        ));
    }
    at_most(
        &format!("{key}.ellipsoids"),
        l.ellipsoids.len(),
        most::ELLIPSOIDS,
        "ellipsoids",
    )?;
    for (i, el) in l.ellipsoids.iter().enumerate() {
        if !(el.centre.iter().all(|v| v.is_finite()) && el.radii.iter().all(|r| r.is_finite() && *r > 0.0)) {
            return Err(invalid(
                format!("{key}.ellipsoids[{i}]"),
                "needs a finite centre and positive radii",
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_config_has_default_world_with_three_layers() {
        let c = Config::embedded();
        let w = c.world("default").unwrap();
        assert_eq!(w.seed, 1);
        assert!(w.layers.len() >= 3);
        for p in ["stratus", "stratocumulus", "altocumulus", "cumulus", "cirrus"] {
            assert!(c.presets.contains_key(p), "preset {p}");
        }
    }

    #[test]
    fn numeric_world_is_seed_with_default_climate() {
        let c = Config::embedded();
        let w = c.world("12345").unwrap();
        assert_eq!(w.seed, 12345);
        assert_eq!(w.layers, c.world("default").unwrap().layers);
        assert!(c.world("99999999999999999999999").is_none());
        assert!(c.world("nope").is_none());
    }

    /// Parses the default config with the first `from` replaced by `to` and asserts
    /// that the error names `named`.
    #[track_caller]
    fn assert_rejected_naming(from: &str, to: &str, named: &str) {
        assert!(DEFAULT_CONFIG.contains(from), "{from:?} is not in the default config");
        let e = Config::parse(&DEFAULT_CONFIG.replacen(from, to, 1))
            .unwrap_err()
            .to_string();
        assert!(e.contains(named), "{e}");
    }

    #[test]
    fn unknown_key_is_named() {
        assert_rejected_naming("[limits]", "[limits]\nbogus_key = 3", "bogus_key");
    }

    #[test]
    fn toml_errors_are_one_bounded_line_that_says_where() {
        let text = format!(
            "[limits]\nmax_level = 3\nx = {}{}\n",
            "[".repeat(10_000),
            "]".repeat(10_000)
        );
        let e = Config::parse(&text).unwrap_err().to_string();
        assert!(e.starts_with("invalid config: line 3, column "), "{e}");
        assert!(!e.contains('\n') && e.len() < 500, "{e}");
        let e = Config::parse("[limits]\nmax_level = 3\nmax_level = 4\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 3") && e.contains("max_level = 4"), "{e}");
    }

    #[test]
    fn limits_and_lists_are_bounded_by_name() {
        assert_rejected_naming("max_columns = 2048", "max_columns = 0", "limits.max_columns");
        assert_rejected_naming(
            "max_cells = 8388608",
            "max_cells = 9223372036854775807",
            "limits.max_cells: must be within",
        );
        let many = (0..=most::AUTHORED)
            .map(|i| format!("[[worlds.overcast.regions]]\nbox = [0.0, 0.0, 1.0, 1.0]\nmix = {{ stratocumulus = 0.1 }}\nramp = {i}.0\n"))
            .collect::<String>();
        let e = Config::parse(&format!("{DEFAULT_CONFIG}\n{many}"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("worlds.overcast.events: has 257 events and regions together"),
            "{e}"
        );
    }

    #[test]
    fn invalid_value_is_named() {
        assert_rejected_naming("depth = 10", "depth = 0", "depth");
        assert_rejected_naming("dt = 20.0", "dt = nan", "dt");
    }

    #[test]
    fn event_fields_are_checked_against_the_kind() {
        // A storm refuses a front's fields; a front requires its own.
        let storm_radii = "radii = [7000.0, 7000.0, 8000.0]";
        let with_width = format!("{storm_radii}\nwidth = 10.0");
        assert_rejected_naming(storm_radii, &with_width, "worlds.archipelago.events[0].width");
        assert_rejected_naming(storm_radii, &with_width, "does not apply to a storm");
        let front_width = "width = 4000.0\nlength = 80000.0";
        assert_rejected_naming(front_width, "length = 80000.0", "worlds.archipelago.events[1].width");
        assert_rejected_naming(front_width, "length = 80000.0", "is required for a front");
    }

    #[test]
    fn invalid_weather_values_are_named() {
        assert_rejected_naming(
            "freezing_level = 3000.0",
            "freezing_level = nan",
            "worlds.default.freezing_level",
        );
        assert_rejected_naming(
            "onset = 500.0, efficiency = 1.0",
            "onset = 500.0, efficiency = 1.5",
            "presets.cumulonimbus.precipitation.efficiency",
        );
        assert_rejected_naming("droplets = 100.0", "droplets = 0.0", "precipitation.droplets");
        assert_rejected_naming("onset = 500.0,", "onset = 500.0, rain = 1,", "rain");
        // A world without a freezing level gets the default one in every layer.
        let c = Config::embedded();
        assert!(
            c.worlds["overcast"]
                .layers
                .iter()
                .all(|l| l.freezing_level == DEFAULT_FREEZING_LEVEL)
        );
    }
}
