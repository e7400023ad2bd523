//! One tile, shaded: density (with a halo) → metaballs → sun shading → billboards
//! and the ground shadow map. Every tile product is encoded from a [`ShadedTile`].

use std::sync::Arc;

use crate::cancel::Cancel;
use crate::density::kept::KeptDensity;
use crate::density::metaballs::{GridPlacement, Lattice, Metaball};
use crate::density::{self, Grid, Region, SimError, check_time};
use crate::stages::{Stage, Stages};
use crate::world::{Keyframe, Layer, Limits, World, keyframe_span};

use super::light::{Lighting, ShadingParams};
use super::shade::{Billboard, shade_where};
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
        Ok(Region::square(origin(self.x, "x")?, origin(self.y, "y")?, TILE_COLUMNS))
    }
}

/// A tile after density, metaballs and shading, for one keyframe span: everything
/// the tile products encode.
///
/// The billboards come in pairs: `billboards[i]` is a metaball at the span's start
/// (`keyframe.t0`) and `end[i]` the same lattice point at its end (`keyframe.t1`),
/// moved by the wind at its altitude. A ball that forms during the span starts with
/// nothing to draw (`splat_tau` 0), one that vanishes ends with nothing. The
/// animation rule between them is [`crate::render::keyframe`]'s.
#[derive(Clone, Debug)]
pub struct ShadedTile {
    /// Index of the layer in its world.
    pub layer: usize,
    /// Name of the layer.
    pub layer_name: String,
    /// The tile's address.
    pub tile: TileId,
    /// World-clock seconds of the span's start (`keyframe.t0`).
    pub t: f64,
    /// The span the tile animates over (an instant for a tile shaded at one time).
    pub keyframe: Keyframe,
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
    /// Wind at the layer's base (m/s, x east, y north) and its change with height
    /// ((m/s) per metre): a billboard at altitude `z` moves at
    /// `wind + shear · (z − base)` ([`ShadedTile::velocity_at`]).
    pub wind: [f64; 2],
    /// Change of the wind with height, (m/s) per metre.
    pub shear: [f64; 2],
    /// The shaded metaballs whose lattice points lie in the tile, in lattice order, at
    /// the span's start.
    pub billboards: Vec<Billboard>,
    /// The same metaballs at the span's end (`end[i]` pairs with `billboards[i]`); a
    /// copy of `billboards` for an instant.
    pub end: Vec<Billboard>,
    /// Sunlight transmittance through this layer along the sun ray that crosses the
    /// layer's base at each column centre, 256×256, row 0 = south. A ground point
    /// (x, y) lies on the ray through `(x, y) + shadow_shift(sun, base)` (see
    /// [`ShadedTile::shadow_at`]): indexing by the base rather than the ground keeps
    /// every occluder of a texel within the tile and its halo, so neighbouring tiles'
    /// shadows meet without a seam at any sun elevation. All 1 when the sun is not
    /// above the horizon (no direct light to shadow). At the span's start.
    pub shadow: Vec<f32>,
    /// The shadow map at the span's end.
    pub shadow_end: Vec<f32>,
    /// The density the tile was built from (the span's start), with `halo` extra
    /// columns on each side.
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

/// Computes the density of a tile (with halo), its metaballs and their shading for
/// the centre of `sun`'s bucket, and the shadow map, at both ends of the span
/// `keyframe` (once for an instant); stops early once `cancel` fires (then an error;
/// `Cancel::never()` runs to the end).
///
/// Each end is an instant shaded on its own ([`ShadedInstant`]): the density at that
/// time over the tile, its halo and the box the wind moves it to over one span, and
/// the lattice placed for that time, drifting with the wind
/// ([`crate::density::metaballs::Drift`]). The span's start keeps the balls whose
/// centres lie in the tile, the end the balls the wind carried those lattice points
/// to ([`Lattice::successor`]), so each ball follows its air. Since the end of one
/// span is the instant the next span starts at, a tile shaded keyframe after
/// keyframe ([`shade_tile_kept`]) shades one instant per keyframe, and a client
/// sees no jump where one span hands over to the next.
#[allow(clippy::too_many_arguments)]
pub fn shade_tile(
    world: &World,
    layer: usize,
    tile: TileId,
    keyframe: Keyframe,
    quality: Quality,
    sun: Sun,
    params: &ShadingParams,
    limits: &Limits,
    cancel: &Cancel,
) -> Result<ShadedTile, RenderError> {
    let mut stages = Stages::default();
    shade_tile_staged(
        world,
        layer,
        tile,
        keyframe,
        quality,
        sun,
        params,
        limits,
        cancel,
        None,
        &mut stages,
    )
}

/// [`shade_tile`] from what the tile kept of its previous keyframes (`kept`, made
/// for this layer and tile with [`KeptTile::for_tile`]), and keeping what the next
/// keyframe can use: the same bytes, at the cost of what changed.
#[allow(clippy::too_many_arguments)]
pub fn shade_tile_kept(
    world: &World,
    layer: usize,
    tile: TileId,
    keyframe: Keyframe,
    quality: Quality,
    sun: Sun,
    params: &ShadingParams,
    limits: &Limits,
    cancel: &Cancel,
    kept: &mut KeptTile,
) -> Result<ShadedTile, RenderError> {
    let mut stages = Stages::default();
    shade_tile_staged(
        world,
        layer,
        tile,
        keyframe,
        quality,
        sun,
        params,
        limits,
        cancel,
        Some(kept),
        &mut stages,
    )
}

/// [`shade_tile`] (with `kept`, [`shade_tile_kept`]) adding the time of each stage to
/// `stages`.
#[allow(clippy::too_many_arguments)]
pub fn shade_tile_staged(
    world: &World,
    layer: usize,
    tile: TileId,
    keyframe: Keyframe,
    quality: Quality,
    sun: Sun,
    params: &ShadingParams,
    limits: &Limits,
    cancel: &Cancel,
    mut kept: Option<&mut KeptTile>,
    stages: &mut Stages,
) -> Result<ShadedTile, RenderError> {
    check_time(keyframe.t0)?;
    let l = checked_layer(world, layer)?;
    tile.region()?.check(tile.z, l.depth, limits)?;
    let halo = tile_halo(l, tile.z, quality, sun);
    let shading = TileShading::new(l, tile, quality, sun, params, halo, keyframe.span())?;
    let square = shading.square;
    let density = |kept: Option<&mut KeptTile>, region: Region, t: f64, stages: &mut Stages| match kept {
        Some(kept) => kept.density.density(world, region, t, true, cancel, stages),
        None => density::density_staged(world, layer, tile.z, region, t, cancel, stages),
    };
    // The span's start, and the density of the tile and its halo then.
    let (start, grid) = match kept.as_deref_mut().and_then(|k| k.instant(&shading, keyframe.t0)) {
        Some(start) => (start, density(kept.as_deref_mut(), square, keyframe.t0, stages)?),
        None => {
            let grid = density(kept.as_deref_mut(), shading.region, keyframe.t0, stages)?;
            let start = Arc::new(shading.instant(&grid, keyframe.t0, stages));
            if let Some(k) = kept.as_deref_mut() {
                k.keep(Arc::clone(&start));
            }
            (start, cut(&grid, shading.region, square))
        }
    };
    cancel.check().map_err(SimError::from)?;
    // The span's end.
    let end = if keyframe.is_instant() {
        Arc::clone(&start)
    } else {
        match kept.as_deref_mut().and_then(|k| k.instant(&shading, keyframe.t1)) {
            Some(end) => end,
            None => {
                let grid = density(kept.as_deref_mut(), shading.region, keyframe.t1, stages)?;
                let end = Arc::new(shading.instant(&grid, keyframe.t1, stages));
                if let Some(k) = kept {
                    k.keep(Arc::clone(&end));
                }
                end
            }
        }
    };
    cancel.check().map_err(SimError::from)?;
    Ok(shading.keyframe(l, layer, keyframe, &start, &end, grid))
}

/// The columns a tile's kept density ([`KeptDensity`]) covers: the tile with the
/// widest halo any quality or sun shades it with, and the same box moved downwind
/// over one keyframe span of its level (the span's end), so that every keyframe's
/// two ends, in every quality and sun bucket, are cut from it.
pub fn kept_region(l: &Layer, tile: TileId) -> Result<Region, RenderError> {
    let column = l.cell_size * (tile.z as f64).exp2();
    let moved = downwind_columns(l, column, keyframe_span(l.dt, tile.z));
    let (a, b) = (
        around(tile, MAX_SHADOW_HALO, [0, 0])?,
        around(tile, MAX_SHADOW_HALO, moved)?,
    );
    let (x0, y0) = (a.x0.min(b.x0), a.y0.min(b.y0));
    let (x1, y1) = (
        (a.x0 + a.cols as i64).max(b.x0 + b.cols as i64),
        (a.y0 + a.rows as i64).max(b.y0 + b.rows as i64),
    );
    Ok(Region {
        x0,
        y0,
        cols: (x1 - x0) as usize,
        rows: (y1 - y0) as usize,
    })
}

/// The layer `layer` of `world`, or a bad request naming it.
fn checked_layer(world: &World, layer: usize) -> Result<&Layer, RenderError> {
    world
        .layers
        .get(layer)
        .ok_or_else(|| RenderError::BadRequest(format!("layer {layer} does not exist in world `{}`", world.name)))
}

/// Whole columns (x, y) the wind at the middle of `l` moves in `span` seconds.
fn downwind_columns(l: &Layer, column: f64, span: f64) -> [i64; 2] {
    let mid = 0.5 * (l.top() - l.base);
    let v = [l.wind[0] + l.shear[0] * mid, l.wind[1] + l.shear[1] * mid];
    // Bounded so the box stays in range for any wind the config accepts; a layer
    // that outruns it leaves the rest to the lattice's shift (empty air beyond).
    v.map(|w| ((w * span / column).round()).clamp(-1e6, 1e6) as i64)
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
    let l = checked_layer(world, layer)?;
    let region = tile.region()?;
    region.check(tile.z, l.depth, limits)?;
    let halo = tile_halo(l, tile.z, quality, sun);
    let grid = density::density_cancellable(world, layer, tile.z, around(tile, halo, [0, 0])?, t, cancel)?;
    Ok((grid, halo))
}

/// The tile's columns plus `halo` on each side, moved by `moved` whole columns.
fn around(tile: TileId, halo: usize, moved: [i64; 2]) -> Result<Region, RenderError> {
    let region = tile.region()?;
    let h = halo as i64;
    let shifted = |v: i64, m: i64| {
        v.checked_sub(h)
            .and_then(|v| v.checked_add(m))
            .ok_or_else(|| SimError::OutOfRange(format!("tile {tile:?} moved by {moved:?} columns overflows")))
    };
    Ok(Region::square(
        shifted(region.x0, moved[0])?,
        shifted(region.y0, moved[1])?,
        TILE_COLUMNS + 2 * halo,
    ))
}

/// What shading a tile of one layer at one level needs, whichever instant.
pub(crate) struct TileShading {
    tile: TileId,
    quality: Quality,
    bucket: SunBucket,
    /// The lattice, not yet placed in time (its drift is the layer's wind).
    lattice: Lattice,
    lighting: Lighting,
    sheet: SplatSheet,
    light_texel: f64,
    origin: [f64; 2],
    column: f64,
    /// The tile's own box, world metres.
    owned: [f64; 4],
    /// Extra columns around the tile for shadowing.
    halo: usize,
    /// The span of the keyframes the instants serve (0 for an instant).
    span: f64,
    /// The tile and its halo: the density a keyframe keeps of its start.
    square: Region,
    /// The columns an instant is shaded over: `square`, and the same box moved by the
    /// wind over one span (so the balls that the wind carries out of the tile still
    /// collect their air).
    region: Region,
    /// Height of the layer's cells, metres.
    cell_height: f64,
}

impl TileShading {
    fn new(
        l: &Layer,
        tile: TileId,
        quality: Quality,
        sun: Sun,
        params: &ShadingParams,
        halo: usize,
        span: f64,
    ) -> Result<TileShading, RenderError> {
        let settings = quality.settings();
        let column = l.cell_size * (tile.z as f64).exp2();
        let spacing = settings.spacing_columns * column;
        let n = TILE_COLUMNS as i64;
        let origin = [
            tile.x.saturating_mul(n) as f64 * column,
            tile.y.saturating_mul(n) as f64 * column,
        ];
        let size = TILE_COLUMNS as f64 * column;
        let moved = downwind_columns(l, column, span);
        let square = around(tile, halo, [0, 0])?;
        Ok(TileShading {
            tile,
            quality,
            bucket: sun.bucket(),
            lattice: Lattice::new(spacing, settings.radius_factor * spacing, l.base, l.top() - l.base)
                .drifting(l.wind, l.shear, 0.0),
            lighting: Lighting::for_quality(sun.bucket().centre(), *params, quality),
            sheet: SplatSheet::new(settings.splat_count, settings.splat_size),
            light_texel: settings.light_texel,
            origin,
            column,
            owned: [origin[0], origin[1], origin[0] + size, origin[1] + size],
            halo,
            span,
            square,
            region: hull(square, around(tile, halo, moved)?),
            cell_height: l.cell_height,
        })
    }

