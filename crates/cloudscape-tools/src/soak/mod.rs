//! Hostile-input soak: sends generated requests ([`generate`]) to a running server
//! and judges every answer against the product contract — a product with the route's
//! content type, a 304, or a JSON error `{"error", "message"}`; never a 5xx other than
//! 503, never a 503 without `Retry-After`, never silence — then checks that the server
//! is still healthy and reports its peak memory. `cloudscape fuzz` is the command line.

pub mod attack;
pub mod conn_attacks;
pub mod generate;
pub mod http;

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

pub use cloudscape_core::cost::process_memory_kb;
pub use generate::{FuzzRequest, Generator, Kind};
use http::{Answer, Connection, Failure};

/// How to run a soak.
#[derive(Clone, Debug)]
pub struct SoakOptions {
    /// `http://HOST:PORT`
    pub target: String,
    /// Requests to send, in all.
    pub requests: u64,
    /// Seed of the [`Generator`]: the same seed sends the same requests.
    pub seed: u64,
    /// Connections sending at once.
    pub concurrency: usize,
    /// Socket timeout of one exchange: an answer slower than this counts as a hang.
    pub timeout: Duration,
    /// The server's process id, to read its peak RSS (`VmHWM`) from `/proc`.
    pub pid: Option<u32>,
    /// A request that must answer 200 after the soak (the known-good product).
    pub good_path: String,
    /// Progress lines on stderr.
    pub progress: bool,
}

/// One answer that breaks the contract.
#[derive(Clone, Debug, Serialize)]
pub struct Violation {
    /// Request index: `Generator::new(seed).request(index)` regenerates it.
    pub index: u64,
    /// How the answer broke the contract, one sentence.
    pub what: String,
    /// The request method (truncated: generated methods may be garbage).
    pub method: String,
    /// The request target (lossy UTF-8, truncated).
    pub target: String,
    /// Extra headers sent (values truncated).
    pub headers: Vec<String>,
}

/// The health checks after the soak.
#[derive(Clone, Debug, Serialize)]
pub struct Health {
    /// Status of `/healthz` (`None`: no answer).
    pub healthz: Option<u16>,
    /// Status of `/readyz`.
    pub readyz: Option<u16>,
    /// Status of the known-good product (retried while 503).
    pub good_product: Option<u16>,
    /// All three answered 200.
    pub healthy: bool,
}

/// The server's resident memory around a run, from `/proc` (`VmRSS`, `VmHWM`), kB;
/// `None` where no pid was given or `/proc` could not be read. The soak and the
/// attack scenario both report it.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct ServerMemory {
    /// Resident memory before the run.
    pub rss_before_kb: Option<u64>,
    /// Peak resident memory (`VmHWM`, the process's high-water mark) after the run.
    pub peak_rss_kb: Option<u64>,
}

impl ServerMemory {
    /// Reads the resident memory of process `pid` before a run (the peak is still unknown).
    pub fn before(pid: Option<u32>) -> ServerMemory {
        ServerMemory {
            rss_before_kb: pid.and_then(process_memory_kb).map(|(rss, _)| rss),
            peak_rss_kb: None,
        }
    }

    /// Reads the peak of process `pid` after the run.
    pub fn with_peak(self, pid: Option<u32>) -> ServerMemory {
        ServerMemory {
            peak_rss_kb: pid.and_then(process_memory_kb).map(|(_, hwm)| hwm),
            ..self
        }
    }

    /// `before 12.3 MiB, peak 45.6 MiB` with `decimals` decimals; `unknown (no --pid)`
    /// for a figure not read.
    pub fn describe(&self, decimals: usize) -> String {
        let mib = |kb: Option<u64>| {
            kb.map_or("unknown (no --pid)".to_string(), |k| {
                format!("{:.*} MiB", decimals, k as f64 / 1024.0)
            })
        };
        format!("before {}, peak {}", mib(self.rss_before_kb), mib(self.peak_rss_kb))
    }
}

