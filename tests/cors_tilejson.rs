//! Into the engines, over real sockets: cross-origin access (CORS, preflights) and the
//! TileJSON 3.0.0 documents with their zoom-addressed tile route. (The official
//! TileJSON schema check is tests/ext/tilejson_schema.sh.)

mod common;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::Duration;

use common::{ServeProcess, client, test_config};
use reqwest::StatusCode;
use reqwest::blocking::Response;

/// A server on the test world with `env` set; the config file lives as long as it.
fn serve(env: &[(&str, &str)]) -> (tempfile::NamedTempFile, ServeProcess) {
    serve_config(&[], env)
}

/// A server on the test world with config `overrides` ([`test_config`]) and `env` set.
fn serve_config(overrides: &[(&str, &str)], env: &[(&str, &str)]) -> (tempfile::NamedTempFile, ServeProcess) {
    let mut file = tempfile::NamedTempFile::new().unwrap();
    file.write_all(test_config(overrides).as_bytes()).unwrap();
    let mut all = vec![("RUST_LOG", "warn")];
    all.extend_from_slice(env);
    let server = ServeProcess::start(&["--config", file.path().to_str().unwrap()], &all);
    (file, server)
}

fn get(url: &str, headers: &[(&str, &str)]) -> Response {
    let mut req = client().get(url);
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    req.send().unwrap()
}

fn header(r: &Response, name: &str) -> Option<String> {
    r.headers().get(name).map(|v| v.to_str().unwrap().to_string())
}

/// The comma-separated names of every value of a header, lower-cased.
fn names(r: &Response, name: &str) -> Vec<String> {
    r.headers()
        .get_all(name)
        .iter()
        .flat_map(|v| v.to_str().unwrap().split(','))
        .map(|s| s.trim().to_ascii_lowercase())
        .filter(|s| !s.is_empty())
        .collect()
}

const ORIGIN: &str = "https://game.example";

fn tile_path(level: u32) -> String {
    format!("/v1/worlds/default/tiles/{level}/0/0/coverage.png?t=0&layer=low")
}

fn preflight(base: &str, path: &str, origin: &str) -> Response {
    client()
        .request(reqwest::Method::OPTIONS, format!("{base}{path}"))
        .header("origin", origin)
        .header("access-control-request-method", "GET")
        .header("access-control-request-headers", "if-none-match")
        .send()
        .unwrap()
}

#[test]
fn any_origin_may_read_tiles_their_headers_and_errors() {
    let (_config, s) = serve(&[]);
    let tile = get(&format!("{}{}", s.base, tile_path(0)), &[("origin", ORIGIN)]);
    assert_eq!(tile.status(), StatusCode::OK);
    assert_eq!(header(&tile, "access-control-allow-origin").as_deref(), Some("*"));
    // Any origin gets the same bytes and headers: nothing to vary on.
    assert!(
        !names(&tile, "vary").contains(&"origin".to_string()),
        "{:?}",
        tile.headers()
    );
    let exposed = names(&tile, "access-control-expose-headers");
    for h in [
        "etag",
        "cache-control",
        "content-location",
        "x-cloudscape-t",
        "x-cloudscape-t1",
        "x-cloudscape-frame",
    ] {
        assert!(exposed.contains(&h.to_string()), "{h} not exposed: {exposed:?}");
    }
    // Every header the tile carries that a script needs is in that list.
    for name in tile.headers().keys() {
        if name.as_str().starts_with("x-cloudscape-") {
            assert!(
                exposed.contains(&name.as_str().to_string()),
                "{name} sent but not exposed"
            );
        }
    }
    let etag = header(&tile, "etag").unwrap();
    let again = get(
        &format!("{}{}", s.base, tile_path(0)),
        &[("origin", ORIGIN), ("if-none-match", &etag)],
    );
    assert_eq!(again.status(), StatusCode::NOT_MODIFIED);
    assert_eq!(header(&again, "access-control-allow-origin").as_deref(), Some("*"));
    // A script can read why a request failed.
    let missing = get(&format!("{}/v1/worlds/nowhere", s.base), &[("origin", ORIGIN)]);
    assert_eq!(missing.status(), StatusCode::NOT_FOUND);
    assert_eq!(header(&missing, "access-control-allow-origin").as_deref(), Some("*"));
    // No Origin, no CORS headers needed, but the answer is the same.
    let plain = get(&format!("{}{}", s.base, tile_path(0)), &[]);
    assert_eq!(header(&plain, "etag").unwrap(), etag);
}

