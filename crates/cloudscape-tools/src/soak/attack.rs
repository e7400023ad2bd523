//! The `attack` scenario: the compute and memory attacks of issue 25 against a
//! running server, each bounded in requests and time, loopback only.
//!
//! - **Render burst (refused)**: eight 89-byte requests for
//!   `render.png?size=4096x4096&quality=accurate` (about 55 CPU-seconds and 1.5 GB
//!   each on the development machine) at once. They must be refused up front.
//! - **Render burst (admitted)**: one heavy render alone, then eight that are within
//!   the limits one at a time (by default 2048² `balanced`, about 5 CPU-seconds each;
//!   choose one that fits a smaller budget), all at once. The
//!   server may shed or time them out, but must stop the work nobody waits for.
//!   Recovery: the time from the burst until an uncached cheap request (a density
//!   tile never asked before) answers 200 again. Target: at most 2 × the budget.
//! - **Amplification**: `billboards.json?quality=accurate` of cloudy tiles, 126 MB
//!   for a 68-byte request before; now refused (413) over the response limit.
//! - **Memory**: the server's peak RSS over the whole scenario (`VmHWM` of `--pid`),
//!   against the bound given (the cache budget + 512 MiB by default).
//! - **Crawl** (with `--crawl N`): N tile requests over random seeds, levels, tiles,
//!   times, products and qualities, from 6 clients that retry a 503 after its
//!   `Retry-After` as a crawler would; every one a new key, so the caches fill to
//!   their budgets and the compute queue stays full. It reports the server's RSS
//!   through the crawl (its peak must stay within the bound), after `--crawl-idle`
//!   seconds of quiet (what is given back), the allocator's figures from `/metrics`,
//!   and the keyframes computed ahead for tiles nobody will ask for again (none).
//!
//! The admitted render burst also counts what it admitted: every admitted render
//! must finish within the budget (a 503 `timeout` breaks it; 503 `overloaded`, shed
//! before any work, does not).
//!
//! Every answer is judged as the soak does: never a 5xx other than 503, never a 503
//! without `Retry-After`. Connection attacks (idle, slowloris, unread replies) live in
//! their own module and join the list in [`attacks`].

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use serde::Serialize;

use super::{ServerMemory, process_memory_kb};

/// How to run the scenario.
#[derive(Clone, Debug)]
pub struct AttackOptions {
    /// `http://HOST:PORT`, a loopback address.
    pub target: String,
    /// The server's process id, to read its RSS from `/proc`.
    pub pid: Option<u32>,
    /// The server's request budget (`server.request_timeout_ms`), seconds.
    pub budget_s: f64,
    /// Peak RSS the server may reach, MiB (default: a 256 MiB cache + 512 MiB).
    pub rss_limit_mib: u64,
    /// Requests per burst.
    pub burst: usize,
    /// Size and quality of the admitted burst's renders (`1024x1024`, `accurate`):
    /// heavy, but within the limits of the server's budget.
    pub heavy_size: String,
    pub heavy_quality: String,
    /// The `world` to attack.
    pub world: String,
    /// Run only the attacks named here (all when empty).
    pub only: Vec<String>,
    /// Tile requests of the crawl (0: no crawl).
    pub crawl: usize,
    /// Seconds of quiet after the crawl before its RSS is read again.
    pub crawl_idle_s: f64,
    /// Progress lines on stderr.
    pub progress: bool,
}

/// What one attack found.
#[derive(Clone, Debug, Serialize)]
pub struct AttackOutcome {
    /// The attack's name ([`Attack::name`]).
    pub name: String,
    /// True when the server held: every answer within the contract and the
    /// attack's own target met.
    pub held: bool,
    /// Answers by status (`error` for no answer).
    pub statuses: BTreeMap<String, u64>,
    /// The attack's figures (seconds, bytes, ratios), by name.
    pub figures: BTreeMap<String, f64>,
    /// What went wrong, if anything, one sentence each.
    pub notes: Vec<String>,
}

