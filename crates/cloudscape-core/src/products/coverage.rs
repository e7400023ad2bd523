//! `coverage.png`: a 2D weather map per tile, for engines that take an external
//! weather texture (in the spirit of the Guerrilla/Unreal weather maps).
//!
//! RGB 8-bit, 256×256, one pixel per column of the tile at its level; row 0 is the
//! northern edge, column 0 the western edge. No alpha channel: every channel is data,
//! and a decoder that premultiplies alpha (a browser canvas) would destroy colour
//! under a small alpha. Linear data (`gAMA` 1.0, [`PngSpace::Linear`]). Channels:
//!
//! - **R — coverage**: the largest density in the column, × 255.
//! - **G — opacity**: vertical opacity `1 − exp(−Σ σ ρ Δz)` of the column (the optical
//!   thickness, squashed into [0, 1)), with σ = [`ShadingParams::default`]'s extinction.
//! - **B — cloud top**: height of the highest cell with density ≥ [`CLOUD_THRESHOLD`]
//!   above the layer base, as a fraction of the layer thickness (cell centre), × 255;
//!   0 where the column holds no cloud. (Until algorithm version 8 B was the cloud base
//!   and A the top. Bases are nearly flat, at the condensation level; tops carry the
//!   shape. The base of a column is in the density grids, a region's in `/region`.)
//!
//! [`ShadingParams::default`]: crate::render::ShadingParams
//! [`PngSpace::Linear`]: crate::render::image::PngSpace

use crate::density::{self, CLOUD_THRESHOLD, Grid, Region, check_time};
use crate::render::image::{PngSpace, encode_png, to_u8};
use crate::render::tile::{TILE_COLUMNS, TileId};
use crate::render::{RenderError, ShadingParams};
use crate::world::{Layer, Limits, World};

/// Computes a tile's density and encodes its coverage map.
pub fn encode_png_for_tile(
    world: &World,
    layer: usize,
    tile: TileId,
    t: f64,
    limits: &Limits,
) -> Result<Vec<u8>, RenderError> {
    check_time(t)?;
    let l = world
        .layers
        .get(layer)
        .ok_or_else(|| RenderError::BadRequest(format!("layer {layer} does not exist in world `{}`", world.name)))?;
    let region: Region = tile.region()?;
    region.check(tile.z, l.depth, limits)?;
    let grid = density::density(world, layer, tile.z, region, t)?;
    Ok(encode_png_from_grid(l, &grid, 0))
}

/// Encodes the coverage map of the 256×256 columns of `grid` that start `halo`
/// columns in from its south-west corner.
pub fn encode_png_from_grid(layer: &Layer, grid: &Grid<f32>, halo: usize) -> Vec<u8> {
    let n = TILE_COLUMNS;
    let sigma = ShadingParams::default().extinction;
    let depth = grid.depth.max(1) as f32;
    let mut bytes = Vec::with_capacity(n * n * 3);
    for row in (0..n).rev() {
        for col in 0..n {
            let (r, c) = (row + halo, col + halo);
            let (mut max, mut tau) = (0.0f32, 0.0f64);
            let mut top = None;
            for k in 0..grid.depth {
                let v = if r < grid.rows && c < grid.cols {
                    grid.get(k, r, c)
                } else {
                    0.0
                };
                max = max.max(v);
                tau += sigma * v as f64 * layer.cell_height;
                if v >= CLOUD_THRESHOLD {
                    top = Some(k);
                }
            }
            let height = |k: Option<usize>| k.map_or(0, |k| to_u8((k as f32 + 0.5) / depth));
            bytes.extend_from_slice(&[to_u8(max), to_u8((1.0 - (-tau).exp()) as f32), height(top)]);
        }
    }
    encode_png(n, n, png::ColorType::Rgb, PngSpace::Linear, &bytes)
}
