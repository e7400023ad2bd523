//! The bit-packed kernel: 64 cells per `u64` along x, one step of the Dobashi
//! 2000 rules (or Rosa 2013's thresholded variant) for one vertical level.
//!
//! Rules (Dobashi et al. 2000, eq. 1–4; Rosa 2013, eq. 3.1–3.4 with the typo in
//! 3.4 corrected from `act(i, j−1, k−1)` to Dobashi's `act(i, j, k−1)`):
//!
//! ```text
//! hum' = (hum ∧ ¬act) ∨ B(p_hum)
//! act' = (¬act ∧ hum ∧ f_act) ∨ B(p_act)
//! cld' = (cld ∨ act) ∧ ¬B(p_ext)
//! f_act = act(x±1) ∨ act(x±2) ∨ act(y±1) ∨ act(y±2) ∨ act(z+1) ∨ act(z−1) ∨ act(z−2)
//! ```
//!
//! Mode `rosa` (eq. 3.5–3.9): the textures are the randomness, so B(p) becomes
//! `tex > p` and f_act is the in-plane 8-neighbour set of eq. 3.9. Rosa writes
//! the equations without parentheses; we read them with ∧ applying to the whole
//! preceding disjunction, as Dobashi's separate "extinction" step does:
//! `cld' = (cld ∨ act) ∧ (tex_cld > p_ext)` and
//! `act' = (hum ∧ ¬act ∧ f_act) ∨ (tex_act > p_act)`. With ∧ binding tighter
//! (`cld ∨ (act ∧ …)`) no cloud could ever disappear, which contradicts the text.
//! Cells outside the grid read as empty ("out of range results in a false value").

use std::ops::Range;

use super::random::{DrawBackend, StepKeys, StochasticDrives, below_portable};
use crate::cpu::Backend;

/// A half-open rectangle of frame cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Rect {
    /// First column (inclusive).
    pub x0: i64,
    /// Column past the last (exclusive).
    pub x1: i64,
    /// First row (inclusive).
    pub y0: i64,
    /// Row past the last (exclusive).
    pub y1: i64,
}

impl Rect {
    /// Whether the rectangle holds no cell.
    pub fn is_empty(&self) -> bool {
        self.x1 <= self.x0 || self.y1 <= self.y0
    }

    /// The smallest rectangle holding both.
    pub fn hull(&self, o: &Rect) -> Rect {
        if self.is_empty() {
            return *o;
        }
        if o.is_empty() {
            return *self;
        }
        Rect {
            x0: self.x0.min(o.x0),
            x1: self.x1.max(o.x1),
            y0: self.y0.min(o.y0),
            y1: self.y1.max(o.y1),
        }
    }

    /// The rectangle grown by `d` cells on every side (an empty one stays empty).
    pub fn expand(&self, d: i64) -> Rect {
        if self.is_empty() {
            return *self;
        }
        Rect {
            x0: self.x0 - d,
            x1: self.x1 + d,
            y0: self.y0 - d,
            y1: self.y1 + d,
        }
    }

    /// The rectangle moved by (`dx`, `dy`) cells (an empty one stays empty).
    pub fn shift(&self, dx: i64, dy: i64) -> Rect {
        if self.is_empty() {
            return *self;
        }
        Rect {
            x0: self.x0 + dx,
            x1: self.x1 + dx,
            y0: self.y0 + dy,
            y1: self.y1 + dy,
        }
    }
}

/// One vertical level's state over a window of its frame, bit-packed along x.
/// Bit `b` of word `w` in row `r` is frame cell (`x0 + 64w + b`, `y0 + r`).
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    /// Frame x of the first bit; a multiple of 64, so words line up with the
    /// global word grid the random keys use.
    pub x0: i64,
    /// Frame y of row 0.
    pub y0: i64,
    /// Words per row.
    pub wpr: usize,
    /// Rows.
    pub rows: usize,
    /// Humidity bits, `wpr` words a row.
    pub hum: Vec<u64>,
    /// Activation bits, `wpr` words a row.
    pub act: Vec<u64>,
    /// Cloud bits, `wpr` words a row.
    pub cld: Vec<u64>,
}

