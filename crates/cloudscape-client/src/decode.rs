//! Decoders of the served products and the plan of a remote render: everything the
//! client does except networking, so the blocking and async fetchers share it and a
//! caller with its own HTTP stack can use it alone.

use std::io::Cursor;

use serde::Deserialize;

use cloudscape_core::products::Product;
use cloudscape_core::products::billboards::{BinBillboards, BinEnd, decode_bin};
use cloudscape_core::render::camera::View;
use cloudscape_core::render::composite::composite;
use cloudscape_core::render::keyframe::between;
use cloudscape_core::render::light::Lighting;
use cloudscape_core::render::scene::{LayerBand, background, mean_shadow, plan_bands};
use cloudscape_core::render::shade::Billboard;
use cloudscape_core::render::splats::SplatSheet;
use cloudscape_core::render::tile::{TILE_COLUMNS, TileId, shadow_lookup, shadow_shift};
use cloudscape_core::render::{Quality, RenderError, RenderRequest, Rendered, Sun};
use cloudscape_core::world::{Keyframe, keyframe_span, prefetch_at};

use crate::ClientError;

/// One layer of a remote world, as discovery (`/v1/worlds/{world}`) describes it.
#[derive(Clone, Debug, Deserialize)]
pub struct RemoteLayer {
    pub name: String,
    pub base: f64,
    pub top: f64,
    pub cell_size: f64,
    /// Seconds per automaton step: the keyframe span of level z is
    /// `world::keyframe_span(dt, z)`.
    pub dt: f64,
}

/// The parts of a remote world's discovery document the client uses.
#[derive(Clone, Debug, Deserialize)]
pub struct RemoteWorld {
    pub name: String,
    pub maxzoom: u32,
    pub layers: Vec<RemoteLayer>,
}

impl RemoteWorld {
    /// The layers' height bands and cell sizes, as the level choice reads them.
    pub fn bands(&self) -> Vec<LayerBand> {
        self.layers
            .iter()
            .map(|l| LayerBand {
                base: l.base,
                top: l.top,
                cell_size: l.cell_size,
            })
            .collect()
    }
}

#[derive(Deserialize)]
struct SplatManifest {
    count: usize,
    size: usize,
    columns: usize,
}

/// A tile's ground shadow map at both ends of its keyframe span, decoded from
/// `shadow.png`.
struct ShadowMap {
    origin: [f64; 2],
    column: f64,
    /// Added to a ground point before the lookup (`render::tile::shadow_shift`).
    shift: [f64; 2],
    /// Transmittance at the span's start and end, 256×256 each, row 0 = south.
    ends: [Vec<f32>; 2],
    /// Where the drawn time falls in the span.
    fraction: f64,
}

impl ShadowMap {
    /// Bilinear lookup of each end, blended (as `ShadedTile::shadow_at`); 1 outside
    /// the tile.
    fn at(&self, x: f64, y: f64) -> f64 {
        let (x, y) = (x + self.shift[0], y + self.shift[1]);
        let [a, b] = &self.ends;
        let a = shadow_lookup(a, self.origin, self.column, x, y);
        let b = shadow_lookup(b, self.origin, self.column, x, y);
        (1.0 - self.fraction) * a + self.fraction * b
    }

    /// The mean transmittance drawn.
    fn mean(&self) -> f64 {
        let mean = |v: &[f32]| v.iter().map(|&v| v as f64).sum::<f64>() / v.len().max(1) as f64;
        (1.0 - self.fraction) * mean(&self.ends[0]) + self.fraction * mean(&self.ends[1])
    }
}

/// Percent-encodes a path segment or query value (RFC 3986 unreserved kept).
pub fn encode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// Decodes an 8-bit PNG into (width, height, channels, samples).
fn decode_png(bytes: &[u8]) -> Result<(usize, usize, usize, Vec<u8>), String> {
    let mut reader = png::Decoder::new(Cursor::new(bytes))
        .read_info()
        .map_err(|e| e.to_string())?;
    let mut buf = vec![0; reader.output_buffer_size().ok_or("PNG too large")?];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    if info.bit_depth != png::BitDepth::Eight {
        return Err(format!("expected an 8-bit PNG, got {:?}", info.bit_depth));
    }
    buf.truncate(info.buffer_size());
    Ok((
        info.width as usize,
        info.height as usize,
        info.color_type.samples(),
        buf,
    ))
}

