//! Play areas kept warm (`[[worlds.NAME.warm]]`) and the world clock, over real sockets:
//! readiness waits for the current and next keyframes, the first request for a warm keyframe is a
//! cache hit, next keyframes are ready before the clock reaches them, discovery lists
//! the areas and the clock, and bad areas or clocks stop the server at start with the
//! key named.

mod common;

use std::io::Write;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{client, eventually, free_port, parse_metric, test_config};

/// World time at the Unix epoch of the test worlds' clock: t ≈ 1.8e8 s these years.
const OFFSET: f64 = -1.6e9;

/// Two play areas on the test world (layers `low`, 100 m cells, dt 10 s, and `high`,
/// 200 m, dt 20 s): a triangle inside level-0 tile (0, 0) of `low` at levels 0 and 1 in
/// two qualities, and a box in tile (1, 0) of `low` at level 0 with a grid product too.
const AREAS: &str = r#"[
    { name = "town", polygon = [[1000.0, 1000.0], [9000.0, 2000.0], [8000.0, 9000.0]], levels = [0, 1], qualities = ["fast", "balanced"] },
    { name = "port", bbox = [30000.0, 1000.0, 35000.0, 6000.0], products = ["billboards.bin", "billboards.delta.bin", "density.u8"] },
]"#;

/// Tile variants of [`AREAS`] per area: `town` 2 layers × 2 levels × 2 qualities (one
/// shading each); `port` 2 layers × (one shading + density.u8).
const TOWN_TILES: u64 = 8;
const PORT_TILES: u64 = 4;
/// Distinct variants kept: `high`'s level-0 tile (0, 0) in `fast` is both areas'.
const DISTINCT_TILES: f64 = 11.0;

/// A `cloudscape serve` process of `config` on a free port, not waited for.
struct Serving {
    child: Child,
    base: String,
    _file: tempfile::NamedTempFile,
}

impl Serving {
    fn spawn(config: &str) -> Serving {
        let mut file = tempfile::NamedTempFile::new().unwrap();
        file.write_all(config.as_bytes()).unwrap();
        let listen = format!("127.0.0.1:{}", free_port());
        let child = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
            .args(["serve", "--config", file.path().to_str().unwrap(), "--listen", &listen])
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn cloudscape serve");
        Serving {
            child,
            base: format!("http://{listen}"),
            _file: file,
        }
    }

    fn get(&self, path: &str) -> reqwest::blocking::Response {
        client()
            .get(format!("{}{path}", self.base))
            .send()
            .unwrap_or_else(|e| panic!("GET {path}: {e}"))
    }

    fn json(&self, path: &str) -> serde_json::Value {
        let r = self.get(path);
        assert_eq!(r.status().as_u16(), 200, "{path}");
        serde_json::from_slice(&r.bytes().unwrap()).unwrap()
    }

    fn metric(&self, name: &str, labels: &[(&str, &str)]) -> f64 {
        parse_metric(&self.get("/metrics").text().unwrap(), name, labels)
    }

