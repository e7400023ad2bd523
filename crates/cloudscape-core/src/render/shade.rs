//! Sun shading of metaballs: the CPU equivalent of Dobashi 2000's splatting from
//! the sun's view.
//!
//! Metaballs are sorted by distance from the sun (nearest first) and splatted, one by
//! one, into a *light buffer*: an orthographic grid perpendicular to the sun direction
//! holding the optical depth accumulated so far. Before a ball adds its own splat, the
//! buffer at its projected centre is the optical depth toward the sun through every
//! ball in front of it; the ball's sun transmittance is
//! `T = exp(−(τ_front + κ · τ_self))` (Beer–Lambert). `κ` ([`SELF_SHADOW`]) is the
//! density-weighted mean fraction of a ball's own centre optical depth that light
//! crosses before reaching matter inside it: along each line half of the line's depth
//! on average, weighted by the line's density, `κ = ∫S² dA / (2 S(0) ∫S dA) ≈ 0.2853`
//! (S the splat line integral, over the disc). After all balls, the buffer is the
//! total optical depth of any sun ray, which gives the ground shadow map.

use crate::density::metaballs::{Lattice, Metaball};

use super::light::{Lighting, dot};
use super::splats::{SplatSheet, centre_line_integral, line_integral};

/// Mean self-shadowing fraction of a ball's centre optical depth (see the module
/// docs): `∫S² dA / (2 S(0) ∫S dA)` over the unit disc, by quadrature.
pub const SELF_SHADOW: f64 = 0.285_28;

/// Largest light-buffer side in texels; larger extents get coarser texels.
const MAX_LIGHT_TEXELS: usize = 4096;

/// A shaded metaball, ready to draw as a camera-facing billboard.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Billboard {
    /// The metaball's lattice indices (i, j, k): pairs the two ends of a keyframe.
    pub index: [i64; 3],
    /// Centre, world metres (x east, y north, altitude).
    pub centre: [f64; 3],
    /// Radius, metres.
    pub radius: f32,
    /// The metaball's collected density in [0, 1].
    pub density: f32,
    /// Optical depth through the centre (unquantised).
    pub tau: f32,
    /// Index into the splat sheet of the quality preset.
    pub splat: u16,
    /// The centre optical depth the billboard is drawn with: the splat's
    /// (`SplatSheet::tau(splat)`), or between two splats' on a keyframe's way from one
    /// end to the other (0: nothing to draw). Opacity at `q` radii² from the centre is
    /// `1 − exp(−splat_tau · P(q))`, P the splat profile.
    pub splat_tau: f32,
    /// Peak opacity of the splat, `1 − exp(−τ_splat)`, in [0, 1).
    pub opacity: f32,
    /// Optical depth of the ball's sun ray (the balls in front plus `κ` of its own).
    pub tau_sun: f32,
    /// Sunlight transmittance reaching the ball, `exp(−tau_sun)`, in [0, 1].
    pub sun_transmittance: f32,
    /// Pre-shaded linear RGB for an isotropic phase,
    /// `albedo · (sun · Σ bⁱ e^{−aⁱ τ_sun} + ambient)` (see [`shade`]), clamped to
    /// [0, 2]. A client applying the phase function adds
    /// [`Lighting::phase_correction`] of `tau_sun`.
    pub colour: [f32; 3],
}

/// The optical depth of sun rays through the shaded balls, on a grid perpendicular
/// to the sun direction.
#[derive(Clone, Debug, PartialEq)]
pub struct LightBuffer {
    /// Origin that positions are taken relative to, world metres.
    origin: [f64; 3],
    u: [f64; 3],
    v: [f64; 3],
    /// Texel size, metres.
    texel: f64,
    /// Buffer coordinates (metres) of the first texel's corner.
    min: [f64; 2],
    width: usize,
    height: usize,
    tau: Vec<f32>,
}

