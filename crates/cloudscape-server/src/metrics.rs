//! Prometheus metrics, one registry per server (so tests can run several servers in
//! one process). Every label value comes from a fixed set, never from what a client
//! sent: routes are route templates (or `unmatched`), methods are the known ones (or
//! `other`), never tiles — so no request can add a series.

use prometheus::{
    CounterVec, Encoder, Histogram, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGauge, IntGaugeVec,
    Opts, Registry, TextEncoder,
};

use cloudscape_core::stages::{Stage, Stages};
use cloudscape_core::world::ALGORITHM_VERSION;

/// Every metric the service exports. Owned by `AppState`; handlers and the compute
/// queue update it.
pub struct Metrics {
    registry: Registry,
    /// Requests by route template, method and status.
    pub requests: IntCounterVec,
    /// Request latency by route template, seconds.
    pub latency: HistogramVec,
    /// Requests being served right now.
    pub in_flight: IntGauge,
    /// Cache lookups that found the bytes, by product kind.
    pub cache_hits: IntCounterVec,
    /// Cache lookups that did not (the request then computes or joins a computation).
    pub cache_misses: IntCounterVec,
    /// Computations actually run, by product kind: concurrent misses on one key count once.
    pub computations: IntCounterVec,
    /// Compute time by product kind, seconds.
    pub compute_seconds: HistogramVec,
    /// Compute jobs running or queued.
    pub queue_depth: IntGauge,
    /// Seconds the admitted compute jobs still need at the queue's measured rate
    /// (updated when scraped): a request whose job would not finish within its budget
    /// behind them is shed.
    pub backlog_seconds: prometheus::Gauge,
    /// Requests refused with 503 because the queue was full, by product kind.
    pub shed: IntCounterVec,
    /// Requests whose time budget ran out.
    pub timeouts: IntCounterVec,
    /// Computations stopped early because nobody waited for them any more.
    pub cancelled: IntCounterVec,
    /// Requests refused up front because their estimated cost or memory is over the
    /// limits (413), by product kind.
    pub refused: IntCounterVec,
    /// Bytes of replies being sent right now (the `server.reply_bytes` budget).
    pub reply_bytes: IntGauge,
    /// Bytes held by the response cache (updated when scraped).
    pub cache_bytes: IntGauge,
    /// The allocator's figures (`crate::allocator::Stats`; updated when scraped, absent
    /// when jemalloc is not the allocator), by `what`: `allocated` (held by the
    /// program), `active`, `resident` (its pages in memory, free ones included: the
    /// difference with `allocated` is its overhead), `retained`.
    pub allocator_bytes: IntGaugeVec,
    /// 1 while ready, 0 while starting or draining.
    pub ready: IntGauge,
    /// Shared-cache (Redis) lookups that found the bytes, by product kind.
    pub redis_hits: IntCounterVec,
    /// Shared-cache lookups that did not (the request then computes).
    pub redis_misses: IntCounterVec,
    /// Shared-cache calls that failed or timed out, by operation (`get`, `set`).
    pub redis_errors: IntCounterVec,
    /// Values read from Redis whose seal did not hold (garbage, another key's value, a
    /// forgery, another secret), by product kind: treated as misses, never served.
    pub redis_rejected: IntCounterVec,
    /// Products not written to Redis: over `server.redis_max_value_bytes`.
    pub redis_oversize: IntCounter,
    /// Lookups that skipped Redis because it failed recently.
    pub redis_skipped: IntCounter,
    /// Entries written to the shared cache.
    pub redis_writes: IntCounter,
    /// Background computations (ahead, warm) that claimed their key in the shared cache
    /// before computing, by outcome: `won` (this replica computes it), `lost` (another
    /// replica does; this one takes the bytes from Redis once they are there).
    pub redis_claims: IntCounterVec,
    /// Sockets accepted (served or refused).
    pub connections_accepted: IntCounter,
    /// Connections being served right now.
    pub connections_open: IntGauge,
    /// Connections closed, by [`CloseReason`].
    pub connections_closed: IntCounterVec,
    /// `accept` calls that failed for want of descriptors or buffers.
    pub accept_errors: IntCounter,
    /// Keyframe computations run ahead of the clock (`ahead`).
    pub ahead_computed: IntCounter,
    /// Requests answered from bytes computed ahead (the first request of each key).
    pub ahead_served: IntCounter,
    /// Requests for a keyframe planned ahead that was not computed yet (the request
    /// computes it, or joins the computation ahead).
    pub ahead_missed: IntCounter,
    /// How late a computation ahead finished after the clock reached its keyframe,
    /// seconds (0 when in time).
    pub ahead_lag: Histogram,
    /// Keyframes planned ahead and not computed yet.
    pub ahead_pending: IntGauge,
    /// Tile variants the hot set follows.
    pub ahead_hot: IntGauge,
    /// Tile variants the play areas keep warm (`crate::warm`).
    pub warm_tiles: IntGauge,
    /// Warm keyframes computed (put in the cache by keeping the play areas warm).
    pub warm_computed: IntCounter,
    /// Requests answered from bytes kept warm (the first request of each key).
    pub warm_served: IntCounter,
    /// How long before the clock reached its keyframe a warm keyframe was ready,
    /// seconds (negative: late, as the first keyframes at start-up always are).
    pub warm_lag: Histogram,
    /// Warm keyframes (current or next) not computed yet.
    pub warm_pending: IntGauge,
    /// Compressed variants served, by coding and whether the cache held them.
    pub encodings: IntCounterVec,
    /// Bytes the tiles' kept state holds (`crate::kept`; updated when scraped).
    pub kept_bytes: IntGauge,
    /// Tiles with a kept state (updated when scraped).
    pub kept_tiles: IntGauge,
    /// Density grids tile jobs used, by source: `reused` (cut from a kept grid),
    /// `live` (from kept automaton runs), `cold` (from scratch).
    pub kept_grids: IntCounterVec,
    /// Automaton steps advanced by kept runs.
    pub kept_steps: IntCounter,
    /// Instants of shading tile jobs used, by how: `reused` (the previous
    /// keyframe's end, kept) or `shaded`.
    pub kept_shadings: IntCounterVec,
    /// Tile jobs that found their tile's kept state held by another job.
    pub kept_busy: IntCounter,
    /// Wall time of tile jobs by stage (`cloudscape_core::stages`, plus `encoding`
    /// and `compression`), seconds.
    pub stage_seconds: CounterVec,
}

