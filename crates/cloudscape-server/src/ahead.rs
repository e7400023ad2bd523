//! Compute-ahead: the next keyframes of the tiles being watched, computed before the
//! clock reaches them.
//!
//! Every tile request tells the [`HotSet`] which variant (world, layer, tile, product,
//! quality, sun) was asked for which keyframe at which `t`. The hot set keeps, per
//! variant, a demand count that decays with a half-life of [`DEMAND_HALF_LIFE`], the
//! latest keyframe asked, and the rate at which the asked `t` advances against the
//! server's own clock (world seconds per real second, 1 until measured). The next
//! keyframe of a *watched* variant is planned with a deadline: the real time at which
//! that clock reaches it.
//!
//! Watched means asked for by a second request (the same keyframe again, another
//! keyframe, another client: players come back to the tiles around them, a crawler
//! does not), or lying in a play area (`crate::warm`), where players are expected. A
//! tile asked for once is followed, but nothing is computed for it: a crawl of
//! one-off tiles would otherwise buy a keyframe nobody asks for per tile it touches.
//! When the hot set is full, a variant asked for once is forgotten before a watched
//! one, so a crawl cannot push the players' tiles out either.
//!
//! A background task ([`run`]) computes planned keyframes most urgent first (earliest
//! deadline, then most demanded), through the same cache and compute queue as the
//! requests, so a request that arrives meanwhile joins the computation instead of
//! repeating it. It runs at most `server.ahead_threads` computations at once, and
//! only while no request is queued and the queue has a free compute thread and another
//! free place, so requests
//! keep priority: a request is never shed for work ahead, and waits at most for the
//! computations ahead already running. Its computations are counted in
//! `cloudscape_ahead_computed_total`, not in `cloudscape_computations_total`, which
//! counts what requests waited for.
//!
//! Replicas: bytes are deterministic, so two replicas computing the same keyframe
//! ahead only waste work. Routing each tile to one replica by its path without the
//! query (nginx `hash $uri consistent` for `/tiles/`, `docker/nginx.conf`) sends all
//! keyframes of a tile to the replica that computes them ahead, so each replica owns
//! its share of the hot set.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::Notify;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::Work;
use cloudscape_core::world::Keyframe;

use crate::cache::{Asker, Computation, ResponseCache, WithSiblings};
use crate::error::ApiError;
use crate::key::CacheKey;
use crate::metrics::Metrics;

/// A computation ahead: the bytes of a key and of its siblings.
pub type AheadJob = Box<dyn FnOnce(&Cancel) -> Result<WithSiblings, ApiError> + Send>;

/// What compute-ahead needs of a watched tile variant (`recipe::TileRecipe`).
pub trait Recipe: Send + Sync {
    /// The variant's identity, whatever its time.
    fn variant(&self) -> String;
    /// The keyframe containing `t`.
    fn keyframe(&self, t: f64) -> Keyframe;
    /// The cache key of one keyframe.
    fn key(&self, keyframe: Keyframe) -> CacheKey;
    /// The family its work is counted under.
    fn family(&self) -> &'static str;
    /// The work of one keyframe and the job that does it.
    fn plan(&self, keyframe: Keyframe) -> Result<(Work, AheadJob), ApiError>;
}

/// Demand counts halve after this long without requests.
pub const DEMAND_HALF_LIFE: Duration = Duration::from_secs(30);
/// A variant not asked for this long (or for three of its spans, if longer) leaves
/// the hot set.
const FORGET_AFTER: Duration = Duration::from_secs(60);
/// How often the worker looks for work when nothing wakes it.
const IDLE_POLL: Duration = Duration::from_millis(250);
/// How long the worker waits for a free compute thread before it looks again.
const BUSY_POLL: Duration = Duration::from_millis(20);

