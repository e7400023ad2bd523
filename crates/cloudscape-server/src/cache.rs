//! The response cache and the bounded compute queue behind it.
//!
//! A miss runs its computation on rayon, but only if one of the queue's slots is free:
//! a full queue sheds the request (503 + `Retry-After`) instead of growing a backlog.
//! Concurrent misses on one key join one computation (moka's `try_get_with`). Every
//! computation has a [`Cancel`] token that fires once no request waits for it any
//! more (the last one's time budget ran out, or its client went away): the job
//! then stops at its next check and gives its queue slot and memory back at once,
//! instead of finishing work nobody will read.
//!
//! `Retry-After` on a shed answer is the real wait: jobs queued × their recent
//! mean time / compute threads.
//!
//! Admission counts the queue, not one job ([`Backlog`]): a request's job is admitted
//! only if the estimated work already admitted ahead of it (what running jobs have
//! left, and every queued job) plus its own can be done within the request's time
//! budget at the rate the queue has been working. A burst of expensive requests is
//! then answered by admitting what can finish and shedding the rest with 503 and a
//! `Retry-After` of the backlog's time, instead of admitting a queue-full that all
//! time out together at the budget.
//!
//! With a [`SharedCache`] (Redis) configured, the one computation of a key first asks
//! it, and stores what it computed there afterwards without waiting.

use std::collections::HashMap;
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::{Duration, Instant};

use axum::body::Bytes;
use moka::future::Cache;
use tokio::sync::{Semaphore, oneshot};

use crate::encode::Coding;
use crate::error::ApiError;
use crate::key::CacheKey;
use crate::metrics::Metrics;
use crate::shared::{Lookup, SharedCache};
use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::Work;

/// Mean job time the queue assumes before it has measured any, seconds.
const INITIAL_MEAN_JOB_S: f64 = 0.05;
/// `mean_job_s` before the first job ends (no `f64` has these bits: a NaN payload).
const NO_JOB_YET: u64 = u64::MAX;
/// Weight of the newest job in the running mean of job times.
const MEAN_JOB_WEIGHT: f64 = 0.25;
/// How often a job waiting for a running place looks at its cancellation token.
const CANCEL_POLL: Duration = Duration::from_millis(50);
/// `Retry-After` bounds, seconds.
const RETRY_AFTER_S: (u32, u32) = (1, 60);

/// How long a replica's claim on a background computation holds in the shared cache
/// (`SharedCache::claim`): longer than any such computation takes, so a replica that
/// died with it leaves it to another within this time.
const CLAIM_TTL: Duration = Duration::from_secs(60);

/// Who a computation is for: a request waiting on it, or one of the background tasks,
/// compute-ahead (`crate::ahead`) and the play areas kept warm (`crate::warm`), whose
/// computations and refusals are counted apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Asker {
    Request,
    Ahead,
    Warm,
}

/// The share of the time budget that the backlog ahead of a request and the request's
/// own work may fill: the rest is the margin for estimates that come out low.
const BACKLOG_SHARE_OF_BUDGET: f64 = 0.8;
/// Busy seconds over which the queue's working rate is measured (older time is
/// forgotten proportionally).
const RATE_WINDOW_S: f64 = 60.0;
/// Busy seconds measured before the measured rate replaces the assumed one.
const RATE_MIN_S: f64 = 1.0;
/// The rate assumed before one is measured, estimated CPU-seconds per second per
/// compute thread: a quarter of what the estimates promise, since the first burst
/// comes before any measurement, and a machine shared with other work runs several
/// times slower than the calibration did (a 1024² `fast` view, 1.5 CPU-s estimated,
/// took 5 s alone on the 2-core development machine at load average 6).
const ASSUMED_RATE_PER_THREAD: f64 = 0.25;

/// The estimated work admitted to the queue and not done yet, and the rate at which
/// the queue does estimated work (estimated CPU-seconds per second of wall time while
/// any job runs). The rate is measured, not assumed: it folds the estimates' error,
/// the machine's speed and whatever else runs on it (other processes, the jobs' own
/// parallelism) into one number, so the backlog's time is in real seconds.
struct Backlog {
    state: Mutex<BacklogState>,
    /// Compute threads (the measured rate is bounded by a multiple of them).
    threads: f64,
}

