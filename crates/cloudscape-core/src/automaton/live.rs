//! Runs kept alive between keyframes: the automaton state of one region, advanced a
//! step at a time instead of run again from its epoch's start for every keyframe.
//!
//! A cold computation of the state at step `m` runs each run its epoch plan names
//! from its empty start (up to `warm-up + epoch + fade` steps back) over the
//! dependency cone of the cells asked for at `m`. A tile watched over time asks for
//! the same region at `m`, `m + 1`, `m + 2`, …: [`LiveRuns`] starts each run once, from
//! its empty grid, over the cone of the region at *every* step the run serves (the
//! windows of the region at those steps, widened backwards by the reach of each
//! step), keeps its grids and drives, and advances it by one step per keyframe.
//!
//! The bits are those of a cold run: the cone of a live run holds the cone of any
//! cold computation of the region at a step it serves (both are built by
//! [`LayerSim::cone_of`] from windows the live ones contain, and the recursion is
//! monotone), every cell inside a cone is computed from cells inside it, and draws
//! and drives are functions of (cell, step) alone, not of the grid that holds them.
//! `density::exact`'s tests and `tests/incremental.rs` compare the two bit for bit.
//!
//! Steps only go forward: a step before the kept state's is not available (the
//! caller computes it cold). A cancelled advance leaves meaningless bits, so the
//! runs are dropped and the next call starts again.

use super::epoch::{RunId, StepPlan, plan_step, served_steps};
use super::kernel::{Drives, Level, Rect};
use super::run::LayerSim;
use crate::region::Region;

/// One run advanced step by step.
#[derive(Debug)]
struct LiveRun {
    id: RunId,
    /// The cells of each level needed at each step, index `step − id.start`, up to
    /// the last step the run serves.
    need: Vec<Vec<Rect>>,
    /// The step `levels` holds.
    step: i64,
    levels: Vec<Level>,
    /// Scratch grids of the same geometry: the next step is written here.
    next: Vec<Level>,
    drives: Vec<Drives>,
}

impl LiveRun {
    /// Run `id` at its empty start, over the cone of `region` at every step it serves.
    fn start(sim: &LayerSim, region: Region, id: RunId) -> LiveRun {
        let (first, last) = served_steps(&sim.fields.layer, id);
        let targets: Vec<(i64, Vec<Rect>)> = (first.max(id.start)..=last)
            .map(|m| (m, targets(sim, region, m)))
            .collect();
        let need = sim.cone_of(id.start, last, |n| {
            targets.iter().find(|(m, _)| *m == n).map(|(_, w)| w.as_slice())
        });
        let levels: Vec<Level> = need[0].iter().map(|r| Level::covering(*r)).collect();
        let drives = sim.drives(&levels, id.reference);
        LiveRun {
            id,
            need,
            step: id.start,
            next: levels.clone(),
            levels,
            drives,
        }
    }

    /// The last step this run can give.
    fn last(&self) -> i64 {
        self.id.start + self.need.len() as i64 - 1
    }

    /// Advances to step `to` (at most the run's last), then drops what the steps left
    /// can no longer read.
    fn advance(&mut self, sim: &LayerSim, to: i64) {
        debug_assert!(to <= self.last());
        while self.step < to && !sim.cancel.is_fired() {
            let s = (self.step - self.id.start) as usize;
            sim.step_all(&self.levels, &mut self.next, &self.drives, self.step, &self.need[s + 1]);
            std::mem::swap(&mut self.levels, &mut self.next);
            self.step += 1;
        }
        self.crop();
    }

    /// Cuts each level whose grid is well over the words covering its cone at the
    /// current step down to those words: the cone only shrinks from step to step
    /// (each step's cells are read only from within the previous step's), so nothing
    /// later reads the cut cells. Their drives go with them.
    fn crop(&mut self) {
        let s = (self.step - self.id.start) as usize;
        for k in 0..self.levels.len() {
            let lv = &self.levels[k];
            let want = self.need[s][k];
            if want.is_empty() {
                continue;
            }
            let covering =
                |r: Rect| ((r.x1 + 63).div_euclid(64) - r.x0.div_euclid(64)) as usize * (r.y1 - r.y0) as usize;
            if 5 * covering(want) >= 4 * lv.wpr * lv.rows {
                continue;
            }
            let (cut, rows, words) = lv.cropped(want);
            self.drives[k] = self.drives[k].cropped(lv.wpr, rows, words);
            self.next[k] = Level::covering(want);
            self.levels[k] = cut;
        }
    }

