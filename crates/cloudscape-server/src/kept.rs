//! What tiles keep between keyframes, under a byte budget.
//!
//! A tile's next keyframe starts from what its last one kept
//! ([`cloudscape_core::render::tile::KeptTile`]: the latest density grids, at level 0
//! the automaton's runs, and the latest instants shaded), so it costs one automaton
//! step and the shading of one instant instead of a cold computation. The states are kept per (world fingerprint,
//! layer, tile) in a cache weighed by the bytes each holds (measured after every
//! job), under `server.kept_bytes`, a part of `server.cache_bytes`: the least
//! recently used go first, and a tile whose state was dropped computes cold once.
//!
//! A job takes its tile's state only if no other job holds it (`try_lock`): a job
//! runs on the rayon pool, whose threads pick up other jobs while they wait, so a
//! job that waited for a lock held by a job on its own thread would wait forever.
//! The rare second job on one tile at one moment computes cold, with the same bytes.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use moka::sync::Cache;
use prometheus::{IntCounter, IntCounterVec};

use cloudscape_core::density::kept::KeptCounts;
use cloudscape_core::render::tile::{KeptTile, ShadingCounts};

use crate::metrics::Metrics;

/// What one kept state costs besides its own allocations: the `Kept` and its
/// `KeptTile` structs and moka's entry, rounded up.
const ENTRY_OVERHEAD: u64 = 2048;

/// One tile's kept state and the bytes it held when last weighed.
pub struct Kept {
    state: Mutex<KeptTile>,
    bytes: AtomicU64,
}

/// The kept states of the tiles, by key, within a byte budget.
pub struct KeptStates {
    cache: Cache<String, Arc<Kept>>,
    /// Grids given, by how (`reused`, `live`, `cold`).
    grids: IntCounterVec,
    /// Automaton steps advanced by live runs.
    steps: IntCounter,
    /// Instants of shading given, by how (`reused`, `shaded`).
    shadings: IntCounterVec,
    /// Jobs that found their tile's state held by another job (they computed cold).
    busy: IntCounter,
}

impl KeptStates {
    /// A store of at most `max_bytes`; `None` for 0 (no state is kept: every keyframe
    /// computes cold).
    pub fn new(max_bytes: u64, metrics: &Metrics) -> Option<KeptStates> {
        (max_bytes > 0).then(|| KeptStates {
            cache: Cache::builder()
                // The state's own allocations (capacities, as `KeptTile::bytes` counts
                // them) and the entry's: its key, its `Kept`, moka's nodes.
                .weigher(|k: &String, v: &Arc<Kept>| {
                    let entry = crate::allocator::allocation(k.len()) as u64 + ENTRY_OVERHEAD;
                    u32::try_from(v.bytes.load(Ordering::Relaxed) + entry).unwrap_or(u32::MAX)
                })
                .max_capacity(max_bytes)
                .build(),
            grids: metrics.kept_grids.clone(),
            steps: metrics.kept_steps.clone(),
            shadings: metrics.kept_shadings.clone(),
            busy: metrics.kept_busy.clone(),
        })
    }

    /// Runs `job` with the kept state of `key` (made by `make` if there is none), or
    /// with `None` when another job holds it; then weighs the state again.
    pub fn with<R>(
        &self,
        key: &str,
        make: impl FnOnce() -> KeptTile,
        job: impl FnOnce(Option<&mut KeptTile>) -> R,
    ) -> R {
        let entry = self.cache.get_with(key.to_string(), || {
            Arc::new(Kept {
                state: Mutex::new(make()),
                bytes: AtomicU64::new(0),
            })
        });
        let Ok(mut state) = entry.state.try_lock() else {
            self.busy.inc();
            return job(None);
        };
        let (counts, steps, shadings) = (
            state.density.counts(),
            state.density.live_steps(),
            state.shading_counts(),
        );
        let out = job(Some(&mut state));
        let after = state.density.counts();
        let KeptCounts { reused, live, cold } = after;
        for (label, n) in [
            ("reused", reused - counts.reused),
            ("live", live - counts.live),
            ("cold", cold - counts.cold),
        ] {
            self.grids.with_label_values(&[label]).inc_by(n);
        }
        self.steps.inc_by(state.density.live_steps() - steps);
        let ShadingCounts { reused, shaded } = state.shading_counts();
        for (label, n) in [
            ("reused", reused - shadings.reused),
            ("shaded", shaded - shadings.shaded),
        ] {
            self.shadings.with_label_values(&[label]).inc_by(n);
        }
        entry.bytes.store(state.bytes() as u64, Ordering::Relaxed);
        drop(state);
        // Inserted again to be weighed again (moka weighs on insert), and evicted down
        // to the budget at once rather than when moka next gets round to it.
        self.cache.insert(key.to_string(), entry);
        self.cache.run_pending_tasks();
        out
    }

    /// Bytes the kept states hold, as last weighed.
    pub fn bytes(&self) -> u64 {
        self.cache.run_pending_tasks();
        self.cache.weighted_size()
    }

    /// Tiles with a kept state.
    pub fn tiles(&self) -> u64 {
        self.cache.run_pending_tasks();
        self.cache.entry_count()
    }
}
