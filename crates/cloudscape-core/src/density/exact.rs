//! Level 0: density and cloud bits straight from the automaton.
//!
//! Density at a world cell and time t = (n + f)·dt: each level's frame has moved
//! by the continuous wind displacement c(t); the cell centre falls at frame
//! position X − c. The cloud bits of steps n and n+1 (each a blend of the runs
//! its epoch plan names) are smoothed with a 3×3 tent (`[1, 2, 1] / 4` per axis),
//! sampled bilinearly at that position, and interpolated linearly in f. The
//! result is a pure function of (world, layer, cell, t).

use std::collections::BTreeMap;

use rayon::prelude::*;

use super::{Grid, Region};
use crate::automaton::epoch::RunId;
use crate::automaton::live::sample_window;
use crate::automaton::run::millis;
use crate::automaton::{LayerSim, Level, LiveRuns, Rect, RunSpec, Snapshot, StepPlan, plan_step};
use crate::cpu::Backend;
use crate::fields::noise::{Coord, MIX_MUL, NoiseBackend, mix64};

/// The epoch plans of `steps` and the snapshots of every run they name, each run
/// made once over the given per-level windows (one run serves every step that
/// needs it).
fn run_plans(sim: &LayerSim, steps: &[i64], windows: &[Rect]) -> (Vec<StepPlan>, BTreeMap<RunId, Vec<Snapshot>>) {
    let (plans, specs) = run_specs(sim, steps, windows);
    let results = specs.into_iter().map(|(id, spec)| (id, sim.run(&spec))).collect();
    (plans, results)
}

/// The epoch plans of `steps` and the one run each names, with every step it serves.
fn run_specs(sim: &LayerSim, steps: &[i64], windows: &[Rect]) -> (Vec<StepPlan>, BTreeMap<RunId, RunSpec>) {
    let layer = &sim.fields.layer;
    let plans: Vec<_> = steps.iter().map(|&m| plan_step(layer, m)).collect();
    let mut runs: BTreeMap<RunId, Vec<i64>> = BTreeMap::new();
    for p in &plans {
        for r in &p.runs {
            let v = runs.entry(*r).or_default();
            if !v.contains(&p.step) {
                v.push(p.step);
            }
        }
    }
    let specs = runs
        .into_iter()
        .map(|(id, mut snaps)| {
            snaps.sort_unstable();
            let spec = RunSpec {
                reference_step: id.reference,
                start: id.start,
                snapshots: snaps,
                windows: windows.to_vec(),
            };
            (id, spec)
        })
        .collect();
    (plans, specs)
}

/// The automaton cell-steps [`density`] over `region` at `t` will run (the same
/// plans and cones), for admission control.
pub fn cell_steps(sim: &LayerSim, region: Region, t: f64) -> u64 {
    let Sampling { steps, windows, .. } = sampling(sim, region, t);
    let (_, specs) = run_specs(sim, &steps, &windows);
    specs
        .values()
        .map(|spec| sim.run_cells(spec))
        .fold(0, u64::saturating_add)
}

/// Runs every run the plans of `steps` need, over the given per-level windows,
/// and returns for each step the cloud bits of each level's window (row-major).
fn states(sim: &LayerSim, steps: &[i64], windows: &[Rect]) -> Vec<Vec<Vec<u8>>> {
    let (plans, results) = run_plans(sim, steps, windows);
    let snaps: Vec<Vec<&[Level]>> = plans
        .iter()
        .map(|p| {
            p.runs
                .iter()
                .map(|id| {
                    let s = results[id].iter().find(|s| s.step == p.step).expect("snapshot planned");
                    s.levels.as_slice()
                })
                .collect()
        })
        .collect();
    blended(sim, &plans, &snaps, windows)
}

