//! The query parameters of the EDR routes, parsed by hand like [`crate::params`] so
//! that every bad input gets its own error: WKT `coords` (`POINT`, `POLYGON`), the
//! radius' `within` and `within-units`, ISO 8601 `datetime` instants and closed
//! intervals, `parameter-name` (or OWSLib's `parameter_names`), the cube's `z`
//! levels, `f` and `crs`. A parameter a route does not read is refused by name
//! ([`Params::check_known`] with the route's list below): an EDR client that sends
//! one expects it to act.
//!
//! Time: world time t seconds is the instant 1970-01-01T00:00:00Z + t (world time 0
//! is the Unix epoch, no leap seconds), so the instants run from the epoch to
//! 9999-12-31T23:59:59Z, the last second a four-digit year names.

use cloudscape_core::civil::{civil_from_days, days_from_civil, month_days};
use cloudscape_core::world::Layer;

use crate::error::ApiError;
use crate::key::stable_hash_hex;
use crate::params::{Params, check_time, parse_f64};

/// Largest number of vertices of an `area` polygon (all rings): the column mask costs
/// columns × vertices.
pub const MAX_POLYGON_VERTICES: usize = 256;

/// The last world time an EDR instant can name: 9999-12-31T23:59:59Z.
pub const MAX_EDR_TIME: f64 = 253_402_300_799.0;

/// The one CRS of the EDR routes: world metres, x east, y north (see
/// [`super::metadata::CRS_WKT`]). `crs=` may name it and nothing else.
pub const CRS_NAME: &str = "cloudscape-local-metres";

/// `parameter-name` as EDR spells it and as OWSLib 0.35's `query_data` sends it
/// (`parameter_names`, the name of its Python argument): both are read.
pub const PARAMETER_NAME: [&str; 2] = ["parameter-name", "parameter_names"];

/// The parameters each EDR route reads, in groups (the cloudscape extras are `layer`
/// and `level`): every query reads [`known::ANY`], every coverage query
/// [`known::COVERAGE`] too, and each its own.
pub mod known {
    pub const METADATA: &[&str] = &["f"];
    pub const ANY: &[&str] = &["f", "crs"];
    pub const COVERAGE: &[&str] = &["datetime", "parameter-name", "parameter_names", "layer"];
    pub const POSITION: &[&str] = &["coords", "z"];
    pub const AREA: &[&str] = &["coords", "level"];
    pub const RADIUS: &[&str] = &["coords", "within", "within-units", "level"];
    pub const CUBE: &[&str] = &["bbox", "z", "level"];
    pub const ITEMS: &[&str] = &["bbox", "datetime", "limit", "offset", "layer"];
}

fn invalid(name: &str, message: impl Into<String>) -> ApiError {
    ApiError::InvalidParameter {
        name: name.to_string(),
        message: message.into(),
    }
}

/// The text between the keyword `keyword` (case-insensitive) and the end of `value`,
/// which must be one parenthesised group: `POINT (1 2)` gives `1 2`.
fn wkt_body<'a>(value: &'a str, keyword: &str) -> Result<&'a str, ApiError> {
    let v = value.trim();
    let (word, rest) = v
        .split_once('(')
        .ok_or_else(|| invalid("coords", format!("must be WKT {keyword}(…), got `{}`", truncated(v))))?;
    let word = word.trim();
    if !word.eq_ignore_ascii_case(keyword) {
        return Err(invalid(
            "coords",
            format!(
                "must be a WKT {keyword} in x y metres (2D; no Z, M or MULTI types), got `{}`",
                truncated(word)
            ),
        ));
    }
    rest.strip_suffix(')')
        .ok_or_else(|| invalid("coords", format!("unbalanced parentheses in `{}`", truncated(v))))
}

fn truncated(s: &str) -> String {
    s.chars().take(64).collect()
}

/// `x y`: two finite numbers separated by white space.
fn wkt_position(text: &str) -> Result<[f64; 2], ApiError> {
    let parts: Vec<&str> = text.split_whitespace().collect();
    if parts.len() != 2 {
        return Err(invalid(
            "coords",
            format!("a position is two numbers `x y`, got `{}`", truncated(text.trim())),
        ));
    }
    Ok([parse_f64("coords", parts[0])?, parse_f64("coords", parts[1])?])
}

