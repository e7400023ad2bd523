//! Regions of columns and the 3D grids computed over them: what the automaton runs
//! and the density is sampled over (both use it, so it sits below them).

use crate::world::{Layer, Limits, MAX_TIME};

/// A request the simulation refuses, before any work starts.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    /// The world time (seconds) is not finite or outside [0, [`MAX_TIME`]].
    #[error("t must be a finite number of seconds within [0, 1e12], got {0}")]
    BadTime(f64),
    /// The bounding box is malformed or has no area.
    #[error("bbox must be four finite numbers X0,Y0,X1,Y1 with X0 < X1 and Y0 < Y1")]
    BadBbox,
    /// The bounding box covers no cell centre.
    #[error("the region holds no cell centre")]
    EmptyRegion,
    /// The region is wider or taller than the limit allows.
    #[error("the region is {cols}×{rows} columns; the limit is {max} columns per side")]
    RegionTooWide {
        /// Columns asked for.
        cols: u64,
        /// Rows asked for.
        rows: u64,
        /// Columns allowed per side.
        max: u64,
    },
    /// The request would simulate more cells than the limit allows.
    #[error("the request needs {cells} cells; the limit is {max}")]
    TooManyCells {
        /// Cells the request needs.
        cells: u64,
        /// Cells allowed.
        max: u64,
    },
    /// The level is above the deepest the layer has.
    #[error("level {level} is out of range (0..={max})")]
    BadLevel {
        /// Level asked for.
        level: u32,
        /// Deepest level.
        max: u32,
    },
    /// A coordinate is beyond [`MAX_CELL_INDEX`] (the message says which).
    #[error("coordinates out of range: {0}")]
    OutOfRange(String),
    /// The computation was stopped (its [`crate::cancel::Cancel`] fired).
    #[error(transparent)]
    Cancelled(#[from] crate::cancel::Cancelled),
}

/// A rectangle of columns at some level: `cols × rows` columns whose first column
/// is (`x0`, `y0`). A level-`z` column spans `2^z` level-0 cells per side.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Region {
    /// Column x of the first column, at the region's level.
    pub x0: i64,
    /// Column y of the first column, at the region's level.
    pub y0: i64,
    /// Columns along x.
    pub cols: usize,
    /// Columns along y.
    pub rows: usize,
}

/// Level-0 cells (and so level-z columns) are limited to ±2^48 so that any
/// cell index, its metres and the halo arithmetic stay exact in i64 and f64.
pub const MAX_CELL_INDEX: i64 = 1 << 48;

/// The level-0 cell of a layer holding a point: column (east), row (north) and
/// vertical level `k`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Cell {
    /// Column index, east (cell `col` spans `[col, col + 1) · cell_size` metres).
    pub col: i64,
    /// Row index, north.
    pub row: i64,
    /// Vertical level from the layer's base, 0 at the bottom.
    pub k: usize,
}

impl Cell {
    /// The cell of `layer` holding the point (`x`, `y`, `z`) in metres. Altitudes
    /// outside the layer are clamped to its bottom or top level; horizontal
    /// positions beyond ±[`MAX_CELL_INDEX`] cells are out of range.
    pub fn at(layer: &Layer, x: f64, y: f64, z: f64) -> Result<Cell, SimError> {
        let index = |v: f64, name: &str| {
            let c = (v / layer.cell_size).floor();
            if c.abs() >= MAX_CELL_INDEX as f64 {
                return Err(SimError::OutOfRange(format!(
                    "{name} = {v} m is beyond ±{MAX_CELL_INDEX} cells"
                )));
            }
            Ok(c as i64)
        };
        let (col, row) = (index(x, "x")?, index(y, "y")?);
        let k = ((z - layer.base) / layer.cell_height)
            .floor()
            .clamp(0.0, (layer.depth - 1) as f64) as usize;
        Ok(Cell { col, row, k })
    }

    /// The one-column region of the cell.
    pub fn region(&self) -> Region {
        Region::square(self.col, self.row, 1)
    }
}

impl Region {
    /// The square of `side × side` columns whose first column is (`x0`, `y0`): a tile,
    /// a tile with its halo.
    pub const fn square(x0: i64, y0: i64, side: usize) -> Region {
        Region {
            x0,
            y0,
            cols: side,
            rows: side,
        }
    }

