//! Keyframes over a real socket: compute-ahead (the next keyframe of a watched tile is
//! computed before the clock reaches it, and a request just after the boundary is
//! answered from it; requests keep priority over it) and encode-once (a compressed
//! variant is made once and served from the cache after).

mod common;

use std::io::Read;
use std::time::{Duration, Instant};

use common::{ServeProcess, client, eventually, metric, test_config};

fn start(overrides: &[(&str, &str)]) -> (ServeProcess, tempfile::NamedTempFile) {
    let file = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(file.path(), test_config(overrides)).unwrap();
    let server = ServeProcess::start(&["--config", file.path().to_str().unwrap()], &[]);
    (server, file)
}

/// Waits up to `limit` for `metric >= at_least`; the metric's last value.
fn wait_for(server: &ServeProcess, name: &str, at_least: f64, limit: Duration) -> f64 {
    let mut v = 0.0;
    eventually(limit, || {
        v = metric(server, name, &[]);
        v >= at_least
    });
    v
}

#[test]
fn a_request_after_the_boundary_is_served_from_what_was_computed_ahead() {
    let (server, _config) = start(&[]);
    let http = client();
    // Level 0 of the `low` layer: keyframes 10 s apart. A player at t = 105 watches
    // keyframe [100, 110).
    let url = |t: &str| {
        format!(
            "{}/v1/worlds/default/tiles/0/1/1/billboards.bin?t={t}&quality=fast&sun=120,40",
            server.base
        )
    };
    let r = http.get(url("105")).send().unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["x-cloudscape-t"], "100");
    // Watched: asked for again (a tile asked for once gets nothing computed ahead).
    assert_eq!(http.get(url("106")).send().unwrap().status(), 200);
    // The next keyframe is computed ahead, without any request for it.
    assert_eq!(
        wait_for(&server, "cloudscape_ahead_computed_total", 1.0, Duration::from_secs(60)),
        1.0
    );
    // Requests' computations are counted apart from those ahead.
    let computed = metric(&server, "cloudscape_computations_total", &[("kind", "tile_shaded")]);
    assert_eq!(computed, 1.0, "the request's own keyframe");
    // The boundary passes: the request for [110, 120) finds it, computes nothing.
    let r = http.get(url("110.2")).send().unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["x-cloudscape-t"], "110");
    let next = r.bytes().unwrap();
    assert_eq!(metric(&server, "cloudscape_ahead_served_total", &[]), 1.0);
    assert_eq!(metric(&server, "cloudscape_ahead_missed_total", &[]), 0.0);
    // Nothing computed for the request: the one computation since is the next
    // keyframe ahead ([120, 130)), planned by this request.
    let ahead = wait_for(&server, "cloudscape_ahead_computed_total", 2.0, Duration::from_secs(60));
    assert_eq!(ahead, 2.0);
    assert_eq!(
        metric(&server, "cloudscape_computations_total", &[("kind", "tile_shaded")]),
        computed,
        "nothing computed for the request"
    );
    // What was computed ahead is what a request computes (a server without
    // compute-ahead).
    let (plain, _c) = start(&[("server.ahead_threads", "0")]);
    let direct = client()
        .get(format!(
            "{}/v1/worlds/default/tiles/0/1/1/billboards.bin?t=110&quality=fast&sun=120,40",
            plain.base
        ))
        .send()
        .unwrap()
        .bytes()
        .unwrap();
    assert_eq!(next, direct);
    assert_eq!(metric(&plain, "cloudscape_ahead_computed_total", &[]), 0.0);
    // The delta form of the same keyframe came with the billboards: served from ahead too.
    let delta = http
        .get(url("110").replace("billboards.bin", "billboards.delta.bin"))
        .send()
        .unwrap();
    assert_eq!(delta.status(), 200);
    assert_eq!(metric(&server, "cloudscape_ahead_served_total", &[]), 2.0);
}

#[test]
fn compute_ahead_never_delays_a_request_past_its_budget() {
    // A short budget, a queue no larger than the threads, and many watched tiles whose
    // next keyframes are all due: requests for other tiles must still be answered
    // within their budget while compute-ahead works through its list.
    let budget_ms = 4000;
    let (server, _config) = start(&[
        ("server.request_timeout_ms", &budget_ms.to_string()),
        ("server.compute_queue", "64"),
    ]);
    let http = client();
    let tile = |x: i64, t: u32| {
        format!(
            "{}/v1/worlds/default/tiles/0/{x}/5/billboards.bin?t={t}&quality=balanced&sun=200,30",
            server.base
        )
    };
    // Watch 12 tiles (each asked for twice): 12 keyframes planned ahead.
    for x in 0..12 {
        for t in [3, 4] {
            assert_eq!(http.get(tile(x, t)).send().unwrap().status(), 200);
        }
    }
    // While compute-ahead still has some of those 12 to compute, 12 requests for
    // tiles nobody watched, 3 at a time. Requests keep priority, so compute-ahead
    // may get no turn until they are done.
    let computed_before = metric(&server, "cloudscape_ahead_computed_total", &[]);
    assert!(computed_before < 12.0, "all 12 were computed ahead before the requests");
    let started = Instant::now();
    let mut worst = Duration::ZERO;
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..3)
            .map(|lane| {
                let http = &http;
                let tile = &tile;
                s.spawn(move || {
                    let mut worst = Duration::ZERO;
                    for i in 0..4 {
                        let t0 = Instant::now();
                        let r = http.get(tile(100 + lane * 4 + i, 3)).send().unwrap();
                        assert_eq!(r.status(), 200, "{}", r.text().unwrap_or_default());
                        worst = worst.max(t0.elapsed());
                    }
                    worst
                })
            })
            .collect();
        for h in handles {
            worst = worst.max(h.join().unwrap());
        }
    });
    assert!(
        worst < Duration::from_millis(budget_ms),
        "a request took {worst:?}, over its {budget_ms} ms budget ({:?} in all)",
        started.elapsed()
    );
    assert_eq!(metric(&server, "cloudscape_timeouts_total", &[]), 0.0);
    assert_eq!(metric(&server, "cloudscape_shed_total", &[]), 0.0);
    // What waited gets its turn once the requests are done: the 12 watched tiles'
    // next keyframes (the 12 requests, one each, planned none).
    let done = wait_for(
        &server,
        "cloudscape_ahead_computed_total",
        12.0,
        Duration::from_secs(60),
    );
    assert!(
        done >= 12.0,
        "{done} computed ahead, {computed_before} before the requests"
    );
}

