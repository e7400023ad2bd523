//! A tile product's recipe: one variant of a tile product (world, layer, tile,
//! product, quality, sun), whatever its keyframe, turned into a cache key and the job
//! that computes it. The `/tiles` route, compute-ahead and the play areas kept warm
//! all go through it, so a keyframe has one key and one computation whoever asks.

use std::sync::Arc;

use axum::body::Bytes;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::{self, Work};
use cloudscape_core::density;
use cloudscape_core::products::Product;
use cloudscape_core::products::catalogue::encode_shaded;
use cloudscape_core::render::TileId;
use cloudscape_core::render::tile::{KeptTile, shade_tile_staged};
use cloudscape_core::render::{Quality, ShadingParams, Sun, SunBucket};
use cloudscape_core::stages::Stages;
use cloudscape_core::world::{Keyframe, Limits, SunConfig, World};

use crate::error::ApiError;
use crate::kept::KeptStates;
use crate::key::{CacheKey, ResolvedWorld};
use crate::metrics::Metrics;

/// The key of one product of a tile. Shaded products add the quality and sun bucket.
pub fn tile_key(base: &CacheKey, product: Product, shading: Option<(Quality, SunBucket)>) -> CacheKey {
    let key = base.clone().with("p", product.name());
    match shading {
        Some((q, bucket)) => key.with("q", q.as_str()).with("s", bucket.id()),
        None => key,
    }
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
        // A delta codes a keyframe on its predecessor only when both were lit alike:
        // the same sun bucket (a fixed sun, or the clock's at both starts).
        let previous_lit_alike = keyframe.index > 0
            && !keyframe.is_instant()
            && shading.is_some_and(|(q, sun)| {
                let span = keyframe.span();
                let before = Keyframe {
                    index: keyframe.index - 1,
                    t0: (keyframe.index - 1) as f64 * span,
                    t1: keyframe.t0,
                };
                self.shading(before)
                    .is_some_and(|(q0, s0)| q0 == q && s0.bucket() == sun.bucket())
            });
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
                        Some(state) => state
                            .density
                            .density(&world, region, keyframe.t0, true, cancel, &mut stages),
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
                    let mut all = encode_shaded(&shaded, limits.max_response_bytes, previous_lit_alike, product);
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