/// For each plan, the cloud bits of each level's window (row-major): each cell from
/// the run its switch hash picks, among the grids `snaps` of the runs the plan names
/// (at the plan's step).
fn blended(sim: &LayerSim, plans: &[StepPlan], snaps: &[Vec<&[Level]>], windows: &[Rect]) -> Vec<Vec<Vec<u8>>> {
    // Per level, every step: the switch hashes depend on the cell and not on the
    // step, so the steps of one level share them.
    let per_level: Vec<Vec<Vec<u8>>> = windows
        .par_iter()
        .enumerate()
        .map(|(k, w)| {
            let cols = (w.x1 - w.x0).max(0) as usize;
            let rows = (w.y1 - w.y0).max(0) as usize;
            let hashes = if snaps.iter().any(|s| s.len() > 1) {
                switch_hashes(sim.stream, k, *w)
            } else {
                Vec::new()
            };
            let mut row_bytes = Vec::new();
            let mut other = vec![0u8; cols];
            plans
                .iter()
                .zip(snaps)
                .map(|(p, snaps)| {
                    let mut out = vec![0u8; cols * rows];
                    if cols == 0 {
                        return out;
                    }
                    let switched = switched_below(p);
                    for (r, row) in out.chunks_exact_mut(cols).enumerate() {
                        let y = w.y0 + r as i64;
                        cld_row(&snaps[0][k], y, w.x0, row, &mut row_bytes);
                        if snaps.len() > 1 {
                            // `pick` names run 0 or 1 only.
                            cld_row(&snaps[1][k], y, w.x0, &mut other, &mut row_bytes);
                            let h = &hashes[r * cols..(r + 1) * cols];
                            // A byte mask, not `if`: LLVM turns an `if` here into a load
                            // through a selected pointer, one byte at a time.
                            for ((o, &b), &h) in row.iter_mut().zip(&other).zip(h) {
                                let m = u8::from(u32::from(h) < switched).wrapping_neg();
                                *o ^= (*o ^ b) & m;
                            }
                        }
                    }
                    out
                })
                .collect()
        })
        .collect();
    // Level-major to step-major.
    let mut by_step: Vec<Vec<Vec<u8>>> = plans.iter().map(|_| Vec::with_capacity(windows.len())).collect();
    for steps in per_level {
        for (s, cells) in steps.into_iter().enumerate() {
            by_step[s].push(cells);
        }
    }
    by_step
}

/// [`states`] from runs kept alive between calls: the same bits, advancing `live`
/// to each step instead of running from the epochs' starts. `None` when `live` does
/// not hold the windows or has gone past a step (the caller computes it cold).
fn live_states(sim: &LayerSim, live: &mut LiveRuns, steps: &[i64], windows: &[Rect]) -> Option<Vec<Vec<Vec<u8>>>> {
    if !steps.iter().all(|&m| live.covers(sim, m, windows) && live.can_give(m)) {
        return None;
    }
    let mut out = Vec::with_capacity(steps.len());
    for &m in steps {
        let (plan, levels) = live.at(sim, m)?;
        out.push(blended(sim, std::slice::from_ref(&plan), &[levels], windows).remove(0));
    }
    Some(out)
}