/// The whole scenario's report.
#[derive(Clone, Debug, Serialize)]
pub struct AttackReport {
    /// The server attacked and its request budget ([`AttackOptions`]).
    pub target: String,
    pub budget_s: f64,
    /// Wall-clock time of the whole scenario.
    pub seconds: f64,
    /// The attacks run, in order.
    pub attacks: Vec<AttackOutcome>,
    /// The server's resident memory before the scenario and its peak after.
    #[serde(flatten)]
    pub memory: ServerMemory,
    /// The peak the server may reach.
    pub rss_limit_kb: u64,
    /// Every attack held and the peak stayed within the limit.
    pub held: bool,
}

impl AttackReport {
    pub fn summary(&self) -> String {
        let mut s = format!(
            "attack scenario against {} (budget {} s) in {:.1} s\n",
            self.target, self.budget_s, self.seconds
        );
        for a in &self.attacks {
            let statuses: Vec<String> = a.statuses.iter().map(|(k, v)| format!("{k}: {v}")).collect();
            let figures: Vec<String> = a.figures.iter().map(|(k, v)| format!("{k} = {v:.3}")).collect();
            s += &format!(
                "{:<24} {}  [{}]  {}\n",
                a.name,
                if a.held { "held" } else { "BROKE" },
                statuses.join(", "),
                figures.join(", ")
            );
            for n in &a.notes {
                s += &format!("    {n}\n");
            }
        }
        s += &format!(
            "server RSS: {} (limit {:.0} MiB)\n",
            self.memory.describe(0),
            self.rss_limit_kb as f64 / 1024.0
        );
        s += if self.held {
            "the server held\n"
        } else {
            "the server did NOT hold\n"
        };
        s
    }
}

/// One attack of the scenario.
pub struct Attack {
    pub name: &'static str,
    pub run: fn(&AttackOptions, &reqwest::blocking::Client) -> AttackOutcome,
}

/// The attacks of the scenario, in order. (Connection attacks add theirs here.)
pub fn attacks() -> Vec<Attack> {
    vec![
        Attack {
            name: "render_burst_refused",
            run: render_burst_refused,
        },
        Attack {
            name: "render_burst_admitted",
            run: render_burst_admitted,
        },
        Attack {
            name: "amplification",
            run: amplification,
        },
        Attack {
            name: "crawl",
            run: crawl,
        },
    ]
}

/// True for `http://` targets on the loopback range (127.0.0.0/8, localhost, [::1]).
pub fn is_loopback_target(target: &str) -> bool {
    let Some(rest) = target.strip_prefix("http://") else {
        return false;
    };
    let host = rest.split('/').next().unwrap_or("");
    let host = match host.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or(""),
        None => host.rsplit_once(':').map_or(host, |(h, _)| h),
    };
    host == "localhost" || host.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// Runs every attack in turn and reports.
pub fn run(opts: &AttackOptions) -> Result<AttackReport, String> {
    if !is_loopback_target(&opts.target) {
        return Err(format!(
            "--target must be an http:// address on loopback (127.0.0.0/8, localhost, [::1]), got `{}`",
            opts.target
        ));
    }
    if !(opts.budget_s.is_finite() && opts.budget_s > 0.0 && opts.budget_s <= 600.0) {
        return Err(format!(
            "the budget must be within (0, 600] seconds, got {}",
            opts.budget_s
        ));
    }
    let client = reqwest::blocking::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs_f64((8.0 * opts.budget_s).max(30.0)))
        .build()
        .map_err(|e| format!("cannot build an HTTP client: {e}"))?;
    let started = Instant::now();
    let memory = ServerMemory::before(opts.pid);
    let mut outcomes = Vec::new();
    let known: Vec<&'static str> = attacks().iter().map(|a| a.name).collect();
    if let Some(bad) = opts.only.iter().find(|n| !known.contains(&n.as_str())) {
        return Err(format!("unknown attack `{bad}`; the attacks are {}", known.join(", ")));
    }
    for attack in attacks() {
        if !opts.only.is_empty() && !opts.only.iter().any(|n| n == attack.name) {
            continue;
        }
        if opts.progress {
            eprintln!("attack: {}", attack.name);
        }
        outcomes.push((attack.run)(opts, &client));
    }
    let memory = memory.with_peak(opts.pid);
    let rss_limit_kb = opts.rss_limit_mib * 1024;
    let rss_ok = memory.peak_rss_kb.is_none_or(|p| p <= rss_limit_kb);
    Ok(AttackReport {
        target: opts.target.clone(),
        budget_s: opts.budget_s,
        seconds: started.elapsed().as_secs_f64(),
        held: rss_ok && outcomes.iter().all(|o| o.held),
        attacks: outcomes,
        memory,
        rss_limit_kb,
    })
}