#[test]
fn preflights_answer_204_for_every_route() {
    let (_config, s) = serve(&[]);
    for path in [
        tile_path(0).as_str(),
        "/v1/worlds",
        "/v1/worlds/default/tilejson.json",
        "/metrics",
        "/nowhere",
    ] {
        let r = preflight(&s.base, path, ORIGIN);
        assert_eq!(r.status(), StatusCode::NO_CONTENT, "{path}");
        assert_eq!(
            header(&r, "access-control-allow-origin").as_deref(),
            Some("*"),
            "{path}"
        );
        let methods = names(&r, "access-control-allow-methods");
        assert_eq!(methods, ["get", "head"], "{path}");
        assert_eq!(names(&r, "access-control-allow-headers"), ["if-none-match"], "{path}");
        assert_eq!(header(&r, "access-control-max-age").as_deref(), Some("86400"), "{path}");
        assert_eq!(r.bytes().unwrap().len(), 0);
    }
    // Preflights are requests like any other in the metrics.
    let counted = common::metric(
        &s,
        "cloudscape_http_requests_total",
        &[("method", "OPTIONS"), ("status", "204")],
    );
    assert!(counted >= 5.0, "{counted}");
}

#[test]
fn listed_origins_only_and_none_at_all() {
    let (_config, s) = serve(&[(
        "CLOUDSCAPE_SERVER_CORS_ORIGINS",
        "https://a.example, http://localhost:5173",
    )]);
    let url = format!("{}/v1/worlds", s.base);
    for origin in ["https://a.example", "http://localhost:5173"] {
        let r = get(&url, &[("origin", origin)]);
        assert_eq!(header(&r, "access-control-allow-origin").as_deref(), Some(origin));
        assert!(names(&r, "vary").contains(&"origin".to_string()), "{:?}", r.headers());
        let p = preflight(&s.base, "/v1/worlds", origin);
        assert_eq!(p.status(), StatusCode::NO_CONTENT);
        assert_eq!(header(&p, "access-control-allow-origin").as_deref(), Some(origin));
    }
    let other = get(&url, &[("origin", "https://evil.example")]);
    assert_eq!(other.status(), StatusCode::OK);
    assert_eq!(header(&other, "access-control-allow-origin"), None);
    let p = preflight(&s.base, "/v1/worlds", "https://evil.example");
    assert_eq!(header(&p, "access-control-allow-origin"), None);
    drop(s);

    let (_config, s) = serve(&[("CLOUDSCAPE_SERVER_CORS_ORIGINS", "[]")]);
    let r = get(&format!("{}/v1/worlds", s.base), &[("origin", ORIGIN)]);
    assert_eq!(header(&r, "access-control-allow-origin"), None);
    let p = preflight(&s.base, "/v1/worlds", ORIGIN);
    assert_eq!(p.status(), StatusCode::METHOD_NOT_ALLOWED);
}

#[test]
fn a_malformed_origin_or_public_url_is_refused_by_name() {
    for (var, value, key) in [
        (
            "CLOUDSCAPE_SERVER_CORS_ORIGINS",
            "https://a.example/",
            "server.cors_origins",
        ),
        ("CLOUDSCAPE_SERVER_CORS_ORIGINS", "a.example", "server.cors_origins"),
        ("CLOUDSCAPE_SERVER_PUBLIC_URL", "clouds.example", "server.public_url"),
        (
            "CLOUDSCAPE_SERVER_PUBLIC_URL",
            "https://clouds.example/?x=1",
            "server.public_url",
        ),
    ] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_cloudscape"))
            .args(["serve", "--listen", "127.0.0.1:0"])
            .env(var, value)
            .output()
            .unwrap();
        assert!(!out.status.success(), "{var}={value}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.starts_with("error: ") && err.contains(key), "{var}={value}: {err}");
    }
}

/// The TileJSON of `query` on `s`, with extra request headers.
fn tilejson(s: &ServeProcess, query: &str, headers: &[(&str, &str)]) -> serde_json::Value {
    let r = get(&format!("{}/v1/worlds/default/tilejson.json?{query}", s.base), headers);
    assert_eq!(r.status(), StatusCode::OK, "{query}");
    assert_eq!(header(&r, "content-type").as_deref(), Some("application/json"));
    serde_json::from_slice(&r.bytes().unwrap()).unwrap()
}