/// The number of switch hashes (from 0 up) whose cells `p.pick` sends to run 1:
/// `pick(h)` is 1 exactly when `h` is below it, since the phase `h·fade >> 16`
/// does not decrease with `h`.
fn switched_below(p: &StepPlan) -> u32 {
    let (mut lo, mut hi) = (0u32, 65536u32);
    while lo < hi {
        let mid = (lo + hi) / 2;
        if p.pick(mid) == 1 {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    lo
}

/// Each byte's 8 bits spread to the low bits of 8 bytes (little-endian), so a
/// word of cloud bits becomes 64 bytes of 0/1 with 8 loads.
const SPREAD: [u64; 256] = {
    let mut t = [0u64; 256];
    let mut v = 0;
    while v < 256 {
        let mut b = 0;
        while b < 8 {
            t[v] |= ((v as u64 >> b) & 1) << (8 * b);
            b += 1;
        }
        v += 1;
    }
    t
};

/// [`Level::cld_at`] for frame cells `x0..x0 + out.len()` of row `y`, as 0/1
/// bytes; `bytes` is scratch space for the row's words spread to bytes.
fn cld_row(lv: &Level, y: i64, x0: i64, out: &mut [u8], bytes: &mut Vec<u8>) {
    let dy = y - lv.y0;
    if dy < 0 || dy >= lv.rows as i64 {
        out.fill(0);
        return;
    }
    let words = &lv.cld[dy as usize * lv.wpr..][..lv.wpr];
    bytes.resize(lv.wpr * 64, 0);
    for (w, chunk) in words.iter().zip(bytes.chunks_exact_mut(64)) {
        for (i, lane) in chunk.chunks_exact_mut(8).enumerate() {
            lane.copy_from_slice(&SPREAD[(w >> (8 * i)) as usize & 255].to_le_bytes());
        }
    }
    // The level's cells are out[lo..hi]; the rest read as empty.
    let len = out.len() as i64;
    let lo = (lv.x0 - x0).clamp(0, len) as usize;
    let hi = (lv.x0 + 64 * lv.wpr as i64 - x0).clamp(0, len) as usize;
    out[..lo].fill(0);
    out[hi..].fill(0);
    if lo < hi {
        let s = (x0 + lo as i64 - lv.x0) as usize;
        out[lo..hi].copy_from_slice(&bytes[s..s + (hi - lo)]);
    }
}

/// Per cell of a window (row-major), a uniform number in 0..65536 that sets when
/// the cell switches runs: a hash of (stream, level, x, y), with the row's
/// `mix64` worked out once per row.
fn switch_hashes(stream: u64, k: usize, w: Rect) -> Vec<u16> {
    switch_hashes_on(NoiseBackend::detect(), stream, k, w)
}

/// `switch_hashes` on one backend (one of [`NoiseBackend::available`]); every
/// backend gives the same bits. Public for the benchmark that compares them.
pub fn switch_hashes_on(backend: NoiseBackend, stream: u64, k: usize, w: Rect) -> Vec<u16> {
    let base = stream ^ 0x6469_7468_6572 ^ ((k as u64) << 40);
    let cols = (w.x1 - w.x0).max(0) as usize;
    let rows = (w.y1 - w.y0).max(0) as usize;
    let mut out = vec![0u16; cols * rows];
    if cols == 0 {
        return out;
    }
    assert!(backend.runs_here(), "{backend:?} hashes on a CPU without them");
    for (r, row) in out.chunks_exact_mut(cols).enumerate() {
        let my = mix64((w.y0 + r as i64) as u64);
        match backend {
            #[cfg(target_arch = "x86_64")]
            NoiseBackend::Avx512 => {
                // SAFETY: the CPU has AVX-512 F and DQ (asserted above).
                unsafe { switch_row_avx512(base, my, w.x0, row) }
            }
            _ => switch_row(base, my, w.x0, row),
        }
    }
    out
}

/// One row of [`switch_hashes`] from frame column `x0` on, a cell at a time.
fn switch_row(base: u64, my: u64, x0: i64, row: &mut [u16]) {
    for (c, h) in row.iter_mut().enumerate() {
        let x = x0 + c as i64;
        *h = (mix64(base ^ mix64(x as u64 ^ my)) >> 48) as u16;
    }
}

/// [`switch_row`] eight cells at a time. The hashes are four 64-bit multiplies a
/// cell; AVX-512 DQ multiplies eight lanes per instruction (x86-64-v3 has no
/// 64-bit vector multiply, so the compiler cannot do this on its own). Integer
/// arithmetic: the same bits. Measured 1.55× the scalar form (`cargo bench
/// --bench core -- 'switch hashes'`); a cold tile inside an epoch cross-fade
/// hashes 10 levels of 260×260 cells, about 1.6 ms of CPU one cell at a time.
///
/// # Safety
/// The CPU must have AVX-512 F and DQ.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq")]
unsafe fn switch_row_avx512(base: u64, my: u64, x0: i64, row: &mut [u16]) {
    use std::arch::x86_64::*;
    let mix = |z: __m512i| {
        let [m0, m1] = MIX_MUL.map(|m| _mm512_set1_epi64(m as i64));
        let z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64::<30>(z)), m0);
        let z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64::<27>(z)), m1);
        _mm512_xor_si512(z, _mm512_srli_epi64::<31>(z))
    };
    let (base_v, my_v) = (_mm512_set1_epi64(base as i64), _mm512_set1_epi64(my as i64));
    let mut x = _mm512_add_epi64(_mm512_set1_epi64(x0), _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7));
    let done = row.len() / 8 * 8;
    for chunk in row[..done].chunks_exact_mut(8) {
        let h = mix(_mm512_xor_si512(base_v, mix(_mm512_xor_si512(x, my_v))));
        let h = _mm512_cvtepi64_epi16(_mm512_srli_epi64::<48>(h));
        // SAFETY: `chunk` is eight u16, 16 bytes.
        unsafe { _mm_storeu_si128(chunk.as_mut_ptr().cast(), h) };
        x = _mm512_add_epi64(x, _mm512_set1_epi64(8));
    }
    switch_row(base, my, x0 + done as i64, &mut row[done..]);
}