    /// The columns at `level` whose centres lie inside `bbox` = [x0, y0, x1, y1]
    /// (world metres, half-open on the high side).
    pub fn from_bbox(layer: &Layer, level: u32, bbox: [f64; 4], limits: &Limits) -> Result<Region, SimError> {
        let [bx0, by0, bx1, by1] = bbox;
        if !(bbox.iter().all(|v| v.is_finite()) && bx0 < bx1 && by0 < by1) {
            return Err(SimError::BadBbox);
        }
        if level > limits.max_level {
            return Err(SimError::BadLevel {
                level,
                max: limits.max_level,
            });
        }
        let w = layer.cell_size * (level as f64).exp2();
        // Column c has its centre at (c + 0.5) * w; it belongs when x0 <= centre < x1.
        let first = |lo: f64| (lo / w - 0.5).ceil();
        let end = |hi: f64| (hi / w - 0.5).ceil();
        let (cx0, cx1, cy0, cy1) = (first(bx0), end(bx1), first(by0), end(by1));
        let lim = (MAX_CELL_INDEX >> level) as f64;
        if [cx0, cx1, cy0, cy1].iter().any(|v| v.abs() > lim) {
            return Err(SimError::OutOfRange(format!(
                "the bbox reaches beyond ±{lim} columns at level {level}"
            )));
        }
        if cx1 <= cx0 || cy1 <= cy0 {
            return Err(SimError::EmptyRegion);
        }
        let cols = (cx1 - cx0) as u64;
        let rows = (cy1 - cy0) as u64;
        if cols > limits.max_columns || rows > limits.max_columns {
            return Err(SimError::RegionTooWide {
                cols,
                rows,
                max: limits.max_columns,
            });
        }
        let cells = cols * rows * layer.depth as u64;
        if cells > limits.max_cells {
            return Err(SimError::TooManyCells {
                cells,
                max: limits.max_cells,
            });
        }
        Ok(Region {
            x0: cx0 as i64,
            y0: cy0 as i64,
            cols: cols as usize,
            rows: rows as usize,
        })
    }

    /// Checks that a region built from other sources (tiles) is in range.
    pub fn check(&self, level: u32, depth: u32, limits: &Limits) -> Result<(), SimError> {
        if level > limits.max_level {
            return Err(SimError::BadLevel {
                level,
                max: limits.max_level,
            });
        }
        let lim = MAX_CELL_INDEX >> level;
        let x1 = self.x0.checked_add(self.cols as i64);
        let y1 = self.y0.checked_add(self.rows as i64);
        match (x1, y1) {
            (Some(x1), Some(y1))
                if self.x0.abs() <= lim && self.y0.abs() <= lim && x1.abs() <= lim && y1.abs() <= lim => {}
            _ => {
                return Err(SimError::OutOfRange(format!("columns beyond ±{lim} at level {level}")));
            }
        }
        if self.cols == 0 || self.rows == 0 {
            return Err(SimError::EmptyRegion);
        }
        let (cols, rows) = (self.cols as u64, self.rows as u64);
        if cols > limits.max_columns || rows > limits.max_columns {
            return Err(SimError::RegionTooWide {
                cols,
                rows,
                max: limits.max_columns,
            });
        }
        let cells = cols * rows * depth as u64;
        if cells > limits.max_cells {
            return Err(SimError::TooManyCells {
                cells,
                max: limits.max_cells,
            });
        }
        Ok(())
    }
}

/// Checks a world time: finite and within [0, 1e12].
pub fn check_time(t: f64) -> Result<f64, SimError> {
    if t.is_finite() && (0.0..=MAX_TIME).contains(&t) {
        Ok(t)
    } else {
        Err(SimError::BadTime(t))
    }
}

/// A 3D grid in C order with shape `(depth, rows, cols)`: row = y (north), col = x (east),
/// depth = altitude level from the layer's base.
#[derive(Clone, Debug, PartialEq)]
pub struct Grid<T> {
    /// Altitude levels.
    pub depth: usize,
    /// Rows (y, north).
    pub rows: usize,
    /// Columns (x, east).
    pub cols: usize,
    /// The values, `depth × rows × cols`, in C order.
    pub data: Vec<T>,
}

impl<T: Copy + Default> Grid<T> {
    /// A grid of the shape filled with `T::default()`.
    pub fn new(depth: usize, rows: usize, cols: usize) -> Grid<T> {
        Grid::filled(depth, rows, cols, T::default())
    }

    /// A grid of the shape with `value` in every cell.
    pub fn filled(depth: usize, rows: usize, cols: usize, value: T) -> Grid<T> {
        Grid {
            depth,
            rows,
            cols,
            data: vec![value; depth * rows * cols],
        }
    }

    /// The index into `data` of (`k`, `row`, `col`).
    #[inline]
    pub fn index(&self, k: usize, row: usize, col: usize) -> usize {
        (k * self.rows + row) * self.cols + col
    }

    /// The value at (`k`, `row`, `col`).
    #[inline]
    pub fn get(&self, k: usize, row: usize, col: usize) -> T {
        self.data[self.index(k, row, col)]
    }
}