/// The `method` label values: the methods HTTP defines, then `other`.
pub const METHODS: [&str; 10] = [
    "GET", "HEAD", "POST", "PUT", "DELETE", "OPTIONS", "PATCH", "TRACE", "CONNECT", "other",
];

/// The `method` label of a request: its method if HTTP defines it, else `other`.
pub fn method_label(method: &axum::http::Method) -> &'static str {
    METHODS[..METHODS.len() - 1]
        .iter()
        .find(|m| **m == method.as_str())
        .copied()
        .unwrap_or("other")
}

/// Why a connection was closed: the `reason` label of `connections_closed`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CloseReason {
    /// The client closed it, or asked to (`Connection: close`).
    Done,
    /// The request head did not arrive within the header-read timeout.
    HeaderTimeout,
    /// The request head was larger than the header buffer (answered 431).
    HeaderTooLarge,
    /// No request and no byte moved within the idle timeout.
    IdleTimeout,
    /// The client took no byte of its response within the write timeout.
    WriteTimeout,
    /// Closed by the server's shutdown.
    Shutdown,
    /// Over the connection cap: answered 503 and closed.
    OverCap,
    /// A protocol or socket error.
    Error,
}

impl CloseReason {
    pub const ALL: [CloseReason; 8] = [
        CloseReason::Done,
        CloseReason::HeaderTimeout,
        CloseReason::HeaderTooLarge,
        CloseReason::IdleTimeout,
        CloseReason::WriteTimeout,
        CloseReason::Shutdown,
        CloseReason::OverCap,
        CloseReason::Error,
    ];

    pub fn label(self) -> &'static str {
        match self {
            CloseReason::Done => "done",
            CloseReason::HeaderTimeout => "header_timeout",
            CloseReason::HeaderTooLarge => "header_too_large",
            CloseReason::IdleTimeout => "idle_timeout",
            CloseReason::WriteTimeout => "write_timeout",
            CloseReason::Shutdown => "shutdown",
            CloseReason::OverCap => "over_cap",
            CloseReason::Error => "error",
        }
    }
}

