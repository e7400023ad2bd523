//! The OpenAPI document (`/openapi.json`), generated from the handlers' annotations.

use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use cloudscape_core::density::RegionStats;
use cloudscape_core::weather::PrecipitationStats;
use cloudscape_core::weather::lightning::{Strike, StrikeKind};
use utoipa::OpenApi;

use crate::extract::TileProduct;
use crate::params::QualityName;
use crate::{discovery, error, lightning, ops, queries, render, tilejson, tiles};

#[derive(OpenApi)]
#[openapi(
    info(
        title = "cloudscape",
        description = "Noise-driven Dobashi cloud simulation for game worlds: tiles, region queries and operator routes. Every error is a JSON object {\"error\": code, \"message\": sentence}."
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
    ApiDoc::openapi()
        .to_pretty_json()
        .expect("the OpenAPI document serialises")
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
}