impl Level {
    /// An empty level covering at least `r` (x widened to whole words).
    pub fn covering(r: Rect) -> Level {
        let x0 = r.x0.div_euclid(64) * 64;
        let x1 = (r.x1 + 63).div_euclid(64) * 64;
        let wpr = ((x1 - x0) / 64).max(0) as usize;
        let rows = (r.y1 - r.y0).max(0) as usize;
        Level {
            x0,
            y0: r.y0,
            wpr,
            rows,
            hum: vec![0; wpr * rows],
            act: vec![0; wpr * rows],
            cld: vec![0; wpr * rows],
        }
    }

    /// The level cut to the words and rows covering `r` (which must lie inside it),
    /// the cells' bits kept, and where the cut lies in the old grid: (rows, words).
    pub fn cropped(&self, r: Rect) -> (Level, std::ops::Range<usize>, std::ops::Range<usize>) {
        let mut out = Level::covering(r);
        let w0 = ((out.x0 - self.x0) / 64) as usize;
        let r0 = (out.y0 - self.y0) as usize;
        debug_assert!(
            w0 + out.wpr <= self.wpr && r0 + out.rows <= self.rows,
            "{r:?} inside the level"
        );
        for row in 0..out.rows {
            let from = (r0 + row) * self.wpr + w0;
            let to = row * out.wpr;
            out.hum[to..to + out.wpr].copy_from_slice(&self.hum[from..from + out.wpr]);
            out.act[to..to + out.wpr].copy_from_slice(&self.act[from..from + out.wpr]);
            out.cld[to..to + out.wpr].copy_from_slice(&self.cld[from..from + out.wpr]);
        }
        let (rows, words) = (r0..r0 + out.rows, w0..w0 + out.wpr);
        (out, rows, words)
    }

    /// The cloud bit at a frame cell (false outside).
    #[inline]
    pub fn cld_at(&self, x: i64, y: i64) -> bool {
        let (dx, dy) = (x - self.x0, y - self.y0);
        if dx < 0 || dy < 0 || dx >= (self.wpr * 64) as i64 || dy >= self.rows as i64 {
            return false;
        }
        (self.cld[dy as usize * self.wpr + (dx / 64) as usize] >> (dx % 64)) & 1 == 1
    }
}

/// What drives formation and extinction for one level (same geometry as its `Level`).
#[derive(Clone, Debug)]
pub enum Drives {
    /// Dobashi: per word, the three probabilities as thresholds (see `random`).
    Stochastic(StochasticDrives),
    /// Rosa: per word, `tex_hum > p_hum`, `tex_act > p_act`, and `tex_cld > p_ext` (keep).
    Threshold {
        /// Cells where `tex_hum > p_hum`: humidity appears.
        hum: Vec<u64>,
        /// Cells where `tex_act > p_act`: activation appears.
        act: Vec<u64>,
        /// Cells where `tex_cld > p_ext`: cloud is kept.
        keep: Vec<u64>,
    },
}

impl Drives {
    /// The drives of rows `rows` and word columns `words` of a level `wpr` words wide
    /// (see [`Level::cropped`]).
    pub fn cropped(&self, wpr: usize, rows: Range<usize>, words: Range<usize>) -> Drives {
        let cut = |v: &Vec<u64>| -> Vec<u64> {
            rows.clone()
                .flat_map(|r| v[r * wpr + words.start..r * wpr + words.end].iter().copied())
                .collect()
        };
        match self {
            Drives::Stochastic(d) => Drives::Stochastic(d.crop(wpr, rows, words)),
            Drives::Threshold { hum, act, keep } => Drives::Threshold {
                hum: cut(hum),
                act: cut(act),
                keep: cut(keep),
            },
        }
    }

    /// Bytes the drives hold.
    pub fn bytes(&self) -> usize {
        match self {
            Drives::Stochastic(d) => d.bytes(),
            Drives::Threshold { hum, act, keep } => 8 * (hum.len() + act.len() + keep.len()),
        }
    }
}

/// Which rule set a step applies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rules {
    /// Dobashi 2000: 11 neighbours including z, stochastic drives.
    Dobashi,
    /// Rosa 2013: 8 in-plane neighbours, threshold drives.
    Rosa,
}

