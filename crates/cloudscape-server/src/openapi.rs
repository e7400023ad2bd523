//! The OpenAPI document (`/openapi.json`), generated from the handlers' annotations.

use utoipa::OpenApi;

use super::{discovery, error, ops, queries, render, stats, tiles};

#[derive(OpenApi)]
#[openapi(
    info(
        title = "cloudscape",
        description = "Noise-driven Dobashi cloud simulation for game worlds: tiles, region queries and operator routes. Every error is a JSON object {\"error\": code, \"message\": sentence}."
    ),
    paths(
        discovery::list,
        discovery::world,
        tiles::tile,
        queries::sample,
        queries::region,
        queries::series,
        render::render_png,
        render::splats_png,
        render::splats_json,
        render::sky_json,
        ops::healthz,
        ops::readyz,
        ops::metrics,
        ops::openapi,
    ),
    components(schemas(
        TileProduct,
        QualityName,
        error::ErrorBody,
        stats::RegionStats,
        discovery::WorldList,
        discovery::WorldSummary,
        discovery::WorldInfo,
        discovery::LayerInfo,
        queries::Columns,
        queries::SampleAnswer,
        queries::RegionAnswer,
        queries::SeriesAnswer,
        queries::SeriesPoint,
        ops::Status,
    ))
)]
struct ApiDoc;

/// The tile products, as the OpenAPI document lists them (the URL names of
/// [`tiles::Product::ALL`]; a unit test keeps the two lists equal).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub enum TileProduct {
    #[schema(rename = "density.npy")]
    DensityNpy,
    #[schema(rename = "density.f32")]
    DensityF32,
    #[schema(rename = "density.u8")]
    DensityU8,
    #[schema(rename = "coverage.png")]
    CoveragePng,
    #[schema(rename = "billboards.json")]
    BillboardsJson,
    #[schema(rename = "billboards.bin")]
    BillboardsBin,
    #[schema(rename = "atlas.png")]
    AtlasPng,
    #[schema(rename = "atlas.json")]
    AtlasJson,
    #[schema(rename = "shadow.png")]
    ShadowPng,
}

/// The quality presets.
#[derive(utoipa::ToSchema)]
#[allow(dead_code)]
pub enum QualityName {
    #[schema(rename = "fast")]
    Fast,
    #[schema(rename = "balanced")]
    Balanced,
    #[schema(rename = "accurate")]
    Accurate,
    #[schema(rename = "reference")]
    Reference,
    #[schema(rename = "reference-single")]
    ReferenceSingle,
}

/// The document as JSON text.
pub fn document() -> String {
    ApiDoc::openapi()
        .to_pretty_json()
        .expect("the OpenAPI document serialises")
}

#[cfg(test)]
mod tests {
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
        let served: Vec<String> = tiles::Product::ALL.iter().map(|p| p.name().to_string()).collect();
        assert_eq!(listed, served);
    }
}
