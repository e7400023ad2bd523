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

use super::random::{Backend, StepKeys, WordDrive, below_portable};

/// A half-open rectangle of frame cells.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Rect {
    pub x0: i64,
    pub x1: i64,
    pub y0: i64,
    pub y1: i64,
}

impl Rect {
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
    pub y0: i64,
    pub wpr: usize,
    pub rows: usize,
    pub hum: Vec<u64>,
    pub act: Vec<u64>,
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
    Stochastic(Vec<WordDrive>),
    /// Rosa: per word, `tex_hum > p_hum`, `tex_act > p_act`, and `tex_cld > p_ext` (keep).
    Threshold {
        hum: Vec<u64>,
        act: Vec<u64>,
        keep: Vec<u64>,
    },
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
    step_level_on(Backend::detect(), old, k, drives, ctx, window, out)
}

/// [`step_level`] with the draws made by `backend` (one of [`Backend::available`]).
pub fn step_level_on(
    backend: Backend,
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
    let wpr = lv.wpr;
    let r_lo = (window.y0 - lv.y0).clamp(0, lv.rows as i64) as usize;
    let r_hi = (window.y1 - lv.y0).clamp(0, lv.rows as i64) as usize;
    let w_lo = (window.x0 - lv.x0).div_euclid(64).clamp(0, wpr as i64) as usize;
    let w_hi = ((window.x1 - lv.x0 + 63).div_euclid(64)).clamp(0, wpr as i64) as usize;
    // z neighbours: (+1, −1, −2) levels, each with the relative shift of its frame.
    let mut zn: [Option<(&Level, i64, i64)>; 3] = [None, None, None];
    if ctx.rules == Rules::Dobashi {
        for (slot, dz) in [1i64, -1, -2].into_iter().enumerate() {
            let kk = k as i64 + dz;
            if kk >= 0 && (kk as usize) < old.len() {
                let (ox, oy) = ctx.offsets[k];
                let (nx, ny) = ctx.offsets[kk as usize];
                zn[slot] = Some((&old[kk as usize], ox - nx, oy - ny));
            }
        }
    }
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
    let keys = StepKeys::new(ctx.stream, k as u32, ctx.n);
    let draws = StepDraws::new(backend, &keys);
    for r in r_lo..r_hi {
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
        // z neighbours: the same frame cells read from the other level's grid, whose
        // words are offset by a whole-word part `q` and a bit part `sh`.
        for (nl, rx, ry) in zn.iter().flatten() {
            let rr = y + ry - nl.y0;
            if rr < 0 || rr >= nl.rows as i64 {
                continue;
            }
            let nrow = &nl.act[rr as usize * nl.wpr..(rr as usize + 1) * nl.wpr];
            let pos = lv.x0 + rx - nl.x0;
            or_shifted(&mut f_row[w_lo..w_hi], nrow, pos + 64 * w_lo as i64);
        }
        match drives {
            Drives::Stochastic(words) => {
                let row = Row {
                    y,
                    wx0: lv.x0.div_euclid(64),
                    act: act_row,
                    hum: &lv.hum[base..base + wpr],
                    cld: &lv.cld[base..base + wpr],
                    f: &f_row,
                    drives: &words[base..base + wpr],
                };
                let out = RowOut {
                    hum: &mut out.hum[base..base + wpr],
                    act: &mut out.act[base..base + wpr],
                    cld: &mut out.cld[base..base + wpr],
                };
                draws.row(&row, out, w_lo..w_hi);
            }
            Drives::Threshold { hum, act, keep } => {
                for w in w_lo..w_hi {
                    let i = base + w;
                    let (a, h, c, f) = (act_row[w], lv.hum[i], lv.cld[i], f_row[w]);
                    out.hum[i] = (h & !a) | hum[i];
                    out.act[i] = (!a & h & f) | act[i];
                    out.cld[i] = (c | a) & keep[i];
                }
            }
        }
    }
}

/// One row of a Dobashi step: the inputs, indexed by word.
struct Row<'a> {
    y: i64,
    /// Global word index of word 0.
    wx0: i64,
    act: &'a [u64],
    hum: &'a [u64],
    cld: &'a [u64],
    f: &'a [u64],
    drives: &'a [WordDrive],
}

struct RowOut<'a> {
    hum: &'a mut [u64],
    act: &'a mut [u64],
    cld: &'a mut [u64],
}

