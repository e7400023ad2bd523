//! The hostile request generator: request `i` of seed `s` is a pure function of
//! `(s, i)` (a counter-based hash, like the automaton's draws), so any request of a
//! soak can be regenerated from the two numbers in its report.
//!
//! Every route of PRODUCT.md is covered, with each parameter drawn from a mix of valid
//! values, boundary values (0, the smallest positive float, 1e12, the largest tile
//! coordinate, i64 overflow, ±90°), malformed values (`nan`, `1e`, `0x10`, unicode
//! digits, empty), oversized values (100 kB numbers, 10⁵-element lists), odd encodings
//! (percent-encoded NUL, invalid and overlong UTF-8, truncated escapes, `+`) and odd
//! paths (dot segments, double slashes, encoded slashes). A smaller share is hostile at
//! the protocol level: raw invalid bytes in the request target, huge or numerous
//! headers, unknown methods; the HTTP layer rejects those before any route sees them.

use cloudscape_core::products::Product;

/// Longest request target the HTTP layer (the `http` crate's `Uri`) accepts; longer
/// ones are refused with a 414 (and the JSON error) before routing.
pub const MAX_URI_BYTES: usize = 65_534;

/// What a generated request is, for judging its answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Well-formed HTTP to a known route: the answer is a product with the route's
    /// content type, a 304, or a JSON error (`{"error", "message"}`).
    Route,
    /// Malformed at the HTTP level (raw bytes, header floods, bad methods, targets over
    /// [`MAX_URI_BYTES`]): the HTTP layer may answer with a 4xx (400, 414, 431) with the
    /// JSON error body, or close the connection.
    Protocol,
}

/// A header name and its raw value (the value need not be valid UTF-8).
pub type RawHeader = (String, Vec<u8>);

/// One generated request, ready to write on a socket.
#[derive(Clone, Debug)]
pub struct FuzzRequest {
    pub method: String,
    /// The request target (path and query) as raw bytes: it may not be valid UTF-8.
    pub target: Vec<u8>,
    /// Extra headers, raw.
    pub headers: Vec<RawHeader>,
    pub kind: Kind,
    /// The content type a 200 must have, when the route fixes it.
    pub ok_type: Option<&'static str>,
}

impl FuzzRequest {
    /// The target for reports: lossy UTF-8, truncated to `max` characters.
    pub fn display_target(&self, max: usize) -> String {
        let s = String::from_utf8_lossy(&self.target);
        if s.chars().count() > max {
            format!(
                "{}… ({} bytes)",
                s.chars().take(max).collect::<String>(),
                self.target.len()
            )
        } else {
            s.into_owned()
        }
    }

    /// The bytes of the request as HTTP/1.1, with `Host` and keep-alive.
    pub fn to_bytes(&self, host: &str) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.target.len() + 256);
        out.extend_from_slice(self.method.as_bytes());
        out.push(b' ');
        out.extend_from_slice(&self.target);
        out.extend_from_slice(b" HTTP/1.1\r\nHost: ");
        out.extend_from_slice(host.as_bytes());
        out.extend_from_slice(b"\r\n");
        for (k, v) in &self.headers {
            out.extend_from_slice(k.as_bytes());
            out.extend_from_slice(b": ");
            out.extend_from_slice(v);
            out.extend_from_slice(b"\r\n");
        }
        out.extend_from_slice(b"\r\n");
        out
    }
}

/// SplitMix64 (Steele et al. 2014), used as a counter-based stream per request.
struct Draws(u64);

impl Draws {
    fn new(seed: u64, index: u64) -> Draws {
        let mut d = Draws(seed ^ index.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        d.next();
        d
    }

    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (n > 0).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    /// True with probability `p`.
    fn chance(&mut self, p: f64) -> bool {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64 <= p
    }

    fn pick<'a>(&mut self, items: &[&'a str]) -> &'a str {
        items[self.below(items.len())]
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next() >> 11) as f64 / (1u64 << 53) as f64)
    }
}

