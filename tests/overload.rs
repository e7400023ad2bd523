//! Overload: far more cold work than the compute queue can take. The excess is shed
//! with 503 + `Retry-After` (a JSON error), every request gets an answer, the server's
//! memory stays bounded, and once the load stops it serves normally again.
//!
//! `overload_figures` (ignored; run by hand) measures the capacity, offers 10× that
//! rate open-loop, and prints the figures BENCHMARKS.md "Hostile inputs and overload"
//! reports:
//!
//!     cargo test --release --test overload -- --ignored --nocapture overload_figures

mod common;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use cloudscape_tools::soak::process_memory_kb;
use common::ServeProcess;

/// The test world (a cold tile costs milliseconds) behind a queue of 2 and a 16 MiB cache.
fn test_world() -> String {
    common::test_config(&[("server.cache_bytes", "16777216"), ("server.compute_queue", "2")])
}

/// One answer: status, whether a 503 carried Retry-After and a JSON `overloaded` or
/// `timeout` error, and the latency.
struct Outcome {
    status: u16,
    proper_503: bool,
    latency: Duration,
}

async fn fetch(client: reqwest::Client, url: String) -> Outcome {
    let started = Instant::now();
    let r = client.get(url).send().await.expect("every request gets an answer");
    let status = r.status().as_u16();
    let retry_after = r.headers().contains_key("retry-after");
    let body = r.bytes().await.unwrap_or_default();
    let code = serde_json::from_slice::<serde_json::Value>(&body)
        .ok()
        .and_then(|v| v["error"].as_str().map(str::to_string));
    Outcome {
        status,
        proper_503: status == 503
            && retry_after
            && matches!(code.as_deref(), Some("overloaded" | "timeout" | "reply_memory_full")),
        latency: started.elapsed(),
    }
}

fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs(120))
        .pool_max_idle_per_host(0)
        .build()
        .unwrap()
}

