//! `GET /v1/worlds/{world}/render.png` (what a client would see) and the splat sheets
//! `GET /v1/splats.png`, `GET /v1/splats.json`, and the clear sky of a sun
//! `GET /v1/sky.json`.

use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::State;
use axum::http::{HeaderMap, HeaderName, HeaderValue};
use axum::response::Response;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::{self, Work};
use cloudscape_core::products::{sky, splats};
use cloudscape_core::render::image::png_noise;
use cloudscape_core::render::light::Lighting;
use cloudscape_core::render::pathtrace::DEFAULT_SAMPLES;
use cloudscape_core::render::scene::{RenderRequest, parse_size};
use cloudscape_core::render::{Camera, Quality, ShadingParams, Sun};
use cloudscape_core::view::render_cancellable;

use cloudscape_core::world::SnappedTime;

use crate::annotations::{ComputedResponses, NotModified, Overloaded, WorldName};
use crate::error::ApiError;
use crate::extract::WorldQuery;
use crate::key::CacheKey;
use crate::params::{Params, QualityName, parse_quality, parse_sun};
use crate::respond::Cached;
use crate::state::AppState;

/// Image size when a request gives none.
const DEFAULT_SIZE: &str = "640x360";

/// What a client would see from a camera, as a PNG.
///
/// 400: Malformed parameter. 413: Too many pixels, tiles in view or samples × pixels, or
/// more work than the time budget on the compute threads or the memory limit allow. 422:
/// t out of range.
#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/render.png",
    tag = "render",
    params(
        WorldName,
        ("camera" = String, Query, description = "X,Y,Z,YAW,PITCH,FOV: metres; yaw clockwise from north; pitch above the horizon; horizontal field of view; degrees", example = "0,0,1200,0,10,60"),
        ("t" = f64, Query, description = "World time, seconds, 0 <= t <= 1e12 (snapped to the first layer's frame grid)", example = 0),
        ("size" = Option<String>, Query, description = "WxH pixels (default 640x360)", example = "64x36"),
        ("quality" = Option<crate::params::QualityName>, Query, description = "fast | balanced (default) | accurate (billboards) | reference (volumetric path tracer: every order of scattering, sky light occluded by the cloud; its noise in X-Cloudscape-Noise) | reference-single (single-scattering ray marcher)"),
        ("samples" = Option<u32>, Query, description = "Samples per pixel of quality=reference, at least 2 (default 32); samples × pixels is limited by [limits] max_path_samples (413 beyond). Refused with other qualities.", example = 32),
        ("sun" = Option<String>, Query, description = "AZ,EL degrees (default: the world clock's sun at t); bucketed to ~8 degrees"),
    ),
    responses(
        (status = 200, description = "The rendered view. For quality=reference, X-Cloudscape-Samples (samples per pixel) and X-Cloudscape-Noise (the path tracer's stated noise: mean over pixels of the standard error of linear luminance, radiance units; the same values are in the PNG's tEXt chunks cloudscape:samples, cloudscape:noise, cloudscape:mean-luminance).", content_type = "image/png", body = Vec<u8>),
        ComputedResponses,
    )
)]
pub async fn render_png(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    let camera_text = params.required("camera")?;
    let camera = Camera::parse(camera_text).map_err(|m| ApiError::InvalidParameter {
        name: "camera".to_string(),
        message: m.to_string(),
    })?;
    let t = params.time("t")?;
    let (width, height) =
        parse_size(params.get("size").unwrap_or(DEFAULT_SIZE)).map_err(|m| ApiError::InvalidParameter {
            name: "size".to_string(),
            message: m.to_string(),
        })?;
    let quality = parse_quality(&params)?.unwrap_or(Quality::Balanced);
    let samples = parse_samples(&params, quality)?;
    let config = s.worlds.config();
    // Every layer of a view is rendered at one time: the first layer's frame.
    let frame = SnappedTime::snap(t, &resolved.world.layers[0], s.settings.frames_per_step);
    let sun = parse_sun(&params)?.unwrap_or_else(|| Sun::from_clock(frame.t, &config.sun));
    let request = RenderRequest {
        camera,
        width,
        height,
        t: frame.t,
        quality,
        sun: Some(sun),
        params: ShadingParams::default(),
        samples,
    };
    // The render limits (pixels, tiles in view, samples) and the estimated work (CPU
    // within the time budget, memory) are checked here, before any work.
    let work = s.admit("render", cost::render(&resolved.world, config, &request)?)?;
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
    let key = if quality == Quality::Reference {
        key.with("n", samples)
    } else {
        key
    };
    let world = resolved.world;
    let config = config.clone();
    let cached = Cached::at("render", key, "image/png", frame, t);
    // Admitted above, before the ETag is compared: a view over the limits is refused
    // even to a client that holds it. Admitting the same work again passes.
    let plan = move || {
        Ok((work, move |cancel: &Cancel| {
            let rendered = render_cancellable(&world, &config, &request, cancel)?;
            let png = match rendered.noise {
                Some(noise) => rendered.image.to_png_with_noise(&noise),
                None => rendered.image.to_png(),
            };
            Ok((Bytes::from(png), Vec::new()))
        }))
    };
    // The noise travels in the PNG itself, so a cached image states it too.
    let noise_headers = |bytes: &Bytes| {
        let mut h = HeaderMap::new();
        if let Some(noise) = png_noise(bytes) {
            h.insert(
                HeaderName::from_static("x-cloudscape-samples"),
                HeaderValue::from(noise.samples),
            );
            if let Ok(v) = HeaderValue::from_str(&format!("{:e}", noise.std_error)) {
                h.insert(HeaderName::from_static("x-cloudscape-noise"), v);
            }
        }
        Ok(h)
    };
    cached.respond_with(&s, &headers, plan, noise_headers).await
}

