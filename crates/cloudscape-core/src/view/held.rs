//! Drawing what a client holds: decoded `billboards.bin` keyframes, by the rules that
//! `cloudscape render`, `render.png`, the Rust client and the viewer all follow.
//!
//! - The billboards at `t` by the animation rule ([`crate::render::keyframe`]).
//! - The ground shadow of each tile derived from the billboards themselves, not sent:
//!   at each end of the span and at each column centre `p` of the tile on its layer's
//!   base, `T = exp(−Σ_b τ_b P(q_b))` over the balls `b` of every held tile of the
//!   layer at that end, `τ_b` the ball's splat optical depth, `P` the splat profile
//!   (`S(√q) / S(0)`, `render::splats`) and `q_b` the squared distance, in radii, from
//!   the ball's centre to the sun ray through `p`. The footprint is widened by the
//!   keyframe's shadow widening `w` (the server's light-buffer texel, in radii): radius
//!   `r √(1 + w²)`, optical depth `τ / (1 + w²)`, so the derived map is as sharp as the
//!   server's light buffer toward the sun (`render::shade`), which it otherwise
//!   reproduces at the column centres. A ground point reads the map where the sun ray from it
//!   crosses the base ([`shadow_shift`]), bilinearly, the two ends blended by the
//!   span's fraction, as `shadow.png` is read. A version-2 client's served shadow maps
//!   are drawn the same way ([`HeldTile::served_shadow`]).
//! - Each billboard lit through the layers above it ([`beneath_layers`]): the optical
//!   depth of its sun ray through every other layer whose base is above the ball, read
//!   from that layer's ground shadow maps where the ray crosses its base, dims the sun
//!   term of its colour and adds to its sun optical depth; the vertical depth (that
//!   times the sun's height) dims its sky and ground light
//!   ([`crate::render::light::Lighting::beneath_layers`]).
//! - Composited over the sky and shadowed ground ([`background`], [`composite`]).
//!
//! A client holds only the tiles its view plans, so a tile's shadow is cast by the
//! held tiles of its layer; the server's own `shadow.png` takes the clouds of a halo
//! around the tile instead.

use crate::cancel::Cancel;
use crate::products::billboards::{BinBillboards, BinEnd};
use crate::products::keyframe_bin::splat_tau;

use crate::render::camera::View;
use crate::render::composite::composite_cancellable;
use crate::render::image::Image;
use crate::render::keyframe::between;
use crate::render::light::{LAYERS_ABOVE_SKY_DEPTH, LAYERS_ABOVE_SUN_DEPTH, Lighting};
use crate::render::scene::{RenderRequest, background, mean_shadow};
use crate::render::shade::{Billboard, profile_at, profile_table};
use crate::render::sun::Sun;
use crate::render::tile::{TILE_COLUMNS, shadow_lookup, shadow_shift};

/// One tile a client holds: a decoded keyframe of a layer.
#[derive(Clone, Debug)]
pub struct HeldTile {
    /// Index of the layer in its world.
    pub layer: usize,
    /// Altitude of the layer's base, metres: where its shadow maps lie.
    pub base: f64,
    /// The decoded `billboards.bin`.
    pub keyframe: BinBillboards,
    /// Shadow maps served beside a version-2 keyframe (`shadow.png`, start and end,
    /// 256×256 each, row 0 south); `None`: derived from the billboards.
    pub served_shadow: Option<[Vec<f32>; 2]>,
}

impl HeldTile {
    /// The keyframe's span (an instant for a version-1 keyframe, at `t`).
    fn span(&self, t: f64) -> [f64; 2] {
        self.keyframe.keyframe.unwrap_or([t, t])
    }

    /// Where `t` falls in the span, in [0, 1] (0 for an instant).
    pub fn fraction(&self, t: f64) -> f64 {
        let [t0, t1] = self.span(t);
        if t1 > t0 {
            ((t - t0) / (t1 - t0)).clamp(0.0, 1.0)
        } else {
            0.0
        }
    }

