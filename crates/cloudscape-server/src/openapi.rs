//! The OpenAPI document, generated from the handlers' annotations (their shared pieces
//! are in [`crate::annotations`]): at `/openapi.json` as OpenAPI 3.1 (what utoipa
//! writes), and at `/v1/edr/api` as OpenAPI 3.0 for the OGC API clients that look for
//! that version (OWSLib's `api()`), the same document in 3.0's words ([`as_3_0`]).
//!
//! Besides the handlers' own answers it says what every route answers before a handler
//! runs: the CORS preflight (an `options` operation on every path) and the refusals of
//! the HTTP layer ([`crate::conn`]). There is no authentication (`security: []`), and
//! the server is the one the document is read from (`servers: [{"url": "/"}]`).

use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use cloudscape_core::density::RegionStats;
use cloudscape_core::weather::PrecipitationStats;
use cloudscape_core::weather::lightning::{Strike, StrikeKind};
use serde_json::json;
use utoipa::OpenApi;

use crate::edr::OPENAPI_3_0;
use crate::extract::TileProduct;
use crate::params::QualityName;
use crate::{discovery, edr, error, lightning, ops, queries, render, tilejson, tiles};

#[derive(OpenApi)]
#[openapi(
    info(
        title = "cloudscape",
        description = "Noise-driven Dobashi cloud simulation for game worlds: tiles, region queries and operator routes. Every error is a JSON object {\"error\": code, \"message\": sentence}. Cross-origin (CORS): every route may be read from another origin (server.cors_origins, any by default) with GET or HEAD, If-None-Match allowed; ETag, Cache-Control, Content-Location, Retry-After, Vary, X-Request-Id and every X-Cloudscape-* header exposed; preflights (OPTIONS) answer 204."
    ),
    paths(
        discovery::list,
        discovery::world,
        tilejson::tilejson,
        tiles::tile,
        tilejson::zoom_tile,
        queries::sample,
        queries::region,
        queries::series,
        lightning::lightning,
        edr::landing,
        edr::landing_slash,
        openapi_3_0,
        edr::conformance,
        edr::collections,
        edr::collection,
        edr::position,
        edr::radius,
        edr::area,
        edr::cube,
        edr::items,
        render::render_png,
        render::splats_png,
        render::splats_json,
        render::sky_json,
        ops::healthz,
        ops::readyz,
        ops::metrics,
        openapi,
    ),
    components(schemas(
        TileProduct,
        QualityName,
        error::ErrorBody,
        RegionStats,
        PrecipitationStats,
        discovery::WorldList,
        discovery::WorldSummary,
        discovery::WorldInfo,
        discovery::LayerInfo,
        tilejson::TileJson,
        tilejson::TileJsonExtra,
        queries::Columns,
        queries::SampleAnswer,
        queries::RegionAnswer,
        queries::SeriesAnswer,
        queries::SeriesPoint,
        lightning::LightningAnswer,
        Strike,
        StrikeKind,
        ops::Status,
    ))
)]
struct ApiDoc;

/// The document (OpenAPI 3.1).
fn document_value() -> serde_json::Value {
    let mut doc = serde_json::to_value(ApiDoc::openapi()).expect("the OpenAPI document serialises");
    doc["security"] = json!([]);
    doc["servers"] = json!([{ "url": "/", "description": "The server this document is read from" }]);
    with_http_refusals(with_preflights(doc))
}

/// The document as JSON text (OpenAPI 3.1).
pub fn document() -> String {
    serde_json::to_string_pretty(&document_value()).expect("the OpenAPI document serialises")
}

/// The document as JSON text in OpenAPI 3.0.
pub fn document_3_0() -> String {
    serde_json::to_string_pretty(&as_3_0(document_value())).expect("the OpenAPI document serialises")
}

