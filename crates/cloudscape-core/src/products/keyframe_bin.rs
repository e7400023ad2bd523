//! `billboards.bin` version 3: one keyframe of a tile's billboards as the states of
//! the metaball lattice's sites, quantised to what the picture needs and coded
//! against what a client already holds.
//!
//! A tile's metaballs sit on a lattice that drifts with the wind
//! ([`crate::density::metaballs::Lattice`]), so a ball is named by its lattice
//! indices `(i, j, k)` and its position, radius and velocity follow from the lattice
//! (spacing, drift of each level, wind of each level): none of them is sent per ball.
//! What is sent per *site* (a lattice point whose centre lies in the tile at the
//! keyframe's start `t0`) is its state at both ends of the span: nothing, or a splat
//! index, a colour and the optical depth of its sun ray. Peak opacity follows from
//! the splat (`1 − e^{−τ_k}`), sun transmittance from `τ_sun` (`e^{−τ_sun}`).
//!
//! Each state is quantised to the precision the rendered picture needs (measured by
//! `cloudscape bench --only wire`): colour channels on `2^bits − 1` steps even in
//! display brightness ([`ColourCurve`]; since ALGORITHM_VERSION 15 of the colour's
//! ambient part, [`SunTerm`]), `τ_sun` on `steps` steps per e-fold above `τ_floor`,
//! the splat index exactly.
//!
//! The states are coded as residuals, one byte per value (two for splat indices of a
//! sheet of more than 255), in planes of one field each, so that the HTTP layer's
//! zstd or gzip finds long runs of small numbers:
//!
//! - the start of the span is predicted in space: each value from its neighbours
//!   on the same lattice level (the median edge detector of LOCO-I / JPEG-LS:
//!   left, up, up-left), sites without a ball taking the prediction itself;
//! - the end of the span is predicted in time: each site's end from its start
//!   (the same air, carried by the wind), or in space where the site was empty;
//! - red and blue are coded after green, less green's own prediction error
//!   (colour changes are mostly changes of brightness).
//!
//! # Two forms
//!
//! The end of one keyframe is the start of the next, bit for bit (the lattice drifts
//! with the air, and the end instant of a span is the start instant of the next:
//! `render::tile`). So:
//!
//! - the **self-contained form** (form 0) codes the start in space and the end in
//!   time: what a client's first view of a tile needs;
//! - the **delta form** (form 1) codes only what a client holding the previous
//!   keyframe of the same tile lacks: the start of the sites the wind carried into
//!   the tile during the previous span (their predecessors were outside it), and the
//!   end in time. Every other site's start is the previous keyframe's end of its
//!   predecessor, the site `(i, j) − shift(k)` of the previous keyframe, `shift` the
//!   previous keyframe's per-level index shift from its `t0` lattice to its `t1`
//!   lattice.
//!
//! A delta is only a delta when the previous keyframe was shaded with the same light
//! (sun bucket, quality): otherwise the server answers the self-contained form, which
//! says so in its header, and a decoder takes either.
//!
//! # Layout, little-endian
//!
//! Header, fixed part (200 bytes; offsets 0–5 and 8–159 as in version 2 where the
//! field is the same):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `CSBB` |
//! | 4 | u16 | format version (3) |
//! | 6 | u16 | form: 0 self-contained, 1 delta on the previous keyframe |
//! | 8 | u32 | header size in bytes (fixed part, level table, plane table) |
//! | 12 | u32 | tile level z |
//! | 16 | i64 | tile x |
//! | 24 | i64 | tile y |
//! | 32 | f64 | tile origin x, world metres (west edge) |
//! | 40 | f64 | tile origin y, world metres (south edge) |
//! | 48 | f32 | sun azimuth, degrees (bucket centre) |
//! | 52 | f32 | sun elevation, degrees (bucket centre) |
//! | 56 | u16 | splat count of the sheet |
//! | 58 | u16 | splat size (texels per side) |
//! | 60 | f32 | tile side, metres |
//! | 64 | f64 | keyframe start t0, world seconds |
//! | 72 | f64 | keyframe end t1 |
//! | 80 | 72 bytes | lighting, as version 2's offsets 80–151 |
//! | 152 | u32 | ALGORITHM_VERSION |
//! | 156 | u32 | billboards: sites with a ball at either end |
//! | 160 | f64 | lattice spacing s, metres |
//! | 168 | f64 | vertical spacing s_v, metres |
//! | 176 | f64 | layer base (altitude of the lattice's bottom), metres |
//! | 184 | f32 | ball radius, metres |
//! | 188 | u8 | colour bits |
//! | 189 | u8 | τ_sun steps per e-fold |
//! | 190 | u16 | lattice levels n |
//! | 192 | f32 | τ_floor |
//! | 196 | u16 | planes P (12) |
//! | 198 | u16 | shadow widening `w`, thousandths of the radius |
//!
//! Then n level records of 88 bytes (level k = 0 at the bottom):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | 2 × f64 | the level's drift at t0, `o(k)` (x, y), metres |
//! | 16 | 2 × f64 | the wind at the level's altitude, m/s |
//! | 32 | 2 × i64 | index shift of the level from the t0 lattice to the t1 lattice |
//! | 48 | i64 | first row j inside the tile |
//! | 56 | u32 | rows inside the tile |
//! | 60 | i64 | first column i of rows with (j + k) even |
//! | 68 | u32 | columns of those rows |
//! | 72 | i64 | first column i of rows with (j + k) odd |
//! | 80 | u32 | columns of those rows |
//! | 84 | u32 | reserved (0) |
//!
//! Then P u32 plane lengths, then the planes in that order: start splat (low bytes),
//! start splat (high bytes; empty for a sheet of at most 255), start green, red, blue,
//! τ_sun; the same six for the end.
//!
//! Site (i, j, k) is centred at `x = (i + ½((j + k) mod 2)) s + o_x(k)`,
//! `y = (j + ½(k mod 2)) s + o_y(k)`, `z = base + (k + ½) s_v` at t0. Sites are taken
//! level by level, row by row (j rising), column by column (i rising) over each
//! level's box (rows `j0 ..`, columns from the smaller first column of the two row
//! kinds to the larger end); a site of the box outside its row's run is outside the
//! tile and holds nothing. The codes, per site and end, are: splat `0` (no ball) or
//! `index + 1`; colour `c = 2 (v / (2^bits − 1))^2.2` per channel; `τ_sun = τ_floor ·
//! e^{(v − 1) / steps}`. Since ALGORITHM_VERSION 13 the colour codes are even steps of
//! the display ([`ColourCurve`]); since 15 they carry the colour's ambient part, the
//! sun term following from `τ_sun` and the header's lighting ([`SunTerm`]).

