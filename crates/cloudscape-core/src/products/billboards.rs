//! Billboard instance lists of a shaded tile: JSON, and a compact binary.
//!
//! Both hold the tile's shaded metaballs, ready to sort and draw as camera-facing
//! quads textured with splat `splat` of the sheet named in the header
//! (`/v1/splats.png?quality=Q`). `colour` is linear RGB pre-shaded for an isotropic
//! phase: `albedo · (sun_rgb · Σ_{i<N} bⁱ e^{−aⁱ τ} + ambient)`, with τ = `tau_sun`,
//! the scattering octaves (N, a, b, c) of the header's `lighting.octaves`
//! (src/render/light.rs, `Octaves`) and the ambient sky and ground light already
//! attenuated through the cloud above and below the ball. A client that wants the
//! phase function adds `albedo · sun_rgb · Σ bⁱ (p(cos θ; cⁱ g) − 1) e^{−aⁱ τ}`
//! (dual Henyey–Greenstein with both g scaled by cⁱ). Opacity is the splat's texel
//! value; `opacity` is its peak (centre) value.
//!
//! # Keyframes
//!
//! A billboard list covers one keyframe span `[t0, t1]` (`world::Keyframe`: one
//! automaton step at level 0, doubling per level up to 16 steps) and holds every
//! metaball at both ends, the end moved by the wind at its altitude. The metaball
//! lattice drifts with the wind, so the balls a span ends with are those the next
//! span starts with: at a boundary a client switches lists without a jump. A client
//! draws any time `t` inside the span by itself, with `f = (t − t0) / (t1 − t0)`:
//!
//! - position `p0 + v (t − t0)`, `v` the record's velocity (m/s);
//! - centre optical depth `(1 − f) τ0 + f τ1` (τ = 0 at an end where the ball is
//!   absent), and from it the opacity `1 − exp(−τ P(q))` at `q` radii² from the
//!   centre, P the splat profile: from the sheet, splat `k` nearest τ gives
//!   `1 − (1 − a_k(q))^(τ / τ_k)`;
//! - colour, `tau_sun`, sun transmittance and peak opacity linear in `f`.
//!
//! This is `render::keyframe`'s rule, which the server's own renderer uses too.
//!
//! # Binary layout (`billboards.bin`), little-endian
//!
//! Version 2. Header, 160 bytes (the first 64 as in version 1):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `CSBB` |
//! | 4 | u16 | format version (2) |
//! | 6 | u16 | record size in bytes (56) |
//! | 8 | u32 | record count |
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
//! | 72 | f64 | keyframe end t1 (the next keyframe's t0) |
//! | 80 | 3 × f32 | unit vector toward the sun (x east, y north, z up) |
//! | 92 | 3 × f32 | sun radiance at the clouds, linear RGB |
//! | 104 | 3 × f32 | ambient sky radiance, linear RGB |
//! | 116 | f32 | single-scattering albedo |
//! | 120 | f32 | extinction per metre at density 1 |
//! | 124 | 3 × f32 | phase: dual Henyey–Greenstein g1, g2 and the mix weight of g1 |
//! | 136 | u32 | scattering octaves N |
//! | 140 | 3 × f32 | octaves a, b, c |
//! | 152 | u32 | ALGORITHM_VERSION |
//! | 156 | u32 | reserved (0) |
//!
//! Records, 56 bytes each (end 0 is t0, end 1 is t1):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | f32 | x − origin x at t0, metres |
//! | 4 | f32 | y − origin y at t0, metres |
//! | 8 | f32 | altitude, metres |
//! | 12 | f32 | radius, metres |
//! | 16 | 2 × f32 | velocity (x, y), m/s: the wind at the altitude |
//! | 24 | 2 × f32 | centre optical depth τ at ends 0 and 1 (0: absent at that end) |
//! | 32 | 2 × u16 | splat index at ends 0 and 1 |
//! | 36 | 3 × f16 | colour at end 0, linear RGB |
//! | 42 | 3 × f16 | colour at end 1 |
//! | 48 | 2 × f16 | optical depth of the sun ray, τ_sun, at ends 0 and 1 |
//! | 52 | 2 × u8 | peak opacity × 255 at ends 0 and 1 |
//! | 54 | 2 × u8 | sun transmittance × 255 at ends 0 and 1 |
//!
//! f16 is IEEE 754 binary16 (WebGL2's `HALF_FLOAT`, three.js's `Float16BufferAttribute`).
//! Version 1 (64-byte header, 36-byte records: offset, radius, splat u16, opacity u8,
//! sun transmittance u8, colour 3 × f32, τ_sun f32; one time, no lighting) is still
//! read by [`decode_bin`].

