//! The EDR metadata documents: landing page, conformance declaration and one
//! collection per world, in the forms the EDR standard gives (and edr-pydantic
//! checks): plain-string labels and descriptions in `parameter_names` (CoverageJSON's
//! parameters have internationalised ones), vertical values as strings, the temporal
//! values as ISO 8601 repeating intervals, no members of our own. Links are absolute
//! (`base`, [`crate::public_url`]). `serde_json` objects keep their keys sorted, so
//! the bytes are fixed for a config and a base.

use serde_json::{Value, json};

use cloudscape_core::density::MAX_CELL_INDEX;
use cloudscape_core::world::World;

use super::covjson::{self, UCUM};
use super::query::{CRS_NAME, MAX_EDR_TIME, Quantity, distance_units, format_instant};
use crate::public_url::encode_segment;

/// The media type of the OpenAPI document as OpenAPI 3.0 (`/v1/edr/api`), as OGC API –
/// Common names it for the `service-desc` link.
pub const OPENAPI_3_0: &str = "application/vnd.oai.openapi+json;version=3.0";
/// The media type of the OpenAPI document as OpenAPI 3.1 (`/openapi.json`).
pub const OPENAPI_3_1: &str = "application/vnd.oai.openapi+json;version=3.1";

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
/// collections, queries (position, radius, area, cube and items; see each
/// collection's `data_queries`), JSON and CoverageJSON. EDR defines no class per
/// query type. (The items answer GeoJSON; the EDR GeoJSON class, which is about the
/// other queries' answers, is not claimed.)
pub const CONFORMS_TO: [&str; 7] = [
    "http://www.opengis.net/spec/ogcapi-common-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-common-2/1.0/conf/collections",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/collections",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/queries",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/json",
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/covjson",
];

fn link(href: String, rel: &str, media: &str, title: &str) -> Value {
    json!({ "href": href, "rel": rel, "type": media, "title": title })
}