#[derive(Default)]
struct BacklogState {
    /// Admitted jobs by ticket: estimated CPU-seconds, and when each started running.
    jobs: HashMap<u64, (f64, Option<Instant>)>,
    next: u64,
    running: usize,
    /// Wall seconds with at least one job running, and the estimated CPU-seconds done
    /// meanwhile (both decayed together over [`RATE_WINDOW_S`]).
    busy_s: f64,
    done_cpu_s: f64,
    /// When `busy_s` was last brought up to date.
    last: Option<Instant>,
}

impl BacklogState {
    fn rate(&self, threads: f64) -> f64 {
        if self.busy_s < RATE_MIN_S {
            ASSUMED_RATE_PER_THREAD * threads
        } else {
            (self.done_cpu_s / self.busy_s).clamp(0.05 * threads, 4.0 * threads)
        }
    }

    /// Adds the wall time since the last event to the busy time, if any job ran.
    fn tick(&mut self, now: Instant) {
        if let Some(last) = self.last
            && self.running > 0
        {
            self.busy_s += now.duration_since(last).as_secs_f64();
            if self.busy_s > RATE_WINDOW_S {
                let keep = RATE_WINDOW_S / self.busy_s;
                self.busy_s *= keep;
                self.done_cpu_s *= keep;
            }
        }
        self.last = Some(now);
    }

    /// Estimated CPU-seconds still to do of the admitted jobs: a running job has done
    /// its share of the rate for as long as it has run (and has a tenth of its
    /// estimate left while it runs: it is not done until it ends).
    fn remaining(&self, now: Instant, rate: f64) -> f64 {
        let per_job = rate / self.running.max(1) as f64;
        self.jobs
            .values()
            .map(|&(cpu_s, started)| match started {
                Some(at) => (cpu_s - now.duration_since(at).as_secs_f64() * per_job).max(0.1 * cpu_s),
                None => cpu_s,
            })
            .sum()
    }
}

