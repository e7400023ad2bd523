//! OGC API – Environmental Data Retrieval (EDR) over the same density as `/sample`,
//! `/region` and `/series`: a landing page (at `/v1/edr` and `/v1/edr/`, the URL
//! OWSLib forms), the conformance declaration, one collection per world (configured
//! worlds are listed; any decimal u64 seed also names one), the `position`, `radius`,
//! `area` and `cube` queries answered as CoverageJSON, and the `items` query, the
//! lightning strikes as GeoJSON ([`items`]).
//!
//! Implemented: those query types with `coords` (WKT POINT / POLYGON), `within` and
//! `within-units`, `bbox`, `z`, `datetime` (ISO 8601 instants and closed intervals;
//! world time t = 0 is 1970-01-01T00:00:00Z), `parameter-name` (or OWSLib's
//! `parameter_names`), `limit` and `offset` (items), `f`, `crs` (the one local CRS),
//! and the cloudscape extras `layer` and `level`; any other parameter is a 400 that
//! names it. Not implemented: trajectory, corridor, locations, instances (a world is
//! one deterministic run), `items/{id}`, other output formats.
//!
//! The values are those of the other queries, by construction: a position's density
//! and precipitation rate are `/sample`'s, an area's, radius' or cube's per-column
//! values aggregate to `/region`'s statistics (`cloudscape_core::density::column_stats`),
//! the items are `/lightning`'s strikes.

mod covjson;
mod items;
mod metadata;
mod query;

pub use metadata::OPENAPI_3_0;

use std::sync::Arc;

use axum::extract::FromRequestParts;
use axum::http::HeaderMap;
use axum::http::request::Parts;
use axum::response::Response;
use rayon::prelude::*;
use serde_json::json;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::{self, Work};
use cloudscape_core::density::{self, CLOUD_THRESHOLD, Cell, Grid, Region, column_stats};
use cloudscape_core::weather::column_rate;
use cloudscape_core::world::{Layer, SnappedTime};

use crate::annotations::{ColumnLevel, ColumnsBbox, ComputedResponses, LayerName, NotModified, WorldName};
use crate::error::ApiError;
use crate::extract::{PointLayers, WorldPath, WorldQuery, layer};
use crate::key::{CacheKey, ResolvedWorld};
use crate::lightning::StrikeQuery;
use crate::params::Params;
use crate::public_url::PublicBase;
use crate::queries::json_bytes;
use crate::respond::{Cached, Freshness};
use crate::state::AppState;

use self::covjson::{Axes, Axis, Coverage, MEDIA_TYPE, Values};
use self::items::Page;
use self::query::{
    Datetime, Footprint, Quantity, check_format, check_query, known, parse_datetime, parse_disc, parse_levels,
    parse_point, parse_polygon, parse_quantities,
};

/// `f=` values of the metadata routes and of the queries.
const JSON: &[&str] = &["json"];
const COVERAGE: &[&str] = &["CoverageJSON", "covjson", "json"];
const GEOJSON: &[&str] = &["GeoJSON", "json"];

/// Bytes a value takes in a CoverageJSON answer, on average (for the size check
/// before any work; the exact size is checked again when the bytes exist).
const BYTES_PER_VALUE: u64 = 12;

/// `f=` of the metadata routes.
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
#[allow(
    dead_code,
    reason = "documentation: utoipa reads the field, the handlers take `MetadataRequest`"
)]
struct JsonFormat {
    /// Format: json (the only one)
    f: Option<String>,
}

/// 400 of the metadata routes.
#[derive(utoipa::IntoResponses)]
#[response(
    status = 400,
    description = "f other than json (invalid_parameter), a parameter other than f (unknown_parameter), a malformed query string or Host"
)]
#[allow(
    dead_code,
    reason = "documentation: utoipa reads the body's type, no handler builds it"
)]
struct NotJson(crate::error::ErrorBody);