/// Numbers at the edges of what parameters accept.
const BOUNDARY_NUMBERS: &[&str] = &[
    "0",
    "-0",
    "+0",
    "5e-324",
    "-5e-324",
    "2.2250738585072014e-308",
    "1e12",
    "1000000000000.0001",
    "999999999999.9999",
    "1e13",
    "-1",
    "1e308",
    "-1e308",
    "1.7976931348623157e308",
    "1e309",
    "-1e309",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "infinity",
    "1099511627776",
    "-1099511627776",
    "281474976710656",
    "9007199254740993",
    "19.999999999999996",
    "20",
    "0.1",
    "86400",
    "90",
    "-90",
    "90.00000000000001",
    "180",
    "360",
    "170",
    "1",
];

/// Text that is not a number, or is one only in other syntaxes.
const MALFORMED: &[&str] = &[
    "",
    " ",
    "abc",
    "1e",
    "1e+",
    "--1",
    "0x10",
    "1_000",
    "1,5",
    "１",
    "٣",
    "1.2.3",
    ".",
    "-",
    "+",
    "e5",
    "true",
    "null",
    "[]",
    "{}",
    "'0'",
    "\"0\"",
    "%00",
    "%FF",
    "%C0%AF",
    "%ED%A0%80",
    "%",
    "%2",
    "%zz",
    "%25",
    "%26t%3D0",
    "0%00",
    "1%20",
    "+1+",
    "%F0%9F%98%80",
    "\u{202e}1",
];

/// Integers for levels and tile coordinates.
const INTEGERS: &[&str] = &[
    "0",
    "1",
    "-1",
    "2",
    "16",
    "17",
    "20",
    "21",
    "40",
    "41",
    "4294967295",
    "4294967296",
    "-2147483648",
    "4294967",
    "-4294967",
    "4294967296",
    "36028797018963967",
    "36028797018963968",
    "9223372036854775807",
    "-9223372036854775808",
    "9223372036854775808",
    "-9223372036854775809",
    "99999999999999999999999999",
    "00000000000000000000000001",
    "+1",
    "1.0",
    "1e3",
    "0x1",
    " 1",
    "",
];

const WORLDS: &[&str] = &[
    "default",
    "default",
    "default",
    "other",
    "0",
    "1",
    "18446744073709551615",
    "18446744073709551616",
    "99999999999999999999",
    "-1",
    "mars",
    "DEFAULT",
    "%64efault",
    "default%00",
    "%FF%FE",
    "..",
    ".",
    "%2e%2e",
    "default%2Fx",
    "0x1",
    "%C0%AE",
];

/// Names that look like tile products and are not; the served ones come from
/// [`Product::ALL`].
const NOT_PRODUCTS: &[&str] = &[
    "density.gif",
    "density",
    "DENSITY.NPY",
    "density.npy%00",
    "..%2Fdensity.npy",
    "",
];

/// Every served product name, then the [`NOT_PRODUCTS`].
fn product_names() -> Vec<&'static str> {
    Product::ALL
        .iter()
        .map(|p| p.name())
        .chain(NOT_PRODUCTS.iter().copied())
        .collect()
}

const QUALITIES: &[&str] = &[
    "fast",
    "balanced",
    "accurate",
    "reference",
    "reference-single",
    "ultra",
    "",
    "FAST",
    "%66ast",
];

const LAYERS: &[&str] = &[
    "low",
    "high",
    "only",
    "stratocumulus",
    "cirrus",
    "nope",
    "",
    "%00",
    "low%20",
];

/// Paths outside the parameterised routes: operator routes, the viewer, odd shapes.
const ODD_PATHS: &[&str] = &[
    "/",
    "/healthz",
    "/readyz",
    "/metrics",
    "/openapi.json",
    "/v1",
    "/v1/",
    "/v1/worlds",
    "/v1/worlds/",
    "//v1/worlds",
    "/v1//worlds",
    "/v1/worlds/default/",
    "/v1/worlds/default/tiles",
    "/v1/worlds/default/tiles/0/0/0",
    "/v1/worlds/default/tiles/0/0/0/density.npy/extra",
    "/v1/worlds/default/../../etc/passwd",
    "/v1/worlds/%2e%2e/%2e%2e/etc/passwd",
    "/v1/splats.png",
    "/v1/splats.json",
    "/v1/splats.gif",
    "/v1/sky.json",
    "/V1/WORLDS",
    "/v2/worlds",
    "/index.html",
    "/%",
    "/%00",
    "/v1/worlds/default/tiles/%30/0/0/density.npy?t=0",
];

