//! The one path of every cached response. Its key, and so its strong ETag, is known
//! before any work: `If-None-Match` is answered 304 first; then the work is estimated
//! and admitted ([`AppState::admit`]), and the bytes come from the cache or from one
//! computation shared by every request for the same key (single flight, with the
//! sibling keys the same work yields), checked against the response limits and sent
//! within the reply budget. Handlers parse their parameters, build a [`Cached`] and
//! supply the estimate and the computation.

use std::sync::Arc;

use axum::body::Bytes;
use axum::http::{HeaderMap, HeaderName, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::Work;
use cloudscape_core::world::{Keyframe, SnappedTime};

use crate::cache::{Computation, Job};
use crate::encode::{self, Coding};
use crate::error::ApiError;
use crate::key::{CacheKey, if_none_match};
use crate::state::AppState;

/// A cached response: what names its bytes and what its headers say.
pub struct Cached {
    /// Metrics label of the work and of the cache lookups.
    pub kind: &'static str,
    pub key: CacheKey,
    pub content_type: &'static str,
    /// The time the bytes are computed for, when there is one.
    pub time: Option<TimeHeaders>,
    /// How long the answer may be kept.
    pub freshness: Freshness,
    /// The URL that names these bytes canonically (`Content-Location`), when the
    /// request named them another way.
    pub content_location: Option<String>,
}

/// The time of a time-dependent answer, as its headers state it: `X-Cloudscape-T`
/// (the time computed), `X-Cloudscape-Frame` (its index on the frame or keyframe
/// grid) and, for a keyframe, `X-Cloudscape-T1` (the end of its span: the next
/// keyframe's time).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeHeaders {
    pub t: f64,
    pub index: u64,
    pub t1: Option<f64>,
}

impl From<SnappedTime> for TimeHeaders {
    fn from(f: SnappedTime) -> TimeHeaders {
        TimeHeaders {
            t: f.t,
            index: f.index,
            t1: None,
        }
    }
}

impl From<Keyframe> for TimeHeaders {
    fn from(k: Keyframe) -> TimeHeaders {
        TimeHeaders {
            t: k.t0,
            index: k.index,
            t1: Some(k.t1),
        }
    }
}

/// The time a keyframe product was asked for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AskedTime {
    /// `t=` of the request, world seconds.
    Given(f64),
    /// No `t`: the world clock's time `t` now, which runs at `rate` world seconds per
    /// real second (the answer changes at the next keyframe, never final).
    Clock { t: f64, rate: f64 },
}

impl AskedTime {
    /// World seconds.
    pub fn t(self) -> f64 {
        match self {
            AskedTime::Given(t) | AskedTime::Clock { t, .. } => t,
        }
    }
}

/// How long an answer may be kept.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Freshness {
    /// Bytes for exactly the times asked: final (`server.cache_control`, immutable
    /// by default).
    Final,
    /// Bytes for a time snapped to the frame grid (`server.cache_control_other`).
    Snapped,
    /// A keyframe asked by a time inside its span, or by the world clock: `max-age`
    /// the seconds until the next keyframe.
    UntilNextKeyframe(u64),
}

impl Freshness {
    /// Final when every time computed is exactly a time asked, else snapped.
    pub fn of_frames(exact: bool) -> Freshness {
        if exact { Freshness::Final } else { Freshness::Snapped }
    }
}

impl Cached {
    /// A response with no frame time of its own (splat sheets, the sky, the strikes of
    /// the span asked).
    pub fn timeless(kind: &'static str, key: CacheKey, content_type: &'static str) -> Cached {
        Cached {
            kind,
            key,
            content_type,
            time: None,
            freshness: Freshness::Final,
            content_location: None,
        }
    }

    /// A response computed for `frame` when `requested` was asked.
    pub fn at(
        kind: &'static str,
        key: CacheKey,
        content_type: &'static str,
        frame: SnappedTime,
        requested: f64,
    ) -> Cached {
        Cached {
            kind,
            key,
            content_type,
            time: Some(frame.into()),
            freshness: Freshness::of_frames(frame.is_exact(requested)),
            content_location: None,
        }
    }