/// What a soak found.
#[derive(Clone, Debug, Serialize)]
pub struct SoakReport {
    /// The options the soak ran with ([`SoakOptions`]).
    pub target: String,
    pub seed: u64,
    pub requests: u64,
    pub concurrency: usize,
    /// Wall-clock time of the soak, health checks excluded.
    pub seconds: f64,
    /// Answers by status code; `closed` (connection closed without an answer) and
    /// `timeout` for the rest.
    pub by_status: BTreeMap<String, u64>,
    /// The same, for the protocol-level requests only (they are also in `by_status`).
    pub protocol_by_status: BTreeMap<String, u64>,
    /// 5xx answers other than 503, listed in `violations`.
    pub server_errors: u64,
    /// Answers that broke the contract, in all.
    pub violation_count: u64,
    /// The first violations (at most 100).
    pub violations: Vec<Violation>,
    /// Latency of well-formed route requests, milliseconds.
    pub latency_ms_p50: f64,
    pub latency_ms_p99: f64,
    pub latency_ms_max: f64,
    /// The server's resident memory before the soak and its peak after.
    #[serde(flatten)]
    pub memory: ServerMemory,
    /// The health checks after the soak.
    pub health_after: Health,
}

impl SoakReport {
    /// True when nothing broke the contract and the server is healthy after.
    pub fn passed(&self) -> bool {
        self.violation_count == 0 && self.health_after.healthy
    }

    /// A short human-readable summary.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "{} requests (seed {}, concurrency {}) in {:.1} s to {}\n",
            self.requests, self.seed, self.concurrency, self.seconds, self.target
        );
        let statuses: Vec<String> = self.by_status.iter().map(|(k, v)| format!("{k}: {v}")).collect();
        s += &format!("by status: {}\n", statuses.join(", "));
        let protocol: Vec<String> = self
            .protocol_by_status
            .iter()
            .map(|(k, v)| format!("{k}: {v}"))
            .collect();
        s += &format!("  of which protocol-level: {}\n", protocol.join(", "));
        s += &format!(
            "latency (route requests): p50 {:.2} ms, p99 {:.2} ms, max {:.1} ms\n",
            self.latency_ms_p50, self.latency_ms_p99, self.latency_ms_max
        );
        s += &format!("server RSS: {}\n", self.memory.describe(1));
        let h = &self.health_after;
        let st = |v: Option<u16>| v.map_or("no answer".to_string(), |c| c.to_string());
        s += &format!(
            "after: /healthz {}, /readyz {}, known-good product {} -> {}\n",
            st(h.healthz),
            st(h.readyz),
            st(h.good_product),
            if h.healthy { "healthy" } else { "NOT HEALTHY" }
        );
        s += &format!(
            "5xx other than 503: {}; contract violations: {}\n",
            self.server_errors, self.violation_count
        );
        for v in &self.violations {
            s += &format!("  #{} {}: {} {} {:?}\n", v.index, v.what, v.method, v.target, v.headers);
        }
        s
    }
}

/// Judges one answer; `None` when it keeps the contract.
pub fn judge(req: &FuzzRequest, a: &Answer) -> Option<String> {
    let ctype = a.header("content-type").unwrap_or("");
    if a.status >= 500 && a.status != 503 {
        return Some(format!("server error {}", a.status));
    }
    if a.status == 503 && a.header("retry-after").is_none() {
        return Some("503 without Retry-After".into());
    }
    if req.kind == Kind::Protocol {
        // Refused by the HTTP layer or the router: a 4xx carries the JSON error like
        // any other (a connection closed without an answer is judged elsewhere).
        let refused = (400..500).contains(&a.status) && req.method != "HEAD";
        let json = ctype.starts_with("application/json")
            && serde_json::from_slice::<serde_json::Value>(&a.body)
                .is_ok_and(|b| b["error"].as_str().is_some_and(|c| !c.is_empty()));
        return (refused && !json).then(|| format!("{} from the HTTP layer without a JSON error body", a.status));
    }
    // A compressed body (the request may have asked for one) is judged by its type.
    let compressed = a
        .header("content-encoding")
        .is_some_and(|e| !e.eq_ignore_ascii_case("identity"));
    if a.status >= 400 {
        if compressed {
            return (!ctype.starts_with("application/json")).then(|| format!("{} without a JSON type", a.status));
        }
        let body: Option<serde_json::Value> = serde_json::from_slice(&a.body).ok();
        let well_formed = body.as_ref().is_some_and(|b| {
            b["error"].as_str().is_some_and(|c| !c.is_empty()) && b["message"].as_str().is_some_and(|m| !m.is_empty())
        });
        if req.method == "HEAD" {
            return (!ctype.starts_with("application/json")).then(|| format!("{} without a JSON type", a.status));
        }
        if !ctype.starts_with("application/json") || !well_formed {
            return Some(format!("{} without a JSON error body (type `{ctype}`)", a.status));
        }
        return None;
    }
    if a.status == 200 && req.method == "GET" {
        if let Some(want) = req.ok_type {
            if !ctype.starts_with(want) {
                return Some(format!("200 with type `{ctype}`, expected `{want}`"));
            }
            let magic_ok = compressed
                || match want {
                    "image/png" => a.body.starts_with(b"\x89PNG\r\n\x1a\n"),
                    "application/json" => matches!(a.body.first(), Some(b'{' | b'[')),
                    _ => a.body_len > 0,
                };
            if !magic_ok {
                return Some(format!("200 `{want}` whose body is not one"));
            }
        }
        return None;
    }
    match a.status {
        200 | 204 | 304 => None,
        s if (300..400).contains(&s) => None,
        s => Some(format!("unexpected status {s}")),
    }
}

