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
        ops::healthz,
        ops::readyz,
        ops::metrics,
        ops::openapi,
    ),
    components(schemas(
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

/// The document as JSON text.
pub fn document() -> String {
    ApiDoc::openapi()
        .to_pretty_json()
        .expect("the OpenAPI document serialises")
}
