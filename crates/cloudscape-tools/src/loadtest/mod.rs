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
//! The server's response-cache hit ratio and CPU time are read from its `/metrics`
//! before and after; the generator's own CPU time from `getrusage` beside it
//! ([`generator`]), and `--nice`/`--cpu` move the generator out of the server's way.
//! Players never decode what they fetch: a body is read chunk by chunk and counted.

pub mod discovery;
pub mod generator;
pub mod geometry;
pub mod record;
pub mod sharing;
pub mod workload;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;
use tokio::sync::Semaphore;

use self::discovery::{Discovery, ServerClock};
pub use self::generator::{Placement, PlacementReadBack};
pub use self::geometry::GeometryKind;
use self::geometry::{Geometry, TravelMode};
use self::record::{BoundaryLatency, Counts, Latency, Outcome, Recorder, SecondSummary};
use self::sharing::LevelSharing;
use self::workload::{Agent, GROUP_SIZE, GameServer, Player, RequestKind, Role, TICK_SECONDS, WorldView};
pub use self::workload::{FetchMode, Wire};

/// Most requests in flight in the open loop; past it the schedule waits (and the wait
/// counts in the latency, which is measured from the intended send time).
const MAX_IN_FLIGHT: usize = 1024;
/// Longest a closed-loop agent backs off after a 503.
const MAX_BACKOFF: Duration = Duration::from_secs(1);
/// The client's timeout for one request.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(30);
/// World-clock seconds at the start when neither `--t` nor the server's clock says.
pub const DEFAULT_T0: f64 = 43_200.0;

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
    /// World-clock seconds at the start; `None`: the server's clock now (from its
    /// discovery), else [`DEFAULT_T0`].
    pub t0: Option<f64>,
    /// World seconds per real second (0 freezes the clock: every tick revalidates);
    /// `None`: the server's clock rate, else 1.
    pub clock: Option<f64>,
    /// Seed of the players' itineraries and views.
    pub seed: u64,
    /// The world the groups move through.
    pub geometry: GeometryKind,
    /// Where the generator runs (`--nice`, `--cpu`).
    pub placement: Placement,
    /// How players fetch: keyframes (as the viewer) or polling every tick.
    pub fetch: FetchMode,
    /// Groups share this many places (itineraries) when set: more players, same tiles.
    pub places: Option<usize>,
    /// The server's process id, to read its CPU time from /proc when its /metrics has
    /// no `process_cpu_seconds_total`.
    pub server_pid: Option<u32>,
    /// Requests are sent from the start but only those sent after this long are
    /// measured (the players' first views, all cold, are warm-up).
    pub warmup: Duration,
    /// The preset players fetch.
    pub quality: cloudscape_core::render::Quality,
    /// The tile format players fetch.
    pub wire: Wire,
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
    #[error("{0}")]
    Placement(String),
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
    /// Keyframes of play areas kept warm (`cloudscape_warm_computed_total`).
    pub warm_computed: u64,
    /// Shaded instants tile jobs took from the keyframe before
    /// (`cloudscape_kept_shadings_total{how="reused"}`) …
    pub shadings_reused: u64,
    /// … and shaded (`{how="shaded"}`).
    pub shadings_shaded: u64,
}

impl ServerFigures {
    /// The share of shaded instants that were reused, if any was given.
    pub fn shading_reused_share(&self) -> Option<f64> {
        let all = self.shadings_reused + self.shadings_shaded;
        (all > 0).then(|| self.shadings_reused as f64 / all as f64)
    }
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

/// What the load generator itself spent, and where it ran.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct GeneratorFigures {
    /// The generator's CPU time over the measured run (user + system, all threads), s.
    pub cpu_seconds: f64,
    /// The same as a share of the run's wall time (1.0 = one core busy).
    pub cpu_cores: f64,
    /// The priority and cores it asked for and ran with, read back from the kernel.
    pub placement: PlacementReadBack,
    /// How late its own timer woke ([`record::LAG_PERIOD_MS`] apart) over the
    /// measured run: its scheduling delay, which every latency above includes. A
    /// generator starved of CPU (niced below a busy server) shows it here.
    pub lag: Latency,
}

/// Where the world clock of a run came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ClockSource {
    /// `--t` (and `--clock`) as given.
    Given,
    /// The server's discovery `clock` (its `now`, and its `rate` unless `--clock`).
    Server,
    /// Neither: t = 43 200 (noon), 1 world second per second.
    Default,
}

/// The world the groups moved through.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct GeometrySummary {
    pub kind: GeometryKind,
    /// Towns and roads (towns geometry); whether the towns are the server's warm areas.
    pub towns: usize,
    pub roads: usize,
    pub towns_from_server: bool,
    /// Groups (of [`GROUP_SIZE`] players) and how many walk, ride and fly.
    pub groups: usize,
    pub walking: usize,
    pub riding: usize,
    pub flying: usize,
}

impl GeometrySummary {
    fn new(g: &Geometry, groups: usize) -> GeometrySummary {
        let count = |m| (0..groups).filter(|&i| g.itinerary(i).mode == m).count();
        GeometrySummary {
            kind: g.kind,
            towns: g.towns.len(),
            roads: g.roads.len(),
            towns_from_server: g.towns_from_server,
            groups,
            walking: count(TravelMode::Walking),
            riding: count(TravelMode::Riding),
            flying: count(TravelMode::Flying),
        }
    }