/// One watched tile variant.
struct HotTile {
    recipe: Arc<dyn Recipe>,
    /// Requests, decayed with [`DEMAND_HALF_LIFE`].
    demand: f64,
    /// Asked for by more than one request, or in a play area: only then are its next
    /// keyframes computed ahead.
    watched: bool,
    last_seen: Instant,
    /// The first request: the clock rate is measured from it.
    first: (Instant, f64),
    /// The latest keyframe asked for, and the `t` and time it was asked at.
    latest: (Keyframe, f64, Instant),
    /// The keyframe planned ahead, and when the clock reaches it.
    planned: Option<(Keyframe, Instant)>,
    /// A keyframe computed ahead (its index), and whether a request found it missing.
    done: Option<u64>,
    missed: Option<u64>,
    /// True while its computation runs.
    running: bool,
}

impl HotTile {
    /// World seconds per real second, as the requests advanced; 1 until measured.
    fn clock_rate(&self) -> f64 {
        let (at, t) = self.first;
        let (_, t_latest, latest_at) = self.latest;
        let real = latest_at.duration_since(at).as_secs_f64();
        let rate = (t_latest - t) / real;
        if real >= 2.0 && rate.is_finite() && rate > 0.0 {
            rate.clamp(0.01, 1e4)
        } else {
            1.0
        }
    }

    fn decayed(&self, now: Instant) -> f64 {
        let idle = now.duration_since(self.last_seen).as_secs_f64();
        self.demand * 0.5f64.powf(idle / DEMAND_HALF_LIFE.as_secs_f64())
    }
}

/// The tiles being watched and the keyframes planned ahead for them.
pub struct HotSet {
    tiles: Mutex<HashMap<String, HotTile>>,
    /// Most variants followed.
    capacity: usize,
    /// Computations ahead at once (0: compute-ahead is off).
    threads: usize,
    wake: Notify,
}

/// A keyframe to compute ahead.
struct Planned {
    variant: String,
    recipe: Arc<dyn Recipe>,
    keyframe: Keyframe,
    deadline: Instant,
}

