//! Play areas kept warm (`[[worlds.NAME.warm]]`, `cloudscape_core::world::warm`): from
//! start-up on, the current and the next keyframe of every tile variant of every area
//! are computed whether anyone asks or not, so the first view of a town is a cache hit.
//!
//! A play area names levels, products, qualities and layers; the tiles of a level are
//! those its box or polygon (grown by its `margin`) reaches. A *variant* is one
//! computation per keyframe of one tile of one layer: the shaded products that every
//! shading encodes (`billboards.bin` and `billboards.delta.bin`, and
//! `precipitation.png` on a layer that can precipitate) are one variant per quality;
//! each shaded product encoded only on request (`billboards.json`, `shadow.png`,
//! `billboards.v2.bin`, the atlas whose image and manifest are one build) is one; every
//! grid product is one. The count of all areas is capped by `server.max_warm_tiles`, checked with the
//! config ([`variants`]).
//!
//! Each variant is a [`TileRecipe`] as a request for its URL would build it (world,
//! layer, tile, product, quality, the sun following the world clock), run through the
//! same cache and compute queue as requests and compute-ahead
//! ([`ResponseCache::compute_ahead`](crate::cache::ResponseCache::compute_ahead)): the
//! bytes, ETags, siblings and the state tiles keep between keyframes (`crate::kept`)
//! are shared, and a request for a warm keyframe's URL is a cache hit.
//!
//! "Now" is the world clock (`[worlds.NAME.clock]`, `world::WorldClock`) read against
//! the server's real time: the keyframe that holds it is current, the one after it
//! next. The worker ([`run`]) computes current keyframes first, then next ones, the
//! earliest first. Priority against requests, as compute-ahead's: a warm keyframe runs
//! while no request is queued and a compute thread is free, never in the queue's last
//! place, so a request waits at most for the warm computations already running. But it
//! must not starve: a current keyframe, or a next one past [`URGENT_FROM`] of the span
//! before it, runs whatever requests are queued, waiting its turn in the queue's order,
//! at most `server.warm_threads` at once, so that it is in the cache before clients
//! fetch it (the viewer and `cloudscape loadtest` fetch the next keyframe from half the
//! span on). Before the server is ready every keyframe is urgent and may use every
//! compute thread: `/readyz` waits until every variant has its current keyframe and
//! its next one in the cache. (Waiting for the current ones alone said ready while
//! most next ones were still to compute: the players who arrived then asked for them
//! at their prefetch points, the replica computed them for requests and the warm
//! worker at once, and shed part of the load it had just said it could take.)

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use tokio::sync::Notify;

use cloudscape_core::fields::noise::mix64;
use cloudscape_core::products::Product;
use cloudscape_core::products::catalogue::Encoding;
use cloudscape_core::render::scene::VIEW_DISTANCE;
use cloudscape_core::render::tile::TILE_COLUMNS;
use cloudscape_core::render::{Quality, TileId};
use cloudscape_core::world::warm::{Margin, WarmArea};
use cloudscape_core::world::{Config, ConfigError, Keyframe, Layer, Limits, MAX_TIME, SunConfig, WorldClock};

use crate::cache::{Asker, Computation, ResponseCache};
use crate::config::ServerConfig;
use crate::error::ApiError;
use crate::kept::KeptStates;
use crate::key::Worlds;
use crate::metrics::Metrics;
use crate::recipe::TileRecipe;

/// Past this fraction of the span before it, a next warm keyframe is urgent: clients
/// fetch it from half the span on (the viewer, `cloudscape loadtest`), which leaves
/// a quarter of a span to have it in the cache first.
pub const URGENT_FROM: f64 = 0.25;
/// Most tiles one area may span at one level of one layer before its tiles are
/// counted one by one (its bounding box grown by the margin).
const MAX_CANDIDATE_TILES: f64 = 65_536.0;
/// How long the worker waits for a free place before it looks again.
const BUSY_POLL: Duration = Duration::from_millis(20);
/// Longest the worker sleeps when nothing is due (the clock may be fast).
const IDLE_POLL: Duration = Duration::from_secs(1);
/// After a refusal (the queue or its memory full), how long a variant waits.
const RETRY_AFTER: Duration = Duration::from_millis(250);
/// Failures other than refusals after which a variant is given up (logged).
const MAX_FAILURES: u32 = 3;

