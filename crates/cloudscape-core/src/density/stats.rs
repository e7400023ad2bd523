//! Region statistics over a density grid: what `/region` and `/series` answer.
//!
//! Definitions (the HTTP tests recompute them from density tiles):
//! - a cell is *cloudy* when its density is at least [`CLOUD_THRESHOLD`];
//! - a column is *covered* when any of its cells is cloudy; `coverage` is the
//!   fraction of the region's columns that are covered;
//! - `mean_density` / `max_density` are over all cells of the region;
//! - `cloud_base` / `cloud_top` are the altitudes (metres) of the bottom of the lowest
//!   and the top of the highest cloudy cell, absent when nothing is cloudy;
//! - `clusters` counts 4-connected groups of covered columns.
//!
//! [`column_stats`] states the same definitions for one column (what the EDR
//! coverages of the server answer per column): a region's `coverage` is the mean of
//! its columns' `covered`, its `mean_density` the mean of their `mean_density` (every
//! column has the layer's depth), its `cloud_base` the lowest column base and its
//! `cloud_top` the highest column top.

use serde::Serialize;

use crate::world::Layer;

use super::Grid;

/// Density at or above which a cell counts as cloud: in region statistics and in the
/// cloud-top channel of `coverage.png`.
pub const CLOUD_THRESHOLD: f32 = 0.1;

/// Statistics of one region at one time.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RegionStats {
    /// Fraction of columns with at least one cloudy cell, in [0, 1].
    pub coverage: f64,
    /// Mean density over all cells, in [0, 1].
    pub mean_density: f64,
    /// Largest density of any cell, in [0, 1].
    pub max_density: f32,
    /// Altitude of the bottom of the lowest cloudy cell, metres.
    pub cloud_base: Option<f64>,
    /// Altitude of the top of the highest cloudy cell, metres.
    pub cloud_top: Option<f64>,
    /// Number of 4-connected groups of covered columns.
    pub clusters: u64,
}

/// Computes the statistics of `grid` (a region of `layer`).
pub fn region_stats(grid: &Grid<f32>, layer: &Layer) -> RegionStats {
    let (depth, rows, cols) = (grid.depth, grid.rows, grid.cols);
    let mut covered = vec![false; rows * cols];
    let mut sum = 0.0f64;
    let mut max = 0.0f32;
    let (mut lowest, mut highest) = (usize::MAX, None::<usize>);
    for k in 0..depth {
        for r in 0..rows {
            for c in 0..cols {
                let v = grid.get(k, r, c);
                sum += v as f64;
                max = max.max(v);
                if v >= CLOUD_THRESHOLD {
                    covered[r * cols + c] = true;
                    lowest = lowest.min(k);
                    highest = Some(k);
                }
            }
        }
    }
    let columns = (rows * cols) as f64;
    let n_covered = covered.iter().filter(|&&c| c).count();
    RegionStats {
        coverage: if columns > 0.0 { n_covered as f64 / columns } else { 0.0 },
        mean_density: if grid.data.is_empty() {
            0.0
        } else {
            sum / grid.data.len() as f64
        },
        max_density: max,
        cloud_base: highest.map(|_| layer.base + lowest as f64 * layer.cell_height),
        cloud_top: highest.map(|k| layer.base + (k + 1) as f64 * layer.cell_height),
        clusters: count_clusters(&covered, rows, cols),
    }
}

/// Statistics of one column of a region: the [`RegionStats`] definitions for a
/// region of that one column.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColumnStats {
    /// Whether any cell of the column is cloudy (density >= [`CLOUD_THRESHOLD`]).
    pub covered: bool,
    /// Mean density over the column's cells, in [0, 1].
    pub mean_density: f64,
    /// Altitude of the bottom of the column's lowest cloudy cell, metres.
    pub cloud_base: Option<f64>,
    /// Altitude of the top of the column's highest cloudy cell, metres.
    pub cloud_top: Option<f64>,
}

/// The statistics of column (`row`, `col`) of `grid` (a region of `layer`).
pub fn column_stats(grid: &Grid<f32>, layer: &Layer, row: usize, col: usize) -> ColumnStats {
    let mut sum = 0.0f64;
    let (mut lowest, mut highest) = (None::<usize>, None::<usize>);
    for k in 0..grid.depth {
        let v = grid.get(k, row, col);
        sum += v as f64;
        if v >= CLOUD_THRESHOLD {
            lowest = lowest.or(Some(k));
            highest = Some(k);
        }
    }
    ColumnStats {
        covered: highest.is_some(),
        mean_density: if grid.depth > 0 { sum / grid.depth as f64 } else { 0.0 },
        cloud_base: lowest.map(|k| layer.base + k as f64 * layer.cell_height),
        cloud_top: highest.map(|k| layer.base + (k + 1) as f64 * layer.cell_height),
    }
}

