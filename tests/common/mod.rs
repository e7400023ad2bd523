//! Shared by the integration tests: the one test world (tests/data/small.toml) with
//! per-test overrides, and a real `cloudscape serve` process started on a free loopback
//! port, ready once `/readyz` answers 200, stopped when dropped.
#![allow(dead_code)]

use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The test world every server test starts from: two thin layers, so a cold tile costs
/// milliseconds.
pub const TEST_WORLD: &str = include_str!("../data/small.toml");

/// [`TEST_WORLD`] with `overrides` applied, as TOML text. Each override is a dotted path
/// (table keys, or an index into an array such as `worlds.default.layers.0`) and a TOML
/// value that replaces or adds the entry there:
/// `test_config(&[("server.compute_queue", "2"), ("worlds.default.layers.0.depth", "1")])`.
/// Panics on an index past an array's end or a value that is not TOML; a misspelt key
/// is added as given and refused by the config parsers, which deny unknown keys.
pub fn test_config(overrides: &[(&str, &str)]) -> String {
    let mut world: toml::Value = toml::Value::Table(TEST_WORLD.parse().expect("tests/data/small.toml is TOML"));
    for &(path, value) in overrides {
        let value = format!("value = {value}")
            .parse::<toml::Table>()
            .unwrap_or_else(|e| panic!("override {path} = {value} is not a TOML value: {e}"))
            .remove("value")
            .unwrap();
        let mut node = &mut world;
        for key in path.split('.') {
            node = child(node, key, path);
        }
        *node = value;
    }
    toml::to_string(&world).expect("a TOML table serializes")
}

/// The entry `key` of a table (an empty table if it is new) or element `key` of an array.
fn child<'a>(node: &'a mut toml::Value, key: &str, path: &str) -> &'a mut toml::Value {
    match node {
        toml::Value::Table(t) => t.entry(key).or_insert_with(|| toml::Value::Table(toml::Table::new())),
        toml::Value::Array(a) => {
            let i: usize = key
                .parse()
                .unwrap_or_else(|_| panic!("override {path}: {key} is not an array index"));
            a.get_mut(i)
                .unwrap_or_else(|| panic!("override {path}: there is no element {i}"))
        }
        _ => panic!("override {path}: {key} would be under a plain value"),
    }
}

/// Runs the built `cloudscape` binary with `args` to its end.
pub fn cloudscape(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(args)
        .output()
        .expect("run cloudscape")
}

