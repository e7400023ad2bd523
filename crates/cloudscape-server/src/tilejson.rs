//! TileJSON 3.0.0 (<https://github.com/mapbox/tilejson-spec/tree/master/3.0.0>) for
//! one product of one layer of a world, `GET /v1/worlds/{world}/tilejson.json`, and
//! the zoom-addressed tile route its `tiles` template names,
//! `GET /v1/worlds/{world}/zoom/{zoom}/{x}/{y}/{product}`.
//!
//! Levels and zooms run opposite ways. Our level 0 is the *finest* (a column is one
//! cell) and level `z` has columns `2^z` cells wide, up to `limits.max_level`;
//! TileJSON's zoom 0 is the *coarsest*. So `zoom = max_level − level`: `minzoom` 0
//! is level `max_level`, `maxzoom` = `max_level` is level 0. `x` counts east and `y`
//! counts *north* from the world origin (negative allowed), which is TileJSON's
//! `"scheme": "tms"` (rows from the south), not `xyz`. A zoom-route tile is the very
//! same bytes, ETag and cache entry as the level-route tile it maps to.
//!
//! URLs are absolute: `server.public_url` when set (the address clients use behind
//! a proxy or CDN), else `http://` (or `https://` when a proxy says so in
//! `X-Forwarded-Proto`) and the request's `Host`. A document built from the request's
//! headers is that client's alone: it says `Cache-Control: private` and `Vary: Host,
//! X-Forwarded-Proto`, so no shared cache (nginx, a CDN) keeps it under the plain URL
//! and hands another client the templates of a `Host` an attacker chose. With
//! `public_url` the document is the same for everyone and caches like discovery.

use std::collections::BTreeMap;
use std::sync::Arc;

use axum::extract::{FromRequestParts, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, HeaderValue, Uri, header};
use axum::response::Response;
use serde::Serialize;
use utoipa::openapi::RefOr;

use cloudscape_core::products::Product;
use cloudscape_core::render::tile::TILE_COLUMNS;
use cloudscape_core::world::ALGORITHM_VERSION;

use crate::annotations::{ComputedResponses, LayerName, NotModified, WorldName};
use crate::discovery::json_response;
use crate::error::ApiError;
use crate::extract::{TilePath, WorldPath, layer, parse_product};
use crate::params::{Params, parse_level, parse_quality, parse_sun};
use crate::state::AppState;
use crate::tiles::{self, TileCell, TileQuery, product_bytes};

/// The TileJSON version written.
pub const TILEJSON_VERSION: &str = "3.0.0";

/// The extent TileJSON's `bounds` defaults to: our tiles cover the whole plane, which
/// is not a geographic projection, so the bounds say "everywhere".
const WHOLE_WORLD: [f64; 4] = [-180.0, -85.051_128_779_806_59, 180.0, 85.051_128_779_806_6];

/// A TileJSON 3.0.0 document (the fields we fill; `vector_layers` is required by the
/// official schema and empty: our tiles are not vector tiles).
#[derive(Serialize, utoipa::ToSchema)]
pub struct TileJson {
    /// Always `3.0.0`.
    pub tilejson: &'static str,
    pub name: String,
    pub description: String,
    /// `ALGORITHM_VERSION.0.0`: a new algorithm version is new bytes.
    pub version: String,
    /// `tms`: tile rows count north (from the south), as our `y` does.
    pub scheme: &'static str,
    /// One absolute URL template of the zoom route, with `{z}` (zoom), `{x}`, `{y}`.
    pub tiles: Vec<String>,
    pub minzoom: u32,
    pub maxzoom: u32,
    /// WGS 84 left, bottom, right, top: the whole world (see the module notes).
    pub bounds: [f64; 4],
    pub vector_layers: Vec<serde_json::Value>,
    /// What TileJSON cannot say: the plane, the level of each zoom, the layer.
    pub cloudscape: TileJsonExtra,
}

/// The `cloudscape` member of a TileJSON document.
#[derive(Serialize, utoipa::ToSchema)]
pub struct TileJsonExtra {
    pub world: String,
    pub layer: String,
    pub product: String,
    /// Our level of a zoom: `level = max_level - zoom` (level 0 is the finest).
    pub level_of_zoom: String,
    pub max_level: u32,
    /// Columns per tile side.
    pub tile_size: i64,
    /// Side of a level-0 tile in metres (a tile of level z is 2^z times that).
    pub tile_metres_level0: f64,
    /// Coordinates: metres on a plane, x east, y north, z up; tile (level, 0, 0)
    /// has its south-west corner at the origin.
    pub crs: &'static str,
    /// Absolute URL template of the same tiles addressed by level (`{z}` = level).
    pub level_tiles: String,
    /// Seconds; when the TileJSON was asked without `t`, the templates keep a `{t}`
    /// placeholder that the client fills (a tile needs a time).
    pub t: Option<f64>,
}

