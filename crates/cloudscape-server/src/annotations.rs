//! The pieces the handlers' OpenAPI annotations share: the answers many routes give
//! in the same words ([`ComputedResponses`], [`NotModified`], [`Overloaded`]), the
//! `{world}` path parameter ([`WorldName`]) and the query parameters several routes
//! read alike ([`LayerName`], [`ColumnsBbox`], [`ColumnLevel`]). Documentation only:
//! utoipa reads these types, no handler builds them. Kept apart from [`crate::openapi`],
//! which names every handler, so that the handlers do not import the module that
//! imports them.
#![allow(
    dead_code,
    reason = "documentation: utoipa reads the fields and variants, no handler builds them"
)]

use crate::error;

/// What a route that computes over a world (tiles, queries, EDR queries, renders)
/// answers besides its 200: the refusals by status, each naming the error codes
/// [`error::ApiError`] gives it. A route's own reasons for a 400, 413 or 422 are in its
/// description.
#[derive(utoipa::IntoResponses)]
pub enum ComputedResponses {
    #[response(status = 304, description = "If-None-Match matched; nothing computed")]
    NotModified,
    #[response(
        status = 400,
        description = "Malformed request (invalid_number, not_finite, missing_parameter, invalid_parameter, invalid_bbox; on the EDR routes also unknown_parameter, a parameter the route does not read); the message names the parameter"
    )]
    Malformed(error::ErrorBody),
    #[response(
        status = 404,
        description = "Unknown world, layer or product (unknown_world, unknown_layer, unknown_product)"
    )]
    Unknown(error::ErrorBody),
    #[response(
        status = 413,
        description = "Over the limits (region_too_large, series_too_long, too_much_work, response_too_large)"
    )]
    TooLarge(error::ErrorBody),
    #[response(
        status = 422,
        description = "Out of range (time_out_of_range, level_out_of_range, coordinates_out_of_range, empty_region)"
    )]
    OutOfRange(error::ErrorBody),
    #[response(
        status = 503,
        description = "Overloaded (queue, compute memory or reply memory full: overloaded, reply_memory_full), over the time budget (timeout) or draining; Retry-After is the queue's wait"
    )]
    Unavailable(error::ErrorBody),
}

/// 304: the request's If-None-Match named the answer's ETag.
#[derive(utoipa::IntoResponses)]
#[response(status = 304, description = "If-None-Match matched")]
pub struct NotModified;

/// 503 of the routes that compute: the compute queue shed the request.
#[derive(utoipa::IntoResponses)]
#[response(status = 503, description = "Overloaded; see Retry-After")]
pub struct Overloaded(error::ErrorBody);

/// The `{world}` of `/v1/worlds/{world}/…` and `/v1/edr/collections/{world}/…`.
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Path)]
pub struct WorldName {
    /// Configured world name, or a decimal u64 seed (default climate)
    #[param(example = "default")]
    pub world: String,
}

/// `layer=` of the routes that read one layer, the world's first unless named.
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct LayerName {
    /// Layer name (default: the world's first layer)
    pub layer: Option<String>,
}

/// `bbox=` of the routes that answer per column of a box (`/region`, `/series`, EDR
/// `cube`).
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ColumnsBbox {
    /// X0,Y0,X1,Y1 in metres, X0 < X1, Y0 < Y1; the columns whose centres lie inside
    #[param(example = "0,0,1000,1000")]
    pub bbox: String,
}

/// `level=` of the routes that answer per column (`/region`, `/series`, EDR `area` and
/// `cube`).
#[derive(utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ColumnLevel {
    /// Level of the columns (default 0); matches the tiles of that level
    pub level: Option<u32>,
}
