//! Operator routes: `/healthz`, `/readyz`, `/metrics` (`/openapi.json` is served by
//! [`crate::openapi`]).

use std::sync::Arc;

use axum::Json;
use axum::extract::State;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

use crate::state::{AppState, Lifecycle};

/// `/healthz` and `/readyz` bodies.
#[derive(Serialize, utoipa::ToSchema)]
pub struct Status {
    /// `ok`, `starting`, `failed` or `draining`.
    pub status: &'static str,
    /// While starting: the tile variants of the play areas kept warm whose current and
    /// next keyframes are not both computed yet (readiness waits for them).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub warm_pending: Option<usize>,
}

impl Status {
    fn of(status: &'static str) -> Status {
        Status {
            status,
            warm_pending: None,
        }
    }
}

fn no_store(status: StatusCode, body: Status) -> Response {
    let mut r = (status, Json(body)).into_response();
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

/// Liveness: the process answers.
#[utoipa::path(get, path = "/healthz", tag = "operations",
    responses((status = 200, body = Status, description = "The process is alive")))]
pub async fn healthz() -> Response {
    no_store(StatusCode::OK, Status::of("ok"))
}

/// Readiness: whether this replica takes its share of the load.
#[utoipa::path(get, path = "/readyz", tag = "operations",
    responses(
        (status = 200, body = Status, description = "Ready to serve"),
        (status = 503, body = Status, description = "Starting (start-up work, then the current and next keyframes of the play areas kept warm), start-up failed, or draining after SIGTERM"),
    ))]
pub async fn readyz(State(s): State<Arc<AppState>>) -> Response {
    let unavailable = |status| no_store(StatusCode::SERVICE_UNAVAILABLE, status);
    match s.readiness.get() {
        Lifecycle::Ready => no_store(StatusCode::OK, Status::of("ok")),
        Lifecycle::Starting => unavailable(Status {
            status: "starting",
            warm_pending: Some(s.warm.start_pending()),
        }),
        Lifecycle::Failed => unavailable(Status::of("failed")),
        Lifecycle::Draining => unavailable(Status::of("draining")),
    }
}

/// Prometheus metrics.
#[utoipa::path(get, path = "/metrics", tag = "operations",
    responses((status = 200, content_type = "text/plain", body = String, description = "Prometheus text exposition")))]
pub async fn metrics(State(s): State<Arc<AppState>>) -> Response {
    s.metrics.cache_bytes.set(s.cache.weighted_size() as i64);
    if let Some(kept) = &s.kept {
        s.metrics.kept_bytes.set(kept.bytes() as i64);
        s.metrics.kept_tiles.set(kept.tiles() as i64);
    }
    s.metrics.queue_depth.set(s.cache.queue_depth() as i64);
    s.metrics.backlog_seconds.set(s.cache.backlog_seconds());
    if let Some(a) = crate::allocator::Stats::read() {
        for (what, v) in [
            ("allocated", a.allocated),
            ("active", a.active),
            ("resident", a.resident),
            ("retained", a.retained),
        ] {
            s.metrics.allocator_bytes.with_label_values(&[what]).set(v as i64);
        }
    }
    let mut r = s.metrics.render().into_response();
    r.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; version=0.0.4"),
    );
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}