/// What the `position`, `area` and `cube` queries share: the times, the parameters
/// and the output asked for.
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
#[allow(
    dead_code,
    reason = "documentation: utoipa reads the fields, the handlers read `Params`"
)]
struct CoverageQuery {
    /// ISO 8601 instant (world time t = 1970-01-01T00:00:00Z + t s; plain seconds also accepted) or closed interval a/b stepping by the layer's dt (at most server.max_series steps); open ends refused
    #[param(example = "1970-01-01T00:00:00Z/1970-01-01T00:00:20Z")]
    datetime: String,
    /// Comma list of cloud_cover, density, cloud_base, cloud_top, precipitation_rate (default all)
    #[param(rename = "parameter-name", example = "cloud_cover,density")]
    parameter_name: Option<String>,
    /// The same as parameter-name, in OWSLib's spelling (its query_data sends parameter_names); give one of the two
    #[param(example = "cloud_cover,density")]
    parameter_names: Option<String>,
    /// CoverageJSON (default) or json
    f: Option<String>,
    /// cloudscape-local-metres (the only CRS)
    crs: Option<String>,
}

/// A request to a metadata route (landing page, conformance, collections): its query
/// parsed, its parameters checked (`f` only, json only), and the absolute URL its
/// links start with.
pub struct MetadataRequest {
    s: Arc<AppState>,
    headers: HeaderMap,
    base: PublicBase,
}

impl FromRequestParts<Arc<AppState>> for MetadataRequest {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, s: &Arc<AppState>) -> Result<Self, ApiError> {
        let params = Params::from_request_parts(parts, s).await?;
        params.check_known(known::METADATA)?;
        check_format(&params, JSON)?;
        Ok(MetadataRequest {
            s: Arc::clone(s),
            headers: parts.headers.clone(),
            base: PublicBase::of(s, &parts.uri, &parts.headers)?,
        })
    }
}

impl MetadataRequest {
    /// The metadata document, cached as `server.cache_control_other` says (private
    /// when its links name the request's Host).
    fn answer(&self, document: &serde_json::Value) -> Result<Response, ApiError> {
        self.base
            .json_response(&self.headers, &self.s.settings.cache_control_other, document)
    }
}

/// The EDR landing page.
#[utoipa::path(
    get,
    path = "/v1/edr",
    tag = "edr",
    params(JsonFormat),
    responses(
        (status = 200, content_type = "application/json", body = Object, description = "The EDR landing page: title and absolute links to itself, the conformance declaration, the collections and the OpenAPI document (service-desc: /v1/edr/api as OpenAPI 3.0, /openapi.json as OpenAPI 3.1); from server.public_url, else from the request's Host (then Cache-Control: private)"),
        NotJson,
        NotModified,
    )
)]
pub async fn landing(request: MetadataRequest) -> Result<Response, ApiError> {
    request.answer(&metadata::landing(&request.base.url))
}

/// The EDR landing page, at the URL OWSLib forms.
///
/// OWSLib's clients add a slash to the URL they are given and ask for it.
#[utoipa::path(
    get,
    path = "/v1/edr/",
    tag = "edr",
    operation_id = "landing_slash",
    params(JsonFormat),
    responses(
        (status = 200, content_type = "application/json", body = Object, description = "The same document as /v1/edr"),
        NotJson,
        NotModified,
    )
)]
pub async fn landing_slash(request: MetadataRequest) -> Result<Response, ApiError> {
    landing(request).await
}

/// The EDR conformance declaration.
#[utoipa::path(
    get,
    path = "/v1/edr/conformance",
    tag = "edr",
    params(JsonFormat),
    responses(
        (status = 200, content_type = "application/json", body = Object, description = "conformsTo: OGC API – Common core and collections; EDR core, collections, queries, json and covjson"),
        NotJson,
        NotModified,
    )
)]
pub async fn conformance(request: MetadataRequest) -> Result<Response, ApiError> {
    request.answer(&metadata::conformance())
}

/// The EDR collections: one per configured world.
#[utoipa::path(
    get,
    path = "/v1/edr/collections",
    tag = "edr",
    params(JsonFormat),
    responses(
        (status = 200, content_type = "application/json", body = Object, description = "One collection per configured world (id = the world's name); a decimal u64 seed also names a collection, unlisted"),
        NotJson,
        NotModified,
    )
)]
pub async fn collections(request: MetadataRequest) -> Result<Response, ApiError> {
    let base = &request.base.url;
    let worlds = request.s.worlds.config().worlds.values();
    let collections: Vec<_> = worlds.map(|w| metadata::collection(w, base)).collect();
    request.answer(&json!({
        "links": [{
            "href": format!("{base}/v1/edr/collections"),
            "rel": "self",
            "type": "application/json",
            "title": "The collections",
        }],
        "collections": collections,
    }))
}

