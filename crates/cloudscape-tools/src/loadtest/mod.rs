//! The load generator behind `cloudscape loadtest`: simulated MMO players and game
//! servers against a running cloudscape, measured with an HDR histogram.
//!
//! Engine: reqwest (async, on a tokio runtime) + `hdrhistogram`, not goose: the workload
//! is stateful per client (a player plans its view with the renderer's level choice
//! and revalidates the ETags it holds), which is plain Rust here; goose would bring its
//! own CLI, scheduler and report, and a large dependency tree, for little of that.
//!
//! Two loops:
//! - **closed** (default): every agent sends its requests one after another, then waits
//!   for its next tick ([`workload::TICK_SECONDS`]); latency is from send to answer.
//! - **open** (`rate`): requests leave on a fixed schedule (request *i* at *i / rate*
//!   seconds) whatever the server does, taken round-robin from the agents. Latency is
//!   measured from the *intended* send time, so a stalled server is charged for the
//!   requests it kept from being sent (coordinated-omission correction, as in wrk2).
//!
//! The server's response-cache hit ratio is read from its `/metrics` before and after.

pub mod record;
pub mod workload;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;
use tokio::sync::Semaphore;

use cloudscape_client::RemoteWorld;

use self::record::{BoundaryLatency, Counts, Latency, Outcome, Recorder, SecondSummary};
pub use self::workload::FetchMode;
use self::workload::{Agent, GROUP_SIZE, GameServer, GroupPath, Player, RequestKind, Role, TICK_SECONDS, WorldView};

/// Most requests in flight in the open loop; past it the schedule waits (and the wait
/// counts in the latency, which is measured from the intended send time).
const MAX_IN_FLIGHT: usize = 1024;
/// Longest a closed-loop agent backs off after a 503.
const MAX_BACKOFF: Duration = Duration::from_secs(1);
/// The client's timeout for one request.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(30);

/// Which clients the run simulates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scenario {
    /// Players in groups fetching the tiles their views need.
    Mmo,
    /// Game servers asking `/region` and `/series` questions.
    Queries,
    /// Players, and one game server per group of players.
    Mixed,
}

impl Scenario {
    pub fn parse(s: &str) -> Option<Scenario> {
        match s {
            "mmo" => Some(Scenario::Mmo),
            "queries" => Some(Scenario::Queries),
            "mixed" => Some(Scenario::Mixed),
            _ => None,
        }
    }
}

/// What to run.
#[derive(Clone, Debug)]
pub struct LoadSpec {
    /// `http://host:port` of the server.
    pub target: String,
    /// World name or seed the clients use.
    pub world: String,
    /// Players (mmo, mixed) or game servers (queries).
    pub players: usize,
    /// How long the run is measured (after the warm-up).
    pub duration: Duration,
    /// Which clients the run simulates.
    pub scenario: Scenario,
    /// Requests per second for the open loop; `None` for the closed loop.
    pub rate: Option<f64>,
    /// World-clock seconds at the start.
    pub t0: f64,
    /// World seconds per real second (0 freezes the clock: every tick revalidates).
    pub clock: f64,
    /// Seed of the players' paths and views.
    pub seed: u64,
    /// How players fetch: keyframes (as the viewer) or polling every tick.
    pub fetch: FetchMode,
    /// Groups share this many places (paths) when set: more players, same tiles.
    pub places: Option<usize>,
    /// The server's process id, to read its CPU time from /proc when its /metrics has
    /// no `process_cpu_seconds_total`.
    pub server_pid: Option<u32>,
    /// Requests are sent from the start but only those sent after this long are
    /// measured (the players' first views, all cold, are warm-up).
    pub warmup: Duration,
}

/// What went wrong before or around the run (failed requests during it are counted, not errors).
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error("the target must look like http://HOST:PORT, got `{0}`")]
    BadTarget(String),
    #[error("cannot read {url}: {message}")]
    Discovery { url: String, message: String },
    #[error("{0}")]
    Spec(String),
    #[error("cannot start the load generator: {0}")]
    Runtime(String),
}

/// The server's response-cache counters (`cloudscape_cache_{hits,misses}_total`, summed
/// over kinds) over the run.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct CacheFigures {
    pub hits: u64,
    pub misses: u64,
    /// hits / (hits + misses); `None` when the server made no lookup. 304s answered
    /// from the ETag alone are not lookups.
    pub hit_ratio: Option<f64>,
}

/// What the server did during the run, from its `/metrics` before and after (and its
/// CPU time from /proc when a pid is given).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct ServerFigures {
    /// Computations run (`cloudscape_computations_total`).
    pub computations: u64,
    /// Their compute time (`cloudscape_compute_duration_seconds_sum`), seconds.
    pub compute_seconds: f64,
    /// What the server computed ahead of the players (`ahead_*` in the report).
    #[serde(flatten)]
    pub ahead: AheadFigures,
    /// Server CPU time over the run, seconds.
    pub cpu_seconds: Option<f64>,
    /// The same as a share of the run's wall time (1.0 = one core busy).
    pub cpu_cores: Option<f64>,
}