/// Decodes a splat sheet from its manifest (`/v1/splats.json`) and PNG (`/v1/splats.png`).
pub fn decode_splat_sheet(manifest: &[u8], png: &[u8]) -> Result<SplatSheet, String> {
    let manifest: SplatManifest = serde_json::from_slice(manifest).map_err(|e| e.to_string())?;
    let (width, height, channels, samples) = decode_png(png)?;
    let (n, s, cols) = (manifest.count, manifest.size, manifest.columns.max(1));
    if channels != 2 || width < cols * s || height < n.div_ceil(cols) * s {
        return Err(format!(
            "a {width}×{height} sheet with {channels} channels cannot hold {n} splats of {s}×{s} in {cols} columns"
        ));
    }
    let mut alpha = Vec::with_capacity(n * s * s);
    for k in 0..n {
        let (gx, gy) = ((k % cols) * s, (k / cols) * s);
        for v in 0..s {
            for u in 0..s {
                alpha.push(samples[((gy + v) * width + gx + u) * 2 + 1] as f32 / 255.0);
            }
        }
    }
    Ok(SplatSheet {
        count: n,
        size: s,
        alpha,
    })
}

/// Decodes a tile's `shadow.png` (R the span's start, G its end) for the billboard
/// tile it belongs to, to be drawn a `fraction` of the way through the span.
fn decode_shadow_map(png: &[u8], tile: &BinBillboards, base: f64, fraction: f64) -> Result<ShadowMap, String> {
    let n = TILE_COLUMNS;
    let (width, height, channels, samples) = decode_png(png)?;
    if (width, height, channels) != (n, n, 3) {
        return Err(format!(
            "expected a {n}×{n} RGB shadow map, got {width}×{height}×{channels}"
        ));
    }
    // PNG row 0 is north; the map's row 0 is south.
    let end = |e: usize| {
        let mut values = Vec::with_capacity(n * n);
        for row in (0..n).rev() {
            values.extend(
                samples[3 * row * n..3 * (row + 1) * n]
                    .chunks_exact(3)
                    .map(|p| p[e] as f32 / 255.0),
            );
        }
        values
    };
    let sun = Sun::new(tile.sun_azimuth_deg as f64, tile.sun_elevation_deg as f64).unwrap_or(Sun {
        azimuth_deg: 0.0,
        elevation_deg: 90.0,
    });
    Ok(ShadowMap {
        origin: tile.origin,
        column: tile.size as f64 / n as f64,
        shift: shadow_shift(sun, base),
        ends: [end(0), end(1)],
        fraction,
    })
}

/// The billboards of a decoded `billboards.bin` at time `t`, by the animation rule
/// (`render::keyframe`): both ends of each record, moved and blended. Version-1
/// records (one time) draw as they are, their optical depth the sheet's.
pub fn billboards_at(decoded: &BinBillboards, sheet: &SplatSheet, t: f64) -> Vec<Billboard> {
    let [t0, t1] = decoded.keyframe.unwrap_or([t, t]);
    let span = t1 - t0;
    let f = if span > 0.0 {
        ((t - t0) / span).clamp(0.0, 1.0)
    } else {
        0.0
    };
    decoded
        .records
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let centre = [
                decoded.origin[0] + r.offset[0] as f64,
                decoded.origin[1] + r.offset[1] as f64,
                r.offset[2] as f64,
            ];
            let end = |e: &BinEnd| Billboard {
                index: [i as i64, 0, 0],
                centre,
                radius: r.radius,
                density: 0.0,
                tau: 0.0,
                splat: e.splat,
                splat_tau: e.splat_tau.unwrap_or_else(|| sheet.tau(e.splat as usize) as f32),
                opacity: e.opacity as f32 / 255.0,
                tau_sun: e.tau_sun,
                sun_transmittance: e.sun_transmittance as f32 / 255.0,
                colour: e.colour,
            };
            let velocity = r.velocity.map(|v| v as f64);
            between(&end(&r.ends[0]), &end(&r.ends[1]), velocity, f * span, f)
        })
        .collect()
}

