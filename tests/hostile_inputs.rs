//! Hostile inputs, as property tests (proptest) over real HTTP on a real socket and
//! over the command line: every route's parameters and every CLI argument, drawn from
//! valid, boundary, malformed, oversized and oddly encoded values. The properties:
//! nothing panics, nothing answers 500, the server's memory stays bounded, and every
//! answer is either the route's product (its content type and magic bytes) or a JSON
//! error `{"error", "message"}` whose status is the one PRODUCT.md gives its kind
//! (400 malformed, 404 unknown, 413/422 over limits, 503 overloaded). Valid requests
//! built to be valid must be served. A bounded run of the `cloudscape fuzz` soak closes
//! the file. Case counts are small so that CI stays fast; `PROPTEST_CASES` raises them.

mod common;

use std::process::Command;
use std::time::Duration;

use cloudscape_tools::soak::http::{Answer, Connection};
use cloudscape_tools::soak::{SoakOptions, process_memory_kb, soak};
use common::ServeProcess;
use proptest::prelude::*;
use proptest::test_runner::{Config as ProptestConfig, TestCaseError, TestRunner};

const BIN: &str = env!("CARGO_BIN_EXE_cloudscape");

/// The test world made cheaper still, with small limits, so any request is cheap and
/// the limits bite: one cell deep, short epochs, a queue of 2, series of 4 frames,
/// regions of at most 300 columns and 300 000 cells, a 32 MiB cache.
fn test_world() -> String {
    const SHORT_EPOCH: &str = "{ length = 2, warmup = 2, fade = 1 }";
    common::test_config(&[
        ("server.cache_bytes", "33554432"),
        ("server.compute_queue", "2"),
        ("server.request_timeout_ms", "5000"),
        ("server.max_series", "4"),
        ("limits.max_columns", "300"),
        ("limits.max_cells", "300000"),
        ("worlds.default.layers.0.depth", "1"),
        ("worlds.default.layers.0.epoch", SHORT_EPOCH),
        ("worlds.default.layers.1.epoch", SHORT_EPOCH),
    ])
}

/// Memory the server may use at most over this whole file, kB (its cache is 32 MiB).
const MAX_RSS_KB: u64 = 768 * 1024;

/// The status PRODUCT.md gives each kind of error (the codes are ApiError's).
fn expected_status(code: &str) -> Option<&'static [u16]> {
    Some(match code {
        "invalid_number" | "not_finite" | "missing_parameter" | "invalid_parameter" | "unknown_parameter"
        | "invalid_bbox" => &[400],
        "unknown_world" | "unknown_layer" | "unknown_product" | "not_found" => &[404],
        "time_out_of_range" | "level_out_of_range" | "coordinates_out_of_range" | "empty_region" => &[422],
        "region_too_large" | "series_too_long" | "too_much_work" | "response_too_large" => &[413],
        "overloaded" | "timeout" | "reply_memory_full" => &[503],
        "method_not_allowed" => &[405],
        "malformed_request" => &[400],
        "uri_too_long" => &[414],
        "headers_too_large" => &[431],
        _ => return None,
    })
}

/// Percent-encodes every byte outside the unreserved set, so any value reaches the
/// server byte for byte.
fn encode(value: &[u8]) -> String {
    value
        .iter()
        .map(|&b| {
            if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
                (b as char).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

/// A parameter value: numbers in and around the valid range, boundary values, and
/// arbitrary bytes (invalid UTF-8 included), sometimes oversized.
fn value(lo: f64, hi: f64) -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        4 => (lo..hi).prop_map(|v| v.to_string().into_bytes()),
        2 => any::<f64>().prop_map(|v| format!("{v:e}").into_bytes()),
        2 => prop::sample::select(vec![
            "0", "-0", "5e-324", "1e12", "1e12000", "-1", "nan", "inf", "-inf", "1e308", "1099511627776",
            "-1099511627776", "9223372036854775808", "1e", "", " ", "0x10", "١", "+", "1,2",
        ])
        .prop_map(|s| s.as_bytes().to_vec()),
        2 => prop::collection::vec(any::<u8>(), 0..24),
        1 => (1usize..20_000).prop_map(|n| vec![b'9'; n]),
    ]
}

/// A comma-separated list of `n` values (or a few more or fewer).
fn list(n: usize, lo: f64, hi: f64) -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        6 => prop::collection::vec(lo..hi, n..=n).prop_map(|v| join(v.iter().map(|x| x.to_string().into_bytes()))),
        3 => prop::collection::vec(value(lo, hi), n..=n).prop_map(|v| join(v.into_iter())),
        1 => prop::collection::vec(value(lo, hi), 0..(n + 3)).prop_map(|v| join(v.into_iter())),
    ]
}