/// The draws of one step in the form a backend uses.
enum StepDraws<'a> {
    #[cfg(target_arch = "x86_64")]
    Avx512(super::random::avx512::Keys),
    Portable(&'a StepKeys),
}

impl<'a> StepDraws<'a> {
    fn new(backend: Backend, keys: &'a StepKeys) -> StepDraws<'a> {
        match backend {
            #[cfg(target_arch = "x86_64")]
            Backend::Avx512 => {
                assert!(Backend::available().contains(&Backend::Avx512), "AVX-512 draws on a CPU without them");
                // SAFETY: the CPU has AVX-512 F, BW and VAES (asserted above).
                StepDraws::Avx512(unsafe { super::random::avx512::keys(keys) })
            }
            _ => StepDraws::Portable(keys),
        }
    }

    /// Words `ws` of a Dobashi row.
    fn row(&self, row: &Row, out: RowOut, ws: Range<usize>) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: made only after the CPU's features were checked (`new`).
            StepDraws::Avx512(keys) => unsafe { stochastic_row_avx512(keys, row, out, ws) },
            StepDraws::Portable(keys) => rules_row(row, out, ws, |d, e, wx| {
                below_portable(keys, row.y, wx, e, &d.t[e], d.shift[e])
            }),
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,vaes")]
unsafe fn stochastic_row_avx512(keys: &super::random::avx512::Keys, row: &Row, out: RowOut, ws: Range<usize>) {
    use super::random::avx512;
    // SAFETY (both calls): the caller checked the CPU's features.
    let y = unsafe { avx512::row(row.y) };
    rules_row(row, out, ws, |d, e, wx| unsafe { avx512::below(keys, y, e, wx, &d.t[e], d.shift[e]) })
}

/// The Dobashi rules over words `ws`, with `below(drive, event, wx)` the lanes
/// whose draw is below their threshold. A lane in `always` fires whatever its draw.
#[inline(always)]
fn rules_row(row: &Row, out: RowOut, ws: Range<usize>, below: impl Fn(&WordDrive, usize, i64) -> u64) {
    // Slices cut to the range's end, so the indexing below needs no bounds checks.
    let n = ws.end;
    let (act, hum, cld, f, drives) = (&row.act[..n], &row.hum[..n], &row.cld[..n], &row.f[..n], &row.drives[..n]);
    let (out_hum, out_act, out_cld) = (&mut out.hum[..n], &mut out.act[..n], &mut out.cld[..n]);
    for w in ws {
        let (a, h, c, d) = (act[w], hum[w], cld[w], &drives[w]);
        let wx = row.wx0 + w as i64;
        let fire = |e: usize| d.always[e] | below(d, e, wx);
        // Where a draw cannot change the result (hum kept, act already set, no
        // cloud to remove) it is made anyway: no branches.
        out_hum[w] = (h & !a) | fire(0);
        out_act[w] = (!a & h & f[w]) | fire(1);
        out_cld[w] = (c | a) & !fire(2);
    }
}

/// ORs into `dst[j]` the 64 bits of `src` that start at bit `pos + 64 j`
/// (bits outside `src` read as 0).
fn or_shifted(dst: &mut [u64], src: &[u64], pos: i64) {
    let q = pos.div_euclid(64);
    let sh = pos.rem_euclid(64) as u32;
    let n = src.len() as i64;
    let word = |i: i64| if i >= 0 && i < n { src[i as usize] } else { 0 };
    // Words j whose two source words q + j and q + j + 1 are both inside `src`.
    let inner_lo = (-q).clamp(0, dst.len() as i64) as usize;
    let inner_hi = (n - 1 - q).clamp(inner_lo as i64, dst.len() as i64) as usize;
    let join = |a: u64, b: u64| ((((b as u128) << 64) | a as u128) >> sh) as u64;
    for (j, d) in dst.iter_mut().enumerate().take(inner_lo) {
        let i = q + j as i64;
        *d |= join(word(i), word(i + 1));
    }
    let off = (q + inner_lo as i64).max(0) as usize;
    for (j, d) in dst[inner_lo..inner_hi].iter_mut().enumerate() {
        *d |= join(src[off + j], src[off + j + 1]);
    }
    for (j, d) in dst.iter_mut().enumerate().skip(inner_hi) {
        let i = q + j as i64;
        *d |= join(word(i), word(i + 1));
    }
}