impl Backlog {
    fn new(threads: usize) -> Backlog {
        Backlog {
            state: Mutex::new(BacklogState::default()),
            threads: threads as f64,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, BacklogState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Seconds the admitted work still needs at the measured rate.
    fn seconds(&self) -> f64 {
        let s = self.lock();
        let rate = s.rate(self.threads);
        s.remaining(Instant::now(), rate) / rate
    }

    /// Admits a job of `cpu_s` estimated CPU-seconds: its ticket, or, when `within` is
    /// given and the work ahead of it plus its own would take longer than that (at the
    /// measured rate), the seconds until it would fit. A job that finds nothing ahead
    /// is always admitted (whether one job alone fits its budget is the 413 check's).
    fn admit(&self, cpu_s: f64, within: Option<Duration>) -> Result<u64, f64> {
        let mut s = self.lock();
        let now = Instant::now();
        let rate = s.rate(self.threads);
        let ahead = s.remaining(now, rate);
        if let Some(budget) = within {
            let fits = BACKLOG_SHARE_OF_BUDGET * budget.as_secs_f64();
            let done_in = (ahead + cpu_s) / rate;
            if !s.jobs.is_empty() && done_in > fits {
                return Err(done_in - fits);
            }
        }
        let ticket = s.next;
        s.next += 1;
        s.jobs.insert(ticket, (cpu_s.max(0.0), None));
        Ok(ticket)
    }

    fn start(&self, ticket: u64) {
        let mut s = self.lock();
        let now = Instant::now();
        s.tick(now);
        if let Some(job) = s.jobs.get_mut(&ticket) {
            job.1 = Some(now);
            s.running += 1;
        }
    }

    /// The job of `ticket` left the queue: before it ran (`ran` false), or after
    /// (`completed`: it did all its work, which is credited to the rate; a job stopped
    /// at its budget is credited nothing: how far it got is unknown, and work that
    /// does not finish in its budget is what the rate must warn of).
    fn finish(&self, ticket: u64, ran: bool, completed: bool) {
        let mut s = self.lock();
        s.tick(Instant::now());
        let Some((cpu_s, started)) = s.jobs.remove(&ticket) else {
            return;
        };
        if ran && started.is_some() {
            if completed {
                s.done_cpu_s += cpu_s;
            }
            s.running = s.running.saturating_sub(1);
        }
    }
}

/// Bounded CPU work: at most `capacity` jobs running or waiting for a rayon thread,
/// holding at most `memory_mib` MiB of estimated working memory between them, and no
/// more estimated work than requests' time budget lets them finish ([`Backlog`]).
pub struct ComputeQueue {
    slots: Arc<Semaphore>,
    capacity: usize,
    /// Working memory of the admitted jobs, in MiB permits (their [`Work::bytes`]).
    memory: Arc<Semaphore>,
    memory_mib: u32,
    /// Running mean of job times (seconds, as `f64` bits), for `Retry-After`.
    mean_job_s: Arc<AtomicU64>,
    /// Places for jobs on the rayon pool, one per thread. Without them every queued
    /// job starts at once (a rayon thread waiting inside one job's `join` picks up
    /// the next job) and they all crawl to the end of their budget together; with
    /// them the oldest jobs run at full speed and finish, FIFO.
    running: Arc<Semaphore>,
    /// The estimated work admitted and not done yet.
    backlog: Arc<Backlog>,
    /// A request's time budget: its job must fit the backlog in it.
    budget: Duration,
}

impl ComputeQueue {
    pub fn new(capacity: usize, memory_bytes: u64, budget: Duration) -> ComputeQueue {
        let memory_mib = (memory_bytes >> 20).clamp(1, Semaphore::MAX_PERMITS as u64 >> 1) as u32;
        let threads = rayon::current_num_threads().max(1);
        ComputeQueue {
            backlog: Arc::new(Backlog::new(threads)),
            budget,
            slots: Arc::new(Semaphore::new(capacity)),
            capacity,
            memory: Arc::new(Semaphore::new(memory_mib as usize)),
            memory_mib,
            mean_job_s: Arc::new(AtomicU64::new(NO_JOB_YET)),
            running: Arc::new(Semaphore::new(threads)),
        }
    }

    /// Seconds the admitted work still needs at the queue's measured rate.
    pub fn backlog_seconds(&self) -> f64 {
        self.backlog.seconds()
    }

    /// Jobs running or queued.
    pub fn depth(&self) -> usize {
        self.capacity - self.slots.available_permits()
    }

    /// How long a client should wait before it retries: the work queued ahead of it
    /// (jobs × their recent mean time) spread over the compute threads, in whole
    /// seconds within [1, 60].
    pub fn retry_after(&self) -> u32 {
        let mean = match self.mean_job_s.load(Ordering::Relaxed) {
            NO_JOB_YET => INITIAL_MEAN_JOB_S,
            m => f64::from_bits(m),
        };
        let threads = rayon::current_num_threads().max(1) as f64;
        let s = (self.depth().max(1) as f64 * mean / threads).ceil();
        s.clamp(RETRY_AFTER_S.0 as f64, RETRY_AFTER_S.1 as f64) as u32
    }

    /// Runs `job` on the rayon pool if a slot and the memory `work` needs are free,
    /// or sheds it. The job gets `cancel` to look at; once it has fired the result
    /// is discarded as [`ApiError::Cancelled`] (and a job whose token fired before it
    /// started is not run). A panicking job is a bug: it becomes `Internal`, the
    /// server keeps running.
    pub async fn run<T: Send + 'static>(
        &self,
        metrics: &Metrics,
        (kind, by): (&str, Asker),
        work: Work,
        cancel: Cancel,
        job: impl FnOnce(&Cancel) -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        // Requests' computations and refusals are counted here; compute-ahead counts
        // its own (`cloudscape_ahead_*`).
        let shed = || {
            if by == Asker::Request {
                metrics.shed.with_label_values(&[kind]).inc();
            }
            ApiError::Overloaded(self.retry_after())
        };
        let Ok(permit) = self.slots.clone().try_acquire_owned() else {
            return Err(shed());
        };
        let mib = (work.bytes.div_ceil(1 << 20)).clamp(1, self.memory_mib as u64) as u32;
        let Ok(memory) = self.memory.clone().try_acquire_many_owned(mib) else {
            return Err(shed());
        };
        // Requests must fit the backlog in their budget; background work (ahead, warm)
        // has no budget, but counts in the backlog of the requests behind it.
        let within = (by == Asker::Request).then_some(self.budget);
        let ticket = match self.backlog.admit(work.cpu_s, within) {
            Ok(ticket) => ticket,
            Err(wait_s) => {
                metrics.shed.with_label_values(&[kind]).inc();
                let retry = (wait_s.ceil() as u32).clamp(RETRY_AFTER_S.0, RETRY_AFTER_S.1);
                return Err(ApiError::Overloaded(retry.max(self.retry_after())));
            }
        };
        // Leaves the backlog however this call ends (answered, shed, dropped with its
        // request).
        let ticket = Ticket {
            backlog: Arc::clone(&self.backlog),
            id: ticket,
            ran: false,
            completed: false,
        };
        metrics.queue_depth.set(self.depth() as i64);
        // Wait (in order) for one of the `threads` running places, or until nobody
        // waits for this job any more.
        let running = loop {
            tokio::select! {
                p = self.running.clone().acquire_owned() => break p.ok(),
                _ = tokio::time::sleep(CANCEL_POLL) => {
                    if cancel.is_fired() {
                        metrics.cancelled.with_label_values(&[kind]).inc();
                        metrics.queue_depth.set(self.depth() as i64 - 1);
                        return Err(ApiError::Cancelled);
                    }
                }
            }
        };
        if by == Asker::Request {
            metrics.computations.with_label_values(&[kind]).inc();
        }
        let timer = metrics.observe_compute(kind);
        let (tx, rx) = oneshot::channel();
        let mean = Arc::clone(&self.mean_job_s);
        let job_cancel = cancel.clone();
        let mut ticket = ticket;
        rayon::spawn(move || {
            ticket.start();
            let started = Instant::now();
            let result = if job_cancel.is_fired() {
                Ok(Err(ApiError::Cancelled))
            } else {
                std::panic::catch_unwind(AssertUnwindSafe(|| job(&job_cancel)))
            };
            let took = started.elapsed().as_secs_f64();
            timer.observe(took);
            let _ = mean.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |m| {
                // The first measured job replaces the assumed mean outright.
                let m = if m == NO_JOB_YET { took } else { f64::from_bits(m) };
                Some((m + MEAN_JOB_WEIGHT * (took - m)).to_bits())
            });
            ticket.completed = !job_cancel.is_fired() && matches!(result, Ok(Ok(_)));
            drop(ticket);
            drop(running);
            drop(memory);
            drop(permit);
            let _ = tx.send(result);
        });
        let result = rx.await;
        metrics.queue_depth.set(self.depth() as i64);
        let result = match result {
            Ok(Ok(r)) => r,
            // The panic hook has logged it; the client gets no internals.
            Ok(Err(_panic)) => Err(ApiError::Panicked),
            Err(_) => Err(ApiError::Internal("a computation was lost".to_string())),
        };
        // A fired token means the loops may have skipped work: never keep the result.
        if cancel.is_fired() {
            metrics.cancelled.with_label_values(&[kind]).inc();
            return Err(ApiError::Cancelled);
        }
        result
    }
}