/// One answer: status (`None` for no answer), whether it keeps the contract, and
/// the body's length.
struct Answer {
    status: Option<u16>,
    retry_after: Option<u32>,
    proper: bool,
    body_bytes: u64,
    error_code: Option<String>,
}

fn get(client: &reqwest::blocking::Client, url: &str) -> Answer {
    match client.get(url).send() {
        Ok(r) => {
            let status = r.status().as_u16();
            let retry_after: Option<u32> = r
                .headers()
                .get("retry-after")
                .and_then(|v| v.to_str().ok()?.parse().ok());
            let body = r.bytes().unwrap_or_default();
            let error_code = serde_json::from_slice::<serde_json::Value>(&body)
                .ok()
                .and_then(|v| v["error"].as_str().map(str::to_string));
            let proper = match status {
                503 => retry_after.is_some() && error_code.is_some(),
                500..=599 => false,
                400..=499 => error_code.is_some(),
                _ => true,
            };
            Answer {
                status: Some(status),
                retry_after,
                proper,
                body_bytes: body.len() as u64,
                error_code,
            }
        }
        Err(_) => Answer {
            status: None,
            retry_after: None,
            proper: false,
            body_bytes: 0,
            error_code: None,
        },
    }
}

/// Sends `urls` at once, one thread each; the answers in order.
fn burst(client: &reqwest::blocking::Client, urls: &[String]) -> Vec<Answer> {
    std::thread::scope(|s| {
        let handles: Vec<_> = urls.iter().map(|u| s.spawn(move || get(client, u))).collect();
        handles
            .into_iter()
            .map(|h| {
                h.join().unwrap_or(Answer {
                    status: None,
                    retry_after: None,
                    proper: false,
                    body_bytes: 0,
                    error_code: None,
                })
            })
            .collect()
    })
}

fn tally(answers: &[Answer], notes: &mut Vec<String>) -> BTreeMap<String, u64> {
    let mut by = BTreeMap::new();
    for a in answers {
        let k = a.status.map_or("error".to_string(), |s| s.to_string());
        *by.entry(k).or_insert(0) += 1;
        if !a.proper {
            notes.push(format!(
                "an answer broke the contract: status {:?}, error {:?}",
                a.status, a.error_code
            ));
        }
    }
    by
}

/// A render URL of the burst; `i` moves the camera so every request is a new key.
fn render_url(o: &AttackOptions, i: usize, size: &str, quality: &str, run: u64) -> String {
    format!(
        "{}/v1/worlds/{}/render.png?camera={},{},1200,0,8,70&t=43200&size={size}&quality={quality}",
        o.target,
        o.world,
        12_800 + 37 * i as u64 + 1000 * run,
        -20_000 - 53 * i as i64,
    )
}

/// A cheap product never asked before (`n` distinct per probe): a level-0 density tile.
fn probe_url(o: &AttackOptions, n: u64) -> String {
    let salt = salt() + n;
    format!(
        "{}/v1/worlds/{}/tiles/0/{}/{}/density.u8?t=40",
        o.target,
        o.world,
        100_000 + salt % 100_000,
        -(100_000 + (salt / 100_000) as i64 % 100_000)
    )
}

/// A number that differs between runs, so a new run asks for keys no earlier run
/// put in the server's cache.
fn salt() -> u64 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    (nanos / 1_000_000) ^ ((std::process::id() as u64) << 20)
}

/// Seconds from `since` until a cheap uncached request answers 200 (probing every
/// 250 ms, at most `limit`); `None` when it never did.
fn recovery(o: &AttackOptions, client: &reqwest::blocking::Client, since: Instant, limit: Duration) -> Option<f64> {
    let mut n = 0;
    while since.elapsed() < limit {
        n += 1;
        if get(client, &probe_url(o, n)).status == Some(200) {
            return Some(since.elapsed().as_secs_f64());
        }
        std::thread::sleep(Duration::from_millis(250));
    }
    None
}

fn outcome(
    name: &str,
    statuses: BTreeMap<String, u64>,
    figures: BTreeMap<String, f64>,
    notes: Vec<String>,
) -> AttackOutcome {
    AttackOutcome {
        name: name.to_string(),
        held: notes.is_empty(),
        statuses,
        figures,
        notes,
    }
}

