//! The service's one error type and the one place where errors become HTTP.
//!
//! Every failure a client can cause maps to a status and a stable machine code in a
//! JSON body `{"error": code, "message": sentence}`. Nothing a client sends produces a
//! 500: a 500 means a bug (a panicking handler or job), and is logged as one.
//!
//! The same body goes out on the paths that never reach a handler: the refusals of the
//! HTTP layer itself (a malformed request, an overlong target, an oversized head), which
//! [`crate::conn`] writes as raw HTTP/1.1 with [`ApiError::http1_response`].

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;

use cloudscape_core::density::SimError;
use cloudscape_core::render::RenderError;
use cloudscape_core::weather::lightning::LightningError;

/// A request the service refuses or could not answer.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ApiError {
    /// A parameter that should be a number is not one (`t=abc`, `x=1e`).
    #[error("parameter `{name}` is not a valid number: `{value}`")]
    InvalidNumber { name: String, value: String },
    /// A number that parsed but is NaN or infinite.
    #[error("parameter `{name}` must be a finite number, got `{value}`")]
    NotFinite { name: String, value: String },
    #[error("missing parameter `{0}`")]
    MissingParameter(String),
    /// A parameter with a value outside its vocabulary (`quality=ultra`, `sun=1`).
    #[error("parameter `{name}`: {message}")]
    InvalidParameter { name: String, message: String },
    /// A query parameter the route does not read (the routes that refuse them: EDR),
    /// with the ones it reads.
    #[error("unknown parameter `{name}`: this route reads {known}")]
    UnknownParameter { name: String, known: String },
    #[error("t must be within [0, 1e12] seconds, got {0}")]
    TimeOutOfRange(f64),
    /// An EDR `datetime` instant before the world clock's start or after the last
    /// second a four-digit year can name.
    #[error(
        "datetime `{0}` is out of range: world time runs from 1970-01-01T00:00:00Z (t = 0) and EDR instants \
         end at 9999-12-31T23:59:59Z (t = 253402300799 s)"
    )]
    DatetimeOutOfRange(String),
    #[error("bbox must be X0,Y0,X1,Y1 in metres with X0 < X1 and Y0 < Y1")]
    InvalidBbox,
    #[error("the bbox holds no column centre at this level")]
    EmptyRegion,
    #[error("{0}")]
    RegionTooLarge(String),
    /// Well-formed but more work than the render limits allow (pixels, tiles in view).
    #[error("{0}")]
    TooMuchWork(String),
    #[error("the series has {points} time points; the limit is {max}")]
    SeriesTooLong { points: u64, max: u32 },
    #[error("level {level} is out of range (0..={max})")]
    LevelOutOfRange { level: String, max: u32 },
    #[error("coordinates out of range: {0}")]
    CoordinatesOutOfRange(String),
    #[error("unknown world `{0}`: use a configured name (see /v1/worlds) or a decimal u64 seed")]
    UnknownWorld(String),
    #[error("unknown layer `{layer}` in world `{world}`")]
    UnknownLayer { world: String, layer: String },
    #[error("unknown product `{0}` (see the world's `products` in /v1/worlds/{{world}})")]
    UnknownProduct(String),
    #[error("no route for {0}")]
    NotFound(String),
    #[error("method not allowed")]
    MethodNotAllowed,
    /// The compute queue (or its memory) is full: shed rather than grow a backlog.
    /// Carries the `Retry-After`, seconds.
    #[error("the server is busy; retry in {0} s")]
    Overloaded(u32),
    /// The request's time budget ran out; its computation was stopped unless another
    /// request still waits for it.
    #[error("the request did not finish within its time budget of {budget_ms} ms; retry in {retry_after} s")]
    Timeout { budget_ms: u64, retry_after: u32 },
    /// A computation stopped because nobody waited for it any more (internal: the
    /// cache turns it into `Overloaded` for a request that joined it late).
    #[error("the computation was stopped: nobody was waiting for it any more")]
    Cancelled,
    /// The answer would be larger than the per-response limit.
    #[error("{0}")]
    ResponseTooLarge(String),
    /// The bytes held by replies still being sent are at their budget.
    #[error(
        "the server holds {held_mib} MiB of replies still being sent (server.reply_bytes is {budget_mib} MiB); retry in {retry_after} s"
    )]
    ReplyMemoryFull {
        held_mib: u64,
        budget_mib: u64,
        retry_after: u32,
    },
    /// The server is shutting down.
    #[error("the server is shutting down")]
    Draining,
    /// The connection is over `server.max_connections` (answered by the connection
    /// layer, which then closes it).
    #[error("the server has as many connections as it serves at once; retry shortly")]
    ConnectionCap,
    /// The request is not HTTP/1.1 that the server can read (its request line or a
    /// header is malformed); refused by the HTTP layer before any route sees it.
    #[error("the request is not valid HTTP/1.1: its request line or a header is malformed")]
    MalformedRequest,
    /// The request target is longer than the HTTP layer reads.
    #[error("the request target is longer than {max} bytes")]
    UriTooLong { max: usize },
    /// The request head (request line and headers) is larger than
    /// `server.max_header_bytes`.
    #[error("the request line and headers are larger than {max} bytes (server.max_header_bytes)")]
    HeadersTooLarge { max: usize },
    /// A handler or a computation panicked: a bug. The panic itself is logged where it
    /// happened (one line, by the process's panic hook); the client learns no more.
    #[error("the server failed on this request (a bug, logged on the server)")]
    Panicked,
    #[error("internal error: {0}")]
    Internal(String),
}

