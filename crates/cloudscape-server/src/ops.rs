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
}

fn no_store(status: StatusCode, body: Status) -> Response {
    let mut r = (status, Json(body)).into_response();
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

#[utoipa::path(get, path = "/healthz", tag = "operations",
    responses((status = 200, body = Status, description = "The process is alive")))]
pub async fn healthz() -> Response {
    no_store(StatusCode::OK, Status { status: "ok" })
}

#[utoipa::path(get, path = "/readyz", tag = "operations",
    responses(
        (status = 200, body = Status, description = "Ready to serve"),
        (status = 503, body = Status, description = "Starting, start-up failed, or draining after SIGTERM"),
    ))]
pub async fn readyz(State(s): State<Arc<AppState>>) -> Response {
    match s.readiness.get() {
        Lifecycle::Ready => no_store(StatusCode::OK, Status { status: "ok" }),
        Lifecycle::Starting => no_store(StatusCode::SERVICE_UNAVAILABLE, Status { status: "starting" }),
        Lifecycle::Failed => no_store(StatusCode::SERVICE_UNAVAILABLE, Status { status: "failed" }),
        Lifecycle::Draining => no_store(StatusCode::SERVICE_UNAVAILABLE, Status { status: "draining" }),
    }
}

#[utoipa::path(get, path = "/metrics", tag = "operations",
    responses((status = 200, content_type = "text/plain", body = String, description = "Prometheus text exposition")))]
pub async fn metrics(State(s): State<Arc<AppState>>) -> Response {
    s.metrics.cache_bytes.set(s.cache.weighted_size() as i64);
    if let Some(kept) = &s.kept {
        s.metrics.kept_bytes.set(kept.bytes() as i64);
        s.metrics.kept_tiles.set(kept.tiles() as i64);
    }
    s.metrics.queue_depth.set(s.cache.queue_depth() as i64);
    let mut r = s.metrics.render().into_response();
    r.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; version=0.0.4"),
    );
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}
