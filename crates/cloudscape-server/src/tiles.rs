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

use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::{self, Work};
use cloudscape_core::density;
use cloudscape_core::products::Product;
use cloudscape_core::products::billboards;
use cloudscape_core::products::catalogue::encode_shaded;
use cloudscape_core::render::TileId;
use cloudscape_core::render::tile::{KeptTile, shade_tile_staged};
use cloudscape_core::render::{Quality, ShadingParams, Sun, SunBucket};
use cloudscape_core::stages::Stages;
use cloudscape_core::world::{Keyframe, Limits, SunConfig, World};

use crate::annotations::{ComputedResponses, LayerName, WorldName};
use crate::error::ApiError;
use crate::extract::{TilePath, TileProduct, layer};
use crate::kept::KeptStates;
use crate::key::{CacheKey, ResolvedWorld};
use crate::metrics::Metrics;
use crate::params::{Params, QualityName, parse_quality, parse_sun};
use crate::respond::Cached;
use crate::state::AppState;

/// The key of one product of a tile. Shaded products add the quality and sun bucket.
fn tile_key(base: &CacheKey, product: Product, shading: Option<(Quality, SunBucket)>) -> CacheKey {
    let key = base.clone().with("p", product.name());
    match shading {
        Some((q, bucket)) => key.with("q", q.as_str()).with("s", bucket.id()),
        None => key,
    }
}

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
    /// density.npy | density.f32 | density.u8 | density.ktx2 | coverage.png | billboards.json | billboards.bin | atlas.png | atlas.json | shadow.png | precipitation.png
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
    /// World time, seconds, 0 <= t <= 1e12. Answered with the keyframe whose span holds t (t0 = floor(t / span) * span, span = dt * 2^min(z, 4)): immutable when t is t0, else max-age until the next keyframe and Content-Location naming the keyframe's URL
    #[param(example = 0)]
    t: f64,
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
            "The product's bytes. Density grids are C order, shape (depth, 256, 256), row = y, col = x; `.npy` is numpy format 1.0 (<f4), `.f32` raw little-endian, `.u8` density × 255 rounded, `.ktx2` a KTX 2.0 R8 3D texture. coverage.png: RGB weather map (R max density, G opacity, B cloud top), linear. billboards.json/.bin: shaded metaball instances at both ends of the keyframe. atlas.png/.json: impostor atlas and manifest. shadow.png: ground shadow map (R at t0, G at t1). precipitation.png: RGBA data, no colour management (R rate, mm/h = 100·(R/255)²; G 255 where snow at sea level; B streak top; A 255 where precipitating). docs/formats.md has every layout. Headers: ETag, X-Cloudscape-T and X-Cloudscape-T1 (the keyframe's span), X-Cloudscape-Frame.",
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
    let t = params.time("t")?;
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
        t,
        canonical,
    );
    let watched: Arc<dyn crate::ahead::Recipe> = Arc::clone(&recipe) as _;
    s.ahead.watched(&s.metrics, &watched, keyframe, t);
    let max_response_bytes = config.limits.max_response_bytes;
    let plan = {
        let recipe = Arc::clone(&recipe);
        move || recipe.plan(keyframe)
    };
    let refuse_oversized_json = |bytes: &Bytes| {
        if product == Product::BillboardsJson && bytes.is_empty() {
            return Err(ApiError::ResponseTooLarge(format!(
                "billboards.json of this tile is over the {} MiB response limit (limits.max_response_bytes): \
                 fetch billboards.bin, the same billboards in {}-byte records, or ask for a lower quality",
                max_response_bytes >> 20,
                billboards::BIN_RECORD_BYTES
            )));
        }
        Ok(HeaderMap::new())
    };
    cached.respond_with(&s, &headers, plan, refuse_oversized_json).await
}

/// One variant of a tile product (world, layer, tile, product, quality, sun), whatever
/// its keyframe: what a request and compute-ahead both turn into a key and a job.
pub struct TileRecipe {
    pub world: ResolvedWorld,
    pub layer: usize,
    pub tile: TileId,
    pub product: Product,
    /// Quality of the shaded products (unused by the others).
    pub quality: Quality,
    /// The sun asked for; `None` follows the world clock at each keyframe.
    pub sun: Option<Sun>,
    pub sun_config: SunConfig,
    pub limits: Limits,
    /// What tiles keep between keyframes (the job starts from it), if the server keeps any.
    pub kept: Option<Arc<KeptStates>>,
    /// Where the jobs' time goes is counted here.
    pub metrics: Arc<Metrics>,
}

/// The job that computes a tile's bytes, and those of its siblings.
pub type TileJob = crate::ahead::AheadJob;

impl TileRecipe {
    /// The keyframe span of this tile's level that contains `t`.
    pub fn keyframe(&self, t: f64) -> Keyframe {
        Keyframe::containing(t, &self.world.world.layers[self.layer], self.tile.z)
    }

    /// Quality and sun of a shaded product at `keyframe` (`None` for the others).
    fn shading(&self, keyframe: Keyframe) -> Option<(Quality, Sun)> {
        self.product.needs_shading().then(|| {
            let sun = self
                .sun
                .unwrap_or_else(|| Sun::from_clock(keyframe.t0, &self.sun_config));
            (self.quality, sun)
        })
    }

    /// The key of the tile product's keyframe, without the product: its siblings share it.
    fn base_key(&self, keyframe: Keyframe) -> CacheKey {
        CacheKey::new("tile", &self.world, self.layer)
            .with("z", self.tile.z)
            .with("x", self.tile.x)
            .with("y", self.tile.y)
            .with("k", keyframe.index)
    }