    /// The `/readyz` answers from the first one the server gives until it says 200
    /// (status and body), and the metrics text at that moment.
    fn watch_readiness(&mut self, limit: Duration) -> (Vec<(u16, serde_json::Value)>, String) {
        let c = client();
        let start = Instant::now();
        let mut seen = Vec::new();
        loop {
            assert!(self.child.try_wait().unwrap().is_none(), "the server exited");
            assert!(
                start.elapsed() < limit,
                "not ready within {limit:?}: {:?}",
                &seen[seen.len().saturating_sub(3)..]
            );
            if let Ok(r) = c.get(format!("{}/readyz", self.base)).send() {
                let status = r.status().as_u16();
                seen.push((status, serde_json::from_slice(&r.bytes().unwrap()).unwrap()));
                if status == 200 {
                    return (seen, self.get("/metrics").text().unwrap());
                }
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

impl Drop for Serving {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The test world with its clock at `rate` and the play areas `areas`.
fn config(rate: f64, areas: &str) -> String {
    config_with(rate, areas, &[])
}

/// [`config`] with more `overrides` (as `common::test_config` takes them).
fn config_with(rate: f64, areas: &str, overrides: &[(&str, &str)]) -> String {
    let clock = format!("{{ offset = {OFFSET:?}, rate = {rate:?} }}");
    let mut all = vec![("worlds.default.clock", clock.as_str()), ("worlds.default.warm", areas)];
    all.extend_from_slice(overrides);
    test_config(&all)
}

fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

#[test]
fn readiness_waits_for_the_warm_keyframes_and_the_first_view_is_a_cache_hit() {
    let mut s = Serving::spawn(&config(1.0, AREAS));
    let (seen, metrics) = s.watch_readiness(Duration::from_secs(120));
    // Not ready while the keyframes are computed: every 503 says how many variants are
    // left, and at the first 200 each variant has its current and next keyframes.
    for (status, body) in &seen[..seen.len() - 1] {
        assert_eq!(*status, 503, "{body}");
        assert_eq!(body["status"], "starting", "{body}");
        let left = body["warm_pending"].as_f64().expect("warm_pending while starting");
        assert!(left <= DISTINCT_TILES, "{body}");
    }
    assert_eq!(parse_metric(&metrics, "cloudscape_warm_tiles", &[]), DISTINCT_TILES);
    assert!(
        parse_metric(&metrics, "cloudscape_warm_computed_total", &[]) >= DISTINCT_TILES,
        "{metrics}"
    );
    assert_eq!(parse_metric(&metrics, "cloudscape_ready", &[]), 1.0);

    // The first view of the town: the current keyframe of every warm tile, every
    // product, is served from the cache; no request computes anything. (Once the next
    // keyframes are computed too, a keyframe boundary passing meanwhile changes
    // nothing: the new current keyframe was the next.)
    assert!(eventually(Duration::from_secs(60), || {
        s.metric("cloudscape_warm_pending", &[]) == 0.0
    }));
    let world = s.json("/v1/worlds/default");
    let now = world["clock"]["now"].as_f64().unwrap();
    let computed = |s: &Serving| s.metric("cloudscape_computations_total", &[]);
    let (before, hits) = (computed(&s), s.metric("cloudscape_cache_hits_total", &[]));
    let mut asked = 0.0;
    for (layer, dt) in [("low", 10.0), ("high", 20.0)] {
        for (z, quality) in [(0, "fast"), (0, "balanced"), (1, "fast"), (1, "balanced")] {
            let span = dt * f64::from(1u32 << z);
            let t0 = (now / span).floor() * span;
            for product in ["billboards.bin", "billboards.delta.bin"] {
                let path = format!("/v1/worlds/default/tiles/{z}/0/0/{product}?t={t0}&layer={layer}&quality={quality}");
                let r = s.get(&path);
                assert_eq!(r.status().as_u16(), 200, "{path}");
                asked += 1.0;
            }
        }
    }
    let t0 = (now / 10.0).floor() * 10.0;
    let r = s.get(&format!("/v1/worlds/default/tiles/0/1/0/density.u8?t={t0}&layer=low"));
    assert_eq!(r.status().as_u16(), 200);
    asked += 1.0;
    assert_eq!(computed(&s), before, "a request computed a warm keyframe");
    assert_eq!(s.metric("cloudscape_cache_hits_total", &[]) - hits, asked);
    assert!(s.metric("cloudscape_warm_served_total", &[]) >= 1.0);
    // The same bytes as a request computes: a server that keeps nothing warm answers
    // the keyframe with the same ETag and body.
    let path = format!("/v1/worlds/default/tiles/0/0/0/billboards.bin?t={t0}&layer=low&quality=fast");
    let warm = s.get(&path);
    let (etag, body) = (warm.headers()["etag"].clone(), warm.bytes().unwrap());
    let mut plain = Serving::spawn(&config_with(1.0, AREAS, &[("server.warm_threads", "0")]));
    plain.watch_readiness(Duration::from_secs(60));
    let again = plain.get(&path);
    assert_eq!(again.headers()["etag"], etag);
    assert_eq!(again.bytes().unwrap(), body);
    assert_eq!(plain.json("/v1/worlds/default")["warm"], serde_json::json!([]));
}

/// Ready means ready for the players: at the first 200 of `/readyz` every warm
/// variant has its next keyframe in the cache as well as its current one, so the
/// players who arrive then and fetch next keyframes at their prefetch points compute
/// nothing (before, readiness came with most next keyframes pending, and 200 players
/// started then got 503s).
#[test]
fn readiness_waits_for_the_next_keyframes_too() {
    // A slow clock (a level-0 span of `low` lasts 100 real seconds; t ≈ 1.8e8 s), so
    // no keyframe boundary passes while the next keyframes are asked for.
    let slow = [("worlds.default.clock", "{ offset = 0.0, rate = 0.1 }")];
    let mut s = Serving::spawn(&config_with(0.1, AREAS, &slow));
    let (seen, metrics) = s.watch_readiness(Duration::from_secs(120));
    assert_eq!(seen.last().unwrap().0, 200);
    assert_eq!(
        parse_metric(&metrics, "cloudscape_warm_pending", &[]),
        0.0,
        "ready with warm keyframes pending"
    );
    let now = s.json("/v1/worlds/default")["clock"]["now"].as_f64().unwrap();
    let computed = |s: &Serving| s.metric("cloudscape_computations_total", &[]);
    let before = computed(&s);
    let next = |dt: f64, z: u32| {
        let span = dt * f64::from(1u32 << z);
        ((now / span).floor() + 1.0) * span
    };
    for (layer, dt) in [("low", 10.0), ("high", 20.0)] {
        for (z, quality) in [(0, "fast"), (0, "balanced"), (1, "fast"), (1, "balanced")] {
            let t = next(dt, z);
            let path = format!("/v1/worlds/default/tiles/{z}/0/0/billboards.bin?t={t}&layer={layer}&quality={quality}");
            assert_eq!(s.get(&path).status().as_u16(), 200, "{path}");
        }
        // The port's tile: (1, 0) of `low`'s 25.6 km tiles, (0, 0) of `high`'s 51.2 km.
        let (t, x) = (next(dt, 0), if layer == "low" { 1 } else { 0 });
        let path = format!("/v1/worlds/default/tiles/0/{x}/0/density.u8?t={t}&layer={layer}");
        assert_eq!(s.get(&path).status().as_u16(), 200, "{path}");
    }
    assert_eq!(
        computed(&s),
        before,
        "a request computed a next keyframe of a play area"
    );
}

#[test]
fn next_keyframes_are_ready_before_the_clock_reaches_them() {
    // Ten world seconds a second: a level-0 keyframe of `low` every real second.
    let areas = r#"[{ name = "camp", bbox = [1000.0, 1000.0, 2000.0, 2000.0], layers = ["low"] }]"#;
    let mut s = Serving::spawn(&config(10.0, areas));
    s.watch_readiness(Duration::from_secs(60));
    // Each keyframe computed before its start adds a positive lag; the first ones
    // (at start-up) are late.
    let early = |s: &Serving| {
        s.metric("cloudscape_warm_lag_seconds_count", &[])
            - s.metric("cloudscape_warm_lag_seconds_bucket", &[("le", "0")])
    };
    assert!(
        eventually(Duration::from_secs(60), || early(&s) >= 5.0),
        "warm keyframes ready before their start: {}",
        early(&s)
    );
    // A keyframe that was not even the next one at start-up is in the cache when a
    // request asks for it as the clock reaches it.
    let now = s.json("/v1/worlds/default")["clock"]["now"].as_f64().unwrap();
    let t0 = ((now / 10.0).floor() + 1.0) * 10.0;
    assert!(eventually(Duration::from_secs(30), || {
        s.json("/v1/worlds/default")["clock"]["now"].as_f64().unwrap() >= t0
    }));
    let before = s.metric("cloudscape_computations_total", &[]);
    let r = s.get(&format!(
        "/v1/worlds/default/tiles/0/0/0/billboards.delta.bin?t={t0}&layer=low&quality=fast"
    ));
    assert_eq!(r.status().as_u16(), 200);
    assert_eq!(s.metric("cloudscape_computations_total", &[]), before);
}

#[test]
fn discovery_lists_the_clock_and_the_play_areas() {
    // AREAS and a ridge kept warm as far as a viewer on it sees (level 3 of `high`).
    let ridge = r#"{ name = "ridge", bbox = [-5000.0, 60000.0, -1000.0, 61000.0], margin = "view", levels = [3], layers = ["high"] }"#;
    let areas = AREAS.replace("\n]", &format!("\n    {ridge},\n]"));
    let mut s = Serving::spawn(&config(2.5, &areas));
    s.watch_readiness(Duration::from_secs(120));
    let before = unix_now();
    let world = s.json("/v1/worlds/default");
    let after = unix_now();
    let clock = &world["clock"];
    assert_eq!(clock["offset"], OFFSET);
    assert_eq!(clock["rate"], 2.5);
    let now = clock["now"].as_f64().unwrap();
    assert!(
        (OFFSET + 2.5 * before).floor() <= now && now <= OFFSET + 2.5 * after,
        "{now} not within the clock's reading around the request, in whole seconds"
    );
    let warm = world["warm"].as_array().unwrap();
    assert_eq!(warm.len(), 3, "{world}");
    let town = &warm[0];
    assert_eq!(town["name"], "town");
    assert_eq!(town["bbox"], serde_json::json!([1000.0, 1000.0, 9000.0, 9000.0]));
    assert_eq!(
        town["polygon"],
        serde_json::json!([[1000.0, 1000.0], [9000.0, 2000.0], [8000.0, 9000.0]])
    );
    assert_eq!(town["margin"], 0.0);
    assert_eq!(town["levels"], serde_json::json!([0, 1]));
    assert_eq!(
        town["products"],
        serde_json::json!(["billboards.bin", "billboards.delta.bin"])
    );
    assert_eq!(town["qualities"], serde_json::json!(["fast", "balanced"]));
    assert_eq!(town["layers"], serde_json::json!(["low", "high"]));
    assert_eq!(town["tiles"], TOWN_TILES);
    let port = &warm[1];
    assert_eq!(port["name"], "port");
    assert_eq!(port["bbox"], serde_json::json!([30000.0, 1000.0, 35000.0, 6000.0]));
    assert!(port["polygon"].is_null());
    assert_eq!(port["levels"], serde_json::json!([0]));
    assert_eq!(port["qualities"], serde_json::json!(["fast"]));
    assert_eq!(port["tiles"], PORT_TILES);
    let ridge = &warm[2];
    assert_eq!(ridge["name"], "ridge");
    assert_eq!(ridge["margin"], "view");
    assert_eq!(ridge["layers"], serde_json::json!(["high"]));
    // Level-3 tiles of `high` are 409.6 km: the ridge's own and its eastern neighbour,
    // 1 km away (within the 30 km a viewer sees; the level-4 tiles above both are split
    // nearer than 3200 m / (2 tan 37.5° / 800 × 8) ≈ 209 km).
    assert_eq!(ridge["tiles"], 2);
    // `now` changes with every answer, the document does not: a weak ETag without it
    // revalidates (304), compressed or not.
    for coding in ["identity", "gzip"] {
        let get = |etag: Option<&str>| {
            let mut r = client()
                .get(format!("{}/v1/worlds/default", s.base))
                .header("accept-encoding", coding);
            if let Some(e) = etag {
                r = r.header("if-none-match", e);
            }
            r.send().unwrap()
        };
        let first = get(None);
        let etag = first.headers()["etag"].to_str().unwrap().to_string();
        assert!(etag.starts_with("W/\""), "{etag}");
        std::thread::sleep(Duration::from_millis(20));
        assert_eq!(get(Some(&etag)).status().as_u16(), 304, "{coding} {etag}");
    }
    // A seed world has the default world's clock, not its play areas.
    let seed = s.json("/v1/worlds/7");
    assert_eq!(seed["clock"]["rate"], 2.5);
    assert_eq!(seed["warm"], serde_json::json!([]));
}

#[test]
fn bad_play_areas_and_clocks_stop_the_server_with_the_key_named() {
    let town = |fields: &str| format!("[{{ name = \"town\", {fields} }}]");
    let bbox = "bbox = [0.0, 0.0, 5000.0, 5000.0]";
    let cases: Vec<(String, String, &str)> = vec![
        (
            "worlds.default.warm".into(),
            town(&format!("{bbox}, products = [\"clouds.gif\"]")),
            "worlds.default.warm[0].products[0]",
        ),
        (
            "worlds.default.warm".into(),
            town(&format!("{bbox}, layers = [\"low\", \"middle\"]")),
            "worlds.default.warm[0].layers[1]",
        ),
        (
            "worlds.default.warm".into(),
            town(&format!("{bbox}, qualities = [\"ultra\"]")),
            "worlds.default.warm[0].qualities[0]",
        ),
        (
            "worlds.default.warm".into(),
            town("polygon = []"),
            "worlds.default.warm[0].polygon",
        ),
        (
            "worlds.default.warm".into(),
            town("bbox = [5000.0, 0.0, 5000.0, 100.0]"),
            "worlds.default.warm[0].bbox",
        ),
        (
            "worlds.default.warm".into(),
            format!("[{{ name = \"town\", {bbox} }}, {{ name = \"town\", {bbox} }}]"),
            "worlds.default.warm[1].name",
        ),
        (
            "worlds.default.warm".into(),
            town(&format!("{bbox}, levels = [0, 1, 2], margin = 1.0e6")),
            "server.max_warm_tiles",
        ),
        (
            "worlds.default.warm".into(),
            town(&format!("{bbox}, levels = [21]")),
            "worlds.default.warm[0].levels",
        ),
        (
            "worlds.default.warm".into(),
            town(&format!("{bbox}, colour = 3")),
            "colour",
        ),
        (
            "worlds.default.warm".into(),
            town(&format!("{bbox}, margin = \"far\"")),
            "worlds.default.warm[0].margin",
        ),
        (
            "worlds.default.warm".into(),
            "[{ bbox = [0.0, 0.0, 1.0, 1.0] }]".into(),
            "name",
        ),
        (
            "worlds.default.clock".into(),
            "{ rate = 0.0 }".into(),
            "worlds.default.clock.rate",
        ),
        (
            "worlds.default.clock".into(),
            "{ rate = -3.0 }".into(),
            "worlds.default.clock.rate",
        ),
        (
            "worlds.default.clock".into(),
            "{ offset = -5.0e12 }".into(),
            "worlds.default.clock",
        ),
    ];
    for (path, value, named) in &cases {
        let mut file = tempfile::NamedTempFile::new().unwrap();
        file.write_all(test_config(&[(path, value)]).as_bytes()).unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
            .args(["serve", "--config", file.path().to_str().unwrap()])
            .args(["--listen", &format!("127.0.0.1:{}", free_port())])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let exited = eventually(Duration::from_secs(30), || child.try_wait().unwrap().is_some());
        if !exited {
            let _ = child.kill();
        }
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(exited && !out.status.success(), "{path} = {value}: the server started");
        assert!(err.contains(named), "{path} = {value}: {err}");
        assert!(err.contains("invalid config"), "{path} = {value}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one clear sentence: {err}");
    }
}
