//! Levels above 0: density on 2^Z-cell columns without running the automaton.
//!
//! The model is the automaton's expected steady-state cloud fraction for the
//! local probabilities (a mean-field reading of Dobashi's rules, below), with
//! the probability fields evaluated at each column centre in the same wind
//! frame and epoch alignment as the exact path, and fBm octaves clamped to what
//! a column can show. Its error against the downsampled level-0 automaton is
//! measured per level in BENCHMARKS.md (`cargo bench --bench core`).
//!
//! Mean field (fractions h, a, c of cells with hum, act, cld; neighbours taken
//! independent, each active with probability a):
//!
//! ```text
//! x  = h(1 − a)                 P(hum ∧ ¬act)
//! F  = 1 − (1 − a)^11           P(f_act), 11 neighbours
//! h' = x + (1 − x) p_hum
//! a' = xF + (1 − xF) p_act
//! c' = (c + a − ca)(1 − p_ext)
//! ```
//!
//! iterated from an empty cell to its fixed point (the mean of the last
//! iterations, since the map can oscillate). Rosa layers are thresholds, so
//! their expected fraction is the probability that the textures pass.

use std::sync::OnceLock;

use rayon::prelude::*;

use super::exact::split_time;
use super::{Grid, Region};
use crate::automaton::{LayerSim, plan_step};
use crate::fields::noise::Coord;
use crate::fields::probability::max_filter;
use crate::world::Mode;
use crate::world::{Event, authored};

/// Lookup-table resolution per axis; axes are in sqrt(p) so small probabilities
/// (activation is typically a few percent) get most of the entries.
const N: usize = 33;

/// Activation spreads from cell to cell through humid air, so a humid column
/// without activation seeds of its own still clouds over from its neighbours:
/// the model treats that as a floor on p_act (fitted against the automaton on
/// the default stratocumulus layer; see BENCHMARKS.md).
const SPREAD_ACT: f32 = 0.003;

/// The activation the mean field is given: the column's own p_act, floored at
/// [`SPREAD_ACT`] only where there is humid air for activation to spread through.
/// Dobashi's `act' = ¬act ∧ hum ∧ f_act` needs `hum`, and with p_hum = 0 a cell
/// never becomes humid, so there the automaton's only activation is its own
/// `rnd < p_act` and the floor would make haze in clear air (and outside an
/// extent, where the feather zeroes every field).
fn spread_activation(p_hum: f32, p_act: f32) -> f32 {
    if p_hum > 0.0 { p_act.max(SPREAD_ACT) } else { p_act }
}

fn steady_state(ph: f64, pa: f64, pe: f64) -> f64 {
    let (mut h, mut a, mut c) = (0.0f64, 0.0f64, 0.0f64);
    let mut tail = 0.0;
    const ITER: usize = 400;
    const TAIL: usize = 64;
    for i in 0..ITER {
        let x = h * (1.0 - a);
        let f = 1.0 - (1.0 - a).powi(11);
        let nh = x + (1.0 - x) * ph;
        let na = x * f + (1.0 - x * f) * pa;
        let nc = (c + a - c * a) * (1.0 - pe);
        (h, a, c) = (nh, na, nc);
        if i >= ITER - TAIL {
            tail += c;
        }
    }
    tail / TAIL as f64
}

fn table() -> &'static Vec<f32> {
    static TABLE: OnceLock<Vec<f32>> = OnceLock::new();
    // Filled on the calling thread (tens of milliseconds, once): a rayon join inside
    // the initialiser deadlocked when another rayon thread, stealing work meanwhile,
    // called `table()` and blocked on the lock whose initialiser waited for it.
    TABLE.get_or_init(|| {
        let axis = |i: usize| {
            let s = i as f64 / (N - 1) as f64;
            s * s
        };
        let mut t = vec![0f32; N * N * N];
        t.chunks_mut(N * N).enumerate().for_each(|(i, plane)| {
            for j in 0..N {
                for k in 0..N {
                    plane[j * N + k] = steady_state(axis(i), axis(j), axis(k)) as f32;
                }
            }
        });
        t
    })
}

/// Calibration of the mean-field fraction against the automaton: the mean
/// downsampled level-0 density in bins of the mean-field value 0, 0.1, …, 1
/// (made monotone). Fitted on world seed 7, t = 5000 s, a 512×512-cell region of
/// the default stratocumulus layer at level 2; evaluated on other seeds and
/// times in BENCHMARKS.md. Regenerate with `cargo bench --bench core -- lod`.
const CALIBRATION: [f32; 11] = [
    0.0, 0.035, 0.118, 0.201, 0.260, 0.263, 0.310, 0.333, 0.436, 0.770, 0.926,
];

