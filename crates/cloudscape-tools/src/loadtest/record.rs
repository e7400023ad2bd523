//! What a load run measured: an HDR histogram of latencies (all requests, and one per
//! second of the run), status counts, bytes, and the report built from them.

use std::collections::BTreeMap;

use hdrhistogram::Histogram;
use serde::Serialize;

use super::sharing::{KeyframeKey, LevelSharing, SharingLog};
use super::workload::RequestKind;

/// Latencies are recorded in microseconds, up to an hour, to 3 significant digits.
const MAX_MICROS: u64 = 3_600_000_000;

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, MAX_MICROS, 3).expect("valid histogram bounds")
}

/// One finished request.
#[derive(Clone, Copy, Debug)]
pub struct Outcome {
    pub kind: RequestKind,
    /// HTTP status, or `None` when the request failed in transport (refused, timed out).
    pub status: Option<u16>,
    /// Seconds from the run's start to when the answer arrived.
    pub at: f64,
    /// Latency in microseconds: from the send in the closed loop, from the intended
    /// send time in the open loop.
    pub micros: u64,
    pub bytes: u64,
    /// Part of a player's first view.
    pub first_view: bool,
    /// Sent in the first real second after a level-0 keyframe boundary.
    pub after_boundary: bool,
    /// The tile keyframe asked for, and the asking agent's group (for the sharing figures).
    pub keyframe: Option<KeyframeKey>,
    pub group: u32,
    /// The product asked for ([`product_of`]), for the bytes by product.
    pub product: &'static str,
}

/// The products whose bytes a report splits a player's traffic into.
const PRODUCTS: [&str; 7] = [
    "billboards.bin",
    "billboards.delta.bin",
    "billboards.v2.bin",
    "shadow.png",
    "precipitation.png",
    "splats.json",
    "splats.png",
];

/// The product a request path asks for (its last segment, without the query), one of
/// [`PRODUCTS`], else `other`.
pub fn product_of(path: &str) -> &'static str {
    let name = path.split('?').next().unwrap_or("").rsplit('/').next().unwrap_or("");
    PRODUCTS.iter().copied().find(|p| *p == name).unwrap_or("other")
}

/// Counts of one second (or one kind) of the run.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Counts {
    pub requests: u64,
    /// 200 (and other 2xx).
    pub ok: u64,
    /// 304: the ETag the client held was still good.
    pub not_modified: u64,
    /// 503: the server shed the request (overloaded or over its time budget).
    pub shed: u64,
    /// Any other status (4xx, 5xx).
    pub other_status: u64,
    /// No answer: connection refused or reset, or the client's timeout.
    pub transport_errors: u64,
}

impl Counts {
    fn add(&mut self, status: Option<u16>) {
        self.requests += 1;
        match status {
            Some(200..=299) => self.ok += 1,
            Some(304) => self.not_modified += 1,
            Some(503) => self.shed += 1,
            Some(_) => self.other_status += 1,
            None => self.transport_errors += 1,
        }
    }
}

/// Everything recorded during a run. Shared by the workers behind a mutex.
pub struct Recorder {
    all: Histogram<u64>,
    /// Requests sent in the first second after a level-0 keyframe boundary, and the others.
    after_boundary: Histogram<u64>,
    elsewhere: Histogram<u64>,
    per_second: Vec<(Histogram<u64>, Counts)>,
    statuses: BTreeMap<u16, u64>,
    totals: Counts,
    by_kind: BTreeMap<RequestKind, Counts>,
    bytes: u64,
    /// Body bytes of players' requests (tiles, prefetches, splat sheets) measured.
    player_bytes: u64,
    /// Body bytes of the players' first views, warm-up or not.
    first_view_bytes: u64,
    /// Body bytes of players' requests measured, by product.
    product_bytes: BTreeMap<&'static str, u64>,
    /// Tile requests by keyframe.
    sharing: SharingLog,
    /// CPU use in each second of the run, as a share of one core: the generator's and
    /// the server's (`None` when unknown).
    cpu: Vec<(Option<f64>, Option<f64>)>,
    /// How late the generator's own timer fired ([`LAG_PERIOD_MS`] apart), in
    /// microseconds: the generator's scheduling delay, which its latencies include.
    lag: Histogram<u64>,
    /// The first transport error, to tell the operator what went wrong.
    pub first_error: Option<String>,
}

/// Period of the generator's lag probe, milliseconds: it sleeps this long, over and
/// over, and records how late it woke.
pub const LAG_PERIOD_MS: u64 = 10;