use crate::render::ShadedTile;
use crate::render::image::to_u8;
use crate::render::light::{Octaves, SunTerm};
use crate::render::shade::Billboard;
use crate::render::splats::TAU_MAX;
use crate::world::ALGORITHM_VERSION;

use super::billboards::{BIN_MAGIC, BinBillboards, BinEnd, BinLighting, BinRecord};

/// The format version this module writes.
pub const VERSION: u16 = 3;
/// Size of the fixed part of the header, bytes.
const FIXED_BYTES: usize = 200;
/// Size of one level record, bytes.
const LEVEL_BYTES: usize = 88;
/// Planes of a keyframe: six per end.
const PLANES: usize = 12;
/// Most lattice levels a decoder accepts.
const MAX_LEVELS: usize = 256;
/// Most rows or columns of one level a decoder accepts (a tile has 256 columns and a
/// lattice at least one column apart).
const MAX_SIDE: u32 = 4096;
/// Most sites a decoder accepts over all levels.
const MAX_SITES: usize = 1 << 23;

/// What a keyframe's bytes hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Form {
    /// Both ends, the start coded in space: decodable alone.
    SelfContained,
    /// The end, and the start of the sites the previous keyframe lacks.
    Delta,
}

impl Form {
    fn code(self) -> u16 {
        match self {
            Form::SelfContained => 0,
            Form::Delta => 1,
        }
    }
}

/// How finely the states are quantised.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Quantisation {
    /// Bits per colour channel (steps of [`ColourCurve`]), 1 to 8.
    pub colour_bits: u8,
    /// Steps of `τ_sun` per e-fold, at least 1.
    pub tau_sun_steps: u8,
}

impl Quantisation {
    /// The default: the coarsest steps that keep the gallery's pictures within the
    /// stated error (`cloudscape bench --only wire`, BENCHMARKS.md "Bytes on the wire").
    pub const DEFAULT: Quantisation = Quantisation {
        colour_bits: 6,
        tau_sun_steps: 8,
    };
}

/// Below this the optical depth of a sun ray is written as this (e^−0.001 = 0.999).
pub const TAU_SUN_FLOOR: f32 = 1e-3;

/// Where the sites of one lattice level lie in a tile at a keyframe's start, and how
/// the level moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LevelSites {
    /// The level's drift at t0, `Lattice::offset`, metres.
    pub offset: [f64; 2],
    /// Wind at the level's altitude, m/s.
    pub velocity: [f64; 2],
    /// Index shift (i, j) of the level from the t0 lattice to the t1 lattice
    /// (`Lattice::successor`).
    pub shift: [i64; 2],
    /// First row inside the tile.
    pub j0: i64,
    /// Rows inside the tile.
    pub rows: u32,
    /// First column and column count inside the tile, of rows with `(j + k)` even and odd.
    pub runs: [(i64, u32); 2],
}

impl LevelSites {
    /// The run of columns of row `j` of level `k`.
    fn run(&self, k: usize, j: i64) -> (i64, u32) {
        self.runs[(j + k as i64).rem_euclid(2) as usize]
    }

    /// First column and width of the level's box.
    fn box_columns(&self) -> (i64, usize) {
        let live = self.runs.iter().filter(|r| r.1 > 0);
        let first = live.clone().map(|r| r.0).min().unwrap_or(0);
        let end = live.map(|r| r.0 + r.1 as i64).max().unwrap_or(first);
        (first, (end - first).max(0) as usize)
    }

    /// Whether site (i, j) of level `k` lies in the tile.
    pub fn contains(&self, k: usize, i: i64, j: i64) -> bool {
        if j < self.j0 || j >= self.j0 + self.rows as i64 {
            return false;
        }
        let (first, n) = self.run(k, j);
        i >= first && i < first + n as i64
    }
}

/// The lattice of a tile at a keyframe: where its sites are and how they move.
#[derive(Clone, Debug, PartialEq)]
pub struct SiteGeometry {
    /// Horizontal spacing, metres.
    pub spacing: f64,
    /// Vertical spacing, metres.
    pub vertical_spacing: f64,
    /// Altitude of the lattice's bottom, metres.
    pub base: f64,
    /// Ball radius, metres.
    pub radius: f32,
    /// Each level's sites, bottom first.
    pub levels: Vec<LevelSites>,
}

impl SiteGeometry {
    /// The sites of `tile` at its keyframe's start: the lattice points whose centres
    /// lie in the tile's box (the test `render::tile` keeps balls by), and the index
    /// shift of each level over the span.
    pub fn of(tile: &ShadedTile) -> SiteGeometry {
        SiteGeometry::spanning(tile, tile.keyframe.t0, tile.keyframe.t1)
    }