/// The server's compute-ahead over the run (`cloudscape_ahead_*`): keyframes computed
/// before players asked for them, and how well that kept up.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct AheadFigures {
    /// Keyframes computed ahead.
    #[serde(rename = "ahead_computed")]
    pub computed: u64,
    /// Requests served from them.
    #[serde(rename = "ahead_served")]
    pub served: u64,
    /// Planned computations ahead that were missed.
    #[serde(rename = "ahead_missed")]
    pub missed: u64,
    /// Mean lag of the computations ahead that finished late, s; `None` when all were
    /// in time.
    #[serde(rename = "ahead_mean_lag_s")]
    pub mean_lag_s: Option<f64>,
}

/// A scrape of the server's /metrics.
struct Scrape {
    text: String,
    cpu: Option<f64>,
}

impl Scrape {
    fn sum(&self, name: &str) -> f64 {
        metric_sum(&self.text, name).unwrap_or(0.0)
    }

    /// How much the counter `name` grew from `before` to this scrape (0 if the
    /// server restarted in between).
    fn increase_since(&self, before: &Scrape, name: &str) -> f64 {
        (self.sum(name) - before.sum(name)).max(0.0)
    }
}

/// Sums the samples of a Prometheus metric family in text exposition.
pub fn metric_sum(metrics: &str, name: &str) -> Option<f64> {
    let mut found = false;
    let mut sum = 0f64;
    for line in metrics.lines() {
        let Some(rest) = line.strip_prefix(name) else {
            continue;
        };
        if !(rest.starts_with('{') || rest.starts_with(' ')) {
            continue;
        }
        if let Some(v) = rest.rsplit(' ').next().and_then(|v| v.parse::<f64>().ok()) {
            found = true;
            sum += v;
        }
    }
    found.then_some(sum)
}

/// CPU seconds (user + system) of process `pid` so far, from /proc.
fn proc_cpu_seconds(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces) in parentheses.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    // SAFETY: sysconf only reads a configuration value.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    (hz > 0).then(|| ticks / hz as f64)
}

async fn scrape(http: &reqwest::Client, base: &str, pid: Option<u32>) -> Option<Scrape> {
    let text = http
        .get(format!("{base}/metrics"))
        .send()
        .await
        .ok()?
        .text()
        .await
        .ok()?;
    let cpu = metric_sum(&text, "process_cpu_seconds_total").or_else(|| pid.and_then(proc_cpu_seconds));
    Some(Scrape { text, cpu })
}

fn cache_figures(before: &Scrape, after: &Scrape) -> CacheFigures {
    let d = |name| after.increase_since(before, name) as u64;
    let (hits, misses) = (d("cloudscape_cache_hits_total"), d("cloudscape_cache_misses_total"));
    CacheFigures {
        hits,
        misses,
        hit_ratio: (hits + misses > 0).then(|| hits as f64 / (hits + misses) as f64),
    }
}

fn server_figures(before: &Scrape, after: &Scrape, elapsed_s: f64) -> ServerFigures {
    let d = |name| after.increase_since(before, name);
    let late = d("cloudscape_ahead_lag_seconds_count");
    let cpu = match (before.cpu, after.cpu) {
        (Some(b), Some(a)) => Some((a - b).max(0.0)),
        _ => None,
    };
    ServerFigures {
        computations: d("cloudscape_computations_total") as u64,
        compute_seconds: d("cloudscape_compute_duration_seconds_sum"),
        ahead: AheadFigures {
            computed: d("cloudscape_ahead_computed_total") as u64,
            served: d("cloudscape_ahead_served_total") as u64,
            missed: d("cloudscape_ahead_missed_total") as u64,
            mean_lag_s: (late > 0.0).then(|| d("cloudscape_ahead_lag_seconds_sum") / late),
        },
        cpu_seconds: cpu,
        cpu_cores: cpu.map(|c| c / elapsed_s.max(1e-9)),
    }
}

/// The outcome of a run; `cloudscape loadtest --json` writes it.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// `http://host:port` of the server, and the world the clients asked for.
    pub target: String,
    pub world: String,
    /// The clients simulated and how players fetched ([`LoadSpec`]).
    pub scenario: Scenario,
    pub fetch: FetchMode,
    /// `closed` or `open`.
    pub mode: &'static str,
    /// Requested rate (open loop).
    pub rate: Option<f64>,
    /// Simulated players and game servers.
    pub players: usize,
    pub game_servers: usize,
    /// Requested duration, seconds.
    pub duration_s: f64,
    /// From the first request to the last answer, seconds.
    pub elapsed_s: f64,
    /// Answers (of any status) per second of `elapsed_s`.
    pub throughput_rps: f64,
    /// Answers by outcome, all requests.
    pub totals: Counts,
    /// Latency of all measured requests.
    pub latency: Latency,
    /// Count by HTTP status.
    pub status: std::collections::BTreeMap<String, u64>,
    /// Answers by outcome, per kind of request.
    pub by_kind: std::collections::BTreeMap<RequestKind, Counts>,
    /// Share of tile and splat answers that were 304 (the held ETag was still good).
    pub revalidated_ratio: Option<f64>,
    /// Body bytes received.
    pub body_bytes: u64,
    /// From the server's /metrics; `None` when it could not be read.
    pub cache: Option<CacheFigures>,
    /// What the server computed and how busy it was; `None` when /metrics could not be read.
    pub server: Option<ServerFigures>,
    /// Latency just after level-0 keyframe boundaries against the rest.
    pub boundary: BoundaryLatency,
    /// Per second of the measured run.
    pub timeline: Vec<SecondSummary>,
    /// (quantile, ms): the HDR percentile distribution.
    pub distribution: Vec<(f64, f64)>,
    /// The first transport error, if any.
    pub first_error: Option<String>,
}

