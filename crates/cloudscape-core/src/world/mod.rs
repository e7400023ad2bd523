//! Worlds, layers and presets: the configuration everything downstream reads.
//!
//! A [`World`] is a seed plus a climate (its [`Layer`]s). The configuration is
//! TOML; the default one is embedded in the binary ([`DEFAULT_CONFIG`], the text of
//! `config/default.toml`).
//! Parsing rejects unknown keys and invalid values with a message that names
//! the key, before anything else runs.

pub mod authored;
mod clock;
mod config;
mod keyframe;
pub mod warm;

pub use clock::WorldClock;
pub use config::{
    Config, ConfigError, DEFAULT_CONFIG, DEFAULT_FREEZING_LEVEL, Limits, MAX_CONFIG_BYTES, SunConfig, read_config_text,
};
pub use keyframe::{Keyframe, MAX_KEYFRAME_DOUBLINGS, PREFETCH_FROM, PREFETCH_SPREAD, keyframe_span, prefetch_at};

use serde::Deserialize;

/// Bumped whenever any change alters output bytes. Baked into cache keys and ETags.
/// 2: byte-wise Bernoulli draws with per-word floating thresholds (`automaton::random`).
/// 3: one random key per word, salted per event.
/// 4: ARS-5 (AES-round) 16-bit draws, compared in full (no high-byte ties).
/// 5: pictures judged against physics (issue 20): a path-traced `reference`, a
///    physical sky and aerial perspective, scattering octaves and sky light through
///    the cloud in the billboards (records of 36 bytes), per-pixel splats with detail
///    erosion, fog around the eye, far levels without haze where no cloud can form,
///    and a fair-weather `default` world.
/// 6: sun buckets 1° wide near the horizon; scattering octaves and sky-light
///    attenuation fitted to the path tracer (b = ¾, sky scale 2); detail erosion by
///    the mean of each billboard's own noise.
/// 7: keyframes (issue 22): tile products per keyframe span (`world::Keyframe`), each
///    billboard at both ends of its span moved by the wind (`billboards.bin` version
///    2, 56-byte records, lighting in the header), shadow maps with both ends, renders
///    drawn by the animation rule (`render::keyframe`).
/// 8: into the engines (issue 23): JSON products print f32 values in their shortest
///    decimals (`0.9`, not `0.8999999761581421`); PNGs carry their colour space
///    (`gAMA` 1.0 for data maps, `sRGB` for pictures); `coverage.png` is RGB with no
///    data in alpha (B is the cloud top; the base is gone).
/// 9: coarse shaded tiles normalise each metaball by the field's vertical integral
///    past 1,024 cell heights of radius.
/// 10: authored weather (storms, fronts and regional overrides that push a layer's
///    humidity and activation, `world::authored`) and the cumulonimbus anvil
///    (`Preset::anvil`: brightness spread under the layer's top).
/// 11: the metaball lattice drifts with the wind (`density::metaballs::Drift`): a
///    keyframe's end is the next keyframe's start (one instant shaded per keyframe,
///    no jump at the boundary); each instant is shaded over the tile, its halo and
///    the box the wind moves it to over a span.
/// 12: `billboards.bin` is version 3 (lattice sites, quantised, coded in planes; a
///    self-contained and a delta form, `products::keyframe_bin`); version 2 is
///    `billboards.v2.bin`.
/// 13: one sun: cloud scatters the irradiance the ground sees (`sun_rgb / 4` per unit
///    4π-normalised phase, [`crate::render::light::SUN_SCATTER`]), the air is lit by
///    it without a display factor, and the tone map carries the exposure
///    ([`crate::render::light::EXPOSURE`]).
/// 14: the billboard presets' light and edges fitted to the path tracer per preset
///    ([`crate::render::Quality::light`]): sky light enters through the upper
///    hemisphere's own radiance, attenuated at diffusion theory's rate; per-preset
///    octaves, detail erosion and splat opacity.
/// 15: `billboards.bin`'s colour codes carry a billboard's ambient part, the sun term
///    following from `τ_sun` ([`crate::render::light::SunTerm`]), so the
///    light a client draws under another layer keeps one step's precision.
pub const ALGORITHM_VERSION: u32 = 15;

/// Largest accepted world time in seconds (PRODUCT.md: `0 <= t <= 1e12`).
pub const MAX_TIME: f64 = 1e12;

