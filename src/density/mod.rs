//! From automaton cells to continuous density: smoothing over space, linear
//! interpolation in time between steps, and the cheaper models for far levels.

mod region;

pub use region::{Grid, MAX_CELL_INDEX, Region, SimError, check_time};

use crate::world::World;

/// Which quantity a grid holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldKind {
    /// Continuous density in [0, 1].
    Density,
    /// The automaton's binary cloud bit (0 or 1).
    Cld,
}

/// The density of layer `layer` of `world` over `region` (columns at `level`) at time `t`.
/// Shape `(depth, rows, cols)`, values in [0, 1].
pub fn density(
    world: &World,
    layer: usize,
    level: u32,
    region: Region,
    t: f64,
) -> Result<Grid<f32>, SimError> {
    let _ = (world, layer, level, region, t);
    Err(SimError::OutOfRange(
        "the simulation core is being built".into(),
    ))
}

/// The automaton's `cld` bits over `region` (level-0 cells) at time `t`.
pub fn cloud_cells(
    world: &World,
    layer: usize,
    region: Region,
    t: f64,
) -> Result<Grid<u8>, SimError> {
    let _ = (world, layer, region, t);
    Err(SimError::OutOfRange(
        "the simulation core is being built".into(),
    ))
}