fn join(parts: impl Iterator<Item = Vec<u8>>) -> Vec<u8> {
    let mut out = Vec::new();
    for (i, p) in parts.enumerate() {
        if i > 0 {
            out.push(b',');
        }
        out.extend(p);
    }
    out
}

fn text(items: &'static [&'static str]) -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        4 => prop::sample::select(items).prop_map(|s| s.as_bytes().to_vec()),
        1 => prop::collection::vec(any::<u8>(), 0..16),
    ]
}

/// Query pairs, each optional: `None` leaves the parameter out.
fn query(pairs: Vec<(&str, Option<Vec<u8>>)>) -> String {
    pairs
        .into_iter()
        .filter_map(|(k, v)| v.map(|v| format!("{k}={}", encode(&v))))
        .collect::<Vec<_>>()
        .join("&")
}

/// One request to the server over a fresh raw connection.
fn get(server: &ServeProcess, target: &str) -> Answer {
    let addr = format!("127.0.0.1:{}", server.port);
    let mut c = Connection::open(&addr, Duration::from_secs(60)).expect("connect");
    let req = format!("GET {target} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
    match c.exchange(req.as_bytes(), false) {
        Ok((a, _)) => a,
        Err(e) => panic!("no answer to {target}: {e:?}"),
    }
}

/// The property every answer must have: the product (type and magic bytes) or a
/// JSON error with the status of its kind.
fn check(target: &str, a: &Answer, product_type: &str) -> Result<(), TestCaseError> {
    let ctype = a.header("content-type").unwrap_or("");
    match a.status {
        200 => {
            prop_assert!(ctype.starts_with(product_type), "{target}: 200 with `{ctype}`");
            let magic_ok = match product_type {
                "image/png" => a.body.starts_with(b"\x89PNG\r\n\x1a\n"),
                "application/json" => a.body.first() == Some(&b'{'),
                _ => a.body_len > 0,
            };
            prop_assert!(magic_ok, "{target}: 200 body is not {product_type}");
        }
        _ => {
            prop_assert!(
                ctype.starts_with("application/json"),
                "{target}: {} with `{ctype}`",
                a.status
            );
            let body: serde_json::Value = serde_json::from_slice(&a.body)
                .map_err(|e| TestCaseError::fail(format!("{target}: error body is not JSON: {e}")))?;
            let code = body["error"].as_str().unwrap_or("");
            prop_assert!(
                body["message"].as_str().is_some_and(|m| !m.is_empty()),
                "{target}: {body}"
            );
            let allowed = expected_status(code);
            prop_assert!(allowed.is_some(), "{target}: unknown error code in {body}");
            prop_assert!(
                allowed.unwrap().contains(&a.status),
                "{target}: `{code}` answered with {}",
                a.status
            );
            if a.status == 503 {
                prop_assert!(a.header("retry-after").is_some(), "{target}: 503 without Retry-After");
            }
        }
    }
    Ok(())
}

fn runner(cases: u32) -> TestRunner {
    let cases = std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(cases);
    TestRunner::new(ProptestConfig {
        cases,
        failure_persistence: None,
        ..ProptestConfig::default()
    })
}

const PRODUCTS: &[&str] = &[
    "density.npy",
    "density.f32",
    "density.u8",
    "coverage.png",
    "billboards.json",
    "billboards.bin",
    "atlas.png",
    "atlas.json",
    "shadow.png",
];

fn product_type(p: &str) -> &'static str {
    match p.rsplit('.').next() {
        Some("png") => "image/png",
        Some("json") => "application/json",
        Some("ktx2") => "image/ktx2",
        _ => "application/octet-stream",
    }
}