/// Asserts that a run of the binary exited with success; if not, the message shows
/// its exit status, stdout and stderr.
pub fn assert_success(out: &Output) {
    assert!(
        out.status.success(),
        "exit {:?}\nstdout: {}\nstderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Runs `cloudscape serve --print-config` with `args` and `env` added: the config it
/// would serve on stdout, or its refusal on stderr.
pub fn print_config(args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["serve", "--print-config"])
        .args(args)
        .envs(env.iter().copied())
        .output()
        .expect("run cloudscape serve --print-config")
}

/// A `cloudscape serve` child process on 127.0.0.1; killed when dropped.
pub struct ServeProcess {
    pub child: Child,
    /// `http://127.0.0.1:PORT`
    pub base: String,
    pub port: u16,
}

/// A port nothing listens on right now (the OS picks it; the listener is closed again),
/// and never one handed out before in this test process. The tests of one binary run
/// at once: without the record two of them could be given the same port between
/// `free_port` and their server's bind, and one test would then talk to the other's
/// server (the loser exits with "address in use").
pub fn free_port() -> u16 {
    static GIVEN: std::sync::Mutex<Vec<u16>> = std::sync::Mutex::new(Vec::new());
    let mut given = GIVEN.lock().unwrap_or_else(|e| e.into_inner());
    loop {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .expect("bind 127.0.0.1:0")
            .local_addr()
            .unwrap()
            .port();
        if !given.contains(&port) {
            given.push(port);
            return port;
        }
    }
}

impl ServeProcess {
    /// Starts `cloudscape serve --listen 127.0.0.1:PORT` with `args` and `env` added (and
    /// no play area kept warm unless `env` says otherwise) and waits (up to 60 s) for
    /// `/readyz`. Panics with the server's stderr if it never
    /// becomes ready.
    /// A port from [`free_port`] can be taken by another test's listener (one bound to
    /// port 0) before the server binds it: then the server is started again on another.
    pub fn start(args: &[&str], env: &[(&str, &str)]) -> ServeProcess {
        let mut attempt = 0;
        loop {
            let mut server = Self::spawn_on(free_port(), args, env);
            match server.ready_or_exit(Duration::from_secs(60)) {
                Ok(()) => return server,
                Err(e) if e.contains("Address already in use") && attempt < 4 => attempt += 1,
                Err(e) => panic!("{}/readyz: the process exited before it answered; {e}", server.base),
            }
        }
    }

    /// As [`ServeProcess::start`] on a chosen port.
    pub fn start_on(port: u16, args: &[&str], env: &[(&str, &str)]) -> ServeProcess {
        let mut server = Self::spawn_on(port, args, env);
        if let Err(e) = server.ready_or_exit(Duration::from_secs(60)) {
            panic!("{}/readyz: the process exited before it answered; {e}", server.base);
        }
        server
    }

    /// Spawns `cloudscape serve` on `port` without waiting for it.
    fn spawn_on(port: u16, args: &[&str], env: &[(&str, &str)]) -> ServeProcess {
        let listen = format!("127.0.0.1:{port}");
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_cloudscape"));
        cmd.arg("serve").args(["--listen", &listen]).args(args);
        cmd.env("CLOUDSCAPE_SERVER_DRAIN_MS", "0");
        // The embedded config's play areas are kept warm from start-up on: seconds of
        // work before readiness and a keyframe per tile every span after it, which
        // would compete with what each test measures. A test that wants them passes
        // `("CLOUDSCAPE_SERVER_WARM_THREADS", "1")` in `env` (tests/warm.rs has its own).
        cmd.env("CLOUDSCAPE_SERVER_WARM_THREADS", "0");
        // Its stderr is a pipe read only if it never becomes ready: at `info` every
        // `/readyz` poll logs a line, and a start-up of half a minute (play areas kept
        // warm, a loaded machine) fills the pipe, after which the server blocks on its
        // next log line. Warnings only, unless `env` says otherwise.
        cmd.env("RUST_LOG", "warn");
        for (k, v) in env {
            cmd.env(k, v);
        }
        let child = cmd
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn cloudscape serve");
        ServeProcess {
            child,
            base: format!("http://{listen}"),
            port,
        }
    }

    /// Waits (up to `limit`, else panics with its stderr) for `/readyz` to answer 200;
    /// the server's stderr if it exits first.
    fn ready_or_exit(&mut self, limit: Duration) -> Result<(), String> {
        let client = reqwest::blocking::Client::builder()
            .no_proxy()
            .timeout(Duration::from_secs(5))
            .build()
            .unwrap();
        let url = format!("{}/readyz", self.base);
        let start = Instant::now();
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Err(format!("exit {status}; cloudscape serve: {}", self.stderr()));
            }
            if let Ok(r) = client.get(&url).send()
                && r.status() == reqwest::StatusCode::OK
            {
                return Ok(());
            }
            if start.elapsed() >= limit {
                let _ = self.child.kill();
                panic!(
                    "{url} did not answer 200 within {limit:?}; cloudscape serve: {}",
                    self.stderr()
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// What the process wrote to stderr (all of it once it has exited).
    fn stderr(&mut self) -> String {
        let mut err = String::new();
        if let Some(mut e) = self.child.stderr.take() {
            use std::io::Read;
            let _ = e.read_to_string(&mut err);
        }
        err
    }

    /// GET `path` (`/v1/worlds`, `/metrics`, …) with [`client`].
    pub fn get(&self, path: &str) -> reqwest::blocking::Response {
        client()
            .get(format!("{}{path}", self.base))
            .send()
            .unwrap_or_else(|e| panic!("GET {path}: {e}"))
    }

    /// Sends SIGTERM and waits for the process; returns whether it exited with success.
    pub fn terminate(mut self) -> bool {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        self.child.wait().map(|s| s.success()).unwrap_or(false)
    }
}

impl Drop for ServeProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Whether `check` holds within `limit`, tried every 50 ms. Counts a server keeps
/// settle a moment after what the client sees (a socket closed, a request answered,
/// work done in the background), so tests wait for them rather than read them once.
pub fn eventually(limit: Duration, mut check: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while !check() {
        if start.elapsed() > limit {
            return false;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    true
}

/// Polls `url` every 50 ms until it answers 200, for at most `limit`. Panics if `child`
/// (the process that serves `url`) exits first or the time runs out, with what
/// `log(child)` gives: the process's own account (its stderr, its error log).
pub fn wait_until_ok(child: &mut Child, url: &str, limit: Duration, log: impl FnOnce(&mut Child) -> String) {
    let client = reqwest::blocking::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs(5))
        .build()
        .unwrap();
    let start = Instant::now();
    loop {
        if let Ok(Some(status)) = child.try_wait() {
            panic!(
                "{url}: the process exited ({status}) before it answered; {}",
                log(child)
            );
        }
        if let Ok(r) = client.get(url).send()
            && r.status() == reqwest::StatusCode::OK
        {
            return;
        }
        if start.elapsed() >= limit {
            panic!("{url} did not answer 200 within {limit:?}; {}", log(child));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A blocking HTTP client for the tests: no proxy, 30 s timeout.
pub fn client() -> reqwest::blocking::Client {
    reqwest::blocking::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs(30))
        .build()
        .unwrap()
}

/// Sum of every sample of the Prometheus metric `name` on `server` whose labels include
/// all of `labels`.
pub fn metric(server: &ServeProcess, name: &str, labels: &[(&str, &str)]) -> f64 {
    parse_metric(&server.get("/metrics").text().unwrap(), name, labels)
}

/// Sum of every sample of the metric `name` in a Prometheus text exposition whose
/// labels include all of `labels`.
pub fn parse_metric(text: &str, name: &str, labels: &[(&str, &str)]) -> f64 {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter(|l| l.starts_with(name) && l[name.len()..].starts_with(['{', ' ']))
        .filter(|l| labels.iter().all(|(k, v)| l.contains(&format!("{k}=\"{v}\""))))
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}

/// The world names of a `/v1/worlds` answer, in its order.
pub fn world_names(list: &serde_json::Value) -> Vec<String> {
    list["worlds"]
        .as_array()
        .expect("`worlds` is an array")
        .iter()
        .map(|w| w["name"].as_str().expect("a world has a name").to_string())
        .collect()
}

/// An in-process server (`cloudscape_server::Server` on 127.0.0.1:0) of the config
/// `text`, ready once `/readyz` answers 200: its base URL and a client for it.
pub async fn start_in_process(text: &str) -> (String, reqwest::Client) {
    let config = cloudscape_core::world::Config::parse(text).expect("the test config is valid");
    let settings = cloudscape_server::ServerConfig::parse(text).expect("the test config is valid");
    let server = cloudscape_server::Server::bind(config, settings)
        .await
        .expect("bind 127.0.0.1:0");
    let base = format!("http://{}", server.local_addr().unwrap());
    tokio::spawn(server.run());
    let client = reqwest::Client::builder().no_proxy().build().unwrap();
    // Readiness waits for the config's warm keyframes: seconds on an idle machine, more
    // than a minute on one shared with other builds (the tests that use this are not
    // about how soon it is ready).
    for _ in 0..3600 {
        if let Ok(r) = client.get(format!("{base}/readyz")).send().await
            && r.status() == reqwest::StatusCode::OK
        {
            return (base, client);
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("server never became ready in 180 s");
}

/// An in-process server ([`start_in_process`]) and its client, asked by path.
pub struct InProcess {
    /// `http://127.0.0.1:PORT`
    pub base: String,
    pub client: reqwest::Client,
}

impl InProcess {
    /// Starts a server of the config `text`.
    pub async fn start(text: &str) -> InProcess {
        let (base, client) = start_in_process(text).await;
        InProcess { base, client }
    }

    pub async fn get(&self, path: &str) -> reqwest::Response {
        self.client
            .get(format!("{}{path}", self.base))
            .send()
            .await
            .expect("request")
    }

    /// The status and JSON body of `path`.
    pub async fn status_json(&self, path: &str) -> (u16, serde_json::Value) {
        let r = self.get(path).await;
        let status = r.status().as_u16();
        let bytes = r.bytes().await.unwrap();
        let body = serde_json::from_slice(&bytes)
            .unwrap_or_else(|e| panic!("{path}: {status}, not JSON ({e}): {}", String::from_utf8_lossy(&bytes)));
        (status, body)
    }

    /// Asserts that `path` answers `status` with a JSON error whose message says
    /// something and whose `error` is `code` (any code when `code` is empty).
    pub async fn assert_error(&self, path: &str, status: u16, code: &str) {
        let (got, body) = self.status_json(path).await;
        assert_eq!(got, status, "{path}: {body}");
        assert!(
            body["message"].as_str().is_some_and(|m| !m.is_empty()),
            "{path}: {body}"
        );
        if !code.is_empty() {
            assert_eq!(body["error"], code, "{path}: {body}");
        }
    }

    /// The JSON body of `path`, which must answer 200.
    pub async fn json(&self, path: &str) -> serde_json::Value {
        let (status, body) = self.status_json(path).await;
        assert_eq!(status, 200, "{path}: {body}");
        body
    }

    /// The body of `path`, which must answer 200.
    pub async fn bytes(&self, path: &str) -> Vec<u8> {
        let r = self.get(path).await;
        assert_eq!(r.status(), reqwest::StatusCode::OK, "{path}");
        r.bytes().await.unwrap().to_vec()
    }

    /// The body of `path` (200) as little-endian f32s: a `density.f32` tile, row-major.
    pub async fn f32s(&self, path: &str) -> Vec<f32> {
        let b = self.bytes(path).await;
        b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    }
}