use serde_json::json;

use super::json_f32 as f;
use crate::render::ShadedTile;
use crate::render::image::to_u8;
use crate::render::shade::Billboard;
use crate::world::ALGORITHM_VERSION;

/// Magic bytes of `billboards.bin`.
pub const BIN_MAGIC: [u8; 4] = *b"CSBB";
/// Version of the binary layout.
pub const BIN_VERSION: u16 = 2;
/// Size of the header, bytes.
pub const BIN_HEADER_BYTES: usize = 160;
/// Size of one record, bytes.
pub const BIN_RECORD_BYTES: usize = 56;
/// Header and record sizes of version 1, still decoded.
const BIN_V1_SIZES: (usize, usize) = (64, 36);

/// The header fields shared by the JSON and the atlas manifest.
pub(crate) fn header_json(tile: &ShadedTile) -> serde_json::Value {
    let l = &tile.lighting;
    let s = tile.quality.settings();
    let octaves = l.billboard.octaves.sanitised();
    json!({
        "algorithm_version": ALGORITHM_VERSION,
        "layer": tile.layer_name,
        "tile": { "z": tile.tile.z, "x": tile.tile.x, "y": tile.tile.y },
        "t": tile.t,
        "quality": tile.quality.as_str(),
        "origin": [tile.origin[0], tile.origin[1]],
        "size": tile.size,
        "sun": {
            "bucket": tile.bucket.id(),
            "azimuth_deg": f(tile.sun.azimuth_deg),
            "elevation_deg": f(tile.sun.elevation_deg),
            "direction": l.sun_dir.map(f),
        },
        "lighting": {
            "sun_rgb": l.sun_rgb.map(f),
            "ambient_rgb": l.ambient_rgb.map(f),
            "albedo": f(l.params.albedo),
            "extinction_per_m": f(l.params.extinction),
            "phase": { "model": "dual Henyey-Greenstein", "g1": f(l.params.phase.g1), "g2": f(l.params.phase.g2), "mix": f(l.params.phase.mix) },
            "octaves": {
                "model": "Wrenninge 2013 scattering octaves: sum over i < count of b^i sun p(theta; c^i g) exp(-a^i tau_sun)",
                "count": octaves.0,
                "a": f(octaves.1),
                "b": f(octaves.2),
                "c": f(octaves.3),
            },
        },
        "splats": {
            "count": s.splat_count,
            "size": s.splat_size,
            "tau_max": crate::render::splats::TAU_MAX,
        },
        "keyframe": {
            "t0": tile.keyframe.t0,
            "t1": tile.keyframe.t1,
            "rule": "at t in [t0, t1], f = (t - t0) / (t1 - t0): position + velocity (t - t0); splat_tau, colour, tau_sun, opacity, sun_transmittance linear in f between a billboard's two ends",
        },
    })
}

/// Fewest bytes one billboard takes in `billboards.json`: its keys and punctuation
/// (two ends of `{"colour":[,,],"density":,"opacity":,"splat":,"splat_tau":,
/// "sun_transmittance":,"tau_sun":}` are 2 × 96 bytes, the rest 58) and a digit per
/// number.
const MIN_JSON_BYTES_PER_BILLBOARD: u64 = 300;

/// [`encode_json`], or no bytes when the document would be over `max` bytes. The
/// empty body stands for "too large" (a JSON document is never empty), so a cache
/// can keep the answer and refuse a repeat without shading the tile again; a tile
/// whose count alone puts it over the limit is not even encoded.
pub fn encode_json_within(tile: &ShadedTile, max: u64) -> Vec<u8> {
    if tile.billboards.len() as u64 * MIN_JSON_BYTES_PER_BILLBOARD > max {
        return Vec::new();
    }
    let json = encode_json(tile);
    if json.len() as u64 > max { Vec::new() } else { json }
}