/// Progress while the run goes: seconds elapsed and answers so far.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    pub elapsed_s: f64,
    pub requests: u64,
    pub shed: u64,
}

/// State every worker shares.
struct Shared {
    world: WorldView,
    paths: Mutex<Vec<GroupPath>>,
    recorder: Mutex<Recorder>,
    http: reqwest::Client,
    base: String,
    start: Instant,
    deadline: Instant,
    /// Requests sent before this are not measured.
    measure_from: Instant,
}

impl Shared {
    fn seconds(&self, at: Instant) -> f64 {
        at.saturating_duration_since(self.start).as_secs_f64()
    }
}

/// Checks `http://host:port` and returns it without a trailing slash.
pub fn parse_target(target: &str) -> Result<String, LoadError> {
    let base = target.trim_end_matches('/');
    match base.strip_prefix("http://") {
        Some(rest) if !rest.is_empty() && !rest.contains('/') => Ok(base.to_string()),
        _ => Err(LoadError::BadTarget(target.to_string())),
    }
}

impl LoadSpec {
    fn check(&self) -> Result<(), LoadError> {
        if self.players == 0 || self.players > 100_000 {
            return Err(LoadError::Spec(format!(
                "--players must be between 1 and 100000, got {}",
                self.players
            )));
        }
        if self.duration.is_zero() || self.duration > Duration::from_secs(7 * 86_400) {
            return Err(LoadError::Spec(
                "--duration must be more than 0 s and at most a week".into(),
            ));
        }
        if let Some(r) = self.rate
            && !(r.is_finite() && r > 0.0 && r <= 1e6)
        {
            return Err(LoadError::Spec(format!(
                "--rate must be a number of requests per second in (0, 1e6], got {r}"
            )));
        }
        if !(self.t0.is_finite() && (0.0..=1e12).contains(&self.t0)) {
            return Err(LoadError::Spec(format!("--t must be in [0, 1e12], got {}", self.t0)));
        }
        if !(self.clock.is_finite() && (0.0..=1e6).contains(&self.clock)) {
            return Err(LoadError::Spec(format!(
                "--clock must be in [0, 1e6], got {}",
                self.clock
            )));
        }
        Ok(())
    }
}

/// Sends one request; returns the outcome (latency from `from`) and the ETag and
/// `Retry-After` of the answer.
async fn send(shared: &Shared, req: &workload::Request, from: Instant) -> (Outcome, Option<String>, Option<Duration>) {
    let mut builder = shared.http.get(format!("{}{}", shared.base, req.path));
    if let Some(e) = &req.etag {
        builder = builder.header(reqwest::header::IF_NONE_MATCH, e.as_str());
    }
    let result = async {
        let response = builder.send().await?;
        let status = response.status().as_u16();
        let header = |name| {
            response
                .headers()
                .get(name)
                .and_then(|v: &reqwest::header::HeaderValue| v.to_str().ok())
                .map(str::to_string)
        };
        let etag = header(reqwest::header::ETAG);
        let retry = header(reqwest::header::RETRY_AFTER)
            .and_then(|v| v.trim().parse::<f64>().ok())
            .map(|s| Duration::from_secs_f64(s.clamp(0.0, 3600.0)));
        let body = response.bytes().await?;
        Ok::<_, reqwest::Error>((status, etag, retry, body.len() as u64))
    }
    .await;
    let done = Instant::now();
    let micros = done.saturating_duration_since(from).as_micros() as u64;
    // The timeline counts from the end of the warm-up.
    let at = done.saturating_duration_since(shared.measure_from).as_secs_f64();
    let after_boundary = shared.world.just_after_boundary(shared.seconds(from));
    match result {
        Ok((status, etag, retry, bytes)) => (
            Outcome {
                kind: req.kind,
                status: Some(status),
                at,
                micros,
                bytes,
                after_boundary,
            },
            (status == 200).then_some(etag).flatten(),
            (status == 503).then_some(retry).flatten(),
        ),
        Err(e) => {
            let mut rec = shared.recorder.lock().unwrap();
            if rec.first_error.is_none() {
                rec.first_error = Some(format!("{}{}: {e}", shared.base, req.path));
            }
            (
                Outcome {
                    kind: req.kind,
                    status: None,
                    at,
                    micros,
                    bytes: 0,
                    after_boundary,
                },
                None,
                None,
            )
        }
    }
}