/// Everything a step of one level needs besides the grids.
pub struct StepContext<'a> {
    /// The rule set of the layer's mode.
    pub rules: Rules,
    /// The layer's random stream (seed and layer).
    pub stream: u64,
    /// The step being advanced from (state at `n` → state at `n + 1`).
    pub n: i64,
    /// Frame offset of every level at step `n` (z neighbours are found through them).
    pub offsets: &'a [(i64, i64)],
}

/// Advances level `k` from `old` (all levels at step n) into `out` (level k at
/// step n + 1, same geometry as `old[k]`), computing the words covering `window`.
pub fn step_level(old: &[Level], k: usize, drives: &Drives, ctx: &StepContext, window: Rect, out: &mut Level) {
    step_level_on(DrawBackend::detect(), old, k, drives, ctx, window, out)
}

/// [`step_level`] with the draws made by `backend` (one of [`DrawBackend::available`]).
pub fn step_level_on(
    backend: DrawBackend,
    old: &[Level],
    k: usize,
    drives: &Drives,
    ctx: &StepContext,
    window: Rect,
    out: &mut Level,
) {
    let lv = &old[k];
    debug_assert_eq!((lv.x0, lv.y0, lv.wpr, lv.rows), (out.x0, out.y0, out.wpr, out.rows));
    if window.is_empty() || lv.wpr == 0 {
        return;
    }
    match drives {
        Drives::Stochastic(words) => {
            let keys = StepKeys::new(ctx.stream, k as u32, ctx.n);
            match backend {
                #[cfg(target_arch = "x86_64")]
                DrawBackend::Avx512 => {
                    assert!(DrawBackend::Avx512.runs_here(), "AVX-512 draws on a CPU without them");
                    // SAFETY: the CPU has AVX-512 F, BW and VAES (asserted above).
                    unsafe {
                        if words.has_always() {
                            step_avx512::<true>(old, k, words, &keys, ctx, window, out)
                        } else {
                            step_avx512::<false>(old, k, words, &keys, ctx, window, out)
                        }
                    }
                }
                _ => {
                    let (mantissas, heads) = (words.mantissas(), words.heads());
                    step_rows(old, k, ctx, window, out, |y, wx, i, s| {
                        let (t, head) = (&mantissas[i], heads[i]);
                        dobashi(
                            s,
                            words.always(head),
                            |e| head.live[e],
                            |e| below_portable(&keys, y, wx, e, &t[e], head.shift[e]),
                        )
                    })
                }
            }
        }
        Drives::Threshold { hum, act, keep } => step_rows(old, k, ctx, window, out, |_, _, i, [a, h, c, f]| {
            [(h & !a) | hum[i], (!a & h & f) | act[i], (c | a) & keep[i]]
        }),
    }
}

/// A z neighbour's row as [`step_avx512`] reads it: the z neighbour of this
/// level's word w is the 64 bits of `src` from bit 64 (q + w) + sh on, source
/// words outside 0..n reading as 0.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct ZRow {
    src: *const u64,
    /// Words from one row of the source level to the next.
    stride: i64,
    n: std::arch::x86_64::__m512i,
    q: i64,
    sh: std::arch::x86_64::__m128i,
    /// 63 − sh.
    back: std::arch::x86_64::__m128i,
}