/// Two unit vectors spanning the plane perpendicular to `s`.
pub(crate) fn plane_basis(s: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let up = [0.0, 0.0, 1.0];
    let c = cross(up, s);
    let n = dot(c, c).sqrt();
    let u = if n > 1e-9 {
        [c[0] / n, c[1] / n, c[2] / n]
    } else {
        [1.0, 0.0, 0.0]
    };
    let v = cross(s, u);
    let m = dot(v, v).sqrt().max(1e-300);
    (u, [v[0] / m, v[1] / m, v[2] / m])
}

pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

impl LightBuffer {
    fn coords(&self, p: [f64; 3]) -> (f64, f64) {
        let r = [p[0] - self.origin[0], p[1] - self.origin[1], p[2] - self.origin[2]];
        (dot(r, self.u), dot(r, self.v))
    }

    /// Optical depth of the sun ray through `p` (bilinear; 0 outside the buffer).
    pub fn tau_at(&self, p: [f64; 3]) -> f64 {
        let (a, b) = self.coords(p);
        let x = (a - self.min[0]) / self.texel - 0.5;
        let y = (b - self.min[1]) / self.texel - 0.5;
        if !(x.is_finite() && y.is_finite()) || x < -1.0 || y < -1.0 {
            return 0.0;
        }
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let at = |xx: i64, yy: i64| {
            if xx < 0 || yy < 0 || xx as usize >= self.width || yy as usize >= self.height {
                0.0
            } else {
                self.tau[yy as usize * self.width + xx as usize] as f64
            }
        };
        let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1, y0) * fx;
        let bottom = at(x0, y0 + 1) * (1.0 - fx) + at(x0 + 1, y0 + 1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Sun transmittance of the ray through `p`, in [0, 1].
    pub fn transmittance_at(&self, p: [f64; 3]) -> f64 {
        (-self.tau_at(p)).exp()
    }

    fn splat(&mut self, a: f64, b: f64, radius: f64, tau_centre: f64) {
        let lut = profile_table();
        let inv_r2 = 1.0 / (radius * radius);
        let x_lo = (((a - radius - self.min[0]) / self.texel).floor().max(0.0)) as usize;
        let y_lo = (((b - radius - self.min[1]) / self.texel).floor().max(0.0)) as usize;
        let x_hi = (((a + radius - self.min[0]) / self.texel).ceil() as usize).min(self.width);
        let y_hi = (((b + radius - self.min[1]) / self.texel).ceil() as usize).min(self.height);
        for y in y_lo..y_hi {
            let tb = self.min[1] + (y as f64 + 0.5) * self.texel - b;
            for x in x_lo..x_hi {
                let ta = self.min[0] + (x as f64 + 0.5) * self.texel - a;
                let q = (ta * ta + tb * tb) * inv_r2;
                if q < 1.0 {
                    self.tau[y * self.width + x] += (tau_centre * profile_at(lut, q)) as f32;
                }
            }
        }
    }
}

/// Entries of the splat-profile table over p² in [0, 1].
const PROFILE_ENTRIES: usize = 4096;

/// `S(p) / S(0)` tabulated over `p²` (linear interpolation between entries; the
/// profile is a smooth polynomial-like function of p², error < 1e-6).
pub(crate) fn profile_table() -> &'static [f64] {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let s0 = centre_line_integral();
        (0..=PROFILE_ENTRIES)
            .map(|i| line_integral((i as f64 / PROFILE_ENTRIES as f64).sqrt()) / s0)
            .collect()
    })
}

#[inline]
pub(crate) fn profile_at(table: &[f64], q: f64) -> f64 {
    let x = q.clamp(0.0, 1.0) * PROFILE_ENTRIES as f64;
    let i = (x as usize).min(PROFILE_ENTRIES - 1);
    let f = x - i as f64;
    table[i] * (1.0 - f) + table[i + 1] * f
}

