//! Query and path parameters, parsed by hand so that every bad input gets its own
//! error code instead of a framework's plain-text rejection.

use cloudscape_core::render::{Quality, Sun};

use crate::error::ApiError;

/// The query string of one request as `(name, value)` pairs; the last of repeated
/// names wins. Unknown names are ignored (cache busters, tracking) unless the route
/// checks them ([`Params::check_known`]).
pub struct Params(pub Vec<(String, String)>);

impl Params {
    /// 400 naming the first parameter that is not in `known`.
    pub fn check_known(&self, known: &[&str]) -> Result<(), ApiError> {
        match self.0.iter().find(|(k, _)| !known.contains(&k.as_str())) {
            None => Ok(()),
            Some((name, _)) => Err(ApiError::UnknownParameter {
                name: name.chars().take(64).collect(),
                known: if known.is_empty() {
                    "no parameter".to_string()
                } else {
                    known.join(", ")
                },
            }),
        }
    }

    pub fn get(&self, name: &str) -> Option<&str> {
        self.0.iter().rev().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }

    pub fn required(&self, name: &str) -> Result<&str, ApiError> {
        self.get(name)
            .ok_or_else(|| ApiError::MissingParameter(name.to_string()))
    }

    /// A finite `f64` if present.
    pub fn f64(&self, name: &str) -> Result<Option<f64>, ApiError> {
        self.get(name).map(|v| parse_f64(name, v)).transpose()
    }

    pub fn required_f64(&self, name: &str) -> Result<f64, ApiError> {
        parse_f64(name, self.required(name)?)
    }

    /// A world time `t` (finite, within [0, 1e12]).
    pub fn time(&self, name: &str) -> Result<f64, ApiError> {
        check_time(self.required_f64(name)?)
    }

    /// An optional level `0..=max`.
    pub fn level(&self, max: u32) -> Result<u32, ApiError> {
        match self.get("level") {
            None => Ok(0),
            Some(v) => parse_level(v, max),
        }
    }

    /// `bbox=X0,Y0,X1,Y1` with X0 < X1 and Y0 < Y1, all finite.
    pub fn bbox(&self) -> Result<[f64; 4], ApiError> {
        let b = parse_list("bbox", self.required("bbox")?, 4)?;
        if !(b[0] < b[2] && b[1] < b[3]) {
            return Err(ApiError::InvalidBbox);
        }
        Ok([b[0], b[1], b[2], b[3]])
    }
}

/// `quality=` if given: one of the presets.
pub fn parse_quality(params: &Params) -> Result<Option<Quality>, ApiError> {
    params
        .get("quality")
        .map(|q| {
            Quality::parse(q).ok_or_else(|| ApiError::InvalidParameter {
                name: "quality".to_string(),
                message: format!("must be one of fast, balanced, accurate, reference, reference-single; got `{q}`"),
            })
        })
        .transpose()
}

/// `sun=AZ,EL` if given (degrees; elevation within [-90, 90]).
pub fn parse_sun(params: &Params) -> Result<Option<Sun>, ApiError> {
    let Some(s) = params.get("sun") else { return Ok(None) };
    let v = parse_list("sun", s, 2)?;
    Sun::new(v[0], v[1])
        .map(Some)
        .ok_or_else(|| ApiError::InvalidParameter {
            name: "sun".to_string(),
            message: "elevation must be within [-90, 90] degrees".to_string(),
        })
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

/// Checks a world time against the contract's range.
pub fn check_time(t: f64) -> Result<f64, ApiError> {
    cloudscape_core::density::check_time(t).map_err(ApiError::from)
}

/// A finite decimal number. `nan`, `inf` are recognised as numbers and refused as such.
pub fn parse_f64(name: &str, value: &str) -> Result<f64, ApiError> {
    let v: f64 = value.trim().parse().map_err(|_| ApiError::InvalidNumber {
        name: name.to_string(),
        value: value.to_string(),
    })?;
    if !v.is_finite() {
        return Err(ApiError::NotFinite {
            name: name.to_string(),
            value: value.to_string(),
        });
    }
    Ok(v)
}

/// Exactly `n` comma-separated finite numbers.
pub fn parse_list(name: &str, value: &str, n: usize) -> Result<Vec<f64>, ApiError> {
    let parts: Vec<&str> = value.split(',').collect();
    if parts.len() != n {
        return Err(ApiError::InvalidParameter {
            name: name.to_string(),
            message: format!("needs {n} comma-separated numbers, got `{value}`"),
        });
    }
    parts.iter().map(|p| parse_f64(name, p)).collect()
}

/// True for `-?[0-9]+`: a well-formed integer, whatever its size.
fn is_integer_syntax(s: &str) -> bool {
    let digits = s.strip_prefix('-').unwrap_or(s);
    !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit())
}

/// A tile or LOD level. A well-formed integer outside `0..=max` (negative, or too big
/// for any integer type) is out of range (422); anything else is malformed (400).
pub fn parse_level(value: &str, max: u32) -> Result<u32, ApiError> {
    if !is_integer_syntax(value) {
        return Err(ApiError::InvalidNumber {
            name: "z".to_string(),
            value: value.to_string(),
        });
    }
    match value.parse::<u32>() {
        Ok(z) if z <= max => Ok(z),
        _ => Err(ApiError::LevelOutOfRange {
            level: value.to_string(),
            max,
        }),
    }
}

/// A tile coordinate: any `i64`; larger well-formed integers are out of range (422).
pub fn parse_tile_coordinate(name: &str, value: &str) -> Result<i64, ApiError> {
    if !is_integer_syntax(value) {
        return Err(ApiError::InvalidNumber {
            name: name.to_string(),
            value: value.to_string(),
        });
    }
    value
        .parse::<i64>()
        .map_err(|_| ApiError::CoordinatesOutOfRange(format!("{name} = {value} does not fit in 64 bits")))
}

