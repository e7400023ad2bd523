//! `GET /v1/worlds/{world}/render.png` (what a client would see) and the splat sheets
//! `GET /v1/splats.png`, `GET /v1/splats.json`, and the clear sky of a sun
//! `GET /v1/sky.json`.

use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::rejection::PathRejection;
use axum::extract::{Path, State};
use axum::http::HeaderMap;
use axum::response::Response;

use crate::products::{sky, splats};
use crate::render::light::Lighting;
use crate::render::scene::{RenderRequest, parse_size, plan, render};
use crate::render::{Camera, Quality, ShadingParams, Sun};

use super::error::ApiError;
use super::key::{CacheKey, Frame};
use super::params::Params;
use super::tiles::{parse_quality, parse_sun, path_error};
use super::{AppState, Representation};

/// Image size when a request gives none.
const DEFAULT_SIZE: &str = "640x360";

#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/render.png",
    tag = "render",
    params(
        ("world" = String, Path, description = "Configured world name, or a decimal u64 seed", example = "default"),
        ("camera" = String, Query, description = "X,Y,Z,YAW,PITCH,FOV: metres; yaw clockwise from north; pitch above the horizon; horizontal field of view; degrees", example = "0,0,1200,0,10,60"),
        ("t" = f64, Query, description = "World time, seconds, 0 <= t <= 1e12 (snapped to the first layer's frame grid)", example = 0),
        ("size" = Option<String>, Query, description = "WxH pixels (default 640x360)", example = "64x36"),
        ("quality" = Option<super::openapi::QualityName>, Query, description = "fast | balanced (default) | accurate | reference (volumetric ray marcher)"),
        ("sun" = Option<String>, Query, description = "AZ,EL degrees (default: the world clock's sun at t); bucketed to ~8 degrees"),
    ),
    responses(
        (status = 200, description = "The rendered view", content_type = "image/png", body = Vec<u8>),
        (status = 304, description = "If-None-Match matched"),
        (status = 400, body = super::error::ErrorBody, description = "Malformed parameter"),
        (status = 404, body = super::error::ErrorBody, description = "Unknown world"),
        (status = 413, body = super::error::ErrorBody, description = "Too many pixels or tiles in view"),
        (status = 422, body = super::error::ErrorBody, description = "t out of range"),
        (status = 503, body = super::error::ErrorBody, description = "Overloaded or over the time budget; see Retry-After"),
    )
)]
pub async fn render_png(
    State(s): State<Arc<AppState>>,
    path: Result<Path<String>, PathRejection>,
    params: Params,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let Path(world) = path.map_err(path_error)?;
    let resolved = s.worlds.resolve(&world)?;
    let camera_text = params.required("camera")?;
    let camera = Camera::parse(camera_text).map_err(|m| ApiError::InvalidParameter {
        name: "camera".to_string(),
        message: m,
    })?;
    let t = params.time("t")?;
    let (width, height) =
        parse_size(params.get("size").unwrap_or(DEFAULT_SIZE)).map_err(|m| ApiError::InvalidParameter {
            name: "size".to_string(),
            message: m,
        })?;
    let quality = parse_quality(&params)?.unwrap_or(Quality::Balanced);
    let config = s.worlds.config();
    // Every layer of a view is rendered at one time: the first layer's frame.
    let frame = Frame::snap(t, &resolved.world.layers[0], s.settings.frames_per_step);
    let sun = parse_sun(&params)?.unwrap_or_else(|| Sun::from_clock(frame.t, &config.sun));
    let request = RenderRequest {
        camera,
        width,
        height,
        t: frame.t,
        quality,
        sun: Some(sun),
        params: ShadingParams::default(),
    };
    // The render limits (pixels, tiles in view) are checked here, before any work.
    plan(&resolved.world, config, &request)?;
    let p = camera.position;
    let key = CacheKey::new("render", &resolved, 0)
        .with(
            "cam",
            format!(
                "{},{},{},{},{},{}",
                p[0], p[1], p[2], camera.yaw_deg, camera.pitch_deg, camera.fov_deg
            ),
        )
        .with("size", format!("{width}x{height}"))
        .with("f", frame.index)
        .with("q", quality.as_str())
        .with("s", sun.bucket().id())
        .with("maxz", config.limits.max_level);
    let repr = Representation {
        etag: key.etag(),
        cache_control: s.cache_control(frame, t),
        frame: Some(frame),
    };
    if let Some(not_modified) = repr.not_modified(&headers) {
        return Ok(not_modified);
    }
    let world = resolved.world;
    let config = config.clone();
    let bytes = s
        .cache
        .get_or_compute(&s.metrics, "render", key, move || {
            Ok(Bytes::from(render(&world, &config, &request)?.image.to_png()))
        })
        .await?;
    Ok(repr.ok("image/png", bytes))
}