    /// Where a grid over `region` (columns of the tile's level) lies in the world.
    fn placement(&self, region: Region) -> GridPlacement {
        GridPlacement {
            x0: region.x0 as f64 * self.column,
            y0: region.y0 as f64 * self.column,
            column: self.column,
            base: self.lattice.base,
            cell_height: self.cell_height,
        }
    }

    /// Whether a point lies in the tile's own box.
    fn inside(&self, c: [f64; 3]) -> bool {
        c[0] >= self.owned[0] && c[0] < self.owned[2] && c[1] >= self.owned[1] && c[1] < self.owned[3]
    }

    /// The index, in the lattice of one span earlier, of the point the wind carried
    /// to lattice point `index` of `lattice`, and its centre then.
    fn predecessor(&self, lattice: &Lattice, index: [i64; 3]) -> ([i64; 3], [f64; 3]) {
        let earlier = lattice.at(lattice.drift.t - self.span);
        let p = lattice.successor(index, &earlier);
        (p, earlier.centre(p[0], p[1], p[2]))
    }

    /// The instant `t` shaded from `grid` (the density over `self.region` at `t`):
    /// the balls of the lattice placed for `t` over the region, lit together, kept
    /// where they start a span in the tile or end one that started there, and the
    /// ground shadow map they cast.
    fn instant(&self, grid: &Grid<f32>, t: f64, stages: &mut Stages) -> ShadedInstant {
        let lattice = self.lattice.at(t);
        debug_assert_eq!((grid.rows, grid.cols), (self.region.rows, self.region.cols));
        let place = self.placement(self.region);
        let r = self.region;
        let all = [
            place.x0,
            place.y0,
            place.x0 + r.cols as f64 * self.column,
            place.y0 + r.rows as f64 * self.column,
        ];
        let balls = stages.time(Stage::Metaballs, || {
            lattice.collect(grid, &place, all, MIN_BALL_DENSITY)
        });
        let keep = |b: &Metaball| {
            self.inside(b.centre) || (self.span > 0.0 && self.inside(self.predecessor(&lattice, b.index).1))
        };
        let (billboards, shadow) = stages.time(Stage::Shading, || self.light(&lattice, &balls, keep));
        ShadedInstant {
            t,
            span: self.span,
            quality: self.quality,
            bucket: self.bucket,
            lattice,
            billboards,
            shadow,
        }
    }

