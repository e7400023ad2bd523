//! Weather products against the cloud tile they come from (issue 24 figures): a cold
//! level-0 density tile of the storm front's cumulonimbus layer, and the
//! `precipitation.png` (and, for scale, `coverage.png`) encoded from that grid, and a
//! lightning query over the same square.
//!
//!     cargo bench --bench weather
//!
//! BENCHMARKS.md ("Weather") holds the figures of a run on the project machine.

use std::hint::black_box;
use std::time::Duration;

use cloudscape_core::density::{self, Region};
use cloudscape_core::products::{coverage, precipitation};
use cloudscape_core::weather::lightning::{self, LightningLimits, LightningPlan};
use cloudscape_core::world::Config;
use criterion::{Criterion, criterion_group, criterion_main};

fn weather(c: &mut Criterion) {
    let mut g = c.benchmark_group("weather");
    g.sample_size(10)
        .measurement_time(Duration::from_secs(5))
        .warm_up_time(Duration::from_secs(1));
    let w = Config::embedded().world("storm-front").unwrap();
    let layer = &w.layers[0];
    // A tile inside the band (y ≈ 30 km at t ≈ 0): rain in most columns.
    let region = Region::square(0, 256, 256);
    let mut t = 1234.5;
    g.bench_function("cold density tile 256x256x30 cumulonimbus", |b| {
        b.iter(|| {
            t += 977.0; // a different epoch every iteration: nothing is reused
            black_box(density::density(&w, 0, 0, region, t).unwrap())
        })
    });
    let grid = density::density(&w, 0, 0, region, 1234.5).unwrap();
    g.bench_function("precipitation.png from that grid", |b| {
        b.iter(|| black_box(precipitation::encode_png(layer, &grid)))
    });
    g.bench_function("coverage.png from that grid", |b| {
        b.iter(|| black_box(coverage::encode_png_from_grid(layer, &grid, 0)))
    });
    // A lightning query over the same tile's 25.6 km square for 10 minutes (ten
    // level-3 density grids of 32×32 columns).
    let bbox = [0.0, 25_600.0, 25_600.0, 51_200.0];
    let plan = LightningPlan::new(&w, 0, bbox, 1200.0, 1800.0, &LightningLimits::default()).unwrap();
    g.bench_function("lightning 25.6 km square, 600 s", |b| {
        b.iter(|| black_box(lightning::strikes(&w, 0, bbox, 1200.0, 1800.0, &plan).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, weather);
criterion_main!(benches);