/// `coords=POINT(x y)`: a point in world metres.
pub fn parse_point(value: &str) -> Result<[f64; 2], ApiError> {
    wkt_position(wkt_body(value, "POINT")?)
}

/// A polygon in world metres: an outer ring and any holes, each implicitly closed.
#[derive(Clone, Debug, PartialEq)]
pub struct Polygon {
    pub rings: Vec<Vec<[f64; 2]>>,
}

impl Polygon {
    /// The bounding box of the outer ring, `[x0, y0, x1, y1]`.
    pub fn bbox(&self) -> [f64; 4] {
        let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        for &[x, y] in &self.rings[0] {
            b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
        }
        b
    }

    pub fn vertices(&self) -> usize {
        self.rings.iter().map(Vec::len).sum()
    }

    /// Whether (x, y) lies inside: the even-odd rule over every ring (a point in a
    /// hole is outside), by counting crossings of a ray towards +x.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let mut inside = false;
        for ring in &self.rings {
            for (i, &[ax, ay]) in ring.iter().enumerate() {
                let [bx, by] = ring[(i + 1) % ring.len()];
                if (ay > y) != (by > y) && x < ax + (y - ay) * (bx - ax) / (by - ay) {
                    inside = !inside;
                }
            }
        }
        inside
    }
}

/// `coords=POLYGON((x y, x y, …), (hole …))`: at least three distinct vertices per
/// ring (closing the ring is optional), at most [`MAX_POLYGON_VERTICES`] in all (413).
pub fn parse_polygon(value: &str) -> Result<Polygon, ApiError> {
    let mut rest = wkt_body(value, "POLYGON")?.trim();
    let mut rings = Vec::new();
    loop {
        let body = rest
            .strip_prefix('(')
            .and_then(|r| r.split_once(')'))
            .ok_or_else(|| invalid("coords", "a POLYGON is a list of rings `((x y, x y, …), …)`"))?;
        let mut ring = body.0.split(',').map(wkt_position).collect::<Result<Vec<_>, _>>()?;
        if ring.len() > 1 && ring.first() == ring.last() {
            ring.pop();
        }
        if ring.len() < 3 {
            return Err(invalid("coords", "each POLYGON ring needs at least three vertices"));
        }
        rings.push(ring);
        if rings.iter().map(Vec::len).sum::<usize>() > MAX_POLYGON_VERTICES {
            return Err(ApiError::TooMuchWork(format!(
                "the polygon has more than {MAX_POLYGON_VERTICES} vertices, the limit"
            )));
        }
        rest = body.1.trim();
        match rest.strip_prefix(',') {
            Some(r) => rest = r.trim(),
            None if rest.is_empty() => break,
            None => {
                return Err(invalid(
                    "coords",
                    format!("unexpected `{}` after a ring", truncated(rest)),
                ));
            }
        }
    }
    let polygon = Polygon { rings };
    let [x0, y0, x1, y1] = polygon.bbox();
    if !(x0 < x1 && y0 < y1) {
        return Err(invalid("coords", "the polygon has no area"));
    }
    Ok(polygon)
}

/// A disc in world metres: the `radius` query's `coords` point and `within` distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Disc {
    pub x: f64,
    pub y: f64,
    pub r: f64,
}

/// The units `within-units` may name, and metres in one of each.
const DISTANCE_UNITS: [(&str, f64); 2] = [("m", 1.0), ("km", 1000.0)];

/// The largest `within` radius, metres: 1e7 m, further than any region the limits admit.
const MAX_RADIUS: f64 = 1e7;

/// The `radius` query's disc: `coords=POINT(x y)`, `within=` a distance > 0 in
/// `within-units` (`m` or `km`; metres when absent, as OWSLib 0.35 sends none).
pub fn parse_disc(params: &Params) -> Result<Disc, ApiError> {
    let [x, y] = parse_point(params.required("coords")?)?;
    let within = parse_f64("within", params.required("within")?)?;
    let unit = params.get("within-units").unwrap_or("m");
    let metres = DISTANCE_UNITS
        .iter()
        .find(|(name, _)| name.eq_ignore_ascii_case(unit.trim()))
        .map(|(_, m)| *m)
        .ok_or_else(|| invalid("within-units", format!("must be m or km, got `{}`", truncated(unit))))?;
    let r = within * metres;
    if !(r > 0.0 && r <= MAX_RADIUS) {
        return Err(invalid(
            "within",
            format!("the radius must be over 0 and at most {MAX_RADIUS:e} m, got {r} m"),
        ));
    }
    Ok(Disc { x, y, r })
}