/// A Dobashi step with the AVX-512 draws, compiled as one function so that the
/// keys stay in registers across rows. Each row goes 8 words at a time: f_act and
/// the rules' deterministic part for the 8 words in vectors, then the draws word
/// by word, which add (hum, act) or remove (cld) the lanes their events fire in.
/// `ALWAYS`: whether some word of the level has lanes that always fire. Most
/// levels have none (only probabilities that quantize to 1 make them), so on
/// those the kernel skips a load per word and the branch that waits on it
/// (BENCHMARKS.md "Automaton").
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,vaes")]
unsafe fn step_avx512<const ALWAYS: bool>(
    old: &[Level],
    k: usize,
    words: &StochasticDrives,
    keys: &StepKeys,
    ctx: &StepContext,
    window: Rect,
    out: &mut Level,
) {
    use std::arch::x86_64::*;

    use super::random::avx512;
    // OR of three operands, and ¬a ∧ b ∧ c, as `vpternlogq` truth tables.
    const OR3: i32 = 0xfe;
    const NA_B_C: i32 = 0x08;
    // SAFETY (all calls below): the caller checked the CPU's features.
    let keys = unsafe { avx512::keys(keys) };
    let span = Span::new(old, k, ctx, window);
    let lv = &old[k];
    let wpr = lv.wpr;
    let (w_lo, w_hi) = (span.words.start, span.words.end);
    let (mantissas, heads) = (words.mantissas(), words.heads());
    // Index vectors: lane l of a chunk starting at word w is word w + l. A lane is
    // read only where its index is in its row (0 ≤ i < n, one unsigned compare).
    let iota = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
    let one = _mm512_set1_epi64(1);
    let wpr_v = _mm512_set1_epi64(wpr as i64);
    let inside = |i: __m512i, n: __m512i| _mm512_cmplt_epu64_mask(i, n);
    // Per z neighbour: its level, row offset, and the parts of its `ZRow` that are
    // the same for every row (each row sets `src`).
    let mut z_levels: [Option<(&Level, i64, ZRow)>; 3] = [None; 3];
    for (slot, z) in z_levels.iter_mut().zip(&span.z) {
        if let Some((nl, ry, shift)) = z {
            let zrow = ZRow {
                src: std::ptr::null(),
                stride: nl.wpr as i64,
                n: _mm512_set1_epi64(shift.n),
                q: shift.q - w_lo as i64,
                sh: _mm_cvtsi64_si128(shift.sh as i64),
                back: _mm_cvtsi64_si128(63 - shift.sh as i64),
            };
            *slot = Some((*nl, *ry, zrow));
        }
    }
    for r in span.rows.clone() {
        let y = lv.y0 + r as i64;
        let base = r * wpr;
        let act = lv.act.as_ptr();
        // The y neighbours' rows (cells outside the level read as empty).
        let mut ys: [Option<*const u64>; 4] = [None; 4];
        for (slot, d) in ys.iter_mut().zip([-2i64, -1, 1, 2]) {
            let rr = r as i64 + d;
            if rr >= 0 && (rr as usize) < lv.rows {
                *slot = Some(act.wrapping_add(rr as usize * wpr));
            }
        }
        // The z neighbours' rows.
        let mut zs: [Option<ZRow>; 3] = [None; 3];
        for (slot, z) in zs.iter_mut().zip(&z_levels) {
            if let Some((nl, ry, zrow)) = z {
                let rr = y + ry - nl.y0;
                if rr >= 0 && rr < nl.rows as i64 {
                    *slot = Some(ZRow {
                        src: nl.act.as_ptr().wrapping_add(rr as usize * nl.wpr),
                        ..*zrow
                    });
                }
            }
        }
        let a_row = act.wrapping_add(base);
        let (h_row, c_row) = (lv.hum.as_ptr().wrapping_add(base), lv.cld.as_ptr().wrapping_add(base));
        let row = unsafe { avx512::row(y) };
        let mut w = w_lo;
        while w < w_hi {
            let wv = _mm512_add_epi64(_mm512_set1_epi64(w as i64), iota);
            // Words i … i + 7 from `p`, the lanes outside `m` as 0.
            // SAFETY: only the lanes in `m` are read, and `inside` keeps them in their row.
            macro_rules! at {
                ($p:expr, $m:expr, $i:expr) => {
                    unsafe { _mm512_maskz_loadu_epi64($m, $p.wrapping_offset($i as isize).cast()) }
                };
            }
            let in_row = inside(wv, wpr_v);
            let a = at!(a_row, in_row, w);
            let prev = at!(a_row, inside(_mm512_sub_epi64(wv, one), wpr_v), w as i64 - 1);
            let next = at!(a_row, inside(_mm512_add_epi64(wv, one), wpr_v), w + 1);
            // Lane b is cell x0 + 64w + b; its x+d neighbour is lane b+d.
            let mut f = _mm512_ternarylogic_epi64::<OR3>(
                _mm512_srli_epi64::<1>(a),
                _mm512_srli_epi64::<2>(a),
                _mm512_slli_epi64::<1>(a),
            );
            f = _mm512_ternarylogic_epi64::<OR3>(f, _mm512_slli_epi64::<2>(a), _mm512_slli_epi64::<63>(next));
            f = _mm512_ternarylogic_epi64::<OR3>(f, _mm512_slli_epi64::<62>(next), _mm512_srli_epi64::<63>(prev));
            f = _mm512_or_si512(f, _mm512_srli_epi64::<62>(prev));
            for p in ys.iter().flatten() {
                f = _mm512_or_si512(f, at!(*p, in_row, w));
            }
            // z neighbours: for this level's word w, source words q + w and q + w + 1
            // joined at `sh` (see `ZRow`).
            for z in zs.iter().flatten() {
                // The source rows were written by whichever thread stepped that level:
                // fetch the ones two rows on ahead.
                let ahead = z
                    .src
                    .wrapping_offset((z.q + w as i64 + 2 * z.stride) as isize)
                    .cast::<i8>();
                _mm_prefetch::<_MM_HINT_T0>(ahead);
                _mm_prefetch::<_MM_HINT_T0>(ahead.wrapping_add(64));
                let qv = _mm512_add_epi64(wv, _mm512_set1_epi64(z.q));
                let lo = at!(z.src, inside(qv, z.n), z.q + w as i64);
                let hi = at!(z.src, inside(_mm512_add_epi64(qv, one), z.n), z.q + w as i64 + 1);
                let join = _mm512_or_si512(
                    _mm512_srl_epi64(lo, z.sh),
                    _mm512_sll_epi64(_mm512_slli_epi64::<1>(hi), z.back),
                );
                f = _mm512_or_si512(f, join);
            }
            let h = at!(h_row, in_row, w);
            let c = at!(c_row, in_row, w);
            // The rules with no event firing: [hum ∧ ¬act, ¬act ∧ hum ∧ f_act, cld ∨ act].
            let mut det = [[0u64; 8]; 3];
            for (d, v) in det.iter_mut().zip([
                _mm512_andnot_si512(a, h),
                _mm512_ternarylogic_epi64::<NA_B_C>(a, h, f),
                _mm512_or_si512(c, a),
            ]) {
                // SAFETY: `d` is 8 words.
                unsafe { _mm512_storeu_si512(d.as_mut_ptr().cast(), v) };
            }
            let n = (w_hi - w).min(8);
            #[allow(clippy::needless_range_loop)] // l indexes the three rows of `det` and the drives
            for l in 0..n {
                let (wl, i) = (w + l, base + w + l);
                // The mantissas are the large stream the kernel reads (192 bytes a
                // word; the heads' 32 come in order, which the hardware prefetcher
                // follows on its own): fetch a few words ahead. A prefetch past the end is harmless.
                let ahead = mantissas.as_ptr().wrapping_add(i + 6).cast::<i8>();
                for line in 0..3 {
                    _mm_prefetch::<_MM_HINT_T0>(ahead.wrapping_add(64 * line));
                }
                let ctr = unsafe { avx512::word(row, span.wx0 + wl as i64) };
                let (t, head) = (&mantissas[i], heads[i]);
                let [h, a, c] = with_draws(
                    [det[0][l], det[1][l], det[2][l]],
                    if ALWAYS { words.always(head) } else { [0; 3] },
                    |e| head.live[e],
                    |e| unsafe { avx512::below(&keys, ctr, e, &t[e], head.shift[e]) },
                );
                (out.hum[i], out.act[i], out.cld[i]) = (h, a, c);
            }
            w += 8;
        }
    }
}

