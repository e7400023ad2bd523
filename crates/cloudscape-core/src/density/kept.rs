//! What a tile keeps between keyframes, so that its next keyframe costs what changed
//! and not what a first request costs.
//!
//! A keyframe product holds both ends of its span, `t0` and `t1`, and the next
//! keyframe starts at that `t1`. [`KeptDensity`] keeps, per tile and layer:
//!
//! - the density grids of the two latest times it computed, over one region that
//!   holds every halo a tile is shaded with and the span's downwind box (so the
//!   next keyframe's start, and a second quality or sun of the same keyframe, are
//!   cut out of a grid already made);
//! - at level 0, the automaton's runs ([`LiveRuns`]), advanced one step per keyframe
//!   instead of run again from their epoch's start.
//!
//! Every grid it gives equals [`super::density`] of the same region and time, bit
//! for bit: density is a function of (world, layer, cell, t), and the live runs give
//! the cold runs' bits (`automaton::live`). When it cannot (a time before the runs'
//! latest step, a region outside the kept one) it computes cold.

use super::{Grid, Region, SimError, density_staged, exact, prepare};
use crate::automaton::LiveRuns;
use crate::cancel::Cancel;
use crate::stages::{Stage, Stages};
use crate::world::World;

/// Grids kept: the two latest times (a keyframe's two ends).
const KEPT_GRIDS: usize = 2;

/// One grid kept: its time and region (columns of the kept state's level).
#[derive(Clone, Debug)]
struct KeptGrid {
    t: f64,
    region: Region,
    grid: Grid<f32>,
}

/// What one tile of one layer keeps between keyframes (see the module docs).
#[derive(Debug)]
pub struct KeptDensity {
    layer: usize,
    level: u32,
    /// The columns every kept grid covers, and (level 0) the live runs hold.
    region: Region,
    /// Level 0: the automaton's runs over `region`.
    live: Option<LiveRuns>,
    grids: Vec<KeptGrid>,
    /// How its grids were obtained, for the statistics.
    counts: KeptCounts,
}

/// How a [`KeptDensity`]'s grids were obtained.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KeptCounts {
    /// Cut out of a kept grid: no density computed.
    pub reused: u64,
    /// From the live runs (level 0).
    pub live: u64,
    /// Computed from scratch.
    pub cold: u64,
}

impl KeptDensity {
    /// Nothing kept yet for layer `layer` at `level`; every grid it keeps covers
    /// `region` (columns at `level`).
    pub fn new(layer: usize, level: u32, region: Region) -> KeptDensity {
        KeptDensity {
            layer,
            level,
            region,
            live: None,
            grids: Vec::new(),
            counts: KeptCounts::default(),
        }
    }

    /// The columns the kept state covers.
    pub fn region(&self) -> Region {
        self.region
    }

    /// The density of `region` at `t` (as [`super::density_cancellable`]), from what
    /// is kept where it can be. With `keep`, the grid of the whole kept region at `t`
    /// is computed and kept (the region must lie inside it), for later calls.
    pub fn density(
        &mut self,
        world: &World,
        region: Region,
        t: f64,
        keep: bool,
        cancel: &Cancel,
        stages: &mut Stages,
    ) -> Result<Grid<f32>, SimError> {
        if let Some(g) = self.grids.iter().find(|g| g.t == t && contains(g.region, region)) {
            self.counts.reused += 1;
            return Ok(stages.time(Stage::Reused, || cut(&g.grid, g.region, region)));
        }
        let whole = keep && contains(self.region, region);
        let asked = if whole { self.region } else { region };
        let grid = self.compute(world, asked, t, cancel, stages)?;
        if !whole {
            return Ok(grid);
        }
        let out = cut(&grid, self.region, region);
        if self.grids.len() >= KEPT_GRIDS && self.grids.iter().all(|g| g.t > t) {
            // Older than everything kept: not worth a place.
            return Ok(out);
        }
        if self.grids.len() >= KEPT_GRIDS {
            // Keep the latest times: drop the earliest.
            let earliest = (0..self.grids.len())
                .min_by(|&a, &b| self.grids[a].t.total_cmp(&self.grids[b].t))
                .expect("not empty");
            self.grids.remove(earliest);
        }
        self.grids.push(KeptGrid {
            t,
            region: self.region,
            grid,
        });
        Ok(out)
    }

