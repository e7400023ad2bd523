//! Runs of the automaton over exactly the cells a request needs.
//!
//! A run starts from an empty grid at step `start` and advances to its last
//! snapshot. Before it starts, the dependency cone is computed backwards: the
//! cells of level k needed at step n are those needed at n+1 widened by 2 in x
//! and y (the reach of f_act), plus the cells the levels above and below read
//! through their relative frame shift. Every level's grid covers its cone at the
//! start; each step computes only the (shrinking) cone. Cells outside the cone
//! may hold garbage but never feed a cell inside it, so the result over the
//! requested windows is exact whatever the window.

use rayon::prelude::*;

use super::frame::Frames;
use super::kernel::{Drives, Level, Rect, Rules, StepContext, step_level};
use super::random::StochasticDrives;
use crate::cancel::Cancel;
use crate::cpu::Backend;
use crate::fields::noise::NoiseBackend;
use crate::fields::noise::mix64;
use crate::fields::probability::{LevelMapping, max_filter};
use crate::fields::{FieldWindow, LayerFields, quantize};
use crate::world::{Mode, World, authored};

/// A layer ready to simulate: its fields, frames and random stream.
#[derive(Clone, Debug)]
pub struct LayerSim {
    /// The layer's probability fields.
    pub fields: LayerFields,
    /// The layer's wind frames, per level.
    pub frames: Frames,
    /// The layer's random stream: the key of every draw (from the world seed and layer index).
    pub stream: u64,
    /// Fired when nobody waits for this simulation any more: [`LayerSim::run`]
    /// then skips its remaining steps (the caller discards the result).
    pub cancel: Cancel,
}

/// One run: from an empty grid at `start` to the last snapshot.
#[derive(Clone, Debug)]
pub struct RunSpec {
    /// Step whose time and frame alignment the probability fields use.
    pub reference_step: i64,
    /// Step at which the grid is empty.
    pub start: i64,
    /// Steps (>= start, ascending) whose state is kept.
    pub snapshots: Vec<i64>,
    /// Frame window of each level that must be exact at every snapshot.
    pub windows: Vec<Rect>,
}

/// The state of every level at one step.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// The step the levels are at.
    pub step: i64,
    /// Every level's state, indexed by level.
    pub levels: Vec<Level>,
}

impl LayerSim {
    /// The simulation of layer `layer_index` of `world`.
    pub fn new(world: &World, layer_index: usize) -> LayerSim {
        let fields = LayerFields::new(world, layer_index);
        let frames = Frames::new(&fields.layer);
        let stream = mix64(world.seed ^ mix64(0x7374_7265_616d ^ ((layer_index as u64) << 32)));
        LayerSim {
            fields,
            frames,
            stream,
            cancel: Cancel::never(),
        }
    }

    /// Where and when the authored weather (`world::authored`) is evaluated for the
    /// run whose fields are aligned at step `reference`: at the middle of the epoch
    /// the run serves (Dobashi: steps `reference − E` to `reference`; Rosa: its own
    /// frame), with the reference frame's offset at that step, so that a frame cell
    /// `x` stands at world cell `x + offset` then. Returns (time in seconds, offset).
    pub fn authored_at(&self, reference: i64) -> (f64, (i64, i64)) {
        let layer = &self.fields.layer;
        let step = match layer.preset.mode {
            Mode::Dobashi => reference - (layer.epoch.length / 2) as i64,
            Mode::Rosa => reference,
        };
        (step as f64 * layer.dt, self.frames.reference_offset(step))
    }

    /// The number of vertical levels.
    pub fn depth(&self) -> usize {
        self.fields.layer.depth as usize
    }

    /// The rules of the layer's mode.
    pub fn rules(&self) -> Rules {
        match self.fields.layer.preset.mode {
            Mode::Dobashi => Rules::Dobashi,
            Mode::Rosa => Rules::Rosa,
        }
    }

    /// Frame offsets of every level at step `n`.
    pub fn offsets(&self, n: i64) -> Vec<(i64, i64)> {
        (0..self.depth() as u32).map(|k| self.frames.offset(k, n)).collect()
    }