/// The Dobashi rules for one word from its state `[act, hum, cld, f_act]`, with
/// the events' `always` masks, `live(event)` their live lanes and
/// `below(event)` the lanes whose draw is below their threshold.
#[inline(always)]
fn dobashi(s: [u64; 4], always: [u64; 3], live: impl Fn(usize) -> u64, below: impl Fn(usize) -> u64) -> [u64; 3] {
    let [a, h, c, f] = s;
    with_draws([h & !a, !a & h & f, c | a], always, live, below)
}

/// The Dobashi rules' random part: from the new `[hum, act, cld]` with no event
/// firing (`[hum ∧ ¬act, ¬act ∧ hum ∧ f_act, cld ∨ act]`), the lanes whose event
/// fires are added to hum and act and removed from cld. A lane in `always` fires
/// whatever its draw; `live(event)` gives the lanes whose draw can fire and
/// `below(event)` those whose draw is below their threshold.
#[inline(always)]
fn with_draws(det: [u64; 3], always: [u64; 3], live: impl Fn(usize) -> u64, below: impl Fn(usize) -> u64) -> [u64; 3] {
    let [keep_h, act_det, cld_det] = det;
    // An event's draws are made only where a live lane could change the result
    // (hum not kept, act not already set, a cloud to remove). Fields are smooth,
    // so this branch goes the same way for long runs of words.
    let fire = |e: usize, care: u64| {
        let hit = if care & live(e) != 0 { below(e) } else { 0 };
        (always[e] | hit) & care
    };
    [
        keep_h | fire(0, !keep_h),
        act_det | fire(1, !act_det),
        cld_det & !fire(2, cld_det),
    ]
}

