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
//! # Binary layout (`billboards.bin`), little-endian
//!
//! Header, 64 bytes:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `CSBB` |
//! | 4 | u16 | format version (1) |
//! | 6 | u16 | record size in bytes (36) |
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
//!
//! Records, 36 bytes each:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | f32 | x − origin x, metres |
//! | 4 | f32 | y − origin y, metres |
//! | 8 | f32 | altitude, metres |
//! | 12 | f32 | radius, metres |
//! | 16 | u16 | splat index |
//! | 18 | u8 | peak opacity × 255, rounded |
//! | 19 | u8 | sun transmittance × 255, rounded |
//! | 20 | 3 × f32 | colour, linear RGB |
//! | 32 | f32 | optical depth of the sun ray, τ_sun |

use serde_json::json;

use crate::render::ShadedTile;
use crate::world::ALGORITHM_VERSION;

/// Magic bytes of `billboards.bin`.
pub const BIN_MAGIC: [u8; 4] = *b"CSBB";
/// Version of the binary layout.
pub const BIN_VERSION: u16 = 1;
/// Size of the header, bytes.
pub const BIN_HEADER_BYTES: usize = 64;
/// Size of one record, bytes.
pub const BIN_RECORD_BYTES: usize = 36;

/// Rounds an f64 to a value that prints shortly in JSON (f32 precision), never NaN.
/// A finite value beyond f32's range keeps its f64 value (rounding it would give ±∞,
/// which JSON writes as `null`).
fn f(v: f64) -> f64 {
    let short = v as f32 as f64;
    if short.is_finite() {
        short
    } else if v.is_finite() {
        v
    } else {
        0.0
    }
}

/// The header fields shared by the JSON and the atlas manifest.
pub(crate) fn header_json(tile: &ShadedTile) -> serde_json::Value {
    let l = &tile.lighting;
    let s = tile.quality.settings();
    let octaves = l.params.octaves.sanitised();
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
    })
}

/// Fewest bytes one billboard takes in `billboards.json`: its keys and punctuation
/// (`{"position":[,,],"radius":,"splat":,"colour":[,,],"opacity":,
/// "sun_transmittance":,"density":},` is 94 bytes) and a digit per number.
const MIN_JSON_BYTES_PER_BILLBOARD: u64 = 100;

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

/// `billboards.json`: the header above plus
/// `"billboards": [{"position": [x, y, z], "radius", "splat", "colour": [r, g, b],
/// "opacity", "sun_transmittance", "tau_sun", "density"}]` and `"count"`.
pub fn encode_json(tile: &ShadedTile) -> Vec<u8> {
    /// One billboard as `serde_json` writes a `json!` map: keys in sorted order.
    #[derive(serde::Serialize)]
    struct Entry {
        colour: [f64; 3],
        density: f64,
        opacity: f64,
        position: [f64; 3],
        radius: f64,
        splat: u16,
        sun_transmittance: f64,
        tau_sun: f64,
    }
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
    let mut out = Vec::with_capacity(head.len() + 190 * tile.billboards.len());
    out.extend_from_slice(&head.as_bytes()[..at]);
    for (i, b) in tile.billboards.iter().enumerate() {
        if i > 0 {
            out.push(b',');
        }
        let e = Entry {
            colour: b.colour.map(|c| f(c as f64)),
            density: f(b.density as f64),
            opacity: f(b.opacity as f64),
            position: b.centre.map(f),
            radius: f(b.radius as f64),
            splat: b.splat,
            sun_transmittance: f(b.sun_transmittance as f64),
            tau_sun: f(b.tau_sun as f64),
        };
        serde_json::to_writer(&mut out, &e).expect("a billboard serialises");
    }
    out.extend_from_slice(&head.as_bytes()[at..]);
    out
}

/// `billboards.bin` (layout in the module docs).
pub fn encode_bin(tile: &ShadedTile) -> Vec<u8> {
    let s = tile.quality.settings();
    let mut out = Vec::with_capacity(BIN_HEADER_BYTES + BIN_RECORD_BYTES * tile.billboards.len());
    out.extend_from_slice(&BIN_MAGIC);
    out.extend_from_slice(&BIN_VERSION.to_le_bytes());
    out.extend_from_slice(&(BIN_RECORD_BYTES as u16).to_le_bytes());
    out.extend_from_slice(&(tile.billboards.len() as u32).to_le_bytes());
    out.extend_from_slice(&tile.tile.z.to_le_bytes());
    out.extend_from_slice(&tile.tile.x.to_le_bytes());
    out.extend_from_slice(&tile.tile.y.to_le_bytes());
    out.extend_from_slice(&tile.origin[0].to_le_bytes());
    out.extend_from_slice(&tile.origin[1].to_le_bytes());
    out.extend_from_slice(&(tile.sun.azimuth_deg as f32).to_le_bytes());
    out.extend_from_slice(&(tile.sun.elevation_deg as f32).to_le_bytes());
    out.extend_from_slice(&(s.splat_count as u16).to_le_bytes());
    out.extend_from_slice(&(s.splat_size as u16).to_le_bytes());
    out.extend_from_slice(&(tile.size as f32).to_le_bytes());
    debug_assert_eq!(out.len(), BIN_HEADER_BYTES);
    for b in &tile.billboards {
        out.extend_from_slice(&((b.centre[0] - tile.origin[0]) as f32).to_le_bytes());
        out.extend_from_slice(&((b.centre[1] - tile.origin[1]) as f32).to_le_bytes());
        out.extend_from_slice(&(b.centre[2] as f32).to_le_bytes());
        out.extend_from_slice(&b.radius.to_le_bytes());
        out.extend_from_slice(&b.splat.to_le_bytes());
        out.push(crate::render::image::to_u8(b.opacity));
        out.push(crate::render::image::to_u8(b.sun_transmittance));
        for c in b.colour {
            out.extend_from_slice(&c.to_le_bytes());
        }
        out.extend_from_slice(&b.tau_sun.to_le_bytes());
    }
    out
}

