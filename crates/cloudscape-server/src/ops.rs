//! Operator routes and start-up: `/healthz`, `/readyz`, `/metrics`, `/openapi.json`.

use std::sync::Arc;

use axum::Json;
use axum::extract::State;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

use cloudscape_core::density::{self, Region};

use super::error::ApiError;
use super::render::{splats_bytes, splats_key};
use super::{AppState, Lifecycle};
use cloudscape_core::render::Quality;

/// `/healthz` and `/readyz` bodies.
#[derive(Serialize, utoipa::ToSchema)]
pub struct Status {
    /// `ok`, `starting`, `failed` or `draining`.
    pub status: &'static str,
}

/// Start-up work: one small computation per layer of every configured world, through
/// the simulation, so that a replica only says it is ready once it can answer (and
/// its thread pools are warm), then the splat sheets of every quality into the cache.
/// Ready when it succeeds; never ready if it fails.
pub async fn start_up(state: Arc<AppState>) {
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
    match result {
        Ok(()) => {
            state.readiness.set(Lifecycle::Ready);
            if state.readiness.get() == Lifecycle::Ready {
                state.metrics.ready.set(1);
            }
            tracing::info!("start-up done: ready");
        }
        Err(e) => {
            state.readiness.set(Lifecycle::Failed);
            tracing::error!(error = %e, "start-up failed: the server will not become ready");
        }
    }
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

#[utoipa::path(get, path = "/openapi.json", tag = "operations",
    responses((status = 200, content_type = "application/json", body = Object, description = "This document")))]
pub async fn openapi() -> Response {
    let mut r = super::openapi::document().into_response();
    r.headers_mut()
        .insert(header::CONTENT_TYPE, HeaderValue::from_static("application/json"));
    r
}
