//! `GET /v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}`: one product of one tile.
//!
//! A tile (z, x, y) is the 256×256 columns at level z whose first column is
//! (x·256, y·256); the world origin is the corner of tile (z, 0, 0).

use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::rejection::PathRejection;
use axum::extract::{Path, State};
use axum::http::HeaderMap;
use axum::response::Response;

use cloudscape_core::cost;
use cloudscape_core::density::{self, Region};
use cloudscape_core::products::grid::{GridFormat, encode_density};
use cloudscape_core::products::{atlas, billboards, coverage, shadow};
use cloudscape_core::render::tile::shade_tile_cancellable;
use cloudscape_core::render::{Quality, ShadedTile, ShadingParams, Sun, SunBucket, TileId};

use super::error::ApiError;
use super::key::{CacheKey, SnappedTime};
use super::params::{Params, parse_level, parse_tile_coordinate};
use super::{AppState, Representation};

/// Columns per tile side (PRODUCT.md: a tile is 256×256 columns at its level).
pub const TILE_SIZE: i64 = 256;

/// What a tile URL can ask for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Product {
    /// The density grid, `(depth, 256, 256)`, in one of the grid encodings.
    Density(GridFormat),
    /// The 2D weather map (`products::coverage`): no sun, no quality.
    Coverage,
    /// A product of the shaded tile: depends on quality and sun bucket.
    Shaded(Shaded),
}

/// The products encoded from one [`ShadedTile`]: computing any of them computes (and
/// caches) all of them, since the shading is the expensive part they share.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shaded {
    BillboardsJson,
    BillboardsBin,
    AtlasPng,
    AtlasJson,
    ShadowPng,
}

impl Shaded {
    const ALL: [Shaded; 5] = [
        Shaded::BillboardsJson,
        Shaded::BillboardsBin,
        Shaded::AtlasPng,
        Shaded::AtlasJson,
        Shaded::ShadowPng,
    ];
}

impl Product {
    /// Every product this server builds, by URL name.
    pub const ALL: [Product; 9] = [
        Product::Density(GridFormat::Npy),
        Product::Density(GridFormat::F32),
        Product::Density(GridFormat::U8),
        Product::Coverage,
        Product::Shaded(Shaded::BillboardsJson),
        Product::Shaded(Shaded::BillboardsBin),
        Product::Shaded(Shaded::AtlasPng),
        Product::Shaded(Shaded::AtlasJson),
        Product::Shaded(Shaded::ShadowPng),
    ];

    pub fn name(self) -> &'static str {
        match self {
            Product::Density(GridFormat::Npy) => "density.npy",
            Product::Density(GridFormat::F32) => "density.f32",
            Product::Density(GridFormat::U8) => "density.u8",
            Product::Coverage => "coverage.png",
            Product::Shaded(Shaded::BillboardsJson) => "billboards.json",
            Product::Shaded(Shaded::BillboardsBin) => "billboards.bin",
            Product::Shaded(Shaded::AtlasPng) => "atlas.png",
            Product::Shaded(Shaded::AtlasJson) => "atlas.json",
            Product::Shaded(Shaded::ShadowPng) => "shadow.png",
        }
    }

    pub fn parse(s: &str) -> Result<Product, ApiError> {
        Product::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| ApiError::UnknownProduct(s.chars().take(64).collect()))
    }

    fn content_type(self) -> &'static str {
        match self {
            Product::Density(_) | Product::Shaded(Shaded::BillboardsBin) => "application/octet-stream",
            Product::Coverage | Product::Shaded(Shaded::AtlasPng | Shaded::ShadowPng) => "image/png",
            Product::Shaded(Shaded::BillboardsJson | Shaded::AtlasJson) => "application/json",
        }
    }

    /// Metrics label.
    fn kind(self) -> &'static str {
        match self {
            Product::Density(_) => "tile_density",
            Product::Coverage => "tile_coverage",
            Product::Shaded(_) => "tile_shaded",
        }
    }
}