/// A distinct cold tile per `i` (never cached before).
fn cold_tile(base: &str, i: u64) -> String {
    format!(
        "{base}/v1/worlds/default/tiles/0/{}/{}/density.u8?t=40",
        i % 1000,
        i / 1000 + 7
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn excess_is_shed_with_503_memory_stays_bounded_and_service_recovers() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("config.toml");
    std::fs::write(&config, test_world()).unwrap();
    let server = ServeProcess::start(&["--config", config.to_str().unwrap()], &[("RUST_LOG", "error")]);
    let pid = server.child.id();
    let c = client();
    // Warm one tile: the known-good product after the storm.
    let good = format!("{}/v1/worlds/default/tiles/0/0/0/density.u8?t=40", server.base);
    assert_eq!(fetch(c.clone(), good.clone()).await.status, 200);

    // 200 cold tiles at once against a queue of 2: 100× what it holds.
    let handles: Vec<_> = (0..200u64)
        .map(|i| tokio::spawn(fetch(c.clone(), cold_tile(&server.base, i))))
        .collect();
    let mut by_status = BTreeMap::new();
    for h in handles {
        let o = h.await.unwrap();
        *by_status.entry(o.status).or_insert(0) += 1;
        assert!(
            o.status == 200 || o.proper_503,
            "status {} (503s need Retry-After and a JSON error)",
            o.status
        );
    }
    assert!(
        by_status.get(&503).copied().unwrap_or(0) > 0,
        "the excess is shed: {by_status:?}"
    );
    assert!(
        by_status.get(&200).copied().unwrap_or(0) > 0,
        "some work is done: {by_status:?}"
    );

    // The server is alive and serves normally once the load stops: the health routes,
    // the cached product, and new work.
    for path in ["/healthz", "/readyz"] {
        assert_eq!(
            fetch(c.clone(), format!("{}{path}", server.base)).await.status,
            200,
            "{path}"
        );
    }
    assert_eq!(fetch(c.clone(), good).await.status, 200);
    let mut fresh = 0;
    for i in 0..20u64 {
        if fetch(c.clone(), cold_tile(&server.base, 900_000 + i)).await.status == 200 {
            fresh += 1;
        }
    }
    assert_eq!(fresh, 20, "sequential new work is never shed once the storm is over");
    let (_, peak_kb) = process_memory_kb(pid).unwrap();
    assert!(peak_kb < 512 * 1024, "peak RSS {peak_kb} kB");
    assert!(server.terminate(), "clean exit after overload");
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// Capacity, 10× capacity open-loop, RSS and recovery, on the embedded default config.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
#[ignore = "measures figures for BENCHMARKS.md; run by hand"]
async fn overload_figures() {
    let server = ServeProcess::start(&[], &[("RUST_LOG", "error")]);
    let pid = server.child.id();
    let c = client();
    let base = server.base.clone();
    let counter = Arc::new(AtomicU64::new(0));
    let next_cold = {
        let counter = Arc::clone(&counter);
        let base = base.clone();
        move || cold_tile(&base, counter.fetch_add(1, Ordering::Relaxed))
    };
    let cached = format!("{base}/v1/worlds/default/tiles/0/0/0/density.u8?t=40");
    fetch(c.clone(), cached.clone()).await;
    let mut idle_cached = Vec::new();
    for _ in 0..50 {
        idle_cached.push(fetch(c.clone(), cached.clone()).await.latency.as_secs_f64() * 1e3);
    }
    let mut idle_cold = Vec::new();
    for _ in 0..5 {
        idle_cold.push(fetch(c.clone(), next_cold()).await.latency.as_secs_f64() * 1e3);
    }
    let (idle_cached_p50, idle_cold_p50) = (percentile(&mut idle_cached, 0.5), percentile(&mut idle_cold, 0.5));

    // Capacity: closed loop, as many clients as the queue holds, for 10 s.
    let queue = 4 * std::thread::available_parallelism().map_or(1, |n| n.get()) as u64;
    let started = Instant::now();
    let done = Arc::new(AtomicU64::new(0));
    let workers: Vec<_> = (0..queue)
        .map(|_| {
            let (c, done, next_cold) = (c.clone(), Arc::clone(&done), next_cold.clone());
            tokio::spawn(async move {
                while started.elapsed() < Duration::from_secs(10) {
                    if fetch(c.clone(), next_cold()).await.status == 200 {
                        done.fetch_add(1, Ordering::Relaxed);
                    }
                }
            })
        })
        .collect();
    for w in workers {
        w.await.unwrap();
    }
    let capacity = done.load(Ordering::Relaxed) as f64 / started.elapsed().as_secs_f64();
    let (rss_before, _) = process_memory_kb(pid).unwrap();

    // 10× capacity, open loop, for 20 s.
    let rate = 10.0 * capacity;
    let interval = Duration::from_secs_f64(1.0 / rate);
    let started = Instant::now();
    let mut handles = Vec::new();
    let mut tick = tokio::time::interval(interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
    while started.elapsed() < Duration::from_secs(20) {
        tick.tick().await;
        handles.push(tokio::spawn(fetch(c.clone(), next_cold())));
    }
    let offered = handles.len();
    let mut by_status: BTreeMap<u16, u64> = BTreeMap::new();
    let (mut ok_ms, mut shed_ms) = (Vec::new(), Vec::new());
    let mut improper = 0;
    for h in handles {
        let o = h.await.unwrap();
        *by_status.entry(o.status).or_default() += 1;
        let ms = o.latency.as_secs_f64() * 1e3;
        match o.status {
            200 => ok_ms.push(ms),
            503 if o.proper_503 => shed_ms.push(ms),
            _ => improper += 1,
        }
    }
    let load_seconds = started.elapsed().as_secs_f64();
    let stopped = Instant::now();
    // Recovery: until a cached tile and a cold tile are back within 2× their idle p50.
    let mut recovered_after = None;
    while stopped.elapsed() < Duration::from_secs(60) {
        let a = fetch(c.clone(), cached.clone()).await;
        let b = fetch(c.clone(), next_cold()).await;
        let (a_ms, b_ms) = (a.latency.as_secs_f64() * 1e3, b.latency.as_secs_f64() * 1e3);
        if a.status == 200 && b.status == 200 && a_ms <= 2.0 * idle_cached_p50.max(1.0) && b_ms <= 2.0 * idle_cold_p50 {
            recovered_after = Some(stopped.elapsed().as_secs_f64());
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let (rss_after, peak) = process_memory_kb(pid).unwrap();
    println!("idle: cached tile p50 {idle_cached_p50:.2} ms, cold tile p50 {idle_cold_p50:.1} ms");
    println!("capacity (closed loop, {queue} clients, cold level-0 tiles): {capacity:.1} tiles/s");
    println!(
        "10x load: offered {offered} requests at {rate:.0}/s over {load_seconds:.1} s; by status {by_status:?}; \
         improper answers {improper}"
    );
    println!(
        "  200 latency p50 {:.0} ms p99 {:.0} ms max {:.0} ms; 503 latency p50 {:.1} ms p99 {:.1} ms max {:.1} ms",
        percentile(&mut ok_ms, 0.5),
        percentile(&mut ok_ms, 0.99),
        percentile(&mut ok_ms, 1.0),
        percentile(&mut shed_ms, 0.5),
        percentile(&mut shed_ms, 0.99),
        percentile(&mut shed_ms, 1.0)
    );
    println!(
        "RSS: before load {:.0} MiB, after {:.0} MiB, peak (VmHWM) {:.0} MiB",
        rss_before as f64 / 1024.0,
        rss_after as f64 / 1024.0,
        peak as f64 / 1024.0
    );
    println!("latency back to idle (both within 2x idle p50) after {recovered_after:?} s");
    assert_eq!(improper, 0);
    assert!(recovered_after.is_some());
}