/// One world's EDR collection.
#[utoipa::path(
    get,
    path = "/v1/edr/collections/{world}",
    tag = "edr",
    params(WorldName, JsonFormat),
    responses(
        (status = 200, content_type = "application/json", body = Object, description = "The world's collection: extent (spatial in world metres, temporal from 1970-01-01T00:00:00Z = world time 0 with its steps as repeating intervals, vertical = the layer bands and level centres, as strings), a data link and a data_queries entry per query (position, radius, area, cube, items), parameter_names (EDR parameter objects, plain-string labels), crs, output_formats, distanceunits; absolute links as the landing page's"),
        (status = 400, body = crate::error::ErrorBody, description = "Malformed path, query or Host, f other than json (invalid_parameter) or a parameter other than f (unknown_parameter)"),
        (status = 404, body = crate::error::ErrorBody, description = "Unknown world"),
        NotModified,
    )
)]
pub async fn collection(request: MetadataRequest, WorldPath(resolved): WorldPath) -> Result<Response, ApiError> {
    request.answer(&metadata::collection(&resolved.world, &request.base.url))
}

/// A CoverageJSON answer over the frames of its time axis: with the time headers of
/// its frame when there is one, final when every frame is exactly a time asked.
fn coverage_cached(key: CacheKey, axis: &[SnappedTime], exact: bool) -> Cached {
    Cached {
        kind: "edr",
        key,
        content_type: MEDIA_TYPE,
        time: (axis.len() == 1).then(|| axis[0].into()),
        freshness: Freshness::of_frames(exact),
        content_location: None,
    }
}

fn join<T: ToString>(items: impl IntoIterator<Item = T>) -> String {
    items.into_iter().map(|i| i.to_string()).collect::<Vec<_>>().join(",")
}

/// The 413 for an answer whose estimated size is over `limits.max_response_bytes`,
/// before any work.
fn check_answer_size(s: &AppState, values: u64) -> Result<(), ApiError> {
    let max = s.worlds.config().limits.max_response_bytes;
    let bytes = values.saturating_mul(BYTES_PER_VALUE);
    if bytes > max {
        return Err(ApiError::ResponseTooLarge(format!(
            "the answer would hold {values} values, about {} MiB; the limit is {} MiB (limits.max_response_bytes): \
             ask for fewer parameters, times or columns, or a higher level",
            bytes >> 20,
            max >> 20
        )));
    }
    Ok(())
}

