//! HTTP warm and cold: an in-process `cloudscape serve` on a loopback port, fetched
//! over real sockets by blocking clients.

use std::time::{Duration, Instant};

use hdrhistogram::Histogram;

use cloudscape_core::world::Config;
use cloudscape_server::{Server, ServerConfig};

use super::{BenchRun, Effort, fmt_s};

/// A running in-process server; stopped when dropped.
pub(super) struct LocalServer {
    /// `http://127.0.0.1:PORT`.
    pub(super) base: String,
    stop: cloudscape_server::ShutdownHandle,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl LocalServer {
    /// The embedded config (every built-in world) with the default `[server]`
    /// settings but no play area kept warm (its keyframes would be computed beside
    /// what is measured), on a free loopback port; returns once `/readyz` answers 200.
    pub(super) fn start() -> Result<LocalServer, String> {
        let config = Config::embedded();
        let server = ServerConfig {
            listen: "127.0.0.1:0".into(),
            drain_ms: 0,
            warm_threads: 0,
            ..ServerConfig::embedded()
        };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .map_err(|e| e.to_string())?;
        let server = runtime
            .block_on(Server::bind(config, server))
            .map_err(|e| format!("cannot bind a loopback port: {e}"))?;
        let addr = server.local_addr().map_err(|e| e.to_string())?;
        let stop = server.shutdown_handle();
        let thread = std::thread::spawn(move || {
            let _ = runtime.block_on(server.run());
        });
        let local = LocalServer {
            base: format!("http://{addr}"),
            stop,
            thread: Some(thread),
        };
        let client = client()?;
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(60) {
            if let Ok(r) = client.get(format!("{}/readyz", local.base)).send()
                && r.status().as_u16() == 200
            {
                return Ok(local);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        Err("the in-process server did not become ready".into())
    }
}

impl Drop for LocalServer {
    fn drop(&mut self) {
        self.stop.trigger();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

pub(super) fn client() -> Result<reqwest::blocking::Client, String> {
    reqwest::blocking::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs(120))
        .build()
        .map_err(|e| e.to_string())
}

/// GETs `url` and returns (status, ETag, body length).
fn get(
    client: &reqwest::blocking::Client,
    url: &str,
    etag: Option<&str>,
) -> Result<(u16, Option<String>, usize), String> {
    let mut req = client.get(url);
    if let Some(e) = etag {
        req = req.header(reqwest::header::IF_NONE_MATCH, e);
    }
    let r = req.send().map_err(|e| format!("{url}: {e}"))?;
    let status = r.status().as_u16();
    let tag = r
        .headers()
        .get(reqwest::header::ETAG)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string);
    let body = r.bytes().map_err(|e| format!("{url}: {e}"))?;
    Ok((status, tag, body.len()))
}

struct Load {
    requests: u64,
    seconds: f64,
    p50: f64,
    p99: f64,
}

/// A Markdown table row of a closed load: run, connections, requests, rate, p50, p99.
fn load_row(run: &str, connections: usize, l: &Load) -> String {
    format!(
        "| {run} | {connections} | {} | {:.0} | {} | {} |\n",
        l.requests,
        l.requests as f64 / l.seconds,
        fmt_s(l.p50),
        fmt_s(l.p99)
    )
}

/// `connections` threads fetching `urls` in rotation for `budget`.
fn closed_load(
    urls: &[String],
    etags: Option<&[String]>,
    connections: usize,
    budget: Duration,
    min_requests: u64,
) -> Result<Load, String> {
    let start = Instant::now();
    let results: Vec<Result<Histogram<u64>, String>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..connections)
            .map(|c| {
                scope.spawn(move || {
                    let client = client()?;
                    let mut h = Histogram::<u64>::new_with_bounds(1, 3_600_000_000, 3).map_err(|e| e.to_string())?;
                    let mut i = c;
                    while h.len() < min_requests || start.elapsed() < budget {
                        let t = Instant::now();
                        let (status, _, _) =
                            get(&client, &urls[i % urls.len()], etags.map(|e| e[i % e.len()].as_str()))?;
                        if !(status == 200 || status == 304) {
                            return Err(format!("{} answered {status}", urls[i % urls.len()]));
                        }
                        h.saturating_record(t.elapsed().as_micros() as u64);
                        i += connections;
                    }
                    Ok(h)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|_| Err("a client thread panicked".into())))
            .collect()
    });
    let seconds = start.elapsed().as_secs_f64();
    let mut all = Histogram::<u64>::new_with_bounds(1, 3_600_000_000, 3).map_err(|e| e.to_string())?;
    for r in results {
        all.add(r?).map_err(|e| e.to_string())?;
    }
    Ok(Load {
        requests: all.len(),
        seconds,
        p50: all.value_at_quantile(0.5) as f64 / 1e6,
        p99: all.value_at_quantile(0.99) as f64 / 1e6,
    })
}

pub fn http(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let server = LocalServer::start()?;
    let (level, tiles, cold_n, budget) = match effort {
        Effort::Smoke => (4, 2, 1, Duration::from_millis(300)),
        Effort::Quick => (0, 4, 2, Duration::from_secs(2)),
        Effort::Full => (0, 16, 6, Duration::from_secs(10)),
    };
    let side = (tiles as f64).sqrt().ceil() as i64;
    let urls: Vec<String> = (0..tiles as i64)
        .map(|i| {
            format!(
                "{}/v1/worlds/default/tiles/{level}/{}/{}/density.u8?t=0",
                server.base,
                i % side,
                i / side
            )
        })
        .collect();
    let client = client()?;
    // Cold: a new canonical frame every request, so each one computes a tile.
    let mut cold = Vec::new();
    let mut bytes = 0;
    for i in 0..cold_n {
        let url = format!(
            "{}/v1/worlds/default/tiles/{level}/0/0/density.u8?t={}",
            server.base,
            100_000 + 5 * i
        );
        let t = Instant::now();
        let (status, _, n) = get(&client, &url, None)?;
        if status != 200 {
            return Err(format!("cold request answered {status}"));
        }
        cold.push(t.elapsed().as_secs_f64());
        bytes = n;
    }
    cold.sort_by(f64::total_cmp);
    // Warm the tiles, keep their ETags.
    let mut etags = Vec::new();
    for u in &urls {
        let (status, tag, _) = get(&client, u, None)?;
        if status != 200 {
            return Err(format!("{u} answered {status}"));
        }
        etags.push(tag.ok_or("a tile came without an ETag")?);
    }
    let mut md = format!(
        "In-process server (embedded config) on a loopback port; blocking reqwest clients, one connection per \
         thread, closed loop. Payload: `density.u8` tiles of the default world's first layer, level {level} \
         ({bytes} bytes), no compression.\n\n| run | connections | requests | requests/s | p50 | p99 |\n|---|---|---|---|---|---|\n"
    );
    md += &format!(
        "| cold: a new frame per request (computes a tile) | 1 | {cold_n} | {:.2} | {} | {} |\n",
        cold_n as f64 / cold.iter().sum::<f64>(),
        fmt_s(cold[cold.len() / 2]),
        fmt_s(cold[cold.len() - 1])
    );
    for connections in [1, 8] {
        let l = closed_load(&urls, None, connections, budget, 2)?;
        md += &load_row(&format!("warm: {tiles} cached tiles in rotation"), connections, &l);
    }
    let l = closed_load(&urls, Some(&etags), 8, budget, 2)?;
    md += &load_row("revalidation: `If-None-Match` → 304", 8, &l);
    md += "\nClient and server share the machine's cores. For a comparison with nginx serving the same bytes \
           (wrk), see \"HTTP\" above; for a realistic mixed workload, `cloudscape loadtest`.\n";
    out.add_section("http", "HTTP: warm and cold", md);
    Ok(())
}
