//! The naive reference: one byte per cell, the rules written out cell by cell,
//! the same counter-based draws. It exists to check the packed kernel bit for bit.

use super::kernel::Rules;
use super::random::{StepKeys, fires};
use crate::world::Event;

/// One level, one byte per cell, over `w × h` frame cells from (`x0`, `y0`).
#[derive(Clone, Debug, PartialEq)]
pub struct NaiveLevel {
    /// Frame x of column 0.
    pub x0: i64,
    /// Frame y of row 0.
    pub y0: i64,
    /// Columns.
    pub w: usize,
    /// Rows.
    pub h: usize,
    /// Humidity per cell (0 or 1), row-major.
    pub hum: Vec<u8>,
    /// Activation per cell (0 or 1), row-major.
    pub act: Vec<u8>,
    /// Cloud per cell (0 or 1), row-major.
    pub cld: Vec<u8>,
}

/// Per-cell drives: thresholds q (0..=65536) for Dobashi, or Rosa's booleans.
#[derive(Clone, Debug)]
pub enum NaiveDrives {
    /// Dobashi: each event's threshold per cell.
    Stochastic {
        /// Humidity thresholds.
        hum: Vec<u32>,
        /// Activation thresholds.
        act: Vec<u32>,
        /// Extinction thresholds.
        ext: Vec<u32>,
    },
    /// Rosa: each rule's texture comparison per cell (0 or 1).
    Threshold {
        /// `tex_hum > p_hum`.
        hum: Vec<u8>,
        /// `tex_act > p_act`.
        act: Vec<u8>,
        /// `tex_cld > p_ext` (the cloud is kept).
        keep: Vec<u8>,
    },
}

impl NaiveLevel {
    fn idx(&self, x: i64, y: i64) -> Option<usize> {
        let (dx, dy) = (x - self.x0, y - self.y0);
        if dx < 0 || dy < 0 || dx >= self.w as i64 || dy >= self.h as i64 {
            None
        } else {
            Some(dy as usize * self.w + dx as usize)
        }
    }

    fn act_at(&self, x: i64, y: i64) -> bool {
        self.idx(x, y).is_some_and(|i| self.act[i] != 0)
    }
}

/// One step of every level; `offsets[k]` is level k's frame offset at step `n`.
pub fn step(
    levels: &[NaiveLevel],
    drives: &[NaiveDrives],
    rules: Rules,
    stream: u64,
    n: i64,
    offsets: &[(i64, i64)],
) -> Vec<NaiveLevel> {
    let mut out = levels.to_vec();
    for (k, lv) in levels.iter().enumerate() {
        for r in 0..lv.h {
            for c in 0..lv.w {
                let (x, y) = (lv.x0 + c as i64, lv.y0 + r as i64);
                let i = r * lv.w + c;
                let mut f = false;
                for (dx, dy) in [(1, 0), (-1, 0), (2, 0), (-2, 0), (0, 1), (0, -1), (0, 2), (0, -2)] {
                    f |= lv.act_at(x + dx, y + dy);
                }
                if rules == Rules::Dobashi {
                    for dz in [1i64, -1, -2] {
                        let kk = k as i64 + dz;
                        if kk < 0 || kk as usize >= levels.len() {
                            continue;
                        }
                        // Frame k cell (x, y) is world (x + O_k); in frame kk that is x + O_k − O_kk.
                        let (ox, oy) = offsets[k];
                        let (nx, ny) = offsets[kk as usize];
                        f |= levels[kk as usize].act_at(x + ox - nx, y + oy - ny);
                    }
                }
                let (hum, act, cld) = (lv.hum[i] != 0, lv.act[i] != 0, lv.cld[i] != 0);
                let (bh, ba, keep) = match &drives[k] {
                    NaiveDrives::Stochastic {
                        hum: qh,
                        act: qa,
                        ext: qe,
                    } => {
                        let keys = StepKeys::new(stream, k as u32, n);
                        let (wx, bit) = (x.div_euclid(64), x.rem_euclid(64) as u32);
                        let fire = |d: Event, q: u32| fires(&keys, y, wx, d, bit, q);
                        (
                            fire(Event::Humidity, qh[i]),
                            fire(Event::Activation, qa[i]),
                            !fire(Event::Extinction, qe[i]),
                        )
                    }
                    NaiveDrives::Threshold {
                        hum: th,
                        act: ta,
                        keep: tk,
                    } => (th[i] != 0, ta[i] != 0, tk[i] != 0),
                };
                out[k].hum[i] = ((hum && !act) || bh) as u8;
                out[k].act[i] = ((!act && hum && f) || ba) as u8;
                out[k].cld[i] = ((cld || act) && keep) as u8;
            }
        }
    }
    out
}