    /// A keyframe product asked for at `asked`: final when that is the keyframe's own
    /// time, else valid until the next keyframe, with `canonical` (the URL that
    /// names the keyframe) as its `Content-Location`.
    pub fn keyframe(
        kind: &'static str,
        key: CacheKey,
        content_type: &'static str,
        keyframe: Keyframe,
        asked: AskedTime,
        canonical: impl FnOnce() -> String,
    ) -> Cached {
        let exact = matches!(asked, AskedTime::Given(t) if keyframe.is_exact(t));
        // Real seconds until the clock reaches the next keyframe (a time given in the
        // request is taken at one world second per second).
        let (t, rate) = match asked {
            AskedTime::Given(t) => (t, 1.0),
            AskedTime::Clock { t, rate } => (t, rate),
        };
        Cached {
            kind,
            key,
            content_type,
            time: Some(keyframe.into()),
            freshness: if exact {
                Freshness::Final
            } else {
                Freshness::UntilNextKeyframe(((keyframe.t1 - t) / rate).ceil().max(1.0) as u64)
            },
            content_location: (!exact).then(canonical),
        }
    }

    /// Answers with the bytes of the key. `plan`, called only when the client does
    /// not hold them already, gives the estimated work and the job that computes them.
    pub async fn respond<J>(
        self,
        s: &Arc<AppState>,
        headers: &HeaderMap,
        plan: impl FnOnce() -> Result<(Work, J), ApiError>,
    ) -> Result<Response, ApiError>
    where
        J: FnOnce(&Cancel) -> Result<Bytes, ApiError> + Send + 'static,
    {
        let plan = || plan().map(|(work, job)| (work, move |cancel: &Cancel| job(cancel).map(|b| (b, Vec::new()))));
        self.respond_with(s, headers, plan, |_| Ok(HeaderMap::new())).await
    }

    /// [`respond`](Self::respond) for a job that also yields sibling keys' bytes,
    /// with `finish`, which sees the bytes (cached or computed) before they are sent:
    /// it may refuse them, or name headers to add.
    pub async fn respond_with<J>(
        self,
        s: &Arc<AppState>,
        headers: &HeaderMap,
        plan: impl FnOnce() -> Result<(Work, J), ApiError>,
        finish: impl FnOnce(&Bytes) -> Result<HeaderMap, ApiError>,
    ) -> Result<Response, ApiError>
    where
        J: Job,
    {
        let repr = Representation {
            etag: self.key.etag(),
            cache_control: cache_control(s, self.freshness),
            time: self.time,
            content_location: self.content_location,
        };
        let compressible = encode::compressible(self.content_type);
        if let Some(mut not_modified) = repr.not_modified(headers) {
            if compressible {
                not_modified
                    .headers_mut()
                    .insert(header::VARY, HeaderValue::from_static("accept-encoding"));
            }
            return Ok(not_modified);
        }
        let (work, job) = plan()?;
        let work = s.admit(self.kind, work)?;
        let bytes = s
            .cache
            .get_or_compute_with_siblings(
                &s.metrics,
                Computation {
                    kind: self.kind,
                    key: self.key.clone(),
                    work,
                    job,
                },
            )
            .await?;
        let extra = finish(&bytes)?;
        repr.check_size(s, &bytes)?;
        let coding = Coding::negotiate(headers).filter(|_| compressible && bytes.len() >= encode::MIN_COMPRESSED_BYTES);
        let (body, coding) = match coding {
            Some(c) => match s.cache.encoded(&s.metrics, &self.key, c, bytes.clone()).await {
                Some(z) => (z, Some(c)),
                None => (bytes, None),
            },
            None => (bytes, None),
        };
        let mut response = repr.ok(s, self.content_type, body)?;
        let h = response.headers_mut();
        h.extend(extra);
        if let Some(c) = coding {
            h.insert(header::CONTENT_ENCODING, HeaderValue::from_static(c.name()));
        }
        if compressible {
            h.insert(header::VARY, HeaderValue::from_static("accept-encoding"));
        }
        Ok(response)
    }
}