/// A job's place in the [`Backlog`], given back when dropped.
struct Ticket {
    backlog: Arc<Backlog>,
    id: u64,
    ran: bool,
    completed: bool,
}

impl Ticket {
    fn start(&mut self) {
        self.ran = true;
        self.backlog.start(self.id);
    }
}

impl Drop for Ticket {
    fn drop(&mut self) {
        self.backlog.finish(self.id, self.ran, self.completed);
    }
}

/// The requests waiting for one computation. Each waiting request holds an `Arc`;
/// when the last one lets go (its budget ran out, it was answered, or its client went
/// away and the handler was dropped) the computation's token fires.
struct Flight {
    cancel: Cancel,
}

impl Drop for Flight {
    fn drop(&mut self) {
        self.cancel.fire();
    }
}

/// The computations that requests are waiting for, by key (concurrent misses on one
/// key join one computation, so they share one [`Flight`]).
#[derive(Default)]
struct Flights(Mutex<HashMap<CacheKey, Weak<Flight>>>);

impl Flights {
    /// Joins the flight of `key`, or starts one.
    fn join(&self, key: &CacheKey) -> Arc<Flight> {
        let mut map = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(f) = map.get(key).and_then(Weak::upgrade) {
            return f;
        }
        if map.len() > 1024 {
            map.retain(|_, f| f.strong_count() > 0);
        }
        let f = Arc::new(Flight { cancel: Cancel::new() });
        map.insert(key.clone(), Arc::downgrade(&f));
        f
    }
}