/// The JSON body of every error response.
#[derive(Serialize, utoipa::ToSchema)]
pub struct ErrorBody {
    /// Stable machine-readable code, e.g. `invalid_number`, `unknown_world`, `overloaded`.
    pub error: &'static str,
    /// One sentence a person can act on.
    pub message: String,
}

impl ApiError {
    /// Status and stable code. The only place where an error gets its status.
    pub fn status_and_code(&self) -> (StatusCode, &'static str) {
        use ApiError::*;
        match self {
            InvalidNumber { .. } => (StatusCode::BAD_REQUEST, "invalid_number"),
            NotFinite { .. } => (StatusCode::BAD_REQUEST, "not_finite"),
            MissingParameter(_) => (StatusCode::BAD_REQUEST, "missing_parameter"),
            InvalidParameter { .. } => (StatusCode::BAD_REQUEST, "invalid_parameter"),
            UnknownParameter { .. } => (StatusCode::BAD_REQUEST, "unknown_parameter"),
            InvalidBbox => (StatusCode::BAD_REQUEST, "invalid_bbox"),
            TimeOutOfRange(_) | DatetimeOutOfRange(_) => (StatusCode::UNPROCESSABLE_ENTITY, "time_out_of_range"),
            EmptyRegion => (StatusCode::UNPROCESSABLE_ENTITY, "empty_region"),
            LevelOutOfRange { .. } => (StatusCode::UNPROCESSABLE_ENTITY, "level_out_of_range"),
            CoordinatesOutOfRange(_) => (StatusCode::UNPROCESSABLE_ENTITY, "coordinates_out_of_range"),
            RegionTooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, "region_too_large"),
            SeriesTooLong { .. } => (StatusCode::PAYLOAD_TOO_LARGE, "series_too_long"),
            TooMuchWork(_) => (StatusCode::PAYLOAD_TOO_LARGE, "too_much_work"),
            ResponseTooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, "response_too_large"),
            UnknownWorld(_) => (StatusCode::NOT_FOUND, "unknown_world"),
            UnknownLayer { .. } => (StatusCode::NOT_FOUND, "unknown_layer"),
            UnknownProduct(_) => (StatusCode::NOT_FOUND, "unknown_product"),
            NotFound(_) => (StatusCode::NOT_FOUND, "not_found"),
            MethodNotAllowed => (StatusCode::METHOD_NOT_ALLOWED, "method_not_allowed"),
            Overloaded(_) | Cancelled | ConnectionCap => (StatusCode::SERVICE_UNAVAILABLE, "overloaded"),
            Timeout { .. } => (StatusCode::SERVICE_UNAVAILABLE, "timeout"),
            ReplyMemoryFull { .. } => (StatusCode::SERVICE_UNAVAILABLE, "reply_memory_full"),
            Draining => (StatusCode::SERVICE_UNAVAILABLE, "draining"),
            MalformedRequest => (StatusCode::BAD_REQUEST, "malformed_request"),
            UriTooLong { .. } => (StatusCode::URI_TOO_LONG, "uri_too_long"),
            HeadersTooLarge { .. } => (StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE, "headers_too_large"),
            Internal(_) | Panicked => (StatusCode::INTERNAL_SERVER_ERROR, "internal"),
        }
    }
}

