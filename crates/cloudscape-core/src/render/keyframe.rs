//! The animation rule: what a keyframe tile looks like at any time inside its span.
//!
//! A keyframe product ([`crate::world::Keyframe`]) holds each metaball at both ends of
//! its span `[t0, t1]`, the second moved by the wind at its altitude. At a time `t` in
//! the span, with `f = (t − t0) / (t1 − t0)`, a billboard is drawn
//!
//! - at `p0 + v · (t − t0)`, `v` the wind at its altitude (so at `t1` it is where the
//!   span's end put it);
//! - with the centre optical depth `splat_tau = (1 − f) τ0 + f τ1` (0 at an end where
//!   the ball is absent: it forms or vanishes during the span), and so the opacity
//!   `1 − exp(−splat_tau · P(q))` at `q` radii² from its centre, P the splat profile;
//!   a client sampling the splat sheet reads splat `k` nearest `splat_tau` and draws
//!   `1 − (1 − a_k)^(splat_tau / τ_k)`, which is the same opacity;
//! - with every other quantity (colour, `tau_sun`, sun transmittance, peak opacity,
//!   density) linear in `f` between its two ends.
//!
//! Shadow maps blend linearly between their two ends: `(1 − f) S0 + f S1` at each
//! texel. Density grids, coverage maps and atlases hold one time each (`t0`): a
//! client blends keyframe `k` and `k + 1` with the same `f`, density grids moved by
//! the wind as [`blend_density_at`] states.
//!
//! The server's own renderer (`cloudscape render`, `render.png`) draws through
//! [`ShadedTile::billboards_at`] and [`ShadedTile::shadow_at`], the viewer and the Rust
//! client apply the same rule to the bytes they fetch, so all of them draw the same
//! picture at any `t`.

use super::shade::Billboard;
use super::tile::{ShadedTile, shadow_lookup, shadow_shift};
use crate::world::Keyframe;

/// Linear interpolation `(1 − f) a + f b`.
#[inline]
fn lerp(a: f32, b: f32, f: f64) -> f32 {
    ((1.0 - f) * a as f64 + f * b as f64) as f32
}

/// A billboard `dt` seconds after the span's start, a fraction `f` of the way from
/// `start` to `end`, moving at `velocity` (m/s, x east, y north).
pub fn between(start: &Billboard, end: &Billboard, velocity: [f64; 2], dt: f64, f: f64) -> Billboard {
    Billboard {
        index: start.index,
        centre: [
            start.centre[0] + velocity[0] * dt,
            start.centre[1] + velocity[1] * dt,
            start.centre[2],
        ],
        radius: start.radius,
        density: lerp(start.density, end.density, f),
        tau: lerp(start.tau, end.tau, f),
        splat: if f < 0.5 { start.splat } else { end.splat },
        splat_tau: lerp(start.splat_tau, end.splat_tau, f),
        opacity: lerp(start.opacity, end.opacity, f),
        tau_sun: lerp(start.tau_sun, end.tau_sun, f),
        sun_transmittance: lerp(start.sun_transmittance, end.sun_transmittance, f),
        colour: [0, 1, 2].map(|c| lerp(start.colour[c], end.colour[c], f)),
    }
}

/// The density a client draws at a point and time inside a keyframe span, from the
/// two keyframes' grids: `(1 − f) · D0(x − v (t − t0)) + f · D1(x + v (t1 − t))`, where
/// `d0` and `d1` read a keyframe's grid (bilinearly) at a world point of the same
/// height, `v` is the wind at that height and `f` is [`Keyframe::fraction`]. At
/// level 0, whose span is one automaton step, this is the model's own interpolation
/// between steps (`density::exact`), up to the second bilinear resampling.
pub fn blend_density_at(
    d0: impl Fn(f64, f64) -> f64,
    d1: impl Fn(f64, f64) -> f64,
    x: [f64; 2],
    velocity: [f64; 2],
    keyframe: &Keyframe,
    t: f64,
) -> f64 {
    let f = keyframe.fraction(t);
    let (back, ahead) = (t - keyframe.t0, keyframe.t1 - t);
    let a = d0(x[0] - velocity[0] * back, x[1] - velocity[1] * back);
    if f == 0.0 {
        return a;
    }
    let b = d1(x[0] + velocity[0] * ahead, x[1] + velocity[1] * ahead);
    (1.0 - f) * a + f * b
}