/// Encoded response bytes under a byte budget, plus the queue that fills it.
pub struct ResponseCache {
    cache: Cache<CacheKey, Bytes>,
    /// Largest entry kept, bytes: a fraction of the budget, so that one entry never
    /// pushes out most of the others. Larger answers are served but not kept.
    max_entry: usize,
    queue: ComputeQueue,
    /// Computations that requests wait for, to stop the ones nobody waits for.
    flights: Flights,
    /// Time budget of one request.
    budget: Duration,
    /// The second-level cache shared by replicas, if configured.
    shared: Option<Arc<SharedCache>>,
    /// Keys computed in the background (ahead, warm) that no request has found yet.
    ahead: AheadKeys,
}

/// Keys computed in the background, ahead of any request, and by whom, until a request
/// finds each (bounded: the oldest half is forgotten when full).
#[derive(Default)]
struct AheadKeys(Mutex<HashMap<CacheKey, (u64, Asker)>>, AtomicU64);

/// Most keys [`AheadKeys`] remembers.
const MAX_AHEAD_KEYS: usize = 1 << 16;

impl AheadKeys {
    fn remember<'a>(&self, keys: impl Iterator<Item = &'a CacheKey>, by: Asker) {
        let mut map = self.0.lock().unwrap_or_else(|e| e.into_inner());
        for key in keys {
            if map.len() >= MAX_AHEAD_KEYS {
                let mut ages: Vec<u64> = map.values().map(|(age, _)| *age).collect();
                ages.sort_unstable();
                let median = ages[ages.len() / 2];
                map.retain(|_, (age, _)| *age > median);
            }
            map.insert(key.clone(), (self.1.fetch_add(1, Ordering::Relaxed), by));
        }
    }

    /// Who computed `key` in the background, once, when no request had found it yet.
    fn served(&self, key: &CacheKey) -> Option<Asker> {
        let mut map = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if map.is_empty() {
            return None;
        }
        map.remove(key).map(|(_, by)| by)
    }
}

/// The share of the cache budget one entry may take at most.
pub const MAX_ENTRY_FRACTION: u64 = 4;

/// What one entry costs the response cache besides its key's and its bytes' own
/// allocations: moka's entry (its value handle, access and write order nodes, hash
/// table slot, timestamps and weight) and the `Bytes` handle, rounded up.
const ENTRY_OVERHEAD: usize = 512;

/// The weight of an entry: the allocations of its key and bytes, as the allocator
/// sizes them, and the cache's own overhead per entry.
fn entry_weight(key: &CacheKey, bytes: &Bytes) -> usize {
    crate::allocator::allocation(key.0.len()) + crate::allocator::allocation(bytes.len()) + ENTRY_OVERHEAD
}

/// `bytes` in an allocation of exactly their length, as [`entry_weight`] counts them: a
/// `Bytes` made from a `Vec` keeps the vector's whole capacity (an encoder's buffer
/// grown by doubling holds up to twice its length), and a slice keeps the whole
/// buffer it was cut from.
fn exact(bytes: Bytes) -> Bytes {
    Bytes::copy_from_slice(&bytes)
}