    /// The billboards of `balls` that `keep` accepts, shaded toward the sun, and the
    /// ground shadow map.
    fn light(
        &self,
        lattice: &Lattice,
        balls: &[Metaball],
        keep: impl Fn(&Metaball) -> bool,
    ) -> (Vec<Billboard>, Vec<f32>) {
        let (billboards, buffer) = shade_where(
            balls,
            lattice,
            &self.lighting,
            &self.sheet,
            self.light_texel,
            self.origin,
            keep,
        );
        let mut shadow = vec![1.0f32; TILE_COLUMNS * TILE_COLUMNS];
        if self.lighting.sun_dir[2] > 0.0 {
            for r in 0..TILE_COLUMNS {
                for c in 0..TILE_COLUMNS {
                    // At the layer's base: the sun line through it crosses only this
                    // tile's clouds and its halo (see `ShadedTile::shadow`).
                    let p = [
                        self.origin[0] + (c as f64 + 0.5) * self.column,
                        self.origin[1] + (r as f64 + 0.5) * self.column,
                        lattice.base,
                    ];
                    shadow[r * TILE_COLUMNS + c] = buffer.transmittance_at(p).clamp(0.0, 1.0) as f32;
                }
            }
        }
        (billboards, shadow)
    }

    /// The keyframe from its two ends (the same instant for an instant) and `grid`,
    /// the density of the tile and its halo at the start.
    fn keyframe(
        &self,
        l: &Layer,
        layer: usize,
        keyframe: Keyframe,
        start: &ShadedInstant,
        end: &ShadedInstant,
        grid: Grid<f32>,
    ) -> ShadedTile {
        let first: Vec<Billboard> = start
            .billboards
            .iter()
            .filter(|b| self.inside(b.centre))
            .copied()
            .collect();
        let (billboards, end_billboards) = if keyframe.is_instant() {
            (first.clone(), first)
        } else {
            // The end's balls whose lattice points started the span in the tile, named
            // by those points so the two ends pair.
            let last: Vec<Billboard> = end
                .billboards
                .iter()
                .filter_map(|b| {
                    let (index, from) = self.predecessor(&end.lattice, b.index);
                    self.inside(from).then_some(Billboard { index, ..*b })
                })
                .collect();
            let span = keyframe.span();
            let (wind, shear, base) = (l.wind, l.shear, l.base);
            let shift = |z: f64| {
                let h = z - base;
                [(wind[0] + shear[0] * h) * span, (wind[1] + shear[1] * h) * span]
            };
            pair_ends(first, last, shift)
        };
        ShadedTile {
            layer,
            layer_name: l.name.clone(),
            tile: self.tile,
            t: keyframe.t0,
            keyframe,
            quality: self.quality,
            bucket: self.bucket,
            sun: self.bucket.centre(),
            lighting: self.lighting.clone(),
            lattice: start.lattice,
            origin: self.origin,
            size: TILE_COLUMNS as f64 * self.column,
            column: self.column,
            wind: l.wind,
            shear: l.shear,
            billboards,
            end: end_billboards,
            shadow: start.shadow.clone(),
            shadow_end: end.shadow.clone(),
            density: grid,
            halo: self.halo,
            place: self.placement(self.square),
        }
    }
}

/// One instant of a tile shaded (see [`shade_tile`]): what the keyframe that starts
/// at `t` and the one that ends there both take from it.
#[derive(Debug)]
pub struct ShadedInstant {
    t: f64,
    span: f64,
    quality: Quality,
    bucket: SunBucket,
    /// The lattice placed for `t`.
    lattice: Lattice,
    /// The shaded balls that start a span in the tile or end one that started there,
    /// in lattice order, named by the lattice of `t`.
    billboards: Vec<Billboard>,
    /// The ground shadow map at `t`.
    shadow: Vec<f32>,
}

impl ShadedInstant {
    /// Whether it is the instant `t` of keyframes shaded as `shading` shades them.
    fn is(&self, shading: &TileShading, t: f64) -> bool {
        self.t == t && self.span == shading.span && self.quality == shading.quality && self.bucket == shading.bucket
    }

