//! Discovery: `/v1/worlds` and `/v1/worlds/{world}` (TileJSON-like).

use cloudscape_core::weather::precipitation::snow_level;
use std::sync::Arc;

use axum::extract::State;
use axum::http::HeaderMap;
use axum::response::Response;
use serde::Serialize;

use cloudscape_core::products::Product;
use cloudscape_core::render::tile::TILE_COLUMNS;
use cloudscape_core::world::warm::Margin;
use cloudscape_core::world::{ALGORITHM_VERSION, MAX_KEYFRAME_DOUBLINGS, MAX_TIME, keyframe_span};

use crate::annotations::{NotModified, WorldName};
use crate::error::ApiError;
use crate::extract::WorldPath;
use crate::key::stable_hash_hex;
use crate::respond::Representation;
use crate::state::AppState;
use crate::warm;

/// One configured world in the list.
#[derive(Serialize, utoipa::ToSchema)]
pub struct WorldSummary {
    pub name: String,
    pub seed: u64,
    pub layers: Vec<String>,
    /// Path of the world's discovery document.
    pub url: String,
}

/// `/v1/worlds`.
#[derive(Serialize, utoipa::ToSchema)]
pub struct WorldList {
    pub algorithm_version: u32,
    /// Configured worlds. Any decimal u64 also names a world: that seed with the
    /// `default` world's climate.
    pub worlds: Vec<WorldSummary>,
}

/// One layer of a world, as clients need it to place tiles in space and time.
#[derive(Serialize, utoipa::ToSchema)]
pub struct LayerInfo {
    pub name: String,
    pub preset: String,
    /// Automaton mode: dobashi or rosa.
    pub mode: String,
    /// Altitude of the layer's bottom and top, metres.
    pub base: f64,
    pub top: f64,
    /// Level-0 cell size, metres (horizontal, vertical).
    pub cell_size: f64,
    pub cell_height: f64,
    /// Depth in cells: the first axis of density grids.
    pub depth: u32,
    /// Seconds per automaton step.
    pub dt: f64,
    /// Seconds between canonical frames (`dt / frames_per_step`): `sample`,
    /// `region`, `series` and `render.png` snap `t` to these.
    pub frame_seconds: f64,
    /// Keyframe span of tiles of level 0, 1, …, seconds: level z uses entry
    /// `min(z, len − 1)` (`dt · 2^min(z, 4)`). Tile products are computed at
    /// `t0 = floor(t / span) · span` and animate by themselves until `t0 + span`.
    pub keyframe_spans: Vec<f64>,
    /// Whether the layer's preset can precipitate (a precipitation efficiency above
    /// 0): `precipitation.png` is worth asking for.
    pub precipitates: bool,
    /// Whether the layer's preset makes lightning (a `lightning` factor above 0):
    /// `/lightning` lists strikes in it.
    pub lightning: bool,
    /// Wind at the base, m/s, and its change with height, (m/s)/m.
    pub wind: [f64; 2],
    pub shear: [f64; 2],
}

/// The world clock: world time `t = offset + rate · u` at Unix second `u` (config
/// `[worlds.NAME.clock]`; without one, `t` is Unix time).
#[derive(Serialize, utoipa::ToSchema)]
pub struct ClockInfo {
    /// World time at the Unix epoch, seconds.
    pub offset: f64,
    /// World seconds per real second.
    pub rate: f64,
    /// World time when this answer was made, whole seconds (within [0, 1e12]);
    /// clients follow it with `offset + rate · u` on their own clock.
    pub now: f64,
}

/// A play area the server keeps warm (config `[[worlds.NAME.warm]]`): the current and
/// next keyframes of its tiles are computed whether anyone asks or not.
#[derive(Serialize, utoipa::ToSchema)]
pub struct WarmInfo {
    pub name: String,
    /// `[x0, y0, x1, y1]`, metres: the area's box, or its polygon's bounding box.
    pub bbox: [f64; 4],
    /// The polygon's vertices `[[x, y], …]`, metres; null for a box.
    pub polygon: Option<Vec<[f64; 2]>>,
    /// How far around the area tiles are kept warm too: metres at every level, or
    /// `"view"` (at each level, as far as a viewer in the area draws that level).
    #[schema(value_type = Object)]
    pub margin: Margin,
    /// Tile levels kept warm.
    pub levels: Vec<u32>,
    /// Tile products kept warm, by URL name.
    pub products: Vec<String>,
    /// Qualities of the shaded products kept warm.
    pub qualities: Vec<String>,
    /// Layers kept warm, by name.
    pub layers: Vec<String>,
    /// Tile variants kept warm (tiles × layers × computations × qualities; the products
    /// of one shading are one computation).
    pub tiles: usize,
}