    /// The sites of `tile`'s box on its lattice placed for `t0`, shifting to `t1`.
    fn spanning(tile: &ShadedTile, t0: f64, t1: f64) -> SiteGeometry {
        let lattice = tile.lattice.at(t0);
        let later = lattice.at(t1);
        let owned = [
            tile.origin[0],
            tile.origin[1],
            tile.origin[0] + tile.size,
            tile.origin[1] + tile.size,
        ];
        let inside = |c: [f64; 3]| c[0] >= owned[0] && c[0] < owned[2] && c[1] >= owned[1] && c[1] < owned[3];
        let s = lattice.spacing;
        let levels = (0..lattice.levels as i64)
            .map(|k| {
                let o = lattice.offset(k);
                let z = lattice.centre(0, 0, k)[2];
                // Rows: a first guess from the drift, then moved until the centres'
                // own test agrees at both edges.
                let oy = 0.5 * (k.rem_euclid(2)) as f64;
                let y_in = |j: i64| {
                    let c = lattice.centre(0, j, k);
                    c[1] >= owned[1] && c[1] < owned[3]
                };
                let (j0, j1) = edges(
                    ((owned[1] - o[1]) / s - oy).ceil() as i64,
                    ((owned[3] - o[1]) / s - oy).ceil() as i64,
                    y_in,
                );
                let run = |parity: i64| {
                    // A row j of this parity: (j + k) mod 2 = parity.
                    let j = if (j0 + k).rem_euclid(2) == parity { j0 } else { j0 + 1 };
                    let ox = 0.5 * parity as f64;
                    let x_in = |i: i64| inside([lattice.centre(i, j, k)[0], owned[1], 0.0]);
                    let (i0, i1) = edges(
                        ((owned[0] - o[0]) / s - ox).ceil() as i64,
                        ((owned[2] - o[0]) / s - ox).ceil() as i64,
                        x_in,
                    );
                    (i0, (i1 - i0).max(0) as u32)
                };
                let next = lattice.successor([0, 0, k], &later);
                LevelSites {
                    offset: o,
                    velocity: tile.velocity_at(z),
                    shift: [next[0], next[1]],
                    j0,
                    rows: (j1 - j0).max(0) as u32,
                    runs: [run(0), run(1)],
                }
            })
            .collect();
        SiteGeometry {
            spacing: s,
            vertical_spacing: lattice.vertical_spacing,
            base: lattice.base,
            radius: lattice.radius as f32,
            levels,
        }
    }

    /// Centre of site (i, j) of level `k` at t0, world metres (`Lattice::centre`).
    pub fn centre(&self, i: i64, j: i64, k: usize) -> [f64; 3] {
        let l = &self.levels[k];
        let ox = 0.5 * ((j + k as i64).rem_euclid(2)) as f64;
        let oy = 0.5 * ((k as i64).rem_euclid(2)) as f64;
        [
            (i as f64 + ox) * self.spacing + l.offset[0],
            (j as f64 + oy) * self.spacing + l.offset[1],
            self.base + (k as f64 + 0.5) * self.vertical_spacing,
        ]
    }

    /// Index of each level's first site in the dense site arrays, and the total.
    fn bases(&self) -> (Vec<usize>, usize) {
        let mut at = 0;
        let bases = self
            .levels
            .iter()
            .map(|l| {
                let here = at;
                at += l.rows as usize * l.box_columns().1;
                here
            })
            .collect();
        (bases, at)
    }

    /// The dense index of site (i, j) of level `k`, if it lies in the level's box.
    fn index(&self, bases: &[usize], k: usize, i: i64, j: i64) -> Option<usize> {
        let l = self.levels.get(k)?;
        let (first, w) = l.box_columns();
        let (r, c) = (j.checked_sub(l.j0)?, i.checked_sub(first)?);
        (r >= 0 && c >= 0 && (r as u64) < l.rows as u64 && (c as u64) < w as u64)
            .then(|| bases[k] + r as usize * w + c as usize)
    }
}

/// The first and one-past-last index of the run where `inside` holds, from guesses
/// `lo`, `hi` that are at most a step or two off (rounding at the edges; a few steps
/// are tried, so a degenerate lattice cannot loop).
fn edges(lo: i64, hi: i64, inside: impl Fn(i64) -> bool) -> (i64, i64) {
    const STEPS: usize = 4;
    let (mut lo, mut hi) = (lo, hi.max(lo));
    for _ in 0..STEPS {
        if inside(lo.saturating_sub(1)) {
            lo -= 1;
        } else if lo < hi && !inside(lo) {
            lo += 1;
        }
        if inside(hi) {
            hi += 1;
        } else if hi > lo && !inside(hi - 1) {
            hi -= 1;
        }
    }
    (lo, hi)
}

/// One site's quantised state at one end.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SiteState {
    /// 0: no ball; else the splat index + 1.
    pub splat: u16,
    /// Colour codes: green, red, blue (the coding order).
    pub grb: [u16; 3],
    /// τ_sun code (1 and up).
    pub tau_sun: u16,
}

/// A decoded keyframe's lattice: its sites and their states at both ends, which the
/// next keyframe's delta form is decoded against.
#[derive(Clone, Debug, PartialEq)]
pub struct LatticeKeyframe {
    /// Where the sites are.
    pub geometry: SiteGeometry,
    /// How the states are quantised.
    pub quantisation: Quantisation,
    /// States at t0, dense over each level's box ([`SiteGeometry`] order).
    pub start: Vec<SiteState>,
    /// States at t1.
    pub end: Vec<SiteState>,
    /// How much wider than a ball its ground shadow is drawn, in radii: the texel of
    /// the light buffer the server shades with (`QualitySettings::light_texel`), so a
    /// shadow derived from the billboards is as sharp as the server's `shadow.png`
    /// (`view::held`).
    pub shadow_widening: f32,
}

/// How colour codes map to linear colour, by the ALGORITHM_VERSION in the header
/// (offset 152).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColourCurve {
    /// Before version 13: steps of `(c / 2)^(1/2.2)`.
    Gamma,
    /// Since version 13: steps of the displayed value at the tone map's exposure E = 3,
    /// `(1 − e^{−E c})^(1/2.2)` ([`crate::render::light::tone_map`]), so every step is
    /// the same on the display (half a step is the largest display error) and no
    /// colour is clipped; the top code stands for `c = 2`. At version 13 cloud's sun
    /// became a quarter of what it was and the tone map gained its exposure: `c / 2`
    /// would have spent half of the codes on colours no cloud has.
    Display,
}

/// The exposure of [`ColourCurve::Display`]: [`crate::render::light::EXPOSURE`] at
/// version 13, fixed here because it is part of the format.
const CODE_EXPOSURE: f64 = 3.0;

impl ColourCurve {
    /// The curve of a header's ALGORITHM_VERSION.
    pub fn of(algorithm_version: u32) -> ColourCurve {
        if algorithm_version >= 13 {
            ColourCurve::Display
        } else {
            ColourCurve::Gamma
        }
    }