/// Maps a mean-field cloud fraction to the automaton's expected density.
pub fn calibrate(m: f32) -> f32 {
    let u = m.clamp(0.0, 1.0) * 10.0;
    let i = (u.floor() as usize).min(9);
    let f = u - i as f32;
    CALIBRATION[i] + (CALIBRATION[i + 1] - CALIBRATION[i]) * f
}

/// Expected steady-state cloud fraction for probabilities (p_hum, p_act, p_ext).
pub fn expected_cloud(ph: f32, pa: f32, pe: f32) -> f32 {
    let t = table();
    let pos = |p: f32| {
        let u = p.clamp(0.0, 1.0).sqrt() * (N - 1) as f32;
        let i = (u.floor() as usize).min(N - 2);
        (i, u - i as f32)
    };
    let ((i, fi), (j, fj), (k, fk)) = (pos(ph), pos(pa), pos(pe));
    let at = |a: usize, b: usize, c: usize| t[(a * N + b) * N + c];
    let mut v = 0.0;
    for (da, wa) in [(0, 1.0 - fi), (1, fi)] {
        for (db, wb) in [(0, 1.0 - fj), (1, fj)] {
            for (dc, wc) in [(0, 1.0 - fk), (1, fk)] {
                v += wa * wb * wc * at(i + da, j + db, k + dc);
            }
        }
    }
    v.clamp(0.0, 1.0)
}

