//! The HTTP service over real sockets: every route, caching, compression, errors,
//! shedding, metrics and shutdown. Each test starts its own server on 127.0.0.1:0
//! with a small test config (tiny layers) so the suite stays fast.

mod common;

use std::collections::HashMap;
use std::time::Duration;

use cloudscape_core::world::Config;
use cloudscape_server::{Server, ServerConfig, ShutdownHandle};
use reqwest::StatusCode;
use reqwest::header::{HeaderMap, HeaderValue};

/// A second world beside the test world's `default`, so routes can tell worlds apart.
const OTHER_WORLD: &str = r#"{ seed = 99, layers = [
    { name = "only", preset = "puffy", base = 2000.0, cell_size = 100.0, cell_height = 100.0,
      depth = 1, dt = 10.0, epoch = { length = 4, warmup = 4, fade = 2 } },
] }"#;

/// The test world as this file serves it: a second world, a fixed sun, a queue of 8 and
/// series of at most 8 frames, then `overrides` (as [`common::test_config`]'s).
fn test_config(overrides: &[(&str, &str)]) -> String {
    let mut all = vec![
        // No compute-ahead: these tests count computations, and a keyframe computed
        // ahead in the background (tests/keyframes.rs tests that) would race them.
        ("server.ahead_threads", "0"),
        ("server.compute_queue", "8"),
        ("server.max_series", "8"),
        ("sun", "{ latitude = 45.0, day_of_year = 172 }"),
        ("worlds.other", OTHER_WORLD),
    ];
    all.extend_from_slice(overrides);
    common::test_config(&all)
}

const TILE_ROUTE: &str = "/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}";

struct TestServer {
    base: String,
    client: reqwest::Client,
    shutdown: ShutdownHandle,
    task: tokio::task::JoinHandle<std::io::Result<()>>,
}

/// The test config with `overrides`, parsed.
fn config_with(overrides: &[(&str, &str)]) -> (Config, ServerConfig) {
    let text = test_config(overrides);
    (
        Config::parse(&text).expect("test config is valid"),
        ServerConfig::parse(&text).expect("test config is valid"),
    )
}

async fn start((config, settings): (Config, ServerConfig)) -> TestServer {
    let server = Server::bind(config, settings).await.expect("bind 127.0.0.1:0");
    let addr = server.local_addr().unwrap();
    let shutdown = server.shutdown_handle();
    let task = tokio::spawn(server.run());
    let client = reqwest::Client::builder().no_proxy().build().unwrap();
    let s = TestServer {
        base: format!("http://{addr}"),
        client,
        shutdown,
        task,
    };
    s.wait_ready().await;
    s
}

impl TestServer {
    async fn get(&self, path: &str) -> reqwest::Response {
        self.get_with(path, &[]).await
    }