    /// The key of what the tile keeps between keyframes: the same for every product,
    /// quality and sun of the tile.
    fn kept_key(&self) -> String {
        format!(
            "{}|l{}|{}/{}/{}",
            self.world.fingerprint, self.layer, self.tile.z, self.tile.x, self.tile.y
        )
    }

    /// The cache key of the product at `keyframe`.
    pub fn key(&self, keyframe: Keyframe) -> CacheKey {
        let shading = self.shading(keyframe).map(|(q, sun)| (q, sun.bucket()));
        tile_key(&self.base_key(keyframe), self.product, shading)
    }

    /// What names the variant whatever its keyframe: the hot set's key.
    pub fn variant(&self) -> String {
        let sun = self.sun.map_or("clock".to_string(), |s| s.bucket().id());
        let q = if self.product.needs_shading() {
            self.quality.as_str()
        } else {
            "-"
        };
        format!(
            "{}|l{}|{}/{}/{}|{}|{q}|{sun}",
            self.world.fingerprint,
            self.layer,
            self.tile.z,
            self.tile.x,
            self.tile.y,
            self.product.name()
        )
    }

    /// The estimated work of the product at `keyframe`, and the job that computes it.
    pub fn plan(&self, keyframe: Keyframe) -> Result<(Work, TileJob), ApiError> {
        let (world, layer, tile, product) = (&self.world.world, self.layer, self.tile, self.product);
        let region = tile.region()?;
        let shading = self.shading(keyframe);
        let work = match shading {
            Some((q, sun)) => cost::shade_tile(world, layer, tile, keyframe, q, sun)?,
            None => cost::density(world, layer, tile.z, region, keyframe.t0)?,
        };
        let world = world.clone();
        let limits = self.limits.clone();
        let base = self.base_key(keyframe);
        let kept = self.kept.clone().filter(|_| !keyframe.is_instant());
        let kept_key = self.kept_key();
        let metrics = Arc::clone(&self.metrics);
        let job: TileJob = Box::new(move |cancel: &Cancel| {
            let mut stages = Stages::default();
            let out = match shading {
                None => {
                    let grid = with_kept(kept.as_deref(), &kept_key, &world, layer, tile, |state| match state {
                        Some(state) => state.density.density(&world, region, keyframe.t0, true, cancel, &mut stages),
                        None => {
                            density::density_staged(&world, layer, tile.z, region, keyframe.t0, cancel, &mut stages)
                        }
                    })?;
                    let bytes = product
                        .encode_grid(&world.layers[layer], &grid)
                        .ok_or_else(|| ApiError::Internal(format!("{} is not a grid product", product.name())))?;
                    Ok((Bytes::from(bytes), Vec::new()))
                }
                Some((q, sun)) => {
                    let params = ShadingParams::default();
                    let shaded = with_kept(kept.as_deref(), &kept_key, &world, layer, tile, |state| {
                        shade_tile_staged(
                            &world,
                            layer,
                            tile,
                            keyframe,
                            q,
                            sun,
                            &params,
                            &limits,
                            cancel,
                            state,
                            &mut stages,
                        )
                    })?;
                    // Shading was the long part: stop here rather than encode for nobody.
                    cancel.check().map_err(|_| ApiError::Cancelled)?;
                    let encoding = std::time::Instant::now();
                    let mut all = encode_shaded(&shaded, limits.max_response_bytes, product);
                    metrics.observe_stage("encoding", encoding.elapsed());
                    let i = all
                        .iter()
                        .position(|(p, _)| *p == product)
                        .ok_or_else(|| ApiError::Internal(format!("{} is not a shaded product", product.name())))?;
                    let (_, wanted) = all.swap_remove(i);
                    let bucket = Some((q, sun.bucket()));
                    let mut siblings: Vec<(CacheKey, Bytes)> = all
                        .into_iter()
                        .map(|(p, b)| (tile_key(&base, p, bucket), Bytes::from(b)))
                        .collect();
                    // The precipitation map from the density this shading was built from:
                    // the viewer asks for it beside the billboards of a layer that can
                    // precipitate, and it costs an encoding here instead of a second
                    // density computation.
                    let (l, rain) = (&world.layers[layer], Product::PrecipitationPng);
                    if l.preset.precipitates()
                        && let Some(b) = rain.encode_grid(l, &shaded.tile_density())
                    {
                        siblings.push((tile_key(&base, rain, None), Bytes::from(b)));
                    }
                    Ok((Bytes::from(wanted), siblings))
                }
            };
            metrics.observe_stages(&stages);
            out
        });
        Ok((work, job))
    }
}

/// Runs `job` with the kept state of `tile` (see [`KeptStates::with`]), or with
/// `None` when the server keeps none.
fn with_kept<R>(
    kept: Option<&KeptStates>,
    key: &str,
    world: &World,
    layer: usize,
    tile: TileId,
    job: impl FnOnce(Option<&mut KeptTile>) -> R,
) -> R {
    match kept {
        Some(k) => k.with(key, || KeptTile::for_tile(&world.layers[layer], layer, tile), job),
        None => job(None),
    }
}

impl crate::ahead::Recipe for TileRecipe {
    fn variant(&self) -> String {
        TileRecipe::variant(self)
    }

    fn keyframe(&self, t: f64) -> Keyframe {
        TileRecipe::keyframe(self, t)
    }

    fn key(&self, keyframe: Keyframe) -> CacheKey {
        TileRecipe::key(self, keyframe)
    }

    fn family(&self) -> &'static str {
        self.product.family()
    }

    fn plan(&self, keyframe: Keyframe) -> Result<(Work, TileJob), ApiError> {
        TileRecipe::plan(self, keyframe)
    }
}