/// The cache key of a splat sheet.
pub fn splats_key(quality: Quality, json: bool) -> CacheKey {
    CacheKey::global("splats")
        .with("q", quality.as_str())
        .with("fmt", if json { "json" } else { "png" })
}

/// Encodes a splat sheet.
pub fn splats_bytes(quality: Quality, json: bool) -> Bytes {
    Bytes::from(if json {
        splats::encode_json_sheet(quality)
    } else {
        splats::encode_png_sheet(quality)
    })
}

async fn splats(s: Arc<AppState>, params: Params, headers: HeaderMap, json: bool) -> Result<Response, ApiError> {
    let quality = parse_quality(&params)?.unwrap_or(Quality::Balanced);
    let key = splats_key(quality, json);
    let repr = Representation {
        etag: key.etag(),
        cache_control: &s.settings.cache_control,
        frame: None,
    };
    if let Some(not_modified) = repr.not_modified(&headers) {
        return Ok(not_modified);
    }
    let bytes = s
        .cache
        .get_or_compute(&s.metrics, "splats", key, move || Ok(splats_bytes(quality, json)))
        .await?;
    Ok(repr.ok(if json { "application/json" } else { "image/png" }, bytes))
}

#[utoipa::path(
    get,
    path = "/v1/splats.png",
    tag = "render",
    params(("quality" = Option<super::openapi::QualityName>, Query, description = "fast | balanced (default) | accurate | reference")),
    responses(
        (status = 200, description = "The splat sprite sheet of the preset", content_type = "image/png", body = Vec<u8>),
        (status = 304, description = "If-None-Match matched"),
        (status = 400, body = super::error::ErrorBody, description = "Unknown quality"),
        (status = 503, body = super::error::ErrorBody, description = "Overloaded; see Retry-After"),
    )
)]
pub async fn splats_png(
    State(s): State<Arc<AppState>>,
    params: Params,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    splats(s, params, headers, false).await
}

#[utoipa::path(
    get,
    path = "/v1/splats.json",
    tag = "render",
    params(("quality" = Option<super::openapi::QualityName>, Query, description = "fast | balanced (default) | accurate | reference")),
    responses(
        (status = 200, description = "Layout of the splat sprite sheet: count, size, the optical depth of each splat", content_type = "application/json", body = Object),
        (status = 304, description = "If-None-Match matched"),
        (status = 400, body = super::error::ErrorBody, description = "Unknown quality"),
        (status = 503, body = super::error::ErrorBody, description = "Overloaded; see Retry-After"),
    )
)]
pub async fn splats_json(
    State(s): State<Arc<AppState>>,
    params: Params,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    splats(s, params, headers, true).await
}

#[utoipa::path(
    get,
    path = "/v1/sky.json",
    tag = "render",
    params(
        ("sun" = Option<String>, Query, description = "AZ,EL degrees; bucketed to ~8 degrees like every shaded product (the sky is for the bucket's centre)", example = "180,45"),
        ("t" = Option<f64>, Query, description = "World time, seconds, 0 <= t <= 1e12: the world clock's sun (when no sun is given)", example = 43200),
    ),
    responses(
        (status = 200, description = "The clear sky of the sun: radiance table over view elevation x azimuth from the sun, sun colour, sky ambients, ground albedo and the aerial-perspective constants and tables (src/products/sky.rs)", content_type = "application/json", body = Object),
        (status = 304, description = "If-None-Match matched"),
        (status = 400, body = super::error::ErrorBody, description = "Neither sun nor t, or a malformed one"),
        (status = 422, body = super::error::ErrorBody, description = "t out of range"),
        (status = 503, body = super::error::ErrorBody, description = "Overloaded; see Retry-After"),
    )
)]
pub async fn sky_json(State(s): State<Arc<AppState>>, params: Params, headers: HeaderMap) -> Result<Response, ApiError> {
    let sun = match parse_sun(&params)? {
        Some(sun) => sun,
        None => {
            if params.get("t").is_none() {
                return Err(ApiError::InvalidParameter {
                    name: "sun".to_string(),
                    message: "give the sun as sun=AZ,EL or a world time t for the clock's sun".to_string(),
                });
            }
            Sun::from_clock(params.time("t")?, &s.worlds.config().sun)
        }
    };
    let bucket = sun.bucket();
    let key = CacheKey::global("sky").with("s", bucket.id());
    let repr = Representation {
        etag: key.etag(),
        cache_control: &s.settings.cache_control,
        frame: None,
    };
    if let Some(not_modified) = repr.not_modified(&headers) {
        return Ok(not_modified);
    }
    let bytes = s
        .cache
        .get_or_compute(&s.metrics, "sky", key, move || {
            let lighting = Lighting::new(bucket.centre(), ShadingParams::default());
            Ok(Bytes::from(sky::encode_json(bucket, &lighting)))
        })
        .await?;
    Ok(repr.ok("application/json", bytes))
}
