//! Simulation-core sections: automaton (packed vs naive), fields (ours vs the `noise`
//! crate), and scaling (cost against region area, level and t). The scene set-up is
//! that of `benches/core.rs`.

use std::hint::black_box;

use noise::{MultiFractal, NoiseFn};
use rayon::prelude::*;

use crate::chart::{Mark, PALETTE, Panel, Series, render};
use cloudscape_core::automaton::kernel::{Drives, Level, Rect, StepContext, step_level};
use cloudscape_core::automaton::naive::{self, NaiveDrives, NaiveLevel};
use cloudscape_core::automaton::{LayerSim, RunSpec};
use cloudscape_core::density::{self, Region};
use cloudscape_core::fields::noise::Fbm;
use cloudscape_core::world::{Config, World};

use super::{BenchRun, Effort, fmt_rate, fmt_s, time, time_batched};

/// The world the automaton and density figures are measured on: `overcast`, whose
/// first layer is the stratocumulus deck (10 cells deep) the published figures have
/// always used (it was the default world's before that became fair-weather cumulus).
fn world() -> World {
    Config::embedded().world("overcast").expect("the overcast world exists")
}

/// The overcast world's stratocumulus layer after a warm-up run, over `size × size` cells, with
/// its spatially varying drives. Shared with `benches/core.rs` (criterion).
pub fn scene(size: i64) -> (LayerSim, Vec<Level>, Vec<Drives>) {
    let sim = LayerSim::new(&world(), 0);
    let window = Rect {
        x0: 0,
        x1: size,
        y0: 0,
        y1: size,
    };
    let spec = RunSpec {
        reference_step: 64,
        start: 40,
        snapshots: vec![64],
        windows: vec![window; sim.depth()],
    };
    let snap = sim.run(&spec).remove(0);
    let levels: Vec<Level> = snap.levels.iter().map(|l| crop(l, window)).collect();
    let drives = sim.drives(&levels, 64);
    (sim, levels, drives)
}

fn crop(l: &Level, r: Rect) -> Level {
    let mut out = Level::covering(r);
    for y in r.y0..r.y1 {
        for x in r.x0..r.x1 {
            if l.cld_at(x, y) {
                let i = (y - out.y0) as usize * out.wpr + ((x - out.x0) / 64) as usize;
                out.cld[i] |= 1 << ((x - out.x0) % 64);
            }
        }
    }
    // hum and act are seeded from cld so activity spreads during the measurement.
    out.act = out.cld.iter().map(|w| w & 0x5555_5555_5555_5555).collect();
    out.hum = out.cld.iter().map(|w| !w).collect();
    out
}

/// `steps` steps of the packed kernel over every word of every level, levels in
/// parallel, from a copy of `levels` (the copies included).
pub fn packed_steps(sim: &LayerSim, levels: &[Level], drives: &[Drives], steps: i64) {
    let mut grids = Grids::of(levels);
    step_grids(sim, drives, &mut grids, steps);
    black_box(&grids);
}

/// The two grids [`step_grids`] steps between.
#[derive(Clone, Debug)]
pub struct Grids {
    /// The state (at the start, and again after the steps).
    pub cur: Vec<Level>,
    /// A buffer of the same shape.
    pub next: Vec<Level>,
}

impl Grids {
    /// The scene's state and a buffer of its shape.
    pub fn of(levels: &[Level]) -> Grids {
        Grids {
            cur: levels.to_vec(),
            next: levels.to_vec(),
        }
    }
}