/// The units of `within-units`, for the collection's radius query.
pub fn distance_units() -> Vec<&'static str> {
    DISTANCE_UNITS.iter().map(|(name, _)| *name).collect()
}

/// The shape an `area` or `radius` query answers: the columns of its bounding box
/// whose centres lie inside; the others are null.
#[derive(Clone, Debug, PartialEq)]
pub enum Footprint {
    Polygon(Polygon),
    Disc(Disc),
}

impl Footprint {
    /// `[x0, y0, x1, y1]`, limit-checked as a region before any work.
    pub fn bbox(&self) -> [f64; 4] {
        match self {
            Footprint::Polygon(p) => p.bbox(),
            Footprint::Disc(d) => [d.x - d.r, d.y - d.r, d.x + d.r, d.y + d.r],
        }
    }

    /// Whether (x, y) lies inside (a disc's edge is inside).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        match self {
            Footprint::Polygon(p) => p.contains(x, y),
            Footprint::Disc(d) => (x - d.x).powi(2) + (y - d.y).powi(2) <= d.r * d.r,
        }
    }

    /// The CPU seconds of testing one column.
    pub fn cost_per_column(&self) -> f64 {
        match self {
            Footprint::Polygon(p) => p.vertices() as f64 * 2e-9,
            Footprint::Disc(_) => 2e-9,
        }
    }

    /// The shape in a cache key: `(name, value)`.
    pub fn key(&self) -> (&'static str, String) {
        match self {
            Footprint::Polygon(p) => ("poly", stable_hash_hex(format!("{:?}", p.rings).as_bytes())),
            Footprint::Disc(d) => ("disc", format!("{},{},{}", d.x, d.y, d.r)),
        }
    }
}

/// The times of a `datetime`: an instant (`t1 == t0`, `interval` false) or a
/// closed interval `t0/t1`, world seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Datetime {
    pub t0: f64,
    pub t1: f64,
    pub interval: bool,
}

impl Datetime {
    /// The times asked: `t0`, `t0 + step`, … <= `t1` (one for an instant). More than
    /// `max` is refused (413) before anything is allocated.
    pub fn times(&self, step: f64, max: u32) -> Result<Vec<f64>, ApiError> {
        let points = ((self.t1 - self.t0) / step).floor() + 1.0;
        if points > max as f64 {
            return Err(ApiError::SeriesTooLong {
                points: points.min(u64::MAX as f64) as u64,
                max,
            });
        }
        Ok((0..points as u64)
            .map(|i| (self.t0 + i as f64 * step).min(self.t1))
            .collect())
    }
}

/// `datetime=`: an ISO 8601 instant (`2024-05-01T12:00:00Z`, a date, or plain world
/// seconds) or a closed interval `a/b` of two of them. Open ends (`../b`, `a/..`)
/// are refused: a world clock has no "latest".
pub fn parse_datetime(params: &Params) -> Result<Datetime, ApiError> {
    let value = params.required("datetime")?;
    let parts: Vec<&str> = value.split('/').collect();
    if parts.iter().any(|p| p.trim().is_empty() || p.trim() == "..") {
        return Err(invalid(
            "datetime",
            "open-ended intervals are not supported: give both ends, `start/end`",
        ));
    }
    match parts[..] {
        [one] => {
            let t = parse_instant(one)?;
            Ok(Datetime {
                t0: t,
                t1: t,
                interval: false,
            })
        }
        [a, b] => {
            let (t0, t1) = (parse_instant(a)?, parse_instant(b)?);
            if t1 < t0 {
                return Err(invalid("datetime", "the interval ends before it starts"));
            }
            Ok(Datetime { t0, t1, interval: true })
        }
        _ => Err(invalid("datetime", "an instant or one interval `start/end`")),
    }
}