/// EDR position query: the values at a point.
///
/// 400: Malformed coords, datetime (or an open interval), parameter-name, f or crs; a
/// parameter the query does not read (unknown_parameter). 413:
/// More time steps than server.max_series, or over the work limits. 422: datetime or
/// coordinates out of range.
#[utoipa::path(
    get,
    path = "/v1/edr/collections/{world}/position",
    tag = "edr",
    params(
        WorldName,
        ("coords" = String, Query, description = "WKT POINT(x y) in world metres (x east, y north)", example = "POINT(150 150)"),
        ("z" = Option<f64>, Query, description = "Altitude above sea level, metres (default 0)", example = 1050),
        ("layer" = Option<String>, Query, description = "Layer name (default: the layer holding z for density, every layer above z for the rest, as /sample)"),
        CoverageQuery,
    ),
    responses(
        (status = 200, content_type = "application/prs.coverage+json", body = Object, description = "A CoverageJSON Coverage: domainType Point for an instant, PointSeries for an interval; density and precipitation_rate equal /sample's at the same point and time"),
        ComputedResponses,
    )
)]
pub async fn position(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    check_query(&params, &[known::POSITION, known::COVERAGE], COVERAGE)?;
    let [x, y] = parse_point(params.required("coords")?)?;
    let z = params.f64("z")?.unwrap_or(0.0);
    let datetime = parse_datetime(&params)?;
    let quantities = parse_quantities(&params, &Quantity::ALL)?;
    let world = &resolved.world;
    // The layers of /sample: the one holding z (its cell's density), and those whose
    // column is above the point.
    let layers = PointLayers::at(world, params.get("layer"), z)?;
    let primary = layers.primary().unwrap_or(0);
    let PointLayers { holding: chosen, above } = layers;
    let times = datetime.times(world.layers[primary].dt, s.settings.max_series)?;
    let limits = &s.worlds.config().limits;
    let columns = above
        .iter()
        .map(|&i| {
            let l = &world.layers[i];
            let c = Cell::at(l, x, y, z)?;
            c.region().check(0, l.depth, limits)?;
            Ok((i, c))
        })
        .collect::<Result<Vec<(usize, Cell)>, ApiError>>()?;
    let cell = Cell::at(&world.layers[primary], x, y, z)?;
    let fps = s.settings.frames_per_step;
    let axis: Vec<SnappedTime> = times
        .iter()
        .map(|&t| SnappedTime::snap(t, &world.layers[primary], fps))
        .collect();
    // frames[time][column]
    let frames: Vec<Vec<SnappedTime>> = times
        .iter()
        .map(|&t| {
            columns
                .iter()
                .map(|(i, _)| SnappedTime::snap(t, &world.layers[*i], fps))
                .collect()
        })
        .collect();
    check_answer_size(&s, (times.len() * quantities.len()) as u64)?;
    let exact = times.iter().zip(&axis).all(|(&t, f)| f.is_exact(t))
        && times
            .iter()
            .zip(&frames)
            .all(|(&t, fs)| fs.iter().all(|f| f.is_exact(t)));
    let key = CacheKey::new("edr-position", &resolved, primary)
        .with("p", format!("{x},{y},{z}"))
        .with("in", chosen.map_or(-1, |i| i as i64))
        .with("above", join(&above))
        .with("q", join(quantities.iter().map(|q| q.name())))
        .with("i", datetime.interval)
        .with("t", join(&times));
    let cached = coverage_cached(key, &axis, exact);
    let world = resolved.world;
    cached
        .respond(&s, &headers, move || {
            let mut work = Work::default();
            for fs in &frames {
                for (f, (i, c)) in fs.iter().zip(&columns) {
                    let w = cost::density(&world, *i, 0, c.region(), f.t)?;
                    work.cpu_s += w.cpu_s;
                    work.bytes = work.bytes.saturating_add(w.bytes);
                }
            }
            Ok((work, move |cancel: &Cancel| {
                let at: Vec<PositionValues> = frames
                    .par_iter()
                    .map(|fs| position_values(&world, &columns, fs, chosen.map(|_| cell.k), primary, cancel))
                    .collect::<Result<_, ApiError>>()?;
                let ranges = quantities
                    .iter()
                    .map(|&q| (q, PositionValues::series(&at, q)))
                    .collect();
                let axes = Axes {
                    x: Axis::Numbers { values: vec![x] },
                    y: Axis::Numbers { values: vec![y] },
                    z: Some(Axis::Numbers { values: vec![z] }),
                    t: Axis::times(&axis.iter().map(|f| f.t).collect::<Vec<_>>()),
                };
                let coverage = if datetime.interval {
                    Coverage::new("PointSeries", axes, vec!["t"], vec![at.len()], ranges)
                } else {
                    Coverage::new("Point", axes, vec![], vec![], ranges)
                };
                json_bytes(&coverage)
            }))
        })
        .await
}

/// A position's values at one time.
struct PositionValues {
    density: f32,
    covered: bool,
    cloud_base: Option<f64>,
    cloud_top: Option<f64>,
    rate: f64,
}

impl PositionValues {
    fn series(at: &[PositionValues], q: Quantity) -> Values {
        match q {
            Quantity::Density => Values::F32(at.iter().map(|v| Some(v.density)).collect()),
            _ => Values::F64(
                at.iter()
                    .map(|v| match q {
                        Quantity::CloudCover => Some(if v.covered { 1.0 } else { 0.0 }),
                        Quantity::CloudBase => v.cloud_base,
                        Quantity::CloudTop => v.cloud_top,
                        _ => Some(v.rate),
                    })
                    .collect(),
            ),
        }
    }
}

/// The values at one time from the columns above the point (each layer at its own
/// frame), computed as `/sample` computes them; `k` is the level of the point's cell
/// in `primary` when the point is in a layer.
fn position_values(
    world: &cloudscape_core::world::World,
    columns: &[(usize, Cell)],
    frames: &[SnappedTime],
    k: Option<usize>,
    primary: usize,
    cancel: &Cancel,
) -> Result<PositionValues, ApiError> {
    let mut v = PositionValues {
        density: 0.0,
        covered: false,
        cloud_base: None,
        cloud_top: None,
        rate: 0.0,
    };
    // Layer by layer in configuration order, as /sample sums its rate.
    for ((i, c), f) in columns.iter().zip(frames) {
        let layer = &world.layers[*i];
        let grid = density::density_cancellable(world, *i, 0, c.region(), f.t, cancel)?;
        if *i == primary
            && let Some(k) = k
        {
            v.density = grid.get(k, 0, 0);
        }
        let column = column_stats(&grid, layer, 0, 0);
        v.covered |= column.covered;
        v.cloud_base = min_option(v.cloud_base, column.cloud_base);
        v.cloud_top = max_option(v.cloud_top, column.cloud_top);
        v.rate += column_rate(layer, &grid, 0, 0);
    }
    Ok(v)
}