/// One agent of the closed loop: a tick's requests back to back, then wait for the next tick.
async fn closed_agent(shared: Arc<Shared>, mut agent: Agent, phase: f64) {
    let tick = Duration::from_secs_f64(TICK_SECONDS);
    let mut next_tick = shared.start + Duration::from_secs_f64(phase * TICK_SECONDS);
    tokio::time::sleep_until(next_tick.into()).await;
    while Instant::now() < shared.deadline {
        let s = shared.seconds(Instant::now());
        agent.plan(&shared.world, &mut shared.paths.lock().unwrap(), s);
        while let Some(req) = agent.next_request() {
            if Instant::now() >= shared.deadline {
                return;
            }
            let sent = Instant::now();
            let (outcome, etag, retry) = send(&shared, &req, sent).await;
            if sent >= shared.measure_from {
                shared.recorder.lock().unwrap().record(outcome);
            }
            agent.answered(&req, etag);
            if outcome.status == Some(503) || outcome.status.is_none() {
                let wait = retry.unwrap_or(MAX_BACKOFF).min(MAX_BACKOFF);
                tokio::time::sleep(wait).await;
            }
        }
        next_tick += tick;
        let now = Instant::now();
        if next_tick < now {
            // Behind: the next tick starts now (a closed loop cannot catch up).
            next_tick = now;
        }
        tokio::time::sleep_until(next_tick.into()).await;
    }
}

/// The open loop: request i leaves at i / rate, round-robin over the agents.
async fn open_loop(shared: Arc<Shared>, agents: Vec<Arc<Mutex<Agent>>>, rate: f64) {
    let slots = Arc::new(Semaphore::new(MAX_IN_FLIGHT));
    let mut tasks = tokio::task::JoinSet::new();
    for i in 0u64.. {
        let intended = shared.start + Duration::from_secs_f64(i as f64 / rate);
        if intended >= shared.deadline {
            break;
        }
        tokio::time::sleep_until(intended.into()).await;
        let agent = agents[(i % agents.len() as u64) as usize].clone();
        let req = {
            let mut a = agent.lock().unwrap();
            if a.idle() {
                a.plan(
                    &shared.world,
                    &mut shared.paths.lock().unwrap(),
                    shared.seconds(intended),
                );
            }
            a.next_request()
        };
        let Some(req) = req else { continue };
        let permit = slots
            .clone()
            .acquire_owned()
            .await
            .expect("the semaphore is never closed");
        let shared = shared.clone();
        tasks.spawn(async move {
            let (outcome, etag, _) = send(&shared, &req, intended).await;
            if intended >= shared.measure_from {
                shared.recorder.lock().unwrap().record(outcome);
            }
            agent.lock().unwrap().answered(&req, etag);
            drop(permit);
        });
        // Reap finished tasks so the set does not grow with the run.
        while tasks.try_join_next().is_some() {}
    }
    while tasks.join_next().await.is_some() {}
}