/// The `op` label values of `redis_errors`.
pub const REDIS_OPS: [&str; 2] = ["get", "set"];

/// The `kind` label values: what a computation produces.
pub const KINDS: [&str; 12] = [
    "tile_density",
    "tile_coverage",
    "tile_precipitation",
    "tile_shaded",
    "sample",
    "region",
    "series",
    "lightning",
    "edr",
    "render",
    "splats",
    "sky",
];

const LATENCY_BUCKETS: [f64; 14] = [
    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0,
];

impl Metrics {
    pub fn new() -> Metrics {
        let m = Metrics::unlabelled();
        // Export every kind from the start, at zero, so dashboards and alerts see the series.
        for kind in KINDS {
            for v in [
                &m.cache_hits,
                &m.cache_misses,
                &m.computations,
                &m.shed,
                &m.timeouts,
                &m.cancelled,
                &m.refused,
                &m.redis_hits,
                &m.redis_misses,
                &m.redis_rejected,
            ] {
                v.with_label_values(&[kind]);
            }
            m.compute_seconds.with_label_values(&[kind]);
        }
        for op in REDIS_OPS {
            m.redis_errors.with_label_values(&[op]);
        }
        for coding in ["gzip", "zstd"] {
            for outcome in ["hit", "miss"] {
                m.encodings.with_label_values(&[coding, outcome]);
            }
        }
        for reason in CloseReason::ALL {
            m.connections_closed.with_label_values(&[reason.label()]);
        }
        // The standard process metrics (process_cpu_seconds_total,
        // process_resident_memory_bytes, process_open_fds, process_max_fds,
        // process_start_time_seconds, process_threads, …), read from /proc when scraped.
        #[cfg(target_os = "linux")]
        m.registry
            .register(Box::new(prometheus::process_collector::ProcessCollector::for_self()))
            .expect("unique metric");
        let build = IntGaugeVec::new(
            Opts::new(
                "cloudscape_build_info",
                "always 1: the build's version and the algorithm version in every cache key and ETag",
            ),
            &["version", "algorithm_version"],
        )
        .expect("valid metric");
        build
            .with_label_values(&[env!("CARGO_PKG_VERSION"), &ALGORITHM_VERSION.to_string()])
            .set(1);
        m.registry.register(Box::new(build)).expect("unique metric");
        m
    }

