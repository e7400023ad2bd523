//! `shadow.png`: the ground shadow map of a shaded tile, at both ends of its keyframe
//! span.
//!
//! 8-bit RGB, 256×256, one pixel per column of the tile at its level; row 0 is the
//! northern edge (a map, north up), column 0 the western edge. **R** is the map at the
//! span's start `t0`, **G** at its end `t1`, **B** is 0; at `t` in the span a client
//! draws `(1 − f) R + f G` with `f = (t − t0) / (t1 − t0)`
//! (`render::keyframe`). Each value is the
//! sunlight transmittance through the layer's clouds along the sun ray that crosses
//! the layer's base altitude at the column's centre, × 255 rounded: 255 = no cloud
//! shadow, 0 = full shadow. The ground point (x, y) (altitude 0) lies on the ray
//! through `(x, y) + (s_x, s_y) · base / s_z` (s the unit vector toward the bucket's
//! sun, `render::tile::shadow_shift`): a client draws the map shifted by
//! `−(s_x, s_y) · base / s_z`. When the sun (bucket centre) is not above the horizon
//! there is no direct light to shadow and every pixel is 255. Occluders beyond the
//! tile's shadow halo are not included.

use crate::render::ShadedTile;
use crate::render::image::{PngSpace, encode_png, to_u8};
use crate::render::tile::TILE_COLUMNS;

/// Encodes the tile's shadow map as a PNG.
pub fn encode_png_map(tile: &ShadedTile) -> Vec<u8> {
    let n = TILE_COLUMNS;
    let mut bytes = Vec::with_capacity(3 * n * n);
    for row in (0..n).rev() {
        let ends = tile.shadow[row * n..(row + 1) * n]
            .iter()
            .zip(&tile.shadow_end[row * n..(row + 1) * n]);
        for (&a, &b) in ends {
            bytes.extend_from_slice(&[to_u8(a), to_u8(b), 0]);
        }
    }
    encode_png(n, n, png::ColorType::Rgb, PngSpace::Linear, &bytes)
}