impl Default for Recorder {
    fn default() -> Self {
        Recorder {
            all: histogram(),
            after_boundary: histogram(),
            elsewhere: histogram(),
            per_second: Vec::new(),
            statuses: BTreeMap::new(),
            totals: Counts::default(),
            by_kind: BTreeMap::new(),
            bytes: 0,
            player_bytes: 0,
            first_view_bytes: 0,
            product_bytes: BTreeMap::new(),
            sharing: SharingLog::default(),
            cpu: Vec::new(),
            lag: histogram(),
            first_error: None,
        }
    }
}

/// Latency figures in milliseconds.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Latency {
    pub min_ms: f64,
    pub mean_ms: f64,
    pub p50_ms: f64,
    pub p90_ms: f64,
    pub p99_ms: f64,
    pub p999_ms: f64,
    pub max_ms: f64,
}

/// The keyframe-boundary spike: latency in the first real second after every level-0
/// keyframe boundary against the rest of the run.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct BoundaryLatency {
    pub after_boundary: Latency,
    pub elsewhere: Latency,
    pub after_boundary_requests: u64,
}

/// One second of the run.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct SecondSummary {
    /// Seconds since the start (answers that arrived in [second, second + 1)).
    pub second: u64,
    pub counts: Counts,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
    /// CPU used in that second, as a share of one core (1.0 = one core busy): the load
    /// generator's own, and the server's (when its /proc entry is readable, `--pid`).
    pub generator_cpu_cores: Option<f64>,
    pub server_cpu_cores: Option<f64>,
}

fn ms(micros: u64) -> f64 {
    micros as f64 / 1000.0
}

fn latency(h: &Histogram<u64>) -> Latency {
    if h.is_empty() {
        return Latency::default();
    }
    Latency {
        min_ms: ms(h.min()),
        mean_ms: h.mean() / 1000.0,
        p50_ms: ms(h.value_at_quantile(0.50)),
        p90_ms: ms(h.value_at_quantile(0.90)),
        p99_ms: ms(h.value_at_quantile(0.99)),
        p999_ms: ms(h.value_at_quantile(0.999)),
        max_ms: ms(h.max()),
    }
}

impl Recorder {
    pub fn record(&mut self, o: Outcome) {
        let v = o.micros.clamp(1, MAX_MICROS);
        self.all.saturating_record(v);
        if o.after_boundary {
            self.after_boundary.saturating_record(v);
        } else {
            self.elsewhere.saturating_record(v);
        }
        let second = o.at.max(0.0) as usize;
        while self.per_second.len() <= second {
            self.per_second.push((histogram(), Counts::default()));
        }
        self.per_second[second].0.saturating_record(v);
        self.per_second[second].1.add(o.status);
        if let Some(s) = o.status {
            *self.statuses.entry(s).or_default() += 1;
        }
        self.totals.add(o.status);
        self.by_kind.entry(o.kind).or_default().add(o.status);
        self.bytes += o.bytes;
        if matches!(o.kind, RequestKind::Tile | RequestKind::Prefetch | RequestKind::Splats) {
            self.player_bytes += o.bytes;
            *self.product_bytes.entry(o.product).or_default() += o.bytes;
        }
        if let Some(k) = o.keyframe {
            self.sharing.record(k, o.group);
        }
    }

    /// Notes one wake-up of the lag probe, `micros` after it was due.
    pub fn record_lag(&mut self, micros: u64) {
        self.lag.saturating_record(micros.clamp(1, MAX_MICROS));
    }

    /// How late the generator's lag probe woke over the measured run: when this is
    /// close to the requests' latency, the latency is the generator's, not the server's.
    pub fn lag(&self) -> Latency {
        latency(&self.lag)
    }

    /// Notes the CPU used in second `second` of the measured run (shares of a core).
    pub fn record_cpu(&mut self, second: usize, generator: Option<f64>, server: Option<f64>) {
        if self.cpu.len() <= second {
            self.cpu.resize(second + 1, (None, None));
        }
        self.cpu[second] = (generator, server);
    }

    /// How much the groups shared, per level.
    pub fn sharing(&self) -> Vec<LevelSharing> {
        self.sharing.by_level()
    }

    pub fn totals(&self) -> &Counts {
        &self.totals
    }

    pub fn latency(&self) -> Latency {
        latency(&self.all)
    }

