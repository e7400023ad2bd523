//! Simulation-core benchmarks: automaton (packed vs naive), fields (ours vs the
//! `noise` crate), cold tile density, far-field levels. Accuracy figures that go
//! with the speed ones (LOD error, coarse-lattice error, bounded-history distance)
//! are computed once and printed before the timings.
//!
//!     cargo bench --bench core
//!
//! BENCHMARKS.md holds the figures of a run on the project machine.

use std::hint::black_box;
use std::time::Duration;

use cloudscape_core::automaton::kernel::Rect;
use cloudscape_core::automaton::naive;
use cloudscape_core::automaton::{LayerSim, RunSpec, plan_step};
use cloudscape_core::cpu::Backend;
use cloudscape_core::density::{self, Region, exact};
use cloudscape_core::fields::noise::NoiseBackend;
use cloudscape_core::world::{Config, Event, World};
use cloudscape_tools::bench::core::{FIELDS_FBM, Grids, packed_steps, scene, step_grids, to_naive};
use criterion::measurement::WallTime;
use criterion::{BatchSize, BenchmarkGroup, BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use noise::{MultiFractal, NoiseFn};

/// The overcast world: its stratocumulus deck is the layer every figure here (and the
/// far-field calibration) was measured on.
fn world() -> World {
    Config::embedded().world("overcast").unwrap()
}

/// A group of 10 samples after 1 s of warm-up, measured for `seconds`: every figure
/// here times a whole, slow operation.
fn group<'a>(c: &'a mut Criterion, name: &str, seconds: u64) -> BenchmarkGroup<'a, WallTime> {
    let mut g = c.benchmark_group(name);
    g.sample_size(10)
        .measurement_time(Duration::from_secs(seconds))
        .warm_up_time(Duration::from_secs(1));
    g
}

fn automaton(c: &mut Criterion) {
    let mut g = group(c, "automaton", 4);
    let (sim, levels, drives) = scene(512);
    let cells = (512 * 512 * sim.depth()) as u64;
    g.throughput(Throughput::Elements(cells * 8));
    // `grids reused`: the two grids are copied right before each timed run and
    // outside it, as a run allocates them once (not once per 8 steps) and steps
    // warm state. The id without it times the copies as well, and stays so that
    // its figures compare with the ones already in BENCHMARKS.md.
    g.bench_function("packed 512x512x10, grids reused, 8 steps", |b| {
        b.iter_batched_ref(
            || Grids::of(&levels),
            |g| step_grids(&sim, &drives, g, 8),
            BatchSize::PerIteration,
        )
    });
    g.bench_function("packed 512x512x10, 8 steps", |b| {
        b.iter(|| packed_steps(&sim, &levels, &drives, 8))
    });
    let (small_sim, small_levels, small_drives) = scene(128);
    let (nl, nd) = to_naive(&small_levels, &small_drives);
    let small_cells = (128 * 128 * small_sim.depth()) as u64;
    g.throughput(Throughput::Elements(small_cells));
    g.bench_function("naive 128x128x10, 1 step", |b| {
        b.iter(|| {
            let offsets = small_sim.offsets(64);
            black_box(naive::step(&nl, &nd, small_sim.rules(), small_sim.stream, 64, &offsets))
        })
    });
    g.finish();
}

fn fields(c: &mut Criterion) {
    let mut g = group(c, "fields", 3);
    let n = 64 * 64;
    g.throughput(Throughput::Elements(n));
    let ours = FIELDS_FBM;
    g.bench_function("ours fbm2 4 octaves", |b| {
        b.iter(|| {
            let mut s = 0.0;
            for i in 0..n as i64 {
                s += ours.sample(4, (i % 64, 0.5), (i / 64, 0.5), None);
            }
            black_box(s)
        })
    });
    let theirs = noise::Fbm::<noise::Simplex>::new(3)
        .set_octaves(4)
        .set_frequency(0.02)
        .set_lacunarity(2.0)
        .set_persistence(0.5);
    g.bench_function("noise crate Fbm<Simplex> 4 octaves", |b| {
        b.iter(|| {
            let mut s = 0.0;
            for i in 0..n as i64 {
                s += theirs.get([(i % 64) as f64 + 0.5, (i / 64) as f64 + 0.5]);
            }
            black_box(s)
        })
    });
    let lf = LayerSim::new(&world(), 0).fields;
    for (name, spacing) in [("exact", [1u32; 3]), ("coarse lattice", lf.coarse_spacing())] {
        g.throughput(Throughput::Elements(256 * 256 * 3));
        g.bench_function(BenchmarkId::new("layer window 256x256x3", name), |b| {
            b.iter(|| black_box(lf.window(0, 0, 256, 256, spacing, None, (0, 0))))
        });
    }
    g.finish();
}