/// Where the absolute URLs of a document start.
struct PublicBase {
    /// Scheme and authority (and `public_url`'s path), no trailing slash.
    url: String,
    /// Taken from the request's headers (no `public_url`): the document is private.
    from_request: bool,
}

/// The scheme and authority clients reach this server at: `server.public_url`, else
/// the request's `Host` (`X-Forwarded-Proto: https` makes it https).
fn public_base(s: &AppState, uri: &Uri, headers: &HeaderMap) -> Result<PublicBase, ApiError> {
    if !s.settings.public_url.is_empty() {
        return Ok(PublicBase {
            url: s.settings.public_url.trim_end_matches('/').to_string(),
            from_request: false,
        });
    }
    let host = uri
        .authority()
        .map(|a| a.as_str().to_string())
        .or_else(|| headers.get("host").and_then(|h| h.to_str().ok()).map(str::to_string))
        .ok_or_else(|| ApiError::InvalidParameter {
            name: "host".to_string(),
            message: "the request has no Host header and server.public_url is not set".to_string(),
        })?;
    let valid = !host.is_empty()
        && host.len() <= 255
        && host
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'-' | b':' | b'[' | b']' | b'_'));
    if !valid {
        return Err(ApiError::InvalidParameter {
            name: "host".to_string(),
            message: format!(
                "the Host header `{}` is not a host[:port]",
                host.chars().take(64).collect::<String>()
            ),
        });
    }
    let https = headers
        .get("x-forwarded-proto")
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.trim().eq_ignore_ascii_case("https"));
    Ok(PublicBase {
        url: format!("{}://{host}", if https { "https" } else { "http" }),
        from_request: true,
    })
}

/// `cache_control` for one client only: its directives with `public` (and the shared
/// caches' `s-maxage`) replaced by `private`.
fn private(cache_control: &str) -> String {
    let kept = cache_control.split(',').map(str::trim).filter(|d| {
        let name = d.split('=').next().unwrap_or("").to_ascii_lowercase();
        !d.is_empty() && !matches!(name.as_str(), "public" | "private" | "s-maxage")
    });
    std::iter::once("private").chain(kept).collect::<Vec<_>>().join(", ")
}

/// The query that every tile URL of the document carries: `t` (or the `{t}`
/// placeholder), `layer`, and `quality` and `sun` when they were asked.
fn tile_query(params: &Params, layer: &str, t: Option<f64>) -> String {
    let mut parts = vec![format!("t={}", t.map_or_else(|| "{t}".to_string(), |t| t.to_string()))];
    parts.push(Params(Vec::new()).query_with("layer", layer));
    for name in ["quality", "sun"] {
        if let Some(v) = params.get(name) {
            parts.push(Params(Vec::new()).query_with(name, v));
        }
    }
    parts.join("&")
}