/// One tile variant of a play area, as the config names it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Variant {
    /// Index of the area in its world's `warm` list.
    pub area: usize,
    pub layer: usize,
    pub tile: TileId,
    /// The product its computation is asked for (the others of the variant come as
    /// siblings).
    pub product: Product,
    /// The quality of a shaded product (unused by grid products).
    pub quality: Quality,
}

/// The seconds since the Unix epoch, now.
pub fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The world time of `clock` at Unix second `unix`, within the accepted range of `t`.
pub fn world_now(clock: &WorldClock, unix: f64) -> f64 {
    clock.at(unix).clamp(0.0, MAX_TIME)
}

/// Checks what the config parser leaves to the server: each world clock reads a
/// time within [0, 1e12] at Unix second `unix`, and the play areas name known products
/// and qualities and reach at most `server.max_warm_tiles` variants together, which
/// it returns ([`variants`]); a compute queue of one place would never let them run.
pub fn check(
    config: &Config,
    settings: &ServerConfig,
    unix: f64,
) -> Result<BTreeMap<String, Vec<Variant>>, ConfigError> {
    for (name, w) in &config.worlds {
        let t = w.clock.at(unix);
        if !(0.0..=MAX_TIME).contains(&t) {
            return Err(ConfigError::invalid(
                format!("worlds.{name}.clock"),
                format!(
                    "reads t = {t:e} s now (offset + rate × {unix:.0} Unix seconds); world time must be within [0, 1e12]"
                ),
            ));
        }
    }
    let all = variants(config, settings.max_warm_tiles)?;
    if !all.is_empty() && settings.warm_threads > 0 && settings.compute_queue == 1 {
        return Err(ConfigError::invalid(
            "server.compute_queue",
            "must be at least 2 (or 0, automatic) to keep play areas warm: warm work never takes the queue's last place",
        ));
    }
    Ok(all)
}

/// Every variant of every configured world's play areas, by world name, checked: known
/// products and qualities, tiles in range, at most `max` variants in all (the error
/// names the area that goes over).
pub fn variants(config: &Config, max: u32) -> Result<BTreeMap<String, Vec<Variant>>, ConfigError> {
    let mut all = BTreeMap::new();
    let mut total = 0usize;
    for (wname, world) in &config.worlds {
        let mut out = Vec::new();
        for (i, area) in world.warm.iter().enumerate() {
            let key = format!("worlds.{wname}.warm[{i}]");
            let (products, qualities) = names(&key, area)?;
            let over = |count: String| {
                ConfigError::invalid(
                    &key,
                    format!(
                        "play area `{}` brings the warm tile variants (tiles × layers × computations × \
                         qualities) to {count}, over server.max_warm_tiles ({max}): give it fewer levels, \
                         layers, products or qualities, a smaller margin, or raise server.max_warm_tiles",
                        area.name
                    ),
                )
            };
            for &layer in &area.layers {
                let l = &world.layers[layer];
                let (shaded, grid) = computations(&products, l);
                let per_tile = shaded.len() * qualities.len() + grid.len();
                for &z in &area.levels {
                    let reach = Reach::of(area, l, z, &qualities);
                    let tiles =
                        tiles_reached(area, l, z, reach).ok_or_else(|| over("more than 65536 a level".into()))?;
                    if total + tiles.len() * per_tile > max as usize {
                        return Err(over(format!("at least {}", total + tiles.len() * per_tile)));
                    }
                    for tile in tiles {
                        in_range(tile, l, &config.limits).map_err(|e| {
                            ConfigError::invalid(
                                format!("{key}.levels"),
                                format!(
                                    "play area `{}` reaches tile {}/{}/{} of layer `{}`, which cannot be served: {e}",
                                    area.name, tile.z, tile.x, tile.y, l.name
                                ),
                            )
                        })?;
                        for &product in &shaded {
                            for &quality in &qualities {
                                out.push(Variant {
                                    area: i,
                                    layer,
                                    tile,
                                    product,
                                    quality,
                                });
                            }
                        }
                        for &product in &grid {
                            out.push(Variant {
                                area: i,
                                layer,
                                tile,
                                product,
                                quality: Quality::Balanced,
                            });
                        }
                        total += per_tile;
                    }
                }
            }
        }
        if !out.is_empty() {
            all.insert(wname.clone(), out);
        }
    }
    Ok(all)
}

