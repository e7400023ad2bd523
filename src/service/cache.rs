//! The response cache and the bounded compute queue behind it.
//!
//! A miss runs its computation on rayon, but only if one of the queue's slots is free:
//! a full queue sheds the request (503 + `Retry-After`) instead of growing a backlog.
//! Concurrent misses on one key join one computation (moka's `try_get_with`). The
//! computation runs in its own task, so a request whose time budget runs out (503)
//! still leaves the bytes in the cache for its retry.
//!
//! With a [`SharedCache`] (Redis) configured, the one computation of a key first asks
//! it, and stores what it computed there afterwards without waiting.

use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Bytes;
use moka::future::Cache;
use tokio::sync::{Semaphore, oneshot};

use super::error::ApiError;
use super::key::CacheKey;
use super::metrics::Metrics;
use super::shared::{Lookup, SharedCache};

/// Bounded CPU work: at most `capacity` jobs running or waiting for a rayon thread.
pub struct ComputeQueue {
    slots: Arc<Semaphore>,
    capacity: usize,
}

impl ComputeQueue {
    pub fn new(capacity: usize) -> ComputeQueue {
        ComputeQueue {
            slots: Arc::new(Semaphore::new(capacity)),
            capacity,
        }
    }

    /// Jobs running or queued.
    pub fn depth(&self) -> usize {
        self.capacity - self.slots.available_permits()
    }

    /// Runs `job` on the rayon pool if a slot is free, or sheds it. A panicking job is
    /// a bug: it becomes `Internal`, the server keeps running.
    pub async fn run<T: Send + 'static>(
        &self,
        metrics: &Metrics,
        kind: &str,
        job: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        let Ok(permit) = self.slots.clone().try_acquire_owned() else {
            metrics.shed.with_label_values(&[kind]).inc();
            return Err(ApiError::Overloaded);
        };
        metrics.queue_depth.set(self.depth() as i64);
        metrics.computations.with_label_values(&[kind]).inc();
        let timer = metrics.observe_compute(kind);
        let (tx, rx) = oneshot::channel();
        rayon::spawn(move || {
            let started = Instant::now();
            let result = std::panic::catch_unwind(AssertUnwindSafe(job));
            timer.observe(started.elapsed().as_secs_f64());
            drop(permit);
            let _ = tx.send(result);
        });
        let result = rx.await;
        metrics.queue_depth.set(self.depth() as i64);
        match result {
            Ok(Ok(r)) => r,
            Ok(Err(panic)) => {
                let what = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "a computation panicked".to_string());
                Err(ApiError::Internal(what))
            }
            Err(_) => Err(ApiError::Internal("a computation was lost".to_string())),
        }
    }
}

/// Encoded response bytes under a byte budget, plus the queue that fills it.
pub struct ResponseCache {
    cache: Cache<CacheKey, Bytes>,
    queue: ComputeQueue,
    /// Time budget of one request.
    budget: Duration,
    /// The second-level cache shared by replicas, if configured.
    shared: Option<Arc<SharedCache>>,
}

impl ResponseCache {
    pub fn new(max_bytes: u64, queue_capacity: usize, budget: Duration, shared: Option<SharedCache>) -> ResponseCache {
        let cache = Cache::builder()
            .weigher(|k: &CacheKey, v: &Bytes| (k.weight() + v.len()).try_into().unwrap_or(u32::MAX))
            .max_capacity(max_bytes)
            .build();
        ResponseCache {
            cache,
            queue: ComputeQueue::new(queue_capacity),
            budget,
            shared: shared.map(Arc::new),
        }
    }

    pub fn weighted_size(&self) -> u64 {
        self.cache.weighted_size()
    }

    /// The bytes of `key`, from the cache or computed by `job` (once for all concurrent
    /// callers), within the request's time budget.
    pub async fn get_or_compute(
        self: &Arc<Self>,
        metrics: &Arc<Metrics>,
        kind: &'static str,
        key: CacheKey,
        job: impl FnOnce() -> Result<Bytes, ApiError> + Send + 'static,
    ) -> Result<Bytes, ApiError> {
        self.get_or_compute_with_siblings(metrics, kind, key, move || job().map(|b| (b, Vec::new())))
            .await
    }

    /// Like [`get_or_compute`](Self::get_or_compute) for a job that also produces the
    /// bytes of other keys from the same work (the products of one shaded tile): those
    /// are cached too.
    pub async fn get_or_compute_with_siblings(
        self: &Arc<Self>,
        metrics: &Arc<Metrics>,
        kind: &'static str,
        key: CacheKey,
        job: impl FnOnce() -> Result<(Bytes, Vec<(CacheKey, Bytes)>), ApiError> + Send + 'static,
    ) -> Result<Bytes, ApiError> {
        if let Some(bytes) = self.cache.get(&key).await {
            metrics.cache_hits.with_label_values(&[kind]).inc();
            return Ok(bytes);
        }
        metrics.cache_misses.with_label_values(&[kind]).inc();
        let this = Arc::clone(self);
        let m = Arc::clone(metrics);
        let task = tokio::spawn(async move {
            let cache = this.cache.clone();
            let shared = this.shared.clone();
            let init = async {
                if let Some(shared) = &shared
                    && let Lookup::Hit(bytes) = shared.get(&m, kind, &key).await
                {
                    return Ok(bytes);
                }
                let (bytes, siblings) = this.queue.run(&m, kind, job).await?;
                for (k, b) in &siblings {
                    cache.insert(k.clone(), b.clone()).await;
                }
                if let Some(shared) = &shared {
                    let mut entries = siblings;
                    entries.push((key.clone(), bytes.clone()));
                    shared.put(&m, entries);
                }
                Ok::<_, ApiError>(bytes)
            };
            this.cache
                .try_get_with(key.clone(), init)
                .await
                .map_err(|e| (*e).clone())
        });
        match tokio::time::timeout(self.budget, task).await {
            Ok(Ok(result)) => result,
            Ok(Err(join)) => Err(ApiError::Internal(format!("compute task failed: {join}"))),
            Err(_) => {
                metrics.timeouts.with_label_values(&[kind]).inc();
                Err(ApiError::Timeout(self.budget.as_millis() as u64))
            }
        }
    }

    /// Runs `job` through the queue with no time budget and no caching (start-up work).
    pub async fn run_unbudgeted<T: Send + 'static>(
        &self,
        metrics: &Metrics,
        kind: &'static str,
        job: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        self.queue.run(metrics, kind, job).await
    }
}

impl ResponseCache {
    /// Puts bytes computed outside a request (start-up work) in the cache.
    pub async fn insert(&self, key: CacheKey, bytes: Bytes) {
        self.cache.insert(key, bytes).await;
    }

    /// Compute jobs running or queued.
    pub fn queue_depth(&self) -> usize {
        self.queue.depth()
    }
}