/// The path of a world's discovery document.
pub fn world_path(world: &str) -> String {
    format!("/v1/worlds/{}", encode(world))
}

/// Refuses a request a remote render cannot serve, before anything is fetched:
/// billboard presets only (`reference` marches the density volume, which the server
/// does not serve as billboards).
pub fn check_remote(req: &RenderRequest) -> Result<(), ClientError> {
    if req.quality.is_volumetric() {
        return Err(RenderError::BadRequest(format!(
            "quality `{}` renders the density locally; a remote render draws billboards (fast, balanced, accurate)",
            req.quality.as_str()
        ))
        .into());
    }
    Ok(())
}

/// A remote render once the world's discovery document is known: the paths to fetch
/// ([`RemoteRender::paths`]) and how their bodies become a picture
/// ([`RemoteRender::compose`]).
pub struct RemoteRender {
    world: String,
    req: RenderRequest,
    info: RemoteWorld,
    bands: Vec<LayerBand>,
    tiles: Vec<(usize, TileId)>,
    query: String,
}

impl RemoteRender {
    /// Plans `req` against `world`'s discovery document: the same level choice as a
    /// local `cloudscape render`.
    pub fn plan(world: &str, info: RemoteWorld, req: &RenderRequest) -> Result<RemoteRender, ClientError> {
        check_remote(req)?;
        let bands = info.bands();
        let tiles = plan_bands(&bands, info.maxzoom, req)?;
        let mut query = format!("quality={}", req.quality.as_str());
        if let Some(sun) = req.sun {
            query.push_str(&format!("&sun={},{}", sun.azimuth_deg, sun.elevation_deg));
        }
        Ok(RemoteRender {
            world: world.to_string(),
            req: *req,
            info,
            bands,
            tiles,
            query,
        })
    }

    /// The keyframe span of a tile of `layer` that holds the request's time.
    fn keyframe(&self, layer: usize, tile: TileId) -> Keyframe {
        Keyframe::on_grid(self.req.t, keyframe_span(self.info.layers[layer].dt, tile.z))
    }

    /// A tile product's keyframe URL: `t` is the keyframe's own time, so the answer
    /// is immutable and every client in the span asks the same URL.
    fn tile_path(&self, layer: usize, tile: TileId, product: Product) -> String {
        self.tile_path_at(layer, tile, product, self.keyframe(layer, tile).t0)
    }

    /// A tile product's URL at keyframe time `t0`.
    fn tile_path_at(&self, layer: usize, tile: TileId, product: Product, t0: f64) -> String {
        format!(
            "/v1/worlds/{}/tiles/{}/{}/{}/{}?t={}&{}&layer={}",
            encode(&self.world),
            tile.z,
            tile.x,
            tile.y,
            product.name(),
            t0,
            self.query,
            encode(&self.info.layers[layer].name)
        )
    }

    /// What to fetch, in the order [`RemoteRender::compose`] takes the bodies: the
    /// splat manifest and sheet, then each tile's `billboards.bin` and `shadow.png`.
    pub fn paths(&self) -> Vec<String> {
        let mut paths = splat_paths(self.req.quality).to_vec();
        for &(layer, tile) in &self.tiles {
            paths.push(self.tile_path(layer, tile, Product::BillboardsBin));
            paths.push(self.tile_path(layer, tile, Product::ShadowPng));
        }
        paths
    }

    /// The next keyframe's products of every tile whose span the request's time is
    /// past the tile's prefetch point ([`cloudscape_core::world::prefetch_at`], in the
    /// second half of the span): what an animating client fetches ahead of need.
    pub fn prefetch_paths(&self) -> Vec<String> {
        let mut paths = Vec::new();
        for &(layer, tile) in &self.tiles {
            let k = self.keyframe(layer, tile);
            if k.fraction(self.req.t) >= prefetch_at(tile.z, tile.x, tile.y) && k.t1 > k.t0 {
                for product in [Product::BillboardsBin, Product::ShadowPng] {
                    paths.push(self.tile_path_at(layer, tile, product, k.t1));
                }
            }
        }
        paths
    }