    /// The sun the tile was shaded for (its bucket's centre).
    pub fn sun(&self) -> Sun {
        let k = &self.keyframe;
        Sun::new(k.sun_azimuth_deg as f64, k.sun_elevation_deg as f64).unwrap_or(Sun {
            azimuth_deg: 0.0,
            elevation_deg: 90.0,
        })
    }

    /// Width of one of the tile's columns, metres.
    fn column(&self) -> f64 {
        self.keyframe.size as f64 / TILE_COLUMNS as f64
    }

    /// The centre optical depth an end is drawn with (version 1: its splat's).
    fn tau(&self, e: &BinEnd) -> f32 {
        e.splat_tau
            .unwrap_or_else(|| splat_tau(e.splat, self.keyframe.splat_count))
    }

    /// The billboards at `t` by the animation rule: each record's two ends, moved and
    /// blended.
    pub fn billboards_at(&self, t: f64) -> Vec<Billboard> {
        let [t0, t1] = self.span(t);
        let f = self.fraction(t);
        let k = &self.keyframe;
        k.records
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let centre = [
                    k.origin[0] + r.offset[0] as f64,
                    k.origin[1] + r.offset[1] as f64,
                    r.offset[2] as f64,
                ];
                let end = |e: &BinEnd| Billboard {
                    index: [i as i64, 0, 0],
                    centre,
                    radius: r.radius,
                    density: 0.0,
                    tau: 0.0,
                    splat: e.splat,
                    splat_tau: self.tau(e),
                    opacity: e.opacity as f32 / 255.0,
                    tau_sun: e.tau_sun,
                    sun_transmittance: e.sun_transmittance as f32 / 255.0,
                    colour: e.colour,
                };
                let velocity = r.velocity.map(|v| v as f64);
                between(&end(&r.ends[0]), &end(&r.ends[1]), velocity, f * (t1 - t0), f)
            })
            .collect()
    }
}

/// The ground shadow maps of `tiles` (start and end, 256×256, row 0 south): served
/// ones as they are, the others derived from the billboards of the held tiles of
/// their layer (see the module docs). With the sun at or below the horizon every
/// value is 1.
pub fn shadow_maps(tiles: &[HeldTile]) -> Vec<[Vec<f32>; 2]> {
    use rayon::prelude::*;
    tiles
        .par_iter()
        .map(|t| match &t.served_shadow {
            Some(served) => served.clone(),
            None => derive_shadow(t, tiles.iter().filter(|s| s.layer == t.layer)),
        })
        .collect()
}