    /// The cells of each level needed at each step from `start` to the last snapshot.
    fn cone(&self, spec: &RunSpec) -> Vec<Vec<Rect>> {
        let end = *spec.snapshots.last().expect("a run has a snapshot");
        self.cone_of(spec.start, end, |n| {
            spec.snapshots.contains(&n).then_some(spec.windows.as_slice())
        })
    }

    /// The cells of each level needed at each step from `start` to `end` (index
    /// `n − start`) for the windows `target(n)` of the steps that have them (`end`
    /// must): the cells needed at n + 1 widened by 2 in x and y (the reach of
    /// f_act), plus those the levels above and below read through their relative
    /// frame shift, plus `target(n)`.
    pub(crate) fn cone_of<'w>(
        &self,
        start: i64,
        end: i64,
        target: impl Fn(i64) -> Option<&'w [Rect]>,
    ) -> Vec<Vec<Rect>> {
        let depth = self.depth();
        let steps = (end - start) as usize;
        let mut need = vec![vec![Rect::default(); depth]; steps + 1];
        need[steps] = target(end).expect("the last step has windows").to_vec();
        let dobashi = self.rules() == Rules::Dobashi;
        for s in (0..steps).rev() {
            let n = start + s as i64;
            let offsets = if dobashi { self.offsets(n) } else { Vec::new() };
            let windows = target(n);
            for k in 0..depth {
                let mut r = need[s + 1][k].expand(2);
                if dobashi {
                    // Level kk reads level k when k = kk + 1, kk − 1 or kk − 2.
                    for kk in [k as i64 - 1, k as i64 + 1, k as i64 + 2] {
                        if kk >= 0 && (kk as usize) < depth {
                            let (ax, ay) = offsets[kk as usize];
                            let (bx, by) = offsets[k];
                            r = r.hull(&need[s + 1][kk as usize].shift(ax - bx, ay - by));
                        }
                    }
                }
                if let Some(w) = windows {
                    r = r.hull(&w[k]);
                }
                need[s][k] = r;
            }
        }
        need
    }

    /// One step of every level, from `levels` (at step `n`) into `next` (at n + 1),
    /// computing the cells `need_next` of each level; skipped once cancelled (the
    /// caller then discards the result).
    pub(crate) fn step_all(&self, levels: &[Level], next: &mut [Level], drives: &[Drives], n: i64, need_next: &[Rect]) {
        if self.cancel.is_fired() {
            return;
        }
        let offsets = self.offsets(n);
        let ctx = StepContext {
            rules: self.rules(),
            stream: self.stream,
            n,
            offsets: &offsets,
        };
        next.par_iter_mut()
            .enumerate()
            .for_each(|(k, o)| step_level(levels, k, &drives[k], &ctx, need_next[k], o));
    }

    /// Per-level drives over each level's grid, from fields aligned at the reference step.
    pub fn drives(&self, levels: &[Level], reference_step: i64) -> Vec<Drives> {
        self.drives_on(levels, reference_step, NoiseBackend::detect())
    }

    /// [`LayerSim::drives`] converting on one backend (one of
    /// [`NoiseBackend::available`]); every backend gives the same drives.
    fn drives_on(&self, levels: &[Level], reference_step: i64, backend: NoiseBackend) -> Vec<Drives> {
        let f = &self.fields;
        let layer = &f.layer;
        let r_off = self.frames.reference_offset(reference_step);
        // Level k's frame cell x is reference-frame cell x + O_k(ref) − O_ref(ref).
        let shifts: Vec<(i64, i64)> = (0..self.depth() as u32)
            .map(|k| {
                let o = self.frames.offset(k, reference_step);
                (o.0 - r_off.0, o.1 - r_off.1)
            })
            .collect();
        let mut hull = Rect::default();
        for (lv, s) in levels.iter().zip(&shifts) {
            let r = Rect {
                x0: lv.x0,
                x1: lv.x0 + 64 * lv.wpr as i64,
                y0: lv.y0,
                y1: lv.y0 + lv.rows as i64,
            };
            hull = hull.hull(&r.shift(s.0, s.1));
        }
        // An anvil spreads brightness from up to its radius away: the window grows by
        // that margin so that every cell's spread is whole, whatever the tiling.
        let margin = f.anvil_cells();
        let hull = hull.expand(margin as i64);
        let tau = f.tau(reference_step as f64 * layer.dt);
        let start = std::time::Instant::now();
        let window = f.window(
            hull.x0,
            hull.y0,
            (hull.x1 - hull.x0) as usize,
            (hull.y1 - hull.y0) as usize,
            f.coarse_spacing(),
            tau,
            r_off,
        );
        let spread: Option<[Vec<f32>; 2]> =
            (margin > 0).then(|| [0, 1].map(|i| max_filter(&window.b[i], window.w, window.h, margin)));
        let fields_done = start.elapsed();
        let thresholds = layer.preset.rosa_thresholds.map(|v| v as f32);
        let mode = layer.preset.mode;
        // The authored weather over the window's cells, at the run's authored time and
        // moved by the reference-frame offset into world metres.
        let authored = (!layer.authored.is_empty()).then(|| {
            let (t, (dx, dy)) = self.authored_at(reference_step);
            let centres =
                |from: i64, n: usize, d: i64| (0..n as i64).map(|c| metres(from + c + d, layer.cell_size)).collect();
            authored::GridPushes::new(
                &layer.authored,
                t,
                centres(hull.x0, window.w, dx),
                centres(hull.y0, window.h, dy),
            )
        });
        let drives: Vec<Drives> = levels
            .par_iter()
            .enumerate()
            .map(|(k, lv)| {
                let conv = Conversion {
                    f,
                    level: f.level_mapping(k as u32),
                    k: k as u32,
                    lv,
                    window: &window,
                    hull,
                    shift: shifts[k],
                    authored: authored.as_ref(),
                    spread: spread.as_ref(),
                };
                match mode {
                    Mode::Dobashi => Drives::Stochastic(stochastic(&conv, backend)),
                    Mode::Rosa => {
                        let words = lv.wpr * lv.rows;
                        let (mut hum, mut act, mut keep) = (vec![0u64; words], vec![0u64; words], vec![0u64; words]);
                        conv.each_word(|i, p| {
                            hum[i] |= lanes_above(&p[0], thresholds[0]);
                            act[i] |= lanes_above(&p[1], thresholds[1]);
                            keep[i] |= lanes_above(&p[2], thresholds[2]);
                        });
                        Drives::Threshold { hum, act, keep }
                    }
                }
            })
            .collect();
        // Where a cold tile's time goes (`RUST_LOG=cloudscape=debug`; BENCHMARKS.md "Cold tile").
        tracing::debug!(
            window = format!("{}x{}", window.w, window.h),
            words = levels.iter().map(|l| l.wpr * l.rows).sum::<usize>(),
            fields_ms = millis(fields_done),
            conversion_ms = millis(start.elapsed() - fields_done),
            "drives"
        );
        drives
    }

    /// The cell-steps `spec` costs: the cells of every level's cone summed over its
    /// steps (the work [`LayerSim::run`] does, from the same cone). Used to refuse
    /// requests that cannot finish in their time budget before they start.
    pub fn run_cells(&self, spec: &RunSpec) -> u64 {
        self.cone(spec)
            .iter()
            .skip(1)
            .flatten()
            .map(|r| ((r.x1 - r.x0).max(0) as u64).saturating_mul((r.y1 - r.y0).max(0) as u64))
            .fold(0u64, u64::saturating_add)
    }

    /// Executes a run and returns its snapshots.
    pub fn run(&self, spec: &RunSpec) -> Vec<Snapshot> {
        debug_assert!(spec.snapshots.is_sorted(), "snapshots ascending");
        let need = self.cone(spec);
        let end = *spec.snapshots.last().expect("a run has a snapshot");
        let mut levels: Vec<Level> = need[0].iter().map(|r| Level::covering(*r)).collect();
        let drives = self.drives(&levels, spec.reference_step);
        let mut next = levels.clone();
        let start = std::time::Instant::now();
        let mut out = Vec::new();
        if spec.snapshots.contains(&spec.start) {
            out.push(Snapshot {
                step: spec.start,
                levels: levels.clone(),
            });
        }
        for (s, need_next) in need.iter().enumerate().skip(1) {
            let n = spec.start + s as i64 - 1;
            // Once cancelled, the remaining steps are skipped: the snapshots keep
            // their shape, their bits are meaningless and the caller discards them.
            self.step_all(&levels, &mut next, &drives, n, need_next);
            std::mem::swap(&mut levels, &mut next);
            if n + 1 == end {
                // The steps' time, copies of earlier snapshots included.
                tracing::debug!(steps = end - spec.start, steps_ms = millis(start.elapsed()), "run");
                // The last step: the grids are not needed after it, so no copy.
                out.push(Snapshot { step: end, levels });
                return out;
            }
            if spec.snapshots.contains(&(n + 1)) {
                out.push(Snapshot {
                    step: n + 1,
                    levels: levels.clone(),
                });
            }
        }
        out
    }
}

