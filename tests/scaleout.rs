//! Scale-out on one machine: three `cloudscape serve` replicas behind Debian's nginx,
//! run with docker/nginx.conf (the file docker/compose.yaml uses) with loopback ports
//! and temporary paths substituted. Shows that replicas agree byte for byte, that
//! nginx serves repeats from its cache and coalesces concurrent misses, that a
//! replica killed under load costs no request, that a request which kills its
//! upstream connection takes no replica out for anyone else, and that no request can
//! poison what nginx caches for the next client.

mod common;

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use common::{ServeProcess, client, free_port, metric, wait_until_ok};

const SMALL_CONFIG: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/small.toml");
const NGINX_CONF: &str = include_str!("../docker/nginx.conf");

/// Replaces `from` (which must be there: the test runs the real file, not a copy).
fn substitute(conf: &mut String, from: &str, to: &str) {
    assert!(conf.contains(from), "docker/nginx.conf no longer contains `{from}`");
    *conf = conf.replace(from, to);
}

/// docker/nginx.conf for loopback: listen on `port`, proxy to `replicas`, keep pid,
/// logs and cache in `dir`.
fn local_nginx_conf(dir: &Path, port: u16, replicas: &[u16; 3]) -> String {
    let d = dir.display();
    let mut conf = NGINX_CONF.to_string();
    substitute(&mut conf, "pid /tmp/nginx.pid;", &format!("pid {d}/nginx.pid;"));
    substitute(&mut conf, "error_log /dev/stderr", &format!("error_log {d}/error.log"));
    substitute(
        &mut conf,
        "access_log /dev/stdout",
        &format!("access_log {d}/access.log"),
    );
    substitute(&mut conf, "/var/cache/nginx/cloudscape", &format!("{d}/cache"));
    substitute(&mut conf, "listen 8080;", &format!("listen 127.0.0.1:{port};"));
    for (i, p) in replicas.iter().enumerate() {
        substitute(
            &mut conf,
            &format!("server cloudscape-{}:8080", i + 1),
            &format!("server 127.0.0.1:{p}"),
        );
    }
    conf
}

/// nginx in the foreground with its own prefix, config and logs; stopped when dropped.
struct Nginx {
    child: Child,
    base: String,
    dir: tempfile::TempDir,
}