/// 4-connected components of `true` cells in a row-major `rows × cols` mask.
fn count_clusters(mask: &[bool], rows: usize, cols: usize) -> u64 {
    let mut seen = vec![false; mask.len()];
    let mut stack = Vec::new();
    let mut count = 0;
    for start in 0..mask.len() {
        if !mask[start] || seen[start] {
            continue;
        }
        count += 1;
        seen[start] = true;
        stack.push(start);
        while let Some(i) = stack.pop() {
            let (r, c) = (i / cols, i % cols);
            let mut visit = |j: usize| {
                if mask[j] && !seen[j] {
                    seen[j] = true;
                    stack.push(j);
                }
            };
            if r > 0 {
                visit(i - cols);
            }
            if r + 1 < rows {
                visit(i + cols);
            }
            if c > 0 {
                visit(i - 1);
            }
            if c + 1 < cols {
                visit(i + 1);
            }
        }
    }
    count
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Config;

    #[test]
    fn stats_of_a_known_grid() {
        let layer = Config::embedded().worlds["default"].layers[0].clone();
        // depth 2, 3×3: two separate covered columns, one cloudy cell at k = 1.
        let mut g = Grid::<f32>::new(2, 3, 3);
        let i = g.index(0, 0, 0);
        g.data[i] = 0.9;
        let i = g.index(1, 2, 2);
        g.data[i] = 0.5;
        let i = g.index(0, 1, 1);
        g.data[i] = 0.05;
        let s = region_stats(&g, &layer);
        assert_eq!(s.coverage, 2.0 / 9.0);
        assert_eq!(s.max_density, 0.9);
        assert!((s.mean_density - 1.45 / 18.0).abs() < 1e-6);
        assert_eq!(s.cloud_base, Some(layer.base));
        assert_eq!(s.cloud_top, Some(layer.base + 2.0 * layer.cell_height));
        assert_eq!(s.clusters, 2);
    }

    #[test]
    fn columns_aggregate_to_the_region() {
        let layer = Config::embedded().worlds["default"].layers[0].clone();
        let mut g = Grid::<f32>::new(3, 2, 4);
        for (i, v) in g.data.iter_mut().enumerate() {
            *v = ((i * 37 % 11) as f32) / 10.0;
        }
        let r = region_stats(&g, &layer);
        let columns: Vec<ColumnStats> = (0..2)
            .flat_map(|row| (0..4).map(move |col| (row, col)))
            .map(|(row, col)| column_stats(&g, &layer, row, col))
            .collect();
        let n = columns.len() as f64;
        let covered = columns.iter().filter(|c| c.covered).count() as f64;
        assert_eq!(r.coverage, covered / n);
        let mean = columns.iter().map(|c| c.mean_density).sum::<f64>() / n;
        assert!((r.mean_density - mean).abs() < 1e-12);
        let base = columns.iter().filter_map(|c| c.cloud_base).min_by(f64::total_cmp);
        let top = columns.iter().filter_map(|c| c.cloud_top).max_by(f64::total_cmp);
        assert_eq!((r.cloud_base, r.cloud_top), (base, top));
        let clear = column_stats(&Grid::<f32>::new(3, 1, 1), &layer, 0, 0);
        assert_eq!((clear.covered, clear.cloud_base, clear.cloud_top), (false, None, None));
    }

    #[test]
    fn empty_sky_has_no_base_and_no_clusters() {
        let layer = Config::embedded().worlds["default"].layers[0].clone();
        let s = region_stats(&Grid::<f32>::new(3, 4, 5), &layer);
        assert_eq!(
            (s.coverage, s.clusters, s.cloud_base, s.cloud_top),
            (0.0, 0, None, None)
        );
    }

    #[test]
    fn clusters_follow_four_connectivity() {
        // Diagonal neighbours are separate clusters; an L shape is one.
        let m = [true, false, true, false, true, false, true, false, true];
        assert_eq!(count_clusters(&m, 3, 3), 5);
        let m = [true, false, true, true];
        assert_eq!(count_clusters(&m, 2, 2), 1);
    }
}