/// One end of a billboard in `billboards.json`.
#[derive(serde::Serialize)]
struct JsonEnd {
    colour: [f64; 3],
    density: f64,
    opacity: f64,
    splat: u16,
    splat_tau: f64,
    sun_transmittance: f64,
    tau_sun: f64,
}

impl JsonEnd {
    fn of(b: &Billboard) -> JsonEnd {
        JsonEnd {
            colour: b.colour.map(|c| f(c as f64)),
            density: f(b.density as f64),
            opacity: f(b.opacity as f64),
            splat: b.splat,
            splat_tau: f(b.splat_tau as f64),
            sun_transmittance: f(b.sun_transmittance as f64),
            tau_sun: f(b.tau_sun as f64),
        }
    }
}

/// One billboard as `serde_json` writes a `json!` map: keys in sorted order.
#[derive(serde::Serialize)]
struct JsonEntry {
    end: JsonEnd,
    position: [f64; 3],
    radius: f64,
    start: JsonEnd,
    velocity: [f64; 2],
}

impl JsonEntry {
    fn of(tile: &ShadedTile, i: usize) -> JsonEntry {
        let b = &tile.billboards[i];
        JsonEntry {
            end: JsonEnd::of(&tile.end[i]),
            position: b.centre.map(f),
            radius: f(b.radius as f64),
            start: JsonEnd::of(b),
            velocity: tile.velocity_at(b.centre[2]).map(f),
        }
    }
}

/// `billboards.json`: the header above plus `"billboards": [{"position": [x, y, z]
/// (at t0), "radius", "velocity": [vx, vy], "start": {..}, "end": {..}}]` (each end
/// `{"colour": [r, g, b], "density", "opacity", "splat", "splat_tau",
/// "sun_transmittance", "tau_sun"}`) and `"count"`.
pub fn encode_json(tile: &ShadedTile) -> Vec<u8> {
    let mut v = header_json(tile);
    v["format"] = json!("cloudscape-billboards");
    v["colour_space"] = json!("linear RGB, pre-shaded for an isotropic phase");
    v["count"] = json!(tile.billboards.len());
    v["billboards"] = json!([]);
    let head = serde_json::to_string(&v).expect("a JSON value serialises");
    // The list is written straight into the output (a `serde_json::Value` per
    // billboard would take ~900 bytes each while encoding), spliced where the empty
    // placeholder sorted: the same bytes as serialising the whole value.
    let at = head
        .find(r#""billboards":[]"#)
        .expect("the placeholder is in the header")
        + r#""billboards":["#.len();
    let mut out = Vec::with_capacity(head.len() + 380 * tile.billboards.len());
    out.extend_from_slice(&head.as_bytes()[..at]);
    for i in 0..tile.billboards.len() {
        if i > 0 {
            out.push(b',');
        }
        serde_json::to_writer(&mut out, &JsonEntry::of(tile, i)).expect("a billboard serialises");
    }
    out.extend_from_slice(&head.as_bytes()[at..]);
    out
}

/// `billboards.bin` (layout in the module docs).
pub fn encode_bin(tile: &ShadedTile) -> Vec<u8> {
    let s = tile.quality.settings();
    let l = &tile.lighting;
    let octaves = l.billboard.octaves.sanitised();
    let mut out = Vec::with_capacity(BIN_HEADER_BYTES + BIN_RECORD_BYTES * tile.billboards.len());
    let f32s = |out: &mut Vec<u8>, v: &[f64]| v.iter().for_each(|&x| out.extend_from_slice(&(x as f32).to_le_bytes()));
    out.extend_from_slice(&BIN_MAGIC);
    out.extend_from_slice(&BIN_VERSION.to_le_bytes());
    out.extend_from_slice(&(BIN_RECORD_BYTES as u16).to_le_bytes());
    out.extend_from_slice(&(tile.billboards.len() as u32).to_le_bytes());
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
    out.extend_from_slice(&0u32.to_le_bytes());
    debug_assert_eq!(out.len(), BIN_HEADER_BYTES);
    let f16s = |out: &mut Vec<u8>, v: &[f32]| {
        v.iter()
            .for_each(|&x| out.extend_from_slice(&half::f16::from_f32(x.min(F16_MAX)).to_le_bytes()))
    };
    for (a, b) in tile.billboards.iter().zip(&tile.end) {
        let v = tile.velocity_at(a.centre[2]);
        f32s(
            &mut out,
            &[a.centre[0] - tile.origin[0], a.centre[1] - tile.origin[1], a.centre[2]],
        );
        f32s(&mut out, &[a.radius as f64, v[0], v[1]]);
        out.extend_from_slice(&a.splat_tau.to_le_bytes());
        out.extend_from_slice(&b.splat_tau.to_le_bytes());
        out.extend_from_slice(&a.splat.to_le_bytes());
        out.extend_from_slice(&b.splat.to_le_bytes());
        f16s(&mut out, &a.colour);
        f16s(&mut out, &b.colour);
        f16s(&mut out, &[a.tau_sun, b.tau_sun]);
        out.extend_from_slice(&[to_u8(a.opacity), to_u8(b.opacity)]);
        out.extend_from_slice(&[to_u8(a.sun_transmittance), to_u8(b.sun_transmittance)]);
    }
    out
}

/// The largest finite f16: optical depths beyond it are written as it (e^−65504 is 0).
const F16_MAX: f32 = 65504.0;

/// The lighting a version-2 header carries (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinLighting {
    /// Unit vector toward the sun (x east, y north, z up).
    pub sun_direction: [f32; 3],
    /// Sun radiance at the clouds, linear RGB.
    pub sun_rgb: [f32; 3],
    /// Ambient sky radiance, linear RGB.
    pub ambient_rgb: [f32; 3],
    /// Single-scattering albedo.
    pub albedo: f32,
    /// Extinction per metre at density 1.
    pub extinction_per_m: f32,
    /// Dual Henyey–Greenstein g1, g2 and the weight of g1.
    pub phase: [f32; 3],
    /// Scattering octaves N.
    pub octaves: u32,
    /// Octaves a, b, c.
    pub octave_abc: [f32; 3],
}

