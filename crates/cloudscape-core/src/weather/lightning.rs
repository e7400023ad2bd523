//! Lightning: strikes as a deterministic, counter-based point process inside deep
//! convective cloud.
//!
//! Space and time are cut into *flash cells*: one level-[`FLASH_LEVEL`] column of the
//! layer (8 × 8 level-0 columns) over a [`FLASH_DT`]-second bucket. A flash cell's
//! rate comes from its column at the bucket's start (the level-3 density, a pure
//! function of the column and time like every density):
//!
//! - **depth**: the cloudy thickness `D` (cells with density ≥ 0.1) must reach
//!   [`MIN_DEPTH`] (deep convection; shallower clouds do not electrify), and the cloud
//!   top `H` (km above sea level) sets the storm's flash rate by Price & Rind 1992
//!   (JGR 97, "A simple lightning parameterization…"), continental storms:
//!   `F = 3.44·10⁻⁵ H^4.9` flashes per minute per storm;
//! - **activation**: the mean density of the cloudy cells (how much of the column is
//!   active cloud) scales it;
//! - the storm rate is spread over a nominal storm area of [`STORM_AREA_M2`]
//!   (100 km²) in proportion to the flash cell's area, and multiplied by the preset's
//!   `lightning` factor (0 for everything but cumulonimbus).
//!
//! The number of strikes in a flash cell is Poisson with mean `rate · FLASH_DT`,
//! drawn by inverting its CDF with a uniform that is a hash of (seed, layer, column,
//! row, bucket), never a stateful RNG, so any machine computes any flash cell. Each
//! strike's time, position and kind are further hashes of the same counter plus its
//! index: uniform in the bucket and the cell; cloud-to-ground with probability
//! [`CG_FRACTION`] (an IC:CG ratio of 3, Boccippio et al. 2001's continental US
//! median), with `z = 0` (the ground contact); intra-cloud otherwise, with `z` uniform
//! between the column's cloud base and top. A query keeps the strikes whose (x, y, t)
//! fall in its half-open box and span, so a box's strikes are exactly the union of
//! its halves'.

use serde::Serialize;

use crate::density::{self, CLOUD_THRESHOLD, Region, SimError, check_time};
use crate::fields::noise::mix64;
use crate::world::World;

/// The level whose columns are flash cells.
pub const FLASH_LEVEL: u32 = 3;
/// Seconds per flash-cell bucket.
pub const FLASH_DT: f64 = 60.0;
/// Least cloudy thickness (metres) of a column that produces lightning.
pub const MIN_DEPTH: f64 = 3000.0;
/// The area one Price & Rind storm rate is spread over, m².
pub const STORM_AREA_M2: f64 = 100.0e6;
/// Share of strikes that reach the ground.
pub const CG_FRACTION: f64 = 0.25;
/// Most strikes one flash cell gives in one bucket (the Poisson tail beyond it is cut).
pub const MAX_STRIKES_PER_CELL: u32 = 64;

/// Bounds on one lightning query, checked before any work.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightningLimits {
    /// Longest span `t1 − t0`, seconds.
    pub max_span: f64,
    /// Longest bbox side, metres.
    pub max_side: f64,
}

impl Default for LightningLimits {
    fn default() -> Self {
        LightningLimits {
            max_span: 3600.0,
            max_side: 50_000.0,
        }
    }
}

/// Cloud-to-ground or intra-cloud.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum StrikeKind {
    /// Cloud-to-ground: `z` is the ground contact (0).
    Cg,
    /// Intra-cloud: `z` is inside the cloud.
    Ic,
}

/// One strike.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Strike {
    /// World time, seconds.
    pub t: f64,
    /// East, metres.
    pub x: f64,
    /// North, metres.
    pub y: f64,
    /// Altitude, metres.
    pub z: f64,
    /// Cloud-to-ground or intra-cloud.
    pub kind: StrikeKind,
}

/// A lightning query refused before any work.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LightningError {
    /// The span or box is over a limit (the message names it).
    #[error("{0}")]
    TooLarge(String),
    /// A malformed box, time or coordinates.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// `t1` is not after `t0`.
    #[error("t1 must be greater than t0")]
    EmptySpan,
}

/// The flash-cell columns and buckets a query reads, checked against `limits`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightningPlan {
    /// The flash-cell columns (level [`FLASH_LEVEL`]) that meet the box.
    pub region: Region,
    /// First bucket index.
    pub bucket0: u64,
    /// Buckets from `bucket0`.
    pub buckets: u64,
}