/// The region of tile (z, x, y), range-checked: the coordinate arithmetic itself
/// (x·256 + 256) must not overflow, and the columns must lie within the simulation's
/// coordinate range at level z.
pub fn tile_region(z: u32, x: i64, y: i64) -> Result<Region, ApiError> {
    let origin = |v: i64, name: &str| {
        v.checked_mul(TILE_SIZE)
            .filter(|o| o.checked_add(TILE_SIZE).is_some())
            .ok_or_else(|| ApiError::CoordinatesOutOfRange(format!("tile {name} = {v} overflows at level {z}")))
    };
    Ok(Region {
        x0: origin(x, "x")?,
        y0: origin(y, "y")?,
        cols: TILE_SIZE as usize,
        rows: TILE_SIZE as usize,
    })
}

/// Parses a rejected path (bad percent-encoding) into our error shape.
pub fn path_error(e: PathRejection) -> ApiError {
    ApiError::InvalidParameter {
        name: "path".to_string(),
        message: e.body_text(),
    }
}

/// `quality=` if given: one of the presets.
pub fn parse_quality(params: &Params) -> Result<Option<Quality>, ApiError> {
    params
        .get("quality")
        .map(|q| {
            Quality::parse(q).ok_or_else(|| ApiError::InvalidParameter {
                name: "quality".to_string(),
                message: format!("must be one of fast, balanced, accurate, reference, reference-single; got `{q}`"),
            })
        })
        .transpose()
}

/// `sun=AZ,EL` if given (degrees; elevation within [-90, 90]).
pub fn parse_sun(params: &Params) -> Result<Option<Sun>, ApiError> {
    let Some(s) = params.get("sun") else { return Ok(None) };
    let v = super::params::parse_list("sun", s, 2)?;
    Sun::new(v[0], v[1])
        .map(Some)
        .ok_or_else(|| ApiError::InvalidParameter {
            name: "sun".to_string(),
            message: "elevation must be within [-90, 90] degrees".to_string(),
        })
}

/// The key of one product of a tile. Shaded products add the quality and sun bucket.
fn tile_key(base: &CacheKey, product: Product, shading: Option<(Quality, SunBucket)>) -> CacheKey {
    let key = base.clone().with("p", product.name());
    match shading {
        Some((q, bucket)) => key.with("q", q.as_str()).with("s", bucket.id()),
        None => key,
    }
}

/// The tile route's segments as sent: world, z, x, y, product (parsed in [`tile`], so
/// a malformed one gets our error rather than the extractor's).
type TileSegments = (String, String, String, String, String);

