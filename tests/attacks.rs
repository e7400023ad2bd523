//! The compute and memory attacks of issue 25, against the real binary: work that
//! cannot finish in its budget is refused up front or stopped when its budget ends
//! (its queue slot comes back), `Retry-After` follows the queue, answers stay within
//! the response limit, the cache keeps no entry over a quarter of its budget, and
//! replies held by clients that do not read stay within the reply budget. Bounds are
//! generous: these run on a loaded 2-core machine.

mod common;

use std::io::Write;
use std::time::{Duration, Instant};

use common::{ServeProcess, metric};

fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs(120))
        .build()
        .unwrap()
}

struct Answer {
    status: u16,
    retry_after: Option<u32>,
    json: serde_json::Value,
    bytes: usize,
}

async fn get(c: &reqwest::Client, url: String) -> Answer {
    let r = c.get(url).send().await.expect("every request gets an answer");
    let status = r.status().as_u16();
    let retry_after = r
        .headers()
        .get("retry-after")
        .and_then(|v| v.to_str().ok()?.parse().ok());
    let body = r.bytes().await.unwrap_or_default();
    Answer {
        status,
        retry_after,
        json: serde_json::from_slice(&body).unwrap_or(serde_json::Value::Null),
        bytes: body.len(),
    }
}

/// A render of the default world; `i` moves the camera, so every `i` is a new key.
fn render(base: &str, i: u64, size: &str, quality: &str) -> String {
    format!(
        "{base}/v1/worlds/default/render.png?camera={},-20000,1200,0,8,70&t=43200&size={size}&quality={quality}",
        12_800 + 41 * i
    )
}

/// One test at a time: each loads both cores on purpose, and the figures they check
/// (budgets, queue times) mean nothing while another test's server competes.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Once no other test's server runs: a server with `env` (and quiet logs) and a client
/// for it. Hold the guard for the whole test.
async fn start(env: &[(&str, &str)]) -> (tokio::sync::MutexGuard<'static, ()>, ServeProcess, reqwest::Client) {
    let serial = SERIAL.lock().await;
    let mut all = vec![("RUST_LOG", "error")];
    all.extend_from_slice(env);
    (serial, ServeProcess::start(&[], &all), client())
}