impl LightningPlan {
    /// Checks the query and lays out its flash cells; no density is computed.
    pub fn new(
        world: &World,
        layer: usize,
        bbox: [f64; 4],
        t0: f64,
        t1: f64,
        limits: &LightningLimits,
    ) -> Result<LightningPlan, LightningError> {
        let (t0, t1) = (check_time(t0)?, check_time(t1)?);
        if !(t1 > t0) {
            return Err(LightningError::EmptySpan);
        }
        if t1 - t0 > limits.max_span {
            return Err(LightningError::TooLarge(format!(
                "the span is {} s; the limit is {} s",
                t1 - t0,
                limits.max_span
            )));
        }
        let [x0, y0, x1, y1] = bbox;
        if !(bbox.iter().all(|v| v.is_finite()) && x0 < x1 && y0 < y1) {
            return Err(SimError::BadBbox.into());
        }
        if x1 - x0 > limits.max_side || y1 - y0 > limits.max_side {
            return Err(LightningError::TooLarge(format!(
                "the bbox is {} × {} m; the limit is {} m a side",
                x1 - x0,
                y1 - y0,
                limits.max_side
            )));
        }
        let l = world
            .layers
            .get(layer)
            .ok_or_else(|| SimError::OutOfRange(format!("no layer {layer}")))?;
        let w = l.cell_size * (FLASH_LEVEL as f64).exp2();
        let (c0, c1) = ((x0 / w).floor(), (x1 / w).ceil());
        let (r0, r1) = ((y0 / w).floor(), (y1 / w).ceil());
        let lim = (density::MAX_CELL_INDEX >> FLASH_LEVEL) as f64;
        if [c0, c1, r0, r1].iter().any(|v| v.abs() > lim) {
            return Err(SimError::OutOfRange(format!("the bbox reaches beyond ±{lim} flash cells")).into());
        }
        let b0 = (t0 / FLASH_DT).floor();
        let b1 = (t1 / FLASH_DT).ceil();
        Ok(LightningPlan {
            region: Region {
                x0: c0 as i64,
                y0: r0 as i64,
                cols: (c1 - c0) as usize,
                rows: (r1 - r0) as usize,
            },
            bucket0: b0 as u64,
            buckets: (b1 - b0) as u64,
        })
    }

    /// The start time of bucket `i` of the plan.
    pub fn bucket_time(&self, i: u64) -> f64 {
        (self.bucket0 + i) as f64 * FLASH_DT
    }
}