/// Tent-smoothed cloud field of one level over a window, kept as the integer
/// tent sums (0..=16; the density is the sum / 16).
struct Smoothed {
    x0: i64,
    y0: i64,
    w: usize,
    sums: Vec<u8>,
}

impl Smoothed {
    /// The [1,2,1] ⊗ [1,2,1] sums of 0/1 cloud bits (cells outside the window
    /// read as 0), as a vertical pass then a horizontal one. Every partial sum is
    /// a whole number at most 16, so this equals the f32 sum over the 9 taps in
    /// any order, bit for bit.
    fn new(bits: &[u8], window: Rect) -> Smoothed {
        let w = (window.x1 - window.x0).max(0) as usize;
        let h = (window.y1 - window.y0).max(0) as usize;
        debug_assert!(bits.iter().all(|&b| b <= 1), "cloud bits are 0 or 1");
        let mut sums = vec![0u8; w * h];
        if w > 0 {
            let mut vert = vec![0u8; w];
            for (r, out) in sums.chunks_exact_mut(w).enumerate() {
                let mid = &bits[r * w..(r + 1) * w];
                for (v, &m) in vert.iter_mut().zip(mid) {
                    *v = 2 * m;
                }
                if r > 0 {
                    for (v, &u) in vert.iter_mut().zip(&bits[(r - 1) * w..r * w]) {
                        *v += u;
                    }
                }
                if r + 1 < h {
                    for (v, &d) in vert.iter_mut().zip(&bits[(r + 1) * w..(r + 2) * w]) {
                        *v += d;
                    }
                }
                for (o, &v) in out.iter_mut().zip(&vert) {
                    *o = 2 * v;
                }
                for (o, &l) in out[1..].iter_mut().zip(&vert) {
                    *o += l;
                }
                for (o, &r) in out.iter_mut().zip(&vert[1..]) {
                    *o += r;
                }
            }
        }
        Smoothed {
            x0: window.x0,
            y0: window.y0,
            w,
            sums,
        }
    }

    /// The tent sums of frame row `y` from frame column `x` on.
    #[inline]
    fn row_from(&self, x: i64, y: i64) -> &[u8] {
        let r = (y - self.y0) as usize * self.w;
        &self.sums[r + (x - self.x0) as usize..r + self.w]
    }
}

/// The smoothed values of frame row `y` interpolated along x: `out[c]` is
/// `s(fx0 + c)·(1 − wx) + s(fx0 + c + 1)·wx`, with `s` the tent sum / 16.
fn lerp_row(s: &Smoothed, fx0: i64, y: i64, wx: f32, out: &mut [f32]) {
    let row = &s.row_from(fx0, y)[..out.len() + 1];
    for ((o, &a), &b) in out.iter_mut().zip(row).zip(&row[1..]) {
        *o = (a as f32 / 16.0) * (1.0 - wx) + (b as f32 / 16.0) * wx;
    }
}

/// Splits t into a step index and a fraction.
pub(crate) fn split_time(t: f64, dt: f64) -> (i64, f64) {
    let s = t / dt;
    let n = s.floor();
    (n as i64, (s - n).clamp(0.0, 1.0))
}

/// What the density over `region` at t samples: the step or two steps it blends,
/// the blend fraction, each level's frame displacement, and each level's window of
/// frame cells (the region's cells plus the reach of the tent and the bilinear step).
struct Sampling {
    steps: Vec<i64>,
    f: f64,
    disp: Vec<(Coord, Coord)>,
    windows: Vec<Rect>,
}