#[test]
fn every_route_answers_a_product_or_a_json_error_under_hostile_parameters() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("config.toml");
    std::fs::write(&config, test_world()).unwrap();
    let server = ServeProcess::start(&["--config", config.to_str().unwrap()], &[("RUST_LOG", "error")]);
    let pid = server.child.id();

    // The small limits are in force, so the values drawn below reach them: 400 columns
    // and 7 frames are within the test world's and the defaults' limits, not these.
    for (target, status, code) in [
        ("/v1/worlds/default/region?bbox=0,0,20000,100&t=0", 200, None),
        (
            "/v1/worlds/default/region?bbox=0,0,40000,100&t=0",
            413,
            Some("region_too_large"),
        ),
        (
            "/v1/worlds/default/series?bbox=0,0,1000,1000&t0=0&t1=60&dt=10",
            413,
            Some("series_too_long"),
        ),
    ] {
        let a = get(&server, target);
        assert_eq!(a.status, status, "{target}");
        if let Some(code) = code {
            let body: serde_json::Value = serde_json::from_slice(&a.body).expect("a JSON error");
            assert_eq!(body["error"], code, "{target}");
        }
    }

    // Tiles: every path segment and query parameter.
    let world = || text(&["default", "default", "7", "18446744073709551616", "mars", "%FF", ".."]);
    let tile = (
        world(),
        prop_oneof![3 => (0u32..4).prop_map(|z| z.to_string().into_bytes()), 1 => value(-2.0, 30.0)],
        prop_oneof![3 => (-4i64..4).prop_map(|x| x.to_string().into_bytes()), 1 => value(-1e19, 1e19)],
        prop_oneof![3 => (-4i64..4).prop_map(|x| x.to_string().into_bytes()), 1 => value(-1e19, 1e19)],
        prop_oneof![6 => prop::sample::select(PRODUCTS).prop_map(|s| s.as_bytes().to_vec()), 1 => text(&["x.png", ""])],
        prop::option::weighted(0.9, value(0.0, 1e5)),
        prop::option::of(text(&["low", "high", "nope", ""])),
        prop::option::of(text(&["fast", "balanced", "accurate", "reference", "ultra"])),
        prop::option::of(list(2, -400.0, 400.0)),
    );
    runner(48)
        .run(&tile, |(w, z, x, y, p, t, layer, quality, sun)| {
            let q = query(vec![("t", t), ("layer", layer), ("quality", quality), ("sun", sun)]);
            let product = String::from_utf8_lossy(&p).into_owned();
            let target = format!(
                "/v1/worlds/{}/tiles/{}/{}/{}/{}?{q}",
                encode(&w),
                encode(&z),
                encode(&x),
                encode(&y),
                encode(&p)
            );
            check(&target, &get(&server, &target), product_type(&product))
        })
        .unwrap();

    // A tile request that is valid by construction is served.
    let valid_tile = (
        0u32..3,
        -3i64..3,
        -3i64..3,
        prop::sample::select(PRODUCTS),
        0.0f64..1e12,
        prop::option::of((-720.0f64..720.0, -90.0f64..=90.0)),
    );
    runner(24)
        .run(&valid_tile, |(z, x, y, p, t, sun)| {
            let sun = sun.map_or(String::new(), |(a, e)| format!("&sun={a},{e}"));
            let target = format!("/v1/worlds/default/tiles/{z}/{x}/{y}/{p}?t={t}{sun}");
            let a = get(&server, &target);
            prop_assert!(a.status == 200 || a.status == 503, "{target}: {}", a.status);
            check(&target, &a, product_type(p))
        })
        .unwrap();

    // A world's route with a query, checked against the route's product type.
    let check_route = |w: &[u8], route: &str, pairs: Vec<(&str, Option<Vec<u8>>)>, product_type: &str| {
        let target = format!("/v1/worlds/{}/{route}?{}", encode(w), query(pairs));
        check(&target, &get(&server, &target), product_type)
    };

    // /sample, /region, /series.
    let sample = (
        world(),
        prop::option::weighted(0.95, value(-1e6, 1e6)),
        prop::option::weighted(0.95, value(-1e6, 1e6)),
        prop::option::weighted(0.95, value(0.0, 8000.0)),
        prop::option::weighted(0.95, value(0.0, 1e5)),
        prop::option::weighted(0.2, text(&["low", "high", "nope"])),
    );
    runner(40)
        .run(&sample, |(w, x, y, z, t, layer)| {
            let pairs = vec![("x", x), ("y", y), ("z", z), ("t", t), ("layer", layer)];
            check_route(&w, "sample", pairs, "application/json")
        })
        .unwrap();
    let region = (
        world(),
        prop::option::weighted(0.95, list(4, -30000.0, 30000.0)),
        prop::option::weighted(0.95, value(0.0, 1e5)),
        prop::option::weighted(0.4, value(0.0, 25.0)),
        prop::option::weighted(0.2, text(&["low", "high", "nope"])),
    );
    runner(40)
        .run(&region, |(w, bbox, t, level, layer)| {
            let pairs = vec![("bbox", bbox), ("t", t), ("level", level), ("layer", layer)];
            check_route(&w, "region", pairs, "application/json")
        })
        .unwrap();
    let series = (
        world(),
        prop::option::weighted(0.95, list(4, -20000.0, 20000.0)),
        prop::option::weighted(0.95, value(0.0, 1e5)),
        prop::option::weighted(0.95, value(0.0, 1e5)),
        prop::option::weighted(0.8, value(0.0, 1e5)),
        prop::option::weighted(0.3, value(0.0, 25.0)),
    );
    runner(32)
        .run(&series, |(w, bbox, t0, t1, dt, level)| {
            let pairs = vec![("bbox", bbox), ("t0", t0), ("t1", t1), ("dt", dt), ("level", level)];
            check_route(&w, "series", pairs, "application/json")
        })
        .unwrap();

    // render.png and the splat sheets.
    let render = (
        world(),
        prop::option::weighted(0.95, list(6, -90.0, 170.0)),
        prop::option::weighted(0.95, value(0.0, 1e5)),
        prop::option::weighted(
            0.8,
            prop_oneof![
                3 => (1usize..40, 1usize..30).prop_map(|(w, h)| format!("{w}x{h}").into_bytes()),
                1 => value(0.0, 1e4),
                1 => text(&["0x0", "8193x1", "100000x100000", "x", "1x1x1"]),
            ],
        ),
        prop::option::of(text(&["fast", "balanced", "accurate", "reference", "ultra"])),
        prop::option::of(list(2, -400.0, 400.0)),
    );
    runner(24)
        .run(&render, |(w, camera, t, size, quality, sun)| {
            let pairs = vec![
                ("camera", camera),
                ("t", t),
                ("size", size),
                ("quality", quality),
                ("sun", sun),
            ];
            check_route(&w, "render.png", pairs, "image/png")
        })
        .unwrap();
    runner(12)
        .run(
            &(
                any::<bool>(),
                prop::option::of(text(&["fast", "balanced", "accurate", "reference", "x"])),
            ),
            |(json, quality)| {
                let target = format!(
                    "/v1/splats.{}?{}",
                    if json { "json" } else { "png" },
                    query(vec![("quality", quality)])
                );
                let want = if json { "application/json" } else { "image/png" };
                check(&target, &get(&server, &target), want)
            },
        )
        .unwrap();

    // The sky of a sun: hostile suns and times.
    runner(16)
        .run(
            &(
                prop::option::of(list(2, -400.0, 400.0)),
                prop::option::of(value(-10.0, 2e12)),
            ),
            |(sun, t)| {
                let target = format!("/v1/sky.json?{}", query(vec![("sun", sun), ("t", t)]));
                check(&target, &get(&server, &target), "application/json")
            },
        )
        .unwrap();

    // Discovery under arbitrary world names (percent-encoded arbitrary bytes).
    runner(24)
        .run(&prop::collection::vec(any::<u8>(), 0..40), |w| {
            let target = format!("/v1/worlds/{}", encode(&w));
            check(&target, &get(&server, &target), "application/json")
        })
        .unwrap();

    // A bounded soak of the generator behind `cloudscape fuzz`: protocol-level garbage
    // (raw bytes, header floods, overlong targets) on top of the above.
    let report = soak(&SoakOptions {
        target: server.base.clone(),
        requests: 3000,
        seed: 7,
        concurrency: 4,
        timeout: Duration::from_secs(60),
        pid: Some(pid),
        good_path: "/v1/worlds/default/tiles/0/0/0/density.u8?t=0".into(),
        progress: false,
    })
    .unwrap();
    assert!(report.passed(), "{}", report.summary());
    assert_eq!(report.server_errors, 0);
    assert!(report.by_status.contains_key("400") && report.by_status.contains_key("200"));

    let (_, peak) = process_memory_kb(pid).expect("the server's /proc status");
    assert!(
        peak < MAX_RSS_KB,
        "the server's peak RSS {peak} kB is over {MAX_RSS_KB} kB"
    );
    assert!(server.terminate(), "the server exits cleanly after all of that");
}

