//! What the blocking and async fetchers share: the bodies fetched so far with their
//! ETags, the counters, and what each answer means (304 reuses the stored body, 503
//! waits its `Retry-After`, anything but 200 is an error).

use std::collections::{HashMap, VecDeque};
use std::time::Duration;

use crate::{ClientError, FetchStats};

/// Times a request is retried after a 503 (overloaded server).
pub(crate) const MAX_RETRIES: u32 = 8;

/// Checks a server URL: `http://HOST:PORT`, no path. Returns it without a trailing `/`.
pub(crate) fn check_base(base: &str) -> Result<String, ClientError> {
    let base = base.trim_end_matches('/');
    let rest = base
        .strip_prefix("http://")
        .ok_or_else(|| ClientError::BadUrl(base.to_string()))?;
    if rest.is_empty() || rest.contains('/') {
        return Err(ClientError::BadUrl(base.to_string()));
    }
    Ok(base.to_string())
}

/// What to do with an answer before its body is read.
pub(crate) enum Head {
    /// The stored body is still good (304).
    Stored(Vec<u8>),
    /// Overloaded: ask again after this long.
    Retry(Duration),
    /// Read the body, then call [`Store::finish`].
    ReadBody,
}

/// Most bodies a store keeps; past it the oldest are forgotten.
pub(crate) const MAX_BODIES: usize = 4096;

/// A stored body: its ETag, and whether its URL's answer never changes
/// (`Cache-Control: immutable`, as keyframe URLs are).
struct Stored {
    etag: Option<String>,
    immutable: bool,
    body: Vec<u8>,
}

/// Bodies by path and query, with the ETag they came with, and the counters.
#[derive(Default)]
pub(crate) struct Store {
    bodies: HashMap<String, Stored>,
    /// Paths in the order they were stored, to forget the oldest.
    order: VecDeque<String>,
    pub(crate) stats: FetchStats,
}

impl Store {
    /// The body of an immutable URL already held: no request needed (counted as reused).
    pub(crate) fn held(&mut self, path: &str) -> Option<Vec<u8>> {
        let s = self.bodies.get(path).filter(|s| s.immutable)?;
        self.stats.reused += 1;
        Some(s.body.clone())
    }

    /// The ETag to revalidate `path` with, if a body is stored; counts the request.
    pub(crate) fn begin(&mut self, path: &str) -> Option<&str> {
        self.stats.requests += 1;
        self.bodies.get(path).and_then(|s| s.etag.as_deref())
    }

    /// Judges an answer's status (and `Retry-After`) on the `attempt`-th try.
    pub(crate) fn head(&mut self, path: &str, status: u16, retry_after: Option<&str>, attempt: u32) -> Head {
        if status == 304
            && let Some(s) = self.bodies.get(path)
        {
            self.stats.revalidated += 1;
            return Head::Stored(s.body.clone());
        }
        if status == 503 && attempt < MAX_RETRIES {
            let after = retry_after.and_then(|v| v.parse::<u64>().ok()).unwrap_or(1);
            return Head::Retry(Duration::from_secs(after.clamp(1, 30)));
        }
        Head::ReadBody
    }

    /// Takes a body: stores a 200 under its ETag, turns anything else into an error
    /// carrying the server's message.
    pub(crate) fn finish(
        &mut self,
        url: String,
        path: &str,
        status: u16,
        etag: Option<String>,
        cache_control: Option<&str>,
        body: Vec<u8>,
    ) -> Result<Vec<u8>, ClientError> {
        if status != 200 {
            let message = serde_json::from_slice::<serde_json::Value>(&body)
                .ok()
                .and_then(|v| v["message"].as_str().map(str::to_string))
                .unwrap_or_else(|| String::from_utf8_lossy(&body).chars().take(200).collect());
            return Err(ClientError::Status { url, status, message });
        }
        self.stats.fetched += 1;
        self.stats.body_bytes += body.len() as u64;
        let immutable = cache_control.is_some_and(|c| c.split(',').any(|d| d.trim().eq_ignore_ascii_case("immutable")));
        if etag.is_some() || immutable {
            let stored = Stored {
                etag,
                immutable,
                body: body.clone(),
            };
            if self.bodies.insert(path.to_string(), stored).is_none() {
                self.order.push_back(path.to_string());
            }
            while self.order.len() > MAX_BODIES {
                if let Some(old) = self.order.pop_front() {
                    self.bodies.remove(&old);
                }
            }
        }
        Ok(body)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_are_checked() {
        assert_eq!(check_base("http://127.0.0.1:8080/").unwrap(), "http://127.0.0.1:8080");
        assert!(check_base("http://127.0.0.1:8080").is_ok());
        assert!(matches!(check_base("127.0.0.1:8080"), Err(ClientError::BadUrl(_))));
        assert!(matches!(check_base("https://x"), Err(ClientError::BadUrl(_))));
        assert!(matches!(check_base("http://x/v1"), Err(ClientError::BadUrl(_))));
    }

    #[test]
    fn a_304_reuses_the_stored_body_and_a_503_waits() {
        let mut s = Store::default();
        assert!(s.begin("/a").is_none());
        let body = s
            .finish(
                "u".into(),
                "/a",
                200,
                Some("\"e\"".into()),
                Some("public, max-age=60"),
                b"xy".to_vec(),
            )
            .unwrap();
        assert!(s.held("/a").is_none(), "a body that may change is revalidated");
        assert_eq!(body, b"xy");
        assert_eq!(s.begin("/a"), Some("\"e\""));
        assert!(matches!(s.head("/a", 304, None, 0), Head::Stored(b) if b == b"xy"));
        assert!(matches!(s.head("/a", 503, Some("3"), 0), Head::Retry(d) if d == Duration::from_secs(3)));
        assert!(matches!(s.head("/a", 503, None, MAX_RETRIES), Head::ReadBody));
        let e = s.finish(
            "u".into(),
            "/a",
            404,
            None,
            None,
            br#"{"message":"no such tile"}"#.to_vec(),
        );
        assert!(matches!(e, Err(ClientError::Status { status: 404, message, .. }) if message == "no such tile"));
        assert_eq!(s.stats.requests, 2);
        assert_eq!((s.stats.fetched, s.stats.revalidated, s.stats.body_bytes), (1, 1, 2));
    }

    #[test]
    fn immutable_bodies_are_reused_without_asking_and_the_store_is_bounded() {
        let mut s = Store::default();
        let cc = Some("public, max-age=31536000, Immutable");
        s.finish("u".into(), "/k?t=20", 200, Some("\"k\"".into()), cc, b"kf".to_vec())
            .unwrap();
        assert_eq!(s.held("/k?t=20").as_deref(), Some(&b"kf"[..]));
        assert_eq!((s.stats.reused, s.stats.requests), (1, 0));
        for i in 0..MAX_BODIES + 10 {
            s.finish("u".into(), &format!("/p{i}"), 200, None, cc, vec![1]).unwrap();
        }
        assert_eq!(s.bodies.len(), MAX_BODIES);
        assert!(s.held("/k?t=20").is_none(), "the oldest is forgotten first");
        assert!(s.held(&format!("/p{}", MAX_BODIES + 9)).is_some());
    }
}