    /// The code value in [0, 1] of linear colour `c`.
    fn encode(self, c: f64) -> f64 {
        let c = if c.is_nan() { 0.0 } else { c.max(0.0) };
        match self {
            ColourCurve::Gamma => (c / 2.0).min(1.0).powf(1.0 / 2.2),
            ColourCurve::Display => (1.0 - (-CODE_EXPOSURE * c).exp()).powf(1.0 / 2.2),
        }
    }

    /// The linear colour of code value `q` in [0, 1].
    fn decode(self, q: f64) -> f64 {
        match self {
            ColourCurve::Gamma => 2.0 * q.powf(2.2),
            ColourCurve::Display if q >= 1.0 => 2.0,
            ColourCurve::Display => (-(1.0 - q.powf(2.2)).ln() / CODE_EXPOSURE).min(2.0),
        }
    }
}

/// The first ALGORITHM_VERSION whose colour codes carry the ambient part of a
/// billboard's colour (its sky and ground light) rather than the whole colour.
pub const AMBIENT_CODES_SINCE: u32 = 15;

/// The [`SunTerm`] of a header's lighting (offsets 92, 116, 136, 140), so an encoder
/// and every decoder compute it from the same f32 values. Since
/// [`AMBIENT_CODES_SINCE`] the colour codes carry `colour − S(τ_sun)`, and a decoder
/// adds `S(τ_sun')` of the dequantised `τ_sun'` back. A client drawing a billboard
/// under another layer takes the sun term away and evaluates it deeper
/// ([`crate::render::light::Lighting::beneath_layers`]): with the whole colour on the
/// codes, what is left (the small, dark ambient) carried the rounding of the large,
/// bright colour, up to 15/255 on the display under a deck (`cloudscape bench --only
/// wire`).
fn header_sun_term(sun_rgb: [f32; 3], albedo: f32, octaves: u32, abc: [f32; 3]) -> SunTerm {
    let octaves = Octaves {
        count: octaves,
        attenuation: abc[0] as f64,
        contribution: abc[1] as f64,
        eccentricity: abc[2] as f64,
    };
    SunTerm::new(sun_rgb.map(f64::from), albedo as f64, octaves)
}

/// The quantiser and dequantiser of the states.
#[derive(Clone, Copy)]
struct Codes {
    levels: f64,
    steps: f64,
    curve: ColourCurve,
    /// The sun term the colour codes leave out (since [`AMBIENT_CODES_SINCE`]).
    sun: Option<SunTerm>,
}

impl Codes {
    fn new(q: Quantisation, curve: ColourCurve) -> Codes {
        Codes {
            levels: ((1u32 << q.colour_bits.clamp(1, 8)) - 1) as f64,
            steps: q.tau_sun_steps.max(1) as f64,
            curve,
            sun: None,
        }
    }

    /// The codes of a file of `algorithm_version` lit by `sun`.
    fn of(q: Quantisation, algorithm_version: u32, sun: SunTerm) -> Codes {
        Codes {
            sun: (algorithm_version >= AMBIENT_CODES_SINCE).then_some(sun),
            ..Codes::new(q, ColourCurve::of(algorithm_version))
        }
    }

    /// The colour codes (green, red, blue) of `colour` with sun optical depth
    /// `tau_sun`: of the whole colour, or of its ambient part.
    fn colours(&self, colour: [f32; 3], tau_sun: f32) -> [u16; 3] {
        let part = match self.sun {
            None => colour.map(|c| c as f64),
            Some(sun) => {
                let s = sun.at(tau_sun as f64);
                [0, 1, 2].map(|i| (colour[i] as f64 - s[i]).max(0.0))
            }
        };
        [self.colour(part[1]), self.colour(part[0]), self.colour(part[2])]
    }

    /// The colour (red, green, blue) of the codes `grb` and the dequantised `tau_sun`.
    /// `sun` is the sun term of the site's dequantised `τ_sun` ([`Codes::sun_terms`]).
    fn colour_values(&self, grb: [u16; 3], sun: Option<&[f64; 3]>) -> [f32; 3] {
        let part = [grb[1], grb[0], grb[2]].map(|v| self.colour_value(v));
        match sun {
            None => part,
            Some(s) => [0, 1, 2].map(|i| (part[i] as f64 + s[i]).min(2.0) as f32),
        }
    }

    /// The sun term of every `τ_sun` code (0 to 255) when the colour codes leave it
    /// out: computed once a keyframe, not once a billboard.
    fn sun_terms(&self) -> Option<Vec<[f64; 3]>> {
        self.sun
            .map(|sun| (0..=255u16).map(|v| sun.at(self.tau_sun_value(v) as f64)).collect())
    }

    fn colour(&self, c: impl Into<f64>) -> u16 {
        (self.curve.encode(c.into()) * self.levels).round() as u16
    }

    fn colour_value(&self, v: u16) -> f32 {
        self.curve.decode(v.min(self.levels as u16) as f64 / self.levels) as f32
    }

    fn tau_sun(&self, t: f32) -> u16 {
        let t = if t.is_nan() { 0.0 } else { t.max(TAU_SUN_FLOOR) } as f64;
        (1.0 + (self.steps * (t / TAU_SUN_FLOOR as f64).ln()).round()).clamp(1.0, 255.0) as u16
    }

    fn tau_sun_value(&self, v: u16) -> f32 {
        (TAU_SUN_FLOOR as f64 * ((v.clamp(1, 255) as f64 - 1.0) / self.steps).exp()) as f32
    }

    fn state(&self, b: &Billboard) -> SiteState {
        if !(b.splat_tau > 0.0) {
            return SiteState::default();
        }
        SiteState {
            splat: b.splat + 1,
            grb: self.colours(b.colour, b.tau_sun),
            tau_sun: self.tau_sun(b.tau_sun),
        }
    }
}

/// Centre optical depth of splat `k` of a sheet of `count` (`SplatSheet::tau`).
pub fn splat_tau(k: u16, count: u16) -> f32 {
    let n = count.max(1) as f64;
    let x = (k.min(count.saturating_sub(1)) as f64 + 1.0) / n;
    (TAU_MAX * x * x) as f32
}