/// Walks the rows and words of `window`, computing each word's f_act (x and y
/// neighbours in this level, z neighbours through the other levels' frame
/// shifts) and storing what `word(y, wx, index, [act, hum, cld, f_act])`
/// returns as the new `[hum, act, cld]`.
#[inline(always)]
fn step_rows(
    old: &[Level],
    k: usize,
    ctx: &StepContext,
    window: Rect,
    out: &mut Level,
    mut word: impl FnMut(i64, i64, usize, [u64; 4]) -> [u64; 3],
) {
    let lv = &old[k];
    let wpr = lv.wpr;
    let span = Span::new(old, k, ctx, window);
    let (w_lo, w_hi) = (span.words.start, span.words.end);
    let wx0 = span.wx0;
    let zeros = vec![0u64; wpr];
    let row_of = |r: i64| -> &[u64] {
        if r >= 0 && (r as usize) < lv.rows {
            &lv.act[r as usize * wpr..(r as usize + 1) * wpr]
        } else {
            &zeros
        }
    };
    // f_act of the words being computed in the current row.
    let mut f_row = vec![0u64; wpr];
    for r in span.rows.clone() {
        let y = lv.y0 + r as i64;
        let base = r * wpr;
        let act_row = &lv.act[base..base + wpr];
        let (ym2, ym1, yp1, yp2) = (
            row_of(r as i64 - 2),
            row_of(r as i64 - 1),
            row_of(r as i64 + 1),
            row_of(r as i64 + 2),
        );
        for w in w_lo..w_hi {
            let a = act_row[w];
            let prev = if w > 0 { act_row[w - 1] } else { 0 };
            let next = if w + 1 < wpr { act_row[w + 1] } else { 0 };
            // Lane b is cell x0 + 64w + b; its x+d neighbour is lane b+d.
            f_row[w] = (a >> 1)
                | (next << 63)
                | (a >> 2)
                | (next << 62)
                | (a << 1)
                | (prev >> 63)
                | (a << 2)
                | (prev >> 62)
                | ym2[w]
                | ym1[w]
                | yp1[w]
                | yp2[w];
        }
        // z neighbours: the same frame cells read from the other level's grid.
        for (nl, ry, shift) in span.z.iter().flatten() {
            let rr = y + ry - nl.y0;
            if rr >= 0 && rr < nl.rows as i64 {
                let nrow = &nl.act[rr as usize * nl.wpr..(rr as usize + 1) * nl.wpr];
                shift.or_into(&mut f_row[w_lo..w_hi], nrow);
            }
        }
        let (hum, cld) = (&lv.hum[base..base + wpr], &lv.cld[base..base + wpr]);
        let (o_hum, o_act, o_cld) = (
            &mut out.hum[base..base + wpr],
            &mut out.act[base..base + wpr],
            &mut out.cld[base..base + wpr],
        );
        for w in w_lo..w_hi {
            let [h, a, c] = word(y, wx0 + w as i64, base + w, [act_row[w], hum[w], cld[w], f_row[w]]);
            (o_hum[w], o_act[w], o_cld[w]) = (h, a, c);
        }
    }
}

