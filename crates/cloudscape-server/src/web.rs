//! The viewer: `GET /` and its static files, embedded in the binary (`web/`), and the
//! JS client module (`clients/js`) at `/client/cloudscape.js` with its TypeScript
//! types at `/client/index.d.ts`, so a page can import the client from the server it
//! draws.
//!
//! The files are compiled in with `include_str!`, so the binary serves the viewer
//! offline and a deployed replica cannot drift from its own API. Each has a strong
//! ETag (a hash of its bytes) and `Cache-Control: no-cache`, so browsers revalidate
//! and get 304s.

use std::sync::Arc;

use axum::Router;
use axum::body::Bytes;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;

use crate::key::{if_none_match, stable_hash_hex};
use crate::state::AppState;

/// One embedded file.
struct Asset {
    path: &'static str,
    content_type: &'static str,
    body: &'static str,
}

impl Asset {
    const fn new(path: &'static str, content_type: &'static str, body: &'static str) -> Asset {
        Asset {
            path,
            content_type,
            body,
        }
    }
}

const HTML: &str = "text/html; charset=utf-8";
const JAVASCRIPT: &str = "text/javascript; charset=utf-8";
const CSS: &str = "text/css; charset=utf-8";
const TEXT: &str = "text/plain; charset=utf-8";

/// Every file of the viewer and the JS client, by URL path.
const ASSETS: [Asset; 5] = [
    Asset::new("/", HTML, include_str!("../../../web/index.html")),
    Asset::new("/viewer.js", JAVASCRIPT, include_str!("../../../web/viewer.js")),
    Asset::new("/viewer.css", CSS, include_str!("../../../web/viewer.css")),
    Asset::new(
        "/client/cloudscape.js",
        JAVASCRIPT,
        include_str!("../../../clients/js/cloudscape.js"),
    ),
    Asset::new(
        "/client/index.d.ts",
        TEXT,
        include_str!("../../../clients/js/index.d.ts"),
    ),
];

fn serve(asset: &'static Asset, request: &HeaderMap) -> Response {
    let etag = format!("\"{}\"", stable_hash_hex(asset.body.as_bytes()));
    let mut headers = HeaderMap::new();
    if let Ok(v) = HeaderValue::from_str(&etag) {
        headers.insert(header::ETAG, v);
    }
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    let matched = request
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|inm| if_none_match(inm, &etag));
    if matched {
        return (StatusCode::NOT_MODIFIED, headers).into_response();
    }
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(asset.content_type));
    (StatusCode::OK, headers, Bytes::from_static(asset.body.as_bytes())).into_response()
}

/// The viewer's routes, to merge into the service router.
pub fn routes() -> Router<Arc<AppState>> {
    ASSETS.iter().fold(Router::new(), |router, asset| {
        router.route(
            asset.path,
            get(move |headers: HeaderMap| async move { serve(asset, &headers) }),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assets_carry_etags_and_revalidate() {
        let index = &ASSETS[0];
        let first = serve(index, &HeaderMap::new());
        assert_eq!(first.status(), StatusCode::OK);
        let etag = first.headers()[header::ETAG].clone();
        let mut again = HeaderMap::new();
        again.insert(header::IF_NONE_MATCH, etag);
        assert_eq!(serve(index, &again).status(), StatusCode::NOT_MODIFIED);
        let mut other = HeaderMap::new();
        other.insert(header::IF_NONE_MATCH, HeaderValue::from_static("\"nope\""));
        assert_eq!(serve(index, &other).status(), StatusCode::OK);
    }

    #[test]
    fn the_js_client_is_served_as_a_module() {
        let client = ASSETS.iter().find(|a| a.path == "/client/cloudscape.js").unwrap();
        assert!(client.content_type.starts_with("text/javascript"));
        assert!(client.body.contains("export class CloudscapeClient"));
        let types = ASSETS.iter().find(|a| a.path == "/client/index.d.ts").unwrap();
        assert!(types.body.contains("export class CloudscapeClient"));
    }

    #[test]
    fn the_page_loads_only_embedded_files() {
        let html = ASSETS[0].body;
        for src in ["/viewer.js", "/viewer.css"] {
            assert!(html.contains(src), "index.html does not reference {src}");
            assert!(ASSETS.iter().any(|a| a.path == src));
        }
        for a in &ASSETS {
            assert!(
                !a.body.contains("http://") && !a.body.contains("https://"),
                "{} names a remote URL",
                a.path
            );
        }
    }
}
