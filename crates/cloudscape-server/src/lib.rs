//! cloudscape-server: the HTTP service, the only crate that knows about HTTP.
//!
//! Shape (after martin and mini-redis): one [`AppState`] shared by every handler,
//! one error type converted to HTTP in one place ([`error`]), one cache in front of
//! one bounded compute queue ([`cache`]), and explicit lifecycle types: a [`Server`]
//! that is bound, then run until its [`ShutdownHandle`] fires, and a [`Readiness`]
//! that `/readyz` reports.
//!
//! Routes (see `openapi.json`): discovery under `/v1/worlds` (and TileJSON 3.0.0 at
//! `/v1/worlds/{world}/tilejson.json`), tiles under
//! `/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}` (and by TileJSON zoom under
//! `/v1/worlds/{world}/zoom/{zoom}/{x}/{y}/{product}`), region queries (`/sample`,
//! `/region`, `/series`), OGC API – EDR under `/v1/edr` (position, radius, area and
//! cube queries answered as CoverageJSON, lightning strikes by the items query as
//! GeoJSON), `/v1/worlds/{world}/render.png`, the splat sheets
//! `/v1/splats.{png,json}`, `/v1/sky.json`, and the operator routes `/healthz`, `/readyz`,
//! `/metrics`, `/openapi.json`.
//!
//! Caching: every computed response takes one path ([`respond::Cached`]) and is keyed
//! by a canonical [`key::CacheKey`] (world fingerprint, layer, tile or region,
//! canonical frame, product, algorithm version); its strong ETag is a hash of that
//! key, known before any work, so `If-None-Match` answers 304 without computing. Bytes are deterministic, so a key's ETag never
//! names two different bodies.

// Slicing a `str` by byte positions panics inside a multibyte character, and every
// string here may come from a client: parsers split at ASCII separators
// (`split_once`, `strip_prefix`) or use `str::get`.
#![deny(clippy::string_slice)]

mod ahead;
pub mod allocator;
mod annotations;
mod cache;
pub mod config;
mod conn;
mod cors;
mod discovery;
mod edr;
mod encode;
mod error;
mod extract;
mod kept;
mod key;
mod lightning;
mod machine;
mod metrics;
mod openapi;
mod ops;
mod panics;
pub mod params;
mod public_url;
mod queries;
mod recipe;
mod render;
mod reply;
mod respond;
mod shared;
mod state;
mod tilejson;
mod tiles;
mod warm;
mod web;

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::{MatchedPath, Request, State};
use axum::http::{HeaderName, HeaderValue, header};
use axum::middleware::{self, Next};
use axum::response::Response;
use axum::routing::get;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tower_http::compression::CompressionLayer;
use tracing::Instrument;

use cloudscape_core::density::{self, Region};
use cloudscape_core::render::Quality;
use cloudscape_core::world::{Config, ConfigError};

pub use config::ServerConfig;
pub use encode::Coding;
pub use error::ApiError;
pub use panics::log_in_one_line as log_panics_in_one_line;
pub use state::{Lifecycle, Readiness};

use self::render::{splats_bytes, splats_key};
use self::state::AppState;

