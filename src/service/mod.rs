//! The HTTP service: the only module that knows about HTTP.
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
mod discovery;
mod error;
mod key;
mod metrics;
mod openapi;
mod ops;
pub mod params;
mod queries;
mod render;
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
use tokio::sync::{Notify, watch};
use tower_http::compression::CompressionLayer;
use tracing::Instrument;

use crate::world::{Config, ServerConfig};

pub use error::ApiError;
pub use stats::{CLOUD_THRESHOLD, RegionStats, region_stats};

use self::cache::ResponseCache;
use self::key::{Frame, Worlds};
use self::metrics::Metrics;
use self::shared::SharedCache;

/// Where the server is in its life, as `/readyz` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Phase {
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
    pub fn get(&self) -> Phase {
        match self.0.load(Ordering::SeqCst) {
            0 => Phase::Starting,
            1 => Phase::Ready,
            2 => Phase::Failed,
            _ => Phase::Draining,
        }
    }

    /// Moves to `to`, except that draining is final.
    fn set(&self, to: Phase) {
        let _ = self.0.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |p| {
            (p != Phase::Draining as u8).then_some(to as u8)
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
    metrics: Arc<Metrics>,
    readiness: Readiness,
    /// Source of request ids: a per-process prefix and a counter.
    request_ids: (u32, AtomicU64),
}

impl AppState {
    fn new(config: Config) -> Result<AppState, String> {
        let settings = config.server.clone();
        let queue = match settings.compute_queue {
            0 => 4 * std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n as usize,
        };
        let cache = ResponseCache::new(
            settings.cache_bytes,
            queue,
            Duration::from_millis(settings.request_timeout_ms),
            SharedCache::new(&settings)?,
        );
        let prefix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos() ^ (d.as_secs() as u32));
        Ok(AppState {
            worlds: Worlds::new(config),
            settings,
            cache: Arc::new(cache),
            metrics: Arc::new(Metrics::new()),
            readiness: Readiness(AtomicU8::new(Phase::Starting as u8)),
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

    /// The `Cache-Control` for a response computed for `frame` when `t` was asked.
    fn cache_control(&self, frame: Frame, requested: f64) -> &str {
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
    /// Binds `config.server.listen` (and sets up, without connecting, the shared cache).
    pub async fn bind(config: Config) -> io::Result<Server> {
        let state = AppState::new(config).map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e))?;
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

    /// Serves until the shutdown handle fires, then drains and returns once in-flight
    /// requests are done (or `shutdown_timeout_ms` passed).
    pub async fn run(self) -> io::Result<()> {
        let state = self.state;
        tokio::spawn(ops::start_up(Arc::clone(&state)));
        let app = router(Arc::clone(&state));
        let stopped_accepting = Arc::new(Notify::new());
        let mut stop = self.stop.subscribe();
        let drain = {
            let state = Arc::clone(&state);
            let stopped_accepting = Arc::clone(&stopped_accepting);
            async move {
                let _ = stop.wait_for(|&s| s).await;
                state.readiness.set(Phase::Draining);
                state.metrics.ready.set(0);
                tracing::info!(drain_ms = state.settings.drain_ms, "shutdown: draining");
                tokio::time::sleep(Duration::from_millis(state.settings.drain_ms)).await;
                tracing::info!("shutdown: no longer accepting; finishing in-flight requests");
                stopped_accepting.notify_one();
            }
        };
        let serve = axum::serve(self.listener, app)
            .with_graceful_shutdown(drain)
            .into_future();
        let deadline = Duration::from_millis(state.settings.shutdown_timeout_ms);
        tokio::select! {
            result = serve => {
                tracing::info!("shutdown: done");
                result
            }
            _ = async { stopped_accepting.notified().await; tokio::time::sleep(deadline).await } => {
                tracing::warn!("shutdown: in-flight requests still running after {deadline:?}; stopping anyway");
                Ok(())
            }
        }
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
        .layer(CompressionLayer::new())
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
    let method = req.method().clone();
    let span = tracing::info_span!("request", id = %id, %method, route = %route);
    let m = &state.metrics;
    m.in_flight.inc();
    let _in_flight = InFlight(m.in_flight.clone());
    let started = Instant::now();
    let mut response = next.run(req).instrument(span.clone()).await;
    let elapsed = started.elapsed();
    let status = response.status();
    m.requests
        .with_label_values(&[route.as_str(), method.as_str(), status.as_str()])
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
    frame: Option<Frame>,
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

    fn ok(&self, content_type: &'static str, body: Bytes) -> Response {
        let mut h = self.headers();
        h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
        (StatusCode::OK, h, body).into_response()
    }
}