/// `/v1/worlds/{world}`: everything a client needs to fetch tiles.
#[derive(Serialize, utoipa::ToSchema)]
pub struct WorldInfo {
    pub name: String,
    pub seed: u64,
    pub algorithm_version: u32,
    /// Columns per tile side.
    pub tile_size: i64,
    pub minzoom: u32,
    pub maxzoom: u32,
    /// Largest accepted `t`, seconds.
    pub max_time: f64,
    pub frames_per_step: u32,
    /// How tile products animate between keyframes (the rule of
    /// `render::keyframe`; docs/formats.md states it per product).
    pub keyframes: String,
    /// Altitude of the 0 °C isotherm, metres (config `freezing_level`).
    pub freezing_level: f64,
    /// Precipitation is snow at and above this altitude (300 m below the freezing
    /// level), rain below it: what a client at its own altitude reads off
    /// `precipitation.png`.
    pub snow_level: f64,
    pub layers: Vec<LayerInfo>,
    /// The world clock, and the world time now.
    pub clock: ClockInfo,
    /// Play areas kept warm (none when the server keeps none: `server.warm_threads` 0).
    pub warm: Vec<WarmInfo>,
    /// Tile products served, by URL name.
    pub products: Vec<String>,
    /// URL templates (paths) for tiles and queries; `{z}`, `{x}`, `{y}`, `{t}`, … are placeholders.
    pub tiles: Vec<String>,
    pub sample: String,
    pub region: String,
    pub series: String,
    pub lightning: String,
    pub render: String,
    pub splats: Vec<String>,
    /// TileJSON 3.0.0 of one layer and product (absolute URLs, zoom = maxzoom − level).
    pub tilejson: String,
}

pub(crate) fn json_response(
    headers: &HeaderMap,
    cache_control: &str,
    value: &impl Serialize,
) -> Result<Response, ApiError> {
    let body = serde_json::to_vec(value).map_err(|e| ApiError::Internal(e.to_string()))?;
    let etag = format!("\"{}\"", stable_hash_hex(&body));
    tagged_json_response(headers, cache_control, body, etag)
}

/// A JSON `body` answered under `etag` (304 when the request names it).
fn tagged_json_response(
    headers: &HeaderMap,
    cache_control: &str,
    body: Vec<u8>,
    etag: String,
) -> Result<Response, ApiError> {
    let repr = Representation {
        etag,
        cache_control: cache_control.to_string(),
        time: None,
        content_location: None,
    };
    Ok(repr
        .not_modified(headers)
        .unwrap_or_else(|| repr.ok_small("application/json", body.into())))
}

/// The configured worlds.
#[utoipa::path(
    get,
    path = "/v1/worlds",
    tag = "discovery",
    responses((status = 200, body = WorldList, description = "Configured worlds"), NotModified)
)]
pub async fn list(State(s): State<Arc<AppState>>, headers: HeaderMap) -> Result<Response, ApiError> {
    let worlds = s
        .worlds
        .config()
        .worlds
        .values()
        .map(|w| WorldSummary {
            name: w.name.clone(),
            seed: w.seed,
            layers: w.layers.iter().map(|l| l.name.clone()).collect(),
            url: format!("/v1/worlds/{}", w.name),
        })
        .collect();
    json_response(
        &headers,
        &s.settings.cache_control_other,
        &WorldList {
            algorithm_version: ALGORITHM_VERSION,
            worlds,
        },
    )
}

