//! The optional Redis second-level cache, against a real `redis-server` (Debian
//! package `redis-server`; CI installs it) started on a free loopback port: replicas
//! share products through it, and a Redis that dies, stops answering or never answered
//! costs requests no more than its deadline (they compute instead).

mod common;

use std::io::Read;
use std::net::TcpListener;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{ServeProcess, client, free_port, metric};

const SMALL_CONFIG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/small.toml");

/// A `redis-server` child process with no persistence; killed when dropped.
struct RedisServer {
    child: Child,
    port: u16,
}

impl RedisServer {
    fn start() -> RedisServer {
        Self::start_on(free_port())
    }

    fn start_on(port: u16) -> RedisServer {
        let child = Command::new("redis-server")
            .args(["--port", &port.to_string(), "--bind", "127.0.0.1"])
            .args([
                "--save",
                "",
                "--appendonly",
                "no",
                "--daemonize",
                "no",
                "--loglevel",
                "warning",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| {
                panic!("cannot run redis-server ({e}): these tests need it (Debian: apt-get install redis-server)")
            });
        let redis = RedisServer { child, port };
        let start = Instant::now();
        while redis.connection().is_err() {
            assert!(start.elapsed() < Duration::from_secs(10), "redis-server did not start");
            std::thread::sleep(Duration::from_millis(20));
        }
        redis
    }

    fn url(&self) -> String {
        format!("redis://127.0.0.1:{}/0", self.port)
    }

    fn connection(&self) -> redis::RedisResult<redis::Connection> {
        let client = redis::Client::open(self.url())?;
        let mut c = client.get_connection_with_timeout(Duration::from_secs(1))?;
        redis::cmd("PING").query::<String>(&mut c)?;
        Ok(c)
    }

    fn keys(&self) -> Vec<String> {
        let mut c = self.connection().expect("redis answers");
        redis::cmd("KEYS").arg("*").query(&mut c).unwrap()
    }

    /// Waits (up to 10 s) until Redis holds at least `n` keys.
    fn wait_for_keys(&self, n: usize) -> Vec<String> {
        let start = Instant::now();
        loop {
            let keys = self.keys();
            if keys.len() >= n {
                return keys;
            }
            assert!(
                start.elapsed() < Duration::from_secs(10),
                "Redis holds {keys:?}, wanted {n} keys"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Waits (up to 10 s) for a key that `wanted` accepts: values are written in the
    /// background, each in its own time, so a count of keys does not say which are in.
    fn wait_for_key(&self, what: &str, wanted: impl Fn(&str) -> bool) -> String {
        let start = Instant::now();
        loop {
            let keys = self.keys();
            if let Some(k) = keys.iter().find(|k| wanted(k)) {
                return k.clone();
            }
            assert!(
                start.elapsed() < Duration::from_secs(10),
                "Redis holds {keys:?}, no key of {what}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn signal(&self, signal: &str) {
        let ok = Command::new("kill")
            .args([signal, &self.child.id().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok, "kill {signal}");
    }
}

impl Drop for RedisServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// GET `path`: (status, ETag, body, seconds taken).
fn get(server: &ServeProcess, path: &str) -> (u16, String, Vec<u8>, f64) {
    let started = Instant::now();
    let r = client().get(format!("{}{path}", server.base)).send().unwrap();
    let status = r.status().as_u16();
    let etag = r
        .headers()
        .get("etag")
        .map(|v| v.to_str().unwrap().to_string())
        .unwrap_or_default();
    let body = r.bytes().unwrap().to_vec();
    (status, etag, body, started.elapsed().as_secs_f64())
}

fn serve_with_redis(url: &str, extra: &[(&str, &str)]) -> ServeProcess {
    let mut env = vec![("CLOUDSCAPE_SERVER_REDIS_URL", url)];
    env.extend_from_slice(extra);
    ServeProcess::start(&["--config", SMALL_CONFIG], &env)
}

#[test]
fn a_second_replica_gets_products_from_redis_with_identical_bytes_and_etags() {
    let redis = RedisServer::start();
    // Redis lookups are counted below: nothing computed ahead of the clock
    // (tests/keyframes.rs) asks Redis meanwhile.
    let a = serve_with_redis(&redis.url(), &[("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0")]);
    let density = "/v1/worlds/default/tiles/0/3/-2/density.npy?t=40";
    let billboards = "/v1/worlds/default/tiles/0/1/1/billboards.json?t=40&sun=120,30";
    // billboards.delta.bin: encoded with the billboards from every shading (`Product::encoding`).
    let atlas = "/v1/worlds/default/tiles/0/1/1/billboards.delta.bin?t=40&sun=120,30";
    let (status, etag_a, body_a, _) = get(&a, density);
    assert_eq!(status, 200);
    assert_eq!(
        metric(&a, "cloudscape_redis_misses_total", &[("kind", "tile_density")]),
        1.0
    );
    assert_eq!(get(&a, billboards).0, 200);
    // Written after the responses, in the background: the density grid, and the shaded
    // tile's products (billboards and its siblings).
    redis.wait_for_key("the density grid", |k| k.contains("|a") && k.contains("|p=density.npy"));
    let keys = redis.wait_for_keys(3);
    assert!(keys.iter().all(|k| k.starts_with("cloudscape:")), "{keys:?}");

    // A fresh replica: empty memory cache, same config, same Redis.
    let b = serve_with_redis(&redis.url(), &[]);
    let (status, etag_b, body_b, _) = get(&b, density);
    assert_eq!(status, 200);
    assert_eq!(etag_a, etag_b, "replicas name the same bytes with the same ETag");
    assert!(body_a == body_b, "bytes from Redis are the bytes computed");
    assert_eq!(
        metric(&b, "cloudscape_redis_hits_total", &[("kind", "tile_density")]),
        1.0
    );
    assert_eq!(
        metric(&b, "cloudscape_computations_total", &[("kind", "tile_density")]),
        0.0
    );
    // A sibling product of the shaded tile that replica A computed but nobody asked A for.
    let (status, _, atlas_b, _) = get(&b, atlas);
    assert_eq!(status, 200);
    assert_eq!(
        metric(&b, "cloudscape_computations_total", &[("kind", "tile_shaded")]),
        0.0
    );
    assert!(atlas_b == get(&a, atlas).2);
    // The second request on B is a memory hit: Redis is not asked again.
    assert_eq!(get(&b, density).0, 200);
    assert_eq!(metric(&b, "cloudscape_redis_hits_total", &[]), 2.0);
    assert_eq!(
        metric(&b, "cloudscape_cache_hits_total", &[("kind", "tile_density")]),
        1.0
    );
}

/// Anything that can write to Redis must not be able to poison the replicas: a tile's
/// key overwritten with garbage (the attack of issue 39: 17 bytes served as a 110 KB
/// PNG with the genuine ETag and `immutable`), or with another tile's genuine value, is
/// a miss on every replica, counted, and the request computes the genuine bytes (and
/// writes them over the planted value).
#[test]
fn garbage_written_under_a_tiles_key_is_never_served() {
    let redis = RedisServer::start();
    let quiet = [("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0")];
    let a = serve_with_redis(&redis.url(), &quiet);
    let shadow = "/v1/worlds/default/tiles/0/1/1/shadow.png?t=40&sun=120,30";
    let other = "/v1/worlds/default/tiles/0/2/1/shadow.png?t=40&sun=120,30";
    let (status, etag, genuine, _) = get(&a, shadow);
    assert_eq!(status, 200);
    assert_eq!(get(&a, other).0, 200);
    let key_of = |tile: &str| redis.wait_for_key(tile, |k| k.contains(tile) && k.contains("|p=shadow.png"));
    let (key, other_key) = (key_of("|x=1|y=1|"), key_of("|x=2|y=1|"));
    let mut c = redis.connection().unwrap();
    let set = |c: &mut redis::Connection, value: &[u8]| {
        redis::cmd("SET").arg(&key).arg(value).query::<()>(c).unwrap();
    };
    for (n, planted) in [
        b"17 bytes of junk!".to_vec(),
        redis::cmd("GET").arg(&other_key).query::<Vec<u8>>(&mut c).unwrap(),
    ]
    .into_iter()
    .enumerate()
    {
        set(&mut c, &planted);
        // A fresh replica: nothing in memory, so it asks Redis.
        let b = serve_with_redis(&redis.url(), &quiet);
        let (status, etag_b, body, _) = get(&b, shadow);
        assert_eq!(status, 200);
        assert_eq!(etag_b, etag);
        assert!(body == genuine, "planted value {n} was served ({} bytes)", body.len());
        assert_eq!(
            metric(&b, "cloudscape_redis_rejected_total", &[("kind", "tile_shaded")]),
            1.0,
            "planted value {n}"
        );
        assert_eq!(metric(&b, "cloudscape_redis_hits_total", &[]), 0.0);
        assert_eq!(
            metric(&b, "cloudscape_computations_total", &[("kind", "tile_shaded")]),
            1.0
        );
        // The genuine bytes are written over the planted value: the next replica hits.
        let start = Instant::now();
        while redis::cmd("GET").arg(&key).query::<Vec<u8>>(&mut c).unwrap() == planted {
            assert!(start.elapsed() < Duration::from_secs(10), "the planted value stayed");
            std::thread::sleep(Duration::from_millis(20));
        }
        let d = serve_with_redis(&redis.url(), &quiet);
        assert!(get(&d, shadow).2 == genuine);
        assert_eq!(
            metric(&d, "cloudscape_redis_hits_total", &[("kind", "tile_shaded")]),
            1.0
        );
    }
}

/// With `server.redis_secret`, values are sealed with a keyed MAC: a replica without the
/// secret (or with another) cannot write a value the fleet serves.
#[test]
fn with_a_secret_only_replicas_holding_it_share_values() {
    let redis = RedisServer::start();
    let fleet = [
        ("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0"),
        ("CLOUDSCAPE_SERVER_REDIS_SECRET", "the fleet's secret, 32 bytes ok"),
    ];
    let density = "/v1/worlds/default/tiles/0/3/-2/density.u8?t=40";
    // An intruder with Redis access but another secret writes first.
    let intruder = serve_with_redis(
        &redis.url(),
        &[
            ("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0"),
            ("CLOUDSCAPE_SERVER_REDIS_SECRET", "not the fleet's secret at all"),
        ],
    );
    assert_eq!(get(&intruder, density).0, 200);
    redis.wait_for_keys(1);
    let a = serve_with_redis(&redis.url(), &fleet);
    assert_eq!(get(&a, density).0, 200);
    assert_eq!(
        metric(&a, "cloudscape_redis_rejected_total", &[("kind", "tile_density")]),
        1.0
    );
    assert_eq!(
        metric(&a, "cloudscape_computations_total", &[("kind", "tile_density")]),
        1.0
    );
    // Once a's value is written, another replica of the fleet takes it.
    std::thread::sleep(Duration::from_millis(500));
    let b = serve_with_redis(&redis.url(), &fleet);
    assert_eq!(get(&b, density).0, 200);
    assert_eq!(
        metric(&b, "cloudscape_redis_hits_total", &[("kind", "tile_density")]),
        1.0
    );
    let out = common::print_config(&[], &[("CLOUDSCAPE_SERVER_REDIS_SECRET", "short")]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("server.redis_secret"));
}

/// Settings that make failures show quickly: a 150 ms Redis deadline, 300 ms back-off,
/// and a request budget far below the test client's, so a stalled request would be a 503.
const FAST_FAILURE: [(&str, &str); 3] = [
    ("CLOUDSCAPE_SERVER_REDIS_TIMEOUT_MS", "150"),
    ("CLOUDSCAPE_SERVER_REDIS_RETRY_MS", "300"),
    ("CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS", "5000"),
];

/// Requests `n` tiles nobody asked for yet (so each one consults Redis, then computes)
/// and checks every one is answered in time.
fn cold_tiles_succeed(server: &ServeProcess, row: i64, n: i64) {
    for x in 0..n {
        let (status, _, body, seconds) = get(server, &format!("/v1/worlds/default/tiles/0/{x}/{row}/density.u8?t=30"));
        assert_eq!(status, 200, "tile ({x}, {row}) while Redis misbehaves");
        assert_eq!(body.len(), 2 * 256 * 256);
        assert!(seconds < 5.0, "tile ({x}, {row}) took {seconds:.2} s");
    }
}

#[test]
fn a_stopped_then_killed_redis_never_fails_a_request_and_is_used_again_once_back() {
    let redis = RedisServer::start();
    let port = redis.port;
    let server = serve_with_redis(&redis.url(), &FAST_FAILURE);
    cold_tiles_succeed(&server, 0, 2);
    redis.wait_for_keys(2);

    // Connected, then silent: every call meets its deadline.
    redis.signal("-STOP");
    cold_tiles_succeed(&server, 1, 6);
    let errors = metric(&server, "cloudscape_redis_errors_total", &[]);
    assert!(errors >= 1.0, "a silent Redis counts as an error");
    // Killed while stopped: connections are refused or reset.
    redis.signal("-KILL");
    drop(redis);
    cold_tiles_succeed(&server, 2, 6);
    assert_eq!(metric(&server, "cloudscape_timeouts_total", &[]), 0.0);

    // Back on the same port: within a few back-off periods, products are written again.
    let redis = RedisServer::start_on(port);
    let start = Instant::now();
    let mut x = 0;
    while redis.keys().is_empty() {
        assert!(
            start.elapsed() < Duration::from_secs(15),
            "the server never reconnected to Redis"
        );
        cold_tiles_succeed_one(&server, 3, x);
        x += 1;
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn cold_tiles_succeed_one(server: &ServeProcess, row: i64, x: i64) {
    let (status, ..) = get(server, &format!("/v1/worlds/default/tiles/0/{x}/{row}/density.u8?t=30"));
    assert_eq!(status, 200);
}

#[test]
fn a_redis_that_accepts_connections_but_never_answers_does_not_stall_requests() {
    // A listener that reads whatever is sent and never writes a byte.
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("redis://{}/0", listener.local_addr().unwrap());
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            std::thread::spawn(move || {
                let mut stream = stream;
                let mut buf = [0u8; 4096];
                while matches!(stream.read(&mut buf), Ok(n) if n > 0) {}
            });
        }
    });
    let server = serve_with_redis(&url, &FAST_FAILURE);
    cold_tiles_succeed(&server, 0, 8);
    assert!(metric(&server, "cloudscape_redis_errors_total", &[("op", "get")]) >= 1.0);
    assert!(
        metric(&server, "cloudscape_redis_skipped_total", &[]) >= 1.0,
        "after a failure, lookups skip Redis for a while instead of waiting again"
    );
    assert_eq!(metric(&server, "cloudscape_redis_hits_total", &[]), 0.0);
}

#[test]
fn an_invalid_redis_url_is_refused_at_start() {
    let out = common::print_config(&[], &[("CLOUDSCAPE_SERVER_REDIS_URL", "http://cache:6379")]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("redis_url"));
}

/// Two replicas keeping the same play area warm through one Redis compute each
/// keyframe once: a background computation claims its key in Redis first
/// (`SET NX`), the replica that lost takes the bytes from Redis, and both become
/// ready and stay warm. Without the claim, both computed every keyframe.
#[test]
fn replicas_keeping_the_same_area_warm_compute_each_keyframe_once() {
    let redis = RedisServer::start();
    let url = redis.url();
    // The low layer's level-0 span is 10 s; at 5 world seconds a second a keyframe
    // passes every 2 s. Six tiles, one computation each per keyframe.
    let text = common::test_config(&[
        ("worlds.default.clock", "{ rate = 5.0 }"),
        (
            "worlds.default.warm",
            "[{ name = \"town\", bbox = [100.0, 100.0, 60000.0, 40000.0], levels = [0], layers = [\"low\"] }]",
        ),
    ]);
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("warm.toml");
    std::fs::write(&config, text).unwrap();
    let config = config.to_str().unwrap().to_string();
    let start = |config: String, url: String| {
        std::thread::spawn(move || {
            ServeProcess::start(
                &["--config", &config],
                &[
                    ("CLOUDSCAPE_SERVER_REDIS_URL", url.as_str()),
                    ("CLOUDSCAPE_SERVER_WARM_THREADS", "1"),
                    // What is measured is the claim, not a slow Redis: on a loaded test
                    // machine a call past the default 100 ms counts as a failure, and
                    // a replica then computes without claiming (the safe side).
                    ("CLOUDSCAPE_SERVER_REDIS_TIMEOUT_MS", "5000"),
                ],
            )
        })
    };
    // Both at once, so that they meet on the first keyframes as well as on the next.
    let (a, b) = (start(config.clone(), url.clone()), start(config, url));
    let (a, b) = (a.join().unwrap(), b.join().unwrap());
    std::thread::sleep(Duration::from_secs(8));
    let mut c = redis.connection().unwrap();
    let computed = |s: &ServeProcess| metric(s, "cloudscape_warm_computed_total", &[]);
    let lost = |s: &ServeProcess| metric(s, "cloudscape_redis_claims_total", &[("outcome", "lost")]);
    let won = |s: &ServeProcess| metric(s, "cloudscape_redis_claims_total", &[("outcome", "won")]);
    // The replicas go on working (a keyframe every 2 s), so the counters and Redis are
    // read between keyframes: a snapshot counts when the counters are the same before
    // and after the claims are listed (no computation started or ended meanwhile).
    let mut last = None;
    let quiet = common::eventually(Duration::from_secs(20), || {
        let before = (computed(&a) + computed(&b), won(&a) + won(&b));
        let claims: Vec<String> = redis::cmd("KEYS").arg("*claim:*").query(&mut c).unwrap();
        let after = (computed(&a) + computed(&b), won(&a) + won(&b));
        let done = before == after && after.0 == after.1;
        last = Some((after, claims));
        done
    });
    let ((total, won_total), claims) = last.unwrap();
    let errors = metric(&a, "cloudscape_redis_errors_total", &[]) + metric(&b, "cloudscape_redis_errors_total", &[]);
    assert!(
        quiet,
        "no quiet moment: computed {total}, won {won_total}, claimed keys {}, Redis errors {errors}",
        claims.len()
    );
    // Each keyframe was claimed once and computed by the replica that won it.
    assert!(claims.len() >= 12, "{} claims: {claims:?}", claims.len());
    assert_eq!(
        total,
        claims.len() as f64,
        "computed {total}, claimed keys {}",
        claims.len()
    );
    assert_eq!(won_total, claims.len() as f64);
    assert!(lost(&a) + lost(&b) > 0.0, "the replicas never met on a keyframe");
    // Both hold every keyframe of the area: nothing pending on either.
    for s in [&a, &b] {
        assert!(
            common::eventually(Duration::from_secs(10), || metric(s, "cloudscape_warm_pending", &[])
                == 0.0),
            "a replica kept keyframes pending"
        );
    }
}
