//! Wind frames. Each vertical level of a layer lives in its own frame that drifts
//! with the wind at that level's height: frame-k cell `i` at step `n` is world
//! cell `i + O_k(n)` with `O_k(n) = floor(v_k · n)` and `v_k` the wind in cells per
//! step. Cells never move within their frame; wind shear shows up as a relative
//! shift between neighbouring levels that changes with `n`. The probability
//! fields are evaluated in the reference frame (the base wind), so weather
//! patterns move with the wind. All offsets are exact integer + fraction
//! arithmetic, so they stay exact at t = 1e12.

use crate::fields::noise::Coord;
use crate::world::Layer;

/// The wind frames of one layer.
#[derive(Clone, Debug)]
pub struct Frames {
    /// Cells per step, per level: (x, y).
    level_velocity: Vec<[f64; 2]>,
    /// Cells per step of the reference frame (the base wind).
    reference_velocity: [f64; 2],
}

impl Frames {
    /// The frames of `layer`: each level's wind in cells per step, from its wind in m/s, `dt` and cell size.
    pub fn new(layer: &Layer) -> Frames {
        let to_cells = |w: [f64; 2]| [w[0] * layer.dt / layer.cell_size, w[1] * layer.dt / layer.cell_size];
        Frames {
            level_velocity: (0..layer.depth).map(|k| to_cells(layer.wind_at_level(k))).collect(),
            reference_velocity: to_cells(layer.wind),
        }
    }

    /// Integer offset of level `k`'s frame at step `n`.
    #[inline]
    pub fn offset(&self, k: u32, n: i64) -> (i64, i64) {
        let v = self.level_velocity[k as usize];
        (Coord::scaled(n, 0.0, v[0]).int, Coord::scaled(n, 0.0, v[1]).int)
    }

    /// Offset of the reference frame at step `n`.
    #[inline]
    pub fn reference_offset(&self, n: i64) -> (i64, i64) {
        let v = self.reference_velocity;
        (Coord::scaled(n, 0.0, v[0]).int, Coord::scaled(n, 0.0, v[1]).int)
    }

    /// Continuous displacement of level `k` at time `n + f` steps, in cells.
    #[inline]
    pub fn displacement(&self, k: u32, n: i64, f: f64) -> (Coord, Coord) {
        let v = self.level_velocity[k as usize];
        (Coord::scaled(n, f, v[0]), Coord::scaled(n, f, v[1]))
    }
}
