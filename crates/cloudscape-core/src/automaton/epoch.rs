//! Bounded history: the state at step `m` never depends on more than a fixed
//! number of earlier steps, so a query at t = 1e12 costs what one at t = 1e3 does.
//!
//! Mode `dobashi`: steps are grouped in epochs of `E` steps. Run `j` starts from
//! an empty grid at `(j−1)E − W` (`W` warm-up steps before it is first used) with
//! its probability fields aligned at step `jE`. Every cell switches from run `e`
//! to run `e+1` once per epoch, at its own step `eE + φ` where `φ` in [0, F) is a
//! per-cell hash (`F` = the `fade` setting; `φ = 0` for every cell when F = 0).
//! So about 1/F of the cells switch on each of the first F steps of an epoch,
//! and the epoch boundary itself is a step like any other: no frame pops.
//! Because draws are keyed by (cell, step) and not by run, two runs over the
//! same steps see the same random numbers and converge once the empty start is
//! forgotten, so a switch rarely flips a cell (measured in BENCHMARKS.md).
//!
//! Mode `rosa`: each frame is Rosa's fixed number of iterations from an empty
//! grid with the textures of that frame's time (Rosa 2013, §4.2.1).

use crate::world::{Layer, Mode};

/// One run: fields aligned at `reference`, empty grid at `start`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct RunId {
    /// Step the run's probability fields are aligned at (its epoch's reference).
    pub reference: i64,
    /// Step at which the run starts from an empty grid.
    pub start: i64,
}

/// How to obtain the state at one step.
#[derive(Clone, Debug, PartialEq)]
pub struct StepPlan {
    /// The step whose state this plan gives.
    pub step: i64,
    /// The old run and, while cells are still switching, the new one.
    pub runs: Vec<RunId>,
    /// With two runs: a cell whose switch phase φ (in [0, fade)) is <= `phase`
    /// has switched to `runs[1]`.
    pub phase: i64,
    /// Steps a switch from the old run to the new one takes (the range of φ).
    pub fade: u32,
}

impl StepPlan {
    /// Index into `runs` of the run that supplies a cell with switch hash `h` (0..65536).
    #[inline]
    pub fn pick(&self, h: u32) -> usize {
        if self.runs.len() < 2 {
            return 0;
        }
        let phi = ((h as u64 * self.fade as u64) >> 16) as i64;
        usize::from(phi <= self.phase)
    }
}

/// The runs that make up the state at step `m`.
pub fn plan_step(layer: &Layer, m: i64) -> StepPlan {
    match layer.preset.mode {
        Mode::Rosa => {
            let run = RunId {
                reference: m,
                start: m - layer.preset.rosa_iterations as i64,
            };
            StepPlan {
                step: m,
                runs: vec![run],
                phase: 0,
                fade: 0,
            }
        }
        Mode::Dobashi => {
            let ep = layer.epoch;
            let (len, warm, fade) = (ep.length as i64, ep.warmup as i64, ep.fade as i64);
            let e = m.div_euclid(len);
            let p = m - e * len;
            let run = |j: i64| RunId {
                reference: j * len,
                start: (j - 1) * len - warm,
            };
            if p + 1 >= fade {
                // Every phase is <= p: all cells are on the new run.
                StepPlan {
                    step: m,
                    runs: vec![run(e + 1)],
                    phase: p,
                    fade: ep.fade,
                }
            } else {
                StepPlan {
                    step: m,
                    runs: vec![run(e), run(e + 1)],
                    phase: p,
                    fade: ep.fade,
                }
            }
        }
    }
}

/// The first and last step whose plan ([`plan_step`]) names run `id`: Dobashi's run
/// `j` serves epoch `j − 1` as the new run and the first `fade − 1` steps of epoch
/// `j` as the old one; a Rosa run serves its own frame.
pub fn served_steps(layer: &Layer, id: RunId) -> (i64, i64) {
    match layer.preset.mode {
        Mode::Rosa => (id.reference, id.reference),
        Mode::Dobashi => {
            let len = layer.epoch.length as i64;
            let fade = layer.epoch.fade as i64;
            (id.reference - len, id.reference + (fade - 1).max(0) - 1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Config;

    #[test]
    fn plans_are_bounded() {
        let w = Config::embedded().world("default").unwrap();
        let layer = &w.layers[0];
        let ep = layer.epoch;
        for m in [0i64, 5, 15, 16, 1_000_000_000_000, i64::MAX / 4] {
            let p = plan_step(layer, m);
            for r in &p.runs {
                assert!(r.start < m, "a run starts before the step it serves");
                assert!(m - r.start <= (ep.length + ep.fade + ep.warmup) as i64);
            }
        }
    }

    #[test]
    fn each_cell_switches_once_per_epoch() {
        let w = Config::embedded().world("default").unwrap();
        let layer = &w.layers[0];
        let len = layer.epoch.length as i64;
        for h in [0u32, 1, 20000, 40000, 65535] {
            let runs: Vec<RunId> = (2 * len + 1..=5 * len)
                .map(|m| {
                    let p = plan_step(layer, m);
                    p.runs[p.pick(h)]
                })
                .collect();
            let switches = runs.windows(2).filter(|w| w[0] != w[1]).count();
            assert_eq!(switches, 3, "hash {h}");
        }
    }

    #[test]
    fn served_steps_are_the_plans_that_name_a_run() {
        let config = Config::embedded();
        for world in ["default", "overcast"] {
            let w = config.world(world).unwrap();
            for layer in &w.layers {
                let mut seen: std::collections::BTreeMap<RunId, (i64, i64)> = Default::default();
                for m in 100..300 {
                    for r in plan_step(layer, m).runs {
                        let e = seen.entry(r).or_insert((m, m));
                        e.1 = m;
                    }
                }
                // Runs seen whole (neither cut by the range's start nor its end).
                for (id, steps) in seen.iter().filter(|(_, s)| s.0 > 100 && s.1 < 299) {
                    assert_eq!(served_steps(layer, *id), *steps, "{world} {} {id:?}", layer.name);
                }
                assert!(seen.len() > 4, "{}", layer.name);
            }
        }
    }
}
