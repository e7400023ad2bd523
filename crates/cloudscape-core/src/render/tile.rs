//! One tile, shaded: density (with a halo) → metaballs → sun shading → billboards
//! and the ground shadow map. Every tile product is encoded from a [`ShadedTile`].

use crate::cancel::Cancel;
use crate::density::metaballs::{GridPlacement, Lattice};
use crate::density::{self, Grid, Region, SimError, check_time};
use crate::world::{Layer, Limits, World};

use super::light::{Lighting, ShadingParams};
use super::shade::{Billboard, shade};
use super::splats::SplatSheet;
use super::sun::{Sun, SunBucket};
use super::{Quality, RenderError};

/// Columns per tile side (PRODUCT.md: a tile is 256×256 columns at its level).
pub const TILE_COLUMNS: usize = 256;

/// Most halo columns fetched around a tile for shadowing by its neighbours.
pub const MAX_SHADOW_HALO: usize = 24;

/// Metaballs below this density are dropped as empty.
pub const MIN_BALL_DENSITY: f32 = 1e-3;

/// A tile address: level `z`, column-tile `x` (east), row-tile `y` (north).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TileId {
    /// Level: a column is `2^z` level-0 cells per side.
    pub z: u32,
    /// Tile column (east), in tiles of [`TILE_COLUMNS`] columns.
    pub x: i64,
    /// Tile row (north), in tiles of [`TILE_COLUMNS`] columns.
    pub y: i64,
}

impl TileId {
    /// The tile's columns at its level: the `TILE_COLUMNS`² columns whose first is
    /// (x·256, y·256). The arithmetic itself (x·256 + 256) must not overflow; whether
    /// the columns lie within the simulation's range is [`Region::check`]'s question.
    pub fn region(&self) -> Result<Region, RenderError> {
        let n = TILE_COLUMNS as i64;
        let origin = |v: i64, name: &str| {
            v.checked_mul(n)
                .filter(|o| o.checked_add(n).is_some())
                .ok_or_else(|| SimError::OutOfRange(format!("tile {name} = {v} overflows at level {}", self.z)))
        };
        Ok(Region {
            x0: origin(self.x, "x")?,
            y0: origin(self.y, "y")?,
            cols: TILE_COLUMNS,
            rows: TILE_COLUMNS,
        })
    }
}

/// A tile after density, metaballs and shading: everything the tile products encode.
#[derive(Clone, Debug)]
pub struct ShadedTile {
    /// Index of the layer in its world.
    pub layer: usize,
    /// Name of the layer.
    pub layer_name: String,
    /// The tile's address.
    pub tile: TileId,
    /// World-clock seconds.
    pub t: f64,
    /// The quality preset it was shaded at.
    pub quality: Quality,
    /// The bucket of the requested sun, and its centre (the sun actually used).
    pub bucket: SunBucket,
    /// The centre of `bucket`: the sun the tile is shaded with.
    pub sun: Sun,
    /// Sun, sky and cloud optics the billboards were shaded with.
    pub lighting: Lighting,
    /// Where the tile's metaballs sit.
    pub lattice: Lattice,
    /// South-west corner of the tile, world metres, and its side, metres.
    pub origin: [f64; 2],
    /// Side of the tile, metres.
    pub size: f64,
    /// Column width at the tile's level, metres.
    pub column: f64,
    /// The shaded metaballs whose centres lie in the tile, in lattice order.
    pub billboards: Vec<Billboard>,
    /// Sunlight transmittance through this layer along the sun ray that crosses the
    /// layer's base at each column centre, 256×256, row 0 = south. A ground point
    /// (x, y) lies on the ray through `(x, y) + shadow_shift(sun, base)` (see
    /// [`ShadedTile::shadow_at`]): indexing by the base rather than the ground keeps
    /// every occluder of a texel within the tile and its halo, so neighbouring tiles'
    /// shadows meet without a seam at any sun elevation. All 1 when the sun is not
    /// above the horizon (no direct light to shadow).
    pub shadow: Vec<f32>,
    /// The density the tile was built from, with `halo` extra columns on each side.
    pub density: Grid<f32>,
    /// Extra columns of `density` on each side of the tile.
    pub halo: usize,
    /// Where `density`'s cells lie in the world.
    pub place: GridPlacement,
}