/// The shadow maps of `target` cast by the billboards of `sources` (its layer's held
/// tiles, itself among them).
fn derive_shadow<'a>(target: &HeldTile, sources: impl Iterator<Item = &'a HeldTile>) -> [Vec<f32>; 2] {
    let n = TILE_COLUMNS;
    let mut map = [vec![0.0f64; n * n], vec![0.0f64; n * n]];
    let s = target.sun().direction();
    let lit = |v: Vec<f64>| -> Vec<f32> { v.into_iter().map(|tau| (-tau).exp() as f32).collect() };
    if !(s[2] > 0.0) {
        let [a, b] = map;
        return [lit(a), lit(b)];
    }
    let table = profile_table();
    let column = target.column();
    let origin = target.keyframe.origin;
    let (x1, y1) = (origin[0] + n as f64 * column, origin[1] + n as f64 * column);
    // Horizontal unit vector toward the sun: the footprint of a ball on the base is an
    // ellipse, `r / s_z` along it and `r` across.
    let h = (s[0] * s[0] + s[1] * s[1]).sqrt();
    let (ux, uy) = if h > 1e-12 { (s[0] / h, s[1] / h) } else { (1.0, 0.0) };
    let range = |lo: f64, hi: f64, o: f64| {
        let a = ((lo - o) / column - 0.5).ceil().max(0.0) as usize;
        let b = (((hi - o) / column - 0.5).floor() + 1.0).clamp(0.0, n as f64) as usize;
        a..b.max(a)
    };
    for source in sources {
        let k = &source.keyframe;
        let span = k.keyframe.map_or(0.0, |k| k[1] - k[0]);
        for r in &k.records {
            // The footprint widened by the server's light-buffer texel (a Gaussian-like
            // blur: the variances add), its optical depth spread to keep the integral.
            let w = source
                .keyframe
                .lattice
                .as_ref()
                .map_or(0.0, |l| l.shadow_widening as f64);
            let spread = 1.0 + w * w;
            let radius = r.radius as f64 * spread.sqrt();
            if !(radius > 0.0 && radius.is_finite()) {
                continue;
            }
            let a = radius / s[2];
            let half = [
                (a * a * ux * ux + radius * radius * uy * uy).sqrt(),
                (a * a * uy * uy + radius * radius * ux * ux).sqrt(),
            ];
            let inv_r2 = 1.0 / (radius * radius);
            for (e, end) in r.ends.iter().enumerate() {
                let tau = source.tau(end) as f64 / spread;
                if !(tau > 0.0) {
                    continue;
                }
                let moved = if e == 1 { span } else { 0.0 };
                let c = [
                    k.origin[0] + r.offset[0] as f64 + r.velocity[0] as f64 * moved,
                    k.origin[1] + r.offset[1] as f64 + r.velocity[1] as f64 * moved,
                    r.offset[2] as f64,
                ];
                // Where the sun ray through the centre crosses the base.
                let lift = (c[2] - target.base) / s[2];
                let pb = [c[0] - s[0] * lift, c[1] - s[1] * lift];
                if pb[0] + half[0] < origin[0]
                    || pb[0] - half[0] > x1
                    || pb[1] + half[1] < origin[1]
                    || pb[1] - half[1] > y1
                {
                    continue;
                }
                for row in range(pb[1] - half[1], pb[1] + half[1], origin[1]) {
                    let wy = pb[1] - (origin[1] + (row as f64 + 0.5) * column);
                    for col in range(pb[0] - half[0], pb[0] + half[0], origin[0]) {
                        let wx = pb[0] - (origin[0] + (col as f64 + 0.5) * column);
                        // The distance between the sun rays through the centre and
                        // through the column: the offset less its part along the sun.
                        let along = wx * s[0] + wy * s[1];
                        let q = (wx * wx + wy * wy - along * along) * inv_r2;
                        if q < 1.0 {
                            map[e][row * n + col] += tau * profile_at(table, q);
                        }
                    }
                }
            }
        }
    }
    let [a, b] = map;
    [lit(a), lit(b)]
}

/// One tile's shadow maps as the ground and the layers below read them at the drawn
/// time.
struct GroundShadow {
    /// The layer whose clouds cast it.
    layer: usize,
    /// Altitude of the layer's base, metres: where the maps lie.
    base: f64,
    /// The move of the sun ray per metre of climb ([`shadow_shift`] of 1 m).
    shift_per_metre: [f64; 2],
    origin: [f64; 2],
    column: f64,
    /// Added to a ground point before the lookup ([`shadow_shift`]).
    shift: [f64; 2],
    ends: [Vec<f32>; 2],
    fraction: f64,
}

impl GroundShadow {
    /// The sun transmittance through the tile's layer of the sun ray from ground point
    /// (x, y): bilinear lookup of each end, blended; 1 outside the tile.
    fn at(&self, x: f64, y: f64) -> f64 {
        self.at_base(x + self.shift[0], y + self.shift[1])
    }

    /// The sun transmittance through the tile's layer of the sun ray from `p`, a point
    /// below the layer's base (1 at or above it: its own layer's light buffer holds
    /// what shadows it there).
    fn above(&self, p: [f64; 3]) -> f64 {
        if !(p[2] < self.base) {
            return 1.0;
        }
        let climb = self.base - p[2];
        let s = self.shift_per_metre;
        self.at_base(p[0] + s[0] * climb, p[1] + s[1] * climb)
    }