/// A decoded `billboards.bin`.
#[derive(Clone, Debug, PartialEq)]
pub struct BinBillboards {
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
    /// The billboards, in the order the tile lists them.
    pub records: Vec<BinRecord>,
}

/// One record of `billboards.bin`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinRecord {
    /// Offset from the tile origin (x, y) and altitude, metres.
    pub offset: [f32; 3],
    /// Billboard radius, metres.
    pub radius: f32,
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

/// Decodes `billboards.bin`; `Err` names what is wrong.
pub fn decode_bin(bytes: &[u8]) -> Result<BinBillboards, String> {
    if bytes.len() < BIN_HEADER_BYTES || bytes[0..4] != BIN_MAGIC {
        return Err("not a cloudscape billboards.bin (bad magic or short header)".into());
    }
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let i64_at = |o: usize| i64::from_le_bytes(bytes[o..o + 8].try_into().expect("8 bytes"));
    let f64_at = |o: usize| f64::from_le_bytes(bytes[o..o + 8].try_into().expect("8 bytes"));
    if u16_at(4) != BIN_VERSION || u16_at(6) as usize != BIN_RECORD_BYTES {
        return Err(format!(
            "unsupported billboards.bin version {} / record size {}",
            u16_at(4),
            u16_at(6)
        ));
    }
    let count = u32_at(8) as usize;
    if bytes.len() != BIN_HEADER_BYTES + count * BIN_RECORD_BYTES {
        return Err(format!(
            "billboards.bin holds {} bytes, expected {}",
            bytes.len(),
            BIN_HEADER_BYTES + count * BIN_RECORD_BYTES
        ));
    }
    let records = (0..count)
        .map(|i| {
            let o = BIN_HEADER_BYTES + i * BIN_RECORD_BYTES;
            BinRecord {
                offset: [f32_at(o), f32_at(o + 4), f32_at(o + 8)],
                radius: f32_at(o + 12),
                splat: u16_at(o + 16),
                opacity: bytes[o + 18],
                sun_transmittance: bytes[o + 19],
                colour: [f32_at(o + 20), f32_at(o + 24), f32_at(o + 28)],
                tau_sun: f32_at(o + 32),
            }
        })
        .collect();
    Ok(BinBillboards {
        z: u32_at(12),
        x: i64_at(16),
        y: i64_at(24),
        origin: [f64_at(32), f64_at(40)],
        sun_azimuth_deg: f32_at(48),
        sun_elevation_deg: f32_at(52),
        splat_count: u16_at(56),
        splat_size: u16_at(58),
        size: f32_at(60),
        records,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Quality, ShadingParams, Sun, TileId, shade_tile};
    use crate::world::Config;

    /// The naive encoding: the whole document as one `serde_json::Value`.
    fn encode_json_naive(tile: &ShadedTile) -> Vec<u8> {
        let mut v = header_json(tile);
        let list: Vec<serde_json::Value> = tile
            .billboards
            .iter()
            .map(|b| {
                json!({
                    "position": b.centre.map(f),
                    "radius": f(b.radius as f64),
                    "splat": b.splat,
                    "colour": b.colour.map(|c| f(c as f64)),
                    "opacity": f(b.opacity as f64),
                    "sun_transmittance": f(b.sun_transmittance as f64),
                    "tau_sun": f(b.tau_sun as f64),
                    "density": f(b.density as f64),
                })
            })
            .collect();
        v["format"] = json!("cloudscape-billboards");
        v["colour_space"] = json!("linear RGB, pre-shaded for an isotropic phase");
        v["count"] = json!(list.len());
        v["billboards"] = serde_json::Value::Array(list);
        serde_json::to_vec(&v).unwrap()
    }

    #[test]
    fn streamed_json_is_the_bytes_of_the_whole_value() {
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        for (tile, t) in [
            (TileId { z: 0, x: 0, y: 0 }, 43200.0),
            (TileId { z: 3, x: -1, y: 2 }, 1000.0),
        ] {
            let s = shade_tile(
                &world,
                0,
                tile,
                t,
                Quality::Fast,
                Sun::new(120.0, 30.0).unwrap(),
                &ShadingParams::default(),
                &config.limits,
                &crate::cancel::Cancel::never(),
            )
            .unwrap();
            assert!(!s.billboards.is_empty(), "{tile:?} has billboards to encode");
            assert_eq!(encode_json(&s), encode_json_naive(&s), "{tile:?}");
        }
    }
}