/// Dobashi's three stochastic events, each with its own probability field:
/// humidity (vapour appears, p_hum), activation (vapour may turn to cloud, p_act)
/// and extinction (cloud vanishes, p_ext). The value indexes a layer's three
/// fields and a word's three drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// Vapour appears in a cell (p_hum).
    Humidity = 0,
    /// A humid cell may become cloud (p_act).
    Activation = 1,
    /// A cloud cell vanishes (p_ext).
    Extinction = 2,
}

impl Event {
    /// The three events in index order.
    pub const ALL: [Event; 3] = [Event::Humidity, Event::Activation, Event::Extinction];
}

/// How a layer's automaton runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Dobashi et al. 2000: stochastic formation/extinction, state carried over steps.
    Dobashi,
    /// Rosa 2013, eq. 3.5–3.9: noise textures are the randomness, probabilities are
    /// thresholds; a fixed number of iterations from an empty grid for each frame.
    Rosa,
}

/// One noise-driven field (Rosa's Noise Maker, per field): fBm of simplex noise,
/// then move/increment, feather and cutoff, then a linear map to a probability.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct FieldSpec {
    /// Base frequency in cycles per kilometre (Rosa's "increment").
    pub frequency: f64,
    /// Octaves of fBm before clamping to what the output resolution can show.
    #[serde(default = "default_octaves")]
    pub octaves: u32,
    /// Frequency ratio between successive octaves.
    #[serde(default = "default_lacunarity")]
    pub lacunarity: f64,
    /// Amplitude ratio between successive octaves.
    #[serde(default = "default_gain")]
    pub gain: f64,
    /// Rosa's "move": a shift of the pattern, in noise units (cycles).
    #[serde(default)]
    pub offset: [f64; 2],
    /// Rosa's cutoff: brightness below `low` maps to 0, above `high` to 1.
    #[serde(default = "default_cutoff")]
    pub cutoff: [f64; 2],
    /// Rosa's feather at the edges of the layer's `extent` (inactive without one).
    #[serde(default)]
    pub feather: Option<Feather>,
    /// Probability at brightness 0 and at brightness 1 (may decrease, e.g. extinction).
    #[serde(default = "default_range")]
    pub range: [f64; 2],
}

/// Rosa 2013 §4.1.2 feather: zero brightness within `start` metres of the extent's
/// edge, fading in until `depth` metres; `falloff` in \[0, 1\] shapes the fade
/// (0 linear, 1 smoothstep-like steepening near the edge).
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Feather {
    /// Metres from the extent's edge within which the brightness is zero.
    pub start: f64,
    /// Metres from the edge at which the fade is complete.
    pub depth: f64,
    /// Shape of the fade in [0, 1]: 0 linear, 1 steepest near the edge.
    #[serde(default)]
    pub falloff: f64,
}

fn default_octaves() -> u32 {
    4
}
fn default_lacunarity() -> f64 {
    2.0
}
fn default_gain() -> f64 {
    0.5
}
fn default_cutoff() -> [f64; 2] {
    [0.0, 1.0]
}
fn default_range() -> [f64; 2] {
    [0.0, 1.0]
}

/// A Dobashi ellipsoid: formation is only likely inside it. Positioned in the
/// layer's wind frame, so it drifts with the base wind.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Ellipsoid {
    /// Centre, world metres at t = 0 (x, y, altitude).
    pub centre: [f64; 3],
    /// Semi-axes in metres.
    pub radii: [f64; 3],
}

/// A cloud type: everything about a layer except where it is and how the air moves.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Preset {
    /// How the automaton runs (Dobashi or Rosa).
    pub mode: Mode,
    /// Height profile: at the top of the layer the brightness needed for
    /// humidity/activation rises by this much, so bases are wider than tops.
    #[serde(default)]
    pub top_narrowing: f64,
    /// The humidity field (p_hum).
    pub humidity: FieldSpec,
    /// The activation field (p_act).
    pub activation: FieldSpec,
    /// The extinction field (p_ext).
    pub extinction: FieldSpec,
    /// Seconds per unit of noise time: the fields evolve slowly (0 = frozen).
    #[serde(default = "default_evolve")]
    pub evolve: f64,
    /// Rosa mode: iterations from an empty grid per frame.
    #[serde(default = "default_rosa_iterations")]
    pub rosa_iterations: u32,
    /// Rosa mode: thresholds p_hum, p_act, p_ext against the textures.
    #[serde(default = "default_rosa_thresholds")]
    pub rosa_thresholds: [f64; 3],
    /// How much of the preset's cloud water falls out (`weather::precipitation`).
    #[serde(default)]
    pub precipitation: PrecipitationSpec,
    /// Lightning: a factor on the Price & Rind flash rate of the layer's deep columns
    /// (`weather::lightning`); 0, the default, for clouds that do not electrify.
    #[serde(default)]
    pub lightning: f64,
    /// An anvil: deep convective cloud spreading sideways under the layer's top (the cap).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub anvil: Option<Anvil>,
}