/// One instant: RFC 3339 / ISO 8601 extended (`YYYY-MM-DDTHH:MM:SS[.fff](Z|±HH:MM)`,
/// or a date `YYYY-MM-DD`, midnight UTC) or a decimal number of world seconds.
pub fn parse_instant(text: &str) -> Result<f64, ApiError> {
    let s = text.trim();
    let t = if s.len() >= 10 && s.as_bytes()[4] == b'-' {
        parse_iso(s).ok_or_else(|| {
            invalid(
                "datetime",
                format!(
                    "`{}` is not an ISO 8601 instant (YYYY-MM-DDTHH:MM:SSZ, a date, or world seconds)",
                    truncated(s)
                ),
            )
        })?
    } else {
        check_time(parse_f64("datetime", s)?)?
    };
    if !(0.0..=MAX_EDR_TIME).contains(&t) {
        return Err(ApiError::DatetimeOutOfRange(truncated(s)));
    }
    Ok(t)
}

fn digits(s: &str) -> Option<i64> {
    (!s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()))
        .then(|| s.parse().ok())
        .flatten()
}

/// Seconds since the epoch of an ISO 8601 extended date or date-time with a zone.
/// Split only at ASCII separators (never by byte counts), so that no input, whatever
/// characters it holds, is cut inside one.
fn parse_iso(s: &str) -> Option<f64> {
    let (date, time) = match s.split_once(['T', 't']) {
        Some((date, time)) => (date, Some(time)),
        None => (s, None),
    };
    let mut d = date.split('-');
    let (y, m, day) = (digits(d.next()?)?, digits(d.next()?)?, digits(d.next()?)?);
    if d.next().is_some() || date.len() != 10 || !(1..=12).contains(&m) || day < 1 || day > month_days(y, m) {
        return None;
    }
    let mut seconds = days_from_civil(y, m, day) as f64 * 86_400.0;
    if let Some(time) = time {
        let (clock, offset) = if let Some(c) = time.strip_suffix(['Z', 'z']) {
            (c, 0)
        } else {
            let (clock, zone) = time.rsplit_once(['+', '-'])?;
            // The sign is the one byte between them.
            let sign = if time.as_bytes().get(clock.len()) == Some(&b'-') {
                -1
            } else {
                1
            };
            let (oh, om) = zone.split_once(':')?;
            let (oh, om) = (digits(oh)?, digits(om)?);
            if oh > 23 || om > 59 {
                return None;
            }
            (clock, sign * (oh * 3600 + om * 60))
        };
        let mut c = clock.split(':');
        let (h, mi, sec) = (digits(c.next()?)?, digits(c.next()?)?, c.next().unwrap_or("00"));
        let (whole, fraction) = sec.split_once('.').unwrap_or((sec, ""));
        let whole = digits(whole)?;
        if c.next().is_some() || h > 23 || mi > 59 || whole > 59 {
            return None;
        }
        // Any number of fraction digits (RFC 3339), all of them digits: `.5e3` or
        // `.5é` is not a fraction.
        let fraction = if fraction.is_empty() {
            0.0
        } else if fraction.bytes().all(|b| b.is_ascii_digit()) {
            format!("0.{fraction}").parse::<f64>().ok()?
        } else {
            return None;
        };
        seconds += (h * 3600 + mi * 60 + whole - offset) as f64 + fraction;
    }
    Some(seconds)
}

/// World time `t` (0 <= t <= [`MAX_EDR_TIME`]) as the ISO 8601 instant it stands for,
/// with as many fraction digits as it needs (at most 9).
pub fn format_instant(t: f64) -> String {
    let mut whole = t.floor() as i64;
    let mut nanos = ((t - t.floor()) * 1e9).round() as i64;
    if nanos >= 1_000_000_000 {
        whole += 1;
        nanos = 0;
    }
    let (y, m, d) = civil_from_days(whole.div_euclid(86_400));
    let s = whole.rem_euclid(86_400);
    let mut out = format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60);
    if nanos > 0 {
        out.push_str(format!(".{nanos:09}").trim_end_matches('0'));
    }
    out.push('Z');
    out
}

/// A quantity the EDR routes answer (`parameter-name`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Quantity {
    CloudCover,
    Density,
    CloudBase,
    CloudTop,
    PrecipitationRate,
}

