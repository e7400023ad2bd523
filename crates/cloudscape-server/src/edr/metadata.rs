//! The EDR metadata documents: landing page, conformance declaration and one
//! collection per world. `serde_json` objects keep their keys sorted, so the bytes are
//! fixed for a config.

use serde_json::{Value, json};

use cloudscape_core::density::MAX_CELL_INDEX;
use cloudscape_core::world::World;

use super::covjson::parameter;
use super::query::{CRS_NAME, MAX_EDR_TIME, Quantity, format_instant};

/// The world plane as a WKT 2 engineering CRS.
pub const CRS_WKT: &str = "ENGCRS[\"cloudscape world plane\",EDATUM[\"world origin: the corner of tile (z, 0, 0)\"],\
CS[Cartesian,2],AXIS[\"easting (x)\",east,ORDER[1],LENGTHUNIT[\"metre\",1]],\
AXIS[\"northing (y)\",north,ORDER[2],LENGTHUNIT[\"metre\",1]]]";

/// Altitude above sea level.
const VERTICAL_WKT: &str = "VERTCRS[\"altitude above sea level\",VDATUM[\"mean sea level\"],CS[vertical,1],\
AXIS[\"altitude (z)\",up,LENGTHUNIT[\"metre\",1]]]";

/// The world clock: t seconds after the Unix epoch.
const TEMPORAL_WKT: &str = "TIMECRS[\"world clock\",TDATUM[\"Gregorian calendar\",TIMEORIGIN[1970-01-01T00:00:00Z]],\
CS[TemporalDateTime,1],AXIS[\"time (T)\",future]]";

/// What the routes conform to: OGC API – Common core and collections, EDR core,
/// collections, queries (position, area and cube; see each collection's
/// `data_queries`), JSON and CoverageJSON. EDR defines no class per query type.
pub const CONFORMS_TO: [&str; 7] = [
    "http://www.opengis.net/spec/ogcapi-common-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-common-2/1.0/conf/collections",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/collections",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/queries",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/json",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/covjson",
];

fn link(href: &str, rel: &str, media: &str, title: &str) -> Value {
    json!({ "href": href, "rel": rel, "type": media, "title": title })
}

pub fn landing() -> Value {
    json!({
        "title": "cloudscape: OGC API – Environmental Data Retrieval",
        "description": "Cloud cover, density, cloud base and top and precipitation rate of every world, by \
            position, area and cube queries, answered as CoverageJSON. World time t = 0 is \
            1970-01-01T00:00:00Z; coordinates are world metres (x east, y north).",
        "links": [
            link("/v1/edr", "self", "application/json", "This document"),
            link("/v1/edr/conformance", "conformance", "application/json", "Conformance classes"),
            link("/v1/edr/collections", "data", "application/json", "One collection per world"),
            link("/openapi.json", "service-desc", "application/vnd.oai.openapi+json", "The OpenAPI document"),
        ],
    })
}

pub fn conformance() -> Value {
    json!({ "conformsTo": CONFORMS_TO })
}

/// The spatial extent: the union of the layers' extents when every layer has one,
/// else every position the world can address (±2^48 cells of its finest layer).
fn spatial_bbox(world: &World) -> [f64; 4] {
    let extents: Option<Vec<[f64; 4]>> = world.layers.iter().map(|l| l.extent).collect();
    match extents {
        Some(e) if !e.is_empty() => e.iter().fold(
            [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY],
            |b, x| [b[0].min(x[0]), b[1].min(x[1]), b[2].max(x[2]), b[3].max(x[3])],
        ),
        _ => {
            let cell = world.layers.iter().map(|l| l.cell_size).fold(f64::INFINITY, f64::min);
            let r = MAX_CELL_INDEX as f64 * cell;
            [-r, -r, r, r]
        }
    }
}