/// What a computation yields: the bytes of its key, and the bytes of sibling keys the
/// same work produced (the other products of one shaded tile).
pub type WithSiblings = (Bytes, Vec<(CacheKey, Bytes)>);

/// The work of a computation, run once on the compute queue (the token fires when no
/// one waits for it any more).
pub trait Job: FnOnce(&Cancel) -> Result<WithSiblings, ApiError> + Send + 'static {}

impl<F: FnOnce(&Cancel) -> Result<WithSiblings, ApiError> + Send + 'static> Job for F {}

/// One computation the cache may run: the metric label of its kind, the key its
/// bytes go under, its estimated work (admitted before) and its job.
pub struct Computation<J> {
    pub kind: &'static str,
    pub key: CacheKey,
    pub work: Work,
    pub job: J,
}

impl ResponseCache {
    pub fn new(max_bytes: u64, queue: ComputeQueue, budget: Duration, shared: Option<SharedCache>) -> ResponseCache {
        let max_entry = (max_bytes / MAX_ENTRY_FRACTION).min(u32::MAX as u64) as usize;
        let cache = Cache::builder()
            // An entry over `max_entry` weighs more than the whole cache, so moka does
            // not admit it; `keep` below also drops it at once in case it was.
            .weigher(move |k: &CacheKey, v: &Bytes| {
                if v.len() > max_entry {
                    u32::MAX
                } else {
                    entry_weight(k, v).try_into().unwrap_or(u32::MAX)
                }
            })
            .max_capacity(max_bytes)
            .build();
        ResponseCache {
            cache,
            max_entry,
            queue,
            flights: Flights::default(),
            budget,
            shared: shared.map(Arc::new),
            ahead: AheadKeys::default(),
        }
    }

    pub fn weighted_size(&self) -> u64 {
        self.cache.weighted_size()
    }

    /// The `Retry-After` (seconds) of an answer shed for load right now.
    pub fn retry_after(&self) -> u32 {
        self.queue.retry_after()
    }

    /// The bytes of `key`, from the cache or computed by `job` (once for all concurrent
    /// callers), within the request's time budget. `work` is the job's estimate (its
    /// working memory is reserved while it runs). A job may also produce the bytes of
    /// other keys from the same work (the products of one shaded tile): those are
    /// cached too.
    ///
    /// When the budget runs out the request answers 503 `timeout`; when no other
    /// request waits for the same computation any more, the computation is stopped
    /// (its token fires) and gives its queue slot back.
    pub async fn get_or_compute_with_siblings(
        self: &Arc<Self>,
        metrics: &Arc<Metrics>,
        computation: Computation<impl Job>,
    ) -> Result<Bytes, ApiError> {
        let (kind, key) = (computation.kind, computation.key.clone());
        if let Some(bytes) = self.cache.get(&key).await {
            metrics.cache_hits.with_label_values(&[kind]).inc();
            match self.ahead.served(&key) {
                Some(Asker::Ahead) => metrics.ahead_served.inc(),
                Some(Asker::Warm) => metrics.warm_served.inc(),
                _ => {}
            }
            return Ok(bytes);
        }
        metrics.cache_misses.with_label_values(&[kind]).inc();
        // Held until this request is answered, times out, or is dropped with its client.
        let flight = self.flights.join(&key);
        let cancel = flight.cancel.clone();
        let this = Arc::clone(self);
        let m = Arc::clone(metrics);
        let task = tokio::spawn(async move {
            let init = this.fill(&m, computation, cancel, Asker::Request, None);
            this.get_with(&key, init).await
        });
        let result = match tokio::time::timeout(self.budget, task).await {
            Ok(Ok(result)) => result,
            Ok(Err(join)) => Err(ApiError::Internal(format!("compute task failed: {join}"))),
            Err(_) => {
                metrics.timeouts.with_label_values(&[kind]).inc();
                Err(ApiError::Timeout {
                    budget_ms: self.budget.as_millis() as u64,
                    retry_after: self.retry_after(),
                })
            }
        };
        drop(flight);
        match result {
            Err(ApiError::Cancelled) => Err(ApiError::Overloaded(self.retry_after())),
            other => other,
        }
    }