impl HotSet {
    pub fn new(capacity: usize, threads: usize) -> HotSet {
        HotSet {
            tiles: Mutex::new(HashMap::new()),
            capacity,
            threads,
            wake: Notify::new(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, HotTile>> {
        self.tiles.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A request asked for `keyframe` of `recipe`'s variant at `t` (`in_area`: the tile
    /// lies in a play area): counts the demand, notes a planned keyframe that is not
    /// ready yet as missed, and plans the next keyframe once the variant is watched.
    pub fn watched(&self, metrics: &Metrics, recipe: &Arc<dyn Recipe>, keyframe: Keyframe, t: f64, in_area: bool) {
        if self.threads == 0 || keyframe.is_instant() {
            return;
        }
        let now = Instant::now();
        let variant = recipe.variant();
        let mut tiles = self.lock();
        let seen = tiles.contains_key(&variant);
        if !seen && tiles.len() >= self.capacity {
            // Full: forget a variant asked for once (the longest ago), else the least
            // watched.
            let coldest = tiles
                .iter()
                .filter(|(_, h)| !h.watched && !h.running)
                .min_by_key(|(_, h)| h.last_seen)
                .or_else(|| {
                    tiles
                        .iter()
                        .min_by(|a, b| a.1.decayed(now).total_cmp(&b.1.decayed(now)))
                })
                .map(|(k, _)| k.clone());
            if let Some(coldest) = coldest {
                tiles.remove(&coldest);
            }
        }
        let hot = tiles.entry(variant).or_insert_with(|| HotTile {
            recipe: Arc::clone(recipe),
            demand: 0.0,
            watched: false,
            last_seen: now,
            first: (now, t),
            latest: (keyframe, t, now),
            planned: None,
            done: None,
            missed: None,
            running: false,
        });
        hot.demand = hot.decayed(now) + 1.0;
        hot.last_seen = now;
        hot.watched |= seen || in_area;
        if let Some((planned, _)) = hot.planned
            && planned.index == keyframe.index
            && hot.done != Some(keyframe.index)
            && hot.missed != Some(keyframe.index)
        {
            hot.missed = Some(keyframe.index);
            metrics.ahead_missed.inc();
        }
        if keyframe.index >= hot.latest.0.index {
            hot.latest = (keyframe, t, now);
        }
        let (latest, t_latest, _) = hot.latest;
        let next = hot.recipe.keyframe(latest.t1);
        let already =
            hot.planned.is_some_and(|(p, _)| p.index >= next.index) || hot.done.is_some_and(|d| d >= next.index);
        if hot.watched && next.index > latest.index && !already {
            let wait = ((next.t0 - t_latest) / hot.clock_rate()).clamp(0.0, 86_400.0);
            hot.planned = Some((next, now + Duration::from_secs_f64(wait)));
            drop(tiles);
            self.wake.notify_one();
        }
    }

    /// The most urgent planned keyframe not running, marked running; forgets
    /// variants nobody watches any more.
    fn next_job(&self, metrics: &Metrics) -> Option<Planned> {
        let now = Instant::now();
        let mut tiles = self.lock();
        tiles.retain(|_, h| {
            let span = h.latest.0.span() / h.clock_rate();
            let keep = FORGET_AFTER.max(Duration::from_secs_f64((3.0 * span).min(86_400.0)));
            h.running || now.duration_since(h.last_seen) < keep
        });
        metrics.ahead_hot.set(tiles.len() as i64);
        let pending = tiles.values().filter(|h| h.planned.is_some() && !h.running).count();
        metrics.ahead_pending.set(pending as i64);
        let (variant, hot) = tiles
            .iter_mut()
            .filter(|(_, h)| h.planned.is_some() && !h.running)
            .min_by(|a, b| {
                let (da, db) = (a.1.planned.map(|p| p.1), b.1.planned.map(|p| p.1));
                da.cmp(&db).then(b.1.decayed(now).total_cmp(&a.1.decayed(now)))
            })?;
        let (keyframe, deadline) = hot.planned?;
        hot.running = true;
        Some(Planned {
            variant: variant.clone(),
            recipe: Arc::clone(&hot.recipe),
            keyframe,
            deadline,
        })
    }

    /// Records the end of a computation ahead.
    fn finished(&self, job: &Planned, computed: bool) {
        let mut tiles = self.lock();
        if let Some(h) = tiles.get_mut(&job.variant) {
            h.running = false;
            if h.planned.is_some_and(|(p, _)| p.index == job.keyframe.index) {
                h.planned = None;
            }
            if computed {
                h.done = Some(job.keyframe.index);
            }
        }
    }
}

/// The compute-ahead worker: runs until the server stops (the task is dropped).
pub async fn run(hot: Arc<HotSet>, cache: Arc<ResponseCache>, metrics: Arc<Metrics>) {
    if hot.threads == 0 {
        return;
    }
    let slots = Arc::new(tokio::sync::Semaphore::new(hot.threads));
    let threads = rayon::current_num_threads().max(1);
    loop {
        // Only while no request is queued, with a free compute thread, and never in the
        // queue's last place: requests keep priority, and none is shed to make room
        // for work ahead.
        let running_ahead = hot.threads - slots.available_permits();
        if cache.queue_depth() > running_ahead || cache.queue_depth() >= threads || cache.queue_free() < 2 {
            tokio::time::sleep(BUSY_POLL).await;
            continue;
        }
        let Ok(permit) = Arc::clone(&slots).acquire_owned().await else {
            return;
        };
        let Some(job) = hot.next_job(&metrics) else {
            drop(permit);
            tokio::select! {
                _ = hot.wake.notified() => {}
                _ = tokio::time::sleep(IDLE_POLL) => {}
            }
            continue;
        };
        let (hot, cache, metrics) = (Arc::clone(&hot), Arc::clone(&cache), Arc::clone(&metrics));
        tokio::spawn(async move {
            let computed = compute(&cache, &metrics, &job).await;
            hot.finished(&job, computed);
            drop(permit);
        });
    }
}

/// Computes one planned keyframe into the cache; true when it is there afterwards.
async fn compute(cache: &Arc<ResponseCache>, m: &Arc<Metrics>, job: &Planned) -> bool {
    let key = job.recipe.key(job.keyframe);
    let kind = job.recipe.family();
    let Ok((work, plan)) = job.recipe.plan(job.keyframe) else {
        return false;
    };
    tracing::debug!(variant = %job.variant, index = job.keyframe.index, bytes = work.bytes, "ahead: start");
    let computed = cache
        .compute_ahead(
            m,
            Computation {
                kind,
                key,
                work,
                job: plan,
            },
            Asker::Ahead,
        )
        .await
        .is_ok();
    tracing::debug!(variant = %job.variant, computed, "ahead: end");
    if computed {
        m.ahead_computed.inc();
        let late = Instant::now().saturating_duration_since(job.deadline);
        m.ahead_lag.observe(late.as_secs_f64());
    }
    computed
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A variant of its own name, keyframes 10 s apart, nothing to compute.
    struct Tile(String);

    impl Recipe for Tile {
        fn variant(&self) -> String {
            self.0.clone()
        }
        fn keyframe(&self, t: f64) -> Keyframe {
            Keyframe::on_grid(t, 10.0)
        }
        fn key(&self, keyframe: Keyframe) -> CacheKey {
            CacheKey(format!("{}|k={}", self.0, keyframe.index))
        }
        fn family(&self) -> &'static str {
            "tile_shaded"
        }
        fn plan(&self, _: Keyframe) -> Result<(Work, AheadJob), ApiError> {
            Ok((Work::default(), Box::new(|_: &Cancel| Err(ApiError::Cancelled))))
        }
    }

    fn ask(hot: &HotSet, m: &Metrics, name: &str, t: f64, in_area: bool) {
        let recipe: Arc<dyn Recipe> = Arc::new(Tile(name.into()));
        hot.watched(m, &recipe, Keyframe::on_grid(t, 10.0), t, in_area);
    }

    fn planned(hot: &HotSet) -> Vec<String> {
        let mut v: Vec<String> = hot
            .lock()
            .iter()
            .filter(|(_, h)| h.planned.is_some())
            .map(|(k, _)| k.clone())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn only_watched_tiles_get_their_next_keyframe_planned() {
        let (hot, m) = (HotSet::new(4096, 1), Metrics::new());
        // A crawl: a hundred tiles asked for once each.
        for i in 0..100 {
            ask(&hot, &m, &format!("crawl/{i}"), 105.0, false);
        }
        assert!(planned(&hot).is_empty(), "{:?}", planned(&hot));
        // A player's tile, asked again (the same keyframe, or the next one).
        ask(&hot, &m, "player/a", 105.0, false);
        ask(&hot, &m, "player/a", 107.0, false);
        ask(&hot, &m, "player/b", 105.0, false);
        ask(&hot, &m, "player/b", 112.0, false);
        // A tile in a play area, from its first request.
        ask(&hot, &m, "town/c", 105.0, true);
        assert_eq!(planned(&hot), ["player/a", "player/b", "town/c"]);
        assert_eq!(hot.lock()["player/b"].planned.unwrap().0.index, 12);
    }

    #[test]
    fn a_full_hot_set_forgets_tiles_asked_for_once_first() {
        let (hot, m) = (HotSet::new(4, 1), Metrics::new());
        ask(&hot, &m, "player", 105.0, false);
        ask(&hot, &m, "player", 106.0, false);
        for i in 0..20 {
            ask(&hot, &m, &format!("crawl/{i}"), 105.0, false);
        }
        let tiles = hot.lock();
        assert_eq!(tiles.len(), 4);
        assert!(tiles.contains_key("player"), "the crawl pushed the player's tile out");
        assert!(tiles.contains_key("crawl/19"));
    }
}