/// Runs the load test. `progress` is called about five times a second.
pub fn run(spec: &LoadSpec, mut progress: impl FnMut(Progress)) -> Result<Report, LoadError> {
    spec.check()?;
    let base = parse_target(&spec.target)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| LoadError::Runtime(e.to_string()))?;
    let http = reqwest::Client::builder()
        .no_proxy()
        .timeout(REQUEST_TIMEOUT)
        .pool_max_idle_per_host(MAX_IN_FLIGHT)
        // Keyframe players stay quiet for seconds; the server closes a connection idle
        // for 5 s, so the pool lets go of it first (a request on a closing connection
        // would count as a transport error).
        .pool_idle_timeout(std::time::Duration::from_secs(4))
        .build()
        .map_err(|e| LoadError::Runtime(e.to_string()))?;
    runtime.block_on(async move {
        let url = format!("{base}/v1/worlds/{}", spec.world);
        let discovery = |message: String| LoadError::Discovery {
            url: url.clone(),
            message,
        };
        let response = http.get(&url).send().await.map_err(|e| discovery(e.to_string()))?;
        let status = response.status();
        let text = response.text().await.map_err(|e| discovery(e.to_string()))?;
        if !status.is_success() {
            return Err(discovery(format!("status {status}: {}", text.trim())));
        }
        let remote: RemoteWorld =
            serde_json::from_str(&text).map_err(|e| discovery(format!("not a world description: {e}")))?;
        if remote.layers.is_empty() {
            return Err(discovery("the world has no layers".into()));
        }
        let world = WorldView::new(&remote, spec.t0, spec.clock);

        let (players, servers) = match spec.scenario {
            Scenario::Mmo => (spec.players, 0),
            Scenario::Queries => (0, spec.players),
            Scenario::Mixed => (spec.players, spec.players.div_ceil(GROUP_SIZE)),
        };
        let groups = spec.players.div_ceil(GROUP_SIZE).max(1);
        // With `places`, group g walks the path of place g mod places.
        let places = spec.places.map_or(groups, |p| p.clamp(1, groups));
        let mut agents: Vec<Agent> = (0..players)
            .map(|i| Agent::new(Role::Player(Player::new(i, spec.seed, spec.fetch))))
            .collect();
        agents.extend((0..servers).map(|i| Agent::new(Role::GameServer(GameServer::new(i)))));

        let start = Instant::now();
        let shared = Arc::new(Shared {
            world,
            paths: Mutex::new(
                (0..groups)
                    .map(|g| GroupPath::new(g % places, places, spec.seed))
                    .collect(),
            ),
            recorder: Mutex::new(Recorder::default()),
            http: http.clone(),
            base: base.clone(),
            start,
            deadline: start + spec.warmup + spec.duration,
            measure_from: start + spec.warmup,
        });

        let work = {
            let shared = shared.clone();
            let n = agents.len();
            let rate = spec.rate;
            tokio::spawn(async move {
                match rate {
                    Some(rate) => {
                        open_loop(
                            shared,
                            agents.into_iter().map(|a| Arc::new(Mutex::new(a))).collect(),
                            rate,
                        )
                        .await
                    }
                    None => {
                        let mut set = tokio::task::JoinSet::new();
                        for (i, a) in agents.into_iter().enumerate() {
                            // Agents start spread over the first tick, as clients that joined at different times.
                            set.spawn(closed_agent(shared.clone(), a, i as f64 / n as f64));
                        }
                        while set.join_next().await.is_some() {}
                    }
                }
            })
        };
        let before = {
            tokio::time::sleep_until(shared.measure_from.into()).await;
            scrape(&http, &base, spec.server_pid).await
        };
        let mut ticker = tokio::time::interval(Duration::from_millis(200));
        tokio::pin!(work);
        loop {
            tokio::select! {
                r = &mut work => {
                    r.map_err(|e| LoadError::Runtime(format!("a worker failed: {e}")))?;
                    break;
                }
                _ = ticker.tick() => {
                    let rec = shared.recorder.lock().unwrap();
                    progress(Progress {
                        elapsed_s: shared.measure_from.elapsed().as_secs_f64(),
                        requests: rec.totals().requests,
                        shed: rec.totals().shed,
                    });
                }
            }
        }
        let elapsed = shared.measure_from.elapsed().as_secs_f64();
        let after = scrape(&http, &base, spec.server_pid).await;
        let rec = shared.recorder.lock().unwrap();
        progress(Progress {
            elapsed_s: elapsed,
            requests: rec.totals().requests,
            shed: rec.totals().shed,
        });
        let (cache, server) = match (&before, &after) {
            (Some(b), Some(a)) => (Some(cache_figures(b, a)), Some(server_figures(b, a, elapsed))),
            _ => (None, None),
        };
        let by_kind = rec.by_kind();
        let (fetched, revalidated) = by_kind
            .iter()
            .filter(|(k, _)| matches!(k, RequestKind::Tile | RequestKind::Prefetch | RequestKind::Splats))
            .fold((0, 0), |(f, r), (_, c)| (f + c.ok, r + c.not_modified));
        Ok(Report {
            target: base.clone(),
            world: spec.world.clone(),
            scenario: spec.scenario,
            fetch: spec.fetch,
            mode: if spec.rate.is_some() { "open" } else { "closed" },
            rate: spec.rate,
            players,
            game_servers: servers,
            duration_s: spec.duration.as_secs_f64(),
            elapsed_s: elapsed,
            throughput_rps: rec.totals().requests as f64 / elapsed.max(1e-9),
            totals: rec.totals().clone(),
            latency: rec.latency(),
            status: rec.statuses(),
            by_kind,
            revalidated_ratio: (fetched + revalidated > 0).then(|| revalidated as f64 / (fetched + revalidated) as f64),
            body_bytes: rec.bytes(),
            cache,
            server,
            boundary: rec.boundary_latency(),
            timeline: rec.timeline(),
            distribution: rec.distribution(),
            first_error: rec.first_error.clone(),
        })
    })
}

/// The players of each step of a capacity sweep, until p99 passes the target: 8, 16,
/// 32, … doubling to 256, then steps of 128 up to 2048.
pub fn sweep_steps() -> Vec<usize> {
    let mut steps: Vec<usize> = (3..=8).map(|e| 1usize << e).collect();
    steps.extend((3..=16).map(|i| i * 128));
    steps
}

/// The p99 a capacity step must stay within, milliseconds.
pub const SWEEP_P99_MS: f64 = 50.0;