/// Reads or writes the residuals of the planes: the one traversal below serves the
/// encoder and the decoder, so they cannot disagree on the order.
trait Residuals {
    /// The value at the next site of `plane`, predicted `pred`: the encoder writes
    /// `actual − pred` and returns `actual`; the decoder reads the residual and
    /// returns `pred + residual`. Values are taken modulo 2^8, or 2^16 for `wide`
    /// (whose high bytes go to plane `plane + 1`).
    fn code(&mut self, plane: usize, pred: u32, actual: u16, wide: bool) -> Result<u16, String>;
}

struct Writer {
    planes: Vec<Vec<u8>>,
}

impl Residuals for Writer {
    fn code(&mut self, plane: usize, pred: u32, actual: u16, wide: bool) -> Result<u16, String> {
        let r = (actual as u32).wrapping_sub(pred);
        self.planes[plane].push(r as u8);
        if wide {
            self.planes[plane + 1].push((r >> 8) as u8);
        }
        Ok(actual)
    }
}

struct Reader<'a> {
    planes: Vec<&'a [u8]>,
    at: [usize; PLANES],
}

impl Residuals for Reader<'_> {
    fn code(&mut self, plane: usize, pred: u32, _actual: u16, wide: bool) -> Result<u16, String> {
        let mut take = |p: usize| {
            let b = self.planes[p].get(self.at[p]).copied();
            self.at[p] += 1;
            b.ok_or_else(|| format!("billboards.bin: plane {p} ends early (truncated or malformed)"))
        };
        let lo = take(plane)? as u32;
        let r = if wide { lo | (take(plane + 1)? as u32) << 8 } else { lo };
        let v = pred.wrapping_add(r);
        Ok(if wide { v as u16 } else { (v & 0xff) as u16 })
    }
}

/// LOCO-I's median edge detector from the left, upper and upper-left values (each
/// falling back on the others at the box's edges; 0 at its first site).
fn med(a: Option<u32>, b: Option<u32>, c: Option<u32>) -> u32 {
    let a2 = a.or(b).unwrap_or(0);
    let b2 = b.unwrap_or(a2);
    let c2 = c.unwrap_or(a2);
    let (a, b, c) = (a2 as i64, b2 as i64, c2 as i64);
    let p = if c >= a.max(b) {
        a.min(b)
    } else if c <= a.min(b) {
        a.max(b)
    } else {
        a + b - c
    };
    p as u32
}

/// Planes of one end: splat (low, high), green, red, blue, τ_sun (at `GREEN + 3`).
const SPLAT: usize = 0;
const GREEN: usize = 2;
const END: usize = 6;

/// The one traversal: every site of every level, start then end. `held` gives, for
/// a delta, the start state a client already holds (from the previous keyframe).
fn traverse(
    geometry: &SiteGeometry,
    wide: bool,
    held: &dyn Fn(usize, i64, i64) -> Option<SiteState>,
    start: &mut [SiteState],
    end: &mut [SiteState],
    coder: &mut dyn Residuals,
) -> Result<(), String> {
    let mut at = 0usize;
    for (k, l) in geometry.levels.iter().enumerate() {
        let (first, w) = l.box_columns();
        let level = at;
        for r in 0..l.rows as usize {
            let j = l.j0 + r as i64;
            for c in 0..w {
                let s = level + r * w + c;
                let i = first + c as i64;
                let left = (c > 0).then(|| s - 1);
                let up = (r > 0).then(|| s - w);
                let upleft = (c > 0 && r > 0).then(|| s - w - 1);
                let spatial = |states: &[SiteState], f: &dyn Fn(&SiteState) -> u16| {
                    med(
                        left.map(|x| f(&states[x]) as u32),
                        up.map(|x| f(&states[x]) as u32),
                        upleft.map(|x| f(&states[x]) as u32),
                    )
                };
                let inside = l.contains(k, i, j);
                // The start.
                let kept = if inside { held(k, i, j) } else { None };
                let pred = spatial(start, &|x| x.splat);
                let splat = match (inside, kept) {
                    (false, _) => 0,
                    (true, Some(h)) => h.splat,
                    (true, None) => coder.code(SPLAT, pred, start[s].splat, wide)?,
                };
                start[s].splat = splat;
                let mut drift = 0u32;
                for f in 0..4 {
                    let field = move |x: &SiteState| if f < 3 { x.grb[f] } else { x.tau_sun };
                    let pred = spatial(start, &field);
                    let v = match kept {
                        _ if splat == 0 => pred as u16,
                        Some(h) => field(&h),
                        None => {
                            let p = if f == 1 || f == 2 {
                                pred.wrapping_add(drift)
                            } else {
                                pred
                            };
                            coder.code(GREEN + f, p, field(&start[s]), false)? & 0xff
                        }
                    };
                    if f == 0 {
                        drift = (v as u32).wrapping_sub(pred);
                    }
                    set(&mut start[s], f, v);
                }
                // The end, from the start of the same site.
                let was = start[s];
                let esplat = if inside {
                    coder.code(END + SPLAT, was.splat as u32, end[s].splat, wide)?
                } else {
                    0
                };
                end[s].splat = esplat;
                let mut drift = 0u32;
                for f in 0..4 {
                    let field = move |x: &SiteState| if f < 3 { x.grb[f] } else { x.tau_sun };
                    let pred = if was.splat != 0 {
                        field(&was) as u32
                    } else {
                        spatial(end, &field)
                    };
                    let v = if esplat == 0 {
                        pred as u16
                    } else {
                        let p = if f == 1 || f == 2 {
                            pred.wrapping_add(drift)
                        } else {
                            pred
                        };
                        coder.code(END + GREEN + f, p, field(&end[s]), false)? & 0xff
                    };
                    if f == 0 {
                        drift = (v as u32).wrapping_sub(pred);
                    }
                    set(&mut end[s], f, v);
                }
            }
        }
        at += l.rows as usize * w;
    }
    Ok(())
}

fn set(s: &mut SiteState, f: usize, v: u16) {
    if f < 3 { s.grb[f] = v } else { s.tau_sun = v }
}

