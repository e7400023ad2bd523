//! Bounded history: the state at step `m` never depends on more than a fixed
//! number of earlier steps, so a query at t = 1e12 costs what one at t = 1e3 does.
//!
//! Mode `dobashi`: steps are grouped in epochs of `E` steps. The run for epoch
//! `e` starts from an empty grid `W` warm-up steps before the epoch (at
//! `eE − W`) and its probability fields are aligned at the epoch start `eE`.
//! Over the last `F` steps of an epoch the state is cross-faded into the next
//! epoch's run (which started early enough, since `F < W`): density is blended
//! with weight `a = (i + 1)/(F + 1)` on the i-th fade step, cloud bits are taken
//! from the next run where a per-cell hash falls below `a`. Because draws are
//! keyed by (cell, step) and not by run, two runs over the same steps see the
//! same random numbers and coalesce once the empty start is forgotten, so the
//! fade changes few cells (measured in BENCHMARKS.md).
//!
//! Mode `rosa`: each frame is Rosa's fixed number of iterations from an empty
//! grid with the textures of that frame's time (Rosa 2013, §4.2.1).

use crate::world::{Layer, Mode};

/// How to obtain the state at one step: runs and their blend weights.
#[derive(Clone, Debug, PartialEq)]
pub struct StepPlan {
    pub step: i64,
    /// (reference step, start step, weight) of each contributing run; weights sum to 1.
    pub runs: Vec<(i64, i64, f32)>,
}

/// The runs that make up the state at step `m`.
pub fn plan_step(layer: &Layer, m: i64) -> StepPlan {
    match layer.preset.mode {
        Mode::Rosa => StepPlan {
            step: m,
            runs: vec![(m, m - layer.preset.rosa_iterations as i64, 1.0)],
        },
        Mode::Dobashi => {
            let e = layer.epoch;
            let (len, warm, fade) = (e.length as i64, e.warmup as i64, e.fade as i64);
            let epoch = m.div_euclid(len);
            let start = epoch * len;
            let mut runs = vec![(start, start - warm, 1.0f32)];
            let fade_from = start + len - fade;
            if fade > 0 && m >= fade_from {
                let a = (m - fade_from + 1) as f32 / (fade + 1) as f32;
                runs[0].2 = 1.0 - a;
                runs.push((start + len, start + len - warm, a));
            }
            StepPlan { step: m, runs }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Config;

    #[test]
    fn plans_are_bounded_and_weights_sum_to_one() {
        let w = Config::embedded().world("default").unwrap();
        let layer = &w.layers[0];
        for m in [0i64, 5, 15, 16, 1_000_000_000_000, i64::MAX / 4] {
            let p = plan_step(layer, m);
            let total: f32 = p.runs.iter().map(|r| r.2).sum();
            assert!((total - 1.0).abs() < 1e-6);
            for &(_, start, _) in &p.runs {
                assert!(start < m, "a run starts before the step it serves");
                assert!(m - start <= (layer.epoch.length + layer.epoch.warmup) as i64);
            }
        }
    }
}