/// Eight requests that cannot finish in any budget: refused up front, and the
/// server serves at once afterwards.
fn render_burst_refused(o: &AttackOptions, client: &reqwest::blocking::Client) -> AttackOutcome {
    let urls: Vec<String> = (0..o.burst)
        .map(|i| render_url(o, i, "4096x4096", "accurate", 0))
        .collect();
    let b = burst_and_recover(o, client, &urls);
    let mut notes = b.notes;
    if b.answers.iter().any(|a| a.status == Some(200)) {
        notes.push("a render that cannot finish inside the budget was computed".to_string());
    }
    outcome("render_burst_refused", b.statuses, b.figures, notes)
}

/// Heavy renders within the limits, all at once: whatever is shed or times out,
/// the queue is free again within 2 × the budget.
fn render_burst_admitted(o: &AttackOptions, client: &reqwest::blocking::Client) -> AttackOutcome {
    let run = salt() % 100_000;
    // One of them alone first, as a user would send one: how long it takes here (and
    // the queue measures its rate from it).
    let started = Instant::now();
    let alone = get(
        client,
        &render_url(o, o.burst + 1, &o.heavy_size, &o.heavy_quality, 1 + run),
    );
    let alone_s = started.elapsed().as_secs_f64();
    let urls: Vec<String> = (0..o.burst)
        .map(|i| render_url(o, i, &o.heavy_size, &o.heavy_quality, 1 + run))
        .collect();
    let mut b = burst_and_recover(o, client, &urls);
    b.figures.insert("alone_s".to_string(), alone_s);
    if alone.status != Some(200) {
        b.notes.push(format!(
            "one render alone was answered {:?} ({:?})",
            alone.status, alone.error_code
        ));
    }
    if let Some(ra) = b.answers.iter().filter_map(|a| a.retry_after).max() {
        b.figures.insert("max_retry_after_s".to_string(), ra as f64);
    }
    // Admitted: answered (200), or run and timed out at the budget. Shed up front
    // (`overloaded`) is not admitted.
    let finished = b.answers.iter().filter(|a| a.status == Some(200)).count();
    let timed_out = b
        .answers
        .iter()
        .filter(|a| a.error_code.as_deref() == Some("timeout"))
        .count();
    b.figures.insert("admitted".to_string(), (finished + timed_out) as f64);
    b.figures.insert("admitted_finished".to_string(), finished as f64);
    if timed_out > 0 {
        b.notes.push(format!(
            "{timed_out} of {} admitted renders timed out at the budget",
            finished + timed_out
        ));
    }
    outcome("render_burst_admitted", b.statuses, b.figures, b.notes)
}

/// What a burst left behind: its answers, their statuses, the figures (how long the
/// burst took to be answered, how long until an uncached request succeeded) and what
/// went wrong.
struct BurstResult {
    answers: Vec<Answer>,
    statuses: BTreeMap<String, u64>,
    figures: BTreeMap<String, f64>,
    notes: Vec<String>,
}

/// Sends `urls` at once, then measures how soon the server serves an uncached
/// request again (within 2 × the budget, else a note).
fn burst_and_recover(o: &AttackOptions, client: &reqwest::blocking::Client, urls: &[String]) -> BurstResult {
    let started = Instant::now();
    let answers = burst(client, urls);
    let answered_s = started.elapsed().as_secs_f64();
    let mut notes = Vec::new();
    let statuses = tally(&answers, &mut notes);
    let limit = Duration::from_secs_f64(6.0 * o.budget_s);
    let rec = recovery(o, client, started, limit);
    match rec {
        Some(s) if s <= 2.0 * o.budget_s => {}
        Some(s) => notes.push(format!(
            "recovery took {s:.1} s, more than 2 × the {} s budget",
            o.budget_s
        )),
        None => notes.push(format!(
            "no uncached request succeeded within {:.0} s",
            6.0 * o.budget_s
        )),
    }
    let figures = BTreeMap::from([
        ("burst_answered_s".to_string(), answered_s),
        ("recovery_s".to_string(), rec.unwrap_or(f64::INFINITY)),
    ]);
    BurstResult {
        answers,
        statuses,
        figures,
        notes,
    }
}