/// Optical depth through the centre of a ball of density `d` on `lattice`:
/// `σ · (d / K) · R · S(0)` with K the lattice's field sum.
pub fn ball_tau(density: f64, lattice: &Lattice, extinction: f64) -> f64 {
    let t = extinction.max(0.0) * density.max(0.0) / lattice.field_sum() * lattice.radius * centre_line_integral();
    // NaN (0 · ∞) means no matter; ∞ is capped so sums stay finite (e^−1e6 = 0 anyway).
    if t.is_nan() { 0.0 } else { t.min(1e6) }
}

/// Splats `balls` (optical depths `taus`) into a light buffer perpendicular to `dir`
/// (a unit vector toward the light), nearest to the light first, and returns for each
/// ball the optical depth in front of it (through every ball splatted before it, at
/// its centre), in input order, plus the buffer of all balls.
fn sweep(
    balls: &[Metaball],
    taus: &[f64],
    radius: f64,
    dir: [f64; 3],
    light_texel: f64,
    origin: [f64; 3],
) -> (Vec<f64>, LightBuffer) {
    let (u, v) = plane_basis(dir);
    let r = radius;
    let rel = |c: [f64; 3]| [c[0] - origin[0], c[1] - origin[1], c[2] - origin[2]];
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for b in balls {
        let p = rel(b.centre);
        let (a, bb) = (dot(p, u), dot(p, v));
        lo = [lo[0].min(a - r), lo[1].min(bb - r)];
        hi = [hi[0].max(a + r), hi[1].max(bb + r)];
    }
    if balls.is_empty() {
        lo = [0.0, 0.0];
        hi = [r, r];
    }
    let mut texel = (light_texel.max(0.05) * r).max(1e-3);
    let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    if extent / texel > MAX_LIGHT_TEXELS as f64 {
        texel = extent / MAX_LIGHT_TEXELS as f64;
    }
    let width = (((hi[0] - lo[0]) / texel).ceil() as usize).clamp(1, MAX_LIGHT_TEXELS);
    let height = (((hi[1] - lo[1]) / texel).ceil() as usize).clamp(1, MAX_LIGHT_TEXELS);
    let mut buffer = LightBuffer {
        origin,
        u,
        v,
        texel,
        min: lo,
        width,
        height,
        tau: vec![0.0; width * height],
    };
    // Nearest to the light first; ties by lattice index so the order never depends on
    // anything but the balls themselves.
    let mut order: Vec<(f64, usize)> = balls
        .iter()
        .enumerate()
        .map(|(i, b)| (dot(rel(b.centre), dir), i))
        .collect();
    order.sort_by(|x, y| {
        y.0.total_cmp(&x.0)
            .then_with(|| balls[x.1].index.cmp(&balls[y.1].index))
    });
    let mut front = vec![0.0; balls.len()];
    for &(_, i) in &order {
        let p = rel(balls[i].centre);
        front[i] = buffer.tau_at(balls[i].centre);
        buffer.splat(dot(p, u), dot(p, v), r, taus[i]);
    }
    (front, buffer)
}

/// Shades `balls` (all of them shadow each other) for `lighting` and returns the
/// billboards of those whose centres lie in `owned` = [x0, y0, x1, y1), plus the
/// light buffer toward the sun: [`shade_where`] with the buffers placed at `owned`'s
/// corner.
pub fn shade(
    balls: &[Metaball],
    lattice: &Lattice,
    lighting: &Lighting,
    sheet: &SplatSheet,
    light_texel: f64,
    owned: [f64; 4],
) -> (Vec<Billboard>, LightBuffer) {
    let inside = |b: &Metaball| {
        let c = b.centre;
        c[0] >= owned[0] && c[0] < owned[2] && c[1] >= owned[1] && c[1] < owned[3]
    };
    shade_where(
        balls,
        lattice,
        lighting,
        sheet,
        light_texel,
        [owned[0], owned[1]],
        inside,
    )
}