    /// Bytes held: both sets of grids and the drives.
    fn bytes(&self) -> usize {
        let grids: usize = self.levels.iter().map(|l| 3 * 8 * l.hum.len()).sum();
        2 * grids + self.drives.iter().map(Drives::bytes).sum::<usize>()
    }
}

/// The windows of each level's frame that must be exact at step `m` for `region`
/// (level-0 cells) to be sampled at any time within a step of `m`: the windows
/// [`crate::density::exact`] samples at steps `m − 1`, `m` and `m + 1` (the integer
/// part of the wind displacement lies between theirs at any time in between).
pub(crate) fn targets(sim: &LayerSim, region: Region, m: i64) -> Vec<Rect> {
    (0..sim.depth() as u32)
        .map(|k| {
            [m - 1, m, m + 1]
                .iter()
                .map(|&n| sample_window(region, sim.frames.displacement(k, n, 0.0)))
                .fold(Rect::default(), |a, b| a.hull(&b))
        })
        .collect()
}

/// The frame window `density::exact` samples for `region` at a displacement: the
/// region's cells moved into the frame, plus the reach of the tent and the bilinear
/// step.
pub(crate) fn sample_window(
    region: Region,
    (cx, cy): (crate::fields::noise::Coord, crate::fields::noise::Coord),
) -> Rect {
    Rect {
        x0: region.x0 - cx.int - 2,
        x1: region.x0 + region.cols as i64 - cx.int + 2,
        y0: region.y0 - cy.int - 2,
        y1: region.y0 + region.rows as i64 - cy.int + 2,
    }
}

/// The automaton state of one region (level-0 cells) kept between keyframes.
#[derive(Debug)]
pub struct LiveRuns {
    region: Region,
    /// The runs started so far and not yet past their last step, by run.
    runs: Vec<LiveRun>,
    /// Steps the live runs advanced (statistics: the work kept state saved is the
    /// cold runs' steps less these).
    steps_run: u64,
    /// The latest step given: steps only go forward.
    latest: Option<i64>,
}

impl LiveRuns {
    /// No run yet, for `region`.
    pub fn new(region: Region) -> LiveRuns {
        LiveRuns {
            region,
            runs: Vec::new(),
            steps_run: 0,
            latest: None,
        }
    }

    /// The region whose state is kept.
    pub fn region(&self) -> Region {
        self.region
    }

    /// Whether every window (one per level, at step `m`) lies within what the runs
    /// keep exact at `m`.
    pub fn covers(&self, sim: &LayerSim, m: i64, windows: &[Rect]) -> bool {
        let t = targets(sim, self.region, m);
        windows.len() == t.len() && windows.iter().zip(&t).all(|(w, t)| w.is_empty() || t.hull(w) == *t)
    }

    /// Whether step `m` can still be given: it is not before the latest step given.
    pub fn can_give(&self, m: i64) -> bool {
        self.latest.is_none_or(|l| m >= l)
    }

    /// The plan of step `m` and the grids of each run it names at `m`: runs not kept
    /// yet start from their empty grid, kept ones advance, runs past their last step
    /// are dropped. `None` when `m` is before the latest step given, or when `sim`
    /// was cancelled (then every run is dropped: their bits mean nothing).
    pub fn at(&mut self, sim: &LayerSim, m: i64) -> Option<(StepPlan, Vec<&[Level]>)> {
        if !self.can_give(m) {
            return None;
        }
        self.latest = Some(m);
        let plan = plan_step(&sim.fields.layer, m);
        self.runs.retain(|r| r.last() >= m);
        for id in &plan.runs {
            if !self.runs.iter().any(|r| r.id == *id) {
                self.runs.push(LiveRun::start(sim, self.region, *id));
            }
        }
        for r in self.runs.iter_mut().filter(|r| plan.runs.contains(&r.id)) {
            self.steps_run += (m - r.step) as u64;
            r.advance(sim, m);
        }
        if sim.cancel.is_fired() {
            self.runs.clear();
            self.latest = None;
            return None;
        }
        let levels = plan
            .runs
            .iter()
            .map(|id| {
                let run = self.runs.iter().find(|r| r.id == *id).expect("started above");
                run.levels.as_slice()
            })
            .collect();
        Some((plan, levels))
    }

    /// Bytes the kept runs hold.
    pub fn bytes(&self) -> usize {
        self.runs.iter().map(LiveRun::bytes).sum()
    }

    /// Automaton steps the kept runs have advanced in all.
    pub fn steps_run(&self) -> u64 {
        self.steps_run
    }
}