/// Generates the hostile requests of one seed.
#[derive(Clone, Debug)]
pub struct Generator {
    pub seed: u64,
}

impl Generator {
    pub fn new(seed: u64) -> Generator {
        Generator { seed }
    }

    /// Request number `index`.
    pub fn request(&self, index: u64) -> FuzzRequest {
        let mut d = Draws::new(self.seed, index);
        if d.chance(0.04) {
            return protocol_request(&mut d);
        }
        let mut req = route_request(&mut d);
        // Odd headers on well-formed requests.
        if d.chance(0.1) {
            let (k, v) = odd_header(&mut d);
            req.headers.push((k, v));
        }
        if req.target.len() > MAX_URI_BYTES {
            // Over the HTTP layer's URI limit: answered 414 before any route sees it.
            req.kind = Kind::Protocol;
        }
        req
    }
}

/// A number: valid range, boundary, malformed, random float, or oversized.
fn number(d: &mut Draws, lo: f64, hi: f64) -> String {
    match d.below(10) {
        0..=3 => format!("{}", d.range(lo, hi)),
        4 => format!("{}", (d.range(lo, hi)).round()),
        5 | 6 => d.pick(BOUNDARY_NUMBERS).to_string(),
        7 => d.pick(MALFORMED).to_string(),
        8 => format!("{:e}", f64::from_bits(d.next())),
        _ => oversized_number(d),
    }
}

fn oversized_number(d: &mut Draws) -> String {
    match d.below(4) {
        0 => "9".repeat(1 + d.below(100_000)),
        1 => format!("0.{}1", "0".repeat(d.below(50_000))),
        2 => format!("1e{}", "9".repeat(1 + d.below(40))),
        _ => format!("{}{}", "-".repeat(1 + d.below(3)), "1".repeat(400)),
    }
}

fn integer(d: &mut Draws, lo: i64, hi: i64) -> String {
    match d.below(8) {
        0..=3 => format!("{}", lo + (d.next() % ((hi - lo) as u64 + 1)) as i64),
        4 | 5 => d.pick(INTEGERS).to_string(),
        6 => d.pick(MALFORMED).to_string(),
        _ => match d.below(3) {
            0 => format!("{}", d.next() as i64),
            1 => "9".repeat(1 + d.below(5000)),
            _ => format!("-{}", d.next()),
        },
    }
}

/// A comma-separated list of `n` numbers, or one of the usual ways to get it wrong.
fn list(d: &mut Draws, n: usize, ranges: &[(f64, f64)]) -> String {
    let count = match d.below(10) {
        0 => d.below(n + 2),
        1 => n + 1 + d.below(3),
        2 if d.chance(0.2) => 10_000,
        _ => n,
    };
    if count > 1000 {
        return vec!["0"; count].join(",");
    }
    let mut parts = Vec::with_capacity(count.min(100_000));
    for i in 0..count {
        let (lo, hi) = ranges[i % ranges.len()];
        parts.push(if d.chance(0.85) {
            format!("{}", d.range(lo, hi))
        } else {
            number(d, lo, hi)
        });
    }
    let sep = match d.below(20) {
        0 => "%2C",
        1 => ",,",
        2 => ";",
        3 => ", ",
        _ => ",",
    };
    parts.join(sep)
}

fn bbox(d: &mut Draws) -> String {
    if d.chance(0.5) {
        // Ordered and small: mostly a valid request.
        let (x, y) = (d.range(-1e5, 1e5).round(), d.range(-1e5, 1e5).round());
        let (w, h) = (d.range(1.0, 3000.0).round(), d.range(1.0, 3000.0).round());
        let (x, y) = if d.chance(0.1) {
            let far = 1.1e14 * if d.chance(0.5) { 1.0 } else { -1.0 };
            (far, far)
        } else {
            (x, y)
        };
        return format!("{},{},{},{}", x, y, x + w, y + h);
    }
    list(d, 4, &[(-1e6, 1e6)])
}