#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}",
    tag = "tiles",
    params(
        ("world" = String, Path, description = "Configured world name, or a decimal u64 seed (default climate)", example = "default"),
        ("z" = u32, Path, description = "Level: a level-z column is 2^z level-0 cells wide", minimum = 0, example = 0),
        ("x" = i64, Path, description = "Tile column (east); negative allowed", example = 0),
        ("y" = i64, Path, description = "Tile row (north); negative allowed", example = 0),
        ("product" = super::openapi::TileProduct, Path, description = "density.npy | density.f32 | density.u8 | coverage.png | billboards.json | billboards.bin | atlas.png | atlas.json | shadow.png", example = "density.u8"),
        ("t" = f64, Query, description = "World time, seconds, 0 <= t <= 1e12; snapped to the layer's frame grid (dt / frames_per_step)", example = 0),
        ("layer" = Option<String>, Query, description = "Layer name (default: the world's first layer)"),
        ("quality" = Option<super::openapi::QualityName>, Query, description = "fast | balanced (default) | accurate | reference | reference-single (the last two as accurate): metaball spacing, splat resolution, atlas texel (billboards, atlas, shadow only)"),
        ("sun" = Option<String>, Query, description = "AZ,EL in degrees; default: the world clock's sun at t. Bucketed to ~8 degrees: suns in one bucket give the same bytes (billboards, atlas, shadow only)"),
    ),
    responses(
        (status = 200, description = "The product's bytes. Density grids are C order, shape (depth, 256, 256), row = y, col = x; `.npy` is numpy format 1.0 (<f4), `.f32` raw little-endian, `.u8` density × 255 rounded. coverage.png: RGBA weather map (R max density, G opacity, B base, A top). billboards.json/.bin: shaded metaball instances. atlas.png/.json: impostor atlas and manifest. shadow.png: ground shadow map. Headers: ETag, X-Cloudscape-T (the frame time computed), X-Cloudscape-Frame.", content(
            (Vec<u8> = "application/octet-stream"),
            (Vec<u8> = "image/png"),
            (Object = "application/json"),
        )),
        (status = 304, description = "If-None-Match matched; nothing computed"),
        (status = 400, description = "Malformed parameter", body = super::error::ErrorBody),
        (status = 404, description = "Unknown world, layer or product", body = super::error::ErrorBody),
        (status = 413, description = "Over the limits: region size, estimated work (CPU within the time budget, memory), or response size (billboards.json over it: use billboards.bin)", body = super::error::ErrorBody),
        (status = 422, description = "t, level or tile coordinates out of range", body = super::error::ErrorBody),
        (status = 503, description = "Overloaded (queue, compute memory or reply memory full) or over the time budget; Retry-After is the queue's wait", body = super::error::ErrorBody),
    )
)]
pub async fn tile(
    State(s): State<Arc<AppState>>,
    path: Result<Path<TileSegments>, PathRejection>,
    params: Params,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let Path((world, z, x, y, product)) = path.map_err(path_error)?;
    let resolved = s.worlds.resolve(&world)?;
    let product = Product::parse(&product)?;
    let limits = &s.worlds.config().limits;
    let z = parse_level(&z, limits.max_level)?;
    let x = parse_tile_coordinate("x", &x)?;
    let y = parse_tile_coordinate("y", &y)?;
    let (layer_index, layer) = super::queries::layer(&resolved.world, params.get("layer"))?;
    let t = params.time("t")?;
    let quality = parse_quality(&params)?;
    let sun = parse_sun(&params)?;
    let region = tile_region(z, x, y)?;
    region.check(z, layer.depth, limits)?;
    let frame = SnappedTime::snap(t, layer, s.settings.frames_per_step);
    let base = CacheKey::new("tile", &resolved, layer_index)
        .with("z", z)
        .with("x", x)
        .with("y", y)
        .with("f", frame.index);
    let shading = match product {
        Product::Shaded(_) => {
            let sun = sun.unwrap_or_else(|| Sun::from_clock(frame.t, &s.worlds.config().sun));
            Some((quality.unwrap_or(Quality::Balanced), sun))
        }
        _ => None,
    };
    let key = tile_key(&base, product, shading.map(|(q, sun)| (q, sun.bucket())));
    let repr = Representation {
        etag: key.etag(),
        cache_control: s.cache_control(frame, t),
        frame: Some(frame),
    };
    if let Some(not_modified) = repr.not_modified(&headers) {
        return Ok(not_modified);
    }
    let world = resolved.world;
    let tile = TileId { z, x, y };
    let work = match shading {
        Some((q, sun)) => cost::shade_tile(&world, layer_index, tile, frame.t, q, sun)?,
        None => cost::density(&world, layer_index, z, region, frame.t)?,
    };
    let work = s.admit(product.kind(), work)?;
    let limits = limits.clone();
    let bytes = s
        .cache
        .get_or_compute_with_siblings(&s.metrics, product.kind(), key, work, move |cancel| {
            match (product, shading) {
                (Product::Density(format), _) => {
                    let grid = density::density_cancellable(&world, layer_index, z, region, frame.t, cancel)?;
                    Ok((Bytes::from(encode_density(&grid, format)), Vec::new()))
                }
                (Product::Coverage, _) => {
                    let png = coverage::encode_png_for_tile(&world, layer_index, tile, frame.t, &limits)?;
                    Ok((Bytes::from(png), Vec::new()))
                }
                (Product::Shaded(wanted), Some((q, sun))) => {
                    let shaded = shade_tile_cancellable(
                        &world,
                        layer_index,
                        tile,
                        frame.t,
                        q,
                        sun,
                        &ShadingParams::default(),
                        &limits,
                        cancel,
                    )?;
                    // Shading was the long part: stop here rather than encode for nobody.
                    cancel.check().map_err(|_| ApiError::Cancelled)?;
                    let mut atlas = Some(atlas::build(&shaded));
                    let mut all: Vec<(Shaded, Bytes)> = Shaded::ALL
                        .into_iter()
                        .map(|p| {
                            let bytes = match p {
                                Shaded::BillboardsJson => json_within(&shaded, limits.max_response_bytes),
                                Shaded::BillboardsBin => billboards::encode_bin(&shaded),
                                Shaded::ShadowPng => shadow::encode_png_map(&shaded),
                                Shaded::AtlasPng => {
                                    atlas.as_mut().map_or_else(Vec::new, |a| std::mem::take(&mut a.png))
                                }
                                Shaded::AtlasJson => atlas
                                    .as_mut()
                                    .map_or_else(Vec::new, |a| std::mem::take(&mut a.manifest)),
                            };
                            (p, Bytes::from(bytes))
                        })
                        .collect();
                    atlas.take();
                    let i = all
                        .iter()
                        .position(|(p, _)| *p == wanted)
                        .expect("every shaded product is encoded");
                    let (_, wanted_bytes) = all.swap_remove(i);
                    let bucket = sun.bucket();
                    let siblings = all
                        .into_iter()
                        .map(|(p, b)| (tile_key(&base, Product::Shaded(p), Some((q, bucket))), b))
                        .collect();
                    Ok((wanted_bytes, siblings))
                }
                (Product::Shaded(_), None) => Err(ApiError::Internal("shaded product without shading".into())),
            }
        })
        .await?;
    if product == Product::Shaded(Shaded::BillboardsJson) && bytes.is_empty() {
        return Err(ApiError::ResponseTooLarge(format!(
            "billboards.json of this tile is over the {} MiB response limit (limits.max_response_bytes): \
             fetch billboards.bin, the same billboards in {}-byte records, or ask for a lower quality",
            s.worlds.config().limits.max_response_bytes >> 20,
            billboards::BIN_RECORD_BYTES
        )));
    }
    repr.ok(&s, product.content_type(), bytes)
}