    /// The bytes of `key` from the shared cache, or computed by `job` through the
    /// queue; the siblings the job yields go into both caches (the key itself is
    /// inserted by the caller's `try_get_with`). Keys computed in the background are
    /// remembered, so the first request that finds each counts as served from ahead
    /// (or warm). `computed`, when given, is set when the job ran here (not when the
    /// bytes came from the shared cache).
    async fn fill(
        &self,
        m: &Arc<Metrics>,
        computation: Computation<impl Job>,
        cancel: Cancel,
        by: Asker,
        computed: Option<&AtomicBool>,
    ) -> Result<Bytes, ApiError> {
        let Computation { kind, key, work, job } = computation;
        if let Some(shared) = &self.shared {
            if let Lookup::Hit(bytes) = shared.get(m, kind, &key).await {
                return Ok(exact(bytes));
            }
            // Work nobody waits for yet (ahead, warm) is done by one replica: the others
            // come back for the bytes (the warm worker and compute-ahead retry a
            // refused key soon, and then find it in Redis). A request computes anyway.
            if by != Asker::Request && !shared.claim(m, &key, CLAIM_TTL).await {
                return Err(ApiError::Overloaded(1));
            }
        }
        // Copied into exact allocations on the compute thread, where the copy costs
        // least.
        let job = move |cancel: &Cancel| {
            job(cancel).map(|(bytes, siblings)| {
                let siblings: Vec<(CacheKey, Bytes)> = siblings.into_iter().map(|(k, b)| (k, exact(b))).collect();
                (exact(bytes), siblings)
            })
        };
        let (bytes, siblings) = match self.queue.run(m, (kind, by), work, cancel, job).await {
            Ok(done) => done,
            Err(e) => {
                if let Some(shared) = self.shared.as_ref().filter(|_| by != Asker::Request) {
                    shared.release(m, &key).await;
                }
                return Err(e);
            }
        };
        if let Some(c) = computed {
            c.store(true, Ordering::Relaxed);
        }
        for (k, b) in &siblings {
            if b.len() <= self.max_entry {
                self.cache.insert(k.clone(), b.clone()).await;
            }
        }
        if by != Asker::Request {
            self.ahead.remember(siblings.iter().map(|(k, _)| k).chain([&key]), by);
        }
        if let Some(shared) = &self.shared {
            let mut entries = siblings;
            entries.push((key, bytes.clone()));
            shared.put(m, entries);
        }
        Ok(bytes)
    }

    /// Computes `key` ahead of any request, for a background task `by` (no time
    /// budget; requests asking for it meanwhile join the computation). `Ok(true)` when
    /// this call computed the bytes, `Ok(false)` when they were in the cache already,
    /// another caller's computation put them there, or they came from the shared cache
    /// (another replica computed them); an error when the queue shed it, it failed, or
    /// another replica holds its claim (then it comes back later for the bytes).
    pub async fn compute_ahead(
        self: &Arc<Self>,
        metrics: &Arc<Metrics>,
        computation: Computation<impl Job>,
        by: Asker,
    ) -> Result<bool, ApiError> {
        let key = computation.key.clone();
        if self.cache.contains_key(&key) {
            return Ok(false);
        }
        let computed = AtomicBool::new(false);
        let init = self.fill(metrics, computation, Cancel::never(), by, Some(&computed));
        self.get_with(&key, init).await?;
        Ok(computed.load(Ordering::Relaxed))
    }

    /// The bytes of `key` from the cache, or from `init` (run once for all concurrent
    /// callers); bytes over `max_entry` are answered but not kept.
    async fn get_with(
        &self,
        key: &CacheKey,
        init: impl Future<Output = Result<Bytes, ApiError>>,
    ) -> Result<Bytes, ApiError> {
        let result = self
            .cache
            .try_get_with(key.clone(), init)
            .await
            .map_err(|e| (*e).clone());
        if let Ok(bytes) = &result
            && bytes.len() > self.max_entry
        {
            self.cache.invalidate(key).await;
        }
        // Evicted down to the budget now: moka otherwise batches its eviction, and a
        // burst of megabyte entries overshoots the budget until it does.
        self.cache.run_pending_tasks().await;
        result
    }

