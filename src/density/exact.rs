//! Level 0: density and cloud bits straight from the automaton.
//!
//! Density at a world cell and time t = (n + f)·dt: each level's frame has moved
//! by the continuous wind displacement c(t); the cell centre falls at frame
//! position X − c. The cloud bits of steps n and n+1 (each a blend of the runs
//! its epoch plan names) are smoothed with a 3×3 tent ([1,2,1]/4 per axis),
//! sampled bilinearly at that position, and interpolated linearly in f. The
//! result is a pure function of (world, layer, cell, t).

use std::collections::BTreeMap;

use rayon::prelude::*;

use super::{Grid, Region};
use crate::automaton::{LayerSim, Level, Rect, RunSpec, Snapshot, plan_step};
use crate::fields::noise::mix64;
use crate::fields::quantize;

/// Runs every plan needed for `steps` with the given per-level windows, and returns
/// for each step the (snapshot, weight) pairs to blend.
fn states(sim: &LayerSim, steps: &[i64], windows: &[Rect]) -> Vec<Vec<(Snapshot, f32)>> {
    let layer = &sim.fields.layer;
    let plans: Vec<_> = steps.iter().map(|&m| plan_step(layer, m)).collect();
    // Group by run (reference step, start): one run serves every step that needs it.
    let mut runs: BTreeMap<(i64, i64), Vec<i64>> = BTreeMap::new();
    for p in &plans {
        for &(reference, start, _) in &p.runs {
            let v = runs.entry((reference, start)).or_default();
            if !v.contains(&p.step) {
                v.push(p.step);
            }
        }
    }
    let mut results: BTreeMap<(i64, i64), Vec<Snapshot>> = BTreeMap::new();
    for ((reference, start), mut snaps) in runs {
        snaps.sort_unstable();
        let spec = RunSpec {
            reference_step: reference,
            start,
            snapshots: snaps,
            windows: windows.to_vec(),
        };
        results.insert((reference, start), sim.run(&spec));
    }
    plans
        .iter()
        .map(|p| {
            p.runs
                .iter()
                .map(|&(reference, start, w)| {
                    let snap = results[&(reference, start)]
                        .iter()
                        .find(|s| s.step == p.step)
                        .expect("snapshot planned")
                        .clone();
                    (snap, w)
                })
                .collect()
        })
        .collect()
}

/// Tent-smoothed, run-blended cloud field of one level over a window.
struct Smoothed {
    x0: i64,
    y0: i64,
    w: usize,
    values: Vec<f32>,
}

impl Smoothed {
    fn new(parts: &[(&Level, f32)], window: Rect) -> Smoothed {
        let w = (window.x1 - window.x0) as usize;
        let h = (window.y1 - window.y0) as usize;
        let mut raw = vec![0f32; w * h];
        for (lv, weight) in parts {
            for r in 0..h {
                for c in 0..w {
                    if lv.cld_at(window.x0 + c as i64, window.y0 + r as i64) {
                        raw[r * w + c] += weight;
                    }
                }
            }
        }
        let at = |c: i64, r: i64| {
            if c < 0 || r < 0 || c >= w as i64 || r >= h as i64 {
                0.0
            } else {
                raw[r as usize * w + c as usize]
            }
        };
        let mut values = vec![0f32; w * h];
        for r in 0..h as i64 {
            for c in 0..w as i64 {
                let mut s = 0.0;
                for (dy, wy) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                    for (dx, wx) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                        s += wx * wy * at(c + dx, r + dy);
                    }
                }
                values[r as usize * w + c as usize] = s / 16.0;
            }
        }
        Smoothed {
            x0: window.x0,
            y0: window.y0,
            w,
            values,
        }
    }

    #[inline]
    fn get(&self, x: i64, y: i64) -> f32 {
        self.values[(y - self.y0) as usize * self.w + (x - self.x0) as usize]
    }
}

/// Splits t into a step index and a fraction.
pub(crate) fn split_time(t: f64, dt: f64) -> (i64, f64) {
    let s = t / dt;
    let n = s.floor();
    (n as i64, (s - n).clamp(0.0, 1.0))
}