fn sampling(sim: &LayerSim, region: Region, t: f64) -> Sampling {
    let (n, f) = split_time(t, sim.fields.layer.dt);
    let steps: Vec<i64> = if f > 0.0 { vec![n, n + 1] } else { vec![n] };
    let disp: Vec<_> = (0..sim.depth() as u32)
        .map(|k| sim.frames.displacement(k, n, f))
        .collect();
    let windows: Vec<Rect> = disp.iter().map(|&d| sample_window(region, d)).collect();
    Sampling {
        steps,
        f,
        disp,
        windows,
    }
}

/// Bilinear taps along one axis of a frame displaced by `c`: the frame index of cell
/// centre X is X − c, which lies between frame cells X − `c.int` − `o` and the next one,
/// weighted `w`; returns (`o`, `w`).
fn taps(c: Coord) -> (i64, f32) {
    if c.frac > 0.0 {
        (1, (1.0 - c.frac) as f32)
    } else {
        (0, 0.0)
    }
}

/// The continuous density over `region` (level-0 cells).
pub fn density(sim: &LayerSim, region: Region, t: f64) -> Grid<f32> {
    let start = std::time::Instant::now();
    let states = cold_states(sim, region, t);
    let states_done = start.elapsed();
    let grid = smooth(sim, region, states);
    // Where a cold tile's time goes (`RUST_LOG=cloudscape=debug`; BENCHMARKS.md "Cold tile").
    tracing::debug!(
        states_ms = millis(states_done),
        smoothing_ms = millis(start.elapsed() - states_done),
        "density"
    );
    grid
}

/// [`density`] from runs kept alive between calls (`live`, which must hold
/// `region`'s windows at t): the same bits. `None` when `live` cannot give them
/// (the caller computes the density cold).
pub fn density_live(sim: &LayerSim, live: &mut LiveRuns, region: Region, t: f64) -> Option<Grid<f32>> {
    Some(smooth(sim, region, kept_states(sim, live, region, t)?))
}

/// The automaton's cloud bits that the density of a region at a time samples: each
/// level's window of its frame at the step or two steps t falls between.
pub struct CloudStates {
    sampling: Sampling,
    /// Per step, per level, the window's bits (row-major, 0 or 1).
    bits: Vec<Vec<Vec<u8>>>,
}

/// The cloud bits [`density`] of `region` at `t` samples, from runs started at their
/// epochs' empty grids.
pub fn cold_states(sim: &LayerSim, region: Region, t: f64) -> CloudStates {
    let sampling = sampling(sim, region, t);
    let bits = states(sim, &sampling.steps, &sampling.windows);
    CloudStates { sampling, bits }
}

/// [`cold_states`] from runs kept alive between calls (the same bits); `None` when
/// `live` does not hold the windows or has gone past a step.
pub fn kept_states(sim: &LayerSim, live: &mut LiveRuns, region: Region, t: f64) -> Option<CloudStates> {
    let sampling = sampling(sim, region, t);
    let bits = live_states(sim, live, &sampling.steps, &sampling.windows)?;
    Some(CloudStates { sampling, bits })
}

/// The density of `region` from its cloud bits (`states`, made for the same region):
/// smoothed with the tent, sampled at the wind displacement, interpolated in time.
pub fn smooth(sim: &LayerSim, region: Region, states: CloudStates) -> Grid<f32> {
    smoothed(sim, region, states.sampling, &states.bits)
}