/// Density over `region` (columns at `level` >= 1).
pub fn density(sim: &LayerSim, level: u32, region: Region, t: f64) -> Grid<f32> {
    let f = &sim.fields;
    let layer = &f.layer;
    let depth = sim.depth();
    let span = 1i64 << level;
    let (n, frac) = split_time(t, layer.dt);
    let plan = plan_step(layer, n);
    // Share of cells already on the newest run (see automaton::epoch).
    let new_weight = if plan.runs.len() > 1 {
        ((plan.phase + 1) as f32 / plan.fade.max(1) as f32).min(1.0)
    } else {
        1.0
    };
    let weights: Vec<f32> = if plan.runs.len() > 1 {
        vec![1.0 - new_weight, new_weight]
    } else {
        vec![1.0]
    };
    let octaves = Event::ALL.map(|w| f.octaves(w, span as f64));
    let (dx, dy) = sim.frames.displacement(0, n, frac);
    let mut grid = Grid::new(depth, region.rows, region.cols);
    let plane = region.rows * region.cols;
    // An anvil's spread in columns of this level (at least one while it has a radius).
    let margin = f
        .layer
        .preset
        .anvil
        .as_ref()
        .map_or(0, |a| a.cells(span as f64 * layer.cell_size));
    // Brightness of each run's fields at every column centre (level 0's frame), and
    // with an anvil the spread of humidity and activation (from `margin` more columns
    // on each side, as `automaton::run` widens its window).
    let which = Event::ALL;
    /// A run's brightness, anvil spread, and column and row centres in the reference frame.
    type Fields = ([Vec<f32>; 3], Option<[Vec<f32>; 2]>, Vec<(i64, f64)>, Vec<(i64, f64)>);
    let brightness: Vec<Fields> = plan
        .runs
        .iter()
        .map(|run| {
            let r_off = sim.frames.reference_offset(run.reference);
            let o0 = sim.frames.offset(0, run.reference);
            let tau = f.tau(run.reference as f64 * layer.dt);
            // Column centres in level-0 cells, moved into the reference frame.
            let centre = |i: i64, d: &Coord, o: i64, r: i64| {
                let c = Coord::new(i * span - d.int + o - r, span as f64 * 0.5 - d.frac);
                (c.int, c.frac)
            };
            let m = margin as i64;
            let (w, h) = (region.cols + 2 * margin, region.rows + 2 * margin);
            let xs: Vec<(i64, f64)> = (-m..region.cols as i64 + m)
                .map(|c| centre(region.x0 + c, &dx, o0.0, r_off.0))
                .collect();
            let ys: Vec<(i64, f64)> = (-m..region.rows as i64 + m)
                .map(|r| centre(region.y0 + r, &dy, o0.1, r_off.1))
                .collect();
            let wide: [Vec<f32>; 3] = std::array::from_fn(|i| {
                let mut out = vec![0f32; w * h];
                f.brightness_grid(which[i], octaves[i], &xs, &ys, tau, r_off, &mut out);
                out
            });
            let inner = |v: &[f32]| -> Vec<f32> {
                v.chunks(w)
                    .skip(margin)
                    .take(region.rows)
                    .flat_map(|row| &row[margin..margin + region.cols])
                    .copied()
                    .collect()
            };
            let spread = (margin > 0).then(|| [0, 1].map(|i| inner(&max_filter(&wide[i], w, h, margin))));
            let (cols, rows) = (
                xs[margin..margin + region.cols].to_vec(),
                ys[margin..margin + region.rows].to_vec(),
            );
            (wide.each_ref().map(|v| inner(v)), spread, cols, rows)
        })
        .collect();
    // Each run's authored weather (`world::authored`) at every column centre, pushed
    // as `automaton::run` pushes it: at the run's authored time, in world metres.
    // Levels get a plane each only when a storm (which has an altitude) needs one;
    // else every level reads the one plane (the stride between levels is 0).
    let pushes: Vec<(Vec<f32>, usize)> = if layer.authored.is_empty() {
        Vec::new()
    } else {
        plan.runs
            .iter()
            .zip(&brightness)
            .map(|(run, (_, _, cols, rows))| {
                let (t_a, o_a) = sim.authored_at(run.reference);
                let metres = |c: &(i64, f64), a: i64| ((c.0 + a) as f64 + c.1) * layer.cell_size;
                let xs: Vec<f64> = cols.iter().map(|c| metres(c, o_a.0)).collect();
                let ys: Vec<f64> = rows.iter().map(|r| metres(r, o_a.1)).collect();
                let p = authored::GridPushes::new(&layer.authored, t_a, xs, ys);
                let (levels, stride) = if p.flat() { (1, 0) } else { (depth, plane) };
                let mut out = vec![0f32; plane * levels];
                out.par_chunks_mut(plane).enumerate().for_each(|(k, out)| {
                    let z = layer.level_altitude(k as u32);
                    for (i, s) in out.iter_mut().enumerate() {
                        *s = p.at(i % region.cols, i / region.cols, z);
                    }
                });
                (out, stride)
            })
            .collect()
    };
    let thresholds = layer.preset.rosa_thresholds.map(|v| v as f32);
    grid.data.par_chunks_mut(plane).enumerate().for_each(|(k, out)| {
        for (i, v) in out.iter_mut().enumerate() {
            let (r, c) = (i / region.cols, i % region.cols);
            let mut d = 0.0;
            let anvil = f.anvil_weight(k as u32);
            for (run, ((b, spread, cols, rows), w)) in brightness.iter().zip(&weights).enumerate() {
                // Dobashi ellipsoids drift with the wind: placed in the reference frame,
                // as `automaton::run` places them.
                let frame_metres = |c: (i64, f64)| (c.0 as f64 + c.1) * layer.cell_size;
                let ew = f.ellipsoid_weight(frame_metres(cols[c]), frame_metres(rows[r]), k as u32);
                let (mut hum, mut act) = (b[0][i], b[1][i]);
                if let Some(m) = spread.as_ref().filter(|_| anvil > 0.0) {
                    hum += (m[0][i] - hum) * anvil;
                    act += (m[1][i] - act) * anvil;
                }
                if let Some((s, level_stride)) = pushes.get(run) {
                    let s = s[k * level_stride + i];
                    (hum, act) = (authored::pushed(hum, s), authored::pushed(act, s));
                }
                let p = f.level_values(k as u32, [hum, act, b[2][i]], ew);
                let e = match layer.preset.mode {
                    Mode::Dobashi => calibrate(expected_cloud(p.hum, spread_activation(p.hum, p.act), p.ext)),
                    // Rosa: cloud where the textures pass their thresholds (eq. 3.6–3.8).
                    Mode::Rosa => {
                        ((p.act > thresholds[1] || p.hum > thresholds[0]) && p.ext > thresholds[2]) as u8 as f32
                    }
                };
                d += w * e;
            }
            *v = d.clamp(0.0, 1.0);
        }
    });
    grid
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_state_ends() {
        assert_eq!(steady_state(0.0, 0.0, 0.0), 0.0);
        // Certain activation, no extinction: every cell is cloud.
        assert!((steady_state(0.0, 1.0, 0.0) - 1.0).abs() < 1e-9);
        // Certain extinction: nothing survives.
        assert_eq!(steady_state(1.0, 1.0, 1.0), 0.0);
        // More extinction, less cloud.
        assert!(steady_state(0.3, 0.01, 0.05) < steady_state(0.3, 0.01, 0.01));
    }

    #[test]
    fn table_lookup_matches_direct_solution_on_nodes_and_between() {
        for &(ph, pa, pe) in &[(0.25f32, 0.0625, 0.015625), (0.3, 0.02, 0.03), (0.1, 0.001, 0.01)] {
            let direct = steady_state(ph as f64, pa as f64, pe as f64) as f32;
            assert!((expected_cloud(ph, pa, pe) - direct).abs() < 0.05, "{ph} {pa} {pe}");
        }
    }
}