impl Quantity {
    pub const ALL: [Quantity; 5] = [
        Quantity::CloudCover,
        Quantity::Density,
        Quantity::CloudBase,
        Quantity::CloudTop,
        Quantity::PrecipitationRate,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Quantity::CloudCover => "cloud_cover",
            Quantity::Density => "density",
            Quantity::CloudBase => "cloud_base",
            Quantity::CloudTop => "cloud_top",
            Quantity::PrecipitationRate => "precipitation_rate",
        }
    }

    /// Whether the quantity has a value per cell (the cube's `z` levels) rather than
    /// per column.
    pub fn per_cell(self) -> bool {
        matches!(self, Quantity::CloudCover | Quantity::Density)
    }
}

/// `parameter-name=a,b` (or `parameter_names=a,b`, not both): the quantities asked,
/// in [`Quantity::ALL`]'s order (so that the same set gives the same bytes), or
/// `default` when absent.
pub fn parse_quantities(params: &Params, default: &[Quantity]) -> Result<Vec<Quantity>, ApiError> {
    let given: Vec<(&str, &str)> = PARAMETER_NAME
        .iter()
        .filter_map(|&name| params.get(name).map(|v| (name, v)))
        .collect();
    let (spelling, value) = match given[..] {
        [] => return Ok(default.to_vec()),
        [one] => one,
        _ => {
            return Err(invalid(
                "parameter-name",
                "give parameter-name or parameter_names (OWSLib's spelling), not both",
            ));
        }
    };
    let mut asked = Vec::new();
    for name in value.split(',').map(str::trim) {
        let q = Quantity::ALL.into_iter().find(|q| q.name() == name).ok_or_else(|| {
            invalid(
                spelling,
                format!(
                    "unknown parameter `{}`; the parameters are {}",
                    truncated(name),
                    Quantity::ALL.map(Quantity::name).join(", ")
                ),
            )
        })?;
        asked.push(q);
    }
    asked.sort();
    asked.dedup();
    Ok(asked)
}

/// The cube's `z`: an interval `a/b` (the levels of `layer` whose centres lie within
/// it) or a list `a,b,…` (the levels holding each altitude, which must lie inside the
/// layer), as ascending level indices; `None` when absent (whole columns).
pub fn parse_levels(params: &Params, layer: &Layer) -> Result<Option<Vec<usize>>, ApiError> {
    let Some(value) = params.get("z") else { return Ok(None) };
    let centre = |k: usize| layer.base + (k as f64 + 0.5) * layer.cell_height;
    let mut levels: Vec<usize> = if let Some((a, b)) = value.split_once('/') {
        if a.trim_start().starts_with(['R', 'r']) {
            return Err(invalid("z", "repeating intervals (Rn/…) are not supported"));
        }
        let (a, b) = (parse_f64("z", a)?, parse_f64("z", b)?);
        let (lo, hi) = (a.min(b), a.max(b));
        (0..layer.depth as usize)
            .filter(|&k| (lo..=hi).contains(&centre(k)))
            .collect()
    } else {
        value
            .split(',')
            .map(|v| {
                let z = parse_f64("z", v)?;
                if !(layer.base <= z && z < layer.top()) {
                    return Err(invalid(
                        "z",
                        format!(
                            "{z} m is outside layer `{}` ({} to {} m)",
                            layer.name,
                            layer.base,
                            layer.top()
                        ),
                    ));
                }
                Ok((((z - layer.base) / layer.cell_height) as usize).min(layer.depth as usize - 1))
            })
            .collect::<Result<_, _>>()?
    };
    levels.sort_unstable();
    levels.dedup();
    if levels.is_empty() {
        return Err(invalid(
            "z",
            format!(
                "selects no level of layer `{}` (level centres from {} to {} m)",
                layer.name,
                centre(0),
                centre(layer.depth as usize - 1)
            ),
        ));
    }
    Ok(Some(levels))
}

/// The checks every query makes before it reads anything: the parameters it reads
/// (the `known` groups and [`known::ANY`]; any other is refused by name), `f` among
/// `formats`, and `crs`.
pub fn check_query(params: &Params, known: &[&[&str]], formats: &[&str]) -> Result<(), ApiError> {
    let read: Vec<&str> = known
        .iter()
        .chain([&known::ANY])
        .flat_map(|g| g.iter().copied())
        .collect();
    params.check_known(&read)?;
    check_format(params, formats)?;
    check_crs(params)
}