    /// One line for the reports.
    fn describe(&self) -> String {
        match self.kind {
            GeometryKind::Spread => format!(
                "spread: {} groups {:.0} m apart at the start, each its own path at 12 m/s",
                self.groups,
                geometry::SPREAD_SPACING
            ),
            GeometryKind::Towns => format!(
                "towns: {} groups in {} {} joined by {} roads ({} walking, {} riding, {} flying)",
                self.groups,
                self.towns,
                if self.towns_from_server {
                    "warm areas of the server"
                } else {
                    "generated towns"
                },
                self.roads,
                self.walking,
                self.riding,
                self.flying
            ),
        }
    }
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

    /// [`Scrape::increase_since`] of the samples carrying `label`.
    fn increase_where(&self, before: &Scrape, name: &str, label: &str) -> f64 {
        let sum = |s: &Scrape| metric_sum_where(&s.text, name, Some(label)).unwrap_or(0.0);
        (sum(self) - sum(before)).max(0.0)
    }
}

/// Sums the samples of a Prometheus metric family in text exposition.
pub fn metric_sum(metrics: &str, name: &str) -> Option<f64> {
    metric_sum_where(metrics, name, None)
}

/// Sums the samples of a metric family whose labels include `label` (`how="reused"`),
/// or all of them for `None`.
pub fn metric_sum_where(metrics: &str, name: &str, label: Option<&str>) -> Option<f64> {
    let mut found = false;
    let mut sum = 0f64;
    for line in metrics.lines() {
        let Some(rest) = line.strip_prefix(name) else {
            continue;
        };
        if !(rest.starts_with('{') || rest.starts_with(' ')) {
            continue;
        }
        if label.is_some_and(|l| !rest.split(' ').next().is_some_and(|labels| labels.contains(l))) {
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
        warm_computed: d("cloudscape_warm_computed_total") as u64,
        shadings_reused: after.increase_where(before, "cloudscape_kept_shadings_total", "how=\"reused\"") as u64,
        shadings_shaded: after.increase_where(before, "cloudscape_kept_shadings_total", "how=\"shaded\"") as u64,
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
    /// The world the groups moved through.
    pub geometry: GeometrySummary,
    /// Distinct places: the level-0 tiles of the world's finest layer that held a
    /// group's centre at a whole second of the measured run.
    pub distinct_places: usize,
    /// Side of those tiles, metres.
    pub place_side_m: f64,
    /// World-clock seconds at the start, world seconds per second, and where they came from.
    pub t0: f64,
    pub clock: f64,
    pub clock_source: ClockSource,
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
    /// The preset the players fetched, and the tile format.
    pub quality: &'static str,
    pub wire: Wire,
    /// What a player received for its first view, bytes on the wire (compressed as
    /// negotiated): the mean over players of their first tick's bodies (keyframes and
    /// splat sheets), warm-up or not; `None` without players.
    pub first_view_bytes_per_player: Option<f64>,
    /// What a player received per second over the measured run (tiles it turned or
    /// moved to, next keyframes, splat sheets), bytes on the wire; `None` without players.
    pub bytes_per_player_s: Option<f64>,
    /// [`Report::bytes_per_player_s`] by product (`billboards.bin`,
    /// `billboards.delta.bin`, `precipitation.png`, …), bytes per player-second.
    pub bytes_per_player_s_by_product: BTreeMap<&'static str, f64>,
    /// From the server's /metrics; `None` when it could not be read.
    pub cache: Option<CacheFigures>,
    /// What the server computed and how busy it was; `None` when /metrics could not be read.
    pub server: Option<ServerFigures>,
    /// What the load generator itself spent, beside the server.
    pub generator: GeneratorFigures,
    /// How much the groups shared, per level (the measured tile requests by keyframe).
    pub sharing: Vec<LevelSharing>,
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
    /// Every group's itinerary: read-only, so agents need no lock to find their place.
    geometry: Geometry,
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
        if let Some(t) = self.t0
            && !(t.is_finite() && (0.0..=1e12).contains(&t))
        {
            return Err(LoadError::Spec(format!("--t must be in [0, 1e12], got {t}")));
        }
        if let Some(c) = self.clock
            && !(c.is_finite() && (0.0..=1e6).contains(&c))
        {
            return Err(LoadError::Spec(format!("--clock must be in [0, 1e6], got {c}")));
        }
        if let Some(n) = self.placement.nice {
            Placement::check_nice(n).map_err(LoadError::Spec)?;
        }
        Ok(())
    }

    /// The world clock of the run: `--t`/`--clock` where given, else the server's clock
    /// (its `now` when discovery answered; its rate), else noon at 1 s per s.
    fn clock(&self, server: Option<ServerClock>) -> (f64, f64, ClockSource) {
        let rate = self.clock.or(server.map(|c| c.rate.clamp(0.0, 1e6))).unwrap_or(1.0);
        match (self.t0, server) {
            (Some(t), _) => (t, rate, ClockSource::Given),
            (None, Some(c)) => (c.now.clamp(0.0, 1e12), rate, ClockSource::Server),
            (None, None) => (DEFAULT_T0, rate, ClockSource::Default),
        }
    }
}

/// Sends one request; returns the outcome (latency from `from`) and the ETag (when the
/// agent keeps it) and `Retry-After` of the answer. The body is counted, not kept.
async fn send(shared: &Shared, req: &workload::Request, from: Instant) -> (Outcome, Option<String>, Option<Duration>) {
    // Players accept compressed bodies as browsers and engines do (the server's zstd
    // or gzip, compressed once per cached response) and count the bytes on the wire
    // without decoding them: reqwest is built without its decoders. (The discovery and
    // metrics reads, which are parsed, ask for none.)
    let mut builder = shared
        .http
        .get(format!("{}{}", shared.base, req.path))
        .header(reqwest::header::ACCEPT_ENCODING, "zstd, gzip");
    if let Some(e) = &req.etag {
        builder = builder.header(reqwest::header::IF_NONE_MATCH, e.as_str());
    }
    let result = async {
        let mut response = builder.send().await?;
        let status = response.status().as_u16();
        let header = |name| {
            response
                .headers()
                .get(name)
                .and_then(|v: &reqwest::header::HeaderValue| v.to_str().ok())
        };
        let etag = (status == 200 && Agent::keeps_etag(req))
            .then(|| header(reqwest::header::ETAG).map(str::to_string))
            .flatten();
        let retry = (status == 503)
            .then(|| header(reqwest::header::RETRY_AFTER))
            .flatten()
            .and_then(|v| v.trim().parse::<f64>().ok())
            .map(|s| Duration::from_secs_f64(s.clamp(0.0, 3600.0)));
        let mut bytes = 0u64;
        while let Some(chunk) = response.chunk().await? {
            bytes += chunk.len() as u64;
        }
        Ok::<_, reqwest::Error>((status, etag, retry, bytes))
    }
    .await;
    let done = Instant::now();
    let micros = done.saturating_duration_since(from).as_micros() as u64;
    // The timeline counts from the end of the warm-up.
    let at = done.saturating_duration_since(shared.measure_from).as_secs_f64();
    let after_boundary = shared.world.just_after_boundary(shared.seconds(from));
    let outcome = |status, bytes| Outcome {
        kind: req.kind,
        status,
        at,
        micros,
        bytes,
        first_view: req.first_view,
        after_boundary,
        keyframe: req.tile.map(|t| t.keyframe),
        group: req.group,
        product: record::product_of(&req.path),
    };
    match result {
        Ok((status, etag, retry, bytes)) => (outcome(Some(status), bytes), etag, retry),
        Err(e) => {
            let mut rec = shared.recorder.lock().unwrap();
            if rec.first_error.is_none() {
                rec.first_error = Some(format!("{}{}: {e}", shared.base, req.path));
            }
            (outcome(None, 0), None, None)
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
        agent.plan(&shared.world, &shared.geometry, s);
        while let Some(req) = agent.next_request() {
            if Instant::now() >= shared.deadline {
                return;
            }
            let sent = Instant::now();
            let (outcome, etag, retry) = send(&shared, &req, sent).await;
            {
                let mut rec = shared.recorder.lock().unwrap();
                if req.first_view {
                    rec.record_first_view(outcome.bytes);
                }
                if sent >= shared.measure_from {
                    rec.record(outcome);
                }
            }
            agent.answered(&req, outcome.status == Some(200), etag);
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

/// Sleeps [`record::LAG_PERIOD_MS`] over and over until the run's deadline and records
/// how late each wake-up came (from the end of the warm-up on): the delay the
/// generator's own scheduling adds to every latency it measures.
async fn lag_probe(shared: Arc<Shared>) {
    let period = Duration::from_millis(record::LAG_PERIOD_MS);
    loop {
        let due = Instant::now() + period;
        if due >= shared.deadline {
            return;
        }
        tokio::time::sleep_until(due.into()).await;
        let late = Instant::now().saturating_duration_since(due);
        if due >= shared.measure_from {
            shared.recorder.lock().unwrap().record_lag(late.as_micros() as u64);
        }
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
                a.plan(&shared.world, &shared.geometry, shared.seconds(intended));
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
            {
                let mut rec = shared.recorder.lock().unwrap();
                if req.first_view {
                    rec.record_first_view(outcome.bytes);
                }
                if intended >= shared.measure_from {
                    rec.record(outcome);
                }
            }
            agent.lock().unwrap().answered(&req, outcome.status == Some(200), etag);
            drop(permit);
        });
        // Reap finished tasks so the set does not grow with the run.
        while tasks.try_join_next().is_some() {}
    }
    while tasks.join_next().await.is_some() {}
}

/// CPU readings once a second of the measured run, for the timeline: the generator's
/// own (getrusage) and the server's (from /proc when its pid is known).
struct CpuSampler {
    pid: Option<u32>,
    second: usize,
    at: Instant,
    generator: f64,
    server: Option<f64>,
}

impl CpuSampler {
    fn new(pid: Option<u32>, at: Instant) -> CpuSampler {
        CpuSampler {
            pid,
            second: 0,
            at,
            generator: generator::cpu_seconds(),
            server: pid.and_then(proc_cpu_seconds),
        }
    }

    /// Records the last second into `rec` once a whole second has passed since the last reading.
    fn tick(&mut self, rec: &mut Recorder) {
        let now = Instant::now();
        let dt = now.saturating_duration_since(self.at).as_secs_f64();
        if dt < 1.0 {
            return;
        }
        let generator = generator::cpu_seconds();
        let server = self.pid.and_then(proc_cpu_seconds);
        let share = |a: f64, b: f64| ((a - b) / dt).max(0.0);
        rec.record_cpu(
            self.second,
            Some(share(generator, self.generator)),
            server.zip(self.server).map(|(a, b)| share(a, b)),
        );
        (self.second, self.at, self.generator, self.server) = (self.second + 1, now, generator, server);
    }
}

/// Runs the load test. `progress` is called about five times a second.
pub fn run(spec: &LoadSpec, mut progress: impl FnMut(Progress)) -> Result<Report, LoadError> {
    spec.check()?;
    let base = parse_target(&spec.target)?;
    // Before the runtime starts its threads, so that they inherit the placement.
    spec.placement.apply().map_err(LoadError::Placement)?;
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
        let found = Discovery::parse(&text).map_err(discovery)?;
        let (t0, clock, clock_source) = spec.clock(found.clock);
        let world = WorldView::new(&found.world, t0, clock);

        let (players, servers) = match spec.scenario {
            Scenario::Mmo => (spec.players, 0),
            Scenario::Queries => (0, spec.players),
            Scenario::Mixed => (spec.players, spec.players.div_ceil(GROUP_SIZE)),
        };
        let groups = spec.players.div_ceil(GROUP_SIZE).max(1);
        // With `places`, group g follows the itinerary of place g mod places.
        let places = spec.places.map_or(groups, |p| p.clamp(1, groups));
        let horizon = (spec.warmup + spec.duration).as_secs_f64() + 2.0 * TICK_SECONDS;
        let geometry = Geometry::new(spec.geometry, places, spec.seed, found.towns, horizon);
        let mut agents: Vec<Agent> = (0..players)
            .map(|i| {
                Agent::new(Role::Player(Player::new(
                    i,
                    spec.seed,
                    spec.fetch,
                    spec.quality,
                    spec.wire,
                )))
            })
            .collect();
        agents.extend((0..servers).map(|i| Agent::new(Role::GameServer(GameServer::new(i, groups)))));

        let start = Instant::now();
        let shared = Arc::new(Shared {
            world,
            geometry,
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
        tokio::spawn(lag_probe(shared.clone()));
        let (before, generator_before, mut sampler) = {
            tokio::time::sleep_until(shared.measure_from.into()).await;
            let before = scrape(&http, &base, spec.server_pid).await;
            (
                before,
                generator::cpu_seconds(),
                CpuSampler::new(spec.server_pid, Instant::now()),
            )
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
                    let mut rec = shared.recorder.lock().unwrap();
                    sampler.tick(&mut rec);
                    progress(Progress {
                        elapsed_s: shared.measure_from.elapsed().as_secs_f64(),
                        requests: rec.totals().requests,
                        shed: rec.totals().shed,
                    });
                }
            }
        }
        let elapsed = shared.measure_from.elapsed().as_secs_f64();
        let generator_cpu = (generator::cpu_seconds() - generator_before).max(0.0);
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
        let warmup = spec.warmup.as_secs_f64();
        let place_side_m = shared.world.finest_tile_side();
        Ok(Report {
            target: base.clone(),
            world: spec.world.clone(),
            scenario: spec.scenario,
            fetch: spec.fetch,
            mode: if spec.rate.is_some() { "open" } else { "closed" },
            rate: spec.rate,
            players,
            game_servers: servers,
            geometry: GeometrySummary::new(&shared.geometry, groups),
            distinct_places: shared
                .geometry
                .distinct_places(groups, place_side_m, warmup, warmup + elapsed),
            place_side_m,
            t0,
            clock,
            clock_source,
            duration_s: spec.duration.as_secs_f64(),
            elapsed_s: elapsed,
            throughput_rps: rec.totals().requests as f64 / elapsed.max(1e-9),
            totals: rec.totals().clone(),
            latency: rec.latency(),
            status: rec.statuses(),
            by_kind,
            revalidated_ratio: (fetched + revalidated > 0).then(|| revalidated as f64 / (fetched + revalidated) as f64),
            body_bytes: rec.bytes(),
            quality: spec.quality.as_str(),
            wire: spec.wire,
            first_view_bytes_per_player: (players > 0).then(|| rec.first_view_bytes() as f64 / players as f64),
            bytes_per_player_s: (players > 0).then(|| rec.player_bytes() as f64 / players as f64 / elapsed.max(1e-9)),
            bytes_per_player_s_by_product: if players > 0 {
                rec.product_bytes()
                    .into_iter()
                    .map(|(p, b)| (p, b as f64 / players as f64 / elapsed.max(1e-9)))
                    .collect()
            } else {
                BTreeMap::new()
            },
            cache,
            server,
            generator: GeneratorFigures {
                cpu_seconds: generator_cpu,
                cpu_cores: generator_cpu / elapsed.max(1e-9),
                placement: spec.placement.read_back(),
                lag: rec.lag(),
            },
            sharing: rec.sharing(),
            boundary: rec.boundary_latency(),
            timeline: rec.timeline(),
            distribution: rec.distribution(),
            first_error: rec.first_error.clone(),
        })
    })
}

/// The players of each step of a capacity sweep, until p99 passes the target: 8, 16,
/// 32, … doubling to 1024.
pub fn sweep_steps() -> Vec<usize> {
    (3..=10).map(|e| 1usize << e).collect()
}

/// The p99 a capacity step must stay within, milliseconds.
pub const SWEEP_P99_MS: f64 = 50.0;

/// One step of a capacity sweep.
#[derive(Clone, Debug, Serialize)]
pub struct SweepStep {
    /// Players of the step, their groups, and the distinct places the groups were in
    /// ([`Report::distinct_places`]).
    pub players: usize,
    pub groups: usize,
    pub places: usize,
    /// World-clock seconds at the step's start.
    pub t0: f64,
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
    /// The load generator's own CPU over the step, as a share of one core.
    pub generator_cpu_cores: f64,
    /// How late the generator's own timer woke, p99, milliseconds
    /// ([`GeneratorFigures::lag`]).
    pub generator_lag_p99_ms: f64,
    /// How much the groups shared, per level.
    pub sharing: Vec<LevelSharing>,
    /// Body bytes per second received.
    pub bytes_per_s: f64,
    /// Bytes a player received per second ([`Report::bytes_per_player_s`]) and for its
    /// first view ([`Report::first_view_bytes_per_player`]).
    pub bytes_per_player_s: Option<f64>,
    pub first_view_bytes_per_player: Option<f64>,
    /// Within [`SWEEP_P99_MS`] and no 503.
    pub holds: bool,
}

impl SweepStep {
    fn overall_sharing(&self) -> Option<LevelSharing> {
        sharing::overall(&self.sharing)
    }
}

/// A capacity sweep: the steps run, and the most players a step held.
#[derive(Clone, Debug, Serialize)]
pub struct SweepReport {
    /// The server, world, fetch mode, quality and world clock every step ran with ([`LoadSpec`]).
    pub target: String,
    pub world: String,
    pub fetch: FetchMode,
    pub quality: &'static str,
    pub wire: Wire,
    pub clock: f64,
    pub clock_source: ClockSource,
    /// The world the groups moved through (as the last step saw it).
    pub geometry: Option<GeometrySummary>,
    /// Side of the tiles distinct places are counted in, metres.
    pub place_side_m: f64,
    /// Where the generator ran (`--nice`, `--cpu`), read back at the last step.
    pub placement: Option<PlacementReadBack>,
    /// Measured seconds of each step, after its warm-up.
    pub step_s: f64,
    /// Warm-up seconds of each step.
    pub warmup_s: f64,
    /// The steps run, in order.
    pub steps: Vec<SweepStep>,
    /// The most players a step held, and the distinct places they were in; `None`
    /// when the first step did not hold.
    pub capacity: Option<usize>,
    pub capacity_places: Option<usize>,
}

/// Raises the number of players step by step ([`sweep_steps`], or `steps`) until a
/// step's p99 passes [`SWEEP_P99_MS`] or any request is shed, or (`every_step`)
/// through all of `steps`, for a whole curve. Each step is a run of `spec` with that
/// many players; the world clock runs on from one step to the next, so no step finds
/// the previous one's keyframes (with the server's clock, each step starts at its
/// `now`; else each starts where the last one's time ended).
pub fn sweep(
    spec: &LoadSpec,
    steps: &[usize],
    every_step: bool,
    mut progress: impl FnMut(usize, Progress),
) -> Result<SweepReport, LoadError> {
    let mut out = Vec::new();
    let mut t0 = spec.t0;
    let mut last: Option<Report> = None;
    for &players in steps {
        let step = LoadSpec {
            players,
            t0: t0.map(|t| t.min(1e12)),
            ..spec.clone()
        };
        let r = run(&step, |p| progress(players, p))?;
        t0 = match r.clock_source {
            ClockSource::Server => None,
            ClockSource::Given | ClockSource::Default => {
                Some(r.t0 + r.clock * (spec.warmup + spec.duration).as_secs_f64())
            }
        };
        let holds = r.latency.p99_ms <= SWEEP_P99_MS && r.totals.shed == 0 && r.totals.transport_errors == 0;
        out.push(SweepStep {
            players,
            groups: r.geometry.groups,
            places: r.distinct_places,
            t0: r.t0,
            throughput_rps: r.throughput_rps,
            p50_ms: r.latency.p50_ms,
            p99_ms: r.latency.p99_ms,
            max_ms: r.latency.max_ms,
            shed: r.totals.shed,
            boundary_p99_ms: r.boundary.after_boundary.p99_ms,
            elsewhere_p99_ms: r.boundary.elsewhere.p99_ms,
            server: r.server.clone(),
            generator_cpu_cores: r.generator.cpu_cores,
            generator_lag_p99_ms: r.generator.lag.p99_ms,
            sharing: r.sharing.clone(),
            bytes_per_s: r.body_bytes as f64 / r.elapsed_s.max(1e-9),
            bytes_per_player_s: r.bytes_per_player_s,
            first_view_bytes_per_player: r.first_view_bytes_per_player,
            holds,
        });
        last = Some(r);
        if !holds && !every_step {
            break;
        }
    }
    let held = out.iter().take_while(|s| s.holds).last();
    Ok(SweepReport {
        target: spec.target.clone(),
        world: spec.world.clone(),
        fetch: spec.fetch,
        quality: spec.quality.as_str(),
        wire: spec.wire,
        clock: last.as_ref().map_or(1.0, |r| r.clock),
        clock_source: last.as_ref().map_or(ClockSource::Default, |r| r.clock_source),
        geometry: last.as_ref().map(|r| r.geometry.clone()),
        place_side_m: last.as_ref().map_or(0.0, |r| r.place_side_m),
        placement: last.as_ref().map(|r| r.generator.placement.clone()),
        step_s: spec.duration.as_secs_f64(),
        warmup_s: spec.warmup.as_secs_f64(),
        capacity: held.map(|s| s.players),
        capacity_places: held.map(|s| s.places),
        steps: out,
    })
}

/// `12.5 %` of a share, or `–`.
fn percent(v: Option<f64>) -> String {
    v.map_or("–".into(), |c| format!("{:.0} %", 100.0 * c))
}

impl SweepReport {
    /// The curve as Markdown tables (what `--sweep` prints and writes to
    /// BENCHMARKS.md): the capacity curve, then the sharing per level of every step.
    pub fn markdown(&self) -> String {
        let geometry = self.geometry.as_ref().map_or(String::from("–"), |g| match g.kind {
            GeometryKind::Spread => format!(
                "`--geometry spread`: groups {:.0} m apart at the start, each its own path at 12 m/s",
                geometry::SPREAD_SPACING
            ),
            GeometryKind::Towns => format!(
                "`--geometry towns`: groups start in {} {} joined by {} roads, {:.0} % walk (near their town), \
                 {:.0} % ride the roads, {:.0} % fly between towns, stopping {:.0}–{:.0} min in each",
                g.towns,
                if g.towns_from_server {
                    "warm areas of the server"
                } else {
                    "generated towns"
                },
                g.roads,
                100.0 * g.walking as f64 / g.groups.max(1) as f64,
                100.0 * g.riding as f64 / g.groups.max(1) as f64,
                100.0 * g.flying as f64 / g.groups.max(1) as f64,
                geometry::DWELL.0 / 60.0,
                geometry::DWELL.1 / 60.0,
            ),
        });
        let mut md = format!(
            "`cloudscape loadtest --sweep` against `{}`, world `{}`: mmo scenario, groups of {GROUP_SIZE} players \
             (within {:.0} m of the group's centre), {geometry}. Players fetch `{}` tiles ({}) {} (prefetching the \
             next keyframe past {:.0}–{:.0} % of a span, by tile) with `Accept-Encoding: zstd, gzip` as browsers \
             do; world clock {} s per second ({}). Generator: {}. Each step: {:.0} s of warm-up \
             (the players' first views) then {:.0} s measured. A step holds when its p99 ≤ {SWEEP_P99_MS} ms \
             with no 503. *Places*: distinct level-0 tiles ({:.1} km) holding a group's centre during the step; \
             *CPU*: share of one core over the step (server from its `process_cpu_seconds_total`, generator \
             from its own `getrusage`); *generator lag*: how late the generator's own {}-ms timer woke, p99 \
             (its scheduling delay, which every latency includes: when it nears the p99, the generator \
             measured itself); *requests per keyframe*: tile requests per distinct tile keyframe at \
             level 0; *shared*: share of the distinct keyframes (all levels) asked for by two groups or more; \
             *warm*: keyframes of the server's play areas computed during the step; *shading reused*: share of \
             the instants the server's tile jobs shaded that were the previous keyframe's end, kept; *KB/s a \
             player*: bytes on the wire a player received per second of the measured run, and *first view* \
             its first tick's.\n\n\
             | players | places | requests/s | p50 | p99 | max | 503 | p99 after a boundary / elsewhere | server CPU | generator CPU | generator lag | computations | ahead computed / served / missed | ahead lag | warm | shading reused | requests per keyframe (level 0) | shared | MB/s | KB/s a player | first view | holds |\n\
             |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
            self.target,
            self.world,
            workload::PARTY_SPREAD,
            self.quality,
            match self.wire {
                Wire::V3 => "`billboards.bin` for a tile's first keyframe, `billboards.delta.bin` after",
                Wire::V2 => "`billboards.v2.bin` and `shadow.png` for every keyframe, `--wire v2`",
            },
            match self.fetch {
                FetchMode::Keyframes => "by keyframe URL (immutable, never revalidated)",
                FetchMode::Poll => "every second at the current time, revalidating (`--poll`)",
            },
            100.0 * workload::PREFETCH_AT.0,
            100.0 * workload::PREFETCH_AT.1,
            self.clock,
            match self.clock_source {
                ClockSource::Given => "`--t`",
                ClockSource::Server => "from the server's clock",
                ClockSource::Default => "from t = 43200",
            },
            self.placement.as_ref().map_or("as is".into(), |p| format!(
                "{} (read back: nice {}, cores {})",
                p.mode,
                p.nice,
                generator::cpu_list(&p.cpus)
            )),
            self.warmup_s,
            self.step_s,
            self.place_side_m / 1000.0,
            record::LAG_PERIOD_MS,
        );
        for s in &self.steps {
            let f = s.server.clone().unwrap_or_default();
            let l0 = s.sharing.iter().find(|l| l.level == 0);
            md += &format!(
                "| {} | {} | {:.0} | {:.1} ms | {:.1} ms | {:.0} ms | {} | {:.1} / {:.1} ms | {} | {} | {:.1} ms | {} | {} / {} / {} | {} | {} | {} | {} | {} | {:.2} | {} | {} | {} |\n",
                s.players,
                s.places,
                s.throughput_rps,
                s.p50_ms,
                s.p99_ms,
                s.max_ms,
                s.shed,
                s.boundary_p99_ms,
                s.elsewhere_p99_ms,
                percent(f.cpu_cores),
                percent(Some(s.generator_cpu_cores)),
                s.generator_lag_p99_ms,
                f.computations,
                f.ahead.computed,
                f.ahead.served,
                f.ahead.missed,
                f.ahead.mean_lag_s.map_or("–".into(), |l| format!("{l:.2} s")),
                f.warm_computed,
                percent(f.shading_reused_share()),
                l0.map_or("–".into(), |l| format!("{:.1}", l.requests_per_keyframe)),
                percent(s.overall_sharing().map(|o| o.shared_by_2_groups)),
                s.bytes_per_s / 1e6,
                s.bytes_per_player_s.map_or("–".into(), |b| format!("{:.1}", b / 1e3)),
                s.first_view_bytes_per_player
                    .map_or("–".into(), |b| format!("{:.0} KB", b / 1e3)),
                if s.holds { "yes" } else { "**no**" },
            );
        }
        md += &match (self.capacity, self.capacity_places) {
            (Some(c), Some(p)) => format!("\nCapacity: **{c} players** in **{p} distinct places** held.\n"),
            _ => "\nCapacity: the first step did not hold.\n".to_string(),
        };
        md += "\nSharing per level (measured tile requests by keyframe):\n\n\
               | players | level | keyframes | requests | requests per keyframe | groups per keyframe | asked by ≥ 2 groups |\n\
               |---|---|---|---|---|---|---|\n";
        for s in &self.steps {
            for l in &s.sharing {
                md += &format!(
                    "| {} | {} | {} | {} | {:.1} | {:.2} | {:.0} % |\n",
                    s.players,
                    l.level,
                    l.keyframes,
                    l.requests,
                    l.requests_per_keyframe,
                    l.groups_per_keyframe,
                    100.0 * l.shared_by_2_groups
                );
            }
        }
        md
    }

    /// Players against p50 and p99; server and generator CPU and compute-ahead lag;
    /// distinct places and sharing (PNG).
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
            title: "CPU (server, generator) and compute-ahead lag".into(),
            x_label: "players".into(),
            y_label: "% of a core / lag ms".into(),
            x_log: true,
            y_log: false,
            series: vec![
                series("server CPU %", 2, &|s| s.server.as_ref()?.cpu_cores.map(|c| 100.0 * c)),
                series("generator CPU %", 1, &|s| Some(100.0 * s.generator_cpu_cores)),
                series("ahead lag ms", 4, &|s| {
                    Some(1000.0 * s.server.as_ref()?.ahead.mean_lag_s.unwrap_or(0.0))
                }),
            ],
        };
        let sharing = Panel {
            title: "places and sharing".into(),
            x_label: "players".into(),
            y_label: "places / requests per keyframe / %".into(),
            x_log: true,
            // Linear: no group shares at the first steps (0 %), which a log axis drops.
            y_log: false,
            series: vec![
                series("distinct places", 0, &|s| Some(s.places as f64)),
                series("requests per keyframe", 3, &|s| {
                    s.overall_sharing().map(|o| o.requests_per_keyframe)
                }),
                series("% keyframes shared by ≥ 2 groups", 2, &|s| {
                    s.overall_sharing().map(|o| 100.0 * o.shared_by_2_groups)
                }),
            ],
        };
        render(&[latency, cpu, sharing], 3, (520, 420))
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
        s += &format!(
            "world: {}; {} distinct places ({:.1} km tiles); t0 {} ({}), clock {} s per second\n",
            self.geometry.describe(),
            self.distinct_places,
            self.place_side_m / 1000.0,
            self.t0,
            match self.clock_source {
                ClockSource::Given => "--t",
                ClockSource::Server => "the server's clock",
                ClockSource::Default => "default",
            },
            self.clock,
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
        if let (Some(first), Some(steady)) = (self.first_view_bytes_per_player, self.bytes_per_player_s) {
            s += &format!(
                "bytes a player received ({}, {}, on the wire): first view {:.0} KB, then {:.1} KB/s\n",
                self.quality,
                match self.wire {
                    Wire::V3 => "billboards.bin and deltas",
                    Wire::V2 => "billboards.v2.bin and shadow.png",
                },
                first / 1e3,
                steady / 1e3
            );
            let parts: Vec<String> = self
                .bytes_per_player_s_by_product
                .iter()
                .filter(|(_, b)| **b > 0.0)
                .map(|(p, b)| format!("{p} {:.1}", b / 1e3))
                .collect();
            if !parts.is_empty() {
                s += &format!("  by product, KB/s: {}\n", parts.join(", "));
            }
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
        let g = &self.generator;
        s += &format!(
            "CPU, share of one core: server {}, generator {} (generator {}; read back: nice {}, cores {}); \
             generator lag (its own {} ms timer, late by) p99 {:.1} ms, max {:.1} ms\n",
            percent(self.server.as_ref().and_then(|f| f.cpu_cores)),
            percent(Some(g.cpu_cores)),
            g.placement.mode,
            g.placement.nice,
            generator::cpu_list(&g.placement.cpus),
            record::LAG_PERIOD_MS,
            g.lag.p99_ms,
            g.lag.max_ms,
        );
        if g.lag.p99_ms > 5.0 && g.lag.p99_ms > 0.5 * self.latency.p99_ms {
            s += &format!(
                "warning: the generator itself ran late (p99 {:.1} ms against a request p99 of {:.1} ms): \
                 the latency is partly its own; give it more CPU (a lower --nice, its own --cpu) or another machine\n",
                g.lag.p99_ms, self.latency.p99_ms
            );
        }
        if !self.sharing.is_empty() {
            s += "sharing by level (distinct tile keyframes; requests per keyframe; asked by >= 2 groups):";
            for l in &self.sharing {
                s += &format!(
                    " L{} {} kf, {:.1} req, {:.0} %;",
                    l.level,
                    l.keyframes,
                    l.requests_per_keyframe,
                    100.0 * l.shared_by_2_groups
                );
            }
            s.pop();
            s += "\n";
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
        let cpu = Panel {
            title: "CPU per second (share of one core)".into(),
            x_label: "seconds since start".into(),
            y_label: "% of a core".into(),
            series: vec![
                Series {
                    name: "generator".into(),
                    points: self
                        .timeline
                        .iter()
                        .filter_map(|s| Some((s.second as f64 + 0.5, 100.0 * s.generator_cpu_cores?)))
                        .collect(),
                    colour: PALETTE[1],
                    mark: Mark::Line,
                },
                Series {
                    name: "server (--pid)".into(),
                    points: self
                        .timeline
                        .iter()
                        .filter_map(|s| Some((s.second as f64 + 0.5, 100.0 * s.server_cpu_cores?)))
                        .collect(),
                    colour: PALETTE[2],
                    mark: Mark::Line,
                },
            ],
            ..Panel::default()
        };
        render(&[over_time, rates, distribution, cpu], 2, (520, 400))
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
    fn reused_shading_is_counted_by_its_label() {
        let scrape = |text: &str| Scrape {
            text: text.into(),
            cpu: None,
        };
        let before = scrape(
            "cloudscape_kept_shadings_total{how=\"reused\"} 4\ncloudscape_kept_shadings_total{how=\"shaded\"} 10\n",
        );
        let after = scrape(
            "cloudscape_kept_shadings_total{how=\"reused\"} 34\ncloudscape_kept_shadings_total{how=\"shaded\"} 20\n\
             cloudscape_warm_computed_total 7\n",
        );
        let f = server_figures(&before, &after, 1.0);
        assert_eq!((f.shadings_reused, f.shadings_shaded, f.warm_computed), (30, 10, 7));
        assert_eq!(f.shading_reused_share(), Some(0.75));
        assert_eq!(ServerFigures::default().shading_reused_share(), None);
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
            t0: Some(0.0),
            clock: Some(1.0),
            seed: 1,
            geometry: GeometryKind::Towns,
            placement: Placement::default(),
            fetch: FetchMode::Keyframes,
            places: None,
            server_pid: None,
            warmup: Duration::ZERO,
            quality: workload::DEFAULT_QUALITY,
            wire: Wire::V3,
        };
        assert!(matches!(run(&spec, |_| {}), Err(LoadError::Spec(_))));
        let spec = LoadSpec {
            players: 1,
            rate: Some(f64::NAN),
            ..spec
        };
        assert!(matches!(run(&spec, |_| {}), Err(LoadError::Spec(_))));
        // A nice value the generator could not take is refused before anything runs.
        let spec = LoadSpec {
            rate: None,
            placement: Placement {
                nice: Some(-5),
                cpus: None,
            },
            ..spec
        };
        match run(&spec, |_| {}) {
            Err(LoadError::Spec(m)) => assert!(m.starts_with("--nice must be between 0 and 19"), "{m}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_clock_comes_from_the_flags_then_the_server_then_noon() {
        let spec = |t0, clock| LoadSpec {
            target: "http://127.0.0.1:1".into(),
            world: "default".into(),
            players: 8,
            duration: Duration::from_secs(1),
            scenario: Scenario::Mmo,
            rate: None,
            t0,
            clock,
            seed: 1,
            geometry: GeometryKind::Towns,
            placement: Placement::default(),
            fetch: FetchMode::Keyframes,
            places: None,
            server_pid: None,
            warmup: Duration::ZERO,
            quality: workload::DEFAULT_QUALITY,
            wire: Wire::V3,
        };
        let server = Some(ServerClock {
            offset: 0.0,
            rate: 2.0,
            now: 90_000.0,
        });
        assert_eq!(spec(None, None).clock(server), (90_000.0, 2.0, ClockSource::Server));
        assert_eq!(
            spec(None, Some(1.0)).clock(server),
            (90_000.0, 1.0, ClockSource::Server)
        );
        assert_eq!(spec(Some(5.0), None).clock(server), (5.0, 2.0, ClockSource::Given));
        assert_eq!(spec(Some(5.0), Some(0.0)).clock(None), (5.0, 0.0, ClockSource::Given));
        assert_eq!(spec(None, None).clock(None), (DEFAULT_T0, 1.0, ClockSource::Default));
    }

    #[test]
    fn the_default_sweep_doubles_from_8_to_1024() {
        assert_eq!(sweep_steps(), vec![8, 16, 32, 64, 128, 256, 512, 1024]);
    }

    #[test]
    fn the_sweep_table_carries_places_generator_cpu_and_sharing() {
        let level = |level, keyframes, requests, shared| LevelSharing {
            level,
            keyframes,
            requests,
            requests_per_keyframe: requests as f64 / keyframes as f64,
            groups_per_keyframe: 1.5,
            shared_by_2_groups: shared,
        };
        let step = SweepStep {
            players: 16,
            groups: 2,
            places: 1,
            t0: 43_200.0,
            throughput_rps: 20.0,
            p50_ms: 1.0,
            p99_ms: 9.0,
            max_ms: 12.0,
            shed: 0,
            boundary_p99_ms: 5.0,
            elsewhere_p99_ms: 9.0,
            server: Some(ServerFigures {
                cpu_cores: Some(1.2),
                ..ServerFigures::default()
            }),
            generator_cpu_cores: 0.034,
            generator_lag_p99_ms: 0.25,
            sharing: vec![level(0, 10, 40, 0.5), level(2, 2, 30, 1.0)],
            bytes_per_s: 1e6,
            bytes_per_player_s: Some(10_000.0),
            first_view_bytes_per_player: Some(500_000.0),
            holds: true,
        };
        let report = SweepReport {
            target: "http://x:1".into(),
            world: "default".into(),
            fetch: FetchMode::Keyframes,
            quality: "fast",
            wire: Wire::V3,
            clock: 1.0,
            clock_source: ClockSource::Server,
            geometry: None,
            place_side_m: 25_600.0,
            placement: None,
            step_s: 20.0,
            warmup_s: 10.0,
            steps: vec![step],
            capacity: Some(16),
            capacity_places: Some(1),
        };
        let md = report.markdown();
        // places 1, server 120 %, generator 3 % and late by 0.2 ms (0.25 rounded to
        // even), 4.0 requests per level-0 keyframe, (5 + 2) / 12 = 58 % of the
        // keyframes shared.
        assert!(
            md.contains("| 16 | 1 | 20 | 1.0 ms | 9.0 ms | 12 ms | 0 | 5.0 / 9.0 ms | 120 % | 3 % | 0.2 ms |"),
            "{md}"
        );
        assert!(md.contains("| 4.0 | 58 % | 1.00 | 10.0 | 500 KB | yes |"), "{md}");
        assert!(md.contains("**16 players** in **1 distinct places**"), "{md}");
        assert!(md.contains("| 16 | 2 | 2 | 30 | 15.0 | 1.50 | 100 % |"), "{md}");
        let png = report.plot().unwrap();
        assert!(png.starts_with(b"\x89PNG"));
    }
}