/// A valid value of each parameter the OpenAPI document lists, by route template and
/// name: the starting point that one parameter at a time is made hostile from, so that
/// the hostile value goes as deep into its parser as a valid one does. `None` for a
/// parameter nobody gave a value yet (the test then says which).
fn example(route: &str, name: &str) -> Option<&'static str> {
    Some(match (name, route.rsplit('/').next().unwrap_or("")) {
        ("world", _) => "default",
        ("z", "{product}") => "1",
        ("zoom", _) => "19",
        ("x" | "y", "{product}") => "-1",
        ("product", _) => "coverage.png",
        ("t", _) => "20.5",
        ("t0", _) => "0",
        ("t1", _) => "30",
        ("dt", _) => "20",
        ("x" | "y", _) => "1234.5",
        ("z", "sample" | "position") => "1050",
        ("z", "cube") => "1000/1200",
        ("bbox", _) => "0,0,2000,2000",
        ("layer", _) => "low",
        ("level", _) => "1",
        ("quality", _) => "fast",
        ("sun", _) => "135.5,30.25",
        ("samples", _) => "4",
        ("size", _) => "16x9",
        // Above every layer, looking up: a valid view that costs little.
        ("camera", _) => "0,-2000,9000,0,80,60",
        ("coords", "position" | "radius") => "POINT(500.5 -250)",
        ("coords", "area") => "POLYGON((0 0, 2000 0, 1000 2000, 0 0))",
        ("within", _) => "750.5",
        ("within-units", _) => "m",
        // A long fraction: a parser that cuts it by byte counts meets the multibyte
        // characters inserted below at every place.
        ("datetime", "items") => "1970-01-01T00:01:00.12345678Z/1970-01-01T00:02:00Z",
        ("datetime", _) => "1970-01-01T00:01:00.12345678Z",
        ("parameter-name" | "parameter_names", _) => "cloud_cover,density",
        ("limit", _) => "10",
        ("offset", _) => "5",
        ("f", "position" | "area" | "cube" | "radius") => "CoverageJSON",
        ("f", "items") => "GeoJSON",
        ("f", _) => "json",
        ("crs", _) => "cloudscape-local-metres",
        _ => return None,
    })
}