fn camera(d: &mut Draws) -> String {
    if d.chance(0.6) {
        return format!(
            "{},{},{},{},{},{}",
            d.range(-1e4, 1e4).round(),
            d.range(-1e4, 1e4).round(),
            d.range(0.0, 1e4).round(),
            d.range(-720.0, 720.0).round(),
            d.range(-90.0, 90.0).round(),
            d.range(1.0, 170.0).round()
        );
    }
    list(
        d,
        6,
        &[
            (-1e13, 1e13),
            (-1e13, 1e13),
            (-1e4, 1e5),
            (-1e4, 1e4),
            (-100.0, 100.0),
            (0.0, 200.0),
        ],
    )
}

fn size(d: &mut Draws) -> String {
    match d.below(8) {
        0..=3 => format!("{}x{}", 1 + d.below(48), 1 + d.below(32)),
        4 => format!("{}x{}", integer(d, 0, 10_000), integer(d, 0, 10_000)),
        5 => d
            .pick(&[
                "0x0",
                "x",
                "1x",
                "x1",
                "1X1",
                "1x1x1",
                "-1x1",
                "8193x1",
                "100000x100000",
            ])
            .to_string(),
        6 => format!("{}x{}", usize::MAX, usize::MAX),
        _ => d.pick(MALFORMED).to_string(),
    }
}

fn sun(d: &mut Draws) -> String {
    if d.chance(0.6) {
        return format!("{},{}", d.range(-720.0, 720.0), d.range(-90.0, 90.0));
    }
    list(d, 2, &[(-1e6, 1e6), (-100.0, 100.0)])
}

fn time(d: &mut Draws) -> String {
    if d.chance(0.5) {
        return format!("{}", d.range(0.0, 2e5).round());
    }
    number(d, 0.0, 1e12)
}

/// `name=value` pairs of a route; each parameter may also be left out or repeated.
fn query(d: &mut Draws, params: &[(&str, String)]) -> String {
    let mut pairs: Vec<String> = Vec::new();
    for (name, value) in params {
        if d.chance(0.05) {
            continue;
        }
        let name = if d.chance(0.02) {
            name.to_uppercase()
        } else {
            name.to_string()
        };
        pairs.push(format!("{name}={value}"));
        if d.chance(0.03) {
            pairs.push(format!("{name}={}", d.pick(MALFORMED)));
        }
    }
    match d.below(40) {
        0 => pairs.push(format!("junk={}", "a".repeat(d.below(200_000)))),
        1 => pairs.push("&&&==&=".to_string()),
        2 => pairs.push("t".to_string()),
        3 => pairs.push(format!("{}=1", "k".repeat(10_000))),
        4 => pairs.extend((0..5000).map(|i| format!("p{i}={i}"))),
        5 => pairs.push("%=%".to_string()),
        6 => pairs.push("a=%FF%FE%FD".to_string()),
        7 => pairs.push("cb=%C0%80".to_string()),
        _ => {}
    }
    if d.chance(0.1) {
        // Shuffle order: the last of repeated names wins, order otherwise irrelevant.
        let n = pairs.len();
        for i in (1..n).rev() {
            let j = d.below(i + 1);
            pairs.swap(i, j);
        }
    }
    pairs.join("&")
}