#[test]
fn tilejson_names_absolute_zoom_urls_that_serve_the_level_tiles() {
    let (_config, s) = serve(&[]);
    let doc = tilejson(&s, "layer=low&product=coverage.png", &[]);
    assert_eq!(doc["tilejson"], "3.0.0");
    assert_eq!(doc["scheme"], "tms");
    assert_eq!(doc["minzoom"], 0);
    let max = doc["maxzoom"].as_u64().unwrap();
    assert_eq!(max, 20, "tests/data/small.toml's limits.max_level");
    assert_eq!(doc["bounds"].as_array().unwrap().len(), 4);
    assert_eq!(doc["vector_layers"], serde_json::json!([]));
    assert_eq!(doc["cloudscape"]["level_of_zoom"], "level = 20 - zoom");
    // Asked without t, the template names no time (the world clock's keyframe, below);
    // the keyframe-addressed one has a {t}.
    let template = doc["tiles"][0].as_str().unwrap();
    let zoom_route = format!("{}/v1/worlds/default/zoom/{{z}}/{{x}}/{{y}}/coverage.png", s.base);
    assert_eq!(template, format!("{zoom_route}?layer=low"));
    assert_eq!(doc["cloudscape"]["t"], serde_json::Value::Null);
    let template = doc["cloudscape"]["keyframe_tiles"].as_str().unwrap();
    assert_eq!(template, format!("{zoom_route}?t={{t}}&layer=low"));
    // maxzoom is our finest level 0, one zoom out is level 1: same bytes and ETag.
    for (zoom, level) in [(max, 0), (max - 1, 1)] {
        let url = template
            .replace("{z}", &zoom.to_string())
            .replace("{x}", "0")
            .replace("{y}", "0")
            .replace("{t}", "0");
        let by_zoom = get(&url, &[]);
        assert_eq!(by_zoom.status(), StatusCode::OK, "{url}");
        let by_level = get(&format!("{}{}", s.base, tile_path(level)), &[]);
        assert_eq!(header(&by_zoom, "etag"), header(&by_level, "etag"));
        assert_eq!(header(&by_zoom, "x-cloudscape-t"), header(&by_level, "x-cloudscape-t"));
        assert_eq!(by_zoom.bytes().unwrap(), by_level.bytes().unwrap());
    }
    // Levels 0 and 1 are different tiles.
    let l0 = get(&format!("{}{}", s.base, tile_path(0)), &[]);
    let l1 = get(&format!("{}{}", s.base, tile_path(1)), &[]);
    assert_ne!(header(&l0, "etag"), header(&l1, "etag"));

    // t, quality and sun given are baked into the URLs; the default product is coverage.png.
    let doc = tilejson(&s, "t=120&quality=fast&sun=90,30", &[]);
    let template = doc["tiles"][0].as_str().unwrap();
    assert!(
        template.ends_with("/coverage.png?t=120&layer=low&quality=fast&sun=90,30"),
        "{template}"
    );
    assert_eq!(doc["cloudscape"]["t"], 120.0);
    let level_template = doc["cloudscape"]["level_tiles"].as_str().unwrap();
    assert!(level_template.starts_with(&format!("{}/v1/worlds/default/tiles/{{z}}/", s.base)));

    // Discovery points to it.
    let world = get(&format!("{}/v1/worlds/default", s.base), &[]).bytes().unwrap();
    let world: serde_json::Value = serde_json::from_slice(&world).unwrap();
    assert_eq!(
        world["tilejson"],
        "/v1/worlds/default/tilejson.json?layer={layer}&product={product}"
    );
}

#[test]
fn tilejson_urls_come_from_the_public_url_or_the_host() {
    let (_config, s) = serve(&[]);
    let doc = tilejson(
        &s,
        "product=billboards.bin",
        &[("host", "clouds.example:8443"), ("x-forwarded-proto", "https")],
    );
    let template = doc["tiles"][0].as_str().unwrap();
    assert!(
        template.starts_with("https://clouds.example:8443/v1/worlds/default/zoom/{z}/{x}/{y}/billboards.bin?"),
        "{template}"
    );
    let doc = tilejson(&s, "product=billboards.bin", &[("host", "clouds.example")]);
    assert!(
        doc["tiles"][0]
            .as_str()
            .unwrap()
            .starts_with("http://clouds.example/v1/")
    );
    drop(s);

    let (_config, s) = serve(&[("CLOUDSCAPE_SERVER_PUBLIC_URL", "https://cdn.example/clouds/")]);
    let doc = tilejson(&s, "layer=high", &[("host", "ignored.example")]);
    let template = doc["tiles"][0].as_str().unwrap();
    assert!(
        template.starts_with("https://cdn.example/clouds/v1/worlds/default/zoom/{z}/{x}/{y}/coverage.png?layer=high"),
        "{template}"
    );
}

/// One raw HTTP/1.1 request; the status code of the answer.
fn raw_status(port: u16, request: &str) -> u16 {
    let mut stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    stream.write_all(request.as_bytes()).unwrap();
    let mut head = [0u8; 12];
    stream.read_exact(&mut head).unwrap();
    std::str::from_utf8(&head[9..12]).unwrap().parse().unwrap()
}

