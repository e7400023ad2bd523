//! What an operator runs into, over real sockets and real pipes: a server whose stderr
//! reader went away, the log formats and the access log, process and build metrics,
//! and a misspelt environment variable.

mod common;

use std::io::{Read, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{ServeProcess, client, test_config};

/// A server on the test world with `args` and `env`, its stderr a pipe held by the test.
fn serve(args: &[&str], env: &[(&str, &str)]) -> (tempfile::NamedTempFile, ServeProcess) {
    let mut file = tempfile::NamedTempFile::new().unwrap();
    file.write_all(test_config(&[]).as_bytes()).unwrap();
    let mut all = vec!["--config", file.path().to_str().unwrap()];
    all.extend_from_slice(args);
    let server = ServeProcess::start(&all, env);
    (file, server)
}

/// Sends SIGTERM; whether the process exits with success within `limit`.
fn terminate_within(s: &mut ServeProcess, limit: Duration) -> bool {
    let _ = Command::new("kill").args(["-TERM", &s.child.id().to_string()]).status();
    let start = Instant::now();
    while start.elapsed() < limit {
        if let Ok(Some(status)) = s.child.try_wait() {
            return status.success();
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    false
}

#[test]
fn a_closed_stderr_neither_breaks_requests_nor_shutdown() {
    // Every request logs at info: each of those writes meets a closed pipe.
    let (_config, mut s) = serve(&[], &[("RUST_LOG", "info")]);
    drop(s.child.stderr.take());
    let c = client();
    for i in 0..20 {
        let r = c.get(format!("{}/healthz", s.base)).send().expect("/healthz answers");
        assert_eq!(r.status().as_u16(), 200, "request {i}");
        let r = c
            .get(format!("{}/v1/worlds/default/tiles/0/0/0/density.u8?t={i}", s.base))
            .send()
            .expect("a tile answers");
        assert_eq!(r.status().as_u16(), 200, "tile {i}");
    }
    assert!(
        terminate_within(&mut s, Duration::from_secs(20)),
        "SIGTERM did not stop the server with success"
    );
}

/// The server's stderr after a few requests and SIGTERM.
fn logs_of(args: &[&str]) -> String {
    let (_config, mut s) = serve(args, &[("RUST_LOG", "info")]);
    let mut stderr = s.child.stderr.take().unwrap();
    let c = client();
    assert_eq!(
        c.get(format!("{}/v1/worlds/default", s.base)).send().unwrap().status(),
        200
    );
    assert_eq!(
        c.get(format!("{}/v1/worlds/nowhere", s.base)).send().unwrap().status(),
        404
    );
    assert!(terminate_within(&mut s, Duration::from_secs(20)));
    let mut text = String::new();
    stderr.read_to_string(&mut text).unwrap();
    text
}

#[test]
fn text_logs_carry_path_and_status_without_ansi_codes() {
    let text = logs_of(&[]);
    assert!(
        !text.contains('\u{1b}'),
        "ANSI escape in logs written to a pipe:\n{text}"
    );
    let served: Vec<&str> = text.lines().filter(|l| l.contains("served")).collect();
    assert!(
        served.iter().any(|l| l.contains("path=/v1/worlds/default")
            && l.contains("route=/v1/worlds/{world}")
            && l.contains("status=200")),
        "{text}"
    );
    assert!(
        served
            .iter()
            .any(|l| l.contains("path=/v1/worlds/nowhere") && l.contains("status=404")),
        "{text}"
    );
}

#[test]
fn json_logs_are_one_object_a_line() {
    let text = logs_of(&["--log-format", "json"]);
    assert!(!text.contains('\u{1b}'), "{text}");
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}")))
        .collect();
    assert!(lines.iter().any(|l| l["message"] == "start-up done: ready"), "{text}");
    let access = lines
        .iter()
        .find(|l| l["message"] == "served" && l["span"]["path"] == "/v1/worlds/nowhere")
        .unwrap_or_else(|| panic!("no access line for /v1/worlds/nowhere:\n{text}"));
    assert_eq!(access["status"], 404);
    assert_eq!(access["span"]["route"], "/v1/worlds/{world}");
    assert_eq!(access["span"]["method"], "GET");
    assert_eq!(access["level"], "INFO");
    assert!(access["timestamp"].is_string());
    // An unknown format is refused by clap with the choices.
    let out = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["serve", "--log-format", "xml"])
        .stdout(Stdio::null())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("json") && err.contains("text"), "{err}");
}

#[test]
fn metrics_include_process_and_build_info() {
    let (_config, s) = serve(&[], &[("RUST_LOG", "warn")]);
    let text = s.get("/metrics").text().unwrap();
    let m = |name: &str| common::parse_metric(&text, name, &[]);
    assert!(m("process_resident_memory_bytes") > 1e6, "{text}");
    assert!(m("process_open_fds") >= 3.0);
    assert!(m("process_max_fds") >= m("process_open_fds"));
    assert!(m("process_threads") >= 2.0);
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    let started = m("process_start_time_seconds");
    assert!(started <= now + 1.0 && started > now - 600.0, "{started} vs {now}");
    assert!(text.contains("# TYPE process_cpu_seconds_total counter"), "{text}");
    let build = [
        ("version", env!("CARGO_PKG_VERSION")),
        (
            "algorithm_version",
            &cloudscape_core::world::ALGORITHM_VERSION.to_string(),
        ),
    ];
    assert_eq!(
        common::parse_metric(&text, "cloudscape_build_info", &build),
        1.0,
        "{text}"
    );
}