impl ApiError {
    /// Seconds a client should wait before retrying a 503 (1 when nothing better is
    /// known: draining, a cancelled join).
    pub fn retry_after(&self) -> u32 {
        match self {
            ApiError::Overloaded(s) | ApiError::Timeout { retry_after: s, .. } => *s,
            ApiError::ReplyMemoryFull { retry_after, .. } => *retry_after,
            _ => 1,
        }
    }
}

impl From<SimError> for ApiError {
    fn from(e: SimError) -> ApiError {
        match e {
            SimError::BadTime(t) => ApiError::TimeOutOfRange(t),
            SimError::BadBbox => ApiError::InvalidBbox,
            SimError::EmptyRegion => ApiError::EmptyRegion,
            SimError::RegionTooWide { .. } | SimError::TooManyCells { .. } => ApiError::RegionTooLarge(e.to_string()),
            SimError::BadLevel { level, max } => ApiError::LevelOutOfRange {
                level: level.to_string(),
                max,
            },
            SimError::OutOfRange(m) => ApiError::CoordinatesOutOfRange(m),
            SimError::Cancelled(_) => ApiError::Cancelled,
        }
    }
}

impl From<LightningError> for ApiError {
    fn from(e: LightningError) -> ApiError {
        match e {
            LightningError::TooLarge(m) => ApiError::RegionTooLarge(m),
            LightningError::Sim(e) => e.into(),
            LightningError::EmptySpan => ApiError::InvalidParameter {
                name: "t1".into(),
                message: "must be greater than t0".into(),
            },
        }
    }
}

impl From<RenderError> for ApiError {
    fn from(e: RenderError) -> ApiError {
        match e {
            RenderError::Sim(e) => e.into(),
            RenderError::BadRequest(m) => ApiError::InvalidParameter {
                name: "request".to_string(),
                message: m,
            },
            RenderError::TooMuchWork(m) => ApiError::TooMuchWork(m),
        }
    }
}

impl ApiError {
    /// The JSON body of this error.
    fn body(&self) -> ErrorBody {
        ErrorBody {
            error: self.status_and_code().1,
            message: self.to_string(),
        }
    }

    /// The whole answer as HTTP/1.1 bytes, for the connection layer, which answers
    /// some requests before (or instead of) hyper and axum: status line, the headers
    /// [`IntoResponse`] gives, `connection: close`, and the JSON body.
    pub fn http1_response(&self) -> Vec<u8> {
        let status = self.status_and_code().0;
        let body = serde_json::to_vec(&self.body()).unwrap_or_default();
        let mut head = format!(
            "HTTP/1.1 {} {}\r\ncontent-type: application/json\r\ncache-control: no-store\r\n",
            status.as_u16(),
            status.canonical_reason().unwrap_or("")
        );
        if status == StatusCode::SERVICE_UNAVAILABLE {
            head += &format!("retry-after: {}\r\n", self.retry_after());
        }
        head += &format!("connection: close\r\ncontent-length: {}\r\n\r\n", body.len());
        let mut out = head.into_bytes();
        out.extend_from_slice(&body);
        out
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let (status, _) = self.status_and_code();
        // A panic was logged by the panic hook, where it happened: one line is enough.
        if status.is_server_error() && status != StatusCode::SERVICE_UNAVAILABLE && self != ApiError::Panicked {
            tracing::error!(error = %self, "request failed");
        }
        let mut response = (status, axum::Json(self.body())).into_response();
        let headers = response.headers_mut();
        headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
        if status == StatusCode::SERVICE_UNAVAILABLE {
            headers.insert(header::RETRY_AFTER, HeaderValue::from(self.retry_after()));
        }
        response
    }
}