/// One parameter of a route: its name, whether it is a path segment, whether it is
/// required, and its valid value.
struct Param {
    name: String,
    in_path: bool,
    required: bool,
    example: &'static str,
}

/// The request target of `route` with every required parameter at its example value
/// and parameter `hostile` (an index into `params`) set to `value`, percent-encoded.
/// (`samples` comes with the one quality that takes it, and a render is always small:
/// the default 640x360 takes seconds in a debug build.)
fn target_with(route: &str, params: &[Param], hostile: usize, value: &str) -> String {
    let mut path = route.to_string();
    let mut query = Vec::new();
    if params[hostile].name == "samples" {
        query.push("quality=reference".to_string());
    }
    for (i, p) in params.iter().enumerate() {
        let v = if i == hostile { value } else { p.example };
        if p.in_path {
            path = path.replace(&format!("{{{}}}", p.name), &encode(v.as_bytes()));
        } else if i == hostile || p.required || p.name == "size" {
            query.push(format!("{}={}", p.name, encode(v.as_bytes())));
        }
    }
    format!("{path}?{}", query.join("&"))
}

/// The property of any answer to any request: never a 500 (or another 5xx than a 503
/// with `Retry-After`), and every error the JSON `{"error", "message"}` with the status
/// of its kind.
fn check_any(target: &str, a: &Answer) -> Result<(), TestCaseError> {
    if a.status < 400 {
        return Ok(());
    }
    let ctype = a.header("content-type").unwrap_or("");
    prop_assert!(
        ctype.starts_with("application/json"),
        "{target}: {} with `{ctype}`",
        a.status
    );
    let body: serde_json::Value = serde_json::from_slice(&a.body)
        .map_err(|e| TestCaseError::fail(format!("{target}: error body is not JSON: {e}")))?;
    let code = body["error"].as_str().unwrap_or("");
    prop_assert!(
        body["message"].as_str().is_some_and(|m| !m.is_empty()),
        "{target}: {body}"
    );
    let allowed = expected_status(code);
    prop_assert!(
        allowed.is_some_and(|s| s.contains(&a.status)),
        "{target}: {} {body}",
        a.status
    );
    if a.status == 503 {
        prop_assert!(a.header("retry-after").is_some(), "{target}: 503 without Retry-After");
    }
    Ok(())
}