/// The shadow halo for a layer: enough columns for a sun ray to cross the layer's
/// thickness at the sun's elevation (at least 5°), plus one metaball radius, capped at
/// [`MAX_SHADOW_HALO`] (occluders farther out are ignored).
fn shadow_halo(thickness: f64, elevation_deg: f64, column: f64, radius: f64) -> usize {
    let el = elevation_deg.max(5.0).to_radians();
    let reach = thickness / el.tan() + radius;
    ((reach / column).ceil() as usize + 1).min(MAX_SHADOW_HALO)
}

/// The halo (columns per side) [`shade_tile`] fetches around a tile of layer `l`.
pub fn tile_halo(l: &Layer, z: u32, quality: Quality, sun: Sun) -> usize {
    let s = quality.settings();
    let column = l.cell_size * (z as f64).exp2();
    let radius = s.radius_factor * s.spacing_columns * column;
    shadow_halo(l.top() - l.base, sun.bucket().centre().elevation_deg, column, radius)
}

/// Computes the density of a tile (with halo), its metaballs, their shading for the
/// centre of `sun`'s bucket, and the shadow map; stops early once `cancel` fires (then
/// an error; `Cancel::never()` runs to the end).
#[allow(clippy::too_many_arguments)]
pub fn shade_tile(
    world: &World,
    layer: usize,
    tile: TileId,
    t: f64,
    quality: Quality,
    sun: Sun,
    params: &ShadingParams,
    limits: &Limits,
    cancel: &Cancel,
) -> Result<ShadedTile, RenderError> {
    let (grid, halo) = tile_density(world, layer, tile, t, quality, sun, limits, cancel)?;
    let l = &world.layers[layer];
    let shaded = shade_density(layer, l, tile, t, quality, sun, params, grid, halo);
    cancel.check().map_err(SimError::from)?;
    Ok(shaded)
}

/// The density [`shade_tile`] shades: the tile plus the halo its billboards and
/// shadows reach into (`(grid, halo)`, the grid `256 + 2·halo` columns square),
/// checked against `limits` first.
#[allow(clippy::too_many_arguments)]
pub fn tile_density(
    world: &World,
    layer: usize,
    tile: TileId,
    t: f64,
    quality: Quality,
    sun: Sun,
    limits: &Limits,
    cancel: &Cancel,
) -> Result<(Grid<f32>, usize), RenderError> {
    check_time(t)?;
    let l = world
        .layers
        .get(layer)
        .ok_or_else(|| RenderError::BadRequest(format!("layer {layer} does not exist in world `{}`", world.name)))?;
    let region = tile.region()?;
    region.check(tile.z, l.depth, limits)?;
    let halo = tile_halo(l, tile.z, quality, sun);
    let h = halo as i64;
    let halo_region = Region {
        x0: region.x0 - h,
        y0: region.y0 - h,
        cols: TILE_COLUMNS + 2 * halo,
        rows: TILE_COLUMNS + 2 * halo,
    };
    let grid = density::density_cancellable(world, layer, tile.z, halo_region, t, cancel)?;
    Ok((grid, halo))
}