impl ShadedTile {
    /// The tile's billboards at `t` under the animation rule (`t` is clamped to the
    /// span; an instant's billboards are its own).
    pub fn billboards_at(&self, t: f64) -> Vec<Billboard> {
        if self.keyframe.is_instant() {
            return self.billboards.clone();
        }
        let f = self.keyframe.fraction(t);
        let dt = f * self.keyframe.span();
        self.billboards
            .iter()
            .zip(&self.end)
            .map(|(a, b)| between(a, b, self.velocity_at(a.centre[2]), dt, f))
            .collect()
    }

    /// Shadow transmittance at ground point (x, y) at time `t`: each end's map read at
    /// the point where the sun ray from it crosses the layer's base ([`shadow_shift`]),
    /// by bilinear lookup, blended linearly over the span; 1 outside the tile.
    pub fn shadow_at(&self, x: f64, y: f64, t: f64) -> f64 {
        let shift = shadow_shift(self.sun, self.place.base);
        let (x, y) = (x + shift[0], y + shift[1]);
        let a = shadow_lookup(&self.shadow, self.origin, self.column, x, y);
        let f = self.keyframe.fraction(t);
        if f == 0.0 {
            return a;
        }
        let b = shadow_lookup(&self.shadow_end, self.origin, self.column, x, y);
        (1.0 - f) * a + f * b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cancel::Cancel;
    use crate::density::{self, Grid, Region};
    use crate::render::tile::{MIN_BALL_DENSITY, TileId, shade_tile};
    use crate::render::{Quality, ShadingParams, Sun};
    use crate::world::Config;

    fn keyframe_tile(t: f64) -> (crate::world::World, ShadedTile) {
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        let tile = TileId { z: 0, x: 1, y: 0 };
        let span = Keyframe::containing(t, &world.layers[0], 0);
        let s = shade_tile(
            &world,
            0,
            tile,
            span,
            Quality::Fast,
            Sun::new(200.0, 35.0).unwrap(),
            &ShadingParams::default(),
            &config.limits,
            &Cancel::never(),
        )
        .unwrap();
        (world, s)
    }

    #[test]
    fn the_rule_starts_and_ends_at_the_keyframes() {
        let (_, s) = keyframe_tile(43_205.0);
        assert_eq!((s.keyframe.t0, s.keyframe.t1), (43_200.0, 43_220.0));
        assert_eq!(s.billboards.len(), s.end.len());
        let at0 = s.billboards_at(43_200.0);
        let at1 = s.billboards_at(43_220.0);
        let mid = s.billboards_at(43_210.0);
        for i in 0..s.billboards.len() {
            let (a, b) = (&s.billboards[i], &s.end[i]);
            assert_eq!(a.index, b.index, "ends pair by lattice point");
            assert_eq!(at0[i], *a);
            assert!((at1[i].centre[0] - b.centre[0]).abs() < 1e-6 && (at1[i].centre[1] - b.centre[1]).abs() < 1e-6);
            assert_eq!((at1[i].splat_tau, at1[i].colour), (b.splat_tau, b.colour));
            let want = 0.5 * (a.splat_tau + b.splat_tau);
            assert!((mid[i].splat_tau - want).abs() <= 1e-6 * want.max(1.0));
            // Halfway, a ball is halfway along its wind.
            let v = s.velocity_at(a.centre[2]);
            assert!((mid[i].centre[0] - (a.centre[0] + 10.0 * v[0])).abs() < 1e-6);
        }
        // Balls form and vanish inside a span: some ends are empty, never both.
        assert!(
            s.billboards
                .iter()
                .zip(&s.end)
                .all(|(a, b)| a.splat_tau > 0.0 || b.splat_tau > 0.0)
        );
        assert!(s.billboards.iter().any(|a| a.splat_tau == 0.0));
        assert!(s.end.iter().any(|b| b.splat_tau == 0.0));
        // A shadow map drawn halfway is the mean of its ends.
        let (x, y) = (s.origin[0] + 9_000.0, s.origin[1] + 12_000.0);
        let half = s.shadow_at(x, y, 43_210.0);
        let ends = 0.5 * (s.shadow_at(x, y, 43_200.0) + s.shadow_at(x, y, 43_220.0));
        assert!((half - ends).abs() < 1e-12);
    }

    #[test]
    fn the_end_collects_the_air_the_wind_brought() {
        // Independent of the moved grid and the cached stencils: each end ball's
        // density is the naive collection from a plain grid at t1 around its centre.
        let (world, s) = keyframe_tile(43_205.0);
        let layer = &world.layers[0];
        let h = s.halo as i64 + 4;
        let n = crate::render::tile::TILE_COLUMNS as i64;
        let region = Region::square(n - h, -h, (n + 2 * h) as usize);
        let g1: Grid<f32> = density::density(&world, 0, 0, region, s.keyframe.t1).unwrap();
        let place = crate::density::metaballs::GridPlacement {
            x0: region.x0 as f64 * layer.cell_size,
            y0: region.y0 as f64 * layer.cell_size,
            column: layer.cell_size,
            base: layer.base,
            cell_height: layer.cell_height,
        };
        let mut checked = 0;
        for b in &s.end {
            let naive = s.lattice.collect_at(&g1, &place, b.centre);
            if b.splat_tau > 0.0 {
                assert!((b.density - naive).abs() < 1e-5, "{b:?}: naive {naive}");
                checked += 1;
            } else {
                assert!(naive < MIN_BALL_DENSITY, "{b:?}: naive {naive}");
            }
        }
        assert!(checked > 100, "{checked}");
    }

    #[test]
    fn blended_density_keyframes_are_the_model_between_steps() {
        // Level 0: keyframes one step apart. The client's blend of two keyframe grids
        // against the density the model computes at that time.
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        let layer = &world.layers[0];
        let region = Region::square(0, 0, 64);
        let (t0, t1, t) = (43_200.0, 43_220.0, 43_207.0);
        let keyframe = Keyframe { index: 2160, t0, t1 };
        let d0 = density::density(&world, 0, 0, region, t0).unwrap();
        let d1 = density::density(&world, 0, 0, region, t1).unwrap();
        let truth = density::density(&world, 0, 0, region, t).unwrap();
        let c = layer.cell_size;
        fn bilinear(g: &Grid<f32>, k: usize, c: f64) -> impl Fn(f64, f64) -> f64 + '_ {
            move |x: f64, y: f64| {
                // Bilinear at cell centres.
                let (u, v) = (x / c - 0.5, y / c - 0.5);
                let (i, j) = (u.floor(), v.floor());
                let (fu, fv) = (u - i, v - j);
                let at = |a: f64, b: f64| g.get(k, b as usize, a as usize) as f64;
                let lo = at(i, j) * (1.0 - fu) + at(i + 1.0, j) * fu;
                let hi = at(i, j + 1.0) * (1.0 - fu) + at(i + 1.0, j + 1.0) * fu;
                lo * (1.0 - fv) + hi * fv
            }
        }
        let read = |g, k| bilinear(g, k, c);
        let (mut err, mut plain, mut n) = (0.0f64, 0.0f64, 0);
        for k in 0..layer.depth as usize {
            let v = layer.wind_at_level(k as u32);
            for r in 8..56 {
                for col in 8..56 {
                    let x = [(col as f64 + 0.5) * c, (r as f64 + 0.5) * c];
                    let blended = blend_density_at(read(&d0, k), read(&d1, k), x, v, &keyframe, t);
                    let want = truth.get(k, r, col) as f64;
                    err += (blended - want).powi(2);
                    let f = (t - t0) / (t1 - t0);
                    let unmoved = (1.0 - f) * d0.get(k, r, col) as f64 + f * d1.get(k, r, col) as f64;
                    plain += (unmoved - want).powi(2);
                    n += 1;
                }
            }
        }
        let (rmse, plain_rmse) = ((err / n as f64).sqrt(), (plain / n as f64).sqrt());
        // Only the second bilinear resampling separates them (0.011 here); a blend
        // that ignores the wind is off by the motion too (0.019).
        assert!(rmse < 0.02, "advected blend RMSE {rmse}");
        assert!(rmse < 0.75 * plain_rmse, "advected {rmse} against unmoved {plain_rmse}");
    }
}