    fn unlabelled() -> Metrics {
        let registry = Registry::new();
        let counter = |name: &str, help: &str, labels: &[&str]| {
            let c = IntCounterVec::new(Opts::new(name, help), labels).expect("valid metric");
            registry.register(Box::new(c.clone())).expect("unique metric");
            c
        };
        let histogram = |name: &str, help: &str, labels: &[&str]| {
            let h = HistogramVec::new(HistogramOpts::new(name, help).buckets(LATENCY_BUCKETS.to_vec()), labels)
                .expect("valid metric");
            registry.register(Box::new(h.clone())).expect("unique metric");
            h
        };
        let plain_counter = |name: &str, help: &str| {
            let c = IntCounter::new(name, help).expect("valid metric");
            registry.register(Box::new(c.clone())).expect("unique metric");
            c
        };
        let gauge = |name: &str, help: &str| {
            let g = IntGauge::new(name, help).expect("valid metric");
            registry.register(Box::new(g.clone())).expect("unique metric");
            g
        };
        Metrics {
            requests: counter(
                "cloudscape_http_requests_total",
                "HTTP requests by route template",
                &["route", "method", "status"],
            ),
            latency: histogram(
                "cloudscape_http_request_duration_seconds",
                "HTTP request latency",
                &["route"],
            ),
            in_flight: gauge("cloudscape_http_requests_in_flight", "HTTP requests being served"),
            cache_hits: counter("cloudscape_cache_hits_total", "response cache hits", &["kind"]),
            cache_misses: counter("cloudscape_cache_misses_total", "response cache misses", &["kind"]),
            computations: counter(
                "cloudscape_computations_total",
                "computations run for requests (coalesced; compute-ahead counts its own)",
                &["kind"],
            ),
            compute_seconds: histogram("cloudscape_compute_duration_seconds", "compute time", &["kind"]),
            queue_depth: gauge("cloudscape_compute_queue_depth", "compute jobs running or queued"),
            backlog_seconds: {
                let g = prometheus::Gauge::new(
                    "cloudscape_compute_backlog_seconds",
                    "seconds the admitted compute jobs still need at the queue's measured rate",
                )
                .expect("valid metric");
                registry.register(Box::new(g.clone())).expect("unique metric");
                g
            },
            shed: counter(
                "cloudscape_shed_total",
                "requests shed with 503: compute queue full",
                &["kind"],
            ),
            timeouts: counter(
                "cloudscape_timeouts_total",
                "requests over their time budget",
                &["kind"],
            ),
            cancelled: counter(
                "cloudscape_cancelled_total",
                "computations stopped early: no request waited for them any more",
                &["kind"],
            ),
            refused: counter(
                "cloudscape_refused_total",
                "requests refused up front: estimated cost or memory over the limits",
                &["kind"],
            ),
            reply_bytes: gauge(
                "cloudscape_reply_bytes",
                "bytes of replies being sent (server.reply_bytes budget)",
            ),
            cache_bytes: gauge("cloudscape_cache_bytes", "bytes held by the response cache"),
            allocator_bytes: {
                let g = IntGaugeVec::new(
                    Opts::new(
                        "cloudscape_allocator_bytes",
                        "jemalloc's figures: allocated (held by the program), active, resident (its pages in memory), retained",
                    ),
                    &["what"],
                )
                .expect("valid metric");
                registry.register(Box::new(g.clone())).expect("unique metric");
                g
            },
            ready: gauge("cloudscape_ready", "1 when ready to serve"),
            redis_hits: counter("cloudscape_redis_hits_total", "shared (Redis) cache hits", &["kind"]),
            redis_misses: counter(
                "cloudscape_redis_misses_total",
                "shared (Redis) cache misses",
                &["kind"],
            ),
            redis_claims: counter(
                "cloudscape_redis_claims_total",
                "background computations that claimed their key in Redis first, by outcome: won, lost",
                &["outcome"],
            ),
            redis_errors: counter(
                "cloudscape_redis_errors_total",
                "shared (Redis) cache calls that failed or timed out",
                &["op"],
            ),
            redis_rejected: counter(
                "cloudscape_redis_rejected_total",
                "values read from Redis whose seal check failed: treated as misses, never served",
                &["kind"],
            ),
            redis_oversize: plain_counter(
                "cloudscape_redis_oversize_total",
                "products not written to Redis: over server.redis_max_value_bytes",
            ),
            redis_skipped: plain_counter(
                "cloudscape_redis_skipped_total",
                "lookups that skipped Redis because it failed recently",
            ),
            redis_writes: plain_counter("cloudscape_redis_writes_total", "entries written to the shared cache"),
            connections_accepted: plain_counter("cloudscape_connections_accepted_total", "sockets accepted"),
            connections_open: gauge("cloudscape_connections_open", "connections being served"),
            connections_closed: counter(
                "cloudscape_connections_closed_total",
                "connections closed, by reason",
                &["reason"],
            ),
            accept_errors: plain_counter(
                "cloudscape_accept_errors_total",
                "accept calls that failed (out of descriptors or buffers)",
            ),
            ahead_computed: plain_counter(
                "cloudscape_ahead_computed_total",
                "keyframes computed ahead of the clock",
            ),
            ahead_served: plain_counter(
                "cloudscape_ahead_served_total",
                "requests answered from bytes computed ahead",
            ),
            ahead_missed: plain_counter(
                "cloudscape_ahead_missed_total",
                "requests for a keyframe planned ahead but not computed yet",
            ),
            ahead_lag: {
                let h = Histogram::with_opts(
                    HistogramOpts::new(
                        "cloudscape_ahead_lag_seconds",
                        "how late a computation ahead finished after the clock reached its keyframe (0: in time)",
                    )
                    .buckets(vec![0.0, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0, 60.0]),
                )
                .expect("valid metric");
                registry.register(Box::new(h.clone())).expect("unique metric");
                h
            },
            ahead_pending: gauge(
                "cloudscape_ahead_pending",
                "keyframes planned ahead and not computed yet",
            ),
            ahead_hot: gauge("cloudscape_ahead_hot_tiles", "tile variants the hot set follows"),
            warm_tiles: gauge("cloudscape_warm_tiles", "tile variants the play areas keep warm"),
            warm_computed: plain_counter(
                "cloudscape_warm_computed_total",
                "keyframes of play areas computed to keep them warm",
            ),
            warm_served: plain_counter("cloudscape_warm_served_total", "requests answered from bytes kept warm"),
            warm_lag: {
                let h = Histogram::with_opts(
                    HistogramOpts::new(
                        "cloudscape_warm_lag_seconds",
                        "how long before the clock reached its keyframe a warm keyframe was ready (negative: late)",
                    )
                    .buckets(vec![-60.0, -10.0, -1.0, 0.0, 1.0, 5.0, 10.0, 30.0, 60.0, 300.0]),
                )
                .expect("valid metric");
                registry.register(Box::new(h.clone())).expect("unique metric");
                h
            },
            warm_pending: gauge(
                "cloudscape_warm_pending",
                "keyframes of play areas (current or next) not computed yet",
            ),
            encodings: counter(
                "cloudscape_encodings_total",
                "compressed variants served, by coding and cache outcome",
                &["coding", "outcome"],
            ),
            kept_bytes: gauge("cloudscape_kept_bytes", "bytes of state tiles keep between keyframes"),
            kept_tiles: gauge("cloudscape_kept_tiles", "tiles with state kept between keyframes"),
            kept_grids: counter(
                "cloudscape_kept_grids_total",
                "density grids of tile jobs, by source: reused (kept grid), live (kept runs), cold",
                &["source"],
            ),
            kept_steps: plain_counter(
                "cloudscape_kept_steps_total",
                "automaton steps advanced by runs kept between keyframes",
            ),
            kept_shadings: counter(
                "cloudscape_kept_shadings_total",
                "instants of shading (metaballs and light) of tile jobs with kept state, by how: reused, shaded",
                &["how"],
            ),
            kept_busy: plain_counter(
                "cloudscape_kept_busy_total",
                "tile jobs that found their tile's kept state in use (computed cold)",
            ),
            stage_seconds: {
                let c = CounterVec::new(
                    Opts::new(
                        "cloudscape_stage_seconds_total",
                        "wall time of tile jobs by stage: automaton, steps, smoothing, far_field, reused, metaballs, shading, encoding, compression",
                    ),
                    &["stage"],
                )
                .expect("valid metric");
                registry.register(Box::new(c.clone())).expect("unique metric");
                c
            },
            registry,
        }
    }

