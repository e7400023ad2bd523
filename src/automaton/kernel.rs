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

use super::random::{Draw, bernoulli, row_key};

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
    /// Dobashi: per word, bit planes of the three probabilities (see `random`),
    /// and per word the lanes of each (hum, act, ext) with a non-zero probability.
    Stochastic {
        hum: Vec<[u64; 17]>,
        act: Vec<[u64; 17]>,
        ext: Vec<[u64; 17]>,
        live: Vec<[u64; 3]>,
    },
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
            let q = pos.div_euclid(64);
            let sh = pos.rem_euclid(64) as u32;
            let word = |i: i64| {
                if i >= 0 && (i as usize) < nrow.len() {
                    nrow[i as usize]
                } else {
                    0
                }
            };
            for (w, f) in f_row.iter_mut().enumerate().take(w_hi).skip(w_lo) {
                let qi = q + w as i64;
                *f |= if sh == 0 {
                    word(qi)
                } else {
                    (word(qi) >> sh) | (word(qi + 1) << (64 - sh))
                };
            }
        }
        let keys = match ctx.rules {
            Rules::Dobashi => {
                [Draw::Humidity, Draw::Activation, Draw::Extinction].map(|d| row_key(ctx.stream, d, k as u32, y, ctx.n))
            }
            Rules::Rosa => [0; 3],
        };
        for w in w_lo..w_hi {
            let a = act_row[w];
            let f = f_row[w];
            let x = lv.x0 + 64 * w as i64;
            let h = lv.hum[base + w];
            let c = lv.cld[base + w];
            let keep_h = h & !a;
            let act_det = !a & h & f;
            let cld_det = c | a;
            let i = base + w;
            let (nh, na, nc) = match drives {
                Drives::Stochastic { hum, act, ext, live } => {
                    let live = live[i];
                    let wx = x.div_euclid(64);
                    // Each draw is decided only where it can fire and change the result.
                    let bh = bernoulli(&hum[i], keys[0], wx, live[0] & !keep_h);
                    let ba = bernoulli(&act[i], keys[1], wx, live[1] & !act_det);
                    let be = bernoulli(&ext[i], keys[2], wx, live[2] & cld_det);
                    (keep_h | bh, act_det | ba, cld_det & !be)
                }
                Drives::Threshold { hum, act, keep } => (keep_h | hum[i], act_det | act[i], cld_det & keep[i]),
            };
            out.hum[i] = nh;
            out.act[i] = na;
            out.cld[i] = nc;
        }
    }
}