/// `steps` steps of the packed kernel over every word of every level, levels in
/// parallel, from the state in `grids.cur` (left there). What the throughput
/// figures time: a run allocates its grids once, not once per call of this.
pub fn step_grids(sim: &LayerSim, drives: &[Drives], grids: &mut Grids, steps: i64) {
    let Grids { cur, next } = grids;
    for n in 0..steps {
        let offsets = sim.offsets(64 + n);
        let ctx = StepContext {
            rules: sim.rules(),
            stream: sim.stream,
            n: 64 + n,
            offsets: &offsets,
        };
        next.par_iter_mut().enumerate().for_each(|(k, o)| {
            let lv = &cur[k];
            let all = Rect {
                x0: lv.x0,
                x1: lv.x0 + 64 * lv.wpr as i64,
                y0: lv.y0,
                y1: lv.y0 + lv.rows as i64,
            };
            step_level(cur, k, &drives[k], &ctx, all, o)
        });
        std::mem::swap(cur, next);
    }
}

/// The same scene in the naive kernel's one-byte-per-cell form.
pub fn to_naive(levels: &[Level], drives: &[Drives]) -> (Vec<NaiveLevel>, Vec<NaiveDrives>) {
    let mut nl = Vec::new();
    let mut nd = Vec::new();
    for (l, d) in levels.iter().zip(drives) {
        let w = l.wpr * 64;
        let bit = |v: &[u64], c: usize| ((v[(c / w) * l.wpr + (c % w) / 64] >> (c % 64)) & 1) as u8;
        let n = w * l.rows;
        nl.push(NaiveLevel {
            x0: l.x0,
            y0: l.y0,
            w,
            h: l.rows,
            hum: (0..n).map(|c| bit(&l.hum, c)).collect(),
            act: (0..n).map(|c| bit(&l.act, c)).collect(),
            cld: (0..n).map(|c| bit(&l.cld, c)).collect(),
        });
        if let Drives::Stochastic(drives) = d {
            let words: Vec<_> = (0..drives.len()).map(|i| drives.word(i)).collect();
            let q = |e: usize, c: usize| -> u32 { words[(c / w) * l.wpr + (c % w) / 64].q(e, (c % 64) as u32) };
            nd.push(NaiveDrives::Stochastic {
                hum: (0..n).map(|c| q(0, c)).collect(),
                act: (0..n).map(|c| q(1, c)).collect(),
                ext: (0..n).map(|c| q(2, c)).collect(),
            });
        }
    }
    (nl, nd)
}

/// Packed (64 cells per u64, all threads) against naive (a byte per cell, one thread).
pub fn automaton(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let (size, steps, naive_size) = match effort {
        Effort::Smoke => (128, 1, 32),
        Effort::Quick => (256, 2, 64),
        Effort::Full => (512, 8, 128),
    };
    let (sim, levels, drives) = scene(size);
    let depth = sim.depth();
    // The grids are copied outside the timed part (as a run allocates them once).
    let packed = time_batched(effort, || Grids::of(&levels), |g| step_grids(&sim, &drives, g, steps));
    let packed_rate = (size * size) as f64 * depth as f64 * steps as f64 / packed.median_s;
    let (small_sim, small_levels, small_drives) = scene(naive_size);
    let (nl, nd) = to_naive(&small_levels, &small_drives);
    let naive = time(effort, || {
        let offsets = small_sim.offsets(64);
        black_box(naive::step(&nl, &nd, small_sim.rules(), small_sim.stream, 64, &offsets));
    });
    let naive_rate = (naive_size * naive_size) as f64 * depth as f64 / naive.median_s;
    let threads = rayon::current_num_threads();
    let markdown = format!(
        "The overcast world's stratocumulus layer (spatially varying probabilities), state after a warm-up run.\n\n\
         | kernel | grid | time (median of {} / {}) | cell-steps/s |\n|---|---|---|---|\n\
         | packed (64 cells/u64, {threads} threads; grids copied outside the timing) | {size}×{size}×{depth}, {steps} step(s) | {} | {} |\n\
         | naive (1 byte/cell, 1 thread) | {naive_size}×{naive_size}×{depth}, 1 step | {} | {} |\n\n\
         Packed / naive: **{:.0}×** (same run).\n",
        packed.iters,
        naive.iters,
        fmt_s(packed.median_s),
        fmt_rate(packed_rate),
        fmt_s(naive.median_s),
        fmt_rate(naive_rate),
        packed_rate / naive_rate
    );
    out.add_section("automaton", "Automaton: packed against naive", markdown);
    Ok(())
}