/// A duration in milliseconds to 0.01 ms, for the phase logs.
pub(crate) fn millis(d: std::time::Duration) -> f64 {
    (d.as_secs_f64() * 1e5).round() / 100.0
}

/// The centre of cell `c` along one axis, world metres.
fn metres(c: i64, cell_size: f64) -> f64 {
    (c as f64 + 0.5) * cell_size
}

/// What turns one level's field window into drives: the level's grid, its frame
/// shift from the reference frame, and the window.
struct Conversion<'a> {
    f: &'a LayerFields,
    level: LevelMapping,
    k: u32,
    lv: &'a Level,
    window: &'a FieldWindow,
    hull: Rect,
    shift: (i64, i64),
    /// The authored weather's push over the window (with authored weather).
    authored: Option<&'a authored::GridPushes<'a>>,
    /// The anvil's spread of humidity and activation over the window (with an anvil).
    spread: Option<&'a [Vec<f32>; 2]>,
}

impl Conversion<'_> {
    /// Calls `word(index, values)` for every word of the level in order, with its
    /// 64 lanes' (hum, act, ext) probabilities (Dobashi) or textures (Rosa).
    #[inline(always)]
    fn each_word(&self, mut word: impl FnMut(usize, &[[f32; 64]; 3])) {
        let (f, lv, window, hull) = (self.f, self.lv, self.window, self.hull);
        let (sx, sy) = self.shift;
        let layer = &f.layer;
        let has_ellipsoids = !layer.ellipsoids.is_empty();
        let authored = self.authored;
        let z = layer.level_altitude(self.k);
        let anvil = f.anvil_weight(self.k);
        let spread = self.spread.filter(|_| anvil > 0.0);
        let mut ew = [1.0f32; 64];
        let (mut hum, mut act) = ([0f32; 64], [0f32; 64]);
        let mut p = [[0f32; 64]; 3];
        for r in 0..lv.rows {
            let y = lv.y0 + r as i64 + sy;
            let row = (y - hull.y0) as usize * window.w;
            for w in 0..lv.wpr {
                // Lane b is frame cell x0 + b; its brightness is at column x0 + b − hull.x0.
                let x0 = lv.x0 + 64 * w as i64 + sx;
                let at = row + (x0 - hull.x0) as usize;
                let mut bright: [&[f32; 64]; 3] =
                    std::array::from_fn(|i| window.b[i][at..at + 64].try_into().expect("64 lanes"));
                if authored.is_some() || spread.is_some() {
                    for b in 0..64 {
                        let (mut h, mut a) = (bright[0][b], bright[1][b]);
                        if let Some(m) = spread {
                            h += (m[0][at + b] - h) * anvil;
                            a += (m[1][at + b] - a) * anvil;
                        }
                        if let Some(pushes) = authored {
                            let s = pushes.at((x0 - hull.x0) as usize + b, (y - hull.y0) as usize, z);
                            (h, a) = (authored::pushed(h, s), authored::pushed(a, s));
                        }
                        (hum[b], act[b]) = (h, a);
                    }
                    bright = [&hum, &act, bright[2]];
                }
                if has_ellipsoids {
                    for (b, e) in ew.iter_mut().enumerate() {
                        let x = x0 + b as i64;
                        *e = f.ellipsoid_weight(
                            (x as f64 + 0.5) * layer.cell_size,
                            (y as f64 + 0.5) * layer.cell_size,
                            self.k,
                        );
                    }
                }
                self.level.values(bright, &ew, &mut p);
                word(r * lv.wpr + w, &p);
            }
        }
    }
}

