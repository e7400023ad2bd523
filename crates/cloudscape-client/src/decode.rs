//! Decoders of the served products and the plan of a remote render: everything the
//! client does except networking, so the blocking and async fetchers share it and a
//! caller with its own HTTP stack can use it alone.

use std::io::Cursor;

use serde::Deserialize;

use cloudscape_core::products::Product;
use cloudscape_core::products::billboards::BinBillboards;
use cloudscape_core::render::scene::{LayerBand, plan_bands};
use cloudscape_core::render::splats::SplatSheet;
use cloudscape_core::render::tile::TileId;
use cloudscape_core::render::{Quality, RenderError, RenderRequest, Rendered, Sun};
use cloudscape_core::view::{HeldTile, held};
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
    /// Whether the layer can rain or snow: a client that draws weather fetches its
    /// `precipitation.png` (discovery's `precipitates`; false when absent).
    #[serde(default)]
    pub precipitates: bool,
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

/// A remote render once the world's discovery document is known: the tiles to draw
/// and the keyframe each needs ([`RemoteRender::tiles`]), their URLs
/// ([`RemoteRender::keyframe_path`]), and how the decoded keyframes become a picture
/// ([`RemoteRender::draw`]).
pub struct RemoteRender {
    world: String,
    req: RenderRequest,
    info: RemoteWorld,
    tiles: Vec<(usize, TileId)>,
    query: String,
}

/// One tile of a remote render: its layer, address and the keyframe that holds the
/// request's time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlannedTile {
    pub layer: usize,
    pub tile: TileId,
    pub keyframe: Keyframe,
}

impl RemoteRender {
    /// Plans `req` against `world`'s discovery document: the same level choice as a
    /// local `cloudscape render` when `req` names its sun. With the clock's sun, which
    /// the client learns from the tiles, the plan's shadows fall straight down until
    /// [`RemoteRender::for_served_sun`] plans the tiles whose shadows the sun throws
    /// into view too.
    pub fn plan(world: &str, info: RemoteWorld, req: &RenderRequest) -> Result<RemoteRender, ClientError> {
        check_remote(req)?;
        let tiles = plan_bands(&info.bands(), info.maxzoom, req)?;
        let mut query = format!("quality={}", req.quality.as_str());
        if let Some(sun) = req.sun {
            query.push_str(&format!("&sun={},{}", sun.azimuth_deg, sun.elevation_deg));
        }
        Ok(RemoteRender {
            world: world.to_string(),
            req: *req,
            info,
            tiles,
            query,
        })
    }

    /// When the request named no sun: the plan for the sun the server shaded
    /// `keyframe` for (the clock's, its bucket's centre), which holds this plan's
    /// tiles and those whose shadows that sun throws into view; the same URLs, with no
    /// sun in them. `None` when the request named its sun or nothing was fetched.
    pub fn for_served_sun(&self, keyframe: Option<&BinBillboards>) -> Result<Option<RemoteRender>, ClientError> {
        if self.req.sun.is_some() {
            return Ok(None);
        }
        let Some(sun) = keyframe.and_then(|k| Sun::new(k.sun_azimuth_deg as f64, k.sun_elevation_deg as f64)) else {
            return Ok(None);
        };
        let with_sun = RenderRequest {
            sun: Some(sun),
            ..self.req
        };
        Ok(Some(RemoteRender {
            world: self.world.clone(),
            req: self.req,
            info: self.info.clone(),
            tiles: plan_bands(&self.info.bands(), self.info.maxzoom, &with_sun)?,
            query: self.query.clone(),
        }))
    }

    /// The keyframe span of a tile of `layer` that holds `t`.
    fn keyframe_at(&self, layer: usize, tile: TileId, t: f64) -> Keyframe {
        Keyframe::on_grid(t, keyframe_span(self.info.layers[layer].dt, tile.z))
    }

    /// The tiles to draw, each with the keyframe that holds the request's time, in the
    /// order [`RemoteRender::draw`] takes them.
    pub fn tiles(&self) -> Vec<PlannedTile> {
        self.tiles
            .iter()
            .map(|&(layer, tile)| PlannedTile {
                layer,
                tile,
                keyframe: self.keyframe_at(layer, tile, self.req.t),
            })
            .collect()
    }

    /// The next keyframe of every tile whose span the request's time is past the
    /// tile's prefetch point ([`cloudscape_core::world::prefetch_at`], in the second
    /// half of the span): what an animating client fetches ahead of need.
    pub fn prefetch(&self) -> Vec<PlannedTile> {
        self.tiles()
            .into_iter()
            .filter(|p| {
                let k = p.keyframe;
                k.fraction(self.req.t) >= prefetch_at(p.tile.z, p.tile.x, p.tile.y) && k.t1 > k.t0
            })
            .map(|p| PlannedTile {
                keyframe: self.keyframe_at(p.layer, p.tile, p.keyframe.t1),
                ..p
            })
            .collect()
    }

    /// What names a tile's keyframes whatever their time: the world, layer, tile,
    /// quality and sun of its URLs.
    pub fn variant(&self, p: &PlannedTile) -> String {
        format!(
            "{}|{}|{}/{}/{}|{}",
            self.world, p.layer, p.tile.z, p.tile.x, p.tile.y, self.query
        )
    }

    /// The URL of a tile's keyframe: `billboards.bin` (self-contained), or with
    /// `delta` `billboards.delta.bin` (coded on the keyframe before it, which the
    /// client holds). `t` is the keyframe's own time, so the answer is immutable.
    pub fn keyframe_path(&self, p: &PlannedTile, delta: bool) -> String {
        let product = if delta {
            Product::BillboardsDelta
        } else {
            Product::BillboardsBin
        };
        format!(
            "/v1/worlds/{}/tiles/{}/{}/{}/{}?t={}&{}&layer={}",
            encode(&self.world),
            p.tile.z,
            p.tile.x,
            p.tile.y,
            product.name(),
            p.keyframe.t0,
            self.query,
            encode(&self.info.layers[p.layer].name)
        )
    }

    /// Draws the decoded keyframes of [`RemoteRender::tiles`] (in that order), as a
    /// local render draws them (`cloudscape_core::view::held`); `base` names the server
    /// in errors.
    pub fn draw(self, base: &str, keyframes: Vec<BinBillboards>) -> Result<Rendered, ClientError> {
        if keyframes.len() != self.tiles.len() {
            return Err(ClientError::Decode {
                url: base.to_string(),
                message: format!("{} keyframes for {} tiles", keyframes.len(), self.tiles.len()),
            });
        }
        let served_sun = keyframes.first().map(|k| (k.sun_azimuth_deg, k.sun_elevation_deg));
        let held: Vec<HeldTile> = self
            .tiles
            .iter()
            .zip(keyframes)
            .map(|(&(layer, _), keyframe)| HeldTile {
                layer,
                base: self.info.layers[layer].base,
                keyframe,
                served_shadow: None,
            })
            .collect();
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
        let image = held::draw(&held, req, sun);
        Ok(Rendered {
            image,
            tiles: self.tiles,
            billboards: held.iter().map(|t| t.keyframe.records.len()).sum(),
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
}