fn route_request(d: &mut Draws) -> FuzzRequest {
    let world = if d.chance(0.03) {
        "w".repeat(d.below(20_000))
    } else if d.chance(0.05) {
        format!("{}", d.next())
    } else if d.chance(0.6) {
        // Mostly a world that exists, so that the parameters behind it get parsed.
        "default".to_string()
    } else {
        d.pick(WORLDS).to_string()
    };
    let (path, ok_type): (String, Option<&'static str>) = match d.below(20) {
        0..=6 => {
            let product = d.pick(&product_names());
            let z = if d.chance(0.7) {
                format!("{}", d.below(4))
            } else {
                integer(d, 0, 20)
            };
            let x = integer(d, -8, 8);
            let y = integer(d, -8, 8);
            let mut params = vec![("t", time(d))];
            if d.chance(0.3) {
                params.push(("layer", d.pick(LAYERS).to_string()));
            }
            if d.chance(0.3) {
                params.push(("quality", d.pick(QUALITIES).to_string()));
            }
            if d.chance(0.3) {
                params.push(("sun", sun(d)));
            }
            let ok = Product::parse(product).map(Product::content_type);
            (
                format!("/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}?{}", query(d, &params)),
                ok,
            )
        }
        7..=9 => {
            let mut params = vec![
                ("x", number(d, -1e5, 1e5)),
                ("y", number(d, -1e5, 1e5)),
                ("z", number(d, 0.0, 1e4)),
                ("t", time(d)),
            ];
            if d.chance(0.2) {
                params.push(("layer", d.pick(LAYERS).to_string()));
            }
            (
                format!("/v1/worlds/{world}/sample?{}", query(d, &params)),
                Some("application/json"),
            )
        }
        10..=12 => {
            let mut params = vec![("bbox", bbox(d)), ("t", time(d))];
            if d.chance(0.4) {
                params.push(("level", integer(d, 0, 8)));
            }
            if d.chance(0.2) {
                params.push(("layer", d.pick(LAYERS).to_string()));
            }
            (
                format!("/v1/worlds/{world}/region?{}", query(d, &params)),
                Some("application/json"),
            )
        }
        13 | 14 => {
            let t0 = time(d);
            let mut params = vec![("bbox", bbox(d)), ("t0", t0), ("t1", time(d))];
            if d.chance(0.7) {
                params.push(("dt", number(d, 0.0, 1e4)));
            }
            if d.chance(0.4) {
                params.push(("level", integer(d, 0, 8)));
            }
            (
                format!("/v1/worlds/{world}/series?{}", query(d, &params)),
                Some("application/json"),
            )
        }
        15 | 16 => {
            let mut params = vec![("camera", camera(d)), ("t", time(d)), ("size", size(d))];
            if d.chance(0.4) {
                params.push(("quality", d.pick(QUALITIES).to_string()));
            }
            if d.chance(0.3) {
                params.push(("sun", sun(d)));
            }
            (
                format!("/v1/worlds/{world}/render.png?{}", query(d, &params)),
                Some("image/png"),
            )
        }
        17 => {
            let json = d.chance(0.5);
            let params = vec![("quality", d.pick(QUALITIES).to_string())];
            let (p, ok) = if json {
                ("/v1/splats.json", "application/json")
            } else {
                ("/v1/splats.png", "image/png")
            };
            (format!("{p}?{}", query(d, &params)), Some(ok))
        }
        18 => (format!("/v1/worlds/{world}"), Some("application/json")),
        _ => {
            let p = d.pick(ODD_PATHS).to_string();
            if d.chance(0.3) {
                let t = time(d);
                (format!("{p}?{}", query(d, &[("t", t)])), None)
            } else {
                (p, None)
            }
        }
    };
    let method = match d.below(50) {
        0 => "HEAD",
        1 => "POST",
        2 => "OPTIONS",
        3 => "DELETE",
        _ => "GET",
    };
    FuzzRequest {
        method: method.to_string(),
        target: uri_safe(&path),
        headers: Vec::new(),
        kind: Kind::Route,
        ok_type: if method == "GET" { ok_type } else { None },
    }
}

/// Percent-encodes every byte a request target may not hold raw (spaces, controls,
/// non-ASCII, quotes, brackets), leaving `%` alone so that the generator's own escapes,
/// valid or not, reach the server as written.
fn uri_safe(path: &str) -> Vec<u8> {
    let mut out = Vec::with_capacity(path.len());
    for &b in path.as_bytes() {
        if b.is_ascii_alphanumeric() || b"-._~!$&'()*+,;=:@/?%".contains(&b) {
            out.push(b);
        } else {
            out.extend_from_slice(format!("%{b:02X}").as_bytes());
        }
    }
    out
}

/// A header a client may send that the server must tolerate.
fn odd_header(d: &mut Draws) -> RawHeader {
    match d.below(8) {
        0 => (
            "If-None-Match".into(),
            d.pick(&["*", "\"\"", "W/\"x\"", "\"a\", \"b\"", ",,,", "\"unterminated"])
                .into(),
        ),
        1 => (
            "Accept-Encoding".into(),
            d.pick(&[
                "gzip",
                "br;q=0",
                "zstd, gzip;q=0.5",
                "*;q=abc",
                "identity;q=0",
                "x-unknown",
            ])
            .into(),
        ),
        2 => (
            "X-Request-Id".into(),
            d.pick(&["", "a b", "x".repeat(200).as_str(), "\"", "%FF"]).into(),
        ),
        3 => (
            "If-None-Match".into(),
            format!("\"{}\"", "e".repeat(d.below(8000))).into_bytes(),
        ),
        4 => ("Range".into(), b"bytes=0-1".to_vec()),
        5 => ("Content-Length".into(), b"0".to_vec()),
        6 => ("Accept".into(), b"*/*".to_vec()),
        _ => ("Cookie".into(), "c".repeat(d.below(4000)).into_bytes()),
    }
}

