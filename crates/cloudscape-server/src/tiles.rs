//! `GET /v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}`: one product of one tile.
//!
//! A tile (z, x, y) is the 256×256 columns at level z whose first column is
//! (x·256, y·256); the world origin is the corner of tile (z, 0, 0). The products are
//! those of [`cloudscape_core::products::catalogue`].

use std::collections::BTreeMap;
use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::State;
use axum::http::{HeaderMap, Uri};
use axum::response::Response;
use utoipa::openapi::RefOr;
use utoipa::openapi::content::Content;
use utoipa::openapi::response::ResponseBuilder;
use utoipa::openapi::schema::{ObjectBuilder, Type};
use utoipa::{IntoResponses, PartialSchema};

use cloudscape_core::products::Product;
use cloudscape_core::render::Quality;
use cloudscape_core::world::Keyframe;

use crate::annotations::{ComputedResponses, LayerName, WorldName};
use crate::error::ApiError;
use crate::extract::{TilePath, TileProduct, layer};
use crate::params::{Params, QualityName, parse_quality, parse_sun};
use crate::recipe::TileRecipe;
use crate::respond::{AskedTime, Cached};
use crate::state::AppState;
use crate::warm::{unix_now, world_now};

/// The column, row and product of a tile's path, after its level (`/tiles`) or zoom
/// (`/zoom`).
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Path)]
#[allow(
    dead_code,
    reason = "documentation: utoipa reads the fields, the handlers take `TilePath`"
)]
pub struct TileCell {
    /// Tile column (east); negative allowed
    #[param(example = 0)]
    x: i64,
    /// Tile row (north; TileJSON scheme tms); negative allowed
    #[param(example = 0)]
    y: i64,
    /// density.npy | density.f32 | density.u8 | density.ktx2 | coverage.png | billboards.json | billboards.bin | billboards.delta.bin | billboards.v2.bin | atlas.png | atlas.json | shadow.png | precipitation.png
    #[param(example = "density.u8")]
    product: TileProduct,
}

/// The query of `/tiles` and `/zoom` besides the layer.
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
#[allow(
    dead_code,
    reason = "documentation: utoipa reads the fields, the handlers read `Params`"
)]
pub struct TileQuery {
    /// World time, seconds, 0 <= t <= 1e12. Answered with the keyframe whose span holds t (t0 = floor(t / span) * span, span = dt * 2^min(z, 4)): immutable when t is t0, else max-age until the next keyframe and Content-Location naming the keyframe's URL. Absent: the world clock's time now (the current keyframe, max-age until the next; what a TileJSON template filled with only {z}/{x}/{y} names)
    #[param(example = 0)]
    t: Option<f64>,
    /// fast | balanced (default) | accurate | reference | reference-single (the last two as accurate): metaball spacing, splat resolution, atlas texel (billboards, atlas, shadow only)
    quality: Option<QualityName>,
    /// AZ,EL in degrees; default: the world clock's sun at t. Bucketed to ~8 degrees: suns in one bucket give the same bytes (billboards, atlas, shadow only)
    sun: Option<String>,
}

/// A 200 of a tile route: the bytes of the product, in its media type
/// ([`Product::content_type`]; the JSON products documented as objects).
pub fn product_bytes(description: &str) -> BTreeMap<String, RefOr<utoipa::openapi::response::Response>> {
    let mut ok = ResponseBuilder::new().description(description);
    for content_type in Product::ALL.map(Product::content_type) {
        let schema = if content_type == "application/json" {
            ObjectBuilder::new().schema_type(Type::Object).into()
        } else {
            <Vec<u8> as PartialSchema>::schema()
        };
        ok = ok.content(content_type, Content::new(Some(schema)));
    }
    BTreeMap::from([("200".to_string(), ok.build().into())])
}

/// The 200 of `/tiles`.
pub struct TileBytes;