fn min_option(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        _ => a.or(b),
    }
}

fn max_option(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.max(b)),
        _ => a.or(b),
    }
}

/// An `area` or `cube` asked: the columns of one layer at one level over times.
struct GridQuery {
    kind: &'static str,
    resolved: ResolvedWorld,
    layer: usize,
    level: u32,
    region: Region,
    /// The area's polygon or the radius' disc: columns whose centres lie outside it
    /// are null.
    footprint: Option<Footprint>,
    /// The cube's vertical levels: values per cell of these levels.
    levels: Option<Vec<usize>>,
    quantities: Vec<Quantity>,
    times: Vec<f64>,
}

/// The common part of a grid query's parameters: layer, level, datetime.
fn grid_times(s: &AppState, params: &Params, layer: &Layer) -> Result<(Datetime, Vec<f64>, u32), ApiError> {
    let datetime = parse_datetime(params)?;
    let times = datetime.times(layer.dt, s.settings.max_series)?;
    let level = params.level(s.worlds.config().limits.max_level)?;
    Ok((datetime, times, level))
}

/// EDR area query: the columns inside a polygon.
///
/// 400: Malformed coords (WKT), datetime (or an open interval), parameter-name, f or crs;
/// a parameter the query does not read (unknown_parameter). 413: Polygon, time steps or answer over the limits. 422: datetime, level or
/// coordinates out of range; no column centre inside.
#[utoipa::path(
    get,
    path = "/v1/edr/collections/{world}/area",
    tag = "edr",
    params(
        WorldName,
        ("coords" = String, Query, description = "WKT POLYGON((x y, …), (hole …)) in world metres, at most 256 vertices; the columns whose centres lie inside (its bbox is limit-checked like /region's)", example = "POLYGON((0 0, 1000 0, 1000 1000, 0 1000, 0 0))"),
        LayerName,
        ColumnLevel,
        CoverageQuery,
    ),
    responses(
        (status = 200, content_type = "application/prs.coverage+json", body = Object, description = "A CoverageJSON Coverage, domainType Grid over t, y, x (column centres); values per column, null outside the polygon; their means are /region's coverage, mean_density and mean_precipitation_mm_h"),
        ComputedResponses,
    )
)]
pub async fn area(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    check_query(&params, &[known::AREA, known::COVERAGE], COVERAGE)?;
    let polygon = Footprint::Polygon(parse_polygon(params.required("coords")?)?);
    footprint_coverage(&s, &headers, &params, "edr-area", polygon, resolved).await
}

/// EDR radius query: the columns within a distance of a point.
///
/// 400: Malformed coords (WKT POINT), within, within-units, datetime (or an open
/// interval), parameter-name, f or crs; a parameter the query does not read
/// (unknown_parameter). 413: The disc's bbox, time steps or answer over the limits.
/// 422: datetime, level or coordinates out of range; no column centre in the disc's
/// bbox.
#[utoipa::path(
    get,
    path = "/v1/edr/collections/{world}/radius",
    tag = "edr",
    params(
        WorldName,
        ("coords" = String, Query, description = "WKT POINT(x y) in world metres, the disc's centre", example = "POINT(1500 1500)"),
        ("within" = f64, Query, description = "The disc's radius in within-units, over 0 and at most 1e7 m; the columns whose centres lie within it (its bbox is limit-checked like /region's)", example = 800),
        ("within-units" = Option<String>, Query, description = "m (default: OWSLib sends none) or km", example = "m"),
        LayerName,
        ColumnLevel,
        CoverageQuery,
    ),
    responses(
        (status = 200, content_type = "application/prs.coverage+json", body = Object, description = "A CoverageJSON Coverage, domainType Grid over t, y, x (the column centres of the disc's bbox); values per column as the area query's, null outside the disc"),
        ComputedResponses,
    )
)]
pub async fn radius(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    check_query(&params, &[known::RADIUS, known::COVERAGE], COVERAGE)?;
    let disc = Footprint::Disc(parse_disc(&params)?);
    footprint_coverage(&s, &headers, &params, "edr-radius", disc, resolved).await
}

