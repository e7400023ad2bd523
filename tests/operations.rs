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
