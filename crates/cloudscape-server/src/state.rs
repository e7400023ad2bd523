//! What every handler shares: the [`AppState`], and the server's [`Lifecycle`].

use std::sync::Arc;
use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use std::time::Duration;

use cloudscape_core::cost::Work;
use cloudscape_core::world::Config;

use crate::ahead::HotSet;
use crate::cache::{ComputeQueue, ResponseCache};
use crate::config::ServerConfig;
use crate::error::ApiError;
use crate::kept::KeptStates;
use crate::key::Worlds;
use crate::metrics::Metrics;
use crate::reply::ReplyBudget;
use crate::shared::SharedCache;
use crate::warm::{self, RecipeParts, Warm};

/// Where the server is in its life, as `/readyz` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Lifecycle {
    /// Start-up work is running; requests are served but the server is not ready.
    Starting = 0,
    Ready = 1,
    /// Start-up work failed: the server stays up (for `/metrics`, logs) but never ready.
    Failed = 2,
    /// Shutdown began: still serving while load balancers notice, then stop accepting.
    Draining = 3,
}

/// The server's phase, shared by the lifecycle and `/readyz`.
pub struct Readiness(AtomicU8);

impl Readiness {
    pub fn get(&self) -> Lifecycle {
        match self.0.load(Ordering::SeqCst) {
            0 => Lifecycle::Starting,
            1 => Lifecycle::Ready,
            2 => Lifecycle::Failed,
            _ => Lifecycle::Draining,
        }
    }

    /// Moves to `to`, except that draining is final.
    pub(crate) fn set(&self, to: Lifecycle) {
        let _ = self.0.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |p| {
            (p != Lifecycle::Draining as u8).then_some(to as u8)
        });
    }
}

/// Everything the handlers share. Built once per server.
pub struct AppState {
    /// The configured worlds and their fingerprints.
    pub worlds: Worlds,
    /// `[server]` settings (cache-control values, frames per step, …).
    pub settings: ServerConfig,
    /// Encoded responses and the bounded compute queue that fills them.
    pub cache: Arc<ResponseCache>,
    /// The bytes that replies being sent may hold (`server.reply_bytes`).
    pub replies: ReplyBudget,
    pub metrics: Arc<Metrics>,
    pub readiness: Readiness,
    /// The tiles being watched, whose next keyframes are computed ahead.
    pub ahead: Arc<HotSet>,
    /// What tiles keep between keyframes (`None` when `server.kept_share` is 0).
    pub kept: Option<Arc<KeptStates>>,
    /// The play areas kept warm (`[[worlds.NAME.warm]]`) and how far the keeping is.
    pub warm: Arc<Warm>,
    /// Source of request ids: a per-process prefix and a counter.
    request_ids: (u32, AtomicU64),
}

impl AppState {
    pub fn new(config: Config, settings: ServerConfig) -> Result<AppState, String> {
        let variants = warm::check(&config, &settings, warm::unix_now()).map_err(|e| e.to_string())?;
        let queue = match settings.compute_queue {
            0 => 4 * std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n as usize,
        };
        let budget = Duration::from_millis(settings.request_timeout_ms);
        let cache = ResponseCache::new(
            settings.response_bytes(),
            ComputeQueue::new(queue, settings.compute_bytes(), budget),
            budget,
            SharedCache::new(&settings)?,
        );
        let metrics = Arc::new(Metrics::new());
        let kept = KeptStates::new(settings.kept_bytes(), &metrics).map(Arc::new);
        let replies = ReplyBudget::new(settings.reply_bytes, metrics.reply_bytes.clone());
        let prefix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos() ^ (d.as_secs() as u32));
        let ahead = Arc::new(HotSet::new(
            settings.ahead_tiles as usize,
            settings.ahead_threads as usize,
        ));
        let worlds = Worlds::new(config, settings.frames_per_step);
        let warm = Warm::new(
            variants,
            settings.warm_threads as usize,
            RecipeParts {
                worlds: &worlds,
                sun: &worlds.config().sun,
                limits: &worlds.config().limits,
                kept: kept.clone(),
                metrics: &metrics,
            },
        );
        Ok(AppState {
            worlds,
            settings,
            cache: Arc::new(cache),
            replies,
            metrics,
            readiness: Readiness(AtomicU8::new(Lifecycle::Starting as u8)),
            ahead,
            kept,
            warm: Arc::new(warm),
            request_ids: (prefix, AtomicU64::new(0)),
        })
    }

    pub fn next_request_id(&self) -> String {
        format!(
            "{:08x}-{:x}",
            self.request_ids.0,
            self.request_ids.1.fetch_add(1, Ordering::Relaxed)
        )
    }

    /// Admission control: refuses (413, naming the limit) a request whose estimated
    /// work cannot finish inside the time budget on this server's compute threads, or
    /// whose working memory is over `limits.max_request_bytes`. Checked before the
    /// cache, so a request over the limits is refused whether or not it was cached.
    pub fn admit(&self, kind: &str, work: Work) -> Result<Work, ApiError> {
        let threads = rayon::current_num_threads().max(1);
        let budget_s = self.settings.request_timeout_ms as f64 / 1000.0;
        let max_cpu = budget_s * threads as f64;
        let max_bytes = self.worlds.config().limits.max_request_bytes;
        let refused = if work.cpu_s > max_cpu {
            Some(format!(
                "this request needs about {:.1} CPU-seconds; the limit is {max_cpu:.1} (the {budget_s} s time \
                 budget, server.request_timeout_ms, on {threads} compute threads): ask for fewer pixels, a \
                 lower quality or a smaller region",
                work.cpu_s
            ))
        } else if work.bytes > max_bytes {
            Some(format!(
                "this request needs about {} MiB of working memory; the limit is {} MiB \
                 (limits.max_request_bytes): ask for fewer pixels, a lower quality or a smaller region",
                work.bytes >> 20,
                max_bytes >> 20
            ))
        } else {
            None
        };
        match refused {
            Some(message) => {
                self.metrics.refused.with_label_values(&[kind]).inc();
                Err(ApiError::TooMuchWork(message))
            }
            None => Ok(work),
        }
    }
}