/// Any request on a fresh connection: the answer, or a failure if the connection closed
/// without one (what a panicking handler did).
fn try_get(server: &ServeProcess, target: &str) -> Result<Answer, TestCaseError> {
    let addr = format!("127.0.0.1:{}", server.port);
    let mut c = Connection::open(&addr, Duration::from_secs(60)).expect("connect");
    let req = format!("GET {target} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
    c.exchange(req.as_bytes(), false)
        .map(|(a, _)| a)
        .map_err(|e| TestCaseError::fail(format!("{target}: no answer ({e:?})")))
}

/// Every parameter of every route the OpenAPI document lists (path segments and query
/// parameters, EDR's included), through the real router on a real socket: each
/// multibyte character of 2, 3 and 4 bytes inserted at every place of the parameter's
/// valid value, then arbitrary UTF-8 strings. Nothing panics or answers 500; every
/// refusal is a JSON 4xx.
#[test]
fn every_parameter_of_every_route_takes_any_utf8_without_a_panic_or_a_500() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("config.toml");
    std::fs::write(&config, test_world()).unwrap();
    let server = ServeProcess::start(&["--config", config.to_str().unwrap()], &[("RUST_LOG", "error")]);
    let doc: serde_json::Value = serde_json::from_str(&server.get("/openapi.json").text().unwrap()).unwrap();
    let mut routes: Vec<(String, Vec<Param>)> = Vec::new();
    for (route, item) in doc["paths"].as_object().unwrap() {
        let mut params = Vec::new();
        for p in item["get"]["parameters"].as_array().into_iter().flatten() {
            let name = p["name"].as_str().unwrap().to_string();
            let example = example(route, &name)
                .unwrap_or_else(|| panic!("{route}: give parameter `{name}` an example value in example()"));
            params.push(Param {
                in_path: p["in"] == "path",
                required: p["required"] == true,
                name,
                example,
            });
        }
        if !params.is_empty() {
            routes.push((route.clone(), params));
        }
    }
    assert!(routes.len() >= 17, "{} routes with parameters", routes.len());

    // The valid values are valid: each route answers its examples with a 2xx.
    for (route, params) in &routes {
        for (i, p) in params.iter().enumerate() {
            let target = target_with(route, params, i, p.example);
            let a = try_get(&server, &target).unwrap();
            assert!(
                a.status < 300,
                "{target}: {} {}",
                a.status,
                String::from_utf8_lossy(&a.body)
            );
        }
    }

    // Every multibyte character at every place of every valid value.
    let mut sent = 0;
    for (route, params) in &routes {
        for (i, p) in params.iter().enumerate() {
            let places = p.example.char_indices().map(|(at, _)| at).chain([p.example.len()]);
            for at in places {
                for c in ['é', '€', '😀'] {
                    let mut value = p.example.to_string();
                    value.insert(at, c);
                    let target = target_with(route, params, i, &value);
                    try_get(&server, &target)
                        .and_then(|a| check_any(&target, &a))
                        .unwrap_or_else(|e| panic!("{e}"));
                    sent += 1;
                }
            }
        }
    }
    assert!(sent > 1000, "{sent} requests");

    // Arbitrary UTF-8, and valid values with arbitrary strings spliced in.
    let pairs: Vec<(usize, usize)> = routes
        .iter()
        .enumerate()
        .flat_map(|(r, (_, params))| (0..params.len()).map(move |i| (r, i)))
        .collect();
    let hostile = (
        prop::sample::select(pairs),
        any::<String>(),
        any::<prop::sample::Index>(),
        any::<String>(),
    );
    runner(256)
        .run(&hostile, |((r, i), whole, at, splice)| {
            let (route, params) = &routes[r];
            let example = params[i].example;
            // The arbitrary string alone, and another spliced into the valid value at
            // a character boundary.
            let places: Vec<usize> = example.char_indices().map(|(p, _)| p).chain([example.len()]).collect();
            let spliced = {
                let mut v = example.to_string();
                v.insert_str(places[at.index(places.len())], &splice);
                v
            };
            for value in [whole, spliced] {
                let target = target_with(route, params, i, &value);
                check_any(&target, &try_get(&server, &target)?)?;
            }
            Ok(())
        })
        .unwrap();
    assert!(server.terminate(), "the server exits cleanly");
}