/// The default `limits.max_response_bytes`: no answer of the scenario may be larger.
const MAX_ANSWER_BYTES: u64 = 64 << 20;

/// `billboards.json?quality=accurate` of cloudy tiles: the answer stays within the
/// response limit (413 pointing to billboards.bin when the list is larger).
fn amplification(o: &AttackOptions, client: &reqwest::blocking::Client) -> AttackOutcome {
    let urls: Vec<String> = (0..2)
        .map(|i| {
            format!(
                "{}/v1/worlds/{}/tiles/0/{i}/0/billboards.json?t=43200&quality=accurate",
                o.target, o.world
            )
        })
        .collect();
    let mut notes = Vec::new();
    // As an attacker would: retry a 503 after its Retry-After until the answer comes.
    let limit = Duration::from_secs_f64(6.0 * o.budget_s);
    let answers: Vec<Answer> = urls
        .iter()
        .map(|u| {
            let started = Instant::now();
            loop {
                let a = get(client, u);
                if a.status != Some(503) || started.elapsed() > limit {
                    return a;
                }
                std::thread::sleep(Duration::from_secs(a.retry_after.unwrap_or(1).clamp(1, 10) as u64));
            }
        })
        .collect();
    let statuses = tally(&answers, &mut notes);
    let request_bytes = urls.iter().map(|u| u.len() - o.target.len()).max().unwrap_or(1) as f64;
    let largest = answers.iter().map(|a| a.body_bytes).max().unwrap_or(0) as f64;
    if largest > MAX_ANSWER_BYTES as f64 {
        notes.push(format!(
            "a {request_bytes}-byte request got a {:.0} MB answer, over the default 64 MiB response limit",
            largest / 1e6
        ));
    }
    let figures = BTreeMap::from([
        ("largest_answer_bytes".to_string(), largest),
        ("bytes_out_per_byte_in".to_string(), largest / request_bytes),
    ]);
    outcome("amplification", statuses, figures, notes)
}

/// Clients of the crawl.
const CRAWL_CLIENTS: usize = 6;

/// The crawl's request `i` of run `salt`: a tile of a random seed world at a random
/// level, place, time, product and quality (SplitMix64 of the index: a run replays).
fn crawl_url(o: &AttackOptions, salt: u64, i: u64) -> String {
    let mut state = salt ^ i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let mut next = || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    const PRODUCTS: [&str; 6] = [
        "billboards.bin",
        "shadow.png",
        "density.u8",
        "coverage.png",
        "billboards.json",
        "atlas.png",
    ];
    const LEVELS: [u32; 7] = [0, 0, 0, 1, 1, 2, 3];
    const QUALITIES: [&str; 3] = ["fast", "balanced", "accurate"];
    let seed = next() % 1_000_000_000_000 + 1;
    let z = LEVELS[(next() % 7) as usize];
    let (x, y) = ((next() % 40) as i64 - 20, (next() % 40) as i64 - 20);
    let t = next() % 1_000_000_000;
    let product = PRODUCTS[(next() % 6) as usize];
    let quality = QUALITIES[(next() % 3) as usize];
    format!(
        "{}/v1/worlds/{seed}/tiles/{z}/{x}/{y}/{product}?t={t}&quality={quality}",
        o.target
    )
}

/// One metric of the server's `/metrics` (the sum of its samples whose labels include
/// `labels`); `None` when it cannot be read.
fn server_metric(o: &AttackOptions, client: &reqwest::blocking::Client, name: &str, label: &str) -> Option<f64> {
    let text = client.get(format!("{}/metrics", o.target)).send().ok()?.text().ok()?;
    let mut sum = None;
    for line in text.lines().filter(|l| !l.starts_with('#')) {
        let (series, value) = line.rsplit_once(' ')?;
        let (metric, labels) = series.split_once('{').unwrap_or((series, ""));
        if metric == name && labels.contains(label) {
            *sum.get_or_insert(0.0) += value.parse::<f64>().ok()?;
        }
    }
    sum
}