#[test]
fn bad_tilejson_and_zoom_requests_are_clear_4xx() {
    let (_config, s) = serve(&[]);
    let base = format!("{}/v1/worlds/default", s.base);
    for (url, status, code) in [
        (format!("{base}/tilejson.json?product=nope.png"), 404, "unknown_product"),
        (format!("{base}/tilejson.json?layer=nope"), 404, "unknown_layer"),
        (format!("{base}/tilejson.json?t=-1"), 422, ""),
        (format!("{base}/tilejson.json?t=abc"), 400, ""),
        (format!("{base}/tilejson.json?quality=ultra"), 400, ""),
        (
            format!("{}/v1/worlds/nowhere/tilejson.json", s.base),
            404,
            "unknown_world",
        ),
        (format!("{base}/zoom/21/0/0/coverage.png?t=0"), 422, ""),
        (format!("{base}/zoom/-1/0/0/coverage.png?t=0"), 422, ""),
        (format!("{base}/zoom/x/0/0/coverage.png?t=0"), 400, ""),
        (format!("{base}/zoom/20/0/0/nope.png?t=0"), 404, "unknown_product"),
        (format!("{base}/zoom/20/0/0/coverage.png?t="), 400, "invalid_number"),
    ] {
        let r = get(&url, &[]);
        assert_eq!(r.status().as_u16(), status, "{url}");
        let body: serde_json::Value = serde_json::from_slice(&r.bytes().unwrap()).unwrap();
        assert!(body["message"].as_str().is_some_and(|m| !m.is_empty()), "{url}: {body}");
        if !code.is_empty() {
            assert_eq!(body["error"], code, "{url}");
        }
    }
    let bad_host = "GET /v1/worlds/default/tilejson.json HTTP/1.1\r\nhost: a/b@c\r\nconnection: close\r\n\r\n";
    assert_eq!(raw_status(s.port, bad_host), 400);
}

/// The world clock's time now on a clock of `rate` world seconds per real second.
fn world_now(rate: f64) -> f64 {
    let unix = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    rate * unix
}

#[test]
fn a_template_filled_with_only_zxy_serves_the_world_clocks_keyframe() {
    // A slow clock (a world second is 100 real seconds): max-age counts real seconds.
    let rate = 0.01;
    let (_config, s) = serve_config(&[("worlds.default.clock", "{ offset = 0.0, rate = 0.01 }")], &[]);
    let doc = tilejson(&s, "layer=low&product=density.u8", &[]);
    // zoom 20 - 4 is level 4: keyframes every 10 s * 2^4.
    let span = 160.0;
    let url = doc["tiles"][0]
        .as_str()
        .unwrap()
        .replace("{z}", "16")
        .replace("{x}", "0")
        .replace("{y}", "-1");
    let before = world_now(rate);
    let r = get(&url, &[]);
    let after = world_now(rate);
    assert_eq!(r.status(), StatusCode::OK, "{url}");
    let t0: f64 = header(&r, "x-cloudscape-t").unwrap().parse().unwrap();
    let t1: f64 = header(&r, "x-cloudscape-t1").unwrap().parse().unwrap();
    assert!(
        [before, after].iter().any(|now| (now / span).floor() * span == t0),
        "keyframe {t0} for a clock between {before} and {after}"
    );
    assert_eq!(t1, t0 + span);
    // Kept until the clock reaches the next keyframe, in real seconds; never immutable.
    let cache_control = header(&r, "cache-control").unwrap();
    let max_age: f64 = cache_control
        .strip_prefix("public, max-age=")
        .unwrap_or_else(|| panic!("{cache_control}"))
        .parse()
        .unwrap();
    let (least, most) = (((t1 - after) / rate).ceil(), ((t1 - before) / rate).ceil());
    assert!(
        (least.max(1.0)..=most).contains(&max_age),
        "max-age {max_age} is not the {least}..{most} real seconds to the next keyframe"
    );
    // The same bytes as the keyframe asked by its time, which Content-Location names.
    let location = header(&r, "content-location").unwrap();
    assert_eq!(
        location,
        format!("/v1/worlds/default/zoom/16/0/-1/density.u8?layer=low&t={t0}")
    );
    let etag = header(&r, "etag");
    let body = r.bytes().unwrap();
    let keyframe = get(&format!("{}{location}", s.base), &[]);
    assert_eq!(header(&keyframe, "etag"), etag);
    assert!(header(&keyframe, "cache-control").unwrap().contains("immutable"));
    assert_eq!(keyframe.bytes().unwrap(), body);
    // An animating client names each keyframe through the {t} template.
    let next = doc["cloudscape"]["keyframe_tiles"]
        .as_str()
        .unwrap()
        .replace("{z}", "16")
        .replace("{x}", "0")
        .replace("{y}", "-1")
        .replace("{t}", &t1.to_string());
    let next = get(&next, &[]);
    assert_eq!(header(&next, "x-cloudscape-t"), Some(t1.to_string()));
    assert_ne!(header(&next, "etag"), etag);
}