/// What the HTTP layer answers on any route before routing ([`crate::conn`]),
/// documented on every GET: an over-long request target (414) or head (431), each
/// with the JSON error body.
fn with_http_refusals(mut doc: serde_json::Value) -> serde_json::Value {
    let refusals = [
        (
            "414",
            "The request target is longer than the HTTP layer reads (uri_too_long)",
        ),
        (
            "431",
            "The request line and headers are larger than server.max_header_bytes (headers_too_large)",
        ),
    ];
    let Some(paths) = doc["paths"].as_object_mut() else {
        return doc;
    };
    for item in paths.values_mut() {
        let Some(responses) = item["get"]["responses"].as_object_mut() else {
            continue;
        };
        for (status, description) in refusals {
            responses.entry(status).or_insert_with(|| {
                json!({
                    "description": description,
                    "content": { "application/json": { "schema": { "$ref": "#/components/schemas/ErrorBody" } } },
                })
            });
        }
    }
    doc
}

/// The document in OpenAPI 3.0's words: the version, the license with a `url` (the
/// SPDX list, where the identifiers of its name are defined) for 3.1's SPDX
/// `identifier`, and every schema rewritten where 3.1 (JSON Schema 2020-12) and 3.0
/// differ ([`schema_3_0`]).
fn as_3_0(mut doc: serde_json::Value) -> serde_json::Value {
    doc["openapi"] = json!("3.0.3");
    if let Some(license) = doc["info"]["license"].as_object_mut()
        && license.remove("identifier").is_some()
    {
        license.insert("url".into(), json!("https://spdx.org/licenses/"));
    }
    if let Some(schemas) = doc["components"]["schemas"].as_object_mut() {
        schemas.values_mut().for_each(schema_3_0);
    }
    if let Some(paths) = doc["paths"].as_object_mut() {
        paths.values_mut().for_each(schemas_in_3_0);
    }
    doc
}

/// Every `schema` member under `value` (parameters, media types, headers), in 3.0.
fn schemas_in_3_0(value: &mut serde_json::Value) {
    match value {
        serde_json::Value::Object(map) => {
            for (key, v) in map.iter_mut() {
                if key == "schema" {
                    schema_3_0(v);
                } else {
                    schemas_in_3_0(v);
                }
            }
        }
        serde_json::Value::Array(items) => items.iter_mut().for_each(schemas_in_3_0),
        _ => {}
    }
}

/// One schema and its subschemas in OpenAPI 3.0's dialect: a `type` list with
/// `"null"` becomes the type and `nullable: true`; `const` an `enum` of one;
/// `examples` its first as `example`; numeric `exclusiveMinimum`/`exclusiveMaximum`
/// the bound and `true`; a `$ref` with siblings (which 3.0 ignores) an `allOf` of
/// the reference, keeping the siblings.
fn schema_3_0(schema: &mut serde_json::Value) {
    let Some(map) = schema.as_object_mut() else { return };
    if map.contains_key("$ref") && map.len() > 1 {
        let reference = map.remove("$ref").expect("present");
        map.insert("allOf".into(), json!([{ "$ref": reference }]));
    }
    if let Some(serde_json::Value::Array(types)) = map.get("type").cloned() {
        let named: Vec<&serde_json::Value> = types.iter().filter(|t| *t != "null").collect();
        map.remove("type");
        if named.len() < types.len() {
            map.insert("nullable".into(), json!(true));
        }
        match named[..] {
            [] => {}
            [one] => {
                map.insert("type".into(), one.clone());
            }
            _ => {
                let any: Vec<_> = named.iter().map(|t| json!({ "type": t })).collect();
                map.insert("anyOf".into(), json!(any));
            }
        }
    }
    if let Some(value) = map.remove("const") {
        map.insert("enum".into(), json!([value]));
    }
    if let Some(serde_json::Value::Array(examples)) = map.get("examples").cloned() {
        map.remove("examples");
        if let Some(first) = examples.first() {
            map.insert("example".into(), first.clone());
        }
    }
    for (exclusive, bound) in [("exclusiveMinimum", "minimum"), ("exclusiveMaximum", "maximum")] {
        if let Some(n) = map.get(exclusive).filter(|v| v.is_number()).cloned() {
            map.insert(bound.into(), n);
            map.insert(exclusive.into(), json!(true));
        }
    }
    for (key, sub) in map.iter_mut() {
        match key.as_str() {
            "properties" | "patternProperties" => {
                if let Some(props) = sub.as_object_mut() {
                    props.values_mut().for_each(schema_3_0);
                }
            }
            "items" | "additionalProperties" | "not" => schema_3_0(sub),
            "allOf" | "oneOf" | "anyOf" => {
                if let Some(list) = sub.as_array_mut() {
                    list.iter_mut().for_each(schema_3_0);
                }
            }
            _ => {}
        }
    }
}