/// Whether a failed run's stderr is the one clear sentence every refusal must be.
fn one_sentence(stderr: &str) -> bool {
    stderr.starts_with("error: ") && stderr.trim_end().lines().count() == 1
}

/// One CLI run: exit code 0 with the product written, or a one-sentence error on stderr
/// and a non-zero exit; never a panic or a signal.
fn check_cli(args: &[String], out: &std::path::Path, magic: &[u8]) -> Result<(), TestCaseError> {
    let _ = std::fs::remove_file(out);
    let o = Command::new(BIN).args(args).output().expect("run cloudscape");
    let stderr = String::from_utf8_lossy(&o.stderr);
    prop_assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    let code = o.status.code();
    prop_assert!(code.is_some(), "{args:?}: killed by a signal; {stderr}");
    match code.unwrap() {
        0 => {
            let bytes =
                std::fs::read(out).map_err(|e| TestCaseError::fail(format!("{args:?}: exit 0, no file: {e}")))?;
            prop_assert!(bytes.starts_with(magic), "{args:?}: wrong product");
        }
        1 => {
            prop_assert!(one_sentence(&stderr), "{args:?}: not one sentence: {stderr}");
            prop_assert!(!out.exists(), "{args:?}: failed but left a file");
        }
        // clap's own usage errors.
        2 => prop_assert!(stderr.contains("error"), "{args:?}: {stderr}"),
        c => prop_assert!(false, "{args:?}: exit code {c}"),
    }
    Ok(())
}

/// An argument value as a string (lossy: the OS passes bytes, but clap wants UTF-8;
/// invalid UTF-8 is covered by one fixed case below).
fn arg(v: Vec<u8>) -> String {
    // An OS argument cannot hold NUL.
    String::from_utf8_lossy(&v).replace('\0', "")
}

/// `COMMAND --config CONFIG`, each flag with its value, each optional flag with its
/// value when one was drawn, and `--out OUT`.
fn cli_args(
    command: &str,
    config: &str,
    flags: Vec<(&str, Vec<u8>)>,
    optional: Vec<(&str, Option<Vec<u8>>)>,
    out: &str,
) -> Vec<String> {
    let mut args: Vec<String> = vec![command.into(), "--config".into(), config.into()];
    for (flag, v) in flags {
        args.extend([flag.to_string(), arg(v)]);
    }
    for (flag, v) in optional {
        if let Some(v) = v {
            args.extend([flag.to_string(), arg(v)]);
        }
    }
    args.extend(["--out".into(), out.into()]);
    args
}