/// Checks what a server would refuse at start beyond what `Config::parse` and
/// `ServerConfig::parse` check: byte budgets over what this machine has (each of them
/// alone could be spent), world clocks that read a time outside [0, 1e12] now, and
/// play areas kept warm (`[[worlds.NAME.warm]]`) that name unknown products or
/// qualities, reach tiles that cannot be served, or need more than
/// `server.max_warm_tiles` tile variants together.
pub fn check_config(config: &Config, settings: &ServerConfig) -> Result<(), ConfigError> {
    if let Some((memory, source)) = machine::memory() {
        for (key, bytes) in [
            ("server.cache_bytes", settings.cache_bytes),
            ("server.compute_memory_bytes", settings.compute_memory_bytes),
            ("server.reply_bytes", settings.reply_bytes),
            ("limits.max_request_bytes", config.limits.max_request_bytes),
            ("limits.max_response_bytes", config.limits.max_response_bytes),
        ] {
            if bytes > memory {
                return Err(ConfigError::invalid(
                    key,
                    format!(
                        "{bytes} bytes ({:.1} GiB) is more than {source}, {memory} bytes ({:.1} GiB)",
                        bytes as f64 / (1u64 << 30) as f64,
                        memory as f64 / (1u64 << 30) as f64
                    ),
                ));
            }
        }
    }
    warm::check(config, settings, warm::unix_now()).map(|_| ())
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
        tokio::spawn(start_up(Arc::clone(&state)));
        let ahead = tokio::spawn(ahead::run(
            Arc::clone(&state.ahead),
            Arc::clone(&state.cache),
            Arc::clone(&state.metrics),
        ));
        let warm = tokio::spawn(warm::run(
            Arc::clone(&state.warm),
            Arc::clone(&state.cache),
            Arc::clone(&state.metrics),
            {
                let state = Arc::clone(&state);
                move || match state.readiness.get() {
                    Lifecycle::Starting => warm::Phase::Starting,
                    Lifecycle::Draining => warm::Phase::Draining,
                    Lifecycle::Ready | Lifecycle::Failed => warm::Phase::Serving,
                }
            },
        ));
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
        ahead.abort();
        warm.abort();
        tracing::info!("shutdown: done");
        Ok(())
    }
}

/// Start-up work: one small computation per layer of every configured world, through
/// the simulation, so that a replica only says it is ready once it can answer (and
/// its thread pools are warm), then the splat sheets of every quality into the cache,
/// and the current and next keyframes of the play areas kept warm (`warm`, computed
/// meanwhile): a replica that says it is ready can take its share of the players at
/// once, prefetches included.
/// Ready when it succeeds; never ready if it fails.
async fn start_up(state: Arc<AppState>) {
    let began = Instant::now();
    let worlds: Vec<_> = state.worlds.config().worlds.values().cloned().collect();
    let result = state
        .cache
        .run_unbudgeted(&state.metrics, "startup", move || {
            for w in &worlds {
                for i in 0..w.layers.len() {
                    let r = Region {
                        x0: 0,
                        y0: 0,
                        cols: 1,
                        rows: 1,
                    };
                    density::density(w, i, 0, r, 0.0)
                        .map_err(|e| ApiError::Internal(format!("world {} layer {i}: {e}", w.name)))?;
                }
            }
            let mut sheets = Vec::new();
            for q in Quality::ALL {
                for json in [false, true] {
                    sheets.push((splats_key(q, json), splats_bytes(q, json)));
                }
            }
            Ok(sheets)
        })
        .await;
    let result = match result {
        Ok(sheets) => {
            for (key, bytes) in sheets {
                state.cache.insert(key, bytes).await;
            }
            Ok(())
        }
        Err(e) => Err(e),
    };
    if result.is_ok() && state.warm.start_pending() > 0 {
        tracing::info!(
            variants = state.warm.start_pending(),
            "start-up: waiting for the current and next keyframes of the play areas kept warm"
        );
        state.warm.started().await;
    }
    match result {
        Ok(()) => {
            state.readiness.set(Lifecycle::Ready);
            if state.readiness.get() == Lifecycle::Ready {
                state.metrics.ready.set(1);
            }
            tracing::info!(seconds = began.elapsed().as_secs_f64(), "start-up done: ready");
        }
        Err(e) => {
            state.readiness.set(Lifecycle::Failed);
            tracing::error!(error = %e, "start-up failed: the server will not become ready");
        }
    }
}