/// An area or radius query: the columns of one layer whose centres lie inside
/// `footprint`, over the times asked.
async fn footprint_coverage(
    s: &Arc<AppState>,
    headers: &HeaderMap,
    params: &Params,
    kind: &'static str,
    footprint: Footprint,
    resolved: ResolvedWorld,
) -> Result<Response, ApiError> {
    let (layer_index, layer) = layer(&resolved.world, params.get("layer"))?;
    let quantities = parse_quantities(params, &Quantity::ALL)?;
    let (_, times, level) = grid_times(s, params, layer)?;
    let region = Region::from_bbox(layer, level, footprint.bbox(), &s.worlds.config().limits)?;
    let query = GridQuery {
        kind,
        layer: layer_index,
        level,
        region,
        footprint: Some(footprint),
        levels: None,
        quantities,
        times,
        resolved,
    };
    grid_coverage(s, headers, query).await
}

/// EDR cube query: the columns, or the cells of some levels, inside a bbox.
///
/// 400: Malformed or inverted bbox, z, datetime (or an open interval), parameter-name, f
/// or crs; a parameter the query does not read (unknown_parameter). 413: bbox, time steps or answer over the limits. 422: datetime, level or
/// coordinates out of range; empty region.
#[utoipa::path(
    get,
    path = "/v1/edr/collections/{world}/cube",
    tag = "edr",
    params(
        WorldName,
        ColumnsBbox,
        ("z" = Option<String>, Query, description = "Vertical levels: an interval a/b (levels centred within it) or a list a,b (the levels holding each altitude); absent: whole columns. With z, parameter-name may name only density and cloud_cover (per cell)", example = "1000/1200"),
        LayerName,
        ColumnLevel,
        CoverageQuery,
    ),
    responses(
        (status = 200, content_type = "application/prs.coverage+json", body = Object, description = "A CoverageJSON Coverage, domainType Grid over t, y, x (and z with z levels): per column as area, or per cell of the selected levels; one time step per layer dt, each equal to the /series point of that time"),
        ComputedResponses,
    )
)]
pub async fn cube(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    check_query(&params, &[known::CUBE, known::COVERAGE], COVERAGE)?;
    let bbox = params.bbox()?;
    let (layer_index, layer) = layer(&resolved.world, params.get("layer"))?;
    let levels = parse_levels(&params, layer)?;
    let per_cell: Vec<Quantity> = Quantity::ALL.into_iter().filter(|q| q.per_cell()).collect();
    let quantities = parse_quantities(&params, if levels.is_some() { &per_cell } else { &Quantity::ALL })?;
    if levels.is_some()
        && let Some(q) = quantities.iter().find(|q| !q.per_cell())
    {
        return Err(ApiError::InvalidParameter {
            name: "parameter-name".into(),
            message: format!(
                "`{}` is a per-column parameter; with z only density and cloud_cover (per cell) are answered",
                q.name()
            ),
        });
    }
    let (_, times, level) = grid_times(&s, &params, layer)?;
    let region = Region::from_bbox(layer, level, bbox, &s.worlds.config().limits)?;
    let query = GridQuery {
        kind: "edr-cube",
        layer: layer_index,
        level,
        region,
        footprint: None,
        levels,
        quantities,
        times,
        resolved,
    };
    grid_coverage(&s, &headers, query).await
}