/// The landing page. OGC clients find the API definition by the `service-desc` link
/// of their OpenAPI version (OWSLib: `application/vnd.oai.openapi+json;version=3.0`):
/// there is one of each.
pub fn landing(base: &str) -> Value {
    json!({
        "title": "cloudscape: OGC API – Environmental Data Retrieval",
        "description": "Cloud cover, density, cloud base and top and precipitation rate of every world, by \
            position, radius, area and cube queries answered as CoverageJSON, and lightning strikes by the \
            items query as GeoJSON. World time t = 0 is 1970-01-01T00:00:00Z; coordinates are world metres \
            (x east, y north).",
        "links": [
            link(format!("{base}/v1/edr"), "self", "application/json", "This document"),
            link(format!("{base}/v1/edr/conformance"), "conformance", "application/json", "Conformance classes"),
            link(format!("{base}/v1/edr/collections"), "data", "application/json", "One collection per world"),
            link(format!("{base}/v1/edr/api"), "service-desc", OPENAPI_3_0, "The OpenAPI document, as OpenAPI 3.0"),
            link(format!("{base}/openapi.json"), "service-desc", OPENAPI_3_1, "The OpenAPI document, as OpenAPI 3.1"),
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

/// The times a world's answers step by: one ISO 8601 repeating interval per distinct
/// layer `dt`, from world time 0 to the last EDR instant.
fn time_steps(world: &World) -> Vec<String> {
    let mut dts: Vec<f64> = world.layers.iter().map(|l| l.dt).collect();
    dts.sort_by(f64::total_cmp);
    dts.dedup();
    dts.iter()
        .map(|dt| {
            let steps = (MAX_EDR_TIME / dt).floor() as u64 + 1;
            format!("R{steps}/{}/PT{dt}S", format_instant(0.0))
        })
        .collect()
}

/// A quantity's entry in `parameter_names`: EDR's parameter object, whose label and
/// description are strings.
fn parameter_name(q: Quantity) -> Value {
    let t = covjson::text(q);
    let mut observed = json!({ "label": t.label });
    if let Some(id) = t.id {
        observed["id"] = json!(id);
    }
    json!({
        "type": "Parameter",
        "id": q.name(),
        "label": t.label,
        "description": t.description,
        "data-type": "float",
        "unit": { "label": t.unit, "symbol": { "value": t.symbol, "type": UCUM } },
        "observedProperty": observed,
    })
}

/// A query of a collection: what its `data_queries` entry says.
struct Query {
    kind: &'static str,
    /// The query string of the link's template.
    template: &'static str,
    description: &'static str,
    coords: &'static str,
    format: &'static str,
}

/// CoverageJSON's name and media type, and GeoJSON's (the items).
const COVERAGE_JSON: (&str, &str) = ("CoverageJSON", super::covjson::MEDIA_TYPE);
const GEO_JSON: (&str, &str) = ("GeoJSON", super::items::MEDIA_TYPE);

const QUERIES: [Query; 5] = [
    Query {
        kind: "position",
        template: "coords=POINT({x} {y})&z={z}&datetime={datetime}",
        description: "The cell at (x, y, z) and the column above it (every layer whose top is above z, or \
            `layer`), as /sample answers them; z defaults to 0 (sea level).",
        coords: "WKT POINT(x y), world metres",
        format: COVERAGE_JSON.0,
    },
    Query {
        kind: "radius",
        template: "coords=POINT({x} {y})&within={within}&within-units=m&datetime={datetime}",
        description: "The columns of one layer (`layer`, default the first) at `level` whose centres lie within \
            `within` of the point (within-units m or km, default m); the others of the disc's bbox are null.",
        coords: "WKT POINT(x y), world metres",
        format: COVERAGE_JSON.0,
    },
    Query {
        kind: "area",
        template: "coords=POLYGON(({x0} {y0},{x1} {y0},{x1} {y1},{x0} {y1}))&datetime={datetime}",
        description: "The columns of one layer (`layer`, default the first) at `level` whose centres lie inside \
            the polygon; the others are null.",
        coords: "WKT POLYGON((x y, …)), world metres",
        format: COVERAGE_JSON.0,
    },
    Query {
        kind: "cube",
        template: "bbox={x0},{y0},{x1},{y1}&datetime={datetime}",
        description: "The columns of one layer at `level` whose centres lie inside the bbox; with z (a/b or a \
            list of altitudes), density and cloud_cover per cell of the selected levels.",
        coords: "bbox=x0,y0,x1,y1, world metres",
        format: COVERAGE_JSON.0,
    },
    Query {
        kind: "items",
        template: "bbox={x0},{y0},{x1},{y1}&datetime={t0}/{t1}",
        description: "The lightning strikes inside the bbox (each side at most 50 km) from t0 (inclusive) to t1 \
            (exclusive, at most 3600 s later), by time, as GeoJSON Point features in world metres; `limit` \
            (default and most 10000) and `offset` page them.",
        coords: "bbox=x0,y0,x1,y1, world metres",
        format: GEO_JSON.0,
    },
];

impl Query {
    fn media_type(&self) -> &'static str {
        if self.format == GEO_JSON.0 {
            GEO_JSON.1
        } else {
            COVERAGE_JSON.1
        }
    }

    fn data_query(&self, base: &str) -> Value {
        let mut variables = json!({
            "title": format!("{} query", self.kind),
            "description": self.description,
            "query_type": self.kind,
            "coords": self.coords,
            "output_formats": [self.format],
            "default_output_format": self.format,
            "crs_details": [{ "crs": CRS_NAME, "wkt": CRS_WKT }],
        });
        if self.kind == "radius" {
            variables["within_units"] = json!(distance_units());
        }
        json!({
            "link": {
                "href": format!("{base}/{}?{}", self.kind, self.template),
                "rel": "data",
                "type": self.media_type(),
                "templated": true,
                "title": format!("{} query", self.kind),
                "variables": variables,
            }
        })
    }
}

/// The collection of one world: id = the world's name. `base` is the absolute URL
/// the links start with.
pub fn collection(world: &World, base: &str) -> Value {
    let url = format!("{base}/v1/edr/collections/{}", encode_segment(&world.name));
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
        .map(|&q| (q.name().to_string(), parameter_name(q)))
        .collect();
    let mut links = vec![
        link(url.clone(), "self", "application/json", "This collection"),
        link(
            format!("{base}/v1/worlds/{}", encode_segment(&world.name)),
            "describedby",
            "application/json",
            "The world's discovery document: layers, cell sizes, dt",
        ),
    ];
    // A `data` link per query, the links OGC clients look for (OWSLib's data()).
    links.extend(QUERIES.iter().map(|q| {
        link(
            format!("{url}/{}", q.kind),
            "data",
            q.media_type(),
            &format!("{} query ({})", q.kind, q.format),
        )
    }));
    let data_queries: serde_json::Map<String, Value> = QUERIES
        .iter()
        .map(|q| (q.kind.to_string(), q.data_query(&url)))
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
        "links": links,
        "extent": {
            "spatial": { "bbox": [spatial_bbox(world)], "crs": CRS_WKT },
            "temporal": {
                "interval": [[format_instant(0.0), format_instant(MAX_EDR_TIME)]],
                "values": time_steps(world),
                "trs": TEMPORAL_WKT,
            },
            "vertical": {
                "interval": bands,
                "values": centres.iter().map(f64::to_string).collect::<Vec<_>>(),
                "vrs": VERTICAL_WKT,
            },
        },
        "data_queries": data_queries,
        "crs": [CRS_NAME],
        "output_formats": [COVERAGE_JSON.0, GEO_JSON.0],
        "distanceunits": distance_units(),
        "parameter_names": parameters,
    })
}