/// One step of a capacity sweep.
#[derive(Clone, Debug, Serialize)]
pub struct SweepStep {
    /// Players of the step.
    pub players: usize,
    /// Answers per second (the step's [`Report::throughput_rps`]).
    pub throughput_rps: f64,
    /// Latency of the step's measured requests, milliseconds.
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    /// Requests shed with 503.
    pub shed: u64,
    /// p99 in the first second after a level-0 keyframe boundary, and elsewhere.
    pub boundary_p99_ms: f64,
    pub elsewhere_p99_ms: f64,
    /// What the server computed and how busy it was; `None` when /metrics could not be read.
    pub server: Option<ServerFigures>,
    /// Body bytes per second received.
    pub bytes_per_s: f64,
    /// Within [`SWEEP_P99_MS`] and no 503.
    pub holds: bool,
}

/// A capacity sweep: the steps run, and the most players a step held.
#[derive(Clone, Debug, Serialize)]
pub struct SweepReport {
    /// The server, world, fetch mode and world clock every step ran with ([`LoadSpec`]).
    pub target: String,
    pub world: String,
    pub fetch: FetchMode,
    pub clock: f64,
    /// Measured seconds of each step, after its warm-up.
    pub step_s: f64,
    /// Warm-up seconds of each step.
    pub warmup_s: f64,
    /// The steps run, in order.
    pub steps: Vec<SweepStep>,
    /// The most players a step held; `None` when the first step did not.
    pub capacity: Option<usize>,
}

/// Raises the number of players step by step ([`sweep_steps`], or `steps`) until a
/// step's p99 passes [`SWEEP_P99_MS`] or any request is shed, or (`every_step`)
/// through all of `steps`, for a whole curve. Each step is a run of `spec` with that
/// many players; the world clock runs on from one step to the next, so no step finds
/// the previous one's keyframes.
pub fn sweep(
    spec: &LoadSpec,
    steps: &[usize],
    every_step: bool,
    mut progress: impl FnMut(usize, Progress),
) -> Result<SweepReport, LoadError> {
    let mut out = Vec::new();
    let mut t0 = spec.t0;
    for &players in steps {
        let step = LoadSpec {
            players,
            t0: t0.min(1e12),
            ..spec.clone()
        };
        let r = run(&step, |p| progress(players, p))?;
        t0 += spec.clock * (spec.warmup + spec.duration).as_secs_f64();
        let holds = r.latency.p99_ms <= SWEEP_P99_MS && r.totals.shed == 0 && r.totals.transport_errors == 0;
        out.push(SweepStep {
            players,
            throughput_rps: r.throughput_rps,
            p50_ms: r.latency.p50_ms,
            p99_ms: r.latency.p99_ms,
            max_ms: r.latency.max_ms,
            shed: r.totals.shed,
            boundary_p99_ms: r.boundary.after_boundary.p99_ms,
            elsewhere_p99_ms: r.boundary.elsewhere.p99_ms,
            server: r.server.clone(),
            bytes_per_s: r.body_bytes as f64 / r.elapsed_s.max(1e-9),
            holds,
        });
        if !holds && !every_step {
            break;
        }
    }
    let capacity = out.iter().take_while(|s| s.holds).last().map(|s| s.players);
    Ok(SweepReport {
        target: spec.target.clone(),
        world: spec.world.clone(),
        fetch: spec.fetch,
        clock: spec.clock,
        step_s: spec.duration.as_secs_f64(),
        warmup_s: spec.warmup.as_secs_f64(),
        steps: out,
        capacity,
    })
}

impl SweepReport {
    /// The curve as a Markdown table (what `--sweep` prints and writes to BENCHMARKS.md).
    pub fn markdown(&self) -> String {
        let mut md = format!(
            "`cloudscape loadtest --sweep` against `{}`, world `{}`: mmo scenario, groups of {GROUP_SIZE} players \
             {} m apart at the start (each group its own path, players within 300 m of its centre), players \
             fetching `{}` tiles {} (prefetching past {:.0} % of a span), world clock {} s per second. Each step: \
             {:.0} s of warm-up (the players' first views, all cold) then {:.0} s measured. A step holds when its \
             p99 ≤ {SWEEP_P99_MS} ms with no 503.\n\n\
             | players | requests/s | p50 | p99 | max | 503 | p99 after a boundary / elsewhere | server CPU | computations | ahead computed / served / missed | ahead lag | MB/s | holds |\n\
             |---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
            self.target,
            self.world,
            workload::GROUP_SPACING,
            workload::CLIENT_QUALITY.as_str(),
            match self.fetch {
                FetchMode::Keyframes => "by keyframe URL (immutable, never revalidated)",
                FetchMode::Poll => "every second at the current time, revalidating (`--poll`)",
            },
            100.0 * workload::PREFETCH_AT,
            self.clock,
            self.warmup_s,
            self.step_s,
        );
        for s in &self.steps {
            let f = s.server.clone().unwrap_or_default();
            md += &format!(
                "| {} | {:.0} | {:.1} ms | {:.1} ms | {:.0} ms | {} | {:.1} / {:.1} ms | {} | {} | {} / {} / {} | {} | {:.2} | {} |\n",
                s.players,
                s.throughput_rps,
                s.p50_ms,
                s.p99_ms,
                s.max_ms,
                s.shed,
                s.boundary_p99_ms,
                s.elsewhere_p99_ms,
                f.cpu_cores.map_or("–".into(), |c| format!("{:.0} %", 100.0 * c)),
                f.computations,
                f.ahead.computed,
                f.ahead.served,
                f.ahead.missed,
                f.ahead.mean_lag_s.map_or("–".into(), |l| format!("{l:.2} s")),
                s.bytes_per_s / 1e6,
                if s.holds { "yes" } else { "**no**" },
            );
        }
        md += &match self.capacity {
            Some(c) => format!("\nCapacity: **{c} players** held.\n"),
            None => "\nCapacity: the first step did not hold.\n".to_string(),
        };
        md
    }