    /// The transmittance of the sun ray crossing the base at (x, y); 1 outside the tile.
    fn at_base(&self, x: f64, y: f64) -> f64 {
        let a = shadow_lookup(&self.ends[0], self.origin, self.column, x, y);
        if self.fraction == 0.0 {
            return a;
        }
        let b = shadow_lookup(&self.ends[1], self.origin, self.column, x, y);
        (1.0 - self.fraction) * a + self.fraction * b
    }

    /// The mean transmittance drawn.
    fn mean(&self) -> f64 {
        let mean = |v: &[f32]| v.iter().map(|&v| v as f64).sum::<f64>() / v.len().max(1) as f64;
        (1.0 - self.fraction) * mean(&self.ends[0]) + self.fraction * mean(&self.ends[1])
    }
}

/// Lights `billboards` of layer `layer` through the clouds of the other layers above
/// them ([`Lighting::beneath_layers`]): the sun's optical depth through each layer
/// whose base is above a ball is read from that layer's shadow maps (`shadows`, the
/// ground's), where the sun ray from the ball crosses the base; the vertical one
/// (what stands between the ball and the sky) is that times the sun's height, the
/// deck taken as locally uniform. Each is taken at its fitted share
/// ([`LAYERS_ABOVE_SUN_DEPTH`], [`LAYERS_ABOVE_SKY_DEPTH`]).
///
/// Each tile is shaded with its own layer's balls only, and the layers above are
/// applied here, when the held tiles are drawn, rather than in the tile's shading:
/// a tile product then depends on one layer's density alone, so it stays cacheable
/// per layer and deterministic by itself (shading a tile knowing the layers above
/// would make every lower tile depend on the tiles above it, at every level and sun
/// bucket, and recompute when any of them changes), and every client that holds the
/// tiles (the Rust client, the viewer) draws the same picture from the same shadow
/// maps it already derives for the ground.
fn beneath_layers(billboards: &mut [Billboard], layer: usize, shadows: &[GroundShadow], lighting: &Lighting) {
    let above: Vec<&GroundShadow> = shadows.iter().filter(|s| s.layer != layer).collect();
    if above.is_empty() || !(lighting.sun_dir[2] > 0.0) {
        return;
    }
    let sun_height = lighting.sun_dir[2];
    for b in billboards.iter_mut() {
        let t: f64 = above.iter().map(|s| s.above(b.centre)).product();
        let tau = -t.clamp(1e-30, 1.0).ln();
        if tau <= 0.0 {
            continue;
        }
        let (colour, tau_sun) = lighting.beneath_layers(
            b.colour,
            b.tau_sun,
            LAYERS_ABOVE_SUN_DEPTH * tau,
            LAYERS_ABOVE_SKY_DEPTH * tau * sun_height,
        );
        b.colour = colour;
        b.tau_sun = tau_sun;
        b.sun_transmittance = (-tau_sun).exp().clamp(0.0, 1.0);
    }
}

/// Draws held tiles for `req` under `sun` (whose bucket's centre lights the sky and
/// ground): the billboards at `req.t` over the sky and the ground shadowed by each
/// tile's maps.
pub fn draw(tiles: &[HeldTile], req: &RenderRequest, sun: Sun) -> Image {
    draw_cancellable(tiles, req, sun, &Cancel::never())
}

