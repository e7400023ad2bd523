//! `precipitation.png`: what falls out of a tile's layer, per column
//! ([`crate::weather::precipitation`] says how it is derived from the density).
//!
//! RGBA 8-bit, 256×256, one pixel per column of the tile at its level; row 0 is the
//! northern edge, column 0 the western edge (like `coverage.png`). The channels are
//! data, not colour: linear values, written without sRGB or gamma chunks, to be read
//! as numbers (an engine samples it as a linear/"data" texture).
//!
//! - **R — rate**: `round(255 · sqrt(min(R, 100) / 100))` with R in mm/h; decode
//!   `R = 100 · (v / 255)²` mm/h. The square root spends the levels where rates are
//!   common: one step is 0.0015 mm/h at the bottom, 0.78 mm/h at the top; 255 means
//!   100 mm/h or more ([`MAX_PNG_RATE`]).
//! - **G — snow**: 255 where it precipitates and what falls at sea level (altitude 0)
//!   is snow (the world's freezing level is at most [`MELTING_DEPTH`] above it), 0
//!   elsewhere. At another altitude `z`, snow falls where `z ≥ freezing_level − 300`
//!   (the freezing level is in the world's discovery document).
//! - **B — streak top**: the lowest level holding cloud (density ≥ 0.1) in the column,
//!   as `coverage.png`'s B: `(k + 0.5) / depth · 255`, where fall streaks start;
//!   0 where nothing falls.
//! - **A — precipitating**: 255 where the rate is above 0, 0 elsewhere, so a dry
//!   column is transparent.
//!
//! [`MELTING_DEPTH`]: crate::weather::precipitation::MELTING_DEPTH

use crate::density::Grid;
use crate::render::image::{self, to_u8};
use crate::render::tile::TILE_COLUMNS;
use crate::weather::precipitation::{PrecipitationKind, column_base, column_rate, kind_at};
use crate::world::Layer;

/// The rate (mm/h) the R channel saturates at: beyond the heaviest hourly rain
/// classes (the Met Office's "violent" starts at 50 mm/h).
pub const MAX_PNG_RATE: f64 = 100.0;

/// The R value of a rate in mm/h.
pub fn rate_to_u8(rate: f64) -> u8 {
    to_u8((rate.clamp(0.0, MAX_PNG_RATE) / MAX_PNG_RATE).sqrt() as f32)
}

/// The rate in mm/h that an R value stands for.
pub fn u8_to_rate(v: u8) -> f64 {
    let f = v as f64 / 255.0;
    MAX_PNG_RATE * f * f
}

/// Encodes the precipitation map of the 256×256 columns of `grid` (a tile's density
/// grid of `layer`).
pub fn encode_png(layer: &Layer, grid: &Grid<f32>) -> Vec<u8> {
    let n = TILE_COLUMNS;
    let depth = grid.depth.max(1) as f32;
    let mut bytes = Vec::with_capacity(n * n * 4);
    for row in (0..n).rev() {
        for col in 0..n {
            let inside = row < grid.rows && col < grid.cols;
            let rate = if inside {
                column_rate(layer, grid, row, col)
            } else {
                0.0
            };
            if !(rate > 0.0) {
                bytes.extend_from_slice(&[0, 0, 0, 0]);
                continue;
            }
            let snow = kind_at(rate, layer.freezing_level, 0.0) == PrecipitationKind::Snow;
            let base = column_base(grid, row, col).map_or(0, |k| to_u8((k as f32 + 0.5) / depth));
            bytes.extend_from_slice(&[rate_to_u8(rate), if snow { 255 } else { 0 }, base, 255]);
        }
    }
    image::encode_png(n, n, png::ColorType::Rgba, image::PngSpace::Linear, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rate_scale_round_trips_within_a_step() {
        assert_eq!(rate_to_u8(0.0), 0);
        assert_eq!(rate_to_u8(100.0), 255);
        assert_eq!(rate_to_u8(1e9), 255);
        assert_eq!(rate_to_u8(f64::NAN), 0);
        assert_eq!(u8_to_rate(255), 100.0);
        for r in [0.01, 0.1, 1.0, 7.6, 37.0, 99.0] {
            let v = rate_to_u8(r);
            // Half a step either side, in the square-root domain.
            let (lo, hi) = (u8_to_rate(v.saturating_sub(1)), u8_to_rate(v.saturating_add(1)));
            assert!(lo <= r && r <= hi, "{r} → {v} ∉ [{lo}, {hi}]");
        }
    }
}