/// The dense start and end states of `tile` over `geometry`'s sites.
fn states_of(tile: &ShadedTile, geometry: &SiteGeometry, codes: Codes) -> (Vec<SiteState>, Vec<SiteState>) {
    let (bases, n) = geometry.bases();
    let (mut start, mut end) = (vec![SiteState::default(); n], vec![SiteState::default(); n]);
    for (a, b) in tile.billboards.iter().zip(&tile.end) {
        let [i, j, k] = a.index;
        let Some(s) = usize::try_from(k).ok().and_then(|k| geometry.index(&bases, k, i, j)) else {
            continue;
        };
        start[s] = codes.state(a);
        end[s] = codes.state(b);
    }
    (start, end)
}

/// The site geometry of the keyframe before `tile`'s, as a client holding it knows it.
fn previous_geometry(tile: &ShadedTile) -> SiteGeometry {
    // As the server places the previous keyframe: index − 1 on the same grid.
    let span = tile.keyframe.span();
    let t0 = tile.keyframe.index.saturating_sub(1) as f64 * span;
    SiteGeometry::spanning(tile, t0, (t0 + span).min(crate::world::MAX_TIME))
}

/// The sites of `geometry` whose start a client holding the previous keyframe
/// (`previous`) has: their predecessors lay in the tile at the previous start.
fn held_by(previous: &SiteGeometry, k: usize, i: i64, j: i64) -> bool {
    previous.levels.get(k).is_some_and(|p| {
        let (pi, pj) = (i.wrapping_sub(p.shift[0]), j.wrapping_sub(p.shift[1]));
        p.contains(k, pi, pj)
    })
}

/// `billboards.bin` version 3 of `tile` in `form`, quantised by `q`. A tile shaded
/// for an instant (no span) has no previous keyframe: its delta form is the
/// self-contained one.
pub fn encode(tile: &ShadedTile, form: Form, q: Quantisation) -> Vec<u8> {
    let q = Quantisation {
        colour_bits: q.colour_bits.clamp(1, 8),
        tau_sun_steps: q.tau_sun_steps.max(1),
    };
    let form = if tile.keyframe.is_instant() || tile.keyframe.t0 <= 0.0 {
        Form::SelfContained
    } else {
        form
    };
    let geometry = SiteGeometry::of(tile);
    let l = &tile.lighting;
    let octaves = l.billboard.octaves.sanitised();
    // The sun term of the header's f32 values, as every decoder computes it.
    let sun = header_sun_term(
        l.sun_rgb.map(|v| v as f32),
        l.params.albedo as f32,
        octaves.0,
        [octaves.1 as f32, octaves.2 as f32, octaves.3 as f32],
    );
    let codes = Codes::of(q, ALGORITHM_VERSION, sun);
    let (mut start, mut end) = states_of(tile, &geometry, codes);
    let s = tile.quality.settings();
    let wide = s.splat_count > 255;
    let previous = (form == Form::Delta).then(|| previous_geometry(tile));
    let snapshot = start.clone();
    let (bases, _) = geometry.bases();
    let held = |k: usize, i: i64, j: i64| {
        let p = previous.as_ref()?;
        held_by(p, k, i, j)
            .then(|| geometry.index(&bases, k, i, j).map(|x| snapshot[x]))
            .flatten()
    };
    let mut writer = Writer {
        planes: vec![Vec::new(); PLANES],
    };
    traverse(&geometry, wide, &held, &mut start, &mut end, &mut writer).expect("writing residuals cannot fail");
    let count = start
        .iter()
        .zip(&end)
        .filter(|(a, b)| a.splat != 0 || b.splat != 0)
        .count() as u32;

    let header_bytes = FIXED_BYTES + LEVEL_BYTES * geometry.levels.len() + 4 * PLANES;
    let body: usize = writer.planes.iter().map(Vec::len).sum();
    let mut out = Vec::with_capacity(header_bytes + body);
    let f32s = |out: &mut Vec<u8>, v: &[f64]| v.iter().for_each(|&x| out.extend_from_slice(&(x as f32).to_le_bytes()));
    out.extend_from_slice(&BIN_MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&form.code().to_le_bytes());
    out.extend_from_slice(&(header_bytes as u32).to_le_bytes());
    out.extend_from_slice(&tile.tile.z.to_le_bytes());
    out.extend_from_slice(&tile.tile.x.to_le_bytes());
    out.extend_from_slice(&tile.tile.y.to_le_bytes());
    out.extend_from_slice(&tile.origin[0].to_le_bytes());
    out.extend_from_slice(&tile.origin[1].to_le_bytes());
    f32s(&mut out, &[tile.sun.azimuth_deg, tile.sun.elevation_deg]);
    out.extend_from_slice(&(s.splat_count as u16).to_le_bytes());
    out.extend_from_slice(&(s.splat_size as u16).to_le_bytes());
    f32s(&mut out, &[tile.size]);
    out.extend_from_slice(&tile.keyframe.t0.to_le_bytes());
    out.extend_from_slice(&tile.keyframe.t1.to_le_bytes());
    f32s(&mut out, &l.sun_dir);
    f32s(&mut out, &l.sun_rgb);
    f32s(&mut out, &l.ambient_rgb);
    f32s(&mut out, &[l.params.albedo, l.params.extinction]);
    f32s(&mut out, &[l.params.phase.g1, l.params.phase.g2, l.params.phase.mix]);
    out.extend_from_slice(&octaves.0.to_le_bytes());
    f32s(&mut out, &[octaves.1, octaves.2, octaves.3]);
    out.extend_from_slice(&ALGORITHM_VERSION.to_le_bytes());
    out.extend_from_slice(&count.to_le_bytes());
    out.extend_from_slice(&geometry.spacing.to_le_bytes());
    out.extend_from_slice(&geometry.vertical_spacing.to_le_bytes());
    out.extend_from_slice(&geometry.base.to_le_bytes());
    out.extend_from_slice(&geometry.radius.to_le_bytes());
    out.push(q.colour_bits);
    out.push(q.tau_sun_steps);
    out.extend_from_slice(&(geometry.levels.len() as u16).to_le_bytes());
    out.extend_from_slice(&TAU_SUN_FLOOR.to_le_bytes());
    out.extend_from_slice(&(PLANES as u16).to_le_bytes());
    out.extend_from_slice(&((s.light_texel * 1000.0).round().clamp(0.0, 65535.0) as u16).to_le_bytes());
    debug_assert_eq!(out.len(), FIXED_BYTES);
    for l in &geometry.levels {
        for v in l.offset.iter().chain(&l.velocity) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for v in l.shift.iter().chain([&l.j0]) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&l.rows.to_le_bytes());
        for (first, n) in l.runs {
            out.extend_from_slice(&first.to_le_bytes());
            out.extend_from_slice(&n.to_le_bytes());
        }
        out.extend_from_slice(&0u32.to_le_bytes());
    }
    for p in &writer.planes {
        out.extend_from_slice(&(p.len() as u32).to_le_bytes());
    }
    debug_assert_eq!(out.len(), header_bytes);
    for p in &writer.planes {
        out.extend_from_slice(p);
    }
    out
}

