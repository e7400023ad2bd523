//! The EDR `items` query: the lightning strikes of a box and span
//! ([`crate::lightning::StrikeQuery`], what `/v1/worlds/{world}/lightning` lists) as a
//! GeoJSON `FeatureCollection` of `Point` features, paged like OGC API – Features
//! (`limit`, `offset`, `numberMatched`, `numberReturned`, a `next` link).
//!
//! Coordinates are world metres `[x, y, z]`, as in every EDR answer of this server,
//! not RFC 7946's WGS 84 longitude and latitude: a game world has none. Times are
//! half-open like `/lightning`'s (`datetime=a/b` lists a <= t < b), so consecutive
//! intervals never list a strike twice.

use axum::body::Bytes;
use serde::Serialize;

use cloudscape_core::weather::lightning::{Strike, StrikeKind};
use cloudscape_core::world::World;

use super::query::format_instant;
use crate::error::ApiError;
use crate::params::Params;
use crate::queries::json_bytes;

/// The media type of GeoJSON.
pub const MEDIA_TYPE: &str = "application/geo+json";

/// The most features a page holds, and the page size when `limit` is absent.
pub const MAX_LIMIT: usize = 10_000;

/// A page of the strikes: `limit` of them from `offset`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Page {
    pub limit: usize,
    pub offset: usize,
}

impl Page {
    /// `limit` (1 to [`MAX_LIMIT`], default that) and `offset` (default 0).
    pub fn parse(params: &Params) -> Result<Page, ApiError> {
        let count = |name: &str, default: usize, min: usize, max: usize| -> Result<usize, ApiError> {
            let Some(v) = params.get(name) else { return Ok(default) };
            match v.trim().parse::<usize>() {
                Ok(n) if (min..=max).contains(&n) => Ok(n),
                _ => Err(ApiError::InvalidParameter {
                    name: name.to_string(),
                    message: format!(
                        "must be an integer from {min} to {max}, got `{}`",
                        v.chars().take(32).collect::<String>()
                    ),
                }),
            }
        };
        Ok(Page {
            limit: count("limit", MAX_LIMIT, 1, MAX_LIMIT)?,
            offset: count("offset", 0, 0, usize::MAX)?,
        })
    }
}

#[derive(Serialize)]
struct Point {
    #[serde(rename = "type")]
    kind: &'static str,
    /// `[x, y, z]`, world metres.
    coordinates: [f64; 3],
}

#[derive(Serialize)]
struct StrikeProperties {
    /// The strike's time as an ISO 8601 instant (world time t = 1970-01-01T00:00:00Z + t s).
    datetime: String,
    /// The same time, world seconds.
    t: f64,
    kind: StrikeKind,
    /// The layer whose cloud flashed.
    layer: String,
}

#[derive(Serialize)]
struct Feature {
    #[serde(rename = "type")]
    kind: &'static str,
    geometry: Point,
    properties: StrikeProperties,
}

#[derive(Serialize)]
struct Link {
    href: String,
    rel: &'static str,
    #[serde(rename = "type")]
    media: &'static str,
    title: &'static str,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct FeatureCollection {
    #[serde(rename = "type")]
    kind: &'static str,
    features: Vec<Feature>,
    number_matched: usize,
    number_returned: usize,
    links: Vec<Link>,
}

/// The page of `strikes` (each with its layer's index, by time) as GeoJSON. `next`
/// gives the URL of the page from an offset (relative to the items URL), for the
/// `next` link when there is a following page.
pub fn feature_collection(
    world: &World,
    strikes: &[(usize, Strike)],
    page: Page,
    next: impl FnOnce(usize) -> String,
) -> Result<Bytes, ApiError> {
    let features: Vec<Feature> = strikes
        .iter()
        .skip(page.offset)
        .take(page.limit)
        .map(|(i, s)| Feature {
            kind: "Feature",
            geometry: Point {
                kind: "Point",
                coordinates: [s.x, s.y, s.z],
            },
            properties: StrikeProperties {
                datetime: format_instant(s.t),
                t: s.t,
                kind: s.kind,
                layer: world.layers[*i].name.clone(),
            },
        })
        .collect();
    let end = page.offset.saturating_add(features.len());
    let links = (end < strikes.len())
        .then(|| Link {
            href: next(end),
            rel: "next",
            media: MEDIA_TYPE,
            title: "The next page",
        })
        .into_iter()
        .collect();
    json_bytes(&FeatureCollection {
        kind: "FeatureCollection",
        number_matched: strikes.len(),
        number_returned: features.len(),
        features,
        links,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(pairs: &[(&str, &str)]) -> Params {
        Params(pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect())
    }

    #[test]
    fn pages_are_bounded_integers() {
        assert_eq!(
            Page::parse(&params(&[])).unwrap(),
            Page {
                limit: MAX_LIMIT,
                offset: 0
            }
        );
        assert_eq!(
            Page::parse(&params(&[("limit", "5"), ("offset", "10")])).unwrap(),
            Page { limit: 5, offset: 10 }
        );
        for (name, bad) in [
            ("limit", "0"),
            ("limit", "10001"),
            ("limit", "-1"),
            ("offset", "x"),
            ("limit", "1.5"),
        ] {
            assert!(
                matches!(Page::parse(&params(&[(name, bad)])), Err(ApiError::InvalidParameter { name: n, .. }) if n == name),
                "{name}={bad}"
            );
        }
    }
}
