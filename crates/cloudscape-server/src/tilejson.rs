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
//! Time: a document asked with `t` bakes that time into its templates. Without `t`
//! its templates name no time, so a generic client that fills only `{z}`, `{x}` and
//! `{y}` gets the world clock's current keyframe (max-age until the next); the
//! `cloudscape.keyframe_tiles` template keeps a `{t}` for clients that animate.
//!
//! URLs are absolute ([`crate::public_url`]): from `server.public_url`, else from the
//! request's `Host` (then the document is private to that client).

use std::collections::BTreeMap;
use std::sync::Arc;

use axum::extract::{FromRequestParts, State};
use axum::http::request::Parts;
use axum::http::{HeaderMap, Uri};
use axum::response::Response;
use serde::Serialize;
use utoipa::openapi::RefOr;

use cloudscape_core::products::Product;
use cloudscape_core::render::tile::TILE_COLUMNS;
use cloudscape_core::world::ALGORITHM_VERSION;

use crate::annotations::{ComputedResponses, LayerName, NotModified, WorldName};
use crate::error::ApiError;
use crate::extract::{TilePath, WorldPath, layer, parse_product};
use crate::params::{Params, parse_level, parse_quality, parse_sun};
use crate::public_url::{PublicBase, encode_segment};
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
    /// Absolute URL template of the zoom route with a `{t}` placeholder as well, for
    /// clients that animate: each keyframe's own `t` is an immutable answer.
    pub keyframe_tiles: String,
    /// Seconds: the time baked into `tiles` and `level_tiles`. Absent when the
    /// TileJSON was asked without `t`: those templates then name no time and answer
    /// the world clock's current keyframe (max-age until the next).
    pub t: Option<f64>,
}

/// When the tile URLs of a document are.
enum TileTime {
    /// Baked in: `t=` of the request.
    At(f64),
    /// Not named: the tile route answers the world clock's current keyframe.
    Clock,
    /// A `{t}` placeholder the client fills.
    Placeholder,
}

/// The query that every tile URL of the document carries: `t` as `time` says,
/// `layer`, and `quality` and `sun` when they were asked.
fn tile_query(params: &Params, layer: &str, time: TileTime) -> String {
    let mut parts = match time {
        TileTime::At(t) => vec![format!("t={t}")],
        TileTime::Clock => Vec::new(),
        TileTime::Placeholder => vec!["t={t}".to_string()],
    };
    parts.push(Params(Vec::new()).query_with("layer", layer));
    for name in ["quality", "sun"] {
        if let Some(v) = params.get(name) {
            parts.push(Params(Vec::new()).query_with(name, v));
        }
    }
    parts.join("&")
}

/// TileJSON 3.0.0 of one product of one layer.
#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/tilejson.json",
    tag = "discovery",
    params(
        WorldName,
        LayerName,
        ("product" = Option<crate::extract::TileProduct>, Query, description = "Tile product (default coverage.png)"),
        ("t" = Option<f64>, Query, description = "World time baked into the tile URLs; without it they name no time and answer the world clock's current keyframe (cloudscape.keyframe_tiles keeps a {t} placeholder)"),
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
    let base = PublicBase::of(&s, &uri, &headers)?;
    let max_level = s.worlds.config().limits.max_level;
    let world_url = format!("{}/v1/worlds/{}", base.url, encode_segment(&w.name));
    let query = tile_query(&params, &layer.name, t.map_or(TileTime::Clock, TileTime::At));
    let zoom_tiles = |query: &str| format!("{world_url}/zoom/{{z}}/{{x}}/{{y}}/{}?{query}", product.name());
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
        tiles: vec![zoom_tiles(&query)],
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
            keyframe_tiles: zoom_tiles(&tile_query(&params, &layer.name, TileTime::Placeholder)),
            t,
        },
    };
    base.json_response(&headers, &s.settings.cache_control_other, &doc)
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

/// One product of one tile, by TileJSON zoom.
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
    fn tile_queries_name_the_time_no_time_or_a_placeholder() {
        let p = Params(vec![("quality".into(), "fast".into()), ("junk".into(), "x".into())]);
        assert_eq!(
            tile_query(&p, "low cu", TileTime::Placeholder),
            "t={t}&layer=low%20cu&quality=fast"
        );
        assert_eq!(tile_query(&p, "low cu", TileTime::Clock), "layer=low%20cu&quality=fast");
        assert_eq!(tile_query(&Params(vec![]), "a", TileTime::At(120.0)), "t=120&layer=a");
    }
}