fn tiles(c: &mut Criterion) {
    let mut g = group(c, "tile", 6);
    let w = world();
    let mut t = 1234.5;
    for level in [0u32, 2, 4] {
        let region = Region::square(256 * 3, -256 * 2, 256);
        g.bench_function(
            BenchmarkId::new("cold density 256x256 stratocumulus, level", level),
            |b| {
                b.iter(|| {
                    t += 977.0; // a different time (and epoch) every iteration: nothing is reused
                    black_box(density::density(&w, 0, level, region, t).unwrap())
                })
            },
        );
    }
    let region = Region::square(0, 0, 256);
    for tt in [1e3, 1e12] {
        g.bench_function(BenchmarkId::new("density 256x256 at t", tt), |b| {
            b.iter(|| black_box(density::density(&w, 0, 0, region, tt).unwrap()))
        });
    }
    // The per-cell hashes that pick a run in an epoch cross-fade, over one level's
    // tile window, on each backend (same bits; a cold tile makes one per level).
    let window = Rect {
        x0: 768,
        x1: 768 + 256,
        y0: -512,
        y1: -512 + 256,
    };
    for &backend in NoiseBackend::available() {
        g.throughput(Throughput::Elements(256 * 256));
        g.bench_function(BenchmarkId::new("switch hashes 256x256", format!("{backend:?}")), |b| {
            b.iter(|| black_box(exact::switch_hashes_on(backend, 1, 0, window)))
        });
    }
    g.finish();
}

/// Accuracy figures, printed once.
fn accuracy() {
    let w = world();
    // Far-field levels against the downsampled automaton (held-out seed and time).
    for (seed, t) in [("1", 1000.0), ("99", 86_400.0 * 3.0 + 17.0)] {
        let mut wd = world();
        wd.seed = seed.parse().unwrap();
        let region = Region::square(-512, 256, 512);
        let full = density::density(&wd, 0, 0, region, t).unwrap();
        for level in [1u32, 2, 3, 4, 5] {
            let s = 1usize << level;
            let lod_region = Region::square(region.x0 >> level, region.y0 >> level, 512 / s);
            let lod = density::density(&wd, 0, level, lod_region, t).unwrap();
            let (mut se, mut bias, mut n) = (0f64, 0f64, 0f64);
            for k in 0..full.depth {
                for r in 0..lod_region.rows {
                    for c in 0..lod_region.cols {
                        let mut m = 0f64;
                        for dy in 0..s {
                            for dx in 0..s {
                                m += full.get(k, r * s + dy, c * s + dx) as f64;
                            }
                        }
                        m /= (s * s) as f64;
                        let e = lod.get(k, r, c) as f64 - m;
                        se += e * e;
                        bias += e;
                        n += 1.0;
                    }
                }
            }
            println!(
                "lod seed {seed} t {t}: level {level}: rmse {:.4}, bias {:+.4}",
                (se / n).sqrt(),
                bias / n
            );
        }
    }
    // Coarse-lattice field error.
    let lf = LayerSim::new(&w, 0).fields;
    let sp = lf.coarse_spacing();
    let exact = lf.window(0, 0, 256, 256, [1; 3], None, (0, 0));
    let coarse = lf.window(0, 0, 256, 256, sp, None, (0, 0));
    for (i, name) in [
        (Event::Humidity, "humidity"),
        (Event::Activation, "activation"),
        (Event::Extinction, "extinction"),
    ] {
        let i = i as usize;
        let max = exact.b[i]
            .iter()
            .zip(&coarse.b[i])
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        println!("coarse lattice {name}: spacing {} cells, max error {max:.4}", sp[i]);
    }
    // Bounded history against a long continuous run: the same cells at the same step.
    let sim = LayerSim::new(&w, 0);
    let layer = &sim.fields.layer;
    let window = Rect {
        x0: 0,
        x1: 128,
        y0: 0,
        y1: 128,
    };
    for m in [200i64, 208, 215] {
        let plan = plan_step(layer, m);
        let run = plan.runs[plan.runs.len() - 1];
        let long_start = run.start - 400;
        let mut diffs = 0usize;
        let mut total = 0usize;
        let short = sim.run(&RunSpec {
            reference_step: run.reference,
            start: run.start,
            snapshots: vec![m],
            windows: vec![window; sim.depth()],
        });
        let long = sim.run(&RunSpec {
            reference_step: run.reference,
            start: long_start,
            snapshots: vec![m],
            windows: vec![window; sim.depth()],
        });
        for k in 0..sim.depth() {
            for y in 0..128 {
                for x in 0..128 {
                    total += 1;
                    diffs += (short[0].levels[k].cld_at(x, y) != long[0].levels[k].cld_at(x, y)) as usize;
                }
            }
        }
        println!(
            "bounded history at step {m}: run of {} steps vs {} steps differs in {:.4} of cells",
            m - run.start,
            m - long_start,
            diffs as f64 / total as f64
        );
    }
}

fn all(c: &mut Criterion) {
    accuracy();
    automaton(c);
    fields(c);
    tiles(c);
}

criterion_group!(benches, all);
criterion_main!(benches);