#[test]
fn every_cli_argument_gets_a_product_or_one_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("config.toml");
    std::fs::write(&config, test_world()).unwrap();
    let config = config.to_str().unwrap().to_string();
    let out = dir.path().join("out.bin");
    let out_s = out.to_str().unwrap().to_string();

    let density = (
        text(&["default", "7", "mars", "18446744073709551616"]),
        list(4, -20000.0, 20000.0),
        value(0.0, 1e5),
        prop::option::of(value(0.0, 25.0)),
        prop::option::of(text(&["low", "high", "nope"])),
        prop::option::of(text(&["density", "cld", "x"])),
        prop::option::of(text(&["npy", "f32", "u8", "png"])),
    );
    runner(32)
        .run(&density, |(w, bbox, t, level, layer, field, format)| {
            let npy = format.is_none();
            let args = cli_args(
                "density",
                &config,
                vec![("--world", w), ("--bbox", bbox), ("--t", t)],
                vec![
                    ("--level", level),
                    ("--layer", layer),
                    ("--field", field),
                    ("--format", format),
                ],
                &out_s,
            );
            check_cli(&args, &out, if npy { b"\x93NUMPY" } else { b"" })
        })
        .unwrap();

    let render = (
        text(&["default", "7", "mars"]),
        list(6, -90.0, 170.0),
        value(0.0, 1e5),
        prop_oneof![3 => (1usize..24, 1usize..16).prop_map(|(w, h)| format!("{w}x{h}").into_bytes()), 1 => value(0.0, 1e5)],
        prop::option::of(text(&["fast", "balanced", "accurate", "reference", "ultra"])),
        prop::option::of(list(2, -400.0, 400.0)),
        prop::option::of(list(3, -1.5, 1.5)),
    );
    runner(20)
        .run(&render, |(w, camera, t, size, quality, sun, phase)| {
            let args = cli_args(
                "render",
                &config,
                vec![("--world", w), ("--camera", camera), ("--t", t), ("--size", size)],
                vec![("--quality", quality), ("--sun", sun), ("--phase", phase)],
                &out_s,
            );
            check_cli(&args, &out, b"\x89PNG")
        })
        .unwrap();

    // `serve --print-config` with hostile flags and environment overrides: a config or
    // one clear error, never a server left running.
    let serve = (
        prop::option::of(text(&["127.0.0.1:0", "nonsense", "[::1]:99999", ""])),
        prop::option::of(text(&["max_level", "cache_bytes", "frames_per_step", "bogus"])),
        value(-10.0, 100.0),
        prop::option::of(text(&["/nonexistent.toml", "", "/dev/null"])),
    );
    runner(16)
        .run(&serve, |(listen, key, v, file)| {
            let mut cmd = Command::new(BIN);
            cmd.args(["serve", "--print-config"]);
            if let Some(l) = listen {
                cmd.args(["--listen", &arg(l)]);
            }
            if let Some(f) = file {
                cmd.args(["--config", &arg(f)]);
            }
            if let Some(k) = key {
                let name = format!("CLOUDSCAPE_LIMITS_{}", arg(k).to_uppercase());
                if !name.is_empty() && !name.contains(['=', '\0']) {
                    cmd.env(name, arg(v).replace('\0', ""));
                }
            }
            let o = cmd.output().expect("run cloudscape serve --print-config");
            let stderr = String::from_utf8_lossy(&o.stderr);
            prop_assert!(!stderr.contains("panicked"), "{stderr}");
            match o.status.code() {
                Some(0) => prop_assert!(String::from_utf8_lossy(&o.stdout).contains("[worlds.default]")),
                Some(1) => prop_assert!(one_sentence(&stderr), "{stderr}"),
                // clap's own usage errors (a `--listen` value that starts with '-'), as
                // `check_cli` accepts them for every other command.
                Some(2) => prop_assert!(stderr.starts_with("error: "), "{stderr}"),
                other => prop_assert!(false, "exit {other:?}: {stderr}"),
            }
            Ok(())
        })
        .unwrap();

    // `fuzz` itself refuses bad arguments clearly.
    for args in [
        vec!["fuzz", "--target", "ftp://x", "--requests", "1"],
        vec!["fuzz", "--target", "http://127.0.0.1:1", "--requests", "1"],
        vec!["fuzz", "--target", "http://127.0.0.1:1", "--concurrency", "0"],
        vec!["fuzz", "--target", "http://127.0.0.1:1", "--timeout", "nan"],
    ] {
        let o = Command::new(BIN).args(&args).output().unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(one_sentence(&stderr), "{stderr}");
    }

    // Arguments that are not UTF-8 at all.
    #[cfg(unix)]
    {
        use std::os::unix::ffi::OsStrExt;
        let bad = std::ffi::OsStr::from_bytes(b"\xff\xfe");
        let o = Command::new(BIN)
            .args(["density", "--world"])
            .arg(bad)
            .args(["--bbox", "0,0,1,1", "--t", "0", "--out", &out_s])
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(!String::from_utf8_lossy(&o.stderr).contains("panicked"));
    }
}