/// `f=`: the routes answer one format each; `f` may name it (case-insensitive).
pub fn check_format(params: &Params, accepted: &[&str]) -> Result<(), ApiError> {
    match params.get("f") {
        Some(f) if !accepted.iter().any(|a| a.eq_ignore_ascii_case(f)) => Err(invalid(
            "f",
            format!("this route answers {}; got `{}`", accepted.join(" or "), truncated(f)),
        )),
        _ => Ok(()),
    }
}

/// `crs=`: absent or [`CRS_NAME`]; a geographic CRS would silently misplace
/// everything, so any other is refused.
pub fn check_crs(params: &Params) -> Result<(), ApiError> {
    match params.get("crs") {
        Some(c) if c != CRS_NAME => Err(invalid(
            "crs",
            format!("the only CRS is {CRS_NAME} (world metres, x east, y north)"),
        )),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(pairs: &[(&str, &str)]) -> Params {
        Params(pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect())
    }

    #[test]
    fn instants_round_trip_through_iso_8601() {
        assert_eq!(parse_instant("1970-01-01T00:00:00Z").unwrap(), 0.0);
        assert_eq!(parse_instant("1970-01-01T00:00:20Z").unwrap(), 20.0);
        assert_eq!(parse_instant("20").unwrap(), 20.0);
        assert_eq!(parse_instant("1970-01-02").unwrap(), 86_400.0);
        assert_eq!(parse_instant("1970-01-01T01:00:00+01:00").unwrap(), 0.0);
        assert_eq!(parse_instant("2000-02-29T12:30:15.25Z").unwrap(), 951_827_415.25);
        assert_eq!(parse_instant("9999-12-31T23:59:59Z").unwrap(), MAX_EDR_TIME);
        for t in [0.0, 2.5, 86_399.0, 951_827_415.25, 1e9, MAX_EDR_TIME] {
            assert_eq!(parse_instant(&format_instant(t)).unwrap(), t, "{}", format_instant(t));
        }
        assert_eq!(format_instant(0.0), "1970-01-01T00:00:00Z");
        assert_eq!(format_instant(2.5), "1970-01-01T00:00:02.5Z");
    }

    #[test]
    fn bad_instants_are_refused() {
        for bad in [
            "1970-13-01T00:00:00Z",
            "1970-02-30",
            "1970-01-01T00:00:00",
            "1970-01-01T24:00:00Z",
            "soon",
            // Multibyte characters where digits belong, at every place a parser could
            // cut by byte counts.
            "2024-05-01T12:00:00.12345678éZ",
            "2024-05-01T12:00:00.1234567890éZ",
            "2024-05-01T12:00:00.éZ",
            "2024-05-01T12:00:00.5e3Z",
            "2024-05-01T12:00:00+0é:00",
            "2024-05-01T12:00:00é+01:00",
            "2024-05-0éT12:00:00Z",
            "é024-05-01T12:00:00Z",
            "2024-é5-01",
            "2024-05-01Té",
        ] {
            assert!(
                matches!(
                    parse_instant(bad),
                    Err(ApiError::InvalidParameter { .. } | ApiError::InvalidNumber { .. })
                ),
                "{bad}"
            );
        }
        assert!(matches!(
            parse_instant("1969-12-31T23:59:59Z"),
            Err(ApiError::DatetimeOutOfRange(_))
        ));
        assert!(matches!(parse_instant("-1"), Err(ApiError::TimeOutOfRange(_))));
        assert!(matches!(parse_instant("1e12"), Err(ApiError::DatetimeOutOfRange(_))));
    }

    #[test]
    fn intervals_are_closed_and_bounded() {
        let d = parse_datetime(&params(&[("datetime", "0/30")])).unwrap();
        assert_eq!(d.times(10.0, 8).unwrap(), vec![0.0, 10.0, 20.0, 30.0]);
        assert!(matches!(
            d.times(1.0, 8),
            Err(ApiError::SeriesTooLong { points: 31, max: 8 })
        ));
        for open in ["../30", "0/..", "/30", "0/"] {
            assert!(parse_datetime(&params(&[("datetime", open)])).is_err(), "{open}");
        }
        assert!(parse_datetime(&params(&[("datetime", "30/0")])).is_err());
    }

    #[test]
    fn wkt_points_and_polygons() {
        assert_eq!(parse_point(" point ( 150 -2.5 ) ").unwrap(), [150.0, -2.5]);
        for bad in [
            "POINT(1)",
            "POINT(1 2 3)",
            "POINT Z(1 2 3)",
            "MULTIPOINT((1 2))",
            "POINT(1 2",
            "1 2",
        ] {
            assert!(parse_point(bad).is_err(), "{bad}");
        }
        let p = parse_polygon("POLYGON((0 0, 10 0, 10 10, 0 10, 0 0), (4 4, 6 4, 6 6, 4 6))").unwrap();
        assert_eq!(p.bbox(), [0.0, 0.0, 10.0, 10.0]);
        assert!(p.contains(1.0, 1.0) && !p.contains(5.0, 5.0) && !p.contains(11.0, 1.0));
        let tri = parse_polygon("POLYGON((0 0, 10 0, 0 10))").unwrap();
        assert!(tri.contains(2.0, 2.0) && !tri.contains(8.0, 8.0));
        for bad in [
            "POLYGON((0 0, 1 1))",
            "POLYGON((0 0, 1 0, 0 0))",
            "POLYGON(0 0, 1 0, 1 1)",
            "POLYGON((0 0, 1 0, 1 1)) x",
        ] {
            assert!(parse_polygon(bad).is_err(), "{bad}");
        }
        let many = format!(
            "POLYGON(({}))",
            (0..=MAX_POLYGON_VERTICES)
                .map(|i| format!("{i} {}", i % 2))
                .collect::<Vec<_>>()
                .join(",")
        );
        assert!(matches!(parse_polygon(&many), Err(ApiError::TooMuchWork(_))));
    }

    #[test]
    fn a_radius_is_a_disc_in_metres() {
        let d = parse_disc(&params(&[
            ("coords", "POINT(100 200)"),
            ("within", "2"),
            ("within-units", "km"),
        ]))
        .unwrap();
        assert_eq!(
            d,
            Disc {
                x: 100.0,
                y: 200.0,
                r: 2000.0
            }
        );
        let d = parse_disc(&params(&[("coords", "POINT(0 0)"), ("within", "50")])).unwrap();
        assert_eq!(d.r, 50.0);
        let f = Footprint::Disc(d);
        assert_eq!(f.bbox(), [-50.0, -50.0, 50.0, 50.0]);
        assert!(f.contains(30.0, 40.0) && !f.contains(30.0, 40.1));
        for (within, unit) in [("0", "m"), ("-1", "m"), ("1e8", "m"), ("1", "mi"), ("1", "")] {
            assert!(
                matches!(
                    parse_disc(&params(&[
                        ("coords", "POINT(0 0)"),
                        ("within", within),
                        ("within-units", unit)
                    ])),
                    Err(ApiError::InvalidParameter { .. })
                ),
                "{within} {unit}"
            );
        }
        assert!(matches!(
            parse_disc(&params(&[("coords", "POINT(0 0)"), ("within", "nan")])),
            Err(ApiError::NotFinite { .. })
        ));
        assert!(matches!(
            parse_disc(&params(&[("coords", "POINT(0 0)")])),
            Err(ApiError::MissingParameter(_))
        ));
    }

    #[test]
    fn parameter_names_are_canonical() {
        let q = parse_quantities(&params(&[("parameter-name", "density,cloud_cover,density")]), &[]).unwrap();
        assert_eq!(q, vec![Quantity::CloudCover, Quantity::Density]);
        assert!(parse_quantities(&params(&[("parameter-name", "temperature")]), &[]).is_err());
        // OWSLib's spelling is read the same, and an unknown name is refused in it.
        let q = parse_quantities(&params(&[("parameter_names", "cloud_top,density")]), &[]).unwrap();
        assert_eq!(q, vec![Quantity::Density, Quantity::CloudTop]);
        assert!(matches!(
            parse_quantities(&params(&[("parameter_names", "rain")]), &[]),
            Err(ApiError::InvalidParameter { name, .. }) if name == "parameter_names"
        ));
        assert!(
            parse_quantities(
                &params(&[("parameter-name", "density"), ("parameter_names", "density")]),
                &[]
            )
            .is_err()
        );
        assert_eq!(
            parse_quantities(&params(&[]), &Quantity::ALL).unwrap(),
            Quantity::ALL.to_vec()
        );
    }
}