    /// Adds the time of each stage of a tile job.
    pub fn observe_stages(&self, stages: &Stages) {
        for stage in Stage::ALL {
            let d = stages.get(stage);
            if !d.is_zero() {
                self.observe_stage(stage.name(), d);
            }
        }
    }

    /// Adds `d` to the time of stage `name`.
    pub fn observe_stage(&self, name: &str, d: std::time::Duration) {
        self.stage_seconds.with_label_values(&[name]).inc_by(d.as_secs_f64());
    }

    /// The text exposition format.
    pub fn render(&self) -> String {
        let mut buf = Vec::new();
        TextEncoder::new()
            .encode(&self.registry.gather(), &mut buf)
            .expect("text encoding cannot fail");
        String::from_utf8(buf).expect("exposition is UTF-8")
    }

    pub fn observe_compute(&self, kind: &str) -> Histogram {
        self.compute_seconds.with_label_values(&[kind])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::Method;

    #[test]
    fn method_labels_come_from_the_fixed_set() {
        for m in &METHODS[..9] {
            assert_eq!(method_label(&Method::from_bytes(m.as_bytes()).unwrap()), *m);
        }
        for odd in ["get", "PROPFIND", "BREW", &"X".repeat(16 << 10)] {
            assert_eq!(method_label(&Method::from_bytes(odd.as_bytes()).unwrap()), "other");
        }
    }
}