/// The fBm both fields benchmarks (here and `benches/core.rs`) time against the `noise`
/// crate's `Fbm<Simplex>` with the same seed, frequency, octaves, lacunarity and gain.
pub const FIELDS_FBM: Fbm = Fbm {
    seed: 3,
    scale: 0.02,
    octaves: 4,
    lacunarity: 2.0,
    gain: 0.5,
    offset: [0.0, 0.0],
};

/// Our fBm against the `noise` crate's, and a layer window exact against the coarse lattice.
pub fn fields(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let n: i64 = match effort {
        Effort::Smoke => 32 * 32,
        _ => 128 * 128,
    };
    let ours = FIELDS_FBM;
    let t_ours = time(effort, || {
        let mut s = 0.0;
        for i in 0..n {
            s += ours.sample(4, (i % 128, 0.5), (i / 128, 0.5), None);
        }
        black_box(s);
    });
    let theirs = noise::Fbm::<noise::Simplex>::new(3)
        .set_octaves(4)
        .set_frequency(0.02)
        .set_lacunarity(2.0)
        .set_persistence(0.5);
    let t_theirs = time(effort, || {
        let mut s = 0.0;
        for i in 0..n {
            s += theirs.get([(i % 128) as f64 + 0.5, (i / 128) as f64 + 0.5]);
        }
        black_box(s);
    });
    let side = if effort == Effort::Smoke { 64 } else { 256 };
    let lf = LayerSim::new(&world(), 0).fields;
    let coarse = lf.coarse_spacing();
    let t_exact = time(effort, || {
        black_box(lf.window(0, 0, side, side, [1; 3], None, (0, 0)));
    });
    let t_coarse = time(effort, || {
        black_box(lf.window(0, 0, side, side, coarse, None, (0, 0)));
    });
    let window = (side * side * 3) as f64;
    let (r_ours, r_theirs) = (n as f64 / t_ours.median_s, n as f64 / t_theirs.median_s);
    let markdown = format!(
        "| field | samples/s |\n|---|---|\n\
         | ours, fBm of 2D simplex, 4 octaves (split i64 + f64 coordinates) | {} |\n\
         | `noise` crate 0.9 `Fbm<Simplex>`, 4 octaves (f64, 256-entry permutation table) | {} |\n\
         | layer window {side}×{side}×3 fields, every cell | {} |\n\
         | layer window {side}×{side}×3 fields, coarse lattice (spacing {:?}) + bilinear | {} |\n\n\
         Ours / crate: **{:.2}×** the crate's rate; coarse lattice / every cell: **{:.1}×**. The crate is the \
         fastest pure-Rust fBm we know of, but its field repeats every 256 lattice units and loses the fraction far \
         from the origin (`tests/fields_precision.rs`), so it is only a yardstick here.\n",
        fmt_rate(r_ours),
        fmt_rate(r_theirs),
        fmt_rate(window / t_exact.median_s),
        coarse,
        fmt_rate(window / t_coarse.median_s),
        r_ours / r_theirs,
        t_exact.median_s / t_coarse.median_s
    );
    out.add_section("fields", "Fields: ours against the noise crate", markdown);
    Ok(())
}