    /// Bytes it holds.
    fn bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + self.billboards.capacity() * std::mem::size_of::<Billboard>()
            + self.shadow.capacity() * 4
    }
}

/// The columns of the smallest box holding `a` and `b`.
fn hull(a: Region, b: Region) -> Region {
    let (x0, y0) = (a.x0.min(b.x0), a.y0.min(b.y0));
    let (x1, y1) = (
        (a.x0 + a.cols as i64).max(b.x0 + b.cols as i64),
        (a.y0 + a.rows as i64).max(b.y0 + b.rows as i64),
    );
    Region {
        x0,
        y0,
        cols: (x1 - x0) as usize,
        rows: (y1 - y0) as usize,
    }
}

/// Variants (quality, sun bucket) whose latest instant a tile keeps.
const KEPT_INSTANTS: usize = 3;

/// What one tile of one layer keeps between keyframes: its density
/// ([`KeptDensity`]: the latest grids and, at level 0, the automaton's runs) and the
/// latest instants it shaded, so that a keyframe whose start is the previous one's
/// end shades one instant, not two.
#[derive(Debug)]
pub struct KeptTile {
    /// The tile's density state.
    pub density: KeptDensity,
    instants: Vec<Arc<ShadedInstant>>,
    counts: ShadingCounts,
}

