//! cloudscape-server: the HTTP service, the only crate that knows about HTTP.
//!
//! Shape (after martin and mini-redis): one [`AppState`] shared by every handler,
//! one error type converted to HTTP in one place ([`error`]), one cache in front of
//! one bounded compute queue ([`cache`]), and explicit lifecycle types: a [`Server`]
//! that is bound, then run until its [`ShutdownHandle`] fires, and a [`Readiness`]
//! that `/readyz` reports.
//!
//! Routes (see `openapi.json`): discovery under `/v1/worlds`, tiles under
//! `/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}`, region queries (`/sample`,
//! `/region`, `/series`), `/v1/worlds/{world}/render.png`, the splat sheets
//! `/v1/splats.{png,json}`, `/v1/sky.json`, and the operator routes `/healthz`, `/readyz`,
//! `/metrics`, `/openapi.json`.
//!
//! Caching: every computed response is keyed by a canonical [`key::CacheKey`] (world
//! fingerprint, layer, tile or region, canonical frame, product, algorithm version);
//! its strong ETag is a hash of that key, known before any work, so `If-None-Match`
//! answers 304 without computing. Bytes are deterministic, so a key's ETag never
//! names two different bodies.

mod cache;
pub mod config;
mod conn;
mod discovery;
mod error;
mod key;
mod metrics;
mod openapi;
mod ops;
pub mod params;
mod queries;
mod render;
mod reply;
mod shared;
mod stats;
mod tiles;
mod web;

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Bytes;
use axum::extract::{MatchedPath, Request, State};
use axum::http::{HeaderMap, HeaderName, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tower_http::compression::CompressionLayer;
use tracing::Instrument;

use cloudscape_core::world::Config;

pub use config::ServerConfig;
pub use error::ApiError;
pub use stats::{CLOUD_THRESHOLD, RegionStats, region_stats};

use self::cache::{ComputeQueue, ResponseCache};
use self::key::{SnappedTime, Worlds};
use self::metrics::Metrics;
use self::reply::ReplyBudget;
use self::shared::SharedCache;
use cloudscape_core::cost::Work;

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
    fn set(&self, to: Lifecycle) {
        let _ = self.0.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |p| {
            (p != Lifecycle::Draining as u8).then_some(to as u8)
        });
    }
}

/// Everything the handlers share. Built once per server.
pub struct AppState {
    /// The configured worlds and their fingerprints.
    worlds: Worlds,
    /// `[server]` settings (cache-control values, frames per step, …).
    settings: ServerConfig,
    /// Encoded responses and the bounded compute queue that fills them.
    cache: Arc<ResponseCache>,
    /// The bytes that replies being sent may hold (`server.reply_bytes`).
    replies: ReplyBudget,
    metrics: Arc<Metrics>,
    readiness: Readiness,
    /// Source of request ids: a per-process prefix and a counter.
    request_ids: (u32, AtomicU64),
}