/// Cost against region area (level 0), against level (a fixed 256×256-column tile, so
/// the ground covered grows 4× per level), and against t (flat).
pub fn scaling(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let w = world();
    let (sides, levels, times): (&[usize], &[u32], &[f64]) = match effort {
        Effort::Smoke => (&[16, 32], &[0, 4], &[1e3, 1e12]),
        Effort::Quick => (&[32, 64, 128], &[0, 2, 4, 6], &[1e3, 1e6, 1e12]),
        Effort::Full => (&[32, 64, 128, 256, 512], &[0, 1, 2, 3, 4, 6, 8], &[1e3, 1e6, 1e9, 1e12]),
    };
    let tile_side = if effort == Effort::Smoke { 32 } else { 256 };
    let mut t_next = 1234.5;
    let mut cold = |level: u32, side: usize| {
        time(effort, || {
            t_next += 977.0; // a new time (and epoch) every call: nothing is reused
            let region = Region {
                x0: 0,
                y0: 0,
                cols: side,
                rows: side,
            };
            black_box(density::density(&w, 0, level, region, t_next).expect("a valid region"));
        })
    };
    let mut md = String::from(
        "Density of the overcast world's stratocumulus layer (10 cells deep), cold (a new epoch each time).\n\n\
         **Against region area** (level 0):\n\n| region (columns) | ground | time | µs per column |\n|---|---|---|---|\n",
    );
    let mut area_pts = Vec::new();
    for &s in sides {
        let t = cold(0, s);
        let cols = (s * s) as f64;
        md += &format!(
            "| {s}×{s} | {:.1} km × {:.1} km | {} | {:.1} |\n",
            s as f64 * 0.1,
            s as f64 * 0.1,
            fmt_s(t.median_s),
            t.median_s / cols * 1e6
        );
        area_pts.push((cols, t.median_s));
    }
    md += &format!(
        "\n**Against level** (one {tile_side}×{tile_side}-column region; a level-Z column is 2^Z cells, so the ground grows 4× per level):\n\n\
         | level | ground side | time |\n|---|---|---|\n"
    );
    let mut level_pts = Vec::new();
    for &z in levels {
        let t = cold(z, tile_side);
        md += &format!(
            "| {z} | {:.1} km | {} |\n",
            tile_side as f64 * 0.1 * (z as f64).exp2(),
            fmt_s(t.median_s)
        );
        level_pts.push((z as f64, t.median_s));
    }
    md += &format!(
        "\n**Against t** ({tile_side}×{tile_side} columns, level 0, computed from scratch each time):\n\n| t (s) | time |\n|---|---|\n"
    );
    let mut t_pts = Vec::new();
    for &tt in times {
        let region = Region {
            x0: 0,
            y0: 0,
            cols: tile_side,
            rows: tile_side,
        };
        let t = time(effort, || {
            black_box(density::density(&w, 0, 0, region, tt).expect("a valid region"));
        });
        md += &format!("| {tt:.0e} | {} |\n", fmt_s(t.median_s));
        t_pts.push((tt, t.median_s));
    }
    md += "\nWhat it says: the cost follows the columns a request asks for (area at level 0), not the ground \
           they cover (a level-Z tile of the same column count covers 4^Z times the ground for about the same \
           time or less), nor the world clock (flat in t: bounded history).\n";
    md += "\n![scaling](@plots@/scaling.png)\n";
    let line = |points: Vec<(f64, f64)>| Series {
        name: String::new(),
        points,
        colour: PALETTE[0],
        mark: Mark::Line,
    };
    let png = render(
        &[
            Panel {
                title: "cost against region area (level 0)".into(),
                x_label: "columns".into(),
                y_label: "seconds".into(),
                x_log: true,
                y_log: true,
                series: vec![line(area_pts)],
            },
            Panel {
                title: "cost against level (same column count)".into(),
                x_label: "level".into(),
                y_label: "seconds".into(),
                series: vec![line(level_pts)],
                ..Panel::default()
            },
            Panel {
                title: "cost against t".into(),
                x_label: "t, seconds".into(),
                y_label: "seconds".into(),
                x_log: true,
                series: vec![line(t_pts)],
                ..Panel::default()
            },
        ],
        3,
        (420, 340),
    )?;
    out.add_plot("scaling.png", png);
    out.add_section("scaling", "Scaling: area, level, t", md);
    Ok(())
}