/// How the instants a [`KeptTile`] gave were obtained.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShadingCounts {
    /// Taken from an earlier keyframe: no metaballs collected, no light swept.
    pub reused: u64,
    /// Shaded.
    pub shaded: u64,
}

impl KeptTile {
    /// Nothing kept yet for layer `layer` of `l`'s tile `tile`: over the columns every
    /// keyframe of it, in every quality and sun, is cut from ([`kept_region`]; the
    /// tile's own columns if that region is out of range, and then the jobs compute
    /// cold where they must).
    pub fn for_tile(l: &Layer, layer: usize, tile: TileId) -> KeptTile {
        let region = kept_region(l, tile)
            .or_else(|_| tile.region())
            .unwrap_or(Region::square(0, 0, 0));
        KeptTile {
            density: KeptDensity::new(layer, tile.z, region),
            instants: Vec::new(),
            counts: ShadingCounts::default(),
        }
    }

    /// The kept instant `t` of `shading`'s keyframes, counted as reused.
    fn instant(&mut self, shading: &TileShading, t: f64) -> Option<Arc<ShadedInstant>> {
        let found = self.instants.iter().find(|i| i.is(shading, t)).cloned();
        self.counts.reused += u64::from(found.is_some());
        found
    }

    /// Keeps `instant`, dropping the earliest when full; counts it as shaded.
    /// Keeps `instant` if it is of the latest time kept (or later: then it replaces
    /// them), for at most [`KEPT_INSTANTS`] variants; counts it as shaded. Only the
    /// latest instant serves a keyframe to come: an earlier keyframe asked again is
    /// in the response cache.
    fn keep(&mut self, instant: Arc<ShadedInstant>) {
        self.counts.shaded += 1;
        let latest = self.instants.iter().map(|i| i.t).fold(f64::NEG_INFINITY, f64::max);
        if instant.t < latest {
            return;
        }
        if instant.t > latest {
            self.instants.clear();
        }
        if self.instants.len() >= KEPT_INSTANTS {
            self.instants.remove(0);
        }
        self.instants.push(instant);
    }