/// A Rosa drive word: bit b is set where lane b's texture is above `threshold`.
#[inline]
fn lanes_above(lanes: &[f32; 64], threshold: f32) -> u64 {
    lanes
        .iter()
        .enumerate()
        .fold(0, |word, (b, &v)| word | (((v > threshold) as u64) << b))
}

/// A Dobashi level's drives: per word, the probabilities quantized to thresholds
/// and appended ([`StochasticDrives::push`]), on `backend` (one of
/// [`NoiseBackend::available`]).
fn stochastic(conv: &Conversion, backend: NoiseBackend) -> StochasticDrives {
    assert!(backend.runs_here(), "{backend:?} conversion on a CPU without it");
    match backend {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the CPU has AVX-512 F (asserted above).
        NoiseBackend::Avx512 => unsafe { stochastic_avx512(conv) },
        _ => stochastic_with(conv, |d, q| d.push_baseline(q)),
    }
}

#[inline(always)]
fn stochastic_with(conv: &Conversion, push: impl Fn(&mut StochasticDrives, [&[u32; 64]; 3])) -> StochasticDrives {
    let mut out = StochasticDrives::with_capacity(conv.lv.wpr * conv.lv.rows);
    let mut q = [[0u32; 64]; 3];
    conv.each_word(|_, p| {
        // Plain loops into a buffer kept across words, so `quantize` runs on many lanes at a time.
        for (q, p) in q.iter_mut().zip(p) {
            for (q, &p) in q.iter_mut().zip(p) {
                *q = quantize(p);
            }
        }
        push(&mut out, q.each_ref());
    });
    out
}