/// The continuous density over `region` (level-0 cells).
pub fn density(sim: &LayerSim, region: Region, t: f64) -> Grid<f32> {
    let layer = &sim.fields.layer;
    let depth = sim.depth();
    let (n, f) = split_time(t, layer.dt);
    let steps: Vec<i64> = if f > 0.0 { vec![n, n + 1] } else { vec![n] };
    let disp: Vec<_> = (0..depth as u32).map(|k| sim.frames.displacement(k, n, f)).collect();
    let windows: Vec<Rect> = disp
        .iter()
        .map(|(cx, cy)| Rect {
            x0: region.x0 - cx.int - 2,
            x1: region.x0 + region.cols as i64 - cx.int + 2,
            y0: region.y0 - cy.int - 2,
            y1: region.y0 + region.rows as i64 - cy.int + 2,
        })
        .collect();
    let st = states(sim, &steps, &windows);
    let mut grid = Grid::new(depth, region.rows, region.cols);
    let plane = region.rows * region.cols;
    grid.data.par_chunks_mut(plane).enumerate().for_each(|(k, out)| {
        let smoothed: Vec<Smoothed> = st
            .iter()
            .map(|parts| {
                Smoothed::new(
                    &parts.iter().map(|(s, w)| (&s.levels[k], *w)).collect::<Vec<_>>(),
                    windows[k],
                )
            })
            .collect();
        let (cx, cy) = disp[k];
        // Bilinear weights: frame index of the cell centre is X − c.
        let (ox, wx) = if cx.frac > 0.0 { (1, 1.0 - cx.frac) } else { (0, 0.0) };
        let (oy, wy) = if cy.frac > 0.0 { (1, 1.0 - cy.frac) } else { (0, 0.0) };
        let (wx, wy) = (wx as f32, wy as f32);
        for r in 0..region.rows {
            let fy = region.y0 + r as i64 - cy.int - oy;
            for c in 0..region.cols {
                let fx = region.x0 + c as i64 - cx.int - ox;
                let sample = |s: &Smoothed| {
                    let top = s.get(fx, fy) * (1.0 - wx) + s.get(fx + 1, fy) * wx;
                    let bot = s.get(fx, fy + 1) * (1.0 - wx) + s.get(fx + 1, fy + 1) * wx;
                    top * (1.0 - wy) + bot * wy
                };
                let d0 = sample(&smoothed[0]);
                let v = if smoothed.len() > 1 {
                    d0 + (sample(&smoothed[1]) - d0) * f as f32
                } else {
                    d0
                };
                out[r * region.cols + c] = v.clamp(0.0, 1.0);
            }
        }
    });
    grid
}

/// The cloud bits over `region` (level-0 cells) at the step containing t.
pub fn cloud_cells(sim: &LayerSim, region: Region, t: f64) -> Grid<u8> {
    let layer = &sim.fields.layer;
    let depth = sim.depth();
    let (n, _) = split_time(t, layer.dt);
    let offsets = sim.offsets(n);
    let windows: Vec<Rect> = offsets
        .iter()
        .map(|&(ox, oy)| Rect {
            x0: region.x0 - ox,
            x1: region.x0 + region.cols as i64 - ox,
            y0: region.y0 - oy,
            y1: region.y0 + region.rows as i64 - oy,
        })
        .collect();
    let st = states(sim, &[n], &windows);
    let parts = &st[0];
    let mut grid = Grid::new(depth, region.rows, region.cols);
    let fade = parts.get(1).map(|p| quantize(p.1)).unwrap_or(0);
    for k in 0..depth {
        let (ox, oy) = offsets[k];
        for r in 0..region.rows {
            let y = region.y0 + r as i64 - oy;
            for c in 0..region.cols {
                let x = region.x0 + c as i64 - ox;
                // Cross-fade: a per-cell hash below the fade weight takes the next epoch's bit.
                let pick = if fade > 0 && dither(sim.stream, k, x, y) < fade {
                    1
                } else {
                    0
                };
                let i = grid.index(k, r, c);
                grid.data[i] = parts[pick].0.levels[k].cld_at(x, y) as u8;
            }
        }
    }
    grid
}

/// A per-cell uniform number in 0..65536, fixed for the cell's lifetime in its frame.
fn dither(stream: u64, k: usize, x: i64, y: i64) -> u32 {
    let h = mix64(stream ^ 0x6469_7468_6572 ^ ((k as u64) << 40) ^ mix64(x as u64 ^ mix64(y as u64)));
    (h >> 48) as u32
}