/// The crawl: `o.crawl` new tiles, then quiet; the server's memory through both.
fn crawl(o: &AttackOptions, client: &reqwest::blocking::Client) -> AttackOutcome {
    let mut notes = Vec::new();
    let mut figures = BTreeMap::new();
    if o.crawl == 0 {
        figures.insert("requests".to_string(), 0.0);
        return outcome("crawl", BTreeMap::new(), figures, notes);
    }
    let salt = salt();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let answers = std::sync::Mutex::new(Vec::new());
    let rss_mib = |pid: u32| process_memory_kb(pid).map(|(rss, hwm)| (rss as f64 / 1024.0, hwm as f64 / 1024.0));
    let ahead_before = server_metric(o, client, "cloudscape_ahead_computed_total", "").unwrap_or(0.0);
    let started = Instant::now();
    let mut peak_rss = 0.0f64;
    std::thread::scope(|s| {
        let workers: Vec<_> = (0..CRAWL_CLIENTS)
            .map(|_| {
                s.spawn(|| {
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        if i >= o.crawl {
                            return;
                        }
                        let url = crawl_url(o, salt, i as u64);
                        // As a crawler: a 503 is retried after its Retry-After (at
                        // most 2 s, 8 times).
                        let mut a = get(client, &url);
                        for _ in 0..8 {
                            if a.status != Some(503) {
                                break;
                            }
                            std::thread::sleep(Duration::from_secs(a.retry_after.unwrap_or(1).clamp(1, 2) as u64));
                            a = get(client, &url);
                        }
                        answers.lock().unwrap_or_else(|e| e.into_inner()).push(a);
                    }
                })
            })
            .collect();
        while workers.iter().any(|w| !w.is_finished()) {
            if let Some((rss, _)) = o.pid.and_then(rss_mib) {
                peak_rss = peak_rss.max(rss);
            }
            if o.progress {
                eprint!(
                    "\rcrawl: {} of {} requests, RSS {:.0} MiB",
                    next.load(std::sync::atomic::Ordering::Relaxed).min(o.crawl),
                    o.crawl,
                    peak_rss
                );
            }
            std::thread::sleep(Duration::from_millis(500));
        }
    });
    if o.progress {
        eprintln!();
    }
    let answers = answers.into_inner().unwrap_or_else(|e| e.into_inner());
    let statuses = tally(&answers, &mut notes);
    figures.insert("requests".to_string(), answers.len() as f64);
    figures.insert("seconds".to_string(), started.elapsed().as_secs_f64());
    let ahead = server_metric(o, client, "cloudscape_ahead_computed_total", "").unwrap_or(0.0) - ahead_before;
    figures.insert("ahead_computed".to_string(), ahead);
    if let Some((rss, hwm)) = o.pid.and_then(rss_mib) {
        figures.insert("rss_end_mib".to_string(), rss);
        figures.insert("peak_rss_mib".to_string(), hwm.max(peak_rss));
    }
    for what in ["allocated", "resident"] {
        if let Some(v) = server_metric(o, client, "cloudscape_allocator_bytes", &format!("what=\"{what}\"")) {
            figures.insert(format!("allocator_{what}_mib"), v / 1048576.0);
        }
    }
    // Quiet: what does the server give back?
    std::thread::sleep(Duration::from_secs_f64(o.crawl_idle_s));
    if let Some((rss, _)) = o.pid.and_then(rss_mib) {
        figures.insert("rss_idle_mib".to_string(), rss);
    }
    if let Some(v) = server_metric(o, client, "cloudscape_allocator_bytes", "what=\"resident\"") {
        figures.insert("allocator_resident_idle_mib".to_string(), v / 1048576.0);
    }
    if let Some(peak) = figures.get("peak_rss_mib")
        && *peak > o.rss_limit_mib as f64
    {
        notes.push(format!(
            "the server's RSS peaked at {peak:.0} MiB, over the {} MiB bound",
            o.rss_limit_mib
        ));
    }
    outcome("crawl", statuses, figures, notes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_loopback_targets_are_attacked() {
        for ok in [
            "http://127.0.0.1:8080",
            "http://127.3.4.5:1/",
            "http://localhost:9",
            "http://[::1]:8080",
        ] {
            assert!(is_loopback_target(ok), "{ok}");
        }
        for bad in [
            "http://10.0.0.1:8080",
            "http://192.168.1.2",
            "http://example.com:80",
            "https://127.0.0.1:8080",
            "127.0.0.1:8080",
            "http://[::2]:80",
        ] {
            assert!(!is_loopback_target(bad), "{bad}");
        }
    }
}
