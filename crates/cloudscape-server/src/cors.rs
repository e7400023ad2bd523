//! Cross-origin access (CORS): a browser game on another origin may fetch every
//! route. tower-http's [`CorsLayer`], configured from `server.cors_origins`: any
//! origin by default, `GET` and `HEAD`, `If-None-Match` allowed in requests (ETag
//! revalidation), and every header a client reads exposed to its script
//! ([`EXPOSED`]). Preflights (`OPTIONS`) answer 204 with no body ([`preflight_204`]).

use std::time::Duration;

use axum::extract::Request;
use axum::http::{HeaderName, HeaderValue, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::Response;
use tower_http::cors::{AllowOrigin, CorsLayer};

/// Response headers a script on another origin may read: the caching headers and
/// every `X-Cloudscape-*` header the server sends (the time of a tile, its keyframe
/// span, the path tracer's samples and noise), the request id and `Retry-After`.
/// A test checks that every `x-cloudscape-*` name in the sources is here.
pub const EXPOSED: [HeaderName; 11] = [
    header::ETAG,
    header::CACHE_CONTROL,
    header::CONTENT_LOCATION,
    header::RETRY_AFTER,
    header::VARY,
    HeaderName::from_static("x-request-id"),
    HeaderName::from_static("x-cloudscape-t"),
    HeaderName::from_static("x-cloudscape-t1"),
    HeaderName::from_static("x-cloudscape-frame"),
    HeaderName::from_static("x-cloudscape-samples"),
    HeaderName::from_static("x-cloudscape-noise"),
];

/// How long a browser may keep a preflight's answer, seconds.
const PREFLIGHT_MAX_AGE_S: u64 = 86_400;

/// The layer for `origins` (`server.cors_origins`, already validated): `["*"]` is any
/// origin (`Access-Control-Allow-Origin: *`, no `Vary: Origin`, so one cached
/// response serves every origin); a list of origins echoes the request's origin when
/// it is listed (with `Vary: Origin`); an empty list sends no CORS headers at all.
pub fn layer(origins: &[String]) -> Option<CorsLayer> {
    if origins.is_empty() {
        return None;
    }
    let base = CorsLayer::new()
        .allow_methods([Method::GET, Method::HEAD])
        .allow_headers([header::IF_NONE_MATCH])
        .expose_headers(EXPOSED)
        .max_age(Duration::from_secs(PREFLIGHT_MAX_AGE_S));
    Some(if origins.iter().any(|o| o == "*") {
        base.allow_origin(AllowOrigin::any()).vary(Vec::<HeaderName>::new())
    } else {
        let list: Vec<HeaderValue> = origins.iter().filter_map(|o| HeaderValue::from_str(o).ok()).collect();
        base.allow_origin(list).vary([header::ORIGIN])
    })
}

/// Checks one entry of `server.cors_origins`: `*`, or an origin as browsers send it
/// (`scheme://host[:port]`, no path, no trailing slash).
pub fn check_origin(origin: &str) -> Result<(), String> {
    if origin == "*" {
        return Ok(());
    }
    let rest = origin
        .strip_prefix("https://")
        .or_else(|| origin.strip_prefix("http://"))
        .ok_or_else(|| format!("`{origin}` must start with http:// or https:// (or be \"*\")"))?;
    let host_ok = !rest.is_empty()
        && rest
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'-' | b':' | b'[' | b']'));
    if !host_ok {
        return Err(format!(
            "`{origin}` must be scheme://host[:port], with no path or trailing slash"
        ));
    }
    Ok(())
}

/// tower-http answers a preflight with 200 and an empty body; the Fetch standard
/// takes any 2xx, and 204 says "no content" to caches and tools as well.
pub async fn preflight_204(req: Request, next: Next) -> Response {
    let preflight = req.method() == Method::OPTIONS;
    let mut response = next.run(req).await;
    if preflight
        && response.status() == StatusCode::OK
        && response.headers().contains_key(header::ACCESS_CONTROL_ALLOW_METHODS)
    {
        *response.status_mut() = StatusCode::NO_CONTENT;
    }
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origins_are_checked() {
        for ok in [
            "*",
            "https://game.example",
            "http://localhost:5173",
            "http://[::1]:8000",
        ] {
            assert!(check_origin(ok).is_ok(), "{ok}");
        }
        for bad in [
            "",
            "game.example",
            "https://",
            "https://a.example/",
            "https://a.example/path",
            "ftp://a",
        ] {
            let e = check_origin(bad).unwrap_err();
            assert!(e.contains(&format!("`{bad}`")), "{e}");
        }
    }

    /// Every `x-cloudscape-*` header the server's sources name is exposed.
    #[test]
    fn every_cloudscape_header_is_exposed() {
        let mut dirs = vec![std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/src"))];
        let mut files = Vec::new();
        while let Some(dir) = dirs.pop() {
            for entry in std::fs::read_dir(dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    dirs.push(path);
                } else {
                    files.push(path);
                }
            }
        }
        let mut named = Vec::new();
        for path in files {
            let text = std::fs::read_to_string(path).unwrap();
            let lower = text.to_lowercase();
            let mut rest = lower.as_str();
            while let Some((_, after)) = rest.split_once("x-cloudscape-") {
                let name: String = after
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '-')
                    .collect();
                let name = name.trim_end_matches('-');
                if !name.is_empty() {
                    named.push(format!("x-cloudscape-{name}"));
                }
                rest = after;
            }
        }
        assert!(named.len() >= 5, "{named:?}");
        for n in named {
            assert!(EXPOSED.iter().any(|h| h.as_str() == n), "{n} is sent but not exposed");
        }
    }
}