/// A decoded `billboards.bin`.
#[derive(Clone, Debug, PartialEq)]
pub struct BinBillboards {
    /// Format version read (1 or 2).
    pub version: u16,
    /// Tile level.
    pub z: u32,
    /// Tile column (east).
    pub x: i64,
    /// Tile row (north).
    pub y: i64,
    /// South-west corner of the tile, metres (x east, y north).
    pub origin: [f64; 2],
    /// Azimuth of the sun the tile was shaded for (its bucket's centre), degrees.
    pub sun_azimuth_deg: f32,
    /// Elevation of that sun, degrees.
    pub sun_elevation_deg: f32,
    /// Splats in the sheet the records index.
    pub splat_count: u16,
    /// Side of one splat, pixels.
    pub splat_size: u16,
    /// Side of the tile, metres.
    pub size: f32,
    /// The keyframe span `[t0, t1]` (version 2; `None` for version 1, one time).
    pub keyframe: Option<[f64; 2]>,
    /// The lighting the records were shaded with (version 2).
    pub lighting: Option<BinLighting>,
    /// `ALGORITHM_VERSION` of the server that wrote it (version 2).
    pub algorithm_version: Option<u32>,
    /// The billboards, in the order the tile lists them.
    pub records: Vec<BinRecord>,
    /// Version 3: the lattice sites and their quantised states, which the next
    /// keyframe's delta form is decoded against.
    pub lattice: Option<super::keyframe_bin::LatticeKeyframe>,
}

/// One end of a record of `billboards.bin`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinEnd {
    /// Centre optical depth the splat is drawn with (0: nothing to draw); `None` in
    /// version 1, where it is the splat's own (`SplatSheet::tau(splat)`).
    pub splat_tau: Option<f32>,
    /// Index of its splat in the sheet.
    pub splat: u16,
    /// Peak opacity × 255.
    pub opacity: u8,
    /// Transmittance of the sun ray to its centre × 255.
    pub sun_transmittance: u8,
    /// Linear RGB, pre-shaded for an isotropic phase (`render::shade::Billboard::colour`).
    pub colour: [f32; 3],
    /// Optical depth of the sun ray.
    pub tau_sun: f32,
}

