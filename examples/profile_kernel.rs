//! Profiling driver (not a benchmark): `valgrind --tool=callgrind` counts the
//! instructions of the packed kernel or of one cold tile, repeatably on a busy machine.
//!
//!     cargo build --release --example profile_kernel
//!     valgrind --tool=callgrind --toggle-collect='*step_level*' target/release/examples/profile_kernel kernel
//!     valgrind --tool=callgrind target/release/examples/profile_kernel tile
//!     target/release/examples/profile_kernel scene   # best of 30 rounds of the criterion scene
//!
//! `RUST_LOG=cloudscape=debug … tile` logs each tile's phases: per run the field
//! window, the conversion to drives and the steps, then the smoothing.
//!
//! `STEPS=N` (default 8) sets the kernel run's length, e.g. `STEPS=100` for a
//! wall-clock or `perf record` run long enough to sample; `SIZE=N` (default 192)
//! the side of the window in cells.
//!
//! valgrind does not run AVX-512, so under callgrind the kernel takes its portable draws.

use std::hint::black_box;

use cloudscape_core::density::{self, Region};
use cloudscape_core::world::Config;

/// CPU time of every thread of this process so far (ns), from /proc/self/task/*/schedstat.
/// On a VM whose vCPUs are often stolen this excludes the stolen time, which wall
/// time does not.
fn cpu_ns() -> u64 {
    let mut sum = 0;
    for task in std::fs::read_dir("/proc/self/task").into_iter().flatten().flatten() {
        if let Ok(s) = std::fs::read_to_string(task.path().join("schedstat")) {
            sum += s
                .split_whitespace()
                .next()
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0);
        }
    }
    sum
}

fn main() {
    // RUST_LOG=cloudscape=debug prints where each tile's time goes (fields,
    // conversion to drives, steps, smoothing).
    if std::env::var_os("RUST_LOG").is_some() {
        tracing_subscriber::fmt()
            .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
            .with_writer(std::io::stderr)
            .init();
    }
    let world = Config::embedded().world("default").unwrap();
    let what = std::env::args().nth(1).unwrap_or_else(|| "kernel".into());
    if what == "scene" {
        // The criterion scene (`cargo bench --bench core -- automaton/packed`):
        // 512×512×10 cells, 8 steps on all threads; prints the best of 30 rounds.
        let (sim, mut levels, mut drives) = cloudscape_tools::bench::core::scene(512);
        // ROWS=N keeps the first N rows of every level (a smaller working set).
        if let Some(rows) = std::env::var("ROWS").ok().and_then(|s| s.parse::<usize>().ok()) {
            for (l, d) in levels.iter_mut().zip(drives.iter_mut()) {
                let n = rows.min(l.rows) * l.wpr;
                l.rows = rows.min(l.rows);
                l.hum.truncate(n);
                l.act.truncate(n);
                l.cld.truncate(n);
                if let cloudscape_core::automaton::kernel::Drives::Stochastic(w) = d {
                    w.truncate(n);
                }
            }
        }
        let (mut best, mut best_cpu) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..30 {
            let (start, cpu) = (std::time::Instant::now(), cpu_ns());
            cloudscape_tools::bench::core::packed_steps(&sim, &levels, &drives, 8);
            best = best.min(start.elapsed().as_secs_f64());
            best_cpu = best_cpu.min((cpu_ns() - cpu) as f64 * 1e-9);
        }
        let cells = levels.iter().map(|l| l.wpr * 64 * l.rows).sum::<usize>() * 8;
        eprintln!(
            "scene: {:.3} ms best, {:.3e} cell-steps/s; {:.3} ms of CPU best, {:.3e} cell-steps per CPU-second",
            best * 1e3,
            cells as f64 / best,
            best_cpu * 1e3,
            cells as f64 / best_cpu
        );
        return;
    }
    if what == "tile" {
        let region = Region {
            x0: 768,
            y0: -512,
            cols: 256,
            rows: 256,
        };
        // TILES=N times N cold tiles, each at a new time (and epoch), and prints the best.
        let tiles: usize = std::env::var("TILES").ok().and_then(|s| s.parse().ok()).unwrap_or(1);
        let (mut best, mut best_cpu) = (f64::INFINITY, f64::INFINITY);
        for i in 0..tiles {
            let (start, cpu) = (std::time::Instant::now(), cpu_ns());
            black_box(density::density(&world, 0, 0, region, 1234.5 + 977.0 * i as f64).unwrap());
            best = best.min(start.elapsed().as_secs_f64());
            best_cpu = best_cpu.min((cpu_ns() - cpu) as f64 * 1e-9);
        }
        eprintln!(
            "tile: {:.1} ms best ({:.1} ms of CPU best) of {tiles}",
            best * 1e3,
            best_cpu * 1e3
        );
        return;
    }
    // The scene `cloudscape bench` and `benches/core.rs` step, so the profile is theirs.
    let size: i64 = std::env::var("SIZE").ok().and_then(|s| s.parse().ok()).unwrap_or(192);
    let (sim, levels, drives) = cloudscape_tools::bench::core::scene(size);
    let mut grids = cloudscape_tools::bench::core::Grids::of(&levels);
    let (start, cpu) = (std::time::Instant::now(), cpu_ns());
    let steps: i64 = std::env::var("STEPS").ok().and_then(|s| s.parse().ok()).unwrap_or(8);
    // One thread, so callgrind and perf see the kernel without rayon's scheduling.
    let serial = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    serial.install(|| cloudscape_tools::bench::core::step_grids(&sim, &drives, &mut grids, steps));
    let cur = grids.cur;
    let cells: usize = cur.iter().map(|l| l.wpr * 64 * l.rows).sum::<usize>() * steps as usize;
    eprintln!(
        "{cells} cell-steps in {:?} ({:.1} ms of CPU)",
        start.elapsed(),
        (cpu_ns() - cpu) as f64 * 1e-6
    );
    black_box(&cur);
}
