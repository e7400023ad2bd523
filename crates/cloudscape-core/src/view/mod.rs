//! What a client sees: the products it holds drawn into a picture, and the whole
//! render of a view (plan, shade, encode, draw) that `cloudscape render` and
//! `render.png` run.
//!
//! The billboard presets draw what a client draws: each tile goes through the bytes
//! it is served as (`billboards.bin` version 3, self-contained) and is drawn by
//! [`held`], so the server's picture and a remote client's are one picture. The
//! volumetric references (`reference`, `reference-single`) draw the density itself
//! (`render::scene::draw_volumetric`).

pub mod held;

use rayon::prelude::*;

use crate::cancel::Cancel;
use crate::density::SimError;
use crate::products::billboards::{decode_bin, encode_bin};
use crate::products::keyframe_bin::{self, Form, Quantisation};
use crate::render::image::Image;
use crate::render::pathtrace::Noise;
use crate::render::scene::{RenderRequest, Rendered, draw_volumetric, prepare_cancellable, request_sun};
use crate::render::{RenderError, ShadedTile, Sun};
use crate::world::{Config, World};

pub use held::HeldTile;

/// Each shaded tile as a client holds it after fetching its self-contained
/// `billboards.bin` (version 3, at quantisation `q`).
pub fn held_tiles(tiles: &[ShadedTile], q: Quantisation) -> Vec<HeldTile> {
    tiles
        .par_iter()
        .map(|t| {
            let bytes = keyframe_bin::encode(t, Form::SelfContained, q);
            HeldTile {
                layer: t.layer,
                base: t.place.base,
                keyframe: decode_bin(&bytes).expect("a keyframe just encoded decodes"),
                served_shadow: None,
            }
        })
        .collect()
}

/// Each shaded tile as a version-2 client holds it: `billboards.bin` version 2 (both
/// ends in f32 and f16) and the served shadow maps at full precision. The picture
/// version 3 is measured against (`cloudscape bench --only wire`).
pub fn held_tiles_v2(tiles: &[ShadedTile]) -> Vec<HeldTile> {
    tiles
        .par_iter()
        .map(|t| HeldTile {
            layer: t.layer,
            base: t.place.base,
            keyframe: decode_bin(&encode_bin(t)).expect("a keyframe just encoded decodes"),
            served_shadow: Some([t.shadow.clone(), t.shadow_end.clone()]),
        })
        .collect()
}

/// Draws shaded tiles as a client draws them once served: their self-contained
/// `billboards.bin` at the served quantisation, the ground shadows derived.
pub fn draw_billboards(tiles: &[ShadedTile], req: &RenderRequest, sun: Sun) -> Image {
    held::draw(&held_tiles(tiles, Quantisation::DEFAULT), req, sun)
}

/// Draws shaded tiles with the renderer of `req.quality`: the path tracer
/// (`reference`, with its noise), the marcher (`reference-single`), or, for the
/// billboard presets, as a client draws them once served ([`held_tiles`]).
pub fn draw(tiles: &[ShadedTile], req: &RenderRequest, sun: Sun) -> (Image, Option<Noise>) {
    draw_cancellable(tiles, req, sun, &Cancel::never())
}

/// [`draw`] that stops early once `cancel` fires (the caller then discards the image).
fn draw_cancellable(tiles: &[ShadedTile], req: &RenderRequest, sun: Sun, cancel: &Cancel) -> (Image, Option<Noise>) {
    draw_volumetric(tiles, req, sun, cancel).unwrap_or_else(|| {
        let held = held_tiles(tiles, Quantisation::DEFAULT);
        (held::draw_cancellable(&held, req, sun, cancel), None)
    })
}

/// Renders a request: the billboards a client would draw for `fast | balanced |
/// accurate`, the path tracer for `reference`, the ray marcher for
/// `reference-single`.
pub fn render(world: &World, config: &Config, req: &RenderRequest) -> Result<Rendered, RenderError> {
    render_cancellable(world, config, req, &Cancel::never())
}

/// [`render`] that stops early once `cancel` fires (then an error): between tiles,
/// between the compositor's bands and between the ray marcher's rows.
pub fn render_cancellable(
    world: &World,
    config: &Config,
    req: &RenderRequest,
    cancel: &Cancel,
) -> Result<Rendered, RenderError> {
    let sun = request_sun(config, req);
    let tiles = prepare_cancellable(world, config, req, cancel)?;
    let ids = tiles.iter().map(|t| (t.layer, t.tile)).collect();
    let (image, noise) = draw_cancellable(&tiles, req, sun, cancel);
    cancel.check().map_err(SimError::from)?;
    let billboards = if req.quality.is_volumetric() {
        0
    } else {
        tiles.iter().map(|t| t.billboards.len()).sum()
    };
    Ok(Rendered {
        image,
        tiles: ids,
        billboards,
        sun,
        noise,
    })
}