/// EDR items query: the lightning strikes in a box and span, as GeoJSON.
///
/// 400: Malformed or inverted bbox, datetime (or not an interval with its end after its
/// start), limit, offset, f or crs; a parameter the query does not read
/// (unknown_parameter). 413: Span over 3600 s or bbox side over 50 km (checked before
/// any work). 422: datetime or coordinates out of range.
#[utoipa::path(
    get,
    path = "/v1/edr/collections/{world}/items",
    tag = "edr",
    params(
        WorldName,
        ("bbox" = String, Query, description = "X0,Y0,X1,Y1 in metres, X0 < X1, Y0 < Y1, each side at most 50 km; strikes with x0 <= x < x1, y0 <= y < y1", example = "-10000,20000,10000,40000"),
        ("datetime" = String, Query, description = "An interval a/b (ISO 8601 instants or world seconds), b after a and at most 3600 s later; strikes with a <= t < b", example = "1970-01-01T00:00:00Z/1970-01-01T00:10:00Z"),
        ("limit" = Option<u32>, Query, description = "Features on the page, 1 to 10000 (default 10000)", minimum = 1, maximum = 10000),
        ("offset" = Option<u64>, Query, description = "Strikes skipped before the page (default 0)"),
        ("layer" = Option<String>, Query, description = "Layer name (default: every layer whose preset has lightning)"),
        ("f" = Option<String>, Query, description = "GeoJSON (default) or json"),
        ("crs" = Option<String>, Query, description = "cloudscape-local-metres (the only CRS)"),
    ),
    responses(
        (status = 200, content_type = "application/geo+json", body = Object, description = "A GeoJSON FeatureCollection of Point features [x, y, z] in world metres (not WGS 84), by time, properties datetime, t (seconds), kind (cg | ic) and layer: /lightning's strikes; numberMatched, numberReturned and a next link (relative) when a page follows"),
        ComputedResponses,
    )
)]
pub async fn items(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    check_query(&params, &[known::ITEMS], GEOJSON)?;
    let bbox = params.bbox()?;
    let datetime = parse_datetime(&params)?;
    if !(datetime.interval && datetime.t1 > datetime.t0) {
        return Err(ApiError::InvalidParameter {
            name: "datetime".into(),
            message: "the items query lists the strikes of an interval start/end, its end after its start".into(),
        });
    }
    let page = Page::parse(&params)?;
    let query = StrikeQuery::new(&resolved.world, params.get("layer"), bbox, datetime.t0, datetime.t1)?;
    let key = query
        .key("edr-items", &resolved)
        .with("page", format!("{},{}", page.limit, page.offset));
    let cached = Cached::timeless("edr", key, items::MEDIA_TYPE);
    let world = resolved.world;
    cached
        .respond(&s, &headers, move || {
            Ok((query.work(&world)?, move |cancel: &Cancel| {
                let strikes = query.strikes(&world, cancel)?;
                items::feature_collection(&world, &strikes, page, |offset| {
                    format!("items?{}", params.query_with("offset", &offset.to_string()))
                })
            }))
        })
        .await
}

/// Answers a grid query through the cache: one density grid per frame.
async fn grid_coverage(s: &Arc<AppState>, headers: &HeaderMap, q: GridQuery) -> Result<Response, ApiError> {
    let layer = &q.resolved.world.layers[q.layer];
    let frames: Vec<SnappedTime> = q
        .times
        .iter()
        .map(|&t| SnappedTime::snap(t, layer, s.settings.frames_per_step))
        .collect();
    let r = q.region;
    let cells_per_frame = r.cols as u64 * r.rows as u64 * q.levels.as_ref().map_or(1, |l| l.len() as u64);
    let values = cells_per_frame * frames.len() as u64 * q.quantities.len() as u64;
    check_answer_size(s, values)?;
    let mut key = CacheKey::new(q.kind, &q.resolved, q.layer)
        .with_region(q.level, r)
        .with("q", join(q.quantities.iter().map(|q| q.name())))
        .with("t", join(&q.times));
    if let Some(f) = &q.footprint {
        let (name, value) = f.key();
        key = key.with(name, value);
    }
    if let Some(levels) = &q.levels {
        key = key.with("k", join(levels));
    }
    let exact = frames.iter().zip(&q.times).all(|(f, &t)| f.is_exact(t));
    let cached = coverage_cached(key, &frames, exact);
    cached
        .respond(s, headers, move || {
            let world = &q.resolved.world;
            let mut work = Work::default();
            for f in &frames {
                let w = cost::density(world, q.layer, q.level, r, f.t)?;
                work.cpu_s += w.cpu_s;
                work.bytes = work.bytes.max(w.bytes);
            }
            // At most one grid per compute thread at once, and the values.
            work.bytes = work
                .bytes
                .saturating_mul(frames.len().min(rayon::current_num_threads().max(1)) as u64)
                .saturating_add(values.saturating_mul(16));
            if let Some(f) = &q.footprint {
                work.cpu_s += (r.cols * r.rows) as f64 * f.cost_per_column();
            }
            Ok((work, move |cancel: &Cancel| grid_answer(&q, &frames, cancel)))
        })
        .await
}