    /// Players against p50 and p99, server CPU and compute-ahead lag (PNG).
    pub fn plot(&self) -> Result<Vec<u8>, String> {
        use crate::chart::{Mark, PALETTE, Panel, Series, render};
        let series = |name: &str, c: usize, f: &dyn Fn(&SweepStep) -> Option<f64>| Series {
            name: name.into(),
            points: self
                .steps
                .iter()
                .filter_map(|s| f(s).map(|v| (s.players as f64, v)))
                .collect(),
            colour: PALETTE[c],
            mark: Mark::Line,
        };
        let latency = Panel {
            title: "latency against players".into(),
            x_label: "players".into(),
            y_label: "ms".into(),
            x_log: true,
            y_log: true,
            series: vec![
                series("p50", 0, &|s| Some(s.p50_ms)),
                series("p99", 1, &|s| Some(s.p99_ms)),
                series("p99 after a boundary", 3, &|s| Some(s.boundary_p99_ms)),
                series("target", 5, &|_| Some(SWEEP_P99_MS)),
            ],
        };
        let cpu = Panel {
            title: "server CPU and compute-ahead lag".into(),
            x_label: "players".into(),
            y_label: "% of a core / lag ms".into(),
            x_log: true,
            y_log: false,
            series: vec![
                series("server CPU %", 2, &|s| s.server.as_ref()?.cpu_cores.map(|c| 100.0 * c)),
                series("ahead lag ms", 4, &|s| {
                    Some(1000.0 * s.server.as_ref()?.ahead.mean_lag_s.unwrap_or(0.0))
                }),
            ],
        };
        render(&[latency, cpu], 2, (560, 420))
    }
}

impl Report {
    /// A short human summary (what `cloudscape loadtest` prints).
    pub fn summary(&self) -> String {
        let t = &self.totals;
        let l = &self.latency;
        let mut s = format!(
            "{} {} loop against {} (world {}): {} players, {} game servers, {:.1} s\n",
            match self.scenario {
                Scenario::Mmo => "mmo",
                Scenario::Queries => "queries",
                Scenario::Mixed => "mixed",
            },
            self.mode,
            self.target,
            self.world,
            self.players,
            self.game_servers,
            self.elapsed_s
        );
        if let Some(r) = self.rate {
            s += &format!("offered rate: {r} requests/s (latency from the intended send time)\n");
        }
        s += &format!(
            "requests: {} ({:.1}/s): 200 {}, 304 {}, 503 {}, other status {}, transport errors {}\n",
            t.requests, self.throughput_rps, t.ok, t.not_modified, t.shed, t.other_status, t.transport_errors
        );
        s += &format!(
            "latency ms: p50 {:.1}  p90 {:.1}  p99 {:.1}  max {:.1}  (mean {:.1})\n",
            l.p50_ms, l.p90_ms, l.p99_ms, l.max_ms, l.mean_ms
        );
        if let Some(r) = self.revalidated_ratio {
            s += &format!("tiles revalidated (304): {:.1} %\n", 100.0 * r);
        }
        let b = &self.boundary;
        if b.after_boundary_requests > 0 {
            s += &format!(
                "p99 in the second after a keyframe boundary: {:.1} ms ({} requests); elsewhere {:.1} ms\n",
                b.after_boundary.p99_ms, b.after_boundary_requests, b.elsewhere.p99_ms
            );
        }
        if let Some(f) = &self.server {
            s += &format!(
                "server: {} computations ({:.1} s of compute){}; ahead: {} computed, {} served, {} missed{}\n",
                f.computations,
                f.compute_seconds,
                f.cpu_cores
                    .map_or(String::new(), |c| format!(", CPU {:.0} % of a core", 100.0 * c)),
                f.ahead.computed,
                f.ahead.served,
                f.ahead.missed,
                f.ahead
                    .mean_lag_s
                    .map_or(String::new(), |l| format!(", mean lag {l:.2} s")),
            );
        }
        match &self.cache {
            Some(CacheFigures {
                hits,
                misses,
                hit_ratio: Some(r),
            }) => {
                s += &format!(
                    "server cache: {hits} hits, {misses} misses, hit ratio {:.1} %\n",
                    100.0 * r
                )
            }
            Some(_) => s += "server cache: no lookups\n",
            None => s += "server cache: /metrics unreadable\n",
        }
        if let Some(e) = &self.first_error {
            s += &format!("first transport error: {e}\n");
        }
        s
    }