/// `samples=` of `quality=reference`: an integer (default [`DEFAULT_SAMPLES`]); its
/// range and the samples × pixels budget are checked with the other render limits.
fn parse_samples(params: &Params, quality: Quality) -> Result<u32, ApiError> {
    let Some(v) = params.get("samples") else {
        return Ok(DEFAULT_SAMPLES);
    };
    if quality != Quality::Reference {
        return Err(ApiError::InvalidParameter {
            name: "samples".to_string(),
            message: format!(
                "applies to quality=reference (the path tracer) only, not `{}`",
                quality.as_str()
            ),
        });
    }
    let n: u64 = v.trim().parse().map_err(|_| ApiError::InvalidNumber {
        name: "samples".to_string(),
        value: v.to_string(),
    })?;
    Ok(u32::try_from(n).unwrap_or(u32::MAX))
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
    let content_type = if json { "application/json" } else { "image/png" };
    let cached = Cached::timeless("splats", splats_key(quality, json), content_type);
    serve_global(&s, &headers, cached, move || splats_bytes(quality, json)).await
}

/// `quality=` of the splat sheets.
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
#[allow(
    dead_code,
    reason = "documentation: utoipa reads the field, the handlers read `Params`"
)]
struct SplatQuality {
    /// fast | balanced (default) | accurate | reference | reference-single
    quality: Option<QualityName>,
}

/// 400 of the splat sheets.
#[derive(utoipa::IntoResponses)]
#[response(status = 400, description = "Unknown quality")]
#[allow(
    dead_code,
    reason = "documentation: utoipa reads the body's type, no handler builds it"
)]
struct UnknownQuality(crate::error::ErrorBody);

/// A product that depends on no world (splat sheets, the sky): no work to admit.
async fn serve_global(
    s: &Arc<AppState>,
    headers: &HeaderMap,
    cached: Cached,
    compute: impl FnOnce() -> Bytes + Send + 'static,
) -> Result<Response, ApiError> {
    cached
        .respond(s, headers, move || {
            Ok((Work::default(), move |_: &Cancel| Ok(compute())))
        })
        .await
}

/// The splat sprite sheet of a quality preset.
#[utoipa::path(
    get,
    path = "/v1/splats.png",
    tag = "render",
    params(SplatQuality),
    responses(
        (status = 200, description = "The splat sprite sheet of the preset", content_type = "image/png", body = Vec<u8>),
        UnknownQuality, NotModified, Overloaded,
    )
)]
pub async fn splats_png(
    State(s): State<Arc<AppState>>,
    params: Params,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    splats(s, params, headers, false).await
}

/// The layout of the splat sprite sheet.
#[utoipa::path(
    get,
    path = "/v1/splats.json",
    tag = "render",
    params(SplatQuality),
    responses(
        (status = 200, description = "Layout of the splat sprite sheet: count, size, the optical depth of each splat", content_type = "application/json", body = Object),
        UnknownQuality, NotModified, Overloaded,
    )
)]
pub async fn splats_json(
    State(s): State<Arc<AppState>>,
    params: Params,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    splats(s, params, headers, true).await
}

/// The clear sky of a sun.
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
        (status = 400, body = crate::error::ErrorBody, description = "Neither sun nor t, or a malformed one"),
        (status = 422, body = crate::error::ErrorBody, description = "t out of range"),
        NotModified, Overloaded,
    )
)]
pub async fn sky_json(
    State(s): State<Arc<AppState>>,
    params: Params,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
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
    let cached = Cached::timeless(
        "sky",
        CacheKey::global("sky").with("s", bucket.id()),
        "application/json",
    );
    serve_global(&s, &headers, cached, move || {
        let lighting = Lighting::new(bucket.centre(), ShadingParams::default());
        Bytes::from(sky::encode_json(bucket, &lighting))
    })
    .await
}