/// A cumulonimbus anvil. From `start` (a fraction of the layer's depth) up to its top,
/// the humidity and activation brightness blend (smoothly, fully at the top) toward
/// their largest value within `radius` metres, and the top narrowing fades out: the
/// updrafts' cloud spreads sideways under the cap (the tropopause, in nature) into a
/// flat, wide top.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Anvil {
    /// Height fraction of the layer, in (0, 1), where the spreading begins.
    pub start: f64,
    /// How far the cloud spreads, metres (the square max filter's half-width).
    pub radius: f64,
}

impl Anvil {
    /// The anvil's weight in [0, 1] at vertical level `k` of a layer `depth` cells deep:
    /// 0 below `start`, rising smoothly to 1 at the top level.
    pub fn weight(&self, k: u32, depth: u32) -> f32 {
        let h = (k as f64 + 0.5) / depth as f64;
        let top = (depth as f64 - 0.5) / depth as f64;
        if h <= self.start || top <= self.start {
            return 0.0;
        }
        let w = ((h - self.start) / (top - self.start)).clamp(0.0, 1.0);
        (w * w * (3.0 - 2.0 * w)) as f32
    }

    /// The radius in whole cells of `cell` metres (at least 1 when the radius is positive).
    pub fn cells(&self, cell: f64) -> usize {
        if self.radius <= 0.0 {
            0
        } else {
            (self.radius / cell).ceil().max(1.0) as usize
        }
    }
}

impl Preset {
    /// Whether the preset's clouds can precipitate at all (an efficiency above 0).
    pub fn precipitates(&self) -> bool {
        self.precipitation.efficiency > 0.0
    }

    /// Whether the preset's clouds make lightning (a `lightning` factor above 0).
    pub fn makes_lightning(&self) -> bool {
        self.lightning > 0.0
    }
}

/// The microphysics of a preset's precipitation (`weather::precipitation` says how
/// they combine): liquid water path from density and depth, then a drizzle-rate
/// power law above an onset threshold, scaled by an efficiency.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct PrecipitationSpec {
    /// Cloud liquid water content at density 1, g/m³ (density scales it linearly).
    pub liquid_water: f64,
    /// Cloud droplet number concentration, per cm³ (maritime ~100, continental ~300):
    /// more droplets, smaller drops, less rain for the same water.
    pub droplets: f64,
    /// Liquid water path below which a column does not precipitate, g/m².
    pub onset: f64,
    /// Precipitation efficiency in [0, 1]: the share of the relation's rate that
    /// reaches the ground (0 for ice clouds whose fall streaks evaporate).
    pub efficiency: f64,
}

impl Default for PrecipitationSpec {
    /// A maritime stratocumulus (Comstock et al. 2004's EPIC clouds).
    fn default() -> Self {
        PrecipitationSpec {
            liquid_water: 0.3,
            droplets: 100.0,
            onset: 50.0,
            efficiency: 1.0,
        }
    }
}

fn default_evolve() -> f64 {
    7200.0
}
fn default_rosa_iterations() -> u32 {
    12
}
fn default_rosa_thresholds() -> [f64; 3] {
    [0.5, 0.5, 0.5]
}

/// Epoch structure of the bounded history (see `automaton::epoch`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct EpochSpec {
    /// Steps per epoch.
    pub length: u32,
    /// Warm-up steps run from an empty grid before the epoch starts.
    pub warmup: u32,
    /// Cells switch from one epoch's run to the next over the first `fade` steps
    /// of an epoch, each at its own step (must be <= length).
    pub fade: u32,
}

impl Default for EpochSpec {
    fn default() -> Self {
        EpochSpec {
            length: 16,
            warmup: 24,
            fade: 16,
        }
    }
}