    /// The latency plot: latency over the run (p50, p99, max per second), answers per
    /// second by status, and the HDR percentile distribution.
    pub fn plot(&self) -> Result<Vec<u8>, String> {
        use crate::chart::{Mark, PALETTE, Panel, Series, render};
        let series = |name: &str, c: usize, f: &dyn Fn(&SecondSummary) -> f64| Series {
            name: name.into(),
            points: self.timeline.iter().map(|s| (s.second as f64 + 0.5, f(s))).collect(),
            colour: PALETTE[c],
            mark: Mark::Line,
        };
        let over_time = Panel {
            title: "latency per second of the run".into(),
            x_label: "seconds since start".into(),
            y_label: "latency, ms".into(),
            y_log: true,
            series: vec![
                series("p50", 0, &|s| s.p50_ms),
                series("p99", 1, &|s| s.p99_ms),
                series("max", 5, &|s| s.max_ms),
            ],
            ..Panel::default()
        };
        let rates = Panel {
            title: "answers per second".into(),
            x_label: "seconds since start".into(),
            y_label: "answers/s".into(),
            series: vec![
                series("200", 2, &|s| s.counts.ok as f64),
                series("304", 0, &|s| s.counts.not_modified as f64),
                series("503", 1, &|s| s.counts.shed as f64),
                series("other/errors", 4, &|s| {
                    (s.counts.other_status + s.counts.transport_errors) as f64
                }),
            ],
            ..Panel::default()
        };
        let distribution = Panel {
            title: "latency by percentile (HDR)".into(),
            x_label: "1/(1-q): 10 = p90, 100 = p99, 1000 = p99.9".into(),
            y_label: "latency, ms".into(),
            x_log: true,
            y_log: true,
            series: vec![Series {
                name: String::new(),
                points: self
                    .distribution
                    .iter()
                    .filter(|(q, _)| *q < 1.0)
                    .map(|&(q, v)| (1.0 / (1.0 - q), v))
                    .collect(),
                colour: PALETTE[0],
                mark: Mark::Line,
            }],
        };
        render(&[over_time, rates, distribution], 3, (520, 400))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counters_are_summed_over_labels_and_prefixes_do_not_match() {
        let text = "# HELP cloudscape_cache_hits_total hits\n\
            cloudscape_cache_hits_total{kind=\"tile\"} 3\n\
            cloudscape_cache_hits_total{kind=\"region\"} 4\n\
            cloudscape_cache_hits_total_other 100\n";
        assert_eq!(metric_sum(text, "cloudscape_cache_hits_total"), Some(7.0));
        assert_eq!(metric_sum(text, "cloudscape_cache_misses_total"), None);
    }

    #[test]
    fn server_figures_keep_their_flat_report_names() {
        let scrape = |text: &str| Scrape {
            text: text.into(),
            cpu: None,
        };
        let before = scrape("cloudscape_ahead_computed_total 2\ncloudscape_ahead_lag_seconds_count 0\n");
        let after = scrape(
            "cloudscape_ahead_computed_total 5\ncloudscape_ahead_lag_seconds_count 2\n\
             cloudscape_ahead_lag_seconds_sum 3\n",
        );
        let v = serde_json::to_value(server_figures(&before, &after, 1.0)).unwrap();
        assert_eq!(v["ahead_computed"], 3);
        assert_eq!(v["ahead_served"], 0);
        assert_eq!(v["ahead_mean_lag_s"], 1.5);
        assert!(v.get("ahead").is_none() && v.get("computed").is_none());
    }

    #[test]
    fn this_process_has_cpu_time() {
        let cpu = proc_cpu_seconds(std::process::id()).expect("/proc is readable");
        assert!((0.0..1e6).contains(&cpu));
        assert!(proc_cpu_seconds(u32::MAX).is_none());
    }

    #[test]
    fn targets_and_specs_are_checked() {
        assert_eq!(parse_target("http://127.0.0.1:8080/").unwrap(), "http://127.0.0.1:8080");
        assert!(parse_target("127.0.0.1:8080").is_err());
        assert!(parse_target("http://h:1/x").is_err());
        let spec = LoadSpec {
            target: "http://127.0.0.1:1".into(),
            world: "default".into(),
            players: 0,
            duration: Duration::from_secs(1),
            scenario: Scenario::Mmo,
            rate: None,
            t0: 0.0,
            clock: 1.0,
            seed: 1,
            fetch: FetchMode::Keyframes,
            places: None,
            server_pid: None,
            warmup: Duration::ZERO,
        };
        assert!(matches!(run(&spec, |_| {}), Err(LoadError::Spec(_))));
        let spec = LoadSpec {
            players: 1,
            rate: Some(f64::NAN),
            ..spec
        };
        assert!(matches!(run(&spec, |_| {}), Err(LoadError::Spec(_))));
    }
}