/// Shades `balls` (all of them shadow each other) for `lighting` and returns the
/// billboards of those `keep` accepts, in input order, plus the light buffer toward
/// the sun. `light_texel` is the buffer texel in radii; the buffers' coordinates are
/// taken relative to `origin` (x, y at the lattice's base), so one `origin` and one
/// set of balls give the same bits whichever balls are kept. Deterministic.
///
/// Two sweeps of the light-buffer machinery: one toward the sun gives each ball's
/// `τ_sun = τ_front + κ τ_self`; one toward the zenith gives the optical depth of the
/// balls above (`τ_up`) and, from the column total, of those below (`τ_down`), each
/// plus `κ τ_self`. The colour is `albedo · (sun_scatter · Σ bⁱ e^{−aⁱ τ_sun) + ambient)`
/// with the octaves of [`crate::render::light::Octaves`] and the ambient of
/// [`Lighting::ambient_source`]: the upper hemisphere's sky (`sky_ambient_above`)
/// through `τ_up`, and the ground under the ball (lit through the sun buffer's total
/// depth) through `τ_down`. The splat is the one of the sheet nearest the ball's
/// optical depth times the preset's `opacity_scale`.
pub fn shade_where(
    balls: &[Metaball],
    lattice: &Lattice,
    lighting: &Lighting,
    sheet: &SplatSheet,
    light_texel: f64,
    origin: [f64; 2],
    keep: impl Fn(&Metaball) -> bool,
) -> (Vec<Billboard>, LightBuffer) {
    let origin = [origin[0], origin[1], lattice.base];
    let r = lattice.radius;
    let extinction = lighting.params.extinction;
    let taus: Vec<f64> = balls
        .iter()
        .map(|b| ball_tau(b.density as f64, lattice, extinction))
        .collect();
    let (front_sun, sun_buffer) = sweep(balls, &taus, r, lighting.sun_dir, light_texel, origin);
    let (front_up, up_buffer) = sweep(balls, &taus, r, [0.0, 0.0, 1.0], light_texel, origin);
    let sun_up = lighting.sun_dir[2] > 0.0;
    let albedo = lighting.params.albedo.clamp(0.0, 1.0);
    let octaves = lighting.billboard.octaves;
    let opacity_scale = lighting.billboard.opacity_scale;
    let opacity_scale = if opacity_scale.is_finite() {
        opacity_scale.max(0.0)
    } else {
        1.0
    };
    let sun = lighting.sun_scatter();
    let out = balls
        .iter()
        .enumerate()
        .filter(|(_, b)| keep(b))
        .map(|(i, b)| {
            let tau = taus[i];
            let c = b.centre;
            // Capped so sums stay finite (e^−1e6 = 0 anyway).
            let tau_sun = (front_sun[i] + SELF_SHADOW * tau).min(1e6);
            let t_sun = (-tau_sun).exp().clamp(0.0, 1.0);
            let tau_up = front_up[i] + SELF_SHADOW * tau;
            let below = (up_buffer.tau_at(c) - front_up[i] - tau).max(0.0);
            let tau_down = below + SELF_SHADOW * tau;
            let ground_t = if sun_up {
                sun_buffer.transmittance_at([c[0], c[1], 0.0])
            } else {
                1.0
            };
            let ambient = lighting.ambient_source(
                lighting.sky_ambient_above,
                lighting.ground_below(ground_t),
                tau_up,
                tau_down,
            );
            let iso = octaves.isotropic_sum(tau_sun);
            let k = sheet.index_for_tau(opacity_scale * tau);
            let colour = [0, 1, 2].map(|ch| (albedo * (sun[ch] * iso + ambient[ch])).clamp(0.0, 2.0) as f32);
            Billboard {
                index: b.index,
                centre: c,
                radius: r as f32,
                density: b.density,
                tau: tau as f32,
                splat: k as u16,
                splat_tau: sheet.tau(k) as f32,
                opacity: (1.0 - (-sheet.tau(k)).exp()) as f32,
                tau_sun: tau_sun as f32,
                sun_transmittance: t_sun as f32,
                colour,
            }
        })
        .collect();
    (out, sun_buffer)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::light::ShadingParams;
    use crate::render::sun::Sun;

    fn column_of_balls(n: usize, density: f32) -> (Vec<Metaball>, Lattice) {
        let lat = Lattice::new(100.0, 150.0, 1000.0, 100.0 * n as f64);
        let balls = (0..n as i64)
            .map(|k| Metaball {
                index: [5, 5, k],
                centre: lat.centre(5, 5, k),
                density,
            })
            .collect();
        (balls, lat)
    }

    #[test]
    fn top_ball_is_brighter_than_bottom_under_high_sun() {
        let (balls, lat) = column_of_balls(6, 0.8);
        let l = Lighting::new(Sun::new(0.0, 89.0).unwrap(), ShadingParams::default());
        let sheet = SplatSheet::new(64, 17);
        let (bb, _) = shade(&balls, &lat, &l, &sheet, 0.3, [0.0, 0.0, 10_000.0, 10_000.0]);
        assert_eq!(bb.len(), 6);
        for w in bb.windows(2) {
            assert!(w[1].sun_transmittance > w[0].sun_transmittance, "{w:?}");
        }
        // The top ball sees only itself: exp(−κτ).
        let top = bb.last().unwrap();
        let expected = (-SELF_SHADOW * top.tau as f64).exp();
        assert!((top.sun_transmittance as f64 - expected).abs() < 1e-4);
        // The ball below sees its own half plus the ball above at the impact parameter
        // of their horizontal offset (odd levels are shifted by half a spacing in x and y).
        let second = bb[bb.len() - 2];
        let off = ((top.centre[0] - second.centre[0]).powi(2) + (top.centre[1] - second.centre[1]).powi(2)).sqrt();
        let front = top.tau as f64 * line_integral(off / 150.0) / centre_line_integral();
        let expected = (-(front + SELF_SHADOW * second.tau as f64)).exp();
        assert!(
            (second.sun_transmittance as f64 - expected).abs() < 0.02,
            "{} vs {expected}",
            second.sun_transmittance
        );
    }

    #[test]
    fn bases_are_darker_than_tops_in_sky_light() {
        // A tall column (12 balls, 1.2 km) lit by the sky and the ground only (no sun):
        // every ball is darker than the one above it, the base darker than the top.
        // At diffusion theory's attenuation (scale 1, every preset's fit).
        let (balls, lat) = column_of_balls(12, 0.6);
        let params = ShadingParams {
            sun_intensity: 0.0,
            light: Some(crate::render::light::BillboardLight {
                sky_extinction_scale: 1.0,
                ..crate::render::light::BillboardLight::default()
            }),
            ..ShadingParams::default()
        };
        let l = Lighting::new(Sun::new(0.0, 60.0).unwrap(), params);
        let sheet = SplatSheet::new(64, 17);
        let (bb, _) = shade(&balls, &lat, &l, &sheet, 0.3, [0.0, 0.0, 10_000.0, 10_000.0]);
        let lum = |b: &Billboard| b.colour.iter().map(|&c| c as f64).sum::<f64>();
        // The bottom may see the ground through less cloud than the one above it; from
        // the second ball up, brightness grows with height, and the top is the brightest.
        for w in bb[1..].windows(2) {
            assert!(lum(&w[1]) > lum(&w[0]), "{:?} vs {:?}", w[0].colour, w[1].colour);
        }
        assert!(lum(&bb[0]) < 0.8 * lum(bb.last().unwrap()));
        // The top ball's light is the closed form: half the sky through its own κτ,
        // half the ground (lit by the sun through the whole column: no sun here, so by
        // the sky alone) through the column below plus κτ.
        let top = bb.last().unwrap();
        let k = l.sky_extinction();
        let tau = top.tau as f64;
        let below: f64 = bb[..bb.len() - 1].iter().map(|b| b.tau as f64).sum();
        let ground = l.ground_below(1.0);
        #[allow(clippy::needless_range_loop)] // ch indexes three arrays and names the channel in the message
        for ch in 0..3 {
            let expected = l.params.albedo
                * (0.5 * l.sky_ambient_above[ch] * (-k * SELF_SHADOW * tau).exp()
                    + 0.5 * ground[ch] * (-k * (below + SELF_SHADOW * tau)).exp());
            // The balls below are offset by half a spacing on odd levels, so the column
            // the up-buffer sees under the top is within a factor of its sum.
            assert!(
                (top.colour[ch] as f64 - expected).abs() < 0.02,
                "{ch}: {} vs {expected}",
                top.colour[ch]
            );
        }
        // With the sun overhead as well, the top still outshines the base.
        let l = Lighting::new(Sun::new(0.0, 89.0).unwrap(), ShadingParams::default());
        let (bb, _) = shade(&balls, &lat, &l, &sheet, 0.3, [0.0, 0.0, 10_000.0, 10_000.0]);
        assert!(lum(&bb[0]) < 0.5 * lum(bb.last().unwrap()));
    }

    #[test]
    fn profile_table_matches_the_closed_form() {
        let t = profile_table();
        for i in 0..=1000 {
            let p = i as f64 / 1000.0;
            let exact = line_integral(p) / centre_line_integral();
            assert!((profile_at(t, p * p) - exact).abs() < 1e-5, "p={p}");
        }
    }

    #[test]
    fn self_shadow_constant_matches_quadrature() {
        // ∫ S(p)^k 2πp dp over [0, 1], midpoint rule.
        let n = 20_000;
        let (mut s1, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let p = (i as f64 + 0.5) / n as f64;
            let s = line_integral(p);
            s1 += s * p;
            s2 += s * s * p;
        }
        let kappa = s2 / (2.0 * centre_line_integral() * s1);
        assert!((kappa - SELF_SHADOW).abs() < 1e-4, "{kappa}");
        // ∫S dA is the volume integral of the field function.
        let vol = s1 * 2.0 * std::f64::consts::PI / n as f64;
        assert!((vol - crate::density::metaballs::wyvill_volume_integral()).abs() < 1e-6);
    }

    #[test]
    fn extremes_give_finite_bounded_values() {
        let sheet = SplatSheet::new(16, 9);
        for density in [0.0f32, 1e-9, 1.0] {
            for extinction in [0.0, 0.01, 1e6, f64::INFINITY] {
                for el in [-90.0, -1.0, 0.0, 0.0001, 45.0, 90.0] {
                    for g in [-1.0, 0.0, 1.0] {
                        let (balls, lat) = column_of_balls(4, density);
                        let params = ShadingParams {
                            extinction,
                            phase: crate::render::light::Phase {
                                g1: g,
                                g2: -g,
                                mix: 0.5,
                            },
                            ..ShadingParams::default()
                        };
                        let l = Lighting::new(Sun::new(30.0, el).unwrap(), params);
                        let (bb, buf) = shade(&balls, &lat, &l, &sheet, 0.3, [0.0, 0.0, 1e4, 1e4]);
                        for b in &bb {
                            assert!(b.tau.is_finite() && b.tau >= 0.0);
                            assert!((0.0..=1.0).contains(&b.sun_transmittance));
                            assert!((0.0..1.0).contains(&b.opacity));
                            assert!(b.colour.iter().all(|c| c.is_finite() && (0.0..=2.0).contains(c)));
                        }
                        let t = buf.transmittance_at([550.0, 550.0, 0.0]);
                        assert!(t.is_finite() && (0.0..=1.0).contains(&t));
                    }
                }
            }
        }
    }
}