/// Fewest bytes one billboard takes in `billboards.json`: its keys and punctuation
/// (`{"position":[,,],"radius":,"splat":,"colour":[,,],"opacity":,
/// "sun_transmittance":,"density":},` is 94 bytes) and a digit per number.
const MIN_JSON_BYTES_PER_BILLBOARD: u64 = 100;

/// `billboards.json` of `shaded`, or no bytes when it would be over `max` bytes. The
/// empty body is what the cache keeps for such a tile (a JSON document is never
/// empty), so a repeat is refused without shading the tile again; a tile whose
/// count alone puts it over the limit is not even encoded.
fn json_within(shaded: &ShadedTile, max: u64) -> Vec<u8> {
    if shaded.billboards.len() as u64 * MIN_JSON_BYTES_PER_BILLBOARD > max {
        return Vec::new();
    }
    let json = billboards::encode_json(shaded);
    if json.len() as u64 > max { Vec::new() } else { json }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_regions_refuse_overflow() {
        assert_eq!(
            tile_region(0, -1, 2).unwrap(),
            Region {
                x0: -256,
                y0: 512,
                cols: 256,
                rows: 256
            }
        );
        assert!(tile_region(0, i64::MAX, 0).is_err());
        assert!(tile_region(0, 0, i64::MIN).is_err());
        assert!(tile_region(0, i64::MAX / 256, 0).is_err());
        assert!(tile_region(0, i64::MAX / 256 - 1, 0).is_ok());
    }

    #[test]
    fn products_round_trip_their_names() {
        for p in Product::ALL {
            assert_eq!(Product::parse(p.name()).unwrap(), p);
        }
        assert!(matches!(
            Product::parse("density.png"),
            Err(ApiError::UnknownProduct(_))
        ));
    }
}