/// A reader of little-endian fields that refuses to read past the end.
struct Fields<'a> {
    bytes: &'a [u8],
}

impl Fields<'_> {
    fn take<const N: usize>(&self, at: usize) -> Result<[u8; N], String> {
        self.bytes
            .get(at..at + N)
            .and_then(|b| b.try_into().ok())
            .ok_or_else(|| format!("billboards.bin: header ends at byte {} (truncated)", self.bytes.len()))
    }
    fn u8(&self, at: usize) -> Result<u8, String> {
        Ok(self.take::<1>(at)?[0])
    }
    fn u16(&self, at: usize) -> Result<u16, String> {
        Ok(u16::from_le_bytes(self.take(at)?))
    }
    fn u32(&self, at: usize) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.take(at)?))
    }
    fn i64(&self, at: usize) -> Result<i64, String> {
        Ok(i64::from_le_bytes(self.take(at)?))
    }
    fn f32(&self, at: usize) -> Result<f32, String> {
        Ok(f32::from_le_bytes(self.take(at)?))
    }
    fn f64(&self, at: usize) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.take(at)?))
    }
    fn f32x3(&self, at: usize) -> Result<[f32; 3], String> {
        Ok([self.f32(at)?, self.f32(at + 4)?, self.f32(at + 8)?])
    }
}

/// Decodes `billboards.bin` version 3. A delta needs `previous`, the decoded keyframe
/// of the same tile, quality and sun that ends where this one starts; a
/// self-contained keyframe ignores it.
pub fn decode(bytes: &[u8], previous: Option<&BinBillboards>) -> Result<BinBillboards, String> {
    let h = Fields { bytes };
    if bytes.len() < FIXED_BYTES || bytes[0..4] != BIN_MAGIC {
        return Err("not a cloudscape billboards.bin (bad magic or short header)".into());
    }
    let version = h.u16(4)?;
    if version != VERSION {
        return Err(format!("billboards.bin version {version} is not version 3"));
    }
    let form = match h.u16(6)? {
        0 => Form::SelfContained,
        1 => Form::Delta,
        f => return Err(format!("billboards.bin: unknown form {f}")),
    };
    let n_levels = h.u16(190)? as usize;
    let planes = h.u16(196)? as usize;
    if n_levels > MAX_LEVELS || planes != PLANES {
        return Err(format!(
            "billboards.bin: {n_levels} levels and {planes} planes (at most {MAX_LEVELS} levels, {PLANES} planes)"
        ));
    }
    let header_bytes = FIXED_BYTES + LEVEL_BYTES * n_levels + 4 * PLANES;
    if h.u32(8)? as usize != header_bytes {
        return Err(format!(
            "billboards.bin: the header says {} bytes, its tables {header_bytes}",
            h.u32(8)?
        ));
    }
    let mut levels = Vec::with_capacity(n_levels);
    let mut sites = 0usize;
    for k in 0..n_levels {
        let o = FIXED_BYTES + k * LEVEL_BYTES;
        let run = |at: usize| -> Result<(i64, u32), String> { Ok((h.i64(at)?, h.u32(at + 8)?)) };
        let l = LevelSites {
            offset: [h.f64(o)?, h.f64(o + 8)?],
            velocity: [h.f64(o + 16)?, h.f64(o + 24)?],
            shift: [h.i64(o + 32)?, h.i64(o + 40)?],
            j0: h.i64(o + 48)?,
            rows: h.u32(o + 56)?,
            runs: [run(o + 60)?, run(o + 72)?],
        };
        let far = |v: i64| v.checked_abs().is_none_or(|a| a > 1 << 52);
        if l.rows > MAX_SIDE
            || l.runs.iter().any(|r| r.1 > MAX_SIDE || far(r.0))
            || far(l.j0)
            || l.shift.iter().any(|&v| far(v))
        {
            return Err(format!("billboards.bin: level {k} has an impossible extent"));
        }
        sites += l.rows as usize * l.box_columns().1;
        if sites > MAX_SITES {
            return Err(format!("billboards.bin: more than {MAX_SITES} sites"));
        }
        levels.push(l);
    }
    let mut lengths = [0usize; PLANES];
    for (p, len) in lengths.iter_mut().enumerate() {
        *len = h.u32(FIXED_BYTES + n_levels * LEVEL_BYTES + 4 * p)? as usize;
    }
    let body: usize = lengths.iter().sum();
    if Some(bytes.len()) != header_bytes.checked_add(body) {
        return Err(format!(
            "billboards.bin holds {} bytes, its header says {}",
            bytes.len(),
            header_bytes as u128 + body as u128
        ));
    }
    let geometry = SiteGeometry {
        spacing: h.f64(160)?,
        vertical_spacing: h.f64(168)?,
        base: h.f64(176)?,
        radius: h.f32(184)?,
        levels,
    };
    let quantisation = Quantisation {
        colour_bits: h.u8(188)?,
        tau_sun_steps: h.u8(189)?,
    };
    if !(1..=8).contains(&quantisation.colour_bits) || quantisation.tau_sun_steps == 0 {
        return Err("billboards.bin: impossible quantisation".into());
    }
    let splat_count = h.u16(56)?;
    let (z, x, y) = (h.u32(12)?, h.i64(16)?, h.i64(24)?);
    let keyframe = [h.f64(64)?, h.f64(72)?];
    let sun = (h.f32(48)?, h.f32(52)?);

    let previous_lattice = match form {
        Form::SelfContained => None,
        Form::Delta => {
            let p = previous.ok_or_else(|| {
                format!(
                    "billboards.bin: a delta keyframe (tile {z}/{x}/{y}, t0 = {}) needs the previous keyframe of its tile",
                    keyframe[0]
                )
            })?;
            let lattice = p.lattice.as_ref().filter(|pl| {
                (p.z, p.x, p.y) == (z, x, y)
                    && p.keyframe
                        .is_some_and(|k| (k[1] - keyframe[0]).abs() <= 1e-9 * keyframe[0].abs().max(1.0))
                    && p.splat_count == splat_count
                    && (p.sun_azimuth_deg, p.sun_elevation_deg) == sun
                    && pl.quantisation == quantisation
                    && pl.geometry.levels.len() == geometry.levels.len()
            });
            Some(lattice.ok_or_else(|| {
                format!(
                    "billboards.bin: this delta follows keyframe t1 = {} of tile {z}/{x}/{y}, not the keyframe given (t1 = {:?}, tile {}/{}/{})",
                    keyframe[0],
                    p.keyframe.map(|k| k[1]),
                    p.z,
                    p.x,
                    p.y
                )
            })?)
        }
    };

    let (_, n) = geometry.bases();
    let (mut start, mut end) = (vec![SiteState::default(); n], vec![SiteState::default(); n]);
    let previous_bases = previous_lattice.map(|p| p.geometry.bases().0).unwrap_or_default();
    let held = |k: usize, i: i64, j: i64| -> Option<SiteState> {
        let prev = previous_lattice?;
        let pl = prev.geometry.levels.get(k)?;
        let (pi, pj) = (i.wrapping_sub(pl.shift[0]), j.wrapping_sub(pl.shift[1]));
        if !pl.contains(k, pi, pj) {
            return None;
        }
        prev.geometry
            .index(&previous_bases, k, pi, pj)
            .and_then(|s| prev.end.get(s).copied())
    };
    let mut reader = Reader {
        planes: Vec::with_capacity(PLANES),
        at: [0; PLANES],
    };
    let mut at = header_bytes;
    for len in lengths {
        reader.planes.push(&bytes[at..at + len]);
        at += len;
    }
    let wide = splat_count > 255;
    traverse(&geometry, wide, &held, &mut start, &mut end, &mut reader)?;
    if let Some(p) = (0..PLANES).find(|&p| reader.at[p] != lengths[p]) {
        return Err(format!(
            "billboards.bin: plane {p} holds {} bytes, the keyframe uses {}",
            lengths[p], reader.at[p]
        ));
    }
    let lattice = LatticeKeyframe {
        geometry,
        quantisation,
        start,
        end,
        shadow_widening: h.u16(198)? as f32 / 1000.0,
    };
    let lighting = BinLighting {
        sun_direction: h.f32x3(80)?,
        sun_rgb: h.f32x3(92)?,
        ambient_rgb: h.f32x3(104)?,
        albedo: h.f32(116)?,
        extinction_per_m: h.f32(120)?,
        phase: h.f32x3(124)?,
        octaves: h.u32(136)?,
        octave_abc: h.f32x3(140)?,
    };
    let codes = Codes::of(
        lattice.quantisation,
        h.u32(152)?,
        header_sun_term(lighting.sun_rgb, lighting.albedo, lighting.octaves, lighting.octave_abc),
    );
    let records = records(&lattice, [h.f64(32)?, h.f64(40)?], splat_count, codes);
    if records.len() != h.u32(156)? as usize {
        return Err(format!(
            "billboards.bin: {} billboards decoded, the header says {}",
            records.len(),
            h.u32(156)?
        ));
    }
    Ok(BinBillboards {
        version,
        z,
        x,
        y,
        origin: [h.f64(32)?, h.f64(40)?],
        sun_azimuth_deg: sun.0,
        sun_elevation_deg: sun.1,
        splat_count,
        splat_size: h.u16(58)?,
        size: h.f32(60)?,
        keyframe: Some(keyframe),
        lighting: Some(lighting),
        algorithm_version: Some(h.u32(152)?),
        records,
        lattice: Some(lattice),
    })
}