/// A crawler buys no compute: tiles asked for once (5,000 of them cost the server 1.7
/// cores for a minute before) get no keyframe computed ahead, while a tile asked for
/// twice still does.
#[test]
fn a_crawl_of_one_off_tiles_computes_nothing_ahead() {
    let (server, _config) = start(&[]);
    let http = client();
    let tile = |x: i64, y: i64, t: f64| {
        format!(
            "{}/v1/worlds/default/tiles/0/{x}/{y}/billboards.bin?t={t}&quality=fast&sun=120,40",
            server.base
        )
    };
    // The crawl: 24 tiles, once each, at times in the middle of their spans.
    for i in 0..24 {
        let r = http
            .get(tile(i % 6, 20 + i / 6, 205.0 + f64::from(i as u8 % 4)))
            .send()
            .unwrap();
        assert_eq!(r.status(), 200);
    }
    // Followed (the hot set knows them), but nothing planned for them.
    assert!(eventually(Duration::from_secs(10), || metric(
        &server,
        "cloudscape_ahead_hot_tiles",
        &[]
    ) == 24.0));
    assert_eq!(metric(&server, "cloudscape_ahead_pending", &[]), 0.0);
    // A player's tile, asked for at two keyframes, after the crawl: its next keyframe
    // is planned after theirs would have been, with a later deadline, so once it is
    // computed ahead any keyframe planned for the crawl would have been too.
    for t in [203.0, 211.0] {
        assert_eq!(http.get(tile(40, 40, t)).send().unwrap().status(), 200);
    }
    assert_eq!(
        wait_for(&server, "cloudscape_ahead_computed_total", 1.0, Duration::from_secs(60)),
        1.0
    );
    assert!(eventually(Duration::from_secs(10), || metric(
        &server,
        "cloudscape_ahead_pending",
        &[]
    ) == 0.0));
    assert_eq!(metric(&server, "cloudscape_ahead_computed_total", &[]), 1.0);
}

#[test]
fn a_compressed_variant_is_made_once_and_served_from_the_cache() {
    let (server, _config) = start(&[("server.ahead_threads", "0")]);
    let http = reqwest::blocking::Client::builder()
        .no_proxy()
        .no_gzip()
        .build()
        .unwrap();
    let url = format!(
        "{}/v1/worlds/default/tiles/0/0/0/billboards.json?t=50&quality=fast&sun=100,40",
        server.base
    );
    let identity = http.get(&url).send().unwrap();
    assert_eq!(identity.headers()["vary"], "accept-encoding");
    let etag = identity.headers()["etag"].to_str().unwrap().to_string();
    let identity = identity.bytes().unwrap();
    let mut bodies = Vec::new();
    for _ in 0..3 {
        let r = http.get(&url).header("accept-encoding", "gzip").send().unwrap();
        assert_eq!(r.status(), 200);
        assert_eq!(r.headers()["content-encoding"], "gzip");
        assert_eq!(r.headers()["vary"], "accept-encoding");
        assert_eq!(
            r.headers()["etag"].to_str().unwrap(),
            format!("\"{}-gzip\"", etag.trim_matches('"'))
        );
        bodies.push(r.bytes().unwrap());
    }
    assert!(bodies.iter().all(|b| *b == bodies[0]), "the same compressed bytes");
    let mut plain = Vec::new();
    flate2::read::GzDecoder::new(&bodies[0][..])
        .read_to_end(&mut plain)
        .unwrap();
    assert_eq!(plain, identity);
    assert!(bodies[0].len() < identity.len() / 2);
    let enc = |outcome| {
        metric(
            &server,
            "cloudscape_encodings_total",
            &[("coding", "gzip"), ("outcome", outcome)],
        )
    };
    assert_eq!(
        (enc("miss"), enc("hit")),
        (1.0, 2.0),
        "compressed once, then from the cache"
    );
    // zstd is preferred when accepted; a 304 still says what varies.
    let z = http.get(&url).header("accept-encoding", "gzip, zstd").send().unwrap();
    assert_eq!(z.headers()["content-encoding"], "zstd");
    let z = z.bytes().unwrap();
    assert_eq!(zstd::bulk::decompress(&z, identity.len()).unwrap(), identity);
    let not_modified = http
        .get(&url)
        .header("accept-encoding", "gzip")
        .header("if-none-match", &etag)
        .send()
        .unwrap();
    assert_eq!(not_modified.status(), 304);
    assert_eq!(not_modified.headers()["vary"], "accept-encoding");
}