/// A uniform in [0, 1) from a 64-bit hash (its top 53 bits).
fn unit(h: u64) -> f64 {
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// The counter of a flash cell: seed, layer, column, row, bucket.
fn counter(seed: u64, layer: usize, col: i64, row: i64, bucket: u64) -> u64 {
    let mut h = mix64(seed ^ 0x4c49_4748_544e_494e); // "LIGHTNIN"
    for v in [layer as u64, col as u64, row as u64, bucket] {
        h = mix64(h ^ v.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    }
    h
}

/// Price & Rind 1992: flashes per minute of a continental storm whose top is `h_km`.
pub fn price_rind_flashes_per_min(h_km: f64) -> f64 {
    if h_km > 0.0 { 3.44e-5 * h_km.powf(4.9) } else { 0.0 }
}

/// Strikes per second of one flash cell whose column (densities from the layer base,
/// `cell_height` metres each) belongs to `layer` of `world`, with `factor` the
/// preset's lightning factor and `cell_area` the flash cell's area (m²).
pub fn flash_rate(column: &[f32], base: f64, cell_height: f64, factor: f64, cell_area: f64) -> f64 {
    let cloudy: Vec<(usize, f32)> = column
        .iter()
        .copied()
        .enumerate()
        .filter(|&(_, d)| d >= CLOUD_THRESHOLD)
        .collect();
    let depth = cloudy.len() as f64 * cell_height;
    if !(factor > 0.0) || depth < MIN_DEPTH {
        return 0.0;
    }
    let top_km = (base + (cloudy.last().map_or(0, |c| c.0) + 1) as f64 * cell_height) / 1000.0;
    let activation = cloudy.iter().map(|c| c.1.min(1.0) as f64).sum::<f64>() / cloudy.len() as f64;
    factor * activation * price_rind_flashes_per_min(top_km) / 60.0 * (cell_area / STORM_AREA_M2)
}

/// The smallest `n` with Poisson(`mean`) CDF(n) > `u`, capped.
fn poisson(mean: f64, u: f64) -> u32 {
    let mut p = (-mean).exp();
    let mut cdf = p;
    let mut n = 0;
    while u >= cdf && n < MAX_STRIKES_PER_CELL {
        n += 1;
        p *= mean / n as f64;
        cdf += p;
    }
    n
}

/// The strikes of layer `layer` of `world` in `bbox` (half-open) during `[t0, t1)`,
/// sorted by time (then x, y). `plan` is [`LightningPlan::new`]'s for the same query.
pub fn strikes(
    world: &World,
    layer: usize,
    bbox: [f64; 4],
    t0: f64,
    t1: f64,
    plan: &LightningPlan,
) -> Result<Vec<Strike>, SimError> {
    let l = &world.layers[layer];
    let factor = l.preset.lightning;
    let mut out = Vec::new();
    if !(factor > 0.0) {
        return Ok(out);
    }
    let w = l.cell_size * (FLASH_LEVEL as f64).exp2();
    let r = plan.region;
    let mut column = vec![0.0f32; l.depth as usize];
    for b in 0..plan.buckets {
        let tb = plan.bucket_time(b);
        let grid = density::density(world, layer, FLASH_LEVEL, r, tb)?;
        for row in 0..r.rows {
            for col in 0..r.cols {
                for (k, v) in column.iter_mut().enumerate() {
                    *v = grid.get(k, row, col);
                }
                let rate = flash_rate(&column, l.base, l.cell_height, factor, w * w);
                if rate <= 0.0 {
                    continue;
                }
                let (c, rw) = (r.x0 + col as i64, r.y0 + row as i64);
                let key = counter(world.seed, layer, c, rw, plan.bucket0 + b);
                let n = poisson(rate * FLASH_DT, unit(key));
                let cloudy: Vec<usize> = (0..column.len()).filter(|&k| column[k] >= CLOUD_THRESHOLD).collect();
                let (lo, hi) = (
                    l.base + cloudy[0] as f64 * l.cell_height,
                    l.base + (cloudy[cloudy.len() - 1] + 1) as f64 * l.cell_height,
                );
                for i in 0..n {
                    let h = |j: u64| unit(mix64(key ^ mix64((i as u64) << 8 | j)));
                    let s = Strike {
                        t: tb + h(1) * FLASH_DT,
                        x: (c as f64 + h(2)) * w,
                        y: (rw as f64 + h(3)) * w,
                        z: 0.0,
                        kind: if h(4) < CG_FRACTION {
                            StrikeKind::Cg
                        } else {
                            StrikeKind::Ic
                        },
                    };
                    let s = Strike {
                        z: match s.kind {
                            StrikeKind::Cg => 0.0,
                            StrikeKind::Ic => lo + h(5) * (hi - lo),
                        },
                        ..s
                    };
                    let [x0, y0, x1, y1] = bbox;
                    if x0 <= s.x && s.x < x1 && y0 <= s.y && s.y < y1 && t0 <= s.t && s.t < t1 {
                        out.push(s);
                    }
                }
            }
        }
    }
    out.sort_by(|a, b| a.t.total_cmp(&b.t).then(a.x.total_cmp(&b.x)).then(a.y.total_cmp(&b.y)));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Config;

    fn storm() -> World {
        Config::embedded().world("storm-front").unwrap()
    }

    fn query(w: &World, bbox: [f64; 4], t0: f64, t1: f64) -> Vec<Strike> {
        let plan = LightningPlan::new(w, 0, bbox, t0, t1, &LightningLimits::default()).unwrap();
        strikes(w, 0, bbox, t0, t1, &plan).unwrap()
    }

    #[test]
    fn price_and_rind_by_hand() {
        // 3.44e-5 · 10^4.9 = 2.73 flashes/min for a 10 km top.
        assert!((price_rind_flashes_per_min(10.0) - 2.7325).abs() < 1e-3);
        assert_eq!(price_rind_flashes_per_min(0.0), 0.0);
        // Shallow columns give nothing; deeper and denser give more.
        let shallow = vec![1.0f32; 10];
        assert_eq!(flash_rate(&shallow, 800.0, 200.0, 1.0, 640_000.0), 0.0);
        let deep = vec![0.5f32; 30];
        let denser = vec![1.0f32; 30];
        let a = flash_rate(&deep, 800.0, 200.0, 1.0, 640_000.0);
        let b = flash_rate(&denser, 800.0, 200.0, 1.0, 640_000.0);
        assert!(a > 0.0 && b > a);
        assert_eq!(flash_rate(&denser, 800.0, 200.0, 0.0, 640_000.0), 0.0);
    }

    #[test]
    fn poisson_inversion_matches_the_cdf() {
        assert_eq!(poisson(0.0, 0.999), 0);
        // mean 1: P(0) = 0.3679, P(≤1) = 0.7358, P(≤2) = 0.9197.
        assert_eq!(poisson(1.0, 0.3), 0);
        assert_eq!(poisson(1.0, 0.5), 1);
        assert_eq!(poisson(1.0, 0.9), 2);
        assert_eq!(poisson(1e9, 0.5), MAX_STRIKES_PER_CELL);
    }

    #[test]
    fn a_box_holds_the_union_of_its_halves_and_the_storm_flashes() {
        let w = storm();
        let bbox = [-10_000.0, 20_000.0, 10_000.0, 40_000.0];
        let all = query(&w, bbox, 0.0, 900.0);
        assert!(all.len() > 5, "the storm band should flash: {}", all.len());
        assert!(all.iter().any(|s| s.kind == StrikeKind::Cg) && all.iter().any(|s| s.kind == StrikeKind::Ic));
        let west = query(&w, [-10_000.0, 20_000.0, 1234.5, 40_000.0], 0.0, 900.0);
        let east = query(&w, [1234.5, 20_000.0, 10_000.0, 40_000.0], 0.0, 900.0);
        let early = query(&w, bbox, 0.0, 456.7);
        let late = query(&w, bbox, 456.7, 900.0);
        for halves in [[west, east], [early, late]] {
            let mut union: Vec<Strike> = halves.concat();
            union.sort_by(|a, b| a.t.total_cmp(&b.t).then(a.x.total_cmp(&b.x)).then(a.y.total_cmp(&b.y)));
            assert_eq!(union, all);
        }
        for s in &all {
            assert!(s.t >= 0.0 && s.t < 900.0 && s.x >= bbox[0] && s.x < bbox[2]);
            let l = &w.layers[0];
            match s.kind {
                StrikeKind::Cg => assert_eq!(s.z, 0.0),
                StrikeKind::Ic => assert!(s.z >= l.base && s.z <= l.top()),
            }
        }
        // Fair weather: no lightning.
        let fair = Config::embedded().world("default").unwrap();
        assert!(query(&fair, bbox, 0.0, 900.0).is_empty());
    }

    #[test]
    fn the_same_query_gives_the_same_strikes_on_any_thread_count() {
        let w = storm();
        let bbox = [-5_000.0, 25_000.0, 5_000.0, 35_000.0];
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| query(&w, bbox, 60.0, 600.0))
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn limits_are_checked_before_any_work() {
        let w = storm();
        let lim = LightningLimits::default();
        let plan = |bbox, t0, t1| LightningPlan::new(&w, 0, bbox, t0, t1, &lim);
        let ok = [0.0, 0.0, 1000.0, 1000.0];
        assert!(matches!(plan(ok, 0.0, 3601.0), Err(LightningError::TooLarge(_))));
        assert!(matches!(
            plan([0.0, 0.0, 60_000.0, 10.0], 0.0, 60.0),
            Err(LightningError::TooLarge(_))
        ));
        assert!(matches!(plan(ok, 60.0, 60.0), Err(LightningError::EmptySpan)));
        assert!(matches!(
            plan(ok, -1.0, 60.0),
            Err(LightningError::Sim(SimError::BadTime(_)))
        ));
        assert!(matches!(
            plan([1.0, 0.0, 0.0, 1.0], 0.0, 60.0),
            Err(LightningError::Sim(SimError::BadBbox))
        ));
        assert!(matches!(
            plan([1e18, 0.0, 1e18 + 1e4, 1.0], 0.0, 60.0),
            Err(LightningError::Sim(SimError::OutOfRange(_)))
        ));
        let p = plan([-100.0, 0.0, 900.0, 800.0], 30.0, 150.0).unwrap();
        assert_eq!((p.region.x0, p.region.cols, p.region.rows), (-1, 3, 1));
        assert_eq!((p.bucket0, p.buckets), (0, 3));
    }
}