    async fn get_with(&self, path: &str, headers: &[(&'static str, &str)]) -> reqwest::Response {
        let mut h = HeaderMap::new();
        for (k, v) in headers {
            h.insert(*k, HeaderValue::from_str(v).unwrap());
        }
        self.client
            .get(format!("{}{path}", self.base))
            .headers(h)
            .send()
            .await
            .expect("request")
    }

    async fn json(&self, path: &str) -> serde_json::Value {
        let r = self.get(path).await;
        assert_eq!(r.status(), StatusCode::OK, "{path}");
        r.json_body().await
    }

    /// Polls `/readyz` (bounded: start-up computes one column per layer).
    async fn wait_ready(&self) {
        for _ in 0..1200 {
            if let Ok(r) = self.client.get(format!("{}/readyz", self.base)).send().await
                && r.status() == StatusCode::OK
            {
                return;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        panic!("server never became ready");
    }

    /// Sum of every sample of `name` whose labels include all of `labels`.
    async fn metric(&self, name: &str, labels: &[(&str, &str)]) -> f64 {
        let text = self.get("/metrics").await.text().await.unwrap();
        common::parse_metric(&text, name, labels)
    }
}

trait JsonBody {
    async fn json_body(self) -> serde_json::Value;
}

impl JsonBody for reqwest::Response {
    async fn json_body(self) -> serde_json::Value {
        let bytes = self.bytes().await.unwrap();
        serde_json::from_slice(&bytes)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {:?}", String::from_utf8_lossy(&bytes)))
    }
}

/// Parses an `.npy` density tile into (shape, values).
fn parse_npy(bytes: &[u8]) -> ((usize, usize, usize), Vec<f32>) {
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
    let hl = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = std::str::from_utf8(&bytes[10..10 + hl]).unwrap();
    assert!(header.contains("'descr': '<f4'"), "{header}");
    let shape = header.split("'shape': (").nth(1).unwrap().split(')').next().unwrap();
    let dims: Vec<usize> = shape
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let values: Vec<f32> = bytes[10 + hl..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    ((dims[0], dims[1], dims[2]), values)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn discovery_lists_worlds_and_describes_layers() {
    let s = start(config_with(&[])).await;
    let list = s.json("/v1/worlds").await;
    let names = common::world_names(&list);
    assert_eq!(names, ["default", "other"]);
    assert_eq!(list["algorithm_version"], cloudscape_core::world::ALGORITHM_VERSION);

    let w = s.json("/v1/worlds/default").await;
    assert_eq!(w["tile_size"], 256);
    assert_eq!(w["maxzoom"], 20);
    assert_eq!(w["layers"][0]["name"], "low");
    assert_eq!(w["layers"][0]["cell_size"], 100.0);
    assert_eq!(w["layers"][0]["dt"], 10.0);
    assert_eq!(w["layers"][0]["frame_seconds"], 2.5);
    // Keyframes: one step at level 0, doubling per level to 16 steps.
    let spans: Vec<f64> = w["layers"][0]["keyframe_spans"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(spans, [10.0, 20.0, 40.0, 80.0, 160.0]);
    assert_eq!(w["layers"][1]["top"], 5200.0);
    assert!(w["products"].as_array().unwrap().iter().any(|p| p == "density.npy"));
    assert!(
        w["tiles"][0]
            .as_str()
            .unwrap()
            .starts_with("/v1/worlds/default/tiles/{z}/{x}/{y}/")
    );

    // A decimal u64 is that seed with the default climate; leading zeros name the same world.
    let seeded = s.json("/v1/worlds/0042").await;
    assert_eq!(seeded["seed"], 42);
    assert_eq!(seeded["name"], "42");
    assert_eq!(seeded["layers"], w["layers"]);

    let r = s.get("/v1/worlds/nowhere").await;
    assert_eq!(r.status(), StatusCode::NOT_FOUND);
    assert_eq!(r.json_body().await["error"], "unknown_world");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn density_tiles_agree_across_encodings_and_are_deterministic() {
    let s = start(config_with(&[])).await;
    let path = |p: &str| format!("/v1/worlds/default/tiles/0/-1/2/{p}?t=30");
    let r = s.get(&path("density.npy")).await;
    assert_eq!(r.status(), StatusCode::OK);
    // Level 0 keyframes are one 10 s step apart: t = 30 is keyframe 3, final.
    assert_eq!(r.headers()["x-cloudscape-t"], "30");
    assert_eq!(r.headers()["x-cloudscape-t1"], "40");
    assert_eq!(r.headers()["x-cloudscape-frame"], "3");
    assert!(r.headers()["cache-control"].to_str().unwrap().contains("immutable"));
    assert!(r.headers().get("content-location").is_none());
    let etag = r.headers()["etag"].to_str().unwrap().to_string();
    assert!(etag.starts_with('"') && etag.ends_with('"'), "strong ETag: {etag}");
    let npy = r.bytes().await.unwrap();
    let (shape, values) = parse_npy(&npy);
    assert_eq!(shape, (2, 256, 256));
    assert!(values.iter().all(|v| (0.0..=1.0).contains(v)));

    let f32_bytes = s.get(&path("density.f32")).await.bytes().await.unwrap();
    assert_eq!(&npy[npy.len() - f32_bytes.len()..], &f32_bytes[..]);
    let u8_bytes = s.get(&path("density.u8")).await.bytes().await.unwrap();
    assert_eq!(u8_bytes.len(), values.len());
    for (q, v) in u8_bytes.iter().zip(&values) {
        assert_eq!(*q, (v * 255.0).round() as u8);
    }

    // Another server computes the same bytes and the same ETag (replicas agree).
    let other = start(config_with(&[])).await;
    let r2 = other.get(&path("density.npy")).await;
    assert_eq!(r2.headers()["etag"].to_str().unwrap(), etag);
    assert_eq!(r2.bytes().await.unwrap(), npy);

    // A t inside the span answers with the keyframe: same bytes and ETag, kept until
    // the next keyframe, and the keyframe's own URL as Content-Location.
    let r3 = s
        .get("/v1/worlds/default/tiles/0/-1/2/density.npy?layer=low&t=37.2")
        .await;
    assert_eq!(r3.headers()["x-cloudscape-t"], "30");
    assert_eq!(r3.headers()["etag"].to_str().unwrap(), etag);
    assert_eq!(r3.headers()["cache-control"], "public, max-age=3");
    assert_eq!(
        r3.headers()["content-location"],
        "/v1/worlds/default/tiles/0/-1/2/density.npy?layer=low&t=30"
    );
    assert_eq!(r3.bytes().await.unwrap(), npy);
    // The next keyframe is another answer.
    let next = s.get("/v1/worlds/default/tiles/0/-1/2/density.npy?t=40").await;
    assert_eq!(next.headers()["x-cloudscape-frame"], "4");
    assert_ne!(next.headers()["etag"].to_str().unwrap(), etag);
    // Level 3's span is 80 s: t = 30 and 79 share keyframe 0.
    let far = |t: &str| format!("/v1/worlds/default/tiles/3/0/0/density.u8?t={t}");
    let (a, b) = (s.get(&far("30")).await, s.get(&far("79")).await);
    assert_eq!(a.headers()["x-cloudscape-t"], "0");
    assert_eq!(a.headers()["x-cloudscape-t1"], "80");
    assert_eq!(a.headers()["etag"], b.headers()["etag"]);

    // A different layer is a different grid (depth 1 here).
    let high = s
        .get("/v1/worlds/default/tiles/0/-1/2/density.npy?t=30&layer=high")
        .await;
    assert_eq!(parse_npy(&high.bytes().await.unwrap()).0, (1, 256, 256));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn if_none_match_gives_304_without_computing() {
    let s = start(config_with(&[])).await;
    let path = "/v1/worlds/default/tiles/3/5/-7/density.u8?t=100";
    let first = s.get(path).await;
    assert_eq!(first.status(), StatusCode::OK);
    let etag = first.headers()["etag"].to_str().unwrap().to_string();
    let computed = s
        .metric("cloudscape_computations_total", &[("kind", "tile_density")])
        .await;

    let r = s.get_with(path, &[("if-none-match", &etag)]).await;
    assert_eq!(r.status(), StatusCode::NOT_MODIFIED);
    assert_eq!(r.headers()["etag"].to_str().unwrap(), etag);
    assert!(r.bytes().await.unwrap().is_empty());

    // A key never computed, asked with its (predictable) ETag: 304, and still nothing computed.
    let other = "/v1/worlds/default/tiles/3/5/-7/density.u8?t=200";
    let probe = s.get_with(other, &[("if-none-match", "\"nope\"")]).await;
    assert_eq!(probe.status(), StatusCode::OK);
    let etag2 = probe.headers()["etag"].to_str().unwrap().to_string();
    let before = s
        .metric("cloudscape_computations_total", &[("kind", "tile_density")])
        .await;
    assert_eq!(before, computed + 1.0);
    let s2 = start(config_with(&[])).await;
    let r = s2
        .get_with(other, &[("if-none-match", &format!("\"x\", {etag2}"))])
        .await;
    assert_eq!(r.status(), StatusCode::NOT_MODIFIED);
    assert_eq!(
        s2.metric("cloudscape_computations_total", &[("kind", "tile_density")])
            .await,
        0.0
    );
    assert_ne!(etag, etag2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn compression_is_negotiated() {
    use std::io::Read;
    let s = start(config_with(&[])).await;
    let path = "/v1/worlds/default/tiles/1/0/0/density.f32?t=0";
    let plain = s.get(path).await;
    assert!(plain.headers().get("content-encoding").is_none());
    let etag = plain.headers()["etag"].to_str().unwrap().to_string();
    let plain = plain.bytes().await.unwrap();

    let gz = s.get_with(path, &[("accept-encoding", "gzip")]).await;
    assert_eq!(gz.headers()["content-encoding"], "gzip");
    assert!(
        gz.headers()["vary"]
            .to_str()
            .unwrap()
            .to_ascii_lowercase()
            .contains("accept-encoding")
    );
    let gz_etag = gz.headers()["etag"].to_str().unwrap().to_string();
    assert_eq!(gz_etag, format!("{}-gzip\"", etag.trim_end_matches('"')));
    let body = gz.bytes().await.unwrap();
    let mut decoded = Vec::new();
    flate2::read::GzDecoder::new(&body[..])
        .read_to_end(&mut decoded)
        .unwrap();
    assert_eq!(decoded, plain);

    let r = s.get_with(path, &[("accept-encoding", "zstd")]).await;
    assert_eq!(r.headers()["content-encoding"], "zstd");
    // No brotli (its encoder state is ~27 MiB a stream): a br-only client gets the
    // identity encoding.
    let r = s.get_with(path, &[("accept-encoding", "br")]).await;
    assert!(r.headers().get("content-encoding").is_none());
    assert_eq!(r.bytes().await.unwrap(), plain);
    // The compressed representation's ETag revalidates too.
    let r = s
        .get_with(path, &[("accept-encoding", "gzip"), ("if-none-match", &gz_etag)])
        .await;
    assert_eq!(r.status(), StatusCode::NOT_MODIFIED);
    // JSON is compressed as well.
    let r = s.get_with("/v1/worlds/default", &[("accept-encoding", "zstd")]).await;
    assert_eq!(r.headers()["content-encoding"], "zstd");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_bad_input_gets_a_json_error_and_the_right_status() {
    let s = start(config_with(&[])).await;
    let tile = "/v1/worlds/default/tiles";
    let cases: Vec<(String, u16, &str)> = vec![
        // malformed numbers
        (format!("{tile}/0/0/0/density.npy?t=abc"), 400, "invalid_number"),
        (format!("{tile}/0/0/0/density.npy?t="), 400, "invalid_number"),
        (format!("{tile}/x/0/0/density.npy?t=0"), 400, "invalid_number"),
        (format!("{tile}/0/1.5/0/density.npy?t=0"), 400, "invalid_number"),
        // NaN / infinity
        (format!("{tile}/0/0/0/density.npy?t=NaN"), 400, "not_finite"),
        (format!("{tile}/0/0/0/density.npy?t=inf"), 400, "not_finite"),
        (
            "/v1/worlds/default/sample?x=1e400&y=0&z=1000&t=0".to_string(),
            400,
            "not_finite",
        ),
        // t out of range
        (format!("{tile}/0/0/0/density.npy?t=-1"), 422, "time_out_of_range"),
        (format!("{tile}/0/0/0/density.npy?t=1e13"), 422, "time_out_of_range"),
        // unknown world / layer / product / route
        (
            "/v1/worlds/mars/tiles/0/0/0/density.npy?t=0".to_string(),
            404,
            "unknown_world",
        ),
        (
            "/v1/worlds/99999999999999999999/tiles/0/0/0/density.npy?t=0".to_string(),
            404,
            "unknown_world",
        ),
        (format!("{tile}/0/0/0/density.npy?t=0&layer=nope"), 404, "unknown_layer"),
        (format!("{tile}/0/0/0/density.gif?t=0"), 404, "unknown_product"),
        ("/v2/nothing".to_string(), 404, "not_found"),
        // render parameters are validated even where unused
        (
            format!("{tile}/0/0/0/density.npy?t=0&quality=ultra"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{tile}/0/0/0/density.npy?t=0&sun=10,95"),
            400,
            "invalid_parameter",
        ),
        // inverted, malformed, empty, oversized bbox
        (
            "/v1/worlds/default/region?bbox=100,0,0,100&t=0".to_string(),
            400,
            "invalid_bbox",
        ),
        (
            "/v1/worlds/default/region?bbox=0,0,100&t=0".to_string(),
            400,
            "invalid_parameter",
        ),
        (
            "/v1/worlds/default/region?bbox=0,0,nan,100&t=0".to_string(),
            400,
            "not_finite",
        ),
        (
            "/v1/worlds/default/region?bbox=0,0,10,10&t=0".to_string(),
            422,
            "empty_region",
        ),
        (
            "/v1/worlds/default/region?bbox=0,0,100000,1000&t=0".to_string(),
            413,
            "region_too_large",
        ),
        // too-long or inverted series
        (
            "/v1/worlds/default/series?bbox=0,0,1000,1000&t0=0&t1=1000&dt=1".to_string(),
            413,
            "series_too_long",
        ),
        (
            "/v1/worlds/default/series?bbox=0,0,1000,1000&t0=0&t1=1e12&dt=1e-300".to_string(),
            413,
            "series_too_long",
        ),
        (
            "/v1/worlds/default/series?bbox=0,0,1000,1000&t0=10&t1=0".to_string(),
            400,
            "invalid_parameter",
        ),
        (
            "/v1/worlds/default/series?bbox=0,0,1000,1000&t0=0&t1=10&dt=0".to_string(),
            400,
            "invalid_parameter",
        ),
        // level and tile coordinates out of range, including i64 overflow
        (format!("{tile}/21/0/0/density.npy?t=0"), 422, "level_out_of_range"),
        (format!("{tile}/-1/0/0/density.npy?t=0"), 422, "level_out_of_range"),
        (
            format!("{tile}/99999999999999999999/0/0/density.npy?t=0"),
            422,
            "level_out_of_range",
        ),
        (
            format!("{tile}/0/9223372036854775807/0/density.npy?t=0"),
            422,
            "coordinates_out_of_range",
        ),
        (
            format!("{tile}/0/0/-9223372036854775808/density.npy?t=0"),
            422,
            "coordinates_out_of_range",
        ),
        (
            format!("{tile}/0/92233720368547758070/0/density.npy?t=0"),
            422,
            "coordinates_out_of_range",
        ),
        (
            format!("{tile}/20/17592186044416/0/density.npy?t=0"),
            422,
            "coordinates_out_of_range",
        ),
        (
            format!("{tile}/0/17592186044416/0/density.npy?t=0"),
            422,
            "coordinates_out_of_range",
        ),
        (
            "/v1/worlds/default/sample?x=1e300&y=0&z=1000&t=0".to_string(),
            422,
            "coordinates_out_of_range",
        ),
        (
            "/v1/worlds/default/region?bbox=0,0,1000,1000&t=0&level=21".to_string(),
            422,
            "level_out_of_range",
        ),
        (
            "/v1/worlds/default/region?bbox=-1e300,0,1e300,1000&t=0".to_string(),
            422,
            "coordinates_out_of_range",
        ),
        // bad percent-encoding
        ("/v1/worlds/%FF%FE".to_string(), 400, "invalid_parameter"),
        (
            "/v1/worlds/default/sample?x=%FF&y=0&z=0&t=0".to_string(),
            400,
            "invalid_number",
        ),
    ];
    for (path, status, code) in cases {
        let r = s.get(&path).await;
        assert_eq!(r.status().as_u16(), status, "{path}");
        assert!(
            r.headers()["content-type"]
                .to_str()
                .unwrap()
                .starts_with("application/json"),
            "{path}"
        );
        let body = r.json_body().await;
        assert_eq!(body["error"], code, "{path}: {body}");
        assert!(body["message"].as_str().is_some_and(|m| !m.is_empty()), "{path}");
    }
    let r = s.client.post(format!("{}/v1/worlds", s.base)).send().await.unwrap();
    assert_eq!(r.status(), StatusCode::METHOD_NOT_ALLOWED);
    assert_eq!(r.json_body().await["error"], "method_not_allowed");
    // None of that was a server error.
    assert_eq!(
        s.metric("cloudscape_http_requests_total", &[("status", "500")]).await,
        0.0
    );
}

/// Coverage of the columns of `bbox` (metres) at level 0, computed from density tiles.
fn coverage_from_tiles(tiles: &HashMap<(i64, i64), Vec<f32>>, bbox: [f64; 4], cell: f64, depth: usize) -> f64 {
    let first = |lo: f64| (lo / cell - 0.5).ceil() as i64;
    let (cx0, cx1, cy0, cy1) = (first(bbox[0]), first(bbox[2]), first(bbox[1]), first(bbox[3]));
    let mut covered = 0;
    for row in cy0..cy1 {
        for col in cx0..cx1 {
            let tile = &tiles[&(col.div_euclid(256), row.div_euclid(256))];
            let (r, c) = (row.rem_euclid(256) as usize, col.rem_euclid(256) as usize);
            if (0..depth).any(|k| tile[(k * 256 + r) * 256 + c] >= cloudscape_core::density::CLOUD_THRESHOLD) {
                covered += 1;
            }
        }
    }
    covered as f64 / ((cx1 - cx0) * (cy1 - cy0)) as f64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn region_sample_and_series_agree_with_the_tiles() {
    let s = start(config_with(&[])).await;
    // A bbox straddling tiles (-1..=0, 0): columns -40..40, 100..160 at 100 m cells.
    let bbox = [-4000.0, 10000.0, 4000.0, 16000.0];
    let mut tiles = HashMap::new();
    for tx in [-1, 0] {
        let r = s
            .get(&format!("/v1/worlds/default/tiles/0/{tx}/0/density.npy?t=40"))
            .await;
        tiles.insert((tx, 0), parse_npy(&r.bytes().await.unwrap()).1);
    }
    let bbox_q = "-4000,10000,4000,16000";
    let region = s.json(&format!("/v1/worlds/default/region?bbox={bbox_q}&t=40")).await;
    assert_eq!(region["columns"]["cols"], 80);
    assert_eq!(region["columns"]["rows"], 60);
    let expected = coverage_from_tiles(&tiles, bbox, 100.0, 2);
    // serde_json parses floats to within one ulp; the counts behind them are equal.
    assert!(
        (region["coverage"].as_f64().unwrap() - expected).abs() < 1e-12,
        "{region} vs {expected}"
    );
    assert!(
        expected > 0.0 && expected < 1.0,
        "the test region should be partly cloudy: {expected}"
    );
    let max = tiles.values().flatten().fold(0.0f32, |m, &v| m.max(v));
    assert!(region["max_density"].as_f64().unwrap() <= max as f64);
    let c = region["coverage"].as_f64().unwrap();
    assert_eq!(region["clusters"].as_u64().unwrap() == 0, c == 0.0);
    assert_eq!(region["cloud_base"].is_null(), c == 0.0);

    // A point sample reads the same cell as the tile: column 7, row 12, level k = 1.
    let sample = s.json("/v1/worlds/default/sample?x=750&y=1250&z=1150&t=40").await;
    assert_eq!(sample["layer"], "low");
    assert_eq!(sample["cell"], serde_json::json!([7, 12, 1]));
    let r = s.get("/v1/worlds/default/tiles/0/0/0/density.npy?t=40").await;
    let (_, t00) = parse_npy(&r.bytes().await.unwrap());
    let want = t00[(256 + 12) * 256 + 7];
    assert_eq!(sample["density"].as_f64().unwrap() as f32, want);
    assert!(sample["cloud"].is_boolean());
    // Above every layer: clear sky, no layer.
    let sky = s.json("/v1/worlds/default/sample?x=0&y=0&z=30000&t=40").await;
    assert!(sky["layer"].is_null());
    assert_eq!(sky["density"], 0.0);

    // The series point at t = 40 equals the region answer.
    let series = s
        .json(&format!("/v1/worlds/default/series?bbox={bbox_q}&t0=20&t1=50&dt=10"))
        .await;
    let points = series["points"].as_array().unwrap();
    assert_eq!(
        points.iter().map(|p| p["t"].as_f64().unwrap()).collect::<Vec<_>>(),
        [20.0, 30.0, 40.0, 50.0]
    );
    assert_eq!(points[2]["coverage"], region["coverage"]);
    assert_eq!(points[2]["mean_density"], region["mean_density"]);
    assert_eq!(points[2]["clusters"], region["clusters"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_identical_requests_compute_once() {
    let s = start(config_with(&[])).await;
    let path = "/v1/worlds/other/tiles/2/-3/4/density.npy?t=70";
    let requests = (0..16).map(|_| {
        let (client, url) = (s.client.clone(), format!("{}{path}", s.base));
        async move { client.get(url).send().await.unwrap() }
    });
    let responses = futures_join_all(requests).await;
    let mut bodies = Vec::new();
    for r in responses {
        assert_eq!(r.status(), StatusCode::OK);
        bodies.push(r.bytes().await.unwrap());
    }
    assert!(bodies.windows(2).all(|w| w[0] == w[1]));
    assert_eq!(
        s.metric("cloudscape_computations_total", &[("kind", "tile_density")])
            .await,
        1.0
    );
    let hits = s
        .metric("cloudscape_cache_hits_total", &[("kind", "tile_density")])
        .await;
    let misses = s
        .metric("cloudscape_cache_misses_total", &[("kind", "tile_density")])
        .await;
    assert_eq!(hits + misses, 16.0);
}

/// Awaits all futures concurrently (spawned, so they really overlap).
async fn futures_join_all<F>(futures: impl Iterator<Item = F>) -> Vec<F::Output>
where
    F: std::future::Future + Send + 'static,
    F::Output: Send + 'static,
{
    let handles: Vec<_> = futures.map(tokio::spawn).collect();
    let mut out = Vec::new();
    for h in handles {
        out.push(h.await.unwrap());
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn overload_sheds_with_503_and_never_500() {
    let s = start(config_with(&[("server.compute_queue", "1")])).await;
    let mut shed = 0;
    for round in 0..5 {
        let requests = (0..24).map(|i| {
            let client = s.client.clone();
            let url = format!("{}/v1/worlds/default/tiles/0/{i}/{round}/density.npy?t=10", s.base);
            async move { client.get(url).send().await.unwrap() }
        });
        for r in futures_join_all(requests).await {
            match r.status() {
                StatusCode::OK => {}
                StatusCode::SERVICE_UNAVAILABLE => {
                    shed += 1;
                    // Retry-After is the queue's wait: one short job on 2 threads.
                    let ra: u32 = r.headers()["retry-after"].to_str().unwrap().parse().unwrap();
                    assert!((1..=60).contains(&ra), "{ra}");
                    assert_eq!(r.json_body().await["error"], "overloaded");
                }
                other => panic!("unexpected status {other}"),
            }
        }
        if shed > 0 {
            break;
        }
    }
    assert!(shed > 0, "a queue of one must shed some of 24 concurrent cold tiles");
    assert_eq!(s.metric("cloudscape_shed_total", &[]).await, shed as f64);
    assert_eq!(
        s.metric("cloudscape_http_requests_total", &[("status", "500")]).await,
        0.0
    );
    // Shedding leaves the server healthy: the same tile answers once the queue is free.
    let r = s.get("/v1/worlds/default/tiles/0/0/0/density.npy?t=10").await;
    assert_eq!(r.status(), StatusCode::OK);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_that_cannot_finish_in_its_time_budget_is_refused_before_any_work() {
    // A 1 ms budget: no computation fits in it on any number of threads. (That a
    // request over its budget is stopped and frees its slot is in tests/attacks.rs.)
    let s = start(config_with(&[("server.request_timeout_ms", "1")])).await;
    let path = "/v1/worlds/default/region?bbox=0,0,51200,51200&t=0";
    let r = s.get(path).await;
    assert_eq!(r.status(), StatusCode::PAYLOAD_TOO_LARGE);
    let body = r.json_body().await;
    assert_eq!(body["error"], "too_much_work");
    assert!(
        body["message"].as_str().unwrap().contains("server.request_timeout_ms"),
        "{body}"
    );
    assert_eq!(
        s.metric("cloudscape_computations_total", &[("kind", "region")]).await,
        0.0
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn operator_routes_health_readiness_metrics_openapi() {
    let s = start(config_with(&[])).await;
    assert_eq!(s.json("/healthz").await["status"], "ok");
    assert_eq!(s.json("/readyz").await["status"], "ok");

    let r = s
        .get_with(
            "/v1/worlds/default/tiles/0/0/0/density.u8?t=0",
            &[("x-request-id", "abc-123")],
        )
        .await;
    assert_eq!(r.headers()["x-request-id"], "abc-123");
    let r = s.get("/v1/worlds").await;
    assert!(!r.headers()["x-request-id"].is_empty());

    let text = s.get("/metrics").await.text().await.unwrap();
    assert!(
        text.contains(&format!("route=\"{TILE_ROUTE}\"")),
        "route template label"
    );
    assert!(!text.contains("tiles/0/0/0"), "no per-tile labels");
    for name in [
        "cloudscape_http_request_duration_seconds_bucket",
        "cloudscape_cache_hits_total",
        "cloudscape_cache_misses_total",
        "cloudscape_compute_duration_seconds_bucket",
        "cloudscape_compute_queue_depth",
        "cloudscape_http_requests_in_flight",
        "cloudscape_ready 1",
    ] {
        assert!(text.contains(name), "{name}");
    }

    let doc = s.json("/openapi.json").await;
    assert!(doc["openapi"].as_str().unwrap().starts_with("3."));
    let paths = doc["paths"].as_object().unwrap();
    for p in [
        "/v1/worlds",
        "/v1/worlds/{world}",
        TILE_ROUTE,
        "/v1/worlds/{world}/sample",
        "/v1/worlds/{world}/region",
        "/v1/worlds/{world}/series",
        "/healthz",
        "/readyz",
        "/metrics",
        "/openapi.json",
        "/v1/worlds/{world}/render.png",
        "/v1/splats.png",
        "/v1/splats.json",
        "/v1/sky.json",
    ] {
        assert!(paths.contains_key(p), "openapi lacks {p}");
    }
    let tile_params: Vec<&str> = paths[TILE_ROUTE]["get"]["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    for p in ["world", "z", "x", "y", "product", "t", "layer", "quality", "sun"] {
        assert!(tile_params.contains(&p), "tile parameter {p}");
    }
    for status in ["200", "304", "400", "404", "413", "422", "503"] {
        assert!(
            paths[TILE_ROUTE]["get"]["responses"].get(status).is_some(),
            "tile response {status}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn graceful_shutdown_drains_and_finishes_in_flight_requests() {
    let s = start(config_with(&[("server.drain_ms", "1500")])).await;
    // A large region is slow enough to be in flight while shutdown starts; if it
    // finishes before it is seen in flight, try another (cold) time.
    let mut observed = false;
    for attempt in 0..10 {
        let url = format!(
            "{}/v1/worlds/default/region?bbox=0,0,51200,51200&t={}",
            s.base,
            1000 + attempt * 10
        );
        let slow = tokio::spawn(s.client.get(url).send());
        // In flight: this /metrics request plus the slow one.
        let mut seen = false;
        while !slow.is_finished() {
            if s.metric("cloudscape_http_requests_in_flight", &[]).await >= 2.0 {
                seen = true;
                break;
            }
        }
        if !seen {
            continue;
        }
        s.shutdown.trigger();
        // The server's drain task marks it draining when it next runs, which on a
        // loaded machine may be after a request or two: readiness must turn within
        // the drain time, while the slow request is still being answered.
        let mut ready = s.get("/readyz").await;
        let since = std::time::Instant::now();
        while ready.status() == StatusCode::OK && since.elapsed() < Duration::from_millis(1000) {
            tokio::time::sleep(Duration::from_millis(10)).await;
            ready = s.get("/readyz").await;
        }
        assert_eq!(ready.status(), StatusCode::SERVICE_UNAVAILABLE);
        assert_eq!(ready.json_body().await["status"], "draining");
        let response = slow.await.unwrap().expect("in-flight request completes");
        assert_eq!(response.status(), StatusCode::OK);
        assert!(response.json_body().await["coverage"].is_number());
        observed = true;
        break;
    }
    assert!(observed, "a slow request was never seen in flight");
    s.task.await.unwrap().expect("server stops cleanly");
    assert!(
        reqwest::Client::new()
            .get(format!("{}/healthz", s.base))
            .send()
            .await
            .is_err(),
        "no longer accepting"
    );
}

#[test]
fn serve_command_prints_config_and_stops_on_sigterm() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("test.toml");
    let test_config = test_config(&[]);
    std::fs::write(&config, &test_config).unwrap();

    let out = common::print_config(
        &["--config", config.to_str().unwrap()],
        &[("CLOUDSCAPE_SERVER_CACHE_BYTES", "12345")],
    );
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    let printed = Config::parse(&text).expect("printed config parses");
    assert_eq!(ServerConfig::parse(&text).unwrap().cache_bytes, 12345);
    assert_eq!(printed.worlds, Config::parse(&test_config).unwrap().worlds);

    let out = common::print_config(&[], &[]);
    let printed = ServerConfig::parse(&String::from_utf8(out.stdout).unwrap()).unwrap();
    assert_eq!(printed.listen, "127.0.0.1:8080", "default listen address");

    let bad = common::print_config(&[], &[("CLOUDSCAPE_SERVER_NOPE", "1")]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("nope"));

    let server = common::ServeProcess::start(&["--config", config.to_str().unwrap()], &[]);
    assert!(server.terminate(), "graceful exit on SIGTERM");
}

const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// Decodes an 8-bit PNG into (width, height, channels, pixels).
fn decode_png(bytes: &[u8]) -> (u32, u32, usize, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    (info.width, info.height, info.color_type.samples(), buf)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn render_tile_products_share_one_shading_per_sun_bucket() {
    let s = start(config_with(&[])).await;
    let tile = "/v1/worlds/default/tiles/0/0/0";
    let q = "t=40&quality=fast&sun=10,30";

    // coverage.png: R is the column's largest density (row 0 = north), never compressed.
    let r = s
        .get_with(&format!("{tile}/coverage.png?t=40"), &[("accept-encoding", "gzip")])
        .await;
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["content-type"], "image/png");
    assert!(r.headers().get("content-encoding").is_none(), "PNG is not recompressed");
    let (w, h, channels, pixels) = decode_png(&r.bytes().await.unwrap());
    assert_eq!((w, h, channels), (256, 256, 3), "RGB: no data in alpha");
    let (_, density) = parse_npy(&s.get(&format!("{tile}/density.npy?t=40")).await.bytes().await.unwrap());
    for (row, col) in [(0usize, 0usize), (17, 200), (255, 255), (128, 3)] {
        let max = (0..2)
            .map(|k| density[(k * 256 + row) * 256 + col])
            .fold(0.0f32, f32::max);
        let red = pixels[((255 - row) * 256 + col) * 3] as f32;
        assert!(
            (red - max * 255.0).abs() <= 1.0,
            "coverage R at ({row}, {col}): {red} vs {max}"
        );
    }

    let get = |product: &'static str, query: &'static str| {
        let url = format!("{}{tile}/{product}?{query}", s.base);
        let client = s.client.clone();
        async move { client.get(url).send().await.unwrap() }
    };
    let json = get("billboards.json", q).await;
    assert_eq!(json.headers()["content-type"], "application/json");
    let etag = json.headers()["etag"].to_str().unwrap().to_string();
    assert!(json.json_body().await.is_object());
    let bin = get("billboards.bin", q).await.bytes().await.unwrap();
    assert_eq!(&bin[..4], b"CSBB");
    let atlas = get("atlas.png", q).await;
    assert_eq!(atlas.headers()["content-type"], "image/png");
    assert_eq!(&atlas.bytes().await.unwrap()[..8], PNG_SIGNATURE);
    assert!(get("atlas.json", q).await.json_body().await.is_object());
    assert_eq!(&get("shadow.png", q).await.bytes().await.unwrap()[..8], PNG_SIGNATURE);
    // Five products, three shadings: the billboards (json and bin) come from one, and
    // only what is asked or every view needs is encoded from it (`Product::encoding`);
    // the impostor atlas (png and json), drawn only on request, from a second one; the
    // shadow map, which clients derive from the billboards, from a third.
    assert_eq!(
        s.metric("cloudscape_computations_total", &[("kind", "tile_shaded")])
            .await,
        3.0
    );

    // A sun in the same ~8° bucket is the same product; another bucket or quality is not.
    let same = get("billboards.json", "t=40&quality=fast&sun=11,31").await;
    assert_eq!(same.headers()["etag"].to_str().unwrap(), etag);
    let other_sun = get("billboards.json", "t=40&quality=fast&sun=100,30").await;
    assert_ne!(other_sun.headers()["etag"].to_str().unwrap(), etag);
    let other_quality = get("billboards.json", "t=40&quality=balanced&sun=10,30").await;
    assert_ne!(other_quality.headers()["etag"].to_str().unwrap(), etag);
    assert_eq!(
        s.metric("cloudscape_computations_total", &[("kind", "tile_shaded")])
            .await,
        5.0
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn render_png_and_splat_sheets() {
    let s = start(config_with(&[])).await;
    let url = "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=40&size=64x36&quality=fast&sun=180,40";
    let r = s.get(url).await;
    assert_eq!(r.status(), StatusCode::OK);
    assert_eq!(r.headers()["content-type"], "image/png");
    let etag = r.headers()["etag"].to_str().unwrap().to_string();
    let png1 = r.bytes().await.unwrap();
    assert_eq!(decode_png(&png1).0, 64);
    assert_eq!(
        s.get_with(url, &[("if-none-match", &etag)]).await.status(),
        StatusCode::NOT_MODIFIED
    );

    for (path, status, code) in [
        ("/v1/worlds/default/render.png?t=0", 400, "missing_parameter"),
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10&t=0",
            400,
            "invalid_parameter",
        ),
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=0&size=0x10",
            400,
            "invalid_parameter",
        ),
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=0&size=8000x8000",
            413,
            "too_much_work",
        ),
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=nan",
            400,
            "not_finite",
        ),
        ("/v1/splats.png?quality=ultra", 400, "invalid_parameter"),
        // The path tracer's samples: an integer of at least 2, only for reference, and
        // samples × pixels within [limits] max_path_samples (2^24), refused before work.
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=0&size=16x9&quality=reference&samples=1",
            400,
            "invalid_parameter",
        ),
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=0&size=16x9&quality=reference&samples=2.5",
            400,
            "invalid_number",
        ),
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=0&size=16x9&quality=fast&samples=8",
            400,
            "invalid_parameter",
        ),
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=0&size=1024x1024&quality=reference&samples=64",
            413,
            "too_much_work",
        ),
        (
            "/v1/worlds/default/render.png?camera=0,0,1200,0,10,60&t=0&size=16x9&quality=reference&samples=99999999999",
            413,
            "too_much_work",
        ),
    ] {
        let r = s.get(path).await;
        assert_eq!(r.status().as_u16(), status, "{path}");
        assert_eq!(r.json_body().await["error"], code, "{path}");
    }

    // The path tracer states its noise, in a header and in the PNG's text, also when the
    // image comes from the cache; the single-scattering marcher states none.
    let url =
        "/v1/worlds/default/render.png?camera=12800,-20000,1200,0,8,70&t=43200&size=16x9&quality=reference&samples=4";
    let mut first = None;
    for _ in 0..2 {
        let r = s.get(url).await;
        assert_eq!(r.status(), StatusCode::OK);
        assert_eq!(r.headers()["x-cloudscape-samples"], "4");
        let noise: f64 = r.headers()["x-cloudscape-noise"].to_str().unwrap().parse().unwrap();
        assert!(noise.is_finite() && noise > 0.0, "{noise}");
        let bytes = r.bytes().await.unwrap();
        let stated = cloudscape_core::render::image::png_noise(&bytes).unwrap();
        assert_eq!((stated.samples, stated.std_error), (4, noise));
        assert_eq!(*first.get_or_insert(bytes.clone()), bytes);
    }
    let single = s
        .get("/v1/worlds/default/render.png?camera=12800,-20000,1200,0,8,70&t=43200&size=16x9&quality=reference-single")
        .await;
    assert_eq!(single.status(), StatusCode::OK);
    assert!(single.headers().get("x-cloudscape-noise").is_none());

    // The sheets are made during start-up: serving them computes nothing.
    let png = s.get("/v1/splats.png?quality=fast").await;
    assert_eq!(png.headers()["content-type"], "image/png");
    assert!(png.headers()["cache-control"].to_str().unwrap().contains("immutable"));
    assert_eq!(&png.bytes().await.unwrap()[..8], PNG_SIGNATURE);
    let json = s.json("/v1/splats.json").await;
    assert_eq!(json["quality"], "balanced");
    assert_eq!(
        s.metric("cloudscape_computations_total", &[("kind", "splats")]).await,
        0.0
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sky_json_serves_the_renderers_sky_per_sun_bucket() {
    use cloudscape_core::render::Sun;
    use cloudscape_core::render::light::{Lighting, ShadingParams};
    let s = start(config_with(&[])).await;
    let noon = s.json("/v1/sky.json?sun=180,60").await;
    let (rows, cols) = (
        noon["sky"]["rows"].as_u64().unwrap(),
        noon["sky"]["columns"].as_u64().unwrap(),
    );
    let rgb = noon["sky"]["rgb"].as_array().unwrap();
    assert_eq!(rgb.len() as u64, rows * cols * 3);
    // The same values as the renderer's own Lighting for the bucket's centre sun.
    let sun = Sun::new(180.0, 60.0).unwrap().bucket().centre();
    let l = Lighting::new(sun, ShadingParams::default());
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * b.abs().max(1e-3);
    for c in 0..3 {
        assert!(close(noon["sun_rgb"][c].as_f64().unwrap(), l.sun_rgb[c]));
        assert!(close(
            noon["sky_ambient_above"][c].as_f64().unwrap(),
            l.sky_ambient_above[c]
        ));
        assert!(close(
            noon["sky_ambient_below"][c].as_f64().unwrap(),
            l.sky_ambient_below[c]
        ));
    }
    let zenith_row = (rows - 1) as usize * cols as usize * 3;
    let night = noon["night_rgb"].as_array().unwrap();
    let z = l.sky_radiance([0.0, 0.0, 1.0]);
    for c in 0..3 {
        let v = rgb[zenith_row + c].as_f64().unwrap() + night[c].as_f64().unwrap();
        assert!(close(v, z[c]), "zenith channel {c}: {v} vs {}", z[c]);
    }
    // A sun in the same ~8° bucket gives the same bytes and ETag; 304 on revalidation.
    let a = s.get("/v1/sky.json?sun=181,61").await;
    let b = s.get("/v1/sky.json?sun=180,60").await;
    let etag = a.headers()["etag"].to_str().unwrap().to_string();
    assert_eq!(etag, b.headers()["etag"].to_str().unwrap());
    assert_eq!(a.bytes().await.unwrap(), b.bytes().await.unwrap());
    let r = s.get_with("/v1/sky.json?sun=180,60", &[("if-none-match", &etag)]).await;
    assert_eq!(r.status(), StatusCode::NOT_MODIFIED);
    // The clock's sun at t, and a sunset sky that is redder than noon's.
    let clock = s.json("/v1/sky.json?t=43200").await;
    assert!(clock["sun"]["elevation_deg"].as_f64().unwrap() > 0.0);
    let low = s.json("/v1/sky.json?sun=270,2").await;
    let ratio = |v: &serde_json::Value| v["sun_rgb"][0].as_f64().unwrap() / v["sun_rgb"][2].as_f64().unwrap();
    assert!(ratio(&low) > 2.0 * ratio(&noon));
    // Bad input is a JSON error.
    for (path, status, code) in [
        ("/v1/sky.json", 400, "invalid_parameter"),
        ("/v1/sky.json?sun=10,95", 400, "invalid_parameter"),
        ("/v1/sky.json?sun=nan,5", 400, "not_finite"),
        ("/v1/sky.json?t=-1", 422, "time_out_of_range"),
    ] {
        let r = s.get(path).await;
        assert_eq!(r.status().as_u16(), status, "{path}");
        assert_eq!(r.json_body().await["error"], code, "{path}");
    }
}
