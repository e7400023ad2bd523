//! The bounded-history trade, measured for one epoch setting per argument
//! (`W:F`, warm-up and fade steps; the epoch length stays the default layer's):
//!
//! - the cold time of a 256×256-column level-0 tile of the default stratocumulus
//!   layer at every phase of an epoch (mean and worst over the 16 phases);
//! - how far the state of a run from its empty start is from a run 400 steps
//!   longer (the same cells, the same draws), at three phases;
//! - the fraction of cells that change per step in each level's wind frame,
//!   ordinary steps against epoch-boundary steps (as `tests/temporal.rs` counts).
//!
//!     cargo run --release --example epoch_trade -- 24:16 16:16 24:8 16:8
//!
//! The first setting given is the one the embedded config uses, for a baseline
//! measured in the same run.

use std::time::Instant;

use cloudscape_core::automaton::{LayerSim, Rect, RunSpec, plan_step};
use cloudscape_core::density::exact::frame_cells;
use cloudscape_core::density::{self, Region};
use cloudscape_core::world::Config;

fn main() {
    let specs: Vec<(u32, u32)> = std::env::args()
        .skip(1)
        .map(|a| {
            let (w, f) = a.split_once(':').expect("an argument is W:F");
            (
                w.parse().expect("W is a step count"),
                f.parse().expect("F is a step count"),
            )
        })
        .collect();
    println!(
        "| warm-up W | fade F | tile mean ms | tile worst ms | runs (mean) | differs from long run (p = 0 / 8 / 15) | change per step: ordinary max / boundary max |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (warmup, fade) in specs {
        let mut world = Config::embedded().world("default").expect("default world");
        let layer = &mut world.layers[0];
        layer.epoch.warmup = warmup;
        layer.epoch.fade = fade.min(layer.epoch.length);
        let (len, dt) = (layer.epoch.length as i64, layer.dt);
        let region = Region {
            x0: 768,
            y0: -512,
            cols: 256,
            rows: 256,
        };
        // One tile per phase, each in a new epoch so no state is shared; best of two
        // passes against a busy host.
        let mut best = vec![f64::INFINITY; len as usize];
        let mut runs = 0usize;
        for pass in 0..2 {
            for p in 0..len {
                let n = (1000 + 7 * p + 50 * pass) * len + p;
                let t = (n as f64 + 0.5) * dt;
                runs += plan_step(&world.layers[0], n).runs.len();
                let start = Instant::now();
                std::hint::black_box(density::density(&world, 0, 0, region, t).expect("tile"));
                best[p as usize] = best[p as usize].min(start.elapsed().as_secs_f64() * 1e3);
            }
        }
        let mean = best.iter().sum::<f64>() / best.len() as f64;
        let worst = best.iter().fold(0f64, |a, &b| a.max(b));

        let sim = LayerSim::new(&world, 0);
        let window = Rect {
            x0: 0,
            x1: 128,
            y0: 0,
            y1: 128,
        };
        let distance: Vec<String> = [0, 8, 15]
            .map(|p| {
                let m = 12 * len + p;
                let plan = plan_step(&sim.fields.layer, m);
                let run = plan.runs[plan.runs.len() - 1];
                let spec = |start: i64| RunSpec {
                    reference_step: run.reference,
                    start,
                    snapshots: vec![m],
                    windows: vec![window; sim.depth()],
                };
                let (short, long) = (sim.run(&spec(run.start)), sim.run(&spec(run.start - 400)));
                let (mut diff, mut total) = (0usize, 0usize);
                for (a, b) in short[0].levels.iter().zip(&long[0].levels) {
                    for y in 0..128 {
                        for x in 0..128 {
                            total += 1;
                            diff += usize::from(a.cld_at(x, y) != b.cld_at(x, y));
                        }
                    }
                }
                format!("{:.1}%", 100.0 * diff as f64 / total as f64)
            })
            .into();

        let windows = vec![
            Rect {
                x0: -64,
                x1: 64,
                y0: -64,
                y1: 64,
            };
            sim.depth()
        ];
        let (first, last) = (3 * len - 4, 5 * len + 2);
        let states: Vec<_> = (first..=last).map(|n| frame_cells(&sim, n, &windows)).collect();
        let (mut ordinary, mut boundary) = (0f64, 0f64);
        for (i, pair) in states.windows(2).enumerate() {
            let n = first + i as i64 + 1;
            let (mut diff, mut total) = (0usize, 0usize);
            for (a, b) in pair[0].iter().zip(&pair[1]) {
                diff += a.iter().zip(b).filter(|(p, q)| p != q).count();
                total += a.len();
            }
            let c = diff as f64 / total as f64;
            if n.rem_euclid(len) == 0 {
                boundary = boundary.max(c);
            } else {
                ordinary = ordinary.max(c);
            }
        }
        println!(
            "| {warmup} | {fade} | {mean:.1} | {worst:.1} | {:.2} | {} | {:.2}% / {:.2}% |",
            runs as f64 / (2 * len) as f64,
            distance.join(" / "),
            100.0 * ordinary,
            100.0 * boundary
        );
    }
}