/// The billboards of a decoded lattice: every site with a ball at either end, in site
/// order, as version-2 records (an end without a ball draws nothing and keeps the
/// other end's light, as `render::tile` pairs them).
fn records(lattice: &LatticeKeyframe, origin: [f64; 2], splat_count: u16, codes: Codes) -> Vec<BinRecord> {
    let suns = codes.sun_terms();
    let g = &lattice.geometry;
    let mut out = Vec::new();
    let mut at = 0usize;
    for (k, l) in g.levels.iter().enumerate() {
        let (first, w) = l.box_columns();
        for r in 0..l.rows as usize {
            let j = l.j0 + r as i64;
            for c in 0..w {
                let s = at + r * w + c;
                let (a, b) = (lattice.start[s], lattice.end[s]);
                if a.splat == 0 && b.splat == 0 {
                    continue;
                }
                let light = |x: &SiteState| {
                    let sun = suns.as_ref().map(|t| &t[usize::from(x.tau_sun.min(255))]);
                    (codes.colour_values(x.grb, sun), codes.tau_sun_value(x.tau_sun))
                };
                let end = |x: &SiteState, other: &SiteState| {
                    let (colour, tau_sun) = light(if x.splat != 0 { x } else { other });
                    let (splat, tau) = if x.splat != 0 {
                        let k = (x.splat - 1).min(splat_count.saturating_sub(1));
                        (k, splat_tau(k, splat_count))
                    } else {
                        (0, 0.0)
                    };
                    BinEnd {
                        splat_tau: Some(tau),
                        splat,
                        opacity: to_u8(1.0 - (-tau).exp()),
                        sun_transmittance: to_u8((-tau_sun).exp()),
                        colour,
                        tau_sun,
                    }
                };
                let centre = g.centre(first + c as i64, j, k);
                out.push(BinRecord {
                    offset: [
                        (centre[0] - origin[0]) as f32,
                        (centre[1] - origin[1]) as f32,
                        centre[2] as f32,
                    ],
                    radius: g.radius,
                    velocity: l.velocity.map(|v| v as f32),
                    ends: [end(&a, &b), end(&b, &a)],
                });
            }
        }
        at += l.rows as usize * w;
    }
    out
}

#[cfg(test)]
mod tests;