/// [`stochastic`] compiled with AVX-512: the lane loops of `values` and
/// `quantize` take 16 lanes per instruction (8 in the baseline build) and
/// [`StochasticDrives::push_avx512`] is inlined. The same IEEE operations in the same
/// order (Rust never contracts or reorders float arithmetic), so the same bits.
/// Measured in BENCHMARKS.md "Cold tile" (the conversion phase of
/// `RUST_LOG=cloudscape=debug target/release/examples/profile_kernel tile`).
///
/// # Safety
/// The CPU must have AVX-512 F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn stochastic_avx512(conv: &Conversion) -> StochasticDrives {
    // SAFETY: this function's caller checked the CPU.
    stochastic_with(conv, |d, q| unsafe { d.push_avx512(q) })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{Config, Ellipsoid};

    /// The AVX-512 conversion and the baseline one give the same drives, on a layer
    /// with Dobashi ellipsoids (so the weights are not all 1) and levels whose
    /// windows and frame shifts differ.
    #[test]
    fn conversion_forms_agree() {
        let mut world = Config::embedded().world("default").expect("the default world");
        let layer = &mut world.layers[0];
        let alt = layer.level_altitude(3);
        layer.ellipsoids.push(Ellipsoid {
            centre: [3000.0, -2000.0, alt],
            radii: [4000.0, 2500.0, 600.0],
        });
        let sim = LayerSim::new(&world, 0);
        let levels: Vec<Level> = (0..sim.depth() as i64)
            .map(|k| {
                Level::covering(Rect {
                    x0: -70 + 13 * k,
                    x1: 250 + 7 * k,
                    y0: -40 - 5 * k,
                    y1: 90,
                })
            })
            .collect();
        for step in [0, 7, 64] {
            let base = sim.drives_on(&levels, step, NoiseBackend::Scalar);
            for &backend in NoiseBackend::available() {
                let got = sim.drives_on(&levels, step, backend);
                for (k, (b, g)) in base.iter().zip(&got).enumerate() {
                    match (b, g) {
                        (Drives::Stochastic(b), Drives::Stochastic(g)) => {
                            assert!(
                                b.heads().iter().any(|h| h.live != [0; 3]),
                                "level {k}: some drive is live"
                            );
                            assert!(b == g, "{backend:?}: level {k} at step {step}");
                        }
                        _ => panic!("a Dobashi layer has stochastic drives"),
                    }
                }
            }
        }
    }
}