/// A resolved cloud layer: a preset placed in an altitude band with wind.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Layer {
    /// The layer's name, unique in its world.
    pub name: String,
    /// The name of the preset it places.
    pub preset_name: String,
    /// The preset it places.
    pub preset: Preset,
    /// Altitude of the layer's bottom, metres.
    pub base: f64,
    /// Horizontal cell size, metres.
    pub cell_size: f64,
    /// Vertical cell size, metres.
    pub cell_height: f64,
    /// Depth in cells.
    pub depth: u32,
    /// Seconds per automaton step.
    pub dt: f64,
    /// Wind at the layer base, m/s (x east, y north).
    pub wind: [f64; 2],
    /// Change of wind with height, (m/s) per metre.
    pub shear: [f64; 2],
    /// How the bounded history is cut into epochs.
    pub epoch: EpochSpec,
    /// Optional bounded extent (world metres) used by the feather effect.
    pub extent: Option<[f64; 4]>,
    /// Dobashi ellipsoids that shape humidity and activation.
    pub ellipsoids: Vec<Ellipsoid>,
    /// The world's authored storms, fronts and regional overrides that drive this
    /// layer's preset (`worlds.NAME.events` and `.regions`), in configuration order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub authored: Vec<authored::Influence>,
    /// The world's freezing level (altitude of the 0 °C isotherm, metres), copied from
    /// `worlds.NAME.freezing_level` so that a layer's products need only the layer.
    pub freezing_level: f64,
}

impl Layer {
    /// Wind (m/s) at the centre of vertical level `k`.
    pub fn wind_at_level(&self, k: u32) -> [f64; 2] {
        let h = (k as f64 + 0.5) * self.cell_height;
        [self.wind[0] + self.shear[0] * h, self.wind[1] + self.shear[1] * h]
    }

    /// Altitude of the centre of vertical level `k`, metres.
    pub fn level_altitude(&self, k: u32) -> f64 {
        self.base + (k as f64 + 0.5) * self.cell_height
    }

    /// Altitude of the layer's top, metres.
    pub fn top(&self) -> f64 {
        self.base + self.depth as f64 * self.cell_height
    }
}

/// A time snapped to a layer's frame grid: the canonical frames that requests for
/// nearby times share, so that they share computed bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SnappedTime {
    /// Frame index: `t_frame = index * dt / frames_per_step`.
    pub index: u64,
    /// The time the bytes are computed for.
    pub t: f64,
}

impl SnappedTime {
    /// Snaps a checked `t` (finite, 0..=[`MAX_TIME`]) to the nearest multiple of
    /// `layer.dt / frames_per_step` (ties away from zero), staying within range.
    pub fn snap(t: f64, layer: &Layer, frames_per_step: u32) -> SnappedTime {
        let period = layer.dt / frames_per_step as f64;
        let mut index = (t / period).round() as u64;
        if index as f64 * period > MAX_TIME {
            index = (MAX_TIME / period).floor() as u64;
        }
        SnappedTime {
            index,
            t: index as f64 * period,
        }
    }

    /// True when the request asked for exactly this frame's time.
    pub fn is_exact(&self, requested: f64) -> bool {
        self.t == requested
    }
}

/// A world: a seed and a climate.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct World {
    /// The world's name in the configuration.
    pub name: String,
    /// The seed every field and draw of the world derives from.
    pub seed: u64,
    /// The cloud layers, in configuration order.
    pub layers: Vec<Layer>,
    /// The world's authored weather as configured (`worlds.NAME.events`, then
    /// `worlds.NAME.regions` one entry per preset of each mix), each with the preset it
    /// drives; every layer placing that preset holds a copy in [`Layer::authored`].
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub authored: Vec<(String, authored::Influence)>,
    /// How the world's time follows real time (`worlds.NAME.clock`): the server's, for
    /// "now"; the simulation takes times as arguments and never reads it.
    pub clock: WorldClock,
    /// Play areas the server keeps warm (`worlds.NAME.warm`), in configuration order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warm: Vec<warm::WarmArea>,
}

impl World {
    /// The layer named `name`, or the first layer when `name` is `None`.
    pub fn layer(&self, name: Option<&str>) -> Option<(usize, &Layer)> {
        match name {
            None => self.layers.first().map(|l| (0, l)),
            Some(n) => self.layers.iter().enumerate().find(|(_, l)| l.name == n),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_snap_to_the_grid_and_stay_in_range() {
        let c = Config::embedded();
        let layer = &c.worlds["default"].layers[0];
        let period = layer.dt / 4.0;
        let f = SnappedTime::snap(period * 3.4, layer, 4);
        assert_eq!(f.index, 3);
        assert_eq!(f.t, period * 3.0);
        assert!(!f.is_exact(period * 3.4));
        assert!(SnappedTime::snap(period * 3.0, layer, 4).is_exact(period * 3.0));
        assert!(SnappedTime::snap(MAX_TIME, layer, 4).t <= MAX_TIME);
        assert_eq!(SnappedTime::snap(0.0, layer, 4).index, 0);
    }
}