#[derive(Default)]
struct Tally {
    by_status: BTreeMap<String, u64>,
    protocol_by_status: BTreeMap<String, u64>,
    server_errors: u64,
    violation_count: u64,
    violations: Vec<Violation>,
    latencies_us: Vec<u32>,
}

impl Tally {
    fn merge(&mut self, o: Tally) {
        for (k, v) in o.by_status {
            *self.by_status.entry(k).or_default() += v;
        }
        for (k, v) in o.protocol_by_status {
            *self.protocol_by_status.entry(k).or_default() += v;
        }
        self.server_errors += o.server_errors;
        self.violation_count += o.violation_count;
        self.violations.extend(o.violations);
        self.latencies_us.extend(o.latencies_us);
    }

    fn violation(&mut self, index: u64, req: &FuzzRequest, what: String) {
        self.violation_count += 1;
        if self.violations.len() < 100 {
            self.violations.push(Violation {
                index,
                what,
                method: req.method.chars().take(20).collect(),
                target: req.display_target(300),
                headers: req
                    .headers
                    .iter()
                    .map(|(k, v)| format!("{k}: {}", String::from_utf8_lossy(&v[..v.len().min(40)])))
                    .collect(),
            });
        }
    }
}

/// Sends one request, reconnecting once when a reused keep-alive connection turns out
/// to be closed.
fn send(
    conn: &mut Option<Connection>,
    addr: &str,
    bytes: &[u8],
    head: bool,
    timeout: Duration,
) -> Result<Answer, Failure> {
    for attempt in 0..2 {
        if conn.is_none() {
            *conn = Some(Connection::open(addr, timeout).map_err(Failure::Closed)?);
        }
        let c = conn.as_mut().expect("connection just opened");
        let reused = c.used > 0;
        match c.exchange(bytes, head) {
            Ok((answer, keep)) => {
                if !keep {
                    *conn = None;
                }
                return Ok(answer);
            }
            Err(e) => {
                *conn = None;
                if !(reused && attempt == 0 && matches!(e, Failure::Closed(_))) {
                    return Err(e);
                }
            }
        }
    }
    unreachable!("the loop returns")
}

/// A plain GET with a fresh connection: status, if any answer came.
pub fn get_status(addr: &str, path: &str, timeout: Duration) -> Option<u16> {
    let req = FuzzRequest {
        method: "GET".into(),
        target: path.as_bytes().to_vec(),
        headers: vec![],
        kind: Kind::Route,
        ok_type: None,
    };
    let mut conn = None;
    send(&mut conn, addr, &req.to_bytes(addr), false, timeout)
        .ok()
        .map(|a| a.status)
}