#[test]
fn an_unknown_environment_variable_is_named() {
    let out = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["serve", "--listen", "127.0.0.1:0"])
        .env("CLOUDSCAPE_SERVER_CACHE_BYTE", "1000")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.starts_with(
            "error: unknown environment variable CLOUDSCAPE_SERVER_CACHE_BYTE: [server] has no key `cache_byte`"
        ),
        "{err}"
    );
    assert!(err.contains("cache_bytes"), "the known keys are listed: {err}");
    assert_eq!(err.lines().count(), 1, "{err}");
}

/// `cloudscape serve --config PATH` (with `env`): it must refuse to start, within a
/// minute (else the test stops it and fails: the old server accepted these and ran),
/// with one sentence on stderr and a non-zero exit. Returns the sentence.
fn refused(path: &str, env: &[(&str, &str)]) -> String {
    let mut child = Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["serve", "--config", path, "--listen", "127.0.0.1:0"])
        .env("CLOUDSCAPE_SERVER_WARM_THREADS", "0")
        .envs(env.iter().copied())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("serve --config {path} {env:?} was not refused within a minute");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    assert_eq!(status.code(), Some(1), "{path}: {err}");
    assert!(
        err.starts_with("error: ") && err.trim_end().lines().count() == 1,
        "{path}: {err}"
    );
    assert!(err.len() < 600, "{path}: a sentence, not {} bytes", err.len());
    err
}

#[test]
fn a_config_number_past_what_the_machine_can_do_is_refused_by_name_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, text: &str| {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path.to_str().unwrap().to_string()
    };
    // Each was accepted, then killed or hung the process: one /series allocated 32 GB
    // (abort), SIGTERM never finished draining, a request could allocate anything.
    for (key, value) in [
        ("server.max_series", "4294967295"),
        ("server.drain_ms", "9223372036854775807"),
        ("server.shutdown_timeout_ms", "9223372036854775807"),
        ("server.request_timeout_ms", "9223372036854775807"),
        ("server.compute_queue", "4294967295"),
        ("server.cache_bytes", "4611686018427387904"),
        ("server.reply_bytes", "9223372036854775807"),
        ("limits.max_request_bytes", "9223372036854775807"),
        ("limits.max_cells", "9223372036854775807"),
    ] {
        let path = write("config.toml", &test_config(&[(key, value)]));
        let err = refused(&path, &[]);
        assert!(
            err.contains(&format!("invalid config: {key}: ")),
            "{key} = {value}: {err}"
        );
    }
    // The environment's overrides are held to the same bounds.
    let path = write("config.toml", &test_config(&[]));
    let err = refused(&path, &[("CLOUDSCAPE_SERVER_DRAIN_MS", "9223372036854775807")]);
    assert!(err.contains("server.drain_ms"), "{err}");
}

#[test]
fn a_config_file_is_read_with_a_size_limit_and_its_lists_are_bounded_before_they_are_checked() {
    // A device that never ends (this read 6 GB in 9 s) and a directory.
    let err = refused("/dev/zero", &[]);
    assert!(
        err.contains("/dev/zero") && err.contains("larger than 1024 KiB"),
        "{err}"
    );
    assert!(refused("/", &[]).contains("cannot read config file /"));

    let dir = tempfile::tempdir().unwrap();
    let areas = |n: usize| {
        let mut text = test_config(&[]);
        for i in 0..n {
            text += &format!("[[worlds.default.warm]]\nname = \"a{i}\"\nbbox = [0.0, 0.0, 10.0, 10.0]\n");
        }
        let path = dir.path().join(format!("areas-{n}.toml"));
        std::fs::write(&path, text).unwrap();
        path.to_str().unwrap().to_string()
    };
    // 10^5 play areas (7 MB) were refused after 34 s and 680 MB: now by their size.
    assert!(refused(&areas(100_000), &[]).contains("larger than 1024 KiB"));
    // Within the size, the count is bounded before any area is looked at.
    let err = refused(&areas(5_000), &[]);
    assert!(
        err.contains("worlds.default.warm: has 5000 play areas; the most is 4096"),
        "{err}"
    );

    // TOML that does not parse is one line that says where, never the line quoted whole.
    let deep = dir.path().join("deep.toml");
    let n = 200_000;
    std::fs::write(&deep, format!("x = {}{}\n", "[".repeat(n), "]".repeat(n))).unwrap();
    let err = refused(deep.to_str().unwrap(), &[]);
    assert!(err.contains("line 1, column"), "{err}");
}