    /// Bytes held: the density state and the instants.
    pub fn bytes(&self) -> usize {
        self.density.bytes() + self.instants.iter().map(|i| i.bytes()).sum::<usize>()
    }

    /// How its instants were obtained so far.
    pub fn shading_counts(&self) -> ShadingCounts {
        self.counts
    }
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

/// [`shade_tile`] of an instant on a density grid already computed: `grid` covers the
/// tile plus `halo` columns on each side (shape `(depth, 256 + 2·halo, 256 + 2·halo)`).
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
    let mut stages = Stages::default();
    let shading = TileShading::new(l, tile, quality, sun, params, halo, 0.0).expect("the grid's tile is in range");
    let start = shading.instant(&grid, t, &mut stages);
    shading.keyframe(l, layer, Keyframe::instant(t), &start, &start, grid)
}

impl ShadedTile {
    /// The density of the tile's own columns at the span's start (`density` without
    /// its halo): the grid `density::density` gives for the tile, since every column
    /// is a function of its own coordinates (seams are exact).
    pub fn tile_density(&self) -> Grid<f32> {
        let d = &self.density;
        let (h, n) = (self.halo, TILE_COLUMNS.min(d.rows.saturating_sub(2 * self.halo)));
        let mut out = Grid::new(d.depth, n, n);
        for k in 0..d.depth {
            for r in 0..n {
                let from = d.index(k, r + h, h);
                let to = out.index(k, r, 0);
                out.data[to..to + n].copy_from_slice(&d.data[from..from + n]);
            }
        }
        out
    }