/// Malformed at the HTTP level.
fn protocol_request(d: &mut Draws) -> FuzzRequest {
    let good = b"/v1/worlds/default/tiles/0/0/0/density.u8?t=0".to_vec();
    let (method, target, headers): (String, Vec<u8>, Vec<RawHeader>) = match d.below(8) {
        // Raw invalid UTF-8 and control bytes in the target.
        0 => {
            let mut t = b"/v1/worlds/".to_vec();
            t.extend((0..1 + d.below(40)).map(|_| (0x80 + d.below(0x80)) as u8));
            t.extend_from_slice(b"/sample?x=0&y=0&z=0&t=0");
            ("GET".into(), t, vec![])
        }
        1 => {
            let mut t = b"/v1/worlds/default/sample?x=".to_vec();
            t.extend((0..1 + d.below(20)).map(|_| d.next() as u8 & 0x1f | 1));
            ("GET".into(), t, vec![])
        }
        // An overlong request target.
        2 => {
            let mut t = b"/v1/worlds/default/sample?x=0&y=0&z=0&t=0&pad=".to_vec();
            t.extend(std::iter::repeat_n(b'a', 64 * 1024 + d.below(1 << 20)));
            ("GET".into(), t, vec![])
        }
        // One huge header.
        3 => (
            "GET".into(),
            good,
            vec![("X-Huge".into(), vec![b'h'; 16 * 1024 + d.below(1 << 20)])],
        ),
        // Many headers.
        4 => {
            let n = 50 + d.below(500);
            (
                "GET".into(),
                good,
                (0..n).map(|i| (format!("X-H{i}"), b"v".to_vec())).collect(),
            )
        }
        // Header values with control or non-ASCII bytes.
        5 => (
            "GET".into(),
            good,
            vec![(
                "X-Request-Id".into(),
                (0..1 + d.below(64)).map(|_| [0x7f, 0x01, 0xff][d.below(3)]).collect(),
            )],
        ),
        // Unknown or malformed methods.
        6 => (
            d.pick(&["BREW", "get", "G ET", "PATCH", "TRACE", "CONNECT", "X"])
                .into(),
            good,
            vec![],
        ),
        _ => (
            "GET".into(),
            d.pick(&[
                "*",
                "v1/worlds",
                "http://evil/v1/worlds",
                "/v1/worlds#frag",
                "/\\v1\\worlds",
                "/v1/worlds?%",
            ])
            .as_bytes()
            .to_vec(),
            vec![],
        ),
    };
    FuzzRequest {
        method,
        target,
        headers,
        kind: Kind::Protocol,
        ok_type: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_a_pure_function_of_seed_and_index() {
        let (a, b) = (Generator::new(7), Generator::new(7));
        for i in [0, 1, 99, 12345] {
            assert_eq!(a.request(i).to_bytes("h"), b.request(i).to_bytes("h"));
        }
        assert_ne!(a.request(1).to_bytes("h"), Generator::new(8).request(1).to_bytes("h"));
    }

    #[test]
    fn every_route_and_both_kinds_are_generated() {
        let g = Generator::new(1);
        let reqs: Vec<FuzzRequest> = (0..4000).map(|i| g.request(i)).collect();
        for needle in [
            "/tiles/",
            "/sample?",
            "/region?",
            "/series?",
            "/render.png?",
            "/v1/splats.",
        ] {
            assert!(
                reqs.iter()
                    .any(|r| r.kind == Kind::Route && r.display_target(200).contains(needle)),
                "{needle}"
            );
        }
        assert!(reqs.iter().any(|r| r.kind == Kind::Protocol));
        assert!(reqs.iter().any(|r| r.target.len() > 60_000));
    }
}