impl Params {
    /// The query of `uri`, percent-decoded, as the handlers see it (also the entry point
    /// of the `query` fuzz target).
    pub fn from_uri(uri: &axum::http::Uri) -> Result<Params, ApiError> {
        let axum::extract::Query(pairs) =
            axum::extract::Query::<Vec<(String, String)>>::try_from_uri(uri).map_err(|e| {
                ApiError::InvalidParameter {
                    name: "query".to_string(),
                    message: e.body_text(),
                }
            })?;
        Ok(Params(pairs))
    }
}

/// Percent-encodes a query name or value (RFC 3986 unreserved characters kept).
fn encode_component(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' | b',' => out.push(b as char),
            _ => out.push_str(&format!("%{b:02X}")),
        }
    }
    out
}

impl Params {
    /// The query string of these parameters with `name` set to `value` (in the place
    /// of its last occurrence; the others dropped, as [`Params::get`] reads the last),
    /// re-encoded: the query of the URL that names the same bytes canonically.
    pub fn query_with(&self, name: &str, value: &str) -> String {
        let last = self.0.iter().rposition(|(k, _)| k == name);
        let mut parts = Vec::with_capacity(self.0.len() + 1);
        for (i, (k, v)) in self.0.iter().enumerate() {
            if k != name {
                parts.push(format!("{}={}", encode_component(k), encode_component(v)));
            } else if Some(i) == last {
                parts.push(format!("{}={}", encode_component(k), encode_component(value)));
            }
        }
        if last.is_none() {
            parts.push(format!("{}={}", encode_component(name), encode_component(value)));
        }
        parts.join("&")
    }
}

impl<S: Send + Sync> axum::extract::FromRequestParts<S> for Params {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut axum::http::request::Parts, _state: &S) -> Result<Self, ApiError> {
        Params::from_uri(&parts.uri)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_classified() {
        assert_eq!(parse_f64("t", " 12.5").unwrap(), 12.5);
        assert!(matches!(parse_f64("t", "abc"), Err(ApiError::InvalidNumber { .. })));
        assert!(matches!(parse_f64("t", ""), Err(ApiError::InvalidNumber { .. })));
        assert!(matches!(parse_f64("t", "NaN"), Err(ApiError::NotFinite { .. })));
        assert!(matches!(parse_f64("t", "-inf"), Err(ApiError::NotFinite { .. })));
        assert!(matches!(parse_f64("t", "1e999"), Err(ApiError::NotFinite { .. })));
    }

    #[test]
    fn levels_and_coordinates_are_range_checked() {
        assert_eq!(parse_level("3", 16).unwrap(), 3);
        assert!(matches!(parse_level("17", 16), Err(ApiError::LevelOutOfRange { .. })));
        assert!(matches!(parse_level("-1", 16), Err(ApiError::LevelOutOfRange { .. })));
        assert!(matches!(
            parse_level("99999999999999999999", 16),
            Err(ApiError::LevelOutOfRange { .. })
        ));
        assert!(matches!(parse_level("1.5", 16), Err(ApiError::InvalidNumber { .. })));
        assert_eq!(parse_tile_coordinate("x", "-9223372036854775808").unwrap(), i64::MIN);
        assert!(matches!(
            parse_tile_coordinate("x", "9223372036854775808"),
            Err(ApiError::CoordinatesOutOfRange(_))
        ));
        assert!(matches!(
            parse_tile_coordinate("x", "0x10"),
            Err(ApiError::InvalidNumber { .. })
        ));
    }

    #[test]
    fn a_canonical_query_replaces_one_parameter_and_keeps_the_rest() {
        let p = Params(vec![
            ("t".into(), "1".into()),
            ("layer".into(), "a b&c".into()),
            ("t".into(), "1234.5".into()),
            ("sun".into(), "10,20".into()),
        ]);
        assert_eq!(p.query_with("t", "1220"), "layer=a%20b%26c&t=1220&sun=10,20");
        assert_eq!(Params(vec![]).query_with("t", "5"), "t=5");
        // What it writes reads back as the same parameters.
        let uri: axum::http::Uri = format!("/x?{}", p.query_with("t", "1220")).parse().unwrap();
        let back = Params::from_uri(&uri).unwrap();
        assert_eq!(
            (back.get("layer"), back.get("t"), back.get("sun")),
            (Some("a b&c"), Some("1220"), Some("10,20"))
        );
    }

    #[test]
    fn unknown_parameters_are_named() {
        let p = Params(vec![("f".into(), "json".into()), ("colour".into(), "blue".into())]);
        assert_eq!(
            p.check_known(&["f", "bbox"]),
            Err(ApiError::UnknownParameter {
                name: "colour".into(),
                known: "f, bbox".into()
            })
        );
        assert!(p.check_known(&["colour", "f"]).is_ok());
        assert!(Params(vec![]).check_known(&[]).is_ok());
    }

    #[test]
    fn bbox_must_be_ordered() {
        let p = Params(vec![("bbox".into(), "0,0,10,10".into())]);
        assert_eq!(p.bbox().unwrap(), [0.0, 0.0, 10.0, 10.0]);
        let p = Params(vec![("bbox".into(), "10,0,0,10".into())]);
        assert_eq!(p.bbox(), Err(ApiError::InvalidBbox));
        let p = Params(vec![("bbox".into(), "0,0,10".into())]);
        assert!(matches!(p.bbox(), Err(ApiError::InvalidParameter { .. })));
    }
}