/// Runs a soak against `opts.target`.
pub fn soak(opts: &SoakOptions) -> Result<SoakReport, String> {
    let addr = http::host_port(&opts.target)?;
    if get_status(&addr, "/healthz", opts.timeout) != Some(200) {
        return Err(format!("{} does not answer /healthz with 200", opts.target));
    }
    let memory = ServerMemory::before(opts.pid);
    let generator = Generator::new(opts.seed);
    let next = AtomicU64::new(0);
    let done = AtomicU64::new(0);
    let total = Mutex::new(Tally::default());
    let started = Instant::now();
    std::thread::scope(|scope| {
        for _ in 0..opts.concurrency.max(1) {
            scope.spawn(|| {
                let mut tally = Tally::default();
                let mut conn: Option<Connection> = None;
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= opts.requests {
                        break;
                    }
                    let req = generator.request(i);
                    let bytes = req.to_bytes(&addr);
                    let t0 = Instant::now();
                    let result = send(&mut conn, &addr, &bytes, req.method == "HEAD", opts.timeout);
                    let elapsed = t0.elapsed();
                    let status = match &result {
                        Ok(a) => a.status.to_string(),
                        Err(Failure::TimedOut) => "timeout".to_string(),
                        Err(Failure::Closed(_)) => "closed".to_string(),
                        Err(Failure::Garbled(_)) => "garbled".to_string(),
                    };
                    *tally.by_status.entry(status.clone()).or_default() += 1;
                    if req.kind == Kind::Protocol {
                        *tally.protocol_by_status.entry(status).or_default() += 1;
                    } else {
                        tally
                            .latencies_us
                            .push(elapsed.as_micros().min(u32::MAX as u128) as u32);
                    }
                    match result {
                        Ok(a) => {
                            if a.status >= 500 && a.status != 503 {
                                tally.server_errors += 1;
                            }
                            if let Some(what) = judge(&req, &a) {
                                tally.violation(i, &req, what);
                            }
                        }
                        Err(Failure::TimedOut) => {
                            tally.violation(i, &req, format!("no answer within {:?}", opts.timeout))
                        }
                        Err(Failure::Garbled(m)) => tally.violation(i, &req, format!("not HTTP: {m}")),
                        // The HTTP layer may drop a connection that sent protocol garbage.
                        Err(Failure::Closed(e)) if req.kind == Kind::Route => {
                            tally.violation(i, &req, format!("connection closed without an answer: {e}"))
                        }
                        Err(Failure::Closed(_)) => {}
                    }
                    let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                    if opts.progress && n.is_multiple_of((opts.requests / 10).max(1)) {
                        eprintln!(
                            "fuzz: {n}/{} requests, {:.0} s",
                            opts.requests,
                            started.elapsed().as_secs_f64()
                        );
                    }
                }
                total.lock().expect("no worker panics holding the tally").merge(tally);
            });
        }
    });
    let seconds = started.elapsed().as_secs_f64();
    let mut tally = total.into_inner().map_err(|_| "a fuzz worker panicked".to_string())?;
    tally.violations.sort_by_key(|v| v.index);
    tally.latencies_us.sort_unstable();
    let pct = |p: f64| {
        let l = &tally.latencies_us;
        if l.is_empty() {
            0.0
        } else {
            l[((l.len() - 1) as f64 * p).round() as usize] as f64 / 1000.0
        }
    };
    let health_after = health(&addr, &opts.good_path, opts.timeout);
    Ok(SoakReport {
        target: opts.target.clone(),
        seed: opts.seed,
        requests: opts.requests,
        concurrency: opts.concurrency,
        seconds,
        latency_ms_p50: pct(0.5),
        latency_ms_p99: pct(0.99),
        latency_ms_max: pct(1.0),
        by_status: tally.by_status,
        protocol_by_status: tally.protocol_by_status,
        server_errors: tally.server_errors,
        violation_count: tally.violation_count,
        violations: tally.violations,
        memory: memory.with_peak(opts.pid),
        health_after,
    })
}

/// `/healthz` and `/readyz` answer 200, and the known-good product is served (retried
/// for up to 30 s while the server sheds, since it may still be finishing work).
pub fn health(addr: &str, good_path: &str, timeout: Duration) -> Health {
    let healthz = get_status(addr, "/healthz", timeout);
    let readyz = get_status(addr, "/readyz", timeout);
    let mut good = None;
    let deadline = Instant::now() + Duration::from_secs(30);
    while Instant::now() < deadline {
        good = get_status(addr, good_path, timeout);
        if good != Some(503) {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    Health {
        healthz,
        readyz,
        good_product: good,
        healthy: healthz == Some(200) && readyz == Some(200) && good == Some(200),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_figures_stay_top_level_fields_of_the_report() {
        let memory = ServerMemory {
            rss_before_kb: Some(1024),
            peak_rss_kb: None,
        };
        let report = attack::AttackReport {
            target: "http://127.0.0.1:1".into(),
            budget_s: 1.0,
            seconds: 0.0,
            attacks: vec![],
            memory,
            rss_limit_kb: 2048,
            held: true,
        };
        let v = serde_json::to_value(&report).unwrap();
        assert_eq!(v["rss_before_kb"], 1024);
        assert!(v["peak_rss_kb"].is_null() && v.get("memory").is_none());
        assert_eq!(memory.describe(1), "before 1.0 MiB, peak unknown (no --pid)");
    }
}