    /// Latency of the requests sent in the first second after a level-0 keyframe
    /// boundary, and of all the others.
    pub fn boundary_latency(&self) -> BoundaryLatency {
        BoundaryLatency {
            after_boundary: latency(&self.after_boundary),
            elsewhere: latency(&self.elsewhere),
            after_boundary_requests: self.after_boundary.len(),
        }
    }

    pub fn statuses(&self) -> BTreeMap<String, u64> {
        self.statuses.iter().map(|(k, v)| (k.to_string(), *v)).collect()
    }

    pub fn by_kind(&self) -> BTreeMap<RequestKind, Counts> {
        self.by_kind.clone()
    }

    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Notes the body of a request of a player's first view, measured or not.
    pub fn record_first_view(&mut self, bytes: u64) {
        self.first_view_bytes += bytes;
    }

    /// Body bytes of the players' measured requests.
    pub fn player_bytes(&self) -> u64 {
        self.player_bytes
    }

    /// Body bytes of the players' first views.
    pub fn first_view_bytes(&self) -> u64 {
        self.first_view_bytes
    }

    /// Body bytes of the players' measured requests, by product.
    pub fn product_bytes(&self) -> BTreeMap<&'static str, u64> {
        self.product_bytes.clone()
    }

    pub fn timeline(&self) -> Vec<SecondSummary> {
        (0..self.per_second.len().max(self.cpu.len()))
            .map(|i| {
                let (l, counts) = self.per_second.get(i).map_or_else(
                    || (Latency::default(), Counts::default()),
                    |(h, c)| (latency(h), c.clone()),
                );
                let (generator_cpu_cores, server_cpu_cores) = self.cpu.get(i).copied().unwrap_or_default();
                SecondSummary {
                    second: i as u64,
                    counts,
                    p50_ms: l.p50_ms,
                    p99_ms: l.p99_ms,
                    max_ms: l.max_ms,
                    generator_cpu_cores,
                    server_cpu_cores,
                }
            })
            .collect()
    }

    /// The latency at quantiles 0, 0.5, 0.75, 0.875, … up to 0.99999 and the maximum:
    /// the HDR "percentile distribution" curve.
    pub fn distribution(&self) -> Vec<(f64, f64)> {
        if self.all.is_empty() {
            return Vec::new();
        }
        let mut out = Vec::new();
        let mut q = 0.0;
        while q < 0.99999 {
            out.push((q, ms(self.all.value_at_quantile(q))));
            q = 1.0 - (1.0 - q) / 2.0;
        }
        out.push((0.99999, ms(self.all.value_at_quantile(0.99999))));
        out.push((1.0, ms(self.all.max())));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_quantiles_are_ordered() {
        let mut r = Recorder::default();
        for (i, status) in [Some(200), Some(304), Some(503), None, Some(404)]
            .into_iter()
            .enumerate()
        {
            r.record(Outcome {
                kind: RequestKind::Tile,
                status,
                at: i as f64 * 0.6,
                micros: 1000 * (i as u64 + 1),
                bytes: 10,
                first_view: false,
                after_boundary: i == 4,
                keyframe: None,
                group: 0,
                product: product_of("/v1/worlds/w/tiles/0/0/0/billboards.delta.bin?t=20"),
            });
        }
        assert_eq!(r.product_bytes().get("billboards.delta.bin"), Some(&r.player_bytes()));
        assert_eq!(product_of("/v1/splats.png?quality=fast"), "splats.png");
        assert_eq!(product_of("/v1/worlds/w/tiles/0/0/0/coverage.png?t=0"), "other");
        let t = r.totals();
        assert_eq!(
            (
                t.requests,
                t.ok,
                t.not_modified,
                t.shed,
                t.other_status,
                t.transport_errors
            ),
            (5, 1, 1, 1, 1, 1)
        );
        let l = r.latency();
        assert!(l.min_ms <= l.p50_ms && l.p50_ms <= l.p90_ms && l.p90_ms <= l.p99_ms && l.p99_ms <= l.max_ms);
        assert!((l.max_ms - 5.0).abs() < 0.01, "{l:?}");
        assert_eq!(r.timeline().len(), 3);
        let d = r.distribution();
        assert!(d.windows(2).all(|w| w[0].0 < w[1].0 && w[0].1 <= w[1].1));
        assert_eq!(r.statuses().get("503"), Some(&1));
        let b = r.boundary_latency();
        assert_eq!(b.after_boundary_requests, 1);
        assert!((b.after_boundary.max_ms - 5.0).abs() < 0.01 && (b.elsewhere.max_ms - 4.0).abs() < 0.01);
    }
}
