//! From automaton cells to continuous density: smoothing over space, linear
//! interpolation in time between steps, and the cheaper models for far levels.

pub mod exact;
pub mod kept;
mod lod;
pub mod metaballs;
pub mod stats;

pub use crate::region::{Cell, Grid, MAX_CELL_INDEX, Region, SimError, check_time};
pub use stats::{CLOUD_THRESHOLD, ColumnStats, RegionStats, column_stats, region_stats};

use crate::automaton::LayerSim;
use crate::cancel::Cancel;
use crate::stages::{Stage, Stages};
use crate::world::{Limits, World};

/// Which quantity a grid holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldKind {
    /// Continuous density in [0, 1].
    Density,
    /// The automaton's binary cloud bit (0 or 1).
    Cld,
}

/// Backstop limits for callers that pass regions of their own making: nothing
/// below allocates more than this whatever the configuration says.
const HARD_LIMITS: Limits = Limits {
    max_columns: 1 << 15,
    max_cells: 1 << 28,
    max_level: 40,
    max_request_bytes: u64::MAX,
    max_response_bytes: u64::MAX,
    max_path_samples: 1 << 24,
};

/// The density of layer `layer` of `world` over `region` (columns at `level`) at time `t`.
/// Shape `(depth, rows, cols)`, values in [0, 1].
pub fn density(world: &World, layer: usize, level: u32, region: Region, t: f64) -> Result<Grid<f32>, SimError> {
    density_cancellable(world, layer, level, region, t, &Cancel::never())
}

/// [`density`] that stops early once `cancel` fires (then `Err(SimError::Cancelled)`).
pub fn density_cancellable(
    world: &World,
    layer: usize,
    level: u32,
    region: Region,
    t: f64,
    cancel: &Cancel,
) -> Result<Grid<f32>, SimError> {
    density_staged(world, layer, level, region, t, cancel, &mut Stages::default())
}

/// [`density_cancellable`] adding the time of each stage to `stages`.
pub fn density_staged(
    world: &World,
    layer: usize,
    level: u32,
    region: Region,
    t: f64,
    cancel: &Cancel,
    stages: &mut Stages,
) -> Result<Grid<f32>, SimError> {
    let mut sim = prepare(world, layer, level, region, t)?;
    cancel.check()?;
    sim.cancel = cancel.clone();
    let grid = if level == 0 {
        let states = stages.time(Stage::Automaton, || exact::cold_states(&sim, region, t));
        stages.time(Stage::Smoothing, || exact::smooth(&sim, region, states))
    } else {
        stages.time(Stage::FarField, || lod::density(&sim, level, region, t))
    };
    cancel.check()?;
    Ok(grid)
}

/// The automaton's `cld` bits over `region` (level-0 cells) at time `t`.
pub fn cloud_cells(world: &World, layer: usize, region: Region, t: f64) -> Result<Grid<u8>, SimError> {
    let sim = prepare(world, layer, 0, region, t)?;
    Ok(exact::cloud_cells(&sim, region, t))
}

/// Automaton cell-steps that [`density`] of `region` will run (0 at levels above 0,
/// which use the mean-field model and run no automaton). Checked like `density`.
pub fn cell_steps(world: &World, layer: usize, level: u32, region: Region, t: f64) -> Result<u64, SimError> {
    let sim = prepare(world, layer, level, region, t)?;
    Ok(if level == 0 {
        exact::cell_steps(&sim, region, t)
    } else {
        0
    })
}

fn prepare(world: &World, layer: usize, level: u32, region: Region, t: f64) -> Result<LayerSim, SimError> {
    check_time(t)?;
    let l = world
        .layers
        .get(layer)
        .ok_or_else(|| SimError::OutOfRange(format!("no layer {layer}")))?;
    region.check(level, l.depth, &HARD_LIMITS)?;
    Ok(LayerSim::new(world, layer))
}