/// Checks `ready` every 100 ms until it holds or `deadline` passes; whether it held.
async fn poll_until(deadline: Instant, ready: impl Fn() -> bool) -> bool {
    while Instant::now() < deadline {
        if ready() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    false
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn work_that_cannot_fit_the_budget_or_the_memory_limit_is_refused_up_front() {
    let (_serial, server, c) = start(&[("CLOUDSCAPE_LIMITS_MAX_REQUEST_BYTES", "134217728")]).await;
    // The request: ~55 CPU-seconds against 10 s × 2 threads.
    let started = Instant::now();
    let a = get(&c, render(&server.base, 0, "4096x4096", "accurate")).await;
    assert_eq!(a.status, 413, "{}", a.json);
    assert_eq!(a.json["error"], "too_much_work");
    let message = a.json["message"].as_str().unwrap();
    assert!(
        message.contains("CPU-seconds") && message.contains("server.request_timeout_ms"),
        "{message}"
    );
    assert!(started.elapsed() < Duration::from_secs(5), "refused before any work");
    // Within the CPU budget but over limits.max_request_bytes (128 MiB here).
    let a = get(&c, render(&server.base, 1, "1024x1024", "balanced")).await;
    assert_eq!(a.status, 413, "{}", a.json);
    assert!(
        a.json["message"].as_str().unwrap().contains("limits.max_request_bytes"),
        "{}",
        a.json
    );
    assert_eq!(metric(&server, "cloudscape_refused_total", &[("kind", "render")]), 2.0);
    assert_eq!(
        metric(&server, "cloudscape_computations_total", &[("kind", "render")]),
        0.0
    );
    // A small view is admitted (drawn, or at worst over its budget on a loaded box).
    let a = get(&c, render(&server.base, 2, "64x36", "fast")).await;
    assert!(a.status == 200 || a.status == 503, "{}", a.json);
    assert_eq!(metric(&server, "cloudscape_refused_total", &[("kind", "render")]), 2.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn work_over_its_budget_is_stopped_and_the_queue_is_free_right_after() {
    let budget_ms = 2000;
    let (_serial, server, c) = start(&[
        ("CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS", &budget_ms.to_string()),
        ("CLOUDSCAPE_SERVER_COMPUTE_QUEUE", "16"),
        ("CLOUDSCAPE_SERVER_COMPUTE_MEMORY_BYTES", "17179869184"),
    ])
    .await;
    // 12 distinct renders, each within the limits (~1.5 CPU-s), ~18 CPU-s together:
    // far more than 2 s on 2 threads. Without admission against the backlog and
    // cancellation the queue stays busy until all of them are done.
    let started = Instant::now();
    let handles: Vec<_> = (0..12)
        .map(|i| tokio::spawn(get_owned(c.clone(), render(&server.base, 100 + i, "1024x1024", "fast"))))
        .collect();
    let mut by_status = std::collections::BTreeMap::new();
    for h in handles {
        let a = h.await.unwrap();
        *by_status.entry(a.status).or_insert(0) += 1;
        assert!(a.status == 200 || a.status == 503, "status {} {}", a.status, a.json);
        if a.status == 503 {
            assert!(a.retry_after.is_some_and(|s| (1..=60).contains(&s)));
            assert!(
                matches!(a.json["error"].as_str(), Some("timeout" | "overloaded")),
                "{}",
                a.json
            );
        }
    }
    let answered = started.elapsed();
    assert!(by_status.get(&503).copied().unwrap_or(0) > 0, "{by_status:?}");
    // Every request is answered by its budget; the stopped jobs give their slots back
    // within a few seconds of that (one tile or band to finish each).
    let limit = Duration::from_millis(budget_ms) + Duration::from_secs(6);
    let emptied = poll_until(started + limit + Duration::from_secs(30), || {
        metric(&server, "cloudscape_compute_queue_depth", &[]) == 0.0
    })
    .await;
    let free_after = started.elapsed();
    assert!(emptied, "the queue empties");
    assert!(
        free_after <= limit,
        "queue free after {free_after:?} (answered after {answered:?}); budget {budget_ms} ms"
    );
    // What could not finish was shed before it started (the backlog was over the
    // budget) or stopped when its budget ran out.
    let stopped = metric(&server, "cloudscape_cancelled_total", &[("kind", "render")]);
    let shed = metric(&server, "cloudscape_shed_total", &[("kind", "render")]);
    assert!(stopped + shed > 0.0, "{by_status:?}");
    // An uncached cheap request is served at once.
    let a = get(
        &c,
        format!("{}/v1/worlds/default/tiles/0/77/-5/density.u8?t=40", server.base),
    )
    .await;
    assert_eq!(a.status, 200);
}

/// Admission counts the queue, not one job: a burst of 32 heavy renders, each legal on
/// its own, with a queue that has room for all 32 and a budget of four times what one
/// takes alone here (measured first, on a server of its own: 0.8 s on an idle 2-core
/// machine, 17 s on one shared with other builds). Before, all 32 were admitted and
/// most timed out together at the budget; now the queue admits what its backlog lets
/// finish within the budget and sheds the rest at once with 503 `overloaded` and a
/// `Retry-After`, and every admitted job is answered 200.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_admits_only_what_finishes_within_the_budget() {
    let alone = {
        let (serial, server, c) = start(&[
            ("CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS", "300000"),
            ("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0"),
        ])
        .await;
        let started = Instant::now();
        assert_eq!(
            get(&c, render(&server.base, 700, "1024x1024", "fast")).await.status,
            200
        );
        drop((server, serial));
        started.elapsed()
    };
    let budget_ms = (4 * alone.as_millis()).clamp(3000, 300_000).to_string();
    let (_serial, server, c) = start(&[
        ("CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS", &budget_ms),
        ("CLOUDSCAPE_SERVER_COMPUTE_QUEUE", "32"),
        ("CLOUDSCAPE_SERVER_COMPUTE_MEMORY_BYTES", "17179869184"),
        ("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0"),
    ])
    .await;
    // Two renders one after the other teach the queue the rate it works at here.
    for i in 0..2 {
        let a = get(&c, render(&server.base, 500 + i, "1024x1024", "fast")).await;
        assert_eq!(a.status, 200, "{} (budget {budget_ms} ms)", a.json);
    }
    let handles: Vec<_> = (0..32)
        .map(|i| tokio::spawn(get_owned(c.clone(), render(&server.base, 600 + i, "1024x1024", "fast"))))
        .collect();
    let mut by = std::collections::BTreeMap::new();
    for h in handles {
        let a = h.await.unwrap();
        let what = match a.status {
            200 => "ok",
            503 => a.json["error"].as_str().unwrap_or("?"),
            _ => "other",
        };
        if a.status == 503 {
            assert!(a.retry_after.is_some_and(|s| (1..=60).contains(&s)), "{}", a.json);
        }
        *by.entry(what.to_string()).or_insert(0) += 1;
    }
    // 32 renders are 16 × one alone on 2 threads, four times the budget: some were
    // admitted and finished, the rest shed up front, none timed out.
    assert!(
        by.get("ok").copied().unwrap_or(0) >= 1,
        "{by:?} (budget {budget_ms} ms)"
    );
    assert!(by.get("overloaded").copied().unwrap_or(0) >= 1, "{by:?}");
    assert_eq!(
        by.get("timeout"),
        None,
        "admitted jobs timed out: {by:?} (budget {budget_ms} ms)"
    );
    assert_eq!(by.values().sum::<u32>(), 32, "{by:?}");
    assert_eq!(metric(&server, "cloudscape_timeouts_total", &[]), 0.0);
    assert_eq!(metric(&server, "cloudscape_cancelled_total", &[]), 0.0);
}

async fn get_owned(c: reqwest::Client, url: String) -> Answer {
    get(&c, url).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn retry_after_follows_the_queue_not_a_constant() {
    let (_serial, server, c) = start(&[
        ("CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS", "60000"),
        ("CLOUDSCAPE_SERVER_COMPUTE_QUEUE", "4"),
        // Room for four 1024² views' working memory (~350 MiB each): the queue, not
        // the memory budget, is what fills here.
        ("CLOUDSCAPE_SERVER_COMPUTE_MEMORY_BYTES", "17179869184"),
    ])
    .await;
    // Two renders one after the other teach the queue its job time (~1.5 s or more).
    for i in 0..2 {
        assert_eq!(
            get(&c, render(&server.base, 200 + i, "1024x1024", "balanced"))
                .await
                .status,
            200
        );
    }
    // Fill the queue with four more, then ask for a fifth. (On a machine so loaded
    // that four views would not finish within the budget, the backlog sheds some of
    // them before the queue fills: the fifth is then shed by the backlog, with a
    // Retry-After of its time.)
    let handles: Vec<_> = (0..4)
        .map(|i| {
            tokio::spawn(get_owned(
                c.clone(),
                render(&server.base, 300 + i, "1024x1024", "balanced"),
            ))
        })
        .collect();
    let mut shed = None;
    for _ in 0..200 {
        let backlog_shed = metric(&server, "cloudscape_shed_total", &[("kind", "render")]) >= 1.0;
        if backlog_shed || metric(&server, "cloudscape_compute_queue_depth", &[]) >= 4.0 {
            shed = Some(get(&c, render(&server.base, 400, "1024x1024", "balanced")).await);
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let shed = shed.expect("the queue filled");
    assert_eq!(shed.status, 503, "{}", shed.json);
    assert_eq!(shed.json["error"], "overloaded");
    // 4 jobs × ≥ 1.5 s / 2 threads: at least 3 s, so more than 2.
    let ra = shed.retry_after.expect("Retry-After");
    assert!((2..=60).contains(&ra), "Retry-After {ra}");
    for h in handles {
        h.await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn billboards_json_over_the_response_limit_is_refused_and_points_to_billboards_bin() {
    let (_serial, server, c) = start(&[("CLOUDSCAPE_LIMITS_MAX_RESPONSE_BYTES", "1048576")]).await;
    let tile = |p: &str| format!("{}/v1/worlds/default/tiles/0/0/0/{p}?t=43200&quality=fast", server.base);
    let a = get(&c, tile("billboards.json")).await;
    assert_eq!(a.status, 413, "{}", a.json);
    assert_eq!(a.json["error"], "response_too_large");
    let m = a.json["message"].as_str().unwrap();
    assert!(
        m.contains("billboards.bin") && m.contains("limits.max_response_bytes"),
        "{m}"
    );
    // The binary form of the same billboards is within the limit, and came from the
    // same shading (no second computation); so does the repeated refusal.
    let bin = get(&c, tile("billboards.bin")).await;
    assert_eq!(bin.status, 200);
    assert!(bin.bytes < 1 << 20);
    assert_eq!(get(&c, tile("billboards.json")).await.status, 413);
    assert_eq!(
        metric(&server, "cloudscape_computations_total", &[("kind", "tile_shaded")]),
        1.0
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_cache_keeps_no_entry_over_a_quarter_of_its_budget() {
    // 4 MiB of response cache (none of it kept for keyframes): at most 1 MiB an
    // entry. density.f32 of a tile is 2.6 MB,
    // density.u8 0.66 MB.
    // The growth of the cache is measured below: nothing computed ahead of the clock
    // (tests/keyframes.rs) adds its entries meanwhile.
    let (_serial, server, c) = start(&[
        ("CLOUDSCAPE_SERVER_CACHE_BYTES", "4194304"),
        ("CLOUDSCAPE_SERVER_KEPT_SHARE", "0"),
        ("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0"),
    ])
    .await;
    let tile = |p: &str| format!("{}/v1/worlds/overcast/tiles/0/3/4/{p}?t=40", server.base);
    let before = metric(&server, "cloudscape_cache_bytes", &[]);
    for _ in 0..2 {
        assert_eq!(get(&c, tile("density.f32")).await.status, 200);
        assert_eq!(get(&c, tile("density.u8")).await.status, 200);
    }
    // The f32 grid was computed twice (never kept), the u8 grid once (kept).
    assert_eq!(
        metric(&server, "cloudscape_computations_total", &[("kind", "tile_density")]),
        3.0
    );
    // The cache grew by the u8 grid and the small entries beside it, never by the
    // 2.6 MB f32 grid (which alone would be more than it grew).
    let grown = metric(&server, "cloudscape_cache_bytes", &[]) - before;
    assert!(grown < 2_621_440.0, "{grown}");
}

/// Sends a GET on a raw socket and reads nothing back.
fn stalled_request(port: u16, path: &str) -> std::net::TcpStream {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(s, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replies_held_by_clients_that_do_not_read_stay_within_the_reply_budget() {
    // A 48 MiB reply budget; balanced billboards.json of a cloudy tile is ~15 MB, so
    // three unread replies (beyond what the sockets' buffers absorb) fill it.
    let (_serial, server, c) = start(&[("CLOUDSCAPE_SERVER_REPLY_BYTES", "50331648")]).await;
    let path = "/v1/worlds/overcast/tiles/0/0/0/billboards.json?t=43200&quality=balanced";
    let full = get(&c, format!("{}{path}", server.base)).await;
    assert_eq!(full.status, 200);
    assert!(full.bytes > 12 << 20, "a large reply: {} bytes", full.bytes);
    let mut stalled = Vec::new();
    let mut refused = None;
    for _ in 0..8 {
        stalled.push(stalled_request(server.port, path));
        tokio::time::sleep(Duration::from_millis(300)).await;
        let a = get(&c, format!("{}{path}", server.base)).await;
        if a.status == 503 {
            refused = Some(a);
            break;
        }
        assert_eq!(a.status, 200);
    }
    let refused = refused.expect("unread replies fill the reply budget");
    assert_eq!(refused.json["error"], "reply_memory_full", "{}", refused.json);
    assert!(refused.retry_after.is_some());
    let held = metric(&server, "cloudscape_reply_bytes", &[]);
    assert!(held <= 50331648.0 && held > 0.0, "{held}");
    // The stalled clients go away: their shares come back and large replies flow.
    drop(stalled);
    let mut served = false;
    for _ in 0..100 {
        if get(&c, format!("{}{path}", server.base)).await.status == 200 {
            served = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(served, "the budget came back once the clients left");
}

#[test]
fn the_attack_scenario_holds_against_the_real_binary() {
    let _serial = SERIAL.blocking_lock();
    // The CI smoke run of `cloudscape fuzz --scenario attack`: a 10 s budget, and the
    // admitted burst 512² `fast` renders (~1 CPU-s each, 8 at once; one alone takes
    // 0.5 s on an idle 2-core machine and a few seconds on one shared with other
    // work, where a 1024² one took over 6 s).
    let server = ServeProcess::start(
        &[],
        &[("RUST_LOG", "error"), ("CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS", "10000")],
    );
    let dir = tempfile::tempdir().unwrap();
    let report = dir.path().join("attack.json");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args([
            "fuzz",
            "--scenario",
            "attack",
            "--target",
            &server.base,
            "--budget",
            "10",
        ])
        .args([
            "--heavy-size",
            "512x512",
            "--heavy-quality",
            "fast",
            "--rss-limit-mib",
            "768",
        ])
        .args([
            "--pid",
            &server.child.id().to_string(),
            "--json",
            report.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert_eq!(r["held"], true, "{stdout}");
    let attack = |name: &str| {
        r["attacks"]
            .as_array()
            .unwrap()
            .iter()
            .find(|a| a["name"] == name)
            .unwrap_or_else(|| panic!("{name} in {stdout}"))
            .clone()
    };
    // The refused burst: 413 only, answered at once.
    let refused = attack("render_burst_refused");
    assert_eq!(refused["statuses"]["413"], 8, "{stdout}");
    // The admitted burst: only 200 and 503, every admitted render finished within
    // the budget, and the queue back within 2 × the budget.
    let admitted = attack("render_burst_admitted");
    for (status, _) in admitted["statuses"].as_object().unwrap() {
        assert!(status == "200" || status == "503", "{stdout}");
    }
    assert_eq!(
        admitted["figures"]["admitted"], admitted["figures"]["admitted_finished"],
        "{stdout}"
    );
    assert!(admitted["figures"]["recovery_s"].as_f64().unwrap() <= 20.0, "{stdout}");
    // No answer over the 64 MiB response limit (126 MB before).
    let amp = attack("amplification");
    assert!(
        amp["figures"]["largest_answer_bytes"].as_f64().unwrap() <= 67108864.0,
        "{stdout}"
    );
    assert!(r["peak_rss_kb"].as_u64().unwrap() <= 768 * 1024, "{stdout}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_computation_whose_client_went_away_is_stopped_before_its_budget_ends() {
    let (_serial, server, _) = start(&[("CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS", "60000")]).await;
    // ~5 CPU-seconds of work; the client hangs up after half a second.
    let path = "/v1/worlds/default/render.png?camera=12000,-20000,1200,0,8,70&t=43200&size=2048x2048&quality=balanced";
    let s = stalled_request(server.port, path);
    tokio::time::sleep(Duration::from_millis(500)).await;
    drop(s);
    let stopped = poll_until(Instant::now() + Duration::from_secs(30), || {
        metric(&server, "cloudscape_cancelled_total", &[("kind", "render")]) >= 1.0
    })
    .await;
    assert!(stopped, "the job was not stopped when its client went away");
    assert_eq!(metric(&server, "cloudscape_compute_queue_depth", &[]), 0.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_shaded_tile_at_the_coarsest_level_costs_what_a_fine_one_does() {
    // A metaball's radius grows with the level while a cell's height does not: at
    // level 19 one ball spans 2.6 million cell heights. Each ball's weight once
    // summed them all (a level-19 billboards.bin ran for minutes on both threads,
    // found by schemathesis); it is now bounded by the layer's depth. Every level
    // answers within a budget a level-0 tile needs a small part of.
    let (_serial, server, c) = start(&[
        ("CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS", "10000"),
        ("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0"),
    ])
    .await;
    // config/default.toml: limits.max_level = 16.
    for z in [0, 9, 13, 16] {
        for product in ["billboards.bin", "atlas.png"] {
            let url = format!("{}/v1/worlds/default/tiles/{z}/1/1/{product}?t=43200", server.base);
            let a = get(&c, url).await;
            assert_eq!(a.status, 200, "level {z} {product}: {}", a.json);
            assert!(a.bytes > 0);
        }
    }
    assert_eq!(metric(&server, "cloudscape_compute_queue_depth", &[]), 0.0);
}