    /// Wind (m/s, x east, y north) at altitude `z`: the layer's base wind plus its
    /// shear over the height above the base.
    pub fn velocity_at(&self, z: f64) -> [f64; 2] {
        let h = z - self.lattice.base;
        [self.wind[0] + self.shear[0] * h, self.wind[1] + self.shear[1] * h]
    }
}

/// Pairs the billboards of a span's two ends by lattice point (both in lattice order):
/// a ball at only one end gets a partner with nothing to draw at the other, moved by
/// `shift` of its altitude, with the same light (so only its opacity changes).
fn pair_ends(
    start: Vec<Billboard>,
    end: Vec<Billboard>,
    shift: impl Fn(f64) -> [f64; 2],
) -> (Vec<Billboard>, Vec<Billboard>) {
    let order = |b: &Billboard| (b.index[2], b.index[1], b.index[0]);
    let empty = |b: &Billboard, sign: f64| {
        let d = shift(b.centre[2]);
        Billboard {
            centre: [b.centre[0] + sign * d[0], b.centre[1] + sign * d[1], b.centre[2]],
            density: 0.0,
            tau: 0.0,
            splat: 0,
            splat_tau: 0.0,
            opacity: 0.0,
            ..*b
        }
    };
    let (mut a, mut b) = (start.into_iter().peekable(), end.into_iter().peekable());
    let (mut s, mut e) = (Vec::new(), Vec::new());
    loop {
        match (a.peek(), b.peek()) {
            (Some(x), Some(y)) if order(x) == order(y) => {
                s.push(a.next().expect("peeked"));
                e.push(b.next().expect("peeked"));
            }
            (Some(x), Some(y)) if order(x) < order(y) => {
                let x = a.next().expect("peeked");
                e.push(empty(&x, 1.0));
                s.push(x);
            }
            (Some(_), None) => {
                let x = a.next().expect("peeked");
                e.push(empty(&x, 1.0));
                s.push(x);
            }
            (_, Some(_)) => {
                let y = b.next().expect("peeked");
                s.push(empty(&y, -1.0));
                e.push(y);
            }
            (None, None) => break,
        }
    }
    (s, e)
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

    /// A tile shaded keyframe after keyframe from what it kept gives the bytes of a
    /// cold shading: at levels 0 to 3, across an epoch boundary (level 0's spans are
    /// steps, so its runs switch inside the sequence), two qualities of one keyframe,
    /// and a keyframe asked again after the state moved past it.
    #[test]
    fn kept_keyframes_equal_cold_ones() {
        use crate::cancel::Cancel;
        use crate::products::Product;
        use crate::products::catalogue::encode_shaded;
        use crate::render::{Quality, ShadingParams, Sun};
        use crate::world::Config;
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        let layer = 1;
        let l = &world.layers[layer];
        let sun = Sun::new(200.0, 35.0).unwrap();
        let params = ShadingParams::default();
        let encode = |s: &ShadedTile| {
            let mut all = encode_shaded(s, u64::MAX, true, Product::BillboardsBin);
            all.sort_by_key(|(p, _)| p.name());
            (all, s.density.data.clone())
        };
        for z in 0..=3u32 {
            let tile = TileId { z, x: -1, y: 0 };
            let mut kept = KeptTile::for_tile(l, layer, tile);
            let span = keyframe_span(l.dt, z);
            // Level 0: the steps 16·200 − 2 … 16·200 + 1 hold an epoch boundary.
            let first = (16 * 200 - 2) / (1i64 << z.min(4));
            let mut asked: Vec<(i64, Quality)> = (first..first + 4).map(|k| (k, Quality::Fast)).collect();
            asked.insert(2, (first + 1, Quality::Balanced));
            asked.push((first, Quality::Fast));
            for (k, q) in asked {
                let keyframe = Keyframe::containing(k as f64 * span, l, z);
                let cold = shade_tile(
                    &world,
                    layer,
                    tile,
                    keyframe,
                    q,
                    sun,
                    &params,
                    &config.limits,
                    &Cancel::never(),
                )
                .unwrap();
                let warm = shade_tile_kept(
                    &world,
                    layer,
                    tile,
                    keyframe,
                    q,
                    sun,
                    &params,
                    &config.limits,
                    &Cancel::never(),
                    &mut kept,
                )
                .unwrap();
                assert!(encode(&cold) == encode(&warm), "level {z}, keyframe {k}, {q:?}");
            }
            let c = kept.density.counts();
            assert!(c.reused >= 4, "level {z}: {c:?}");
            assert!(z > 0 || c.live >= 5, "level {z}: {c:?}");
            // Each keyframe after the first of a run shades its end alone.
            let s = kept.shading_counts();
            assert!(s.reused >= 3, "level {z}: {s:?}");
        }
    }

    /// Where one keyframe hands over to the next, a ball that the first span ends
    /// with inside the tile is the ball the next span starts with: the same place and
    /// the same light, so a client draws no jump at the boundary.
    #[test]
    fn a_span_ends_where_the_next_one_starts() {
        use crate::cancel::Cancel;
        use crate::render::{Quality, ShadingParams, Sun};
        use crate::world::Config;
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        let (layer, sun) = (0, Sun::new(200.0, 35.0).unwrap());
        for z in [0u32, 2] {
            let l = &world.layers[layer];
            let tile = TileId { z, x: 1, y: 0 };
            let span = keyframe_span(l.dt, z);
            let shade = |k: u64| {
                let keyframe = Keyframe::containing(k as f64 * span, l, z);
                shade_tile(
                    &world,
                    layer,
                    tile,
                    keyframe,
                    Quality::Fast,
                    sun,
                    &ShadingParams::default(),
                    &config.limits,
                    &Cancel::never(),
                )
                .unwrap()
            };
            let k = (43_200.0 / span) as u64;
            let (a, b) = (shade(k), shade(k + 1));
            let owned = |c: [f64; 3]| {
                c[0] >= a.origin[0] && c[0] < a.origin[0] + a.size && c[1] >= a.origin[1] && c[1] < a.origin[1] + a.size
            };
            let mut matched = 0;
            for e in a.end.iter().filter(|e| e.splat_tau > 0.0 && owned(e.centre)) {
                let s = b
                    .billboards
                    .iter()
                    .find(|s| {
                        (s.centre[0] - e.centre[0]).abs() < 1e-6
                            && (s.centre[1] - e.centre[1]).abs() < 1e-6
                            && s.centre[2] == e.centre[2]
                    })
                    .unwrap_or_else(|| panic!("level {z}: {e:?} starts no ball of the next span"));
                assert_eq!(
                    (s.splat_tau, s.colour, s.tau_sun, s.density),
                    (e.splat_tau, e.colour, e.tau_sun, e.density),
                    "level {z}"
                );
                matched += 1;
            }
            assert!(matched > 100, "level {z}: {matched}");
            assert!(a.shadow_end == b.shadow, "level {z}: the shadow map hands over too");
        }
    }
}