    /// The `coding` variant of `bytes`, the cached bytes of `key`: compressed once and
    /// kept in the cache beside them (concurrent requests join one compression);
    /// `None` if compressing failed.
    pub async fn encoded(&self, metrics: &Metrics, key: &CacheKey, coding: Coding, bytes: Bytes) -> Option<Bytes> {
        let key = key.clone().with("enc", coding.name());
        if let Some(b) = self.cache.get(&key).await {
            metrics.encodings.with_label_values(&[coding.name(), "hit"]).inc();
            return Some(b);
        }
        metrics.encodings.with_label_values(&[coding.name(), "miss"]).inc();
        let init = async move {
            tokio::task::spawn_blocking(move || {
                let start = std::time::Instant::now();
                let out = coding.compress(&bytes).map(exact);
                (out, start.elapsed())
            })
            .await
            .map_err(|e| e.to_string())
            .and_then(|(out, took)| {
                metrics.observe_stage("compression", took);
                out
            })
        };
        let b = self.cache.try_get_with(key.clone(), init).await.ok()?;
        if b.len() > self.max_entry {
            self.cache.invalidate(&key).await;
        }
        Some(b)
    }

    /// Runs `job` through the queue with no time budget and no caching (start-up work).
    pub async fn run_unbudgeted<T: Send + 'static>(
        &self,
        metrics: &Metrics,
        kind: &'static str,
        job: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
    ) -> Result<T, ApiError> {
        self.queue
            .run(
                metrics,
                (kind, Asker::Request),
                Work::default(),
                Cancel::never(),
                move |_| job(),
            )
            .await
    }
}

impl ResponseCache {
    /// Puts bytes computed outside a request (start-up work) in the cache.
    pub async fn insert(&self, key: CacheKey, bytes: Bytes) {
        if bytes.len() <= self.max_entry {
            self.cache.insert(key, bytes).await;
        }
    }

    /// Seconds the compute jobs admitted still need, at the queue's measured rate.
    pub fn backlog_seconds(&self) -> f64 {
        self.queue.backlog_seconds()
    }

    /// Compute jobs running or queued.
    pub fn queue_depth(&self) -> usize {
        self.queue.depth()
    }

    /// Places left in the compute queue.
    pub fn queue_free(&self) -> usize {
        self.queue.capacity - self.queue.depth()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_backlog_admits_what_fits_the_budget_behind_the_work_already_admitted() {
        // Eight threads, nothing measured yet: 2 estimated CPU-seconds a second
        // (ASSUMED_RATE_PER_THREAD). A 10 s budget leaves 8 s
        // (BACKLOG_SHARE_OF_BUDGET) for the work ahead and one's own.
        let backlog = Backlog::new(8);
        let budget = Some(Duration::from_secs(10));
        let a = backlog.admit(6.0, budget).expect("nothing ahead");
        let b = backlog.admit(6.0, budget).expect("12 CPU-s: 6 s");
        // 18 CPU-s would take 9 s: over by about a second.
        let wait = backlog.admit(6.0, budget).unwrap_err();
        assert!((wait - 1.0).abs() < 0.1, "{wait}");
        // A smaller job still fits; background work is admitted whatever the backlog.
        let c = backlog.admit(3.0, budget).expect("15 CPU-s: 7.5 s");
        let d = backlog.admit(40.0, None).expect("no budget");
        // One job alone is always admitted (the 413 check judges a job on its own).
        let empty = Backlog::new(2);
        empty.admit(100.0, budget).expect("nothing ahead");
        // Work leaves the backlog when its job ends, run or not.
        backlog.start(a);
        backlog.finish(a, true, true);
        for t in [b, c, d] {
            backlog.finish(t, false, false);
        }
        assert_eq!(backlog.seconds(), 0.0);
        backlog.admit(6.0, budget).expect("the backlog is empty again");
    }
}