/// [`shade_tile`] on a density grid already computed: `grid` covers the tile plus
/// `halo` columns on each side (shape `(depth, 256 + 2·halo, 256 + 2·halo)`).
#[allow(clippy::too_many_arguments)]
pub fn shade_density(
    layer: usize,
    l: &Layer,
    tile: TileId,
    t: f64,
    quality: Quality,
    sun: Sun,
    params: &ShadingParams,
    grid: Grid<f32>,
    halo: usize,
) -> ShadedTile {
    let settings = quality.settings();
    let column = l.cell_size * (tile.z as f64).exp2();
    let spacing = settings.spacing_columns * column;
    let lattice = Lattice::new(spacing, settings.radius_factor * spacing, l.base, l.top() - l.base);
    let bucket = sun.bucket();
    let centre_sun = bucket.centre();
    let n = TILE_COLUMNS as i64;
    let (x0, y0) = (tile.x.saturating_mul(n), tile.y.saturating_mul(n));
    let place = GridPlacement {
        x0: (x0 - halo as i64) as f64 * column,
        y0: (y0 - halo as i64) as f64 * column,
        column,
        base: l.base,
        cell_height: l.cell_height,
    };
    let origin = [x0 as f64 * column, y0 as f64 * column];
    let size = TILE_COLUMNS as f64 * column;
    let owned = [origin[0], origin[1], origin[0] + size, origin[1] + size];
    let all = [
        place.x0,
        place.y0,
        place.x0 + grid.cols as f64 * column,
        place.y0 + grid.rows as f64 * column,
    ];
    let balls = lattice.collect(&grid, &place, all, MIN_BALL_DENSITY);
    let lighting = Lighting::new(centre_sun, *params);
    let sheet = SplatSheet::new(settings.splat_count, settings.splat_size);
    let (billboards, buffer) = shade(&balls, &lattice, &lighting, &sheet, settings.light_texel, owned);
    let mut shadow = vec![1.0f32; TILE_COLUMNS * TILE_COLUMNS];
    if centre_sun.elevation_deg > 0.0 {
        for r in 0..TILE_COLUMNS {
            for c in 0..TILE_COLUMNS {
                // At the layer's base: the sun line through it crosses only this
                // tile's clouds and its halo (see `ShadedTile::shadow`).
                let p = [
                    origin[0] + (c as f64 + 0.5) * column,
                    origin[1] + (r as f64 + 0.5) * column,
                    l.base,
                ];
                shadow[r * TILE_COLUMNS + c] = buffer.transmittance_at(p).clamp(0.0, 1.0) as f32;
            }
        }
    }
    ShadedTile {
        layer,
        layer_name: l.name.clone(),
        tile,
        t,
        quality,
        bucket,
        sun: centre_sun,
        lighting,
        lattice,
        origin,
        size,
        column,
        billboards,
        shadow,
        density: grid,
        halo,
        place,
    }
}

/// Where the sun ray from a ground point crosses altitude `base`, relative to the
/// point (metres east, north): `(s_x, s_y) · base / s_z` for the unit vector `s`
/// toward `sun`. The sun's height is floored at sin 1° so the shift stays finite (below
/// that every shadow map is all 1 anyway).
pub fn shadow_shift(sun: Sun, base: f64) -> [f64; 2] {
    let s = sun.direction();
    let k = base / s[2].max(1f64.to_radians().sin());
    [s[0] * k, s[1] * k]
}

impl ShadedTile {
    /// Shadow transmittance at ground point (x, y): the map read at the point where
    /// the sun ray from it crosses the layer's base ([`shadow_shift`]), by bilinear
    /// lookup; 1 outside the tile.
    pub fn shadow_at(&self, x: f64, y: f64) -> f64 {
        let shift = shadow_shift(self.sun, self.place.base);
        shadow_lookup(&self.shadow, self.origin, self.column, x + shift[0], y + shift[1])
    }
}

/// Bilinear lookup of a tile's `TILE_COLUMNS`² shadow map (row 0 south, texel centres
/// at column centres) at (x, y), already shifted along the sun ray; 1 outside the tile.
/// The served `shadow.png` is read back through this too, so a remote render and a
/// local one look shadows up alike.
pub fn shadow_lookup(map: &[f32], origin: [f64; 2], column: f64, x: f64, y: f64) -> f64 {
    let n = TILE_COLUMNS;
    let u = (x - origin[0]) / column - 0.5;
    let v = (y - origin[1]) / column - 0.5;
    if !(u > -0.5 && v > -0.5 && u < n as f64 - 0.5 && v < n as f64 - 0.5) {
        return 1.0;
    }
    let (u, v) = (u.clamp(0.0, (n - 1) as f64), v.clamp(0.0, (n - 1) as f64));
    let (u0, v0) = ((u.floor() as usize).min(n - 2), (v.floor() as usize).min(n - 2));
    let (fu, fv) = (u - u0 as f64, v - v0 as f64);
    let at = |c: usize, r: usize| map[r * n + c] as f64;
    let a = at(u0, v0) * (1.0 - fu) + at(u0 + 1, v0) * fu;
    let b = at(u0, v0 + 1) * (1.0 - fu) + at(u0 + 1, v0 + 1) * fu;
    a * (1.0 - fv) + b * fv
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_regions_refuse_overflow() {
        let region = |z, x, y| TileId { z, x, y }.region();
        assert_eq!(
            region(0, -1, 2).unwrap(),
            Region {
                x0: -256,
                y0: 512,
                cols: 256,
                rows: 256
            }
        );
        assert!(region(0, i64::MAX, 0).is_err());
        assert!(region(0, 0, i64::MIN).is_err());
        assert!(region(0, i64::MAX / 256, 0).is_err());
        assert!(region(0, i64::MAX / 256 - 1, 0).is_ok());
    }
}