/// The density over `region` from the cloud bits `st` of the sampling's steps:
/// smoothed, sampled at the wind displacement, interpolated in time.
fn smoothed(sim: &LayerSim, region: Region, sampling: Sampling, st: &[Vec<Vec<u8>>]) -> Grid<f32> {
    let depth = sim.depth();
    let Sampling { f, disp, windows, .. } = sampling;
    let mut grid = Grid::new(depth, region.rows, region.cols);
    let plane = region.rows * region.cols;
    let cols = region.cols;
    let f = f as f32;
    grid.data.par_chunks_mut(plane).enumerate().for_each(|(k, out)| {
        let smoothed: Vec<Smoothed> = st.iter().map(|levels| Smoothed::new(&levels[k], windows[k])).collect();
        let (cx, cy) = disp[k];
        let ((ox, wx), (oy, wy)) = (taps(cx), taps(cy));
        let fx0 = region.x0 - cx.int - ox;
        let fy0 = region.y0 - cy.int - oy;
        // Frame rows fy and fy + 1 of each step, interpolated along x; output row
        // r + 1 reuses row r's lower row as its upper one.
        let mut top: Vec<Vec<f32>> = smoothed
            .iter()
            .map(|s| {
                let mut row = vec![0f32; cols];
                lerp_row(s, fx0, fy0, wx, &mut row);
                row
            })
            .collect();
        let mut bot = top.clone();
        for (r, out) in out.chunks_exact_mut(cols).enumerate() {
            let fy = fy0 + r as i64;
            for (s, row) in smoothed.iter().zip(bot.iter_mut()) {
                lerp_row(s, fx0, fy + 1, wx, row);
            }
            let lerp_y = |t: f32, b: f32| t * (1.0 - wy) + b * wy;
            if smoothed.len() > 1 {
                let (t0, b0, t1, b1) = (&top[0][..cols], &bot[0][..cols], &top[1][..cols], &bot[1][..cols]);
                for ((((o, &t0), &b0), &t1), &b1) in out.iter_mut().zip(t0).zip(b0).zip(t1).zip(b1) {
                    let d0 = lerp_y(t0, b0);
                    *o = (d0 + (lerp_y(t1, b1) - d0) * f).clamp(0.0, 1.0);
                }
            } else {
                for ((o, &t0), &b0) in out.iter_mut().zip(&top[0][..cols]).zip(&bot[0][..cols]) {
                    *o = lerp_y(t0, b0).clamp(0.0, 1.0);
                }
            }
            std::mem::swap(&mut top, &mut bot);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Config;

    /// The per-cell switch hash the blend was first written with; `switch_hashes`
    /// must equal it.
    fn switch_hash(stream: u64, k: usize, x: i64, y: i64) -> u32 {
        let h = mix64(stream ^ 0x6469_7468_6572 ^ ((k as u64) << 40) ^ mix64(x as u64 ^ mix64(y as u64)));
        (h >> 48) as u32
    }

    /// The plain form of `states`: one cell at a time.
    fn states_reference(sim: &LayerSim, steps: &[i64], windows: &[Rect]) -> Vec<Vec<Vec<u8>>> {
        // The same runs as `states`; what differs is the per-cell read below.
        let (plans, results) = run_plans(sim, steps, windows);
        plans
            .iter()
            .map(|p| {
                let snaps: Vec<&Snapshot> = p
                    .runs
                    .iter()
                    .map(|id| results[id].iter().find(|s| s.step == p.step).expect("snapshot planned"))
                    .collect();
                windows
                    .iter()
                    .enumerate()
                    .map(|(k, w)| {
                        let mut out = Vec::new();
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

    /// The plain tent: nine bounds-checked taps per cell, summed in f32.
    struct SmoothedReference {
        x0: i64,
        y0: i64,
        w: usize,
        values: Vec<f32>,
    }

    impl SmoothedReference {
        fn new(bits: &[u8], window: Rect) -> SmoothedReference {
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
            SmoothedReference {
                x0: window.x0,
                y0: window.y0,
                w,
                values,
            }
        }

        fn get(&self, x: i64, y: i64) -> f32 {
            self.values[(y - self.y0) as usize * self.w + (x - self.x0) as usize]
        }
    }

    /// The plain form of `density`: per-cell states, the nine-tap tent and four
    /// bounds-checked reads per sample.
    fn density_reference(sim: &LayerSim, region: Region, t: f64) -> Grid<f32> {
        let depth = sim.depth();
        let Sampling {
            steps,
            f,
            disp,
            windows,
        } = sampling(sim, region, t);
        let st = states_reference(sim, &steps, &windows);
        let mut grid = Grid::new(depth, region.rows, region.cols);
        let plane = region.rows * region.cols;
        for (k, out) in grid.data.chunks_mut(plane).enumerate() {
            let smoothed: Vec<SmoothedReference> = st
                .iter()
                .map(|levels| SmoothedReference::new(&levels[k], windows[k]))
                .collect();
            let (cx, cy) = disp[k];
            let ((ox, wx), (oy, wy)) = (taps(cx), taps(cy));
            for r in 0..region.rows {
                let fy = region.y0 + r as i64 - cy.int - oy;
                for c in 0..region.cols {
                    let fx = region.x0 + c as i64 - cx.int - ox;
                    let sample = |s: &SmoothedReference| {
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
        }
        grid
    }

    fn bits(grid: &Grid<f32>) -> Vec<u32> {
        grid.data.iter().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn density_and_cells_equal_their_plain_forms_through_run_switches() {
        let world = Config::embedded().world("default").unwrap();
        let sim = LayerSim::new(&world, 0);
        let layer = &sim.fields.layer;
        // Steps of the first epoch switch after a step with one run, so both kinds are covered.
        let two = (1..10_000)
            .find(|&m| plan_step(layer, m).runs.len() > 1 && plan_step(layer, m - 1).runs.len() == 1)
            .expect("a step blending two runs");
        let dt = layer.dt;
        let regions = [
            Region {
                x0: -37,
                y0: 5,
                cols: 41,
                rows: 23,
            },
            Region {
                x0: 100_003,
                y0: -7_777,
                cols: 1,
                rows: 3,
            },
        ];
        for region in regions {
            for t in [
                two as f64 * dt,
                (two as f64 - 0.5) * dt,
                (two as f64 + 0.37) * dt,
                (two as f64 + 1.0) * dt,
                1234.5,
            ] {
                assert_eq!(
                    bits(&density(&sim, region, t)),
                    bits(&density_reference(&sim, region, t)),
                    "{region:?} t={t}"
                );
            }
            let (n, _) = split_time(two as f64 * dt, dt);
            let windows: Vec<Rect> = (0..sim.depth() as i64)
                .map(|k| Rect {
                    x0: region.x0 - 3 * k,
                    x1: region.x0 + region.cols as i64 + k,
                    y0: region.y0 + k,
                    y1: region.y0 + region.rows as i64 + 2 * k,
                })
                .collect();
            assert_eq!(
                states(&sim, &[n, n + 1], &windows),
                states_reference(&sim, &[n, n + 1], &windows)
            );
        }
    }

    #[test]
    fn switch_hashes_equal_the_per_cell_hash() {
        let mut s = 9u64;
        for _ in 0..50 {
            s = mix64(s);
            let x0 = (s % 2_000_000) as i64 - 1_000_000;
            let y0 = (mix64(s) % 2_000_000) as i64 - 1_000_000;
            let w = Rect {
                x0,
                x1: x0 + (s >> 40) as i64 % 70,
                y0,
                y1: y0 + (s >> 50) as i64 % 9,
            };
            let k = (s >> 20) as usize % 12;
            let want: Vec<u16> = (w.y0..w.y1)
                .flat_map(|y| (w.x0..w.x1).map(move |x| switch_hash(s, k, x, y) as u16))
                .collect();
            for &backend in NoiseBackend::available() {
                assert_eq!(switch_hashes_on(backend, s, k, w), want, "{backend:?}");
            }
        }
    }

    #[test]
    fn switched_below_splits_the_hashes_as_pick_does() {
        let run = RunId { reference: 0, start: 0 };
        for fade in [0u32, 1, 2, 3, 7, 64, 1000, 65535, 65536, u32::MAX] {
            for phase in [-5i64, -1, 0, 1, 2, 6, 63, 999, 65535, 1 << 40] {
                for runs in [vec![run], vec![run, run]] {
                    let p = StepPlan {
                        step: 0,
                        runs,
                        phase,
                        fade,
                    };
                    let n1 = switched_below(&p);
                    for h in 0..65536u32 {
                        assert_eq!(p.pick(h), usize::from(h < n1), "fade {fade} phase {phase} h {h}");
                    }
                }
            }
        }
    }

    fn random_level(s: &mut u64) -> Level {
        *s = mix64(*s);
        let mut lv = Level::covering(Rect {
            x0: (*s % 400) as i64 - 200,
            x1: (*s % 400) as i64 - 200 + (*s >> 32) as i64 % 200,
            y0: (*s >> 16) as i64 % 9 - 4,
            y1: (*s >> 16) as i64 % 9 - 4 + (*s >> 24) as i64 % 7,
        });
        for w in lv.cld.iter_mut() {
            *s = mix64(*s);
            *w = *s;
        }
        lv
    }

    #[test]
    fn cld_row_equals_cld_at_inside_and_outside_the_level() {
        let mut s = 4u64;
        let mut scratch = Vec::new();
        for _ in 0..300 {
            let lv = random_level(&mut s);
            s = mix64(s);
            let x0 = lv.x0 + (s % 300) as i64 - 150;
            let y = lv.y0 + (s >> 20) as i64 % 12 - 3;
            let mut out = vec![7u8; (s >> 40) as usize % 400];
            cld_row(&lv, y, x0, &mut out, &mut scratch);
            let want: Vec<u8> = (0..out.len() as i64).map(|i| lv.cld_at(x0 + i, y) as u8).collect();
            assert_eq!(out, want, "{lv:?} x0 {x0} y {y}");
        }
    }

    #[test]
    fn tent_sums_equal_the_nine_tap_f32_tent() {
        let mut s = 17u64;
        let mut sizes: Vec<(i64, i64)> = (0..5).flat_map(|w| (0..5).map(move |h| (w, h))).collect();
        sizes.extend([(67, 13), (260, 3), (1, 40)]);
        for (w, h) in sizes {
            for density in [0u64, 1, 2, 3] {
                let cells: Vec<u8> = (0..w * h)
                    .map(|_| {
                        s = mix64(s);
                        // All clear, all cloud, and two mixes.
                        match density {
                            0 => 0,
                            1 => 1,
                            2 => (s & 1) as u8,
                            _ => u8::from(s.is_multiple_of(5)),
                        }
                    })
                    .collect();
                let window = Rect {
                    x0: -3 * w,
                    x1: -2 * w,
                    y0: 11,
                    y1: 11 + h,
                };
                let (got, want) = (Smoothed::new(&cells, window), SmoothedReference::new(&cells, window));
                for y in window.y0..window.y1 {
                    for x in window.x0..window.x1 {
                        let g = got.row_from(x, y)[0] as f32 / 16.0;
                        assert_eq!(g.to_bits(), want.get(x, y).to_bits(), "{w}×{h} at {x},{y}");
                    }
                }
            }
        }
    }

    /// Runs kept alive give the bits of cold runs: a region watched keyframe after
    /// keyframe (whole steps, and times between steps) across two epoch boundaries,
    /// on a Dobashi layer whose levels shear apart and on a Rosa layer; a region
    /// inside the kept one too; and a step the runs have passed is refused.
    #[test]
    fn live_runs_give_the_bits_of_cold_runs() {
        let world = Config::embedded().world("default").unwrap();
        for layer in [0, 2] {
            let sim = LayerSim::new(&world, layer);
            let dt = sim.fields.layer.dt;
            let region = Region::square(-40, 30, 70);
            let mut live = LiveRuns::new(region);
            let inner = Region::square(-20, 40, 33);
            // Phases 13..=37 of the 16-step epochs: two boundaries.
            for m in 16 * 100 + 13..16 * 102 + 6 {
                for t in [m as f64 * dt, (m as f64 + 0.25) * dt] {
                    let cold = density(&sim, region, t);
                    let warm = density_live(&sim, &mut live, region, t).expect("live covers its region");
                    assert!(cold.data == warm.data, "layer {layer}, t = {t}");
                }
                if m % 5 == 0 {
                    let t = m as f64 * dt + dt;
                    let warm = density_live(&sim, &mut live, inner, t).expect("inside");
                    assert!(density(&sim, inner, t).data == warm.data, "inner, t = {t}");
                }
            }
            assert!(live.steps_run() > 0 && live.bytes() > 0);
            // Gone past: refused, not wrong.
            assert!(density_live(&sim, &mut live, region, 16.0 * 100.0 * dt).is_none());
            // Outside the kept region: refused.
            let outside = Region::square(-40, 30, 90);
            assert!(density_live(&sim, &mut live, outside, 16.0 * 103.0 * dt).is_none());
        }
    }
}