impl AppState {
    fn new(config: Config, settings: ServerConfig) -> Result<AppState, String> {
        let queue = match settings.compute_queue {
            0 => 4 * std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n as usize,
        };
        let cache = ResponseCache::new(
            settings.cache_bytes,
            ComputeQueue::new(queue, settings.compute_memory_bytes),
            Duration::from_millis(settings.request_timeout_ms),
            SharedCache::new(&settings)?,
        );
        let metrics = Arc::new(Metrics::new());
        let replies = ReplyBudget::new(settings.reply_bytes, metrics.reply_bytes.clone());
        let prefix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos() ^ (d.as_secs() as u32));
        Ok(AppState {
            worlds: Worlds::new(config, settings.frames_per_step),
            settings,
            cache: Arc::new(cache),
            replies,
            metrics,
            readiness: Readiness(AtomicU8::new(Lifecycle::Starting as u8)),
            request_ids: (prefix, AtomicU64::new(0)),
        })
    }

    fn next_request_id(&self) -> String {
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
    fn admit(&self, kind: &str, work: Work) -> Result<Work, ApiError> {
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

    /// The `Cache-Control` for a response computed for `frame` when `t` was asked.
    fn cache_control(&self, frame: SnappedTime, requested: f64) -> &str {
        if frame.is_exact(requested) {
            &self.settings.cache_control
        } else {
            &self.settings.cache_control_other
        }
    }
}

/// Triggers a graceful shutdown: `/readyz` turns 503, requests are still served for
/// `drain_ms`, then the listener closes and in-flight requests finish.
#[derive(Clone)]
pub struct ShutdownHandle(Arc<watch::Sender<bool>>);

impl ShutdownHandle {
    pub fn trigger(&self) {
        self.0.send_replace(true);
    }
}

/// A bound, not yet running server.
pub struct Server {
    listener: TcpListener,
    state: Arc<AppState>,
    stop: Arc<watch::Sender<bool>>,
}

impl Server {
    /// Binds `server.listen` (and sets up, without connecting, the shared cache).
    pub async fn bind(config: Config, server: ServerConfig) -> io::Result<Server> {
        let state = AppState::new(config, server).map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
        let listener = TcpListener::bind(state.settings.listen.as_str()).await?;
        Ok(Server {
            listener,
            state: Arc::new(state),
            stop: Arc::new(watch::channel(false).0),
        })
    }

    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    pub fn shutdown_handle(&self) -> ShutdownHandle {
        ShutdownHandle(Arc::clone(&self.stop))
    }

    /// Serves until the shutdown handle fires, then drains: `/readyz` says 503 for
    /// `drain_ms` while requests are still served, then the listener closes and the
    /// connections are shut down (see [`conn`]).
    pub async fn run(self) -> io::Result<()> {
        let state = self.state;
        tokio::spawn(ops::start_up(Arc::clone(&state)));
        let app = router(Arc::clone(&state));
        let mut stop = self.stop.subscribe();
        let drain = {
            let state = Arc::clone(&state);
            async move {
                let _ = stop.wait_for(|&s| s).await;
                state.readiness.set(Lifecycle::Draining);
                state.metrics.ready.set(0);
                tracing::info!(drain_ms = state.settings.drain_ms, "shutdown: draining");
                tokio::time::sleep(Duration::from_millis(state.settings.drain_ms)).await;
                tracing::info!("shutdown: no longer accepting");
            }
        };
        let limits = conn::ConnLimits::new(&state.settings);
        conn::serve(self.listener, app, limits, Arc::clone(&state.metrics), drain).await;
        tracing::info!("shutdown: done");
        Ok(())
    }
}

/// The router with every route and the layers every route shares.
fn router(state: Arc<AppState>) -> Router {
    Router::new()
        .route("/v1/worlds", get(discovery::list))
        .route("/v1/worlds/{world}", get(discovery::world))
        .route("/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}", get(tiles::tile))
        .route("/v1/worlds/{world}/sample", get(queries::sample))
        .route("/v1/worlds/{world}/region", get(queries::region))
        .route("/v1/worlds/{world}/series", get(queries::series))
        .route("/v1/worlds/{world}/render.png", get(render::render_png))
        .route("/v1/splats.png", get(render::splats_png))
        .route("/v1/splats.json", get(render::splats_json))
        .route("/v1/sky.json", get(render::sky_json))
        .route("/healthz", get(ops::healthz))
        .route("/readyz", get(ops::readyz))
        .route("/metrics", get(ops::metrics))
        .route("/openapi.json", get(ops::openapi))
        .merge(web::routes())
        .fallback(|req: Request| async move { ApiError::NotFound(req.uri().path().chars().take(200).collect()) })
        .method_not_allowed_fallback(|| async { ApiError::MethodNotAllowed })
        // No brotli: its encoder holds ~27 MiB a stream at quality 4 (measured: 12
        // clients that stalled a 16 MB billboards.json added 325 MiB of RSS, against
        // 4 MiB for gzip and 18 MiB for zstd), memory outside the reply budget.
        .layer(CompressionLayer::new().no_br())
        .layer(middleware::from_fn(tag_coding))
        .layer(middleware::from_fn_with_state(Arc::clone(&state), observe))
        .with_state(state)
}

const REQUEST_ID: HeaderName = HeaderName::from_static("x-request-id");

/// Counts requests in flight, even when the client goes away mid-request.
struct InFlight(prometheus::IntGauge);

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.dec();
    }
}