fn query(base: &str, kind: &str, template: &str, description: &str, coords: &str) -> Value {
    json!({
        "link": {
            "href": format!("{base}/{kind}?{template}"),
            "rel": "data",
            "templated": true,
            "title": format!("{kind} query"),
            "variables": {
                "title": format!("{kind} query"),
                "description": description,
                "query_type": kind,
                "coords": coords,
                "output_formats": ["CoverageJSON"],
                "default_output_format": "CoverageJSON",
                "crs_details": [{ "crs": CRS_NAME, "wkt": CRS_WKT }],
            },
        }
    })
}

/// The collection of one world: id = the world's name.
pub fn collection(world: &World) -> Value {
    let base = format!("/v1/edr/collections/{}", world.name);
    let layers = &world.layers;
    let lowest = layers.iter().map(|l| l.base).fold(f64::INFINITY, f64::min);
    let highest = layers.iter().map(|l| l.top()).fold(f64::NEG_INFINITY, f64::max);
    let mut bands = vec![[lowest.to_string(), highest.to_string()]];
    bands.extend(layers.iter().map(|l| [l.base.to_string(), l.top().to_string()]));
    let mut centres: Vec<f64> = layers
        .iter()
        .flat_map(|l| (0..l.depth).map(|k| l.base + (k as f64 + 0.5) * l.cell_height))
        .collect();
    centres.sort_by(f64::total_cmp);
    let parameters: serde_json::Map<String, Value> = Quantity::ALL
        .iter()
        .map(|&q| (q.name().to_string(), json!(parameter(q))))
        .collect();
    json!({
        "id": world.name,
        "title": format!("cloudscape world {}", world.name),
        "description": format!(
            "Seed {} with {} cloud layer(s): {}. Interval datetimes step by the layer's dt.",
            world.seed,
            layers.len(),
            layers.iter().map(|l| format!("{} ({}–{} m, dt {} s)", l.name, l.base, l.top(), l.dt))
                .collect::<Vec<_>>().join(", ")
        ),
        "links": [
            link(&base, "self", "application/json", "This collection"),
            link(&format!("/v1/worlds/{}", world.name), "describedby", "application/json",
                "The world's discovery document: layers, cell sizes, dt"),
        ],
        "extent": {
            "spatial": { "bbox": [spatial_bbox(world)], "crs": CRS_WKT },
            "temporal": {
                "interval": [[format_instant(0.0), format_instant(MAX_EDR_TIME)]],
                "trs": TEMPORAL_WKT,
            },
            "vertical": { "interval": bands, "values": centres, "vrs": VERTICAL_WKT },
        },
        "layers": layers.iter().map(|l| json!({
            "name": l.name, "base": l.base, "top": l.top(), "cell_size": l.cell_size, "dt": l.dt,
        })).collect::<Vec<_>>(),
        "data_queries": {
            "position": query(&base, "position", "coords=POINT({x} {y})&z={z}&datetime={datetime}",
                "The cell at (x, y, z) and the column above it (every layer whose top is above z, or `layer`), \
                 as /sample answers them; z defaults to 0 (sea level).",
                "WKT POINT(x y), world metres"),
            "area": query(&base, "area", "coords=POLYGON(({x0} {y0},{x1} {y0},{x1} {y1},{x0} {y1}))&datetime={datetime}",
                "The columns of one layer (`layer`, default the first) at `level` whose centres lie inside the \
                 polygon; the others are null.",
                "WKT POLYGON((x y, …)), world metres"),
            "cube": query(&base, "cube", "bbox={x0},{y0},{x1},{y1}&datetime={datetime}",
                "The columns of one layer at `level` whose centres lie inside the bbox; with z (a/b or a list \
                 of altitudes), density and cloud_cover per cell of the selected levels.",
                "bbox=x0,y0,x1,y1, world metres"),
        },
        "crs": [CRS_NAME],
        "output_formats": ["CoverageJSON"],
        "parameter_names": parameters,
    })
}