    /// Composites the fetched bodies (in [`RemoteRender::paths`] order; `base` names
    /// the server in errors).
    pub fn compose(self, base: &str, bodies: &[Vec<u8>]) -> Result<Rendered, ClientError> {
        let paths = self.paths();
        if bodies.len() != paths.len() {
            return Err(ClientError::Decode {
                url: base.to_string(),
                message: format!("{} bodies for {} paths", bodies.len(), paths.len()),
            });
        }
        let decode_error = |i: usize| {
            let url = format!("{base}{}", paths[i]);
            move |message: String| ClientError::Decode { url, message }
        };
        let sheet = decode_splat_sheet(&bodies[0], &bodies[1]).map_err(decode_error(1))?;
        let mut billboards = Vec::new();
        let mut shadows = Vec::new();
        let mut served_sun = None;
        for (k, &(layer, tile)) in self.tiles.iter().enumerate() {
            let (bin, shadow) = (2 + 2 * k, 3 + 2 * k);
            let decoded = decode_bin(&bodies[bin]).map_err(decode_error(bin))?;
            served_sun.get_or_insert((decoded.sun_azimuth_deg, decoded.sun_elevation_deg));
            billboards.extend(billboards_at(&decoded, &sheet, self.req.t));
            let fraction = self.keyframe(layer, tile).fraction(self.req.t);
            shadows.push(
                decode_shadow_map(&bodies[shadow], &decoded, self.bands[layer].base, fraction)
                    .map_err(decode_error(shadow))?,
            );
        }
        // Every tile is shaded for the centre of the request's sun bucket, which the
        // tiles report; the sky and ground use the same.
        let req = &self.req;
        let sun = match (served_sun, req.sun) {
            (Some((az, el)), _) => Sun::new(az as f64, el as f64).ok_or_else(|| ClientError::Decode {
                url: base.to_string(),
                message: format!("tiles report an impossible sun {az},{el}"),
            })?,
            (None, Some(sun)) => sun,
            (None, None) => {
                return Err(RenderError::BadRequest(
                    "the view holds no cloud tiles, so the server's sun is unknown; pass --sun AZ,EL".into(),
                )
                .into());
            }
        };
        let view = View::perspective(&req.camera, req.width, req.height);
        let lighting = Lighting::new(sun.bucket().centre(), req.params);
        let far = mean_shadow(
            self.tiles
                .iter()
                .zip(&shadows)
                .map(|(&(layer, _), s)| (layer, s.mean())),
        );
        let mut image = background(&view, &lighting, far, |x, y| {
            shadows.iter().map(|s| s.at(x, y)).product()
        });
        composite(&mut image, &billboards, &lighting, &view);
        Ok(Rendered {
            image,
            tiles: self.tiles,
            billboards: billboards.len(),
            sun,
            noise: None,
        })
    }
}

/// The quality named in a splat path, for callers that fetch the sheet alone.
pub fn splat_paths(quality: Quality) -> [String; 2] {
    let q = quality.as_str();
    [
        format!("/v1/splats.json?quality={q}"),
        format!("/v1/splats.png?quality={q}"),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_encoded() {
        assert_eq!(encode("a b/c"), "a%20b%2Fc");
        assert_eq!(encode("stratocumulus"), "stratocumulus");
    }

    #[test]
    fn shadow_lookup_matches_the_tile_rule() {
        let n = TILE_COLUMNS;
        let mut values = vec![1.0f32; n * n];
        values[0] = 0.0; // south-west column
        let mut map = ShadowMap {
            origin: [1000.0, 2000.0],
            column: 100.0,
            shift: [0.0, 0.0],
            ends: [values, vec![1.0f32; n * n]],
            fraction: 0.0,
        };
        assert_eq!(map.at(1050.0, 2050.0), 0.0);
        assert_eq!(map.at(900.0, 2050.0), 1.0, "outside the tile");
        assert!(
            (map.at(1100.0, 2050.0) - 0.5).abs() < 1e-9,
            "halfway to the next column"
        );
        // A quarter of the way to an end without the shadow: a quarter lit.
        map.fraction = 0.25;
        assert!((map.at(1050.0, 2050.0) - 0.25).abs() < 1e-9);
    }
}