/// One record of `billboards.bin`: a billboard at both ends of the span (version 1:
/// both ends the same, velocity 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinRecord {
    /// Offset from the tile origin (x, y) and altitude at t0, metres.
    pub offset: [f32; 3],
    /// Billboard radius, metres.
    pub radius: f32,
    /// Wind velocity at its altitude (x, y), m/s.
    pub velocity: [f32; 2],
    /// The billboard at t0 and at t1.
    pub ends: [BinEnd; 2],
}

/// Decodes a self-contained `billboards.bin` of version 3, 2 or 1; `Err` names what
/// is wrong. A version-3 delta needs its previous keyframe: [`decode_bin_after`].
pub fn decode_bin(bytes: &[u8]) -> Result<BinBillboards, String> {
    decode_bin_after(bytes, None)
}

/// Decodes `billboards.bin` of any version a client may hold the previous keyframe
/// of: a version-3 delta is decoded against `previous` (the same tile's keyframe that
/// ends where it starts), anything else alone.
pub fn decode_bin_after(bytes: &[u8], previous: Option<&BinBillboards>) -> Result<BinBillboards, String> {
    if bytes.len() < BIN_V1_SIZES.0 || bytes[0..4] != BIN_MAGIC {
        return Err("not a cloudscape billboards.bin (bad magic or short header)".into());
    }
    if u16::from_le_bytes([bytes[4], bytes[5]]) == super::keyframe_bin::VERSION {
        return super::keyframe_bin::decode(bytes, previous);
    }
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let f16_at = |o: usize| half::f16::from_le_bytes([bytes[o], bytes[o + 1]]).to_f32();
    let i64_at = |o: usize| i64::from_le_bytes(bytes[o..o + 8].try_into().expect("8 bytes"));
    let f64_at = |o: usize| f64::from_le_bytes(bytes[o..o + 8].try_into().expect("8 bytes"));
    let f32x3 = |o: usize| [f32_at(o), f32_at(o + 4), f32_at(o + 8)];
    let version = u16_at(4);
    let (header, record) = match version {
        1 => BIN_V1_SIZES,
        2 => (BIN_HEADER_BYTES, BIN_RECORD_BYTES),
        v => return Err(format!("unsupported billboards.bin version {v}")),
    };
    if u16_at(6) as usize != record {
        return Err(format!(
            "billboards.bin version {version} has {record}-byte records, not {}",
            u16_at(6)
        ));
    }
    let count = u32_at(8) as usize;
    if Some(bytes.len()) != count.checked_mul(record).and_then(|r| r.checked_add(header)) {
        return Err(format!(
            "billboards.bin holds {} bytes, expected {} for {count} records",
            bytes.len(),
            header as u128 + count as u128 * record as u128
        ));
    }
    let records = (0..count)
        .map(|i| {
            let o = header + i * record;
            if version == 1 {
                let end = BinEnd {
                    splat_tau: None,
                    splat: u16_at(o + 16),
                    opacity: bytes[o + 18],
                    sun_transmittance: bytes[o + 19],
                    colour: f32x3(o + 20),
                    tau_sun: f32_at(o + 32),
                };
                return BinRecord {
                    offset: f32x3(o),
                    radius: f32_at(o + 12),
                    velocity: [0.0; 2],
                    ends: [end; 2],
                };
            }
            let end = |e: usize| BinEnd {
                splat_tau: Some(f32_at(o + 24 + 4 * e)),
                splat: u16_at(o + 32 + 2 * e),
                opacity: bytes[o + 52 + e],
                sun_transmittance: bytes[o + 54 + e],
                colour: [0, 1, 2].map(|c| f16_at(o + 36 + 6 * e + 2 * c)),
                tau_sun: f16_at(o + 48 + 2 * e),
            };
            BinRecord {
                offset: f32x3(o),
                radius: f32_at(o + 12),
                velocity: [f32_at(o + 16), f32_at(o + 20)],
                ends: [end(0), end(1)],
            }
        })
        .collect();
    let v2 = version == 2;
    Ok(BinBillboards {
        version,
        z: u32_at(12),
        x: i64_at(16),
        y: i64_at(24),
        origin: [f64_at(32), f64_at(40)],
        sun_azimuth_deg: f32_at(48),
        sun_elevation_deg: f32_at(52),
        splat_count: u16_at(56),
        splat_size: u16_at(58),
        size: f32_at(60),
        keyframe: v2.then(|| [f64_at(64), f64_at(72)]),
        lighting: v2.then(|| BinLighting {
            sun_direction: f32x3(80),
            sun_rgb: f32x3(92),
            ambient_rgb: f32x3(104),
            albedo: f32_at(116),
            extinction_per_m: f32_at(120),
            phase: f32x3(124),
            octaves: u32_at(136),
            octave_abc: f32x3(140),
        }),
        algorithm_version: v2.then(|| u32_at(152)),
        records,
        lattice: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Quality, ShadingParams, Sun, TileId, shade_tile};
    use crate::world::{Config, Keyframe};

    /// The naive encoding: the whole document as one `serde_json::Value`.
    fn encode_json_naive(tile: &ShadedTile) -> Vec<u8> {
        let end = |b: &Billboard| {
            json!({
                "colour": b.colour.map(|c| f(c as f64)),
                "density": f(b.density as f64),
                "opacity": f(b.opacity as f64),
                "splat": b.splat,
                "splat_tau": f(b.splat_tau as f64),
                "sun_transmittance": f(b.sun_transmittance as f64),
                "tau_sun": f(b.tau_sun as f64),
            })
        };
        let mut v = header_json(tile);
        let list: Vec<serde_json::Value> = (0..tile.billboards.len())
            .map(|i| {
                let b = &tile.billboards[i];
                json!({
                    "position": b.centre.map(f),
                    "radius": f(b.radius as f64),
                    "velocity": tile.velocity_at(b.centre[2]).map(f),
                    "start": end(b),
                    "end": end(&tile.end[i]),
                })
            })
            .collect();
        v["format"] = json!("cloudscape-billboards");
        v["colour_space"] = json!("linear RGB, pre-shaded for an isotropic phase");
        v["count"] = json!(list.len());
        v["billboards"] = serde_json::Value::Array(list);
        serde_json::to_vec(&v).unwrap()
    }

    fn shaded(tile: TileId, t: f64) -> ShadedTile {
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        shade_tile(
            &world,
            0,
            tile,
            Keyframe::containing(t, &world.layers[0], tile.z),
            Quality::Fast,
            Sun::new(120.0, 30.0).unwrap(),
            &ShadingParams::default(),
            &config.limits,
            &crate::cancel::Cancel::never(),
        )
        .unwrap()
    }

    #[test]
    fn streamed_json_is_the_bytes_of_the_whole_value() {
        for (tile, t) in [
            (TileId { z: 0, x: 0, y: 0 }, 43200.0),
            (TileId { z: 3, x: -1, y: 2 }, 1000.0),
        ] {
            let s = shaded(tile, t);
            assert!(!s.billboards.is_empty(), "{tile:?} has billboards to encode");
            assert_eq!(encode_json(&s), encode_json_naive(&s), "{tile:?}");
            let min = s.billboards.len() as u64 * MIN_JSON_BYTES_PER_BILLBOARD;
            assert!(
                encode_json(&s).len() as u64 > min,
                "MIN_JSON_BYTES_PER_BILLBOARD is a lower bound"
            );
        }
    }

    #[test]
    fn binary_round_trips_both_ends_within_f16() {
        let s = shaded(TileId { z: 0, x: 0, y: 0 }, 43210.0);
        let bytes = encode_bin(&s);
        assert_eq!(bytes.len(), BIN_HEADER_BYTES + BIN_RECORD_BYTES * s.billboards.len());
        let d = decode_bin(&bytes).unwrap();
        assert_eq!((d.version, d.z, d.x, d.y), (2, 0, 0, 0));
        assert_eq!(d.keyframe, Some([43200.0, 43220.0]));
        assert_eq!(d.algorithm_version, Some(ALGORITHM_VERSION));
        let l = d.lighting.unwrap();
        assert_eq!(l.sun_direction, s.lighting.sun_dir.map(|v| v as f32));
        assert_eq!(l.octaves, s.lighting.billboard.octaves.sanitised().0);
        // Some balls form or vanish within a span, most persist.
        let absent = |e: &BinEnd| e.splat_tau == Some(0.0);
        assert!(d.records.iter().any(|r| absent(&r.ends[0]) || absent(&r.ends[1])));
        assert!(
            d.records
                .iter()
                .filter(|r| !absent(&r.ends[0]) && !absent(&r.ends[1]))
                .count()
                > d.records.len() / 2
        );
        for (i, r) in d.records.iter().enumerate() {
            let (a, b) = (&s.billboards[i], &s.end[i]);
            assert_eq!(r.offset[2], a.centre[2] as f32);
            let v = s.velocity_at(a.centre[2]);
            assert_eq!(r.velocity, v.map(|x| x as f32));
            for (e, bb) in [(0, a), (1, b)] {
                let end = &r.ends[e];
                assert_eq!(end.splat_tau, Some(bb.splat_tau));
                assert_eq!(end.splat, bb.splat);
                for c in 0..3 {
                    // binary16: 11 significant bits.
                    assert!((end.colour[c] - bb.colour[c]).abs() <= bb.colour[c].abs() / 1024.0 + 1e-7);
                }
                assert!((end.tau_sun - bb.tau_sun.min(F16_MAX)).abs() <= bb.tau_sun.min(F16_MAX) / 1024.0 + 1e-7);
            }
            // The end is where the wind takes the start over the span.
            let moved = [a.centre[0] + v[0] * 20.0, a.centre[1] + v[1] * 20.0];
            assert!((moved[0] - b.centre[0]).abs() < 1e-6 && (moved[1] - b.centre[1]).abs() < 1e-6);
        }
        // Truncated or padded bytes are refused with a reason.
        assert!(decode_bin(&bytes[..bytes.len() - 1]).unwrap_err().contains("expected"));
        let mut wrong = bytes.clone();
        wrong[4] = 9;
        assert!(decode_bin(&wrong).unwrap_err().contains("version 9"));
    }

    #[test]
    fn version_1_is_still_read() {
        // A version-1 file written by hand from its layout: 64-byte header, one record.
        let mut v1 = Vec::new();
        v1.extend_from_slice(b"CSBB");
        v1.extend_from_slice(&1u16.to_le_bytes());
        v1.extend_from_slice(&36u16.to_le_bytes());
        v1.extend_from_slice(&1u32.to_le_bytes());
        v1.extend_from_slice(&2u32.to_le_bytes());
        v1.extend_from_slice(&(-3i64).to_le_bytes());
        v1.extend_from_slice(&4i64.to_le_bytes());
        v1.extend_from_slice(&(-76800.0f64).to_le_bytes());
        v1.extend_from_slice(&102400.0f64.to_le_bytes());
        for x in [150.0f32, 40.0] {
            v1.extend_from_slice(&x.to_le_bytes());
        }
        v1.extend_from_slice(&64u16.to_le_bytes());
        v1.extend_from_slice(&33u16.to_le_bytes());
        v1.extend_from_slice(&102400.0f32.to_le_bytes());
        for x in [10.0f32, 20.0, 1500.0, 300.0] {
            v1.extend_from_slice(&x.to_le_bytes());
        }
        v1.extend_from_slice(&7u16.to_le_bytes());
        v1.extend_from_slice(&[200, 100]);
        for x in [0.5f32, 0.6, 0.7, 1.25] {
            v1.extend_from_slice(&x.to_le_bytes());
        }
        let d = decode_bin(&v1).unwrap();
        assert_eq!(
            (d.version, d.z, d.x, d.y, d.origin),
            (1, 2, -3, 4, [-76800.0, 102400.0])
        );
        assert_eq!((d.keyframe, d.lighting, d.algorithm_version), (None, None, None));
        let r = d.records[0];
        assert_eq!(
            (r.offset, r.radius, r.velocity),
            ([10.0, 20.0, 1500.0], 300.0, [0.0, 0.0])
        );
        let e = BinEnd {
            splat_tau: None,
            splat: 7,
            opacity: 200,
            sun_transmittance: 100,
            colour: [0.5, 0.6, 0.7],
            tau_sun: 1.25,
        };
        assert_eq!(r.ends, [e, e]);
    }
}
