//! The absolute URLs a document names (TileJSON templates, the EDR links): where
//! clients reach this server, and how a document that depends on it is cached.
//!
//! URLs are absolute: `server.public_url` when set (the address clients use behind a
//! proxy or CDN), else `http://` (or `https://` when a proxy says so in
//! `X-Forwarded-Proto`) and the request's `Host`. A document built from the request's
//! headers is that client's alone: it says `Cache-Control: private` and `Vary: Host,
//! X-Forwarded-Proto`, so no shared cache (nginx, a CDN) keeps it under the plain URL
//! and hands another client the URLs of a `Host` an attacker chose. With `public_url`
//! the document is the same for everyone and caches like discovery.

use axum::http::{HeaderMap, HeaderValue, Uri, header};
use axum::response::Response;
use serde::Serialize;

use crate::discovery::json_response;
use crate::error::ApiError;
use crate::params::Params;
use crate::state::AppState;

/// Where the absolute URLs of a document start.
pub struct PublicBase {
    /// Scheme and authority (and `public_url`'s path), no trailing slash.
    pub url: String,
    /// Taken from the request's headers (no `public_url`): the document is private.
    from_request: bool,
}

impl PublicBase {
    /// The scheme and authority clients reach this server at: `server.public_url`,
    /// else the request's `Host` (`X-Forwarded-Proto: https` makes it https).
    pub fn of(s: &AppState, uri: &Uri, headers: &HeaderMap) -> Result<PublicBase, ApiError> {
        if !s.settings.public_url.is_empty() {
            return Ok(PublicBase {
                url: s.settings.public_url.trim_end_matches('/').to_string(),
                from_request: false,
            });
        }
        let host = uri
            .authority()
            .map(|a| a.as_str().to_string())
            .or_else(|| headers.get("host").and_then(|h| h.to_str().ok()).map(str::to_string))
            .ok_or_else(|| ApiError::InvalidParameter {
                name: "host".to_string(),
                message: "the request has no Host header and server.public_url is not set".to_string(),
            })?;
        let valid = !host.is_empty()
            && host.len() <= 255
            && host
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'-' | b':' | b'[' | b']' | b'_'));
        if !valid {
            return Err(ApiError::InvalidParameter {
                name: "host".to_string(),
                message: format!(
                    "the Host header `{}` is not a host[:port]",
                    host.chars().take(64).collect::<String>()
                ),
            });
        }
        let https = headers
            .get("x-forwarded-proto")
            .and_then(|v| v.to_str().ok())
            .is_some_and(|v| v.trim().eq_ignore_ascii_case("https"));
        Ok(PublicBase {
            url: format!("{}://{host}", if https { "https" } else { "http" }),
            from_request: true,
        })
    }

    /// A document that names URLs under this base, answered with `cache_control`, made
    /// private (and varying by `Host` and `X-Forwarded-Proto`) when the base came from
    /// the request.
    pub fn json_response(
        &self,
        headers: &HeaderMap,
        cache_control: &str,
        document: &impl Serialize,
    ) -> Result<Response, ApiError> {
        if !self.from_request {
            return json_response(headers, cache_control, document);
        }
        let mut response = json_response(headers, &private(cache_control), document)?;
        response
            .headers_mut()
            .append(header::VARY, HeaderValue::from_static("host, x-forwarded-proto"));
        Ok(response)
    }
}

/// `cache_control` for one client only: its directives with `public` (and the shared
/// caches' `s-maxage`) replaced by `private`.
fn private(cache_control: &str) -> String {
    let kept = cache_control.split(',').map(str::trim).filter(|d| {
        let name = d.split('=').next().unwrap_or("").to_ascii_lowercase();
        !d.is_empty() && !matches!(name.as_str(), "public" | "private" | "s-maxage")
    });
    std::iter::once("private").chain(kept).collect::<Vec<_>>().join(", ")
}

/// A name (a world's) as one URL path segment.
pub fn encode_segment(name: &str) -> String {
    let q = Params(Vec::new()).query_with("n", name);
    q.trim_start_matches("n=").to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_document_of_the_request_host_is_private() {
        assert_eq!(private("public, max-age=60"), "private, max-age=60");
        assert_eq!(
            private("max-age=60, s-maxage=600, PUBLIC, stale-while-revalidate=30"),
            "private, max-age=60, stale-while-revalidate=30"
        );
        assert_eq!(private(""), "private");
        assert_eq!(encode_segment("my world"), "my%20world");
    }
}