/// The CoverageJSON of a grid query.
fn grid_answer(q: &GridQuery, frames: &[SnappedTime], cancel: &Cancel) -> Result<axum::body::Bytes, ApiError> {
    let world = &q.resolved.world;
    let layer = &world.layers[q.layer];
    let r = q.region;
    let w = layer.cell_size * (q.level as f64).exp2();
    let inside: Option<Vec<bool>> = q.footprint.as_ref().map(|p| {
        (0..r.rows)
            .flat_map(|row| (0..r.cols).map(move |col| (row, col)))
            .map(|(row, col)| {
                p.contains(
                    (r.x0 as f64 + col as f64 + 0.5) * w,
                    (r.y0 as f64 + row as f64 + 0.5) * w,
                )
            })
            .collect()
    });
    let per_frame: Vec<Vec<Values>> = frames
        .par_iter()
        .map(|f| {
            let grid = density::density_cancellable(world, q.layer, q.level, r, f.t, cancel)?;
            Ok(q.quantities
                .iter()
                .map(|&quantity| frame_values(&grid, layer, quantity, q.levels.as_deref(), inside.as_deref()))
                .collect())
        })
        .collect::<Result<_, ApiError>>()?;
    let ranges = q
        .quantities
        .iter()
        .enumerate()
        .map(|(i, &quantity)| (quantity, concat(per_frame.iter().map(|f| &f[i]))))
        .collect();
    let (axis_names, shape, z) = match &q.levels {
        Some(levels) => (
            vec!["t", "z", "y", "x"],
            vec![frames.len(), levels.len(), r.rows, r.cols],
            Some(Axis::Numbers {
                values: levels
                    .iter()
                    .map(|&k| layer.base + (k as f64 + 0.5) * layer.cell_height)
                    .collect(),
            }),
        ),
        None => (vec!["t", "y", "x"], vec![frames.len(), r.rows, r.cols], None),
    };
    let axes = Axes {
        x: Axis::columns(r.x0, r.cols, w),
        y: Axis::columns(r.y0, r.rows, w),
        z,
        t: Axis::times(&frames.iter().map(|f| f.t).collect::<Vec<_>>()),
    };
    json_bytes(&Coverage::new("Grid", axes, axis_names, shape, ranges))
}

/// One quantity of one frame, row-major over (levels,) rows, columns; `None`
/// outside the footprint.
fn frame_values(
    grid: &Grid<f32>,
    layer: &Layer,
    q: Quantity,
    levels: Option<&[usize]>,
    inside: Option<&[bool]>,
) -> Values {
    let columns = grid.rows * grid.cols;
    let kept = |i: usize| inside.is_none_or(|m| m[i]);
    if let Some(levels) = levels {
        let cells = levels.iter().flat_map(|&k| (0..columns).map(move |i| (k, i)));
        return match q {
            Quantity::Density => Values::F32(
                cells
                    .map(|(k, i)| kept(i).then(|| grid.get(k, i / grid.cols, i % grid.cols)))
                    .collect(),
            ),
            _ => Values::F64(
                cells
                    .map(|(k, i)| {
                        kept(i)
                            .then(|| f64::from(u8::from(grid.get(k, i / grid.cols, i % grid.cols) >= CLOUD_THRESHOLD)))
                    })
                    .collect(),
            ),
        };
    }
    Values::F64(
        (0..columns)
            .map(|i| {
                if !kept(i) {
                    return None;
                }
                let (row, col) = (i / grid.cols, i % grid.cols);
                let c = column_stats(grid, layer, row, col);
                match q {
                    Quantity::CloudCover => Some(f64::from(u8::from(c.covered))),
                    Quantity::Density => Some(c.mean_density),
                    Quantity::CloudBase => c.cloud_base,
                    Quantity::CloudTop => c.cloud_top,
                    Quantity::PrecipitationRate => Some(column_rate(layer, grid, row, col)),
                }
            })
            .collect(),
    )
}

/// The frames' values of one quantity, one after the other.
fn concat<'a>(parts: impl Iterator<Item = &'a Values>) -> Values {
    let mut parts = parts.peekable();
    match parts.peek() {
        Some(Values::F32(_)) => Values::F32(
            parts
                .flat_map(|p| match p {
                    Values::F32(v) => v.clone(),
                    Values::F64(_) => Vec::new(),
                })
                .collect(),
        ),
        _ => Values::F64(
            parts
                .flat_map(|p| match p {
                    Values::F64(v) => v.clone(),
                    Values::F32(_) => Vec::new(),
                })
                .collect(),
        ),
    }
}