/// [`draw`] that leaves the remaining bands undrawn once `cancel` fires.
pub fn draw_cancellable(tiles: &[HeldTile], req: &RenderRequest, sun: Sun, cancel: &Cancel) -> Image {
    use rayon::prelude::*;
    let view = View::perspective(&req.camera, req.width, req.height);
    let lighting = Lighting::for_quality(sun.bucket().centre(), req.params, req.quality);
    let shadows: Vec<GroundShadow> = tiles
        .iter()
        .zip(shadow_maps(tiles))
        .map(|(t, ends)| GroundShadow {
            layer: t.layer,
            base: t.base,
            shift_per_metre: shadow_shift(t.sun(), 1.0),
            origin: t.keyframe.origin,
            column: t.column(),
            shift: shadow_shift(t.sun(), t.base),
            ends,
            fraction: t.fraction(req.t),
        })
        .collect();
    let far = mean_shadow(tiles.iter().zip(&shadows).map(|(t, s)| (t.layer, s.mean())));
    let mut image = background(&view, &lighting, far, |x, y| {
        shadows.iter().map(|s| s.at(x, y)).product()
    });
    let all: Vec<Billboard> = tiles
        .par_iter()
        .map(|t| {
            let mut bbs = t.billboards_at(req.t);
            beneath_layers(&mut bbs, t.layer, &shadows, &lighting);
            bbs
        })
        .collect::<Vec<_>>()
        .concat();
    composite_cancellable(&mut image, &all, &lighting, &view, cancel);
    image
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::light::ShadingParams;

    fn ball(z: f64) -> Billboard {
        Billboard {
            index: [0, 0, 0],
            centre: [12_800.0, 12_800.0, z],
            radius: 300.0,
            density: 0.5,
            tau: 1.0,
            splat: 10,
            splat_tau: 1.0,
            opacity: 0.6,
            tau_sun: 1.0,
            sun_transmittance: (-1.0f32).exp(),
            colour: [0.3, 0.32, 0.36],
        }
    }

    #[test]
    fn a_deck_above_dims_the_layers_below_it_only() {
        let sun = Sun::new(180.0, 60.0).unwrap();
        let lighting = Lighting::new(sun, ShadingParams::default());
        let n = TILE_COLUMNS * TILE_COLUMNS;
        let deck = GroundShadow {
            layer: 1,
            base: 3000.0,
            shift_per_metre: shadow_shift(sun, 1.0),
            origin: [0.0, 0.0],
            column: 100.0,
            shift: shadow_shift(sun, 3000.0),
            ends: [vec![(-3.0f32).exp(); n], vec![(-3.0f32).exp(); n]],
            fraction: 0.0,
        };
        let shadows = [deck];
        // A ball of the layer below: the deck's τ 3 at the shares of LAYERS_ABOVE_*.
        let mut below = [ball(1500.0)];
        beneath_layers(&mut below, 0, &shadows, &lighting);
        let s_z = sun.direction()[2];
        let (colour, tau_sun) = lighting.beneath_layers(
            ball(1500.0).colour,
            1.0,
            LAYERS_ABOVE_SUN_DEPTH * 3.0,
            LAYERS_ABOVE_SKY_DEPTH * 3.0 * s_z,
        );
        for ch in 0..3 {
            assert!(
                (below[0].colour[ch] - colour[ch]).abs() < 1e-5,
                "{:?} vs {colour:?}",
                below[0].colour
            );
            assert!(below[0].colour[ch] < ball(1500.0).colour[ch]);
        }
        assert!((below[0].tau_sun - tau_sun).abs() < 1e-4);
        assert!((below[0].sun_transmittance - (-tau_sun).exp()).abs() < 1e-6);
        // Above the deck's base, or of the deck's own layer: left alone (its own light
        // buffer holds what shadows it).
        let mut above = [ball(3500.0)];
        beneath_layers(&mut above, 0, &shadows, &lighting);
        assert_eq!(above[0], ball(3500.0));
        let mut own = [ball(1500.0)];
        beneath_layers(&mut own, 1, &shadows, &lighting);
        assert_eq!(own[0], ball(1500.0));
        // With the sun down nothing changes (the maps are all 1 then anyway).
        let night = Lighting::new(Sun::new(180.0, -5.0).unwrap(), ShadingParams::default());
        let mut dark = [ball(1500.0)];
        beneath_layers(&mut dark, 0, &shadows, &night);
        assert_eq!(dark[0], ball(1500.0));
    }
}