/// The part of level `k` a step computes: its rows, the words of each row, and
/// the z neighbours (+1, −1, −2 levels) with their frame's row offset and a
/// [`Shift`] whose word 0 is the span's first word (`words.start`), the same for
/// every row.
struct Span<'a> {
    rows: Range<usize>,
    words: Range<usize>,
    /// Global word index of the level's word 0.
    wx0: i64,
    z: [Option<(&'a Level, i64, Shift)>; 3],
}

impl<'a> Span<'a> {
    fn new(old: &'a [Level], k: usize, ctx: &StepContext, window: Rect) -> Span<'a> {
        let lv = &old[k];
        let wpr = lv.wpr;
        let r_lo = (window.y0 - lv.y0).clamp(0, lv.rows as i64) as usize;
        let r_hi = (window.y1 - lv.y0).clamp(0, lv.rows as i64) as usize;
        let w_lo = (window.x0 - lv.x0).div_euclid(64).clamp(0, wpr as i64) as usize;
        let w_hi = ((window.x1 - lv.x0 + 63).div_euclid(64)).clamp(0, wpr as i64) as usize;
        let mut z: [Option<(&Level, i64, Shift)>; 3] = [None, None, None];
        if ctx.rules == Rules::Dobashi {
            for (slot, dz) in [1i64, -1, -2].into_iter().enumerate() {
                let kk = k as i64 + dz;
                if kk >= 0 && (kk as usize) < old.len() {
                    let nl = &old[kk as usize];
                    let (ox, oy) = ctx.offsets[k];
                    let (nx, ny) = ctx.offsets[kk as usize];
                    let pos = lv.x0 + ox - nx - nl.x0 + 64 * w_lo as i64;
                    z[slot] = Some((nl, oy - ny, Shift::new(pos, nl.wpr, w_hi - w_lo)));
                }
            }
        }
        Span {
            rows: r_lo..r_hi,
            words: w_lo..w_hi,
            wx0: lv.x0.div_euclid(64),
            z,
        }
    }
}

/// Reading a row of another level at a bit offset: `dst[j]` gets the 64 bits of
/// the source row that start at bit `pos + 64 j` (bits outside it read as 0),
/// with the word part `q`, the bit part `sh`, and the `inner` range of `j`
/// whose two source words are both inside the row, worked out once per level.
struct Shift {
    q: i64,
    sh: u32,
    n: i64,
    inner: Range<usize>,
}

impl Shift {
    fn new(pos: i64, src_len: usize, dst_len: usize) -> Shift {
        let q = pos.div_euclid(64);
        let n = src_len as i64;
        let lo = (-q).clamp(0, dst_len as i64) as usize;
        let hi = (n - 1 - q).clamp(lo as i64, dst_len as i64) as usize;
        Shift {
            q,
            sh: pos.rem_euclid(64) as u32,
            n,
            inner: lo..hi,
        }
    }

    #[inline(always)]
    fn or_into(&self, dst: &mut [u64], src: &[u64]) {
        let (q, sh, n) = (self.q, self.sh, self.n);
        let word = |i: i64| if i >= 0 && i < n { src[i as usize] } else { 0 };
        // The 64 bits from bit `sh` of `a` on into `b`; `(b << 1) << (63 − sh)` is 0
        // for sh = 0, so no branch is needed.
        let join = |a: u64, b: u64| (a >> sh) | ((b << 1) << (63 - sh));
        for (j, d) in dst.iter_mut().enumerate().take(self.inner.start) {
            let i = q + j as i64;
            *d |= join(word(i), word(i + 1));
        }
        if !self.inner.is_empty() {
            let off = (q + self.inner.start as i64) as usize;
            let inner = &mut dst[self.inner.clone()];
            let pairs = src[off..off + inner.len() + 1].windows(2);
            for (d, p) in inner.iter_mut().zip(pairs) {
                *d |= join(p[0], p[1]);
            }
        }
        for (j, d) in dst.iter_mut().enumerate().skip(self.inner.end) {
            let i = q + j as i64;
            *d |= join(word(i), word(i + 1));
        }
    }
}