/// Every route answers a CORS preflight ([`crate::cors`]): an `options` operation on
/// every path (its id the GET's with `_preflight`), with the path's parameters as plain
/// strings (a preflight does not look at them) and the preflight's answer.
fn with_preflights(mut doc: serde_json::Value) -> serde_json::Value {
    let header = |description: &str| json!({ "description": description, "schema": { "type": "string" } });
    let request_header =
        |name: &str| json!({ "name": name, "in": "header", "required": false, "schema": { "type": "string" } });
    let Some(paths) = doc["paths"].as_object_mut() else {
        return doc;
    };
    for item in paths.values_mut() {
        let mut parameters: Vec<serde_json::Value> = item["get"]["parameters"]
            .as_array()
            .into_iter()
            .flatten()
            .filter(|p| p["in"] == "path")
            .map(|p| json!({ "name": p["name"], "in": "path", "required": true, "schema": { "type": "string" } }))
            .collect();
        parameters.extend(
            [
                "Origin",
                "Access-Control-Request-Method",
                "Access-Control-Request-Headers",
            ]
            .map(request_header),
        );
        let operation_id = format!("{}_preflight", item["get"]["operationId"].as_str().unwrap_or("route"));
        item["options"] = json!({
            "operationId": operation_id,
            "tags": ["cors"],
            "summary": "CORS preflight",
            "description": "Answered for every route before it is routed (server.cors_origins: any origin by default; [] turns CORS off and OPTIONS is then 405).",
            "parameters": parameters,
            "responses": {
                "204": {
                    "description": "The preflight's answer, no body",
                    "headers": {
                        "Access-Control-Allow-Origin": header("* by default, or the request's Origin when server.cors_origins lists it (absent otherwise)"),
                        "Access-Control-Allow-Methods": header("GET,HEAD"),
                        "Access-Control-Allow-Headers": header("if-none-match"),
                        "Access-Control-Max-Age": header("86400"),
                    }
                },
                "405": { "description": "CORS is off (server.cors_origins = [])" }
            }
        });
    }
    doc
}

/// This document, as OpenAPI 3.1.
#[utoipa::path(get, path = "/openapi.json", tag = "operations",
    responses((status = 200, content_type = "application/json", body = Object, description = "This document, OpenAPI 3.1")))]
pub async fn openapi() -> Response {
    json_text(document(), "application/json")
}

/// This document, as OpenAPI 3.0.
///
/// The same routes in OpenAPI 3.0's words, for the OGC API clients that look for that
/// version (the EDR landing page's service-desc link).
#[utoipa::path(get, path = "/v1/edr/api", tag = "edr",
    responses((status = 200, content_type = "application/vnd.oai.openapi+json;version=3.0", body = Object, description = "This document, OpenAPI 3.0.3")))]
pub async fn openapi_3_0() -> Response {
    json_text(document_3_0(), OPENAPI_3_0)
}

fn json_text(text: String, content_type: &'static str) -> Response {
    let mut r = text.into_response();
    r.headers_mut()
        .insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    r
}

#[cfg(test)]
mod tests {
    use cloudscape_core::products::Product;

    use super::*;

    #[test]
    fn documented_products_are_the_served_products() {
        let doc: serde_json::Value = serde_json::from_str(&document()).unwrap();
        let listed: Vec<String> = doc["components"]["schemas"]["TileProduct"]["enum"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap().to_string())
            .collect();
        let served: Vec<String> = Product::ALL.iter().map(|p| p.name().to_string()).collect();
        assert_eq!(listed, served);
    }

