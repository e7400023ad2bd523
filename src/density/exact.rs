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
use crate::automaton::epoch::RunId;
use crate::automaton::{LayerSim, Rect, RunSpec, Snapshot, plan_step};
use crate::fields::noise::mix64;

/// Runs every run the plans of `steps` need, over the given per-level windows,
/// and returns for each step the cloud bits of each level's window (row-major).
fn states(sim: &LayerSim, steps: &[i64], windows: &[Rect]) -> Vec<Vec<Vec<u8>>> {
    let layer = &sim.fields.layer;
    let plans: Vec<_> = steps.iter().map(|&m| plan_step(layer, m)).collect();
    // One run serves every step that needs it.
    let mut runs: BTreeMap<RunId, Vec<i64>> = BTreeMap::new();
    for p in &plans {
        for r in &p.runs {
            let v = runs.entry(*r).or_default();
            if !v.contains(&p.step) {
                v.push(p.step);
            }
        }
    }
    let mut results: BTreeMap<RunId, Vec<Snapshot>> = BTreeMap::new();
    for (id, mut snaps) in runs {
        snaps.sort_unstable();
        let spec = RunSpec {
            reference_step: id.reference,
            start: id.start,
            snapshots: snaps,
            windows: windows.to_vec(),
        };
        results.insert(id, sim.run(&spec));
    }
    plans
        .iter()
        .map(|p| {
            let snaps: Vec<&Snapshot> = p
                .runs
                .iter()
                .map(|id| results[id].iter().find(|s| s.step == p.step).expect("snapshot planned"))
                .collect();
            windows
                .par_iter()
                .enumerate()
                .map(|(k, w)| {
                    let mut out = Vec::with_capacity(((w.x1 - w.x0) * (w.y1 - w.y0)) as usize);
                    for y in w.y0..w.y1 {
                        for x in w.x0..w.x1 {
                            let run = if snaps.len() > 1 {
                                p.pick(switch_hash(sim.stream, k, x, y))
                            } else {
                                0
                            };
                            out.push(snaps[run].levels[k].cld_at(x, y) as u8);
                        }
                    }
                    out
                })
                .collect()
        })
        .collect()
}

/// Tent-smoothed cloud field of one level over a window.
struct Smoothed {
    x0: i64,
    y0: i64,
    w: usize,
    values: Vec<f32>,
}

impl Smoothed {
    fn new(bits: &[u8], window: Rect) -> Smoothed {
        let w = (window.x1 - window.x0) as usize;
        let h = (window.y1 - window.y0) as usize;
        let at = |c: i64, r: i64| {
            if c < 0 || r < 0 || c >= w as i64 || r >= h as i64 {
                0.0
            } else {
                bits[r as usize * w + c as usize] as f32
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
        let smoothed: Vec<Smoothed> = st.iter().map(|levels| Smoothed::new(&levels[k], windows[k])).collect();
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
    let (n, _) = split_time(t, sim.fields.layer.dt);
    let windows: Vec<Rect> = sim
        .offsets(n)
        .iter()
        .map(|&(ox, oy)| Rect {
            x0: region.x0 - ox,
            x1: region.x0 + region.cols as i64 - ox,
            y0: region.y0 - oy,
            y1: region.y0 + region.rows as i64 - oy,
        })
        .collect();
    let data = frame_cells(sim, n, &windows).concat();
    Grid {
        depth: sim.depth(),
        rows: region.rows,
        cols: region.cols,
        data,
    }
}

/// The cloud bits of each level over a window of its own frame at step `n`
/// (row-major per level).
pub fn frame_cells(sim: &LayerSim, n: i64, windows: &[Rect]) -> Vec<Vec<u8>> {
    states(sim, &[n], windows).remove(0)
}

/// A per-cell uniform number in 0..65536 that sets when the cell switches runs.
fn switch_hash(stream: u64, k: usize, x: i64, y: i64) -> u32 {
    let h = mix64(stream ^ 0x6469_7468_6572 ^ ((k as u64) << 40) ^ mix64(x as u64 ^ mix64(y as u64)));
    (h >> 48) as u32
}