/// The `Cache-Control` of an answer of `freshness`.
pub fn cache_control(s: &AppState, freshness: Freshness) -> String {
    match freshness {
        Freshness::Final => s.settings.cache_control.clone(),
        Freshness::Snapped => s.settings.cache_control_other.clone(),
        Freshness::UntilNextKeyframe(seconds) => format!("public, max-age={seconds}"),
    }
}

/// Headers shared by every computed response.
pub struct Representation {
    pub etag: String,
    pub cache_control: String,
    /// The time the bytes were computed for, if time-dependent.
    pub time: Option<TimeHeaders>,
    /// `Content-Location`: the canonical URL of the bytes, when asked another way.
    pub content_location: Option<String>,
}

impl Representation {
    fn headers(&self) -> HeaderMap {
        let mut h = HeaderMap::new();
        if let Ok(v) = HeaderValue::from_str(&self.etag) {
            h.insert(header::ETAG, v);
        }
        if let Ok(v) = HeaderValue::from_str(&self.cache_control) {
            h.insert(header::CACHE_CONTROL, v);
        }
        if let Some(f) = self.time {
            if let Ok(v) = HeaderValue::from_str(&f.t.to_string()) {
                h.insert(HeaderName::from_static("x-cloudscape-t"), v);
            }
            h.insert(
                HeaderName::from_static("x-cloudscape-frame"),
                HeaderValue::from(f.index),
            );
            if let Some(Ok(v)) = f.t1.map(|t1| HeaderValue::from_str(&t1.to_string())) {
                h.insert(HeaderName::from_static("x-cloudscape-t1"), v);
            }
        }
        if let Some(Ok(v)) = self.content_location.as_deref().map(HeaderValue::from_str) {
            h.insert(header::CONTENT_LOCATION, v);
        }
        h
    }

    /// 413 for a body over `limits.max_response_bytes`.
    pub fn check_size(&self, state: &AppState, body: &Bytes) -> Result<(), ApiError> {
        let max = state.worlds.config().limits.max_response_bytes;
        if body.len() as u64 > max {
            return Err(ApiError::ResponseTooLarge(format!(
                "the answer is {} MiB; the limit is {} MiB (limits.max_response_bytes)",
                body.len() >> 20,
                max >> 20
            )));
        }
        Ok(())
    }

    /// 304 when `If-None-Match` names this representation: no computation needed.
    pub fn not_modified(&self, request: &HeaderMap) -> Option<Response> {
        let inm = request.get(header::IF_NONE_MATCH)?.to_str().ok()?;
        if_none_match(inm, &self.etag).then(|| (StatusCode::NOT_MODIFIED, self.headers()).into_response())
    }

    /// The 200 answer with `body`, which holds its share of the reply budget
    /// ([`crate::reply`]) until it is sent; 503 when the budget is spent. A body over
    /// `limits.max_response_bytes` is refused with 413.
    pub fn ok(&self, state: &AppState, content_type: &'static str, body: Bytes) -> Result<Response, ApiError> {
        self.check_size(state, &body)?;
        let body = state.replies.body(body, state.cache.retry_after())?;
        Ok(self.respond(content_type, body))
    }

    /// The 200 answer for a body known to be small (discovery, a clear-sky sample):
    /// no limit or budget to check.
    pub fn ok_small(&self, content_type: &'static str, body: Bytes) -> Response {
        self.respond(content_type, body.into())
    }

    fn respond(&self, content_type: &'static str, body: axum::body::Body) -> Response {
        let mut h = self.headers();
        h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
        (StatusCode::OK, h, body).into_response()
    }
}