impl Nginx {
    fn start(replicas: &[u16; 3]) -> Nginx {
        let dir = tempfile::tempdir().unwrap();
        // Run as root, nginx's workers drop to an unprivileged user that must reach the cache.
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
        }
        let port = free_port();
        let conf = dir.path().join("nginx.conf");
        std::fs::write(&conf, local_nginx_conf(dir.path(), port, replicas)).unwrap();
        let exe = ["/usr/sbin/nginx", "nginx"]
            .into_iter()
            .find(|e| Command::new(e).arg("-v").stderr(Stdio::null()).status().is_ok())
            .expect("nginx is not installed: this test needs it (Debian: apt-get install nginx)");
        let child = Command::new(exe)
            .arg("-p")
            .arg(dir.path())
            .arg("-c")
            .arg(&conf)
            .arg("-e")
            .arg(dir.path().join("error.log"))
            .args(["-g", "daemon off;"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn nginx");
        let mut nginx = Nginx {
            child,
            base: format!("http://127.0.0.1:{port}"),
            dir,
        };
        let healthz = format!("{}/healthz", nginx.base);
        let error_log = nginx.dir.path().join("error.log");
        wait_until_ok(&mut nginx.child, &healthz, Duration::from_secs(20), |_| {
            format!("nginx: {}", std::fs::read_to_string(error_log).unwrap_or_default())
        });
        nginx
    }
}

impl Drop for Nginx {
    fn drop(&mut self) {
        // SIGQUIT: graceful stop of the master and its workers.
        let _ = Command::new("kill")
            .args(["-QUIT", &self.child.id().to_string()])
            .status();
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(5) {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

struct Answer {
    status: u16,
    etag: String,
    cache: String,
    body: Vec<u8>,
}

fn get(base: &str, path: &str, headers: &[(&str, &str)]) -> Answer {
    let mut req = client().get(format!("{base}{path}"));
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    let r = req.send().unwrap();
    let header = |name: &str| {
        r.headers()
            .get(name)
            .map(|v| v.to_str().unwrap().to_string())
            .unwrap_or_default()
    };
    let (status, etag, cache) = (r.status().as_u16(), header("etag"), header("x-cache-status"));
    Answer {
        status,
        etag,
        cache,
        body: r.bytes().unwrap().to_vec(),
    }
}

fn computations(replicas: &[ServeProcess]) -> f64 {
    replicas
        .iter()
        .map(|r| metric(r, "cloudscape_computations_total", &[]))
        .sum()
}

fn start_replicas() -> Vec<ServeProcess> {
    (0..3)
        .map(|_| ServeProcess::start(&["--config", SMALL_CONFIG], &[]))
        .collect()
}

fn ports(replicas: &[ServeProcess]) -> [u16; 3] {
    [replicas[0].port, replicas[1].port, replicas[2].port]
}

#[test]
fn replicas_agree_and_nginx_caches_and_coalesces() {
    let replicas = start_replicas();
    let nginx = Nginx::start(&ports(&replicas));

    // Every replica answers a key with the same bytes under the same ETag.
    for path in [
        "/v1/worlds/default/tiles/0/2/-1/density.npy?t=40",
        "/v1/worlds/default/tiles/0/2/-1/coverage.png?t=40",
        "/v1/worlds/default/tiles/0/2/-1/billboards.bin?t=40&sun=90,20",
        "/v1/worlds/77/region?bbox=0,0,25600,25600&t=40",
    ] {
        let answers: Vec<Answer> = replicas.iter().map(|r| get(&r.base, path, &[])).collect();
        for a in &answers {
            assert_eq!(a.status, 200, "{path}");
            assert!(!a.etag.is_empty(), "{path} has an ETag");
            assert_eq!(a.etag, answers[0].etag, "{path}: ETags differ between replicas");
            assert!(a.body == answers[0].body, "{path}: bytes differ between replicas");
        }
        // Through nginx: the same bytes and ETag, computed once, then from nginx's cache.
        let first = get(&nginx.base, path, &[]);
        assert_eq!((first.status, first.cache.as_str()), (200, "MISS"), "{path}");
        assert!(first.body == answers[0].body && first.etag == answers[0].etag, "{path}");
        let before = computations(&replicas);
        for _ in 0..3 {
            let again = get(&nginx.base, path, &[]);
            assert_eq!((again.status, again.cache.as_str()), (200, "HIT"), "{path}");
            assert!(again.body == answers[0].body && again.etag == answers[0].etag, "{path}");
        }
        assert_eq!(computations(&replicas), before, "{path}: cache hits reach no replica");
        // Revalidation against nginx's copy: 304, no body.
        let revalidated = get(&nginx.base, path, &[("if-none-match", &answers[0].etag)]);
        assert_eq!(revalidated.status, 304, "{path}");
    }

    // The image's HEALTHCHECK: `cloudscape probe` succeeds on a live replica, and fails
    // with one sentence where nothing listens.
    let probe = |url: &str| {
        Command::new(env!("CARGO_BIN_EXE_cloudscape"))
            .args(["probe", "--url", url])
            .output()
            .unwrap()
    };
    assert!(probe(&format!("{}/healthz", replicas[0].base)).status.success());
    let dead = probe(&format!("http://127.0.0.1:{}/healthz", free_port()));
    assert!(!dead.status.success());
    assert!(String::from_utf8_lossy(&dead.stderr).starts_with("error: "));

    // Operator routes say no-store and are never cached.
    for _ in 0..2 {
        assert_eq!(get(&nginx.base, "/readyz", &[]).cache, "MISS");
    }
    assert_eq!(
        get(&nginx.base, "/metrics", &[]).status,
        404,
        "replicas are scraped directly"
    );

    // Eight clients ask for one cold URL at once: nginx sends the misses upstream
    // without a cache lock (its waiters would poll every 500 ms), all to the replica
    // the tile hashes to, which joins them into one computation. nginx then has it.
    let path = "/v1/worlds/default/tiles/0/-5/4/density.f32?t=80";
    let before = computations(&replicas);
    let answers: Vec<Answer> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..8).map(|_| s.spawn(|| get(&nginx.base, path, &[]))).collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert!(answers.iter().all(|a| a.status == 200 && a.body == answers[0].body));
    assert!(answers.iter().any(|a| a.cache == "MISS"), "the first went upstream");
    assert_eq!(computations(&replicas) - before, 1.0, "concurrent misses computed once");
    let again = get(&nginx.base, path, &[]);
    assert_eq!((again.cache.as_str(), again.body == answers[0].body), ("HIT", true));
}

#[test]
fn killing_a_replica_under_load_loses_no_request() {
    let mut replicas = start_replicas();
    let nginx = Nginx::start(&ports(&replicas));
    let clients = 4;
    let per_client = 60;
    let done = AtomicUsize::new(0);
    let (failures, done_at_kill): (Vec<String>, usize) = std::thread::scope(|s| {
        let handles: Vec<_> = (0..clients)
            .map(|c| {
                let (base, done) = (&nginx.base, &done);
                s.spawn(move || {
                    let mut failures = Vec::new();
                    for i in 0..per_client {
                        // Distinct cold URLs (cheap point samples), so every request goes
                        // upstream to some replica.
                        let path = format!("/v1/worlds/default/sample?x={}&y={}&z=1050&t=20", i * 150, c * 150);
                        let a = get(base, &path, &[]);
                        if a.status != 200 || !a.body.starts_with(b"{") {
                            failures.push(format!("{path}: {} ({} bytes)", a.status, a.body.len()));
                        }
                        done.fetch_add(1, Ordering::SeqCst);
                    }
                    failures
                })
            })
            .collect();
        // A sixth of the way through, SIGKILL one replica: no drain, its connections die.
        let start = Instant::now();
        while done.load(Ordering::SeqCst) < clients * per_client / 6 && start.elapsed() < Duration::from_secs(60) {
            std::thread::sleep(Duration::from_millis(5));
        }
        replicas[1].child.kill().unwrap();
        let done_at_kill = done.load(Ordering::SeqCst);
        replicas[1].child.wait().unwrap();
        let failures = handles.into_iter().flat_map(|h| h.join().unwrap()).collect();
        (failures, done_at_kill)
    });
    assert!(failures.is_empty(), "requests lost: {failures:?}");
    assert!(
        done_at_kill < clients * per_client / 2,
        "the replica died while most of the load was still to come ({done_at_kill} done)"
    );
    // The survivors computed everything the dead replica had not.
    let survivors: f64 = [&replicas[0], &replicas[2]]
        .iter()
        .map(|r| metric(r, "cloudscape_computations_total", &[("kind", "sample")]))
        .sum();
    assert!(survivors >= (clients * per_client - done_at_kill) as f64);
    let log = std::fs::read_to_string(nginx.dir.path().join("access.log")).unwrap();
    let samples: Vec<&str> = log.lines().filter(|l| l.contains("/sample?")).collect();
    assert_eq!(samples.len(), clients * per_client);
    // nginx logs every upstream a request tried: some tried the dead replica, then another.
    let dead = format!("127.0.0.1:{}, ", replicas[1].port);
    assert!(
        samples.iter().any(|l| l.contains(&dead) && l.contains(" 200 ")),
        "no request was retried on a live replica:\n{}",
        samples.join("\n")
    );
}

/// A relay in front of one replica that forwards both ways, except that a connection
/// carrying a request whose bytes hold [`POISON`] is closed at once, unanswered: what
/// a replica that crashes on a request (a panic, an abort) did to nginx.
struct Relay {
    port: u16,
    stop: Arc<AtomicBool>,
}

/// The marker of a request that kills its upstream connection.
const POISON: &[u8] = b"poison";

impl Relay {
    fn start(upstream: u16) -> Relay {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        listener.set_nonblocking(true).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = Arc::clone(&stop);
        std::thread::spawn(move || {
            while !stopped.load(Ordering::SeqCst) {
                match listener.accept() {
                    Ok((down, _)) => {
                        down.set_nonblocking(false).unwrap();
                        let up = TcpStream::connect(("127.0.0.1", upstream)).unwrap();
                        Relay::pipe(down, up);
                    }
                    Err(_) => std::thread::sleep(Duration::from_millis(2)),
                }
            }
        });
        Relay { port, stop }
    }

    /// Copies `down` (nginx) to `up` (the replica) and back, each way on a thread;
    /// poison from nginx closes both.
    fn pipe(down: TcpStream, up: TcpStream) {
        let (mut down_r, mut up_w) = (down.try_clone().unwrap(), up.try_clone().unwrap());
        let (kill_down, kill_up) = (down.try_clone().unwrap(), up.try_clone().unwrap());
        std::thread::spawn(move || {
            let mut buf = [0u8; 16 * 1024];
            loop {
                match down_r.read(&mut buf) {
                    Ok(0) | Err(_) => break,
                    Ok(n) if buf[..n].windows(POISON.len()).any(|w| w == POISON) => {
                        let _ = kill_down.shutdown(Shutdown::Both);
                        let _ = kill_up.shutdown(Shutdown::Both);
                        return;
                    }
                    Ok(n) => {
                        if up_w.write_all(&buf[..n]).is_err() {
                            break;
                        }
                    }
                }
            }
            let _ = up_w.shutdown(Shutdown::Write);
        });
        let (mut up_r, mut down_w) = (up, down);
        std::thread::spawn(move || {
            let _ = std::io::copy(&mut up_r, &mut down_w);
            let _ = down_w.shutdown(Shutdown::Write);
        });
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

#[test]
fn a_request_that_kills_its_upstream_connection_takes_no_replica_out_for_the_others() {
    let replicas = start_replicas();
    let relays: Vec<Relay> = replicas.iter().map(|r| Relay::start(r.port)).collect();
    let nginx = Nginx::start(&[relays[0].port, relays[1].port, relays[2].port]);
    let sample = |i: usize, extra: &str| format!("/v1/worlds/default/sample?x={}&y=300&z=1050&t=20{extra}", i * 150);

    // nginx retries a request that failed on a kept-alive upstream connection without
    // counting the try (the connection may just have gone stale), which would blur the
    // count of tries below: first let the connections of its start-up checks expire
    // (the upstream keepalive_timeout, 4 s).
    std::thread::sleep(Duration::from_secs(5));
    // Three requests that each kill every upstream connection they are sent on, all to
    // one shard, so the same replicas see each failure.
    for _ in 0..3 {
        let a = get(&nginx.base, &sample(0, "&poison"), &[]);
        assert_eq!(a.status, 502, "the poisoned request itself fails");
    }
    // Everyone else is served, on every shard: no replica was taken out.
    let failures: Vec<String> = (1..=60)
        .map(|i| (i, get(&nginx.base, &sample(i, ""), &[])))
        .filter(|(_, a)| a.status != 200)
        .map(|(i, a)| format!("{}: {}", sample(i, ""), a.status))
        .collect();
    assert!(failures.is_empty(), "other clients failed: {failures:?}");
    // Each poisoned request was tried on two replicas, not on all three.
    let log = std::fs::read_to_string(nginx.dir.path().join("access.log")).unwrap();
    let poisoned: Vec<&str> = log.lines().filter(|l| l.contains("poison")).collect();
    assert_eq!(poisoned.len(), 3, "{log}");
    for line in poisoned {
        let tried = line
            .split("upstream=")
            .nth(1)
            .unwrap_or("")
            .split(" upstream_status")
            .next()
            .unwrap_or("");
        assert_eq!(tried.matches("127.0.0.1:").count(), 2, "{line}");
    }
    // The replicas served all the others.
    let served: f64 = replicas
        .iter()
        .map(|r| metric(r, "cloudscape_computations_total", &[("kind", "sample")]))
        .sum();
    assert!(served >= 60.0, "{served}");
}

/// A raw request to nginx; the status and the body.
fn raw(base: &str, request: &str) -> (u16, Vec<u8>) {
    let addr = base.strip_prefix("http://").unwrap();
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    s.write_all(request.as_bytes()).unwrap();
    let mut answer = Vec::new();
    s.read_to_end(&mut answer).unwrap();
    let text = String::from_utf8_lossy(&answer).into_owned();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let status = head.split(' ').nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    (status, body.as_bytes().to_vec())
}

#[test]
fn a_tilejson_request_with_a_forged_host_does_not_change_what_the_next_client_gets() {
    let replicas = start_replicas();
    let nginx = Nginx::start(&ports(&replicas));
    let path = "/v1/worlds/default/tilejson.json?layer=low";
    let authority = nginx.base.strip_prefix("http://").unwrap().to_string();
    let template = |body: &[u8]| {
        let doc: serde_json::Value = serde_json::from_slice(body).unwrap();
        doc["tiles"][0].as_str().unwrap().to_string()
    };
    // A forged Host and X-Forwarded-Proto, then an absolute-form request line naming
    // another host: what each gets is its own business...
    let forged = [
        format!("GET {path} HTTP/1.1\r\nHost: evil.example\r\nX-Forwarded-Proto: https\r\nConnection: close\r\n\r\n"),
        format!(
            "GET http://evil.example{path} HTTP/1.1\r\nHost: {authority}\r\nX-Forwarded-Proto: https\r\nConnection: close\r\n\r\n"
        ),
    ];
    for request in &forged {
        let (status, body) = raw(&nginx.base, request);
        assert_eq!(status, 200, "{request}");
        assert!(
            !template(&body).starts_with("https://"),
            "nginx says how it was reached: {}",
            template(&body)
        );
    }
    // ...and the next client, asking the plain URL, gets the templates of the address
    // it reached nginx at (port included), every time.
    for _ in 0..3 {
        let a = get(&nginx.base, path, &[]);
        assert_eq!(a.status, 200);
        let t = template(&a.body);
        assert!(t.starts_with(&format!("{}/v1/worlds/default/zoom/", nginx.base)), "{t}");
        assert_ne!(a.cache, "HIT", "a document built from a request's Host is never cached");
    }
    // A replica says so itself: private, and varying with what it was built from.
    let r = client().get(format!("{}{path}", replicas[0].base)).send().unwrap();
    let header = |n: &str| {
        r.headers()
            .get_all(n)
            .iter()
            .map(|v| v.to_str().unwrap().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    assert!(
        header("cache-control").starts_with("private"),
        "{}",
        header("cache-control")
    );
    assert!(header("vary").contains("host, x-forwarded-proto"), "{}", header("vary"));
}