    /// Whether `value` holds, anywhere, a JSON Schema construct of 3.1 that 3.0 lacks.
    fn has_3_1_schema(value: &serde_json::Value) -> Option<String> {
        match value {
            serde_json::Value::Object(map) => {
                if map.get("type").is_some_and(|t| t.is_array()) {
                    return Some(format!("type list in {value}"));
                }
                if map.contains_key("$ref") && map.len() > 1 {
                    return Some(format!("$ref with siblings in {value}"));
                }
                if map.contains_key("const") || map.get("exclusiveMinimum").is_some_and(|v| v.is_number()) {
                    return Some(format!("const or numeric bound in {value}"));
                }
                map.values().find_map(has_3_1_schema)
            }
            serde_json::Value::Array(items) => items.iter().find_map(has_3_1_schema),
            _ => None,
        }
    }

    #[test]
    fn the_3_0_document_is_the_same_routes_in_3_0_words() {
        let v3_1: serde_json::Value = serde_json::from_str(&document()).unwrap();
        let v3_0: serde_json::Value = serde_json::from_str(&document_3_0()).unwrap();
        assert_eq!(v3_1["openapi"], "3.1.0");
        assert_eq!(v3_0["openapi"], "3.0.3");
        // The 3.1 document uses what 3.0 lacks (so the rewriting is exercised), the 3.0
        // one does not.
        assert!(has_3_1_schema(&v3_1["components"]).is_some());
        assert_eq!(has_3_1_schema(&v3_0), None);
        assert!(v3_0["info"]["license"].get("identifier").is_none());
        let paths = |d: &serde_json::Value| d["paths"].as_object().unwrap().keys().cloned().collect::<Vec<_>>();
        assert_eq!(paths(&v3_0), paths(&v3_1));
        // A nullable number keeps its type; a described reference keeps its description.
        let mut schema = json!({ "type": ["number", "null"], "examples": [1.5], "exclusiveMinimum": 0 });
        schema_3_0(&mut schema);
        assert_eq!(
            schema,
            json!({ "type": "number", "nullable": true, "example": 1.5, "minimum": 0, "exclusiveMinimum": true })
        );
        let mut schema = json!({ "$ref": "#/components/schemas/X", "description": "why" });
        schema_3_0(&mut schema);
        assert_eq!(
            schema,
            json!({ "allOf": [{ "$ref": "#/components/schemas/X" }], "description": "why" })
        );
    }

    #[test]
    fn every_get_says_what_it_answers_with_a_summary_and_a_refusal() {
        let doc: serde_json::Value = serde_json::from_str(&document()).unwrap();
        assert_eq!(doc["security"], json!([]));
        for (path, item) in doc["paths"].as_object().unwrap() {
            let get = &item["get"];
            assert!(
                get["summary"].as_str().is_some_and(|s| !s.is_empty()),
                "{path}: no summary"
            );
            let codes: Vec<&String> = get["responses"].as_object().unwrap().keys().collect();
            assert!(codes.iter().any(|c| c.starts_with('4')), "{path}: {codes:?}");
            for status in ["414", "431"] {
                assert_eq!(
                    get["responses"][status]["content"]["application/json"]["schema"]["$ref"],
                    "#/components/schemas/ErrorBody",
                    "{path} {status}"
                );
            }
            assert!(item["options"]["operationId"].as_str().unwrap().ends_with("_preflight"));
        }
    }

    #[test]
    fn every_path_documents_its_preflight() {
        let doc: serde_json::Value = serde_json::from_str(&document()).unwrap();
        let paths = doc["paths"].as_object().unwrap();
        assert!(paths.len() >= 16, "{}", paths.len());
        for (path, item) in paths {
            let options = &item["options"];
            assert!(options["responses"]["204"].is_object(), "{path}");
            let declared: Vec<&str> = options["parameters"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|p| p["in"] == "path")
                .map(|p| p["name"].as_str().unwrap())
                .collect();
            let templated = path.matches('{').count();
            assert_eq!(declared.len(), templated, "{path}: {declared:?}");
        }
    }
}