#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/tilejson.json",
    tag = "discovery",
    params(
        WorldName,
        LayerName,
        ("product" = Option<crate::extract::TileProduct>, Query, description = "Tile product (default coverage.png)"),
        ("t" = Option<f64>, Query, description = "World time baked into the tile URLs; without it they keep a {t} placeholder"),
        ("quality" = Option<crate::params::QualityName>, Query, description = "Passed on to the tile URLs"),
        ("sun" = Option<String>, Query, description = "AZ,EL, passed on to the tile URLs"),
    ),
    responses(
        (status = 200, body = TileJson, description = "TileJSON 3.0.0. zoom = max_level - level (our level 0 is the finest); scheme tms (y counts north); absolute URLs from server.public_url, else from the request's Host and X-Forwarded-Proto (then Cache-Control: private and Vary: Host, X-Forwarded-Proto: no shared cache keeps it)"),
        (status = 400, body = crate::error::ErrorBody, description = "Malformed parameter or Host"),
        (status = 404, body = crate::error::ErrorBody, description = "Unknown world, layer or product"),
        (status = 422, body = crate::error::ErrorBody, description = "t out of range"),
        NotModified,
    )
)]
pub async fn tilejson(
    State(s): State<Arc<AppState>>,
    WorldPath(resolved): WorldPath,
    params: Params,
    uri: Uri,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let w = &resolved.world;
    let (_, layer) = layer(w, params.get("layer"))?;
    let product = match params.get("product") {
        Some(p) => parse_product(p)?,
        None => Product::CoveragePng,
    };
    let t = match params.get("t") {
        Some(_) => Some(params.time("t")?),
        None => None,
    };
    parse_quality(&params)?;
    parse_sun(&params)?;
    let base = public_base(&s, &uri, &headers)?;
    let max_level = s.worlds.config().limits.max_level;
    let world_url = format!("{}/v1/worlds/{}", base.url, encode_segment(&w.name));
    let query = tile_query(&params, &layer.name, t);
    let doc = TileJson {
        tilejson: TILEJSON_VERSION,
        name: format!("cloudscape {} {} {}", w.name, layer.name, product.name()),
        description: format!(
            "Layer {} ({}, {:.0}-{:.0} m) of world {}, product {}. zoom = {max_level} - level: our level 0 \
             (one cell per column, {} m) is maxzoom; y counts north (scheme tms); coordinates are metres on \
             a plane (x east, y north), not a map projection. See docs/formats.md.",
            layer.name,
            layer.preset_name,
            layer.base,
            layer.top(),
            w.name,
            product.name(),
            layer.cell_size,
        ),
        version: format!("{ALGORITHM_VERSION}.0.0"),
        scheme: "tms",
        tiles: vec![format!("{world_url}/zoom/{{z}}/{{x}}/{{y}}/{}?{query}", product.name())],
        minzoom: 0,
        maxzoom: max_level,
        bounds: WHOLE_WORLD,
        vector_layers: Vec::new(),
        cloudscape: TileJsonExtra {
            world: w.name.clone(),
            layer: layer.name.clone(),
            product: product.name().to_string(),
            level_of_zoom: format!("level = {max_level} - zoom"),
            max_level,
            tile_size: TILE_COLUMNS as i64,
            tile_metres_level0: layer.cell_size * TILE_COLUMNS as f64,
            crs: "metres on a plane: x east, y north, z up; tile (level, 0, 0) starts at the origin",
            level_tiles: format!("{world_url}/tiles/{{z}}/{{x}}/{{y}}/{}?{query}", product.name()),
            t,
        },
    };
    if !base.from_request {
        return json_response(&headers, &s.settings.cache_control_other, &doc);
    }
    let mut response = json_response(&headers, &private(&s.settings.cache_control_other), &doc)?;
    response
        .headers_mut()
        .append(header::VARY, HeaderValue::from_static("host, x-forwarded-proto"));
    Ok(response)
}

/// A world name as one URL path segment.
fn encode_segment(name: &str) -> String {
    let q = Params(Vec::new()).query_with("n", name);
    q.trim_start_matches("n=").to_string()
}

/// `/v1/worlds/{world}/zoom/{zoom}/{x}/{y}/{product}`: the tile at level
/// `max_level − zoom`.
pub struct ZoomTilePath(pub TilePath);

impl FromRequestParts<Arc<AppState>> for ZoomTilePath {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, s: &Arc<AppState>) -> Result<Self, ApiError> {
        let level = |zoom: &str, max: u32| parse_level(zoom, max).map(|zoom| max - zoom);
        TilePath::parse(parts, s, level).await.map(ZoomTilePath)
    }
}

/// The 200 of `/zoom`.
pub struct ZoomTileBytes;

impl utoipa::IntoResponses for ZoomTileBytes {
    fn responses() -> BTreeMap<String, RefOr<utoipa::openapi::response::Response>> {
        product_bytes("The same bytes, ETag and headers as /tiles/{max_level - zoom}/{x}/{y}/{product}")
    }
}

#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/zoom/{zoom}/{x}/{y}/{product}",
    tag = "tiles",
    params(
        WorldName,
        ("zoom" = u32, Path, description = "TileJSON zoom: the tile of level max_level - zoom (zoom max_level is level 0, the finest)", minimum = 0, example = 16),
        TileCell,
        TileQuery,
        LayerName,
    ),
    responses(ZoomTileBytes, ComputedResponses)
)]
pub async fn zoom_tile(
    state: State<Arc<AppState>>,
    params: Params,
    ZoomTilePath(path): ZoomTilePath,
    uri: Uri,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    tiles::tile(state, params, path, uri, headers).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_queries_keep_a_time_placeholder_or_the_time() {
        let p = Params(vec![("quality".into(), "fast".into()), ("junk".into(), "x".into())]);
        assert_eq!(tile_query(&p, "low cu", None), "t={t}&layer=low%20cu&quality=fast");
        assert_eq!(tile_query(&Params(vec![]), "a", Some(120.0)), "t=120&layer=a");
        assert_eq!(encode_segment("my world"), "my%20world");
    }

    #[test]
    fn a_document_of_the_request_host_is_private() {
        assert_eq!(private("public, max-age=60"), "private, max-age=60");
        assert_eq!(
            private("max-age=60, s-maxage=600, PUBLIC, stale-while-revalidate=30"),
            "private, max-age=60, stale-while-revalidate=30"
        );
        assert_eq!(private(""), "private");
    }
}