impl IntoResponses for TileBytes {
    fn responses() -> BTreeMap<String, RefOr<utoipa::openapi::response::Response>> {
        product_bytes(
            "The product's bytes. Density grids are C order, shape (depth, 256, 256), row = y, col = x; `.npy` is numpy format 1.0 (<f4), `.f32` raw little-endian, `.u8` density × 255 rounded, `.ktx2` a KTX 2.0 R8 3D texture. coverage.png: RGB weather map (R max density, G opacity, B cloud top), linear. billboards.json: shaded metaball instances at both ends of the keyframe. billboards.bin: the same keyframe as quantised lattice states (version 3, self-contained); billboards.delta.bin: coded on the tile's previous keyframe (version 3, delta form; self-contained where the previous was lit otherwise); billboards.v2.bin: version 2's 56-byte records. atlas.png/.json: impostor atlas and manifest. shadow.png: ground shadow map (R at t0, G at t1). precipitation.png: RGBA data, no colour management (R rate, mm/h = 100·(R/255)²; G 255 where snow at sea level; B streak top; A 255 where precipitating). docs/formats.md has every layout. Headers: ETag, X-Cloudscape-T and X-Cloudscape-T1 (the keyframe's span), X-Cloudscape-Frame.",
        )
    }
}

/// One product of one tile.
///
/// 400: Malformed parameter. 413: Over the limits: region size, estimated work (CPU
/// within the time budget, memory), or response size (billboards.json over it: use
/// billboards.bin). 422: t, level or tile coordinates out of range.
#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}",
    tag = "tiles",
    params(
        WorldName,
        ("z" = u32, Path, description = "Level: a level-z column is 2^z level-0 cells wide", minimum = 0, example = 0),
        TileCell,
        TileQuery,
        LayerName,
    ),
    responses(TileBytes, ComputedResponses)
)]
pub async fn tile(
    State(s): State<Arc<AppState>>,
    params: Params,
    TilePath { world, tile, product }: TilePath,
    uri: Uri,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let (layer_index, layer) = layer(&world.world, params.get("layer"))?;
    // Without `t`, the world clock's time now: a URL with only {z}/{x}/{y} filled (a
    // generic TileJSON client's) is the current keyframe.
    let asked = match params.get("t") {
        Some(_) => AskedTime::Given(params.time("t")?),
        None => {
            let clock = &world.world.clock;
            AskedTime::Clock {
                t: world_now(clock, unix_now()),
                rate: clock.rate,
            }
        }
    };
    let t = asked.t();
    let quality = parse_quality(&params)?;
    let sun = parse_sun(&params)?;
    let config = s.worlds.config();
    let region = tile.region()?;
    region.check(tile.z, layer.depth, &config.limits)?;
    let keyframe = Keyframe::containing(t, layer, tile.z);
    let recipe = Arc::new(TileRecipe {
        world,
        layer: layer_index,
        tile,
        product,
        quality: quality.unwrap_or(Quality::Balanced),
        sun,
        sun_config: config.sun.clone(),
        limits: config.limits.clone(),
        kept: s.kept.clone(),
        metrics: Arc::clone(&s.metrics),
    });
    let canonical = || format!("{}?{}", uri.path(), params.query_with("t", &keyframe.t0.to_string()));
    let cached = Cached::keyframe(
        product.family(),
        recipe.key(keyframe),
        product.content_type(),
        keyframe,
        asked,
        canonical,
    );
    let max_response_bytes = config.limits.max_response_bytes;
    let plan = {
        let recipe = Arc::clone(&recipe);
        move || recipe.plan(keyframe)
    };
    let refuse_oversized_json = |bytes: &Bytes| {
        if product == Product::BillboardsJson && bytes.is_empty() {
            return Err(ApiError::ResponseTooLarge(format!(
                "billboards.json of this tile is over the {} MiB response limit (limits.max_response_bytes): \
                 fetch billboards.bin, the same billboards in a few bytes each, or ask for a lower quality",
                max_response_bytes >> 20,
            )));
        }
        Ok(HeaderMap::new())
    };
    let watched: Arc<dyn crate::ahead::Recipe> = Arc::clone(&recipe) as _;
    let response = cached.respond_with(&s, &headers, plan, refuse_oversized_json).await?;
    // Only an answered request watches the tile: a crawler retrying a 503 has not
    // asked for it twice.
    let in_area = s.warm.covers(&recipe.world.fingerprint, layer_index, tile);
    s.ahead.watched(&s.metrics, &watched, keyframe, t, in_area);
    Ok(response)
}