    /// The density of `region` at `t`: from the live runs at level 0 where they can
    /// give it, else cold.
    fn compute(
        &mut self,
        world: &World,
        region: Region,
        t: f64,
        cancel: &Cancel,
        stages: &mut Stages,
    ) -> Result<Grid<f32>, SimError> {
        if self.level > 0 {
            self.counts.cold += 1;
            return density_staged(world, self.layer, self.level, region, t, cancel, stages);
        }
        let mut sim = prepare(world, self.layer, self.level, region, t)?;
        cancel.check()?;
        sim.cancel = cancel.clone();
        let live = self.live.get_or_insert_with(|| LiveRuns::new(self.region));
        let Some(states) = stages.time(Stage::Steps, || exact::kept_states(&sim, live, region, t)) else {
            self.counts.cold += 1;
            return density_staged(world, self.layer, self.level, region, t, cancel, stages);
        };
        self.counts.live += 1;
        let grid = stages.time(Stage::Smoothing, || exact::smooth(&sim, region, states));
        cancel.check()?;
        Ok(grid)
    }

    /// Bytes held: the grids and the live runs.
    pub fn bytes(&self) -> usize {
        let grids: usize = self.grids.iter().map(|g| 4 * g.grid.data.capacity()).sum();
        grids + self.live.as_ref().map_or(0, LiveRuns::bytes)
    }

    /// How its grids were obtained so far.
    pub fn counts(&self) -> KeptCounts {
        self.counts
    }

    /// Automaton steps its live runs advanced.
    pub fn live_steps(&self) -> u64 {
        self.live.as_ref().map_or(0, LiveRuns::steps_run)
    }
}

/// Whether `outer` holds every column of `inner`.
fn contains(outer: Region, inner: Region) -> bool {
    inner.x0 >= outer.x0
        && inner.y0 >= outer.y0
        && inner.x0 + inner.cols as i64 <= outer.x0 + outer.cols as i64
        && inner.y0 + inner.rows as i64 <= outer.y0 + outer.rows as i64
}

/// The columns `inner` of a grid over `outer` (which holds them).
fn cut(grid: &Grid<f32>, outer: Region, inner: Region) -> Grid<f32> {
    let (dx, dy) = ((inner.x0 - outer.x0) as usize, (inner.y0 - outer.y0) as usize);
    let mut out = Grid::new(grid.depth, inner.rows, inner.cols);
    for k in 0..grid.depth {
        for r in 0..inner.rows {
            let from = grid.index(k, r + dy, dx);
            let to = out.index(k, r, 0);
            out.data[to..to + inner.cols].copy_from_slice(&grid.data[from..from + inner.cols]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::density::density;
    use crate::world::Config;

    /// Whatever it gives, at level 0 and a far level, for the whole region and parts
    /// of it, at keyframe ends and at times it passed, equals a cold computation.
    #[test]
    fn kept_grids_equal_cold_ones() {
        let world = Config::embedded().world("default").unwrap();
        for level in [0u32, 2] {
            let region = Region::square(-10, 5, 48);
            let mut kept = KeptDensity::new(1, level, region);
            let inner = Region::square(0, 9, 30);
            let moved = Region::square(-8, 6, 30);
            let dt = world.layers[1].dt * f64::from(1u32 << level);
            for i in 0..20 {
                let (t0, t1) = ((2000 + i) as f64 * dt, (2001 + i) as f64 * dt);
                for (r, t) in [(inner, t0), (moved, t1), (region, t1), (inner, t0)] {
                    let got = kept
                        .density(&world, r, t, true, &Cancel::never(), &mut Stages::default())
                        .unwrap();
                    let want = density(&world, 1, level, r, t).unwrap();
                    assert!(got.data == want.data, "level {level}, {r:?} at {t}");
                }
            }
            // A time before the latest: cold, still equal.
            let back = 1990.0 * dt;
            let got = kept
                .density(&world, inner, back, true, &Cancel::never(), &mut Stages::default())
                .unwrap();
            assert!(got.data == density(&world, 1, level, inner, back).unwrap().data);
            let c = kept.counts();
            assert!(c.reused >= 40, "{c:?}");
            if level == 0 {
                assert!(c.live >= 20 && kept.live_steps() > 0, "{c:?}");
            }
            assert!(kept.bytes() > 0);
        }
    }
}
