//! The OpenAPI document (`/openapi.json`), generated from the handlers' annotations
//! (their shared pieces are in [`crate::annotations`]).

use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use cloudscape_core::density::RegionStats;
use cloudscape_core::weather::PrecipitationStats;
use cloudscape_core::weather::lightning::{Strike, StrikeKind};
use serde_json::json;
use utoipa::OpenApi;

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
        edr::conformance,
        edr::collections,
        edr::collection,
        edr::position,
        edr::area,
        edr::cube,
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

/// The document as JSON text.
pub fn document() -> String {
    let doc = serde_json::to_value(ApiDoc::openapi()).expect("the OpenAPI document serialises");
    serde_json::to_string_pretty(&with_preflights(doc)).expect("the OpenAPI document serialises")
}

/// Every route answers a CORS preflight ([`crate::cors`]): an `options` operation on
/// every path, with the path's parameters as plain strings (a preflight does not look
/// at them) and the preflight's answer.
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
        item["options"] = json!({
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

#[utoipa::path(get, path = "/openapi.json", tag = "operations",
    responses((status = 200, content_type = "application/json", body = Object, description = "This document")))]
pub async fn openapi() -> Response {
    let mut r = document().into_response();
    r.headers_mut()
        .insert(header::CONTENT_TYPE, HeaderValue::from_static("application/json"));
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