/// Request id, tracing span, metrics by route template, and a log line per request.
async fn observe(State(state): State<Arc<AppState>>, req: Request, next: Next) -> Response {
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or("unmatched", |p| p.as_str())
        .to_string();
    let id = req
        .headers()
        .get(&REQUEST_ID)
        .and_then(|v| v.to_str().ok())
        .filter(|v| !v.is_empty() && v.len() <= 64 && v.bytes().all(|b| b.is_ascii_graphic()))
        .map_or_else(|| state.next_request_id(), str::to_string);
    // Labels and log fields from fixed sets: a client-made method name is `other`.
    let method = metrics::method_label(req.method());
    let span = tracing::info_span!("request", id = %id, method, route = %route);
    let m = &state.metrics;
    m.in_flight.inc();
    let _in_flight = InFlight(m.in_flight.clone());
    let started = Instant::now();
    let mut response = next.run(req).instrument(span.clone()).await;
    let elapsed = started.elapsed();
    let status = response.status();
    m.requests
        .with_label_values(&[route.as_str(), method, status.as_str()])
        .inc();
    m.latency
        .with_label_values(&[route.as_str()])
        .observe(elapsed.as_secs_f64());
    span.in_scope(|| tracing::info!(status = status.as_u16(), micros = elapsed.as_micros() as u64, "served"));
    if let Ok(v) = HeaderValue::from_str(&id) {
        response.headers_mut().insert(REQUEST_ID, v);
    }
    response
}

/// A compressed representation is a different representation: its strong ETag gets
/// the coding appended (`"…-gzip"`); [`key::if_none_match`] accepts either form.
async fn tag_coding(req: Request, next: Next) -> Response {
    let mut response = next.run(req).await;
    let coding = response
        .headers()
        .get(header::CONTENT_ENCODING)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string);
    if let Some(coding) = coding {
        let tagged = response
            .headers()
            .get(header::ETAG)
            .and_then(|v| v.to_str().ok())
            .map(|etag| format!("\"{}-{coding}\"", etag.trim_matches('"')));
        if let Some(v) = tagged.and_then(|t| HeaderValue::from_str(&t).ok()) {
            response.headers_mut().insert(header::ETAG, v);
        }
    }
    response
}

/// Headers shared by every computed response.
struct Representation<'a> {
    etag: String,
    cache_control: &'a str,
    /// The canonical frame the bytes were computed for, if time-dependent.
    frame: Option<SnappedTime>,
}

impl Representation<'_> {
    fn headers(&self) -> HeaderMap {
        let mut h = HeaderMap::new();
        if let Ok(v) = HeaderValue::from_str(&self.etag) {
            h.insert(header::ETAG, v);
        }
        if let Ok(v) = HeaderValue::from_str(self.cache_control) {
            h.insert(header::CACHE_CONTROL, v);
        }
        if let Some(f) = self.frame {
            if let Ok(v) = HeaderValue::from_str(&f.t.to_string()) {
                h.insert(HeaderName::from_static("x-cloudscape-t"), v);
            }
            h.insert(
                HeaderName::from_static("x-cloudscape-frame"),
                HeaderValue::from(f.index),
            );
        }
        h
    }

    /// 304 when `If-None-Match` names this representation: no computation needed.
    fn not_modified(&self, request: &HeaderMap) -> Option<Response> {
        let inm = request.get(header::IF_NONE_MATCH)?.to_str().ok()?;
        key::if_none_match(inm, &self.etag).then(|| (StatusCode::NOT_MODIFIED, self.headers()).into_response())
    }

    /// The 200 answer with `body`, which holds its share of the reply budget
    /// ([`reply`]) until it is sent; 503 when the budget is spent. A body over
    /// `limits.max_response_bytes` is refused with 413.
    fn ok(&self, state: &AppState, content_type: &'static str, body: Bytes) -> Result<Response, ApiError> {
        let max = state.worlds.config().limits.max_response_bytes;
        if body.len() as u64 > max {
            return Err(ApiError::ResponseTooLarge(format!(
                "the answer is {} MiB; the limit is {} MiB (limits.max_response_bytes)",
                body.len() >> 20,
                max >> 20
            )));
        }
        let body = state.replies.body(body, state.cache.retry_after())?;
        Ok(self.respond(content_type, body))
    }

    /// The 200 answer for a body known to be small (discovery, a clear-sky sample):
    /// no limit or budget to check.
    fn ok_small(&self, content_type: &'static str, body: Bytes) -> Response {
        self.respond(content_type, body.into())
    }

    fn respond(&self, content_type: &'static str, body: axum::body::Body) -> Response {
        let mut h = self.headers();
        h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
        (StatusCode::OK, h, body).into_response()
    }
}