/// The area's products and qualities by their URL names.
fn names(key: &str, area: &WarmArea) -> Result<(Vec<Product>, Vec<Quality>), ConfigError> {
    let products = area
        .products
        .iter()
        .enumerate()
        .map(|(j, p)| {
            Product::parse(p).ok_or_else(|| {
                let known: Vec<&str> = Product::ALL.iter().map(|p| p.name()).collect();
                ConfigError::invalid(
                    format!("{key}.products[{j}]"),
                    format!("unknown product `{p}` (products: {})", known.join(", ")),
                )
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let qualities = area
        .qualities
        .iter()
        .enumerate()
        .map(|(j, q)| {
            Quality::parse(q).ok_or_else(|| {
                let known: Vec<&str> = Quality::ALL.iter().map(|q| q.as_str()).collect();
                ConfigError::invalid(
                    format!("{key}.qualities[{j}]"),
                    format!("unknown quality `{q}` (qualities: {})", known.join(", ")),
                )
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok((products, qualities))
}

/// The computations that make `products` of one tile of `layer`, each named by the
/// product it asks for: the shaded ones (once per quality), then the grid ones. A
/// shading encodes the eager products (`billboards.bin`, `billboards.delta.bin`)
/// whatever it is asked for, and `precipitation.png` on a layer that can precipitate
/// (`cloudscape_core::products::catalogue::encode_shaded`, `recipe::TileRecipe::plan`),
/// so those ride along with any shading; each product encoded only on request takes a
/// shading of its own (one for the atlas's two halves).
fn computations(products: &[Product], layer: &Layer) -> (Vec<Product>, Vec<Product>) {
    let mut shaded: Vec<Product> = Vec::new();
    for &p in products.iter().filter(|p| p.encoding() == Encoding::OnRequest) {
        if !shaded.iter().any(|&q| q.shares_work_with(p)) {
            shaded.push(p);
        }
    }
    if shaded.is_empty()
        && let Some(&eager) = products.iter().find(|p| p.encoding() == Encoding::Eager)
    {
        shaded.push(eager);
    }
    let rides_along =
        |p: &Product| *p == Product::PrecipitationPng && !shaded.is_empty() && layer.preset.precipitates();
    let grid = products
        .iter()
        .copied()
        .filter(|p| !p.needs_shading() && !rides_along(p))
        .collect();
    (shaded, grid)
}

/// The viewer's screen as `cloudscape loadtest` simulates it: 800 pixels wide, a
/// horizontal field of view of 75° (the viewer's default camera).
const VIEWER_WIDTH: f64 = 800.0;
const VIEWER_FOV_DEG: f64 = 75.0;

/// Which tiles of a level an area keeps warm.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Reach {
    /// Those within this many metres of it.
    Within(f64),
    /// `margin = "view"`: those the renderer's level choice (`render::scene::plan_bands`)
    /// may draw at this level for an eye in the area: a tile of level z + 1 splits into
    /// its four level-z children while one of its columns, at the tile's nearest
    /// distance d, spans more than the preset's `lod_pixels` pixels, so the level-z
    /// tiles drawn are children of parents nearer than `split` = column(z + 1) /
    /// (pixel angle × lod_pixels), and within `VIEW_DISTANCE`. (The eye's height only
    /// shortens d; here it is on the ground.)
    View { split: f64 },
}

impl Reach {
    /// How the tiles of level `z` of `layer` are chosen for `area`, the finest of
    /// `qualities` deciding the level choice.
    fn of(area: &WarmArea, layer: &Layer, z: u32, qualities: &[Quality]) -> Reach {
        match area.margin {
            Margin::Metres(m) => Reach::Within(m),
            Margin::View => {
                let lod = qualities
                    .iter()
                    .map(|q| q.settings().lod_pixels)
                    .fold(f64::INFINITY, f64::min);
                let pixel = 2.0 * (VIEWER_FOV_DEG.to_radians() / 2.0).tan() / VIEWER_WIDTH;
                let column = layer.cell_size * f64::from(z + 1).exp2();
                Reach::View {
                    split: column / (pixel * lod),
                }
            }
        }
    }

    /// The farthest a tile kept warm may be from the area, metres.
    fn distance(self) -> f64 {
        match self {
            Reach::Within(m) => m,
            Reach::View { .. } => VIEW_DISTANCE,
        }
    }
}

/// The tiles of level `z` of `layer` that `reach` keeps warm around the area, in row
/// order; `None` when the area's bounding box grown by the reach's distance spans more
/// than [`MAX_CANDIDATE_TILES`].
fn tiles_reached(area: &WarmArea, layer: &Layer, z: u32, reach: Reach) -> Option<Vec<TileId>> {
    let size = TILE_COLUMNS as f64 * layer.cell_size * f64::from(z).exp2();
    let [x0, y0, x1, y1] = area.bounds();
    let m = reach.distance();
    // Tile x covers [x·size, (x + 1)·size): the first whose end is past x0 − m, the last
    // whose start is before x1 + m.
    let first = |v: f64| ((v - m) / size).floor();
    let last = |v: f64| ((v + m) / size).ceil() - 1.0;
    let (cx, cy) = (last(x1) - first(x0) + 1.0, last(y1) - first(y0) + 1.0);
    if !(cx * cy <= MAX_CANDIDATE_TILES) {
        return None;
    }
    let (tx0, ty0, tx1, ty1) = (first(x0) as i64, first(y0) as i64, last(x1) as i64, last(y1) as i64);
    let mut out = Vec::new();
    for y in ty0..=ty1 {
        for x in tx0..=tx1 {
            let rect = [
                x as f64 * size,
                y as f64 * size,
                (x + 1) as f64 * size,
                (y + 1) as f64 * size,
            ];
            let kept = match reach {
                Reach::Within(m) => area.reaches(rect, m),
                Reach::View { split } => {
                    // The parent: the level-(z + 1) tile holding this one.
                    let (px, py, ps) = (x.div_euclid(2) as f64, y.div_euclid(2) as f64, 2.0 * size);
                    let parent = [px * ps, py * ps, (px + 1.0) * ps, (py + 1.0) * ps];
                    area.reaches(rect, VIEW_DISTANCE) && area.reaches(parent, split)
                }
            };
            if kept {
                out.push(TileId { z, x, y });
            }
        }
    }
    Some(out)
}

/// Whether a request for `tile` of `layer` would be served (its columns in range and
/// within the limits), as the tile route checks it.
fn in_range(tile: TileId, layer: &Layer, limits: &Limits) -> Result<(), String> {
    let region = tile.region().map_err(|e| e.to_string())?;
    region.check(tile.z, layer.depth, limits).map_err(|e| e.to_string())
}

/// One variant kept warm: the recipe a request for its URL builds, and its world's clock.
struct WarmTile {
    recipe: Arc<TileRecipe>,
    clock: WorldClock,
    /// Where it comes among keyframes due at the same time: an order of this
    /// process's own (a hash of the variant's place in the list and a number drawn at
    /// start-up), so that replicas keeping the same areas warm work through them in
    /// different orders. With a shared cache each keyframe is then claimed by one
    /// replica (`SharedCache::claim`), mostly the same one span after span, so its
    /// kept state serves the next keyframe; the others take the bytes from Redis.
    order: u64,
}

/// SplitMix64 (a golden-ratio step, then the noise's finaliser `mix64`): the warm
/// worker's per-process order of variants.
fn mix(z: u64) -> u64 {
    mix64(z.wrapping_add(0x9E37_79B9_7F4A_7C15))
}

/// What the worker knows of one variant.
#[derive(Default)]
struct Progress {
    /// Keyframe indices in the cache (from the current one on).
    done: Vec<u64>,
    /// True while a computation of it runs.
    running: bool,
    /// True once its current and next keyframes were both in the cache at once (or it
    /// was given up): readiness waits for every variant's.
    ready: bool,
    /// Given up after failures: no longer kept.
    dropped: bool,
    /// Not tried again before this (after a refusal).
    retry_at: Option<Instant>,
    /// Failures since its last success.
    failures: u32,
}

/// The play areas kept warm, and how far the keeping is.
pub struct Warm {
    tiles: Vec<WarmTile>,
    progress: Mutex<Vec<Progress>>,
    /// `server.warm_threads` (0: no area is kept warm).
    threads: usize,
    /// Variants that have not yet had their current and next keyframes at once.
    start_pending: AtomicUsize,
    started: Notify,
    /// Variants per (world, area index), for discovery.
    counts: BTreeMap<(String, usize), usize>,
    /// The tiles of the areas, by (world fingerprint, layer, tile): where compute-ahead
    /// follows a tile from its first request (`crate::ahead`).
    covered: std::collections::HashSet<(String, usize, TileId)>,
    wake: Notify,
}

/// A keyframe of a variant to compute.
struct Due {
    index: usize,
    keyframe: Keyframe,
    /// From when it runs whatever requests are queued (Unix seconds).
    urgent_at: f64,
}

/// The pieces of the server state a warm tile's recipe holds, as a request's does.
pub struct RecipeParts<'a> {
    pub worlds: &'a Worlds,
    pub sun: &'a SunConfig,
    pub limits: &'a Limits,
    pub kept: Option<Arc<KeptStates>>,
    pub metrics: &'a Arc<Metrics>,
}

impl Warm {
    /// The variants of `all` (from [`variants`]) as recipes, each once (areas may
    /// share coarse tiles); none when `threads` is 0.
    pub fn new(all: BTreeMap<String, Vec<Variant>>, threads: usize, parts: RecipeParts<'_>) -> Warm {
        let mut tiles = Vec::new();
        let mut counts = BTreeMap::new();
        let mut kept = std::collections::HashSet::new();
        // Drawn once per process: scheduling only, never bytes.
        let seed = mix(u64::from(std::process::id())
            ^ SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos() as u64));
        if threads > 0 {
            for (name, list) in all {
                let Ok(world) = parts.worlds.resolve(&name) else {
                    continue;
                };
                let clock = world.world.clock;
                for v in list {
                    *counts.entry((name.clone(), v.area)).or_insert(0) += 1;
                    let shaded = v.product.needs_shading();
                    let quality = if shaded { v.quality.as_str() } else { "-" };
                    if !kept.insert((name.clone(), v.layer, v.tile, v.product, quality)) {
                        continue;
                    }
                    tiles.push(WarmTile {
                        recipe: Arc::new(TileRecipe {
                            world: world.clone(),
                            layer: v.layer,
                            tile: v.tile,
                            product: v.product,
                            quality: v.quality,
                            sun: None,
                            sun_config: parts.sun.clone(),
                            limits: parts.limits.clone(),
                            kept: parts.kept.clone(),
                            metrics: Arc::clone(parts.metrics),
                        }),
                        clock,
                        order: mix(seed ^ tiles.len() as u64),
                    });
                }
            }
        }
        parts.metrics.warm_tiles.set(tiles.len() as i64);
        let covered = tiles
            .iter()
            .map(|t| (t.recipe.world.fingerprint.clone(), t.recipe.layer, t.recipe.tile))
            .collect();
        let progress = tiles.iter().map(|_| Progress::default()).collect();
        Warm {
            start_pending: AtomicUsize::new(tiles.len()),
            tiles,
            progress: Mutex::new(progress),
            threads,
            started: Notify::new(),
            counts,
            covered,
            wake: Notify::new(),
        }
    }

    /// Whether `tile` of `layer` of the world with `fingerprint` is one a play area
    /// keeps warm (in any product or quality).
    pub fn covers(&self, fingerprint: &str, layer: usize, tile: TileId) -> bool {
        !self.covered.is_empty() && self.covered.contains(&(fingerprint.to_string(), layer, tile))
    }

    /// Whether play areas are kept warm (`server.warm_threads` > 0).
    pub fn enabled(&self) -> bool {
        self.threads > 0
    }

    /// The variants area `area` of world `world` keeps warm.
    pub fn count(&self, world: &str, area: usize) -> usize {
        self.counts.get(&(world.to_string(), area)).copied().unwrap_or(0)
    }

    /// Variants that have not yet had their current and next keyframes in the cache
    /// at once (readiness waits for them).
    pub fn start_pending(&self) -> usize {
        self.start_pending.load(Ordering::SeqCst)
    }

    /// Returns once every variant has had its current and next keyframes in the cache
    /// at once (or was given up).
    pub async fn started(&self) {
        loop {
            // Registered before the check: a notification between them is not lost.
            let notified = self.started.notified();
            if self.start_pending() == 0 {
                return;
            }
            notified.await;
        }
    }

    /// Marks variant `p` started (its current and next keyframes in the cache, or given
    /// up); true when it was the last.
    fn mark_started(&self, p: &mut Progress) -> bool {
        if p.ready {
            return false;
        }
        p.ready = true;
        self.start_pending.fetch_sub(1, Ordering::SeqCst) == 1
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Progress>> {
        self.progress.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The most urgent keyframe to compute at Unix second `unix` (current keyframes
    /// first, then by when clients will ask), the keyframes not computed yet, the Unix
    /// second at which the next current keyframe begins, and whether the last variant
    /// not started yet has just had its current and next keyframes at once (then
    /// [`Warm::notify_started`] is due, once the caller has published `pending`).
    fn due(&self, unix: f64) -> (Option<Due>, usize, f64, bool) {
        let now = Instant::now();
        let mut progress = self.lock();
        let mut best: Option<((u8, f64, u64), Due)> = None;
        let mut pending = 0;
        let mut change = f64::INFINITY;
        let mut all_started = false;
        for (index, (tile, p)) in self.tiles.iter().zip(progress.iter_mut()).enumerate() {
            if p.dropped {
                continue;
            }
            let current = tile.recipe.keyframe(world_now(&tile.clock, unix));
            p.done.retain(|&d| d >= current.index);
            if current.t1 > current.t0 {
                change = change.min(tile.clock.unix_at(current.t1));
            }
            let next = tile.recipe.keyframe(current.t1);
            let next_done = next.index <= current.index || p.done.contains(&next.index);
            if p.done.contains(&current.index) && next_done {
                all_started |= self.mark_started(p);
            }
            let keyframes = [(false, current), (true, next)];
            for (is_next, k) in keyframes {
                if (is_next && k.index <= current.index) || p.done.contains(&k.index) {
                    continue;
                }
                pending += 1;
                if p.running || p.retry_at.is_some_and(|r| r > now) {
                    continue;
                }
                let urgent_at = tile.clock.unix_at(k.t0 - (1.0 - URGENT_FROM) * k.span());
                // Current keyframes (0) before next ones (1), then the earliest, then
                // this process's own order.
                let rank = (u8::from(is_next), urgent_at, tile.order);
                if best.as_ref().is_none_or(|(b, _)| rank < *b) {
                    best = Some((
                        rank,
                        Due {
                            index,
                            keyframe: k,
                            urgent_at,
                        },
                    ));
                }
            }
        }
        (best.map(|(_, d)| d), pending, change, all_started)
    }

    /// Wakes [`Warm::started`]'s waiters.
    fn notify_started(&self) {
        self.started.notify_waiters();
    }

    fn start(&self, index: usize) {
        self.lock()[index].running = true;
    }

    /// Records the end of a computation of `due`.
    fn finished(&self, metrics: &Metrics, due: &Due, outcome: Result<bool, ApiError>) {
        let tile = &self.tiles[due.index];
        let mut progress = self.lock();
        let p = &mut progress[due.index];
        p.running = false;
        match outcome {
            Ok(computed) => {
                p.done.push(due.keyframe.index);
                p.failures = 0;
                p.retry_at = None;
                if computed {
                    metrics.warm_computed.inc();
                    let lag = tile.clock.unix_at(due.keyframe.t0) - unix_now();
                    metrics.warm_lag.observe(lag);
                }
            }
            Err(ApiError::Overloaded(_)) => p.retry_at = Some(Instant::now() + RETRY_AFTER),
            Err(e) => {
                p.failures += 1;
                p.retry_at = Some(Instant::now() + RETRY_AFTER);
                if p.failures >= MAX_FAILURES {
                    p.dropped = true;
                    tracing::error!(
                        variant = %tile.recipe.variant(),
                        error = %e,
                        "warm: giving up a tile variant after {MAX_FAILURES} failures"
                    );
                }
            }
        }
        if p.dropped && self.mark_started(p) {
            self.notify_started();
        }
    }
}

/// Where the server is in its life, as the warm worker needs it (`phase` in [`run`]:
/// the server's `Lifecycle`, told apart from its `/readyz` here so that this module
/// does not depend on the server's state).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Not ready yet: warm work may use every compute thread.
    Starting,
    Serving,
    /// Shutting down: nothing new is started.
    Draining,
}

/// The warm worker: runs until the server stops (the task is dropped). `phase` says
/// where the server is in its life.
pub async fn run(
    warm: Arc<Warm>,
    cache: Arc<ResponseCache>,
    metrics: Arc<Metrics>,
    phase: impl Fn() -> Phase + Send + 'static,
) {
    if warm.tiles.is_empty() {
        return;
    }
    let compute_threads = rayon::current_num_threads().max(1);
    let running = Arc::new(AtomicUsize::new(0));
    loop {
        let phase = phase();
        let starting = phase == Phase::Starting;
        let unix = unix_now();
        let (due, pending, change, all_started) = warm.due(unix);
        metrics.warm_pending.set(pending as i64);
        if all_started {
            warm.notify_started();
        }
        let busy = running.load(Ordering::SeqCst);
        let wait = match due {
            None => Duration::from_secs_f64((change - unix).clamp(0.01, IDLE_POLL.as_secs_f64())),
            Some(_) if phase == Phase::Draining => BUSY_POLL,
            Some(due) => {
                // Requests keep priority. Politely (no request queued: the queue holds
                // only warm work; and a compute thread free) a warm keyframe may take any
                // free thread. Urgently (before ready, a current keyframe, or a next one
                // past URGENT_FROM of the span before it) it runs whatever is queued, in
                // the queue's order, at most `warm_threads` at once (before ready, every
                // compute thread). Never in the queue's last place.
                let depth = cache.queue_depth();
                let limit = if starting {
                    warm.threads.max(compute_threads)
                } else {
                    warm.threads
                };
                let polite = depth <= busy && depth < compute_threads;
                let urgent = starting || due.urgent_at <= unix;
                if busy < limit && cache.queue_free() >= 2 && (urgent || polite) {
                    warm.start(due.index);
                    running.fetch_add(1, Ordering::SeqCst);
                    let (warm, cache, metrics, running) = (
                        Arc::clone(&warm),
                        Arc::clone(&cache),
                        Arc::clone(&metrics),
                        Arc::clone(&running),
                    );
                    tokio::spawn(async move {
                        let outcome = compute(&warm, &cache, &metrics, &due).await;
                        warm.finished(&metrics, &due, outcome);
                        running.fetch_sub(1, Ordering::SeqCst);
                        warm.wake.notify_one();
                    });
                    continue;
                }
                BUSY_POLL
            }
        };
        tokio::select! {
            _ = warm.wake.notified() => {}
            _ = tokio::time::sleep(wait) => {}
        }
    }
}

/// Computes one warm keyframe into the cache, as a request for its URL would: `Ok(true)`
/// when this computation put it there, `Ok(false)` when it was there already.
async fn compute(warm: &Warm, cache: &Arc<ResponseCache>, metrics: &Arc<Metrics>, due: &Due) -> Result<bool, ApiError> {
    let recipe = &warm.tiles[due.index].recipe;
    let (work, job) = recipe.plan(due.keyframe)?;
    tracing::debug!(variant = %recipe.variant(), index = due.keyframe.index, "warm: start");
    let computation = Computation {
        kind: recipe.product.family(),
        key: recipe.key(due.keyframe),
        work,
        job,
    };
    cache.compute_ahead(metrics, computation, Asker::Warm).await
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The embedded config with the default world's play areas replaced by one, the
    /// TOML table `warm`.
    fn config(warm: &str) -> Result<Config, ConfigError> {
        let mut doc: toml::Table = cloudscape_core::world::DEFAULT_CONFIG.parse().unwrap();
        let area: toml::Table = warm.parse().unwrap();
        let default = doc["worlds"]["default"].as_table().unwrap().clone();
        let mut default = default;
        default.insert("warm".into(), toml::Value::Array(vec![toml::Value::Table(area)]));
        doc.get_mut("worlds")
            .and_then(|w| w.as_table_mut())
            .unwrap()
            .insert("default".into(), toml::Value::Table(default));
        Config::parse(&toml::to_string(&doc).unwrap())
    }

    #[test]
    fn a_town_inside_one_tile_is_one_variant_per_layer_and_level() {
        // 5 km around the centre of level-0 tile (0, 0) of the 100 m layers (25.6 km).
        let c = config("name = \"town\"\nbbox = [10300.0, 10300.0, 15300.0, 15300.0]\nlevels = [0, 1, 2]").unwrap();
        let all = variants(&c, 4096).unwrap();
        let list = &all["default"];
        // Three layers × three levels, each one shading (billboards.bin and its delta) in `fast`.
        assert_eq!(list.len(), 9, "{list:?}");
        assert!(list.iter().all(|v| v.tile.x == 0 && v.tile.y == 0));
        assert!(
            list.iter()
                .all(|v| v.product == Product::BillboardsBin && v.quality == Quality::Fast)
        );
    }

    #[test]
    fn products_group_into_computations() {
        let c = Config::embedded();
        let layer = &c.worlds["default"].layers[0];
        let (shaded, grid) = computations(
            &[
                Product::ShadowPng,
                Product::BillboardsBin,
                Product::AtlasJson,
                Product::AtlasPng,
                Product::DensityU8,
                Product::PrecipitationPng,
            ],
            layer,
        );
        // shadow.png and the atlas are each encoded on request: a shading each (the
        // atlas's halves share one); billboards.bin comes with either.
        assert_eq!(shaded, [Product::ShadowPng, Product::AtlasJson]);
        // The cumulus layer precipitates: its map comes with the shading.
        assert!(layer.preset.precipitates());
        assert_eq!(grid, [Product::DensityU8]);
        let (shaded, grid) = computations(&[Product::BillboardsDelta, Product::BillboardsBin], layer);
        assert_eq!(
            (shaded.as_slice(), grid.len()),
            ([Product::BillboardsDelta].as_slice(), 0)
        );
    }

    #[test]
    fn margins_reach_the_neighbours_and_the_cap_names_the_area() {
        let c = config(
            "name = \"town\"\nbbox = [10300.0, 10300.0, 15300.0, 15300.0]\nmargin = 12000.0\nlayers = [\"cumulus\"]",
        )
        .unwrap();
        // 10.3 − 12 km < 0 and 15.3 + 12 km > 25.6 km: the four level-0 neighbours by an
        // edge; those by a corner are √2 × 10.3 ≈ 14.6 km away.
        assert_eq!(variants(&c, 4096).unwrap()["default"].len(), 5);
        let e = variants(&c, 4).unwrap_err().to_string();
        assert!(e.contains("worlds.default.warm[0]") && e.contains("`town`"), "{e}");
        assert!(e.contains("server.max_warm_tiles"), "{e}");
    }

    #[test]
    fn the_view_margin_keeps_what_the_level_choice_may_draw_from_the_area() {
        let c = config(
            "name = \"town\"\nbbox = [10300.0, 10300.0, 15300.0, 15300.0]\nmargin = \"view\"\nlayers = [\"cumulus\"]",
        )
        .unwrap();
        let mut tiles: Vec<(i64, i64)> = variants(&c, 4096).unwrap()["default"]
            .iter()
            .map(|v| (v.tile.x, v.tile.y))
            .collect();
        tiles.sort_unstable();
        // `fast` on the viewer's screen splits a level-1 tile (51.2 km) nearer than
        // 200 m / (2 tan 37.5° / 800 × 8) ≈ 13.0 km: parents (0, 0), (−1, 0) and (0, −1)
        // (10.3 km away; (−1, −1) is 14.6 km), whose children within 30 km are drawn.
        assert_eq!(
            tiles,
            [(-1, 0), (-1, 1), (0, -1), (0, 0), (0, 1), (1, -1), (1, 0), (1, 1)]
        );
    }

    #[test]
    fn unknown_products_and_qualities_are_named() {
        let c = config("name = \"town\"\nbbox = [0.0, 0.0, 1.0, 1.0]\nproducts = [\"shadow.png\", \"clouds.gif\"]")
            .unwrap();
        let e = variants(&c, 4096).unwrap_err().to_string();
        assert!(
            e.contains("worlds.default.warm[0].products[1]") && e.contains("clouds.gif"),
            "{e}"
        );
        let c = config("name = \"town\"\nbbox = [0.0, 0.0, 1.0, 1.0]\nqualities = [\"ultra\"]").unwrap();
        let e = variants(&c, 4096).unwrap_err().to_string();
        assert!(
            e.contains("worlds.default.warm[0].qualities[0]") && e.contains("ultra"),
            "{e}"
        );
    }

    #[test]
    fn a_clock_out_of_range_now_is_refused() {
        let text = cloudscape_core::world::DEFAULT_CONFIG.replace(
            "[worlds.overcast]\nseed = 1",
            "[worlds.overcast]\nseed = 1\nclock = { offset = -1e12 }",
        );
        let c = Config::parse(&text).unwrap();
        let e = check(&c, &ServerConfig::default(), 1.7e9).unwrap_err().to_string();
        assert!(e.contains("worlds.overcast.clock"), "{e}");
    }
}