/// One world's discovery document.
#[utoipa::path(
    get,
    path = "/v1/worlds/{world}",
    tag = "discovery",
    params(WorldName),
    responses(
        (status = 200, body = WorldInfo, description = "Layers, cell sizes, tile size, levels, dt, algorithm version, URL templates"),
        (status = 400, body = crate::error::ErrorBody, description = "Malformed path"),
        (status = 404, body = crate::error::ErrorBody, description = "Unknown world"),
        NotModified,
    )
)]
pub async fn world(
    State(s): State<Arc<AppState>>,
    WorldPath(resolved): WorldPath,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let w = resolved.world;
    let fps = s.settings.frames_per_step;
    let base = format!("/v1/worlds/{}", w.name);
    let clock = ClockInfo {
        offset: w.clock.offset,
        rate: w.clock.rate,
        now: warm::world_now(&w.clock, warm::unix_now()).floor(),
    };
    let warm = if s.warm.enabled() {
        w.warm
            .iter()
            .enumerate()
            .map(|(i, a)| WarmInfo {
                name: a.name.clone(),
                bbox: a.bounds(),
                polygon: a.polygon().map(<[[f64; 2]]>::to_vec),
                margin: a.margin,
                levels: a.levels.clone(),
                products: a.products.clone(),
                qualities: a.qualities.clone(),
                layers: a.layers.iter().map(|&l| w.layers[l].name.clone()).collect(),
                tiles: s.warm.count(&w.name, i),
            })
            .collect()
    } else {
        Vec::new()
    };
    let info = WorldInfo {
        clock,
        warm,
        seed: w.seed,
        algorithm_version: ALGORITHM_VERSION,
        tile_size: TILE_COLUMNS as i64,
        minzoom: 0,
        maxzoom: s.worlds.config().limits.max_level,
        max_time: MAX_TIME,
        frames_per_step: fps,
        keyframes: "A tile of level z is computed at keyframes t0 = k * span(z), span(z) = dt * 2^min(z, 4) \
                    (keyframe_spans). Ask the keyframe's own t for an immutable answer; any t inside the span \
                    answers with the same bytes, max-age until the next keyframe and Content-Location naming \
                    the keyframe's URL; no t, the world clock's current keyframe in the same way. billboards hold each billboard at t0 and t1 = t0 + span with its wind \
                    velocity: at t, f = (t - t0) / span, draw it at position + velocity * (t - t0) with \
                    splat_tau, colour, tau_sun and opacity linear in f. shadow.png holds t0 (R) and t1 (G), \
                    blended linearly. Density grids, coverage.png and atlases hold t0: blend keyframes k and \
                    k + 1 with the same f, density moved by the wind at each height."
            .to_string(),
        freezing_level: w.layers[0].freezing_level,
        snow_level: snow_level(w.layers[0].freezing_level),
        layers: w
            .layers
            .iter()
            .map(|l| LayerInfo {
                name: l.name.clone(),
                preset: l.preset_name.clone(),
                mode: format!("{:?}", l.preset.mode).to_lowercase(),
                base: l.base,
                top: l.top(),
                cell_size: l.cell_size,
                cell_height: l.cell_height,
                depth: l.depth,
                dt: l.dt,
                frame_seconds: l.dt / fps as f64,
                keyframe_spans: (0..=MAX_KEYFRAME_DOUBLINGS).map(|z| keyframe_span(l.dt, z)).collect(),
                precipitates: l.preset.precipitates(),
                lightning: l.preset.makes_lightning(),
                wind: l.wind,
                shear: l.shear,
            })
            .collect(),
        products: Product::ALL.iter().map(|p| p.name().to_string()).collect(),
        tiles: Product::ALL
            .iter()
            .map(|p| {
                format!(
                    "{base}/tiles/{{z}}/{{x}}/{{y}}/{}?t={{t}}&layer={{layer}}&quality={{quality}}&sun={{az}},{{el}}",
                    p.name()
                )
            })
            .collect(),
        sample: format!("{base}/sample?x={{x}}&y={{y}}&z={{z}}&t={{t}}"),
        region: format!("{base}/region?bbox={{x0}},{{y0}},{{x1}},{{y1}}&t={{t}}&layer={{layer}}&level={{level}}"),
        series: format!("{base}/series?bbox={{x0}},{{y0}},{{x1}},{{y1}}&t0={{t0}}&t1={{t1}}&dt={{dt}}&layer={{layer}}"),
        lightning: format!("{base}/lightning?bbox={{x0}},{{y0}},{{x1}},{{y1}}&t0={{t0}}&t1={{t1}}"),
        render: format!(
            "{base}/render.png?camera={{x}},{{y}},{{z}},{{yaw}},{{pitch}},{{fov}}&t={{t}}&size={{w}}x{{h}}&quality={{quality}}&sun={{az}},{{el}}"
        ),
        splats: vec![
            "/v1/splats.png?quality={quality}".to_string(),
            "/v1/splats.json?quality={quality}".to_string(),
        ],
        tilejson: format!("{base}/tilejson.json?layer={{layer}}&product={{product}}"),
        name: w.name,
    };
    // `clock.now` differs in every answer: the ETag is that of the document without it,
    // weak (the bodies differ in `now` only, which clients follow from `offset` and
    // `rate`), so revalidation still answers 304 while the world is unchanged.
    let json = |info: &WorldInfo| serde_json::to_vec(info).map_err(|e| ApiError::Internal(e.to_string()));
    let mut info = info;
    let now = std::mem::replace(&mut info.clock.now, 0.0);
    let etag = format!("W/\"{}\"", stable_hash_hex(&json(&info)?));
    info.clock.now = now;
    tagged_json_response(&headers, &s.settings.cache_control_other, json(&info)?, etag)
}