/// The router with every route and the layers every route shares.
fn router(state: Arc<AppState>) -> Router {
    let routes = Router::new()
        .route("/v1/worlds", get(discovery::list))
        .route("/v1/worlds/{world}", get(discovery::world))
        .route("/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}", get(tiles::tile))
        .route("/v1/worlds/{world}/tilejson.json", get(tilejson::tilejson))
        .route(
            "/v1/worlds/{world}/zoom/{zoom}/{x}/{y}/{product}",
            get(tilejson::zoom_tile),
        )
        .route("/v1/worlds/{world}/sample", get(queries::sample))
        .route("/v1/worlds/{world}/region", get(queries::region))
        .route("/v1/worlds/{world}/series", get(queries::series))
        .route("/v1/worlds/{world}/lightning", get(lightning::lightning))
        .route("/v1/worlds/{world}/render.png", get(render::render_png))
        .route("/v1/edr", get(edr::landing))
        .route("/v1/edr/", get(edr::landing_slash))
        .route("/v1/edr/api", get(openapi::openapi_3_0))
        .route("/v1/edr/conformance", get(edr::conformance))
        .route("/v1/edr/collections", get(edr::collections))
        .route("/v1/edr/collections/{world}", get(edr::collection))
        .route("/v1/edr/collections/{world}/position", get(edr::position))
        .route("/v1/edr/collections/{world}/radius", get(edr::radius))
        .route("/v1/edr/collections/{world}/area", get(edr::area))
        .route("/v1/edr/collections/{world}/cube", get(edr::cube))
        .route("/v1/edr/collections/{world}/items", get(edr::items))
        .route("/v1/splats.png", get(render::splats_png))
        .route("/v1/splats.json", get(render::splats_json))
        .route("/v1/sky.json", get(render::sky_json))
        .route("/healthz", get(ops::healthz))
        .route("/readyz", get(ops::readyz))
        .route("/metrics", get(ops::metrics))
        .route("/openapi.json", get(openapi::openapi))
        .merge(web::routes());
    // The tests' way to make a handler panic (see the `test-panic` feature).
    #[cfg(any(test, feature = "test-panic"))]
    let routes = routes.route("/__test/panic", get(test_panic));
    let routes = routes
        .fallback(|req: Request| async move { ApiError::NotFound(req.uri().path().chars().take(200).collect()) })
        .method_not_allowed_fallback(|| async { ApiError::MethodNotAllowed })
        // No brotli (tower-http's `compression-br` feature is off): its encoder holds
        // ~27 MiB a stream at quality 4 (measured: 12 clients that stalled a 16 MB
        // billboards.json added 325 MiB of RSS, against 4 MiB for gzip and 18 MiB for
        // zstd), memory outside the reply budget.
        .layer(CompressionLayer::new())
        .layer(middleware::from_fn(tag_coding))
        // A panicking handler answers 500 with the JSON error (see `panics`), under
        // CORS and `observe` like any answer, so it is counted and logged as a 500.
        .layer(panics::catch());
    // CORS outside compression and the handlers, so errors carry it too; inside
    // `observe`, so preflights are counted and logged like any request.
    let routes = match cors::layer(&state.settings.cors_origins) {
        Some(cors) => routes.layer(cors).layer(middleware::from_fn(cors::preflight_204)),
        None => routes,
    };
    routes
        .layer(middleware::from_fn_with_state(Arc::clone(&state), observe))
        .with_state(state)
}

/// `GET /__test/panic`: panics (tests only).
#[cfg(any(test, feature = "test-panic"))]
async fn test_panic() -> Response {
    panic!("the test route panicked, as asked")
}

const REQUEST_ID: HeaderName = HeaderName::from_static("x-request-id");

/// Longest request path written to the access log, characters.
const MAX_LOGGED_PATH: usize = 512;

/// Counts requests in flight, even when the client goes away mid-request.
struct InFlight(prometheus::IntGauge);

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.dec();
    }
}

/// Request id, tracing span, metrics by route template, and a log line per request
/// (the access log: id, method, route template, path, status, time).
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
    // The path as sent (the URI parser admits only printable ASCII), cut to a bound.
    let path: String = req.uri().path().chars().take(MAX_LOGGED_PATH).collect();
    let span = tracing::info_span!("request", id = %id, method, route = %route, path = %path);
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

/// A compressed representation is a different representation: its ETag gets the
/// coding appended (`"…-gzip"`, `W/"…-gzip"` for a weak one); [`key::if_none_match`]
/// accepts either form.
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
            .map(|etag| {
                let (weak, tag) = etag.strip_prefix("W/").map_or(("", etag), |t| ("W/", t));
                format!("{weak}\"{}-{coding}\"", tag.trim_matches('"'))
            });
        if let Some(v) = tagged.and_then(|t| HeaderValue::from_str(&t).ok()) {
            response.headers_mut().insert(header::ETAG, v);
        }
    }
    response
}
