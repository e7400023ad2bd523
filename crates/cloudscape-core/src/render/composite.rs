//! The billboard compositor: draws shaded metaballs the way a game client would —
//! camera-facing quads textured with their splat, sorted by distance and blended with
//! `over` (premultiplied: `C = α·c + (1 − α)·C`, back to front).
//!
//! Because `over` is associative, the compositor walks the same sorted list front to
//! back with the equivalent `under` operator (`C += (1 − A)·α·c`, `A += (1 − A)·α`)
//! and adds the background last: the same picture as back-to-front blending, except
//! that a pixel stops taking billboards once its transmittance `1 − A` is below
//! [`OPAQUE_TRANSMITTANCE`] (what it skips is at most that fraction of a colour), and a
//! billboard whose footprint is all opaque is skipped whole. That keeps the cost of
//! the overdraw of dense decks bounded.
//!
//! Each billboard's colour is its pre-shaded (isotropic) colour plus
//! [`Lighting::phase_correction`] of its sun optical depth: the scattering octaves
//! with the phase function evaluated for the direction from the eye to the
//! billboard's centre (see `render::light::Octaves`).
//!
//! The opacity is the splat's profile evaluated at each pixel, `α = 1 − exp(−τ_k ·
//! S(p)/S(0))` with `τ_k` the centre optical depth of splat `k` of the preset's sheet
//! and `p` the impact parameter: sampled once per pixel whatever the billboard's size
//! on screen (no texture to magnify, so near billboards stay as sharp as the field
//! itself). Because of that form, the product of `(1 − α)` along a pixel is the
//! Beer–Lambert transmittance of the metaball field: the compositor and the ray
//! marcher agree on coverage by construction.
//!
//! **Detail erosion** (`render::detail`): after the billboards, each pixel's
//! accumulated opacity `A` (the smooth field's coverage) is eroded by Nubis's remap,
//! `A' = erode(A, E · n)`, and its colour scaled by `A'/A`, with
//! `E` = the preset's `BillboardLight::detail_erosion` ([`super::Quality::light`])
//! and `n = Σ_k w_k n_k / Σ_k w_k` the opacity-weighted mean over the billboards the
//! pixel took (`w_k = (1 − A)·α_k`) of
//! the detail noise `n_k` at the pixel's point on billboard `k`'s plane (first
//! octave one radius of `k`, octaves limited by `k`'s pixel footprint; `n_k = 0`,
//! no erosion, where not even the first octave spans the footprint). Each `n_k` is
//! smooth across the screen, so their mean is too; the noise at the mean *point*
//! is not: where near and far billboards overlap, that point sweeps along the view
//! ray through many wavelengths within a few pixels and draws contour ripples.
//! Eroding the sum rather than each ball keeps the lattice invisible (eroding each
//! ball's rim opens gaps between neighbours), eats thin edges into cauliflower and
//! leaves opaque cores alone. It only removes opacity.
//!
//! Billboards are seen through the air between the eye and their centre (aerial
//! perspective, `c · T_air + L_in`, [`Lighting::hazed`]; not in orthographic views,
//! the impostors, which a client hazes by their own distance).
//!
//! A ball within `AROUND_EYE_RADII` of the eye is not a quad: its field is integrated
//! along each pixel's ray over the part of the chord in front of the eye (closed form,
//! [`line_integral_beyond`]), and shaded for that ray's direction. Inside a cloud layer
//! that is fog, thicker toward nearby ball centres, with the same opacity as the ray
//! marcher sees through the same field.

use rayon::prelude::*;

use crate::cancel::Cancel;

use super::camera::{View, ViewKind};
use super::detail;
use super::image::Image;
use super::light::Lighting;
use super::shade::{Billboard, profile_at, profile_table};
use super::splats::{centre_line_integral, line_integral_beyond};

/// Rows per band drawn in parallel; each band is drawn independently, so the result
/// does not depend on the thread count.
const BAND_ROWS: usize = 16;

/// A pixel whose remaining transmittance is below this takes no more billboards.
pub const OPAQUE_TRANSMITTANCE: f64 = 1e-3;

/// Columns per block of the per-band opacity map used to skip hidden billboards.
const BLOCK_COLUMNS: usize = 8;

/// Billboards nearer than this fraction of their radius to the eye along the view
/// axis, but not [`AROUND_EYE_RADII`] near, are skipped: they lie beside the eye, out
/// of view, where a projected quad would be meaningless.
const NEAR_CLIP_RADII: f64 = 0.5;

/// A ball whose centre is within this many radii of the eye (perspective views) is
/// not drawn as a projected splat but integrated along every pixel's ray: only the
/// chord in front of the eye counts ([`line_integral_beyond`]), so a ball around the
/// eye is fog in every direction, thicker toward its centre, and a ball just beside
/// the eye covers the solid angle it really covers. A projected splat would be the
/// whole chord on a quad around the centre's projection, or nothing once the centre
/// is behind the eye: a blank frame or a hole inside a cloud layer.
const AROUND_EYE_RADII: f64 = 2.0;

/// A billboard as the compositor draws it: where it lands, its colour for this view,
/// and what its per-pixel opacity needs.
pub struct Footprint {
    /// Sort distance from the eye.
    pub dist: f64,
    /// Centre on screen and radius, pixels.
    pub x: f64,
    /// Centre y on screen, pixels.
    pub y: f64,
    /// Radius on screen, pixels.
    pub r_px: f64,
    /// Radiance for this view (pre-shaded colour plus the phase correction).
    pub colour: [f64; 3],
    /// Centre optical depth of the billboard's splat.
    tau: f64,
    centre: [f64; 3],
    radius: f64,
    /// Octaves of detail noise the billboard's pixel footprint carries.
    detail_octaves: u32,
    /// The view's screen axes in the world (the billboard's plane).
    right: [f64; 3],
    up: [f64; 3],
}

impl Footprint {
    /// The footprint of `b` in `view`, or `None` when it is off screen or behind the
    /// near clip.
    pub fn new(b: &Billboard, lighting: &Lighting, view: &View) -> Option<Footprint> {
        let p = view.project(b.centre)?;
        let r = b.radius as f64;
        if p.depth < NEAR_CLIP_RADII * r && matches!(view.kind, ViewKind::Perspective { .. }) {
            return None;
        }
        let r_px = r * p.scale;
        if !(r_px.is_finite() && r_px > 0.0) {
            return None;
        }
        let (w, h) = (view.width as f64, view.height as f64);
        if p.x + r_px < 0.0 || p.y + r_px < 0.0 || p.x - r_px > w || p.y - r_px > h {
            return None;
        }
        let dir = view.direction_to(b.centre);
        let corr = lighting.phase_correction(b.tau_sun as f64, dir);
        let colour = [0, 1, 2].map(|i| (b.colour[i] as f64 + corr[i]).max(0.0));
        // Orthographic views (impostors) have no eye: the client hazes them.
        let colour = match view.kind {
            ViewKind::Perspective { .. } => lighting.hazed(colour, view.origin, b.centre),
            ViewKind::Orthographic { .. } => colour,
        };
        Some(Footprint {
            dist: view.sort_distance(b.centre),
            x: p.x,
            y: p.y,
            r_px,
            colour,
            tau: b.splat_tau as f64,
            centre: b.centre,
            radius: r,
            detail_octaves: detail::octaves_for(r, 1.0 / p.scale),
            right: view.right,
            up: view.up,
        })
    }

    /// Opacity at (`dx`, `dy`) radii from the centre (screen axes, y down); 0 outside.
    pub fn alpha(&self, dx: f64, dy: f64) -> f64 {
        let q = dx * dx + dy * dy;
        if !(q < 1.0) {
            return 0.0;
        }
        1.0 - (-self.tau * profile_at(profile_table(), q)).exp()
    }

    /// The world point at (`dx`, `dy`) radii from the centre on the billboard's plane.
    pub fn point(&self, dx: f64, dy: f64) -> [f64; 3] {
        let (a, b) = (dx * self.radius, -dy * self.radius);
        [0, 1, 2].map(|i| self.centre[i] + a * self.right[i] + b * self.up[i])
    }
}

/// What the detail erosion of a pixel needs, accumulated over the splats it takes
/// with their weights `w = (1 − A)·α`: Σ w·n_k and Σ w (balls around the eye are
/// fog, not edges: they add nothing here).
type Where = [f64; 2];

/// The eroded opacity of a pixel of accumulated opacity `a` and accumulated
/// [`Where`] `at`, for erosion strength `strength` (see the module docs).
fn eroded(a: f64, at: &Where, strength: f64) -> f64 {
    let w = at[1];
    if !(a > 0.0) || !(w > 0.0) || strength <= 0.0 {
        return a;
    }
    detail::erode(a, strength * at[0] / w)
}

/// Draws `billboards` over `image` (which holds the background, premultiplied).
pub fn composite(image: &mut Image, billboards: &[Billboard], lighting: &Lighting, view: &View) {
    composite_cancellable(image, billboards, lighting, view, &Cancel::never());
}

/// [`composite`] that leaves the remaining bands undrawn once `cancel` fires (the
/// caller then discards the image).
pub fn composite_cancellable(
    image: &mut Image,
    billboards: &[Billboard],
    lighting: &Lighting,
    view: &View,
    cancel: &Cancel,
) {
    /// How a billboard covers the screen.
    enum Draw {
        /// A splat around its projected centre.
        Splat(Footprint),
        /// A ball near the eye, integrated along each pixel's ray: centre, radius
        /// (metres), the splat's centre optical depth, its pre-shaded colour and sun
        /// optical depth (the phase correction is per ray).
        AroundEye {
            centre: [f64; 3],
            radius: f64,
            tau: f64,
            colour: [f64; 3],
            tau_sun: f64,
        },
    }
    struct Item {
        dist: f64,
        draw: Draw,
    }
    let perspective = matches!(view.kind, ViewKind::Perspective { .. });
    let items: Vec<Item> = billboards
        .iter()
        .filter_map(|b| {
            let r = b.radius as f64;
            let dist = view.sort_distance(b.centre);
            if perspective && dist < AROUND_EYE_RADII * r {
                if !(r > 0.0 && dist.is_finite()) {
                    return None;
                }
                return Some(Item {
                    dist,
                    draw: Draw::AroundEye {
                        centre: b.centre,
                        radius: r,
                        tau: b.splat_tau as f64,
                        colour: b.colour.map(|c| c as f64),
                        tau_sun: b.tau_sun as f64,
                    },
                });
            }
            let f = Footprint::new(b, lighting, view)?;
            Some(Item {
                dist: f.dist,
                draw: Draw::Splat(f),
            })
        })
        .collect();
    let s0 = centre_line_integral();
    // Front to back, the exact reverse of a stable back-to-front sort (which keeps the
    // input order for equal distances).
    let mut order: Vec<usize> = (0..items.len()).collect();
    order.sort_by(|&a, &b| items[a].dist.total_cmp(&items[b].dist).then(b.cmp(&a)));
    let items: Vec<&Item> = order.iter().map(|&i| &items[i]).collect();

    let erosion = lighting.billboard.detail_erosion;
    let erosion = if erosion.is_finite() {
        erosion.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let width = image.width;
    let bands: Vec<(usize, usize)> = (0..image.height)
        .step_by(BAND_ROWS)
        .map(|y0| (y0, (y0 + BAND_ROWS).min(image.height)))
        .collect();
    let mut rgb_chunks: Vec<&mut [[f32; 3]]> = image.rgb.chunks_mut(BAND_ROWS * width).collect();
    let mut a_chunks: Vec<&mut [f32]> = image.alpha.chunks_mut(BAND_ROWS * width).collect();
    let work: Vec<_> = bands
        .into_iter()
        .zip(rgb_chunks.drain(..).zip(a_chunks.drain(..)))
        .collect();
    let any_around_eye = items.iter().any(|it| matches!(it.draw, Draw::AroundEye { .. }));
    work.into_par_iter().for_each(|((y0, y1), (rgb, alpha))| {
        if cancel.is_fired() {
            return;
        }
        let n = (y1 - y0) * width;
        let mut acc = vec![[0.0f64; 3]; n];
        let mut acc_a = vec![0.0f64; n];
        let mut acc_at: Vec<Where> = vec![[0.0; 2]; if erosion > 0.0 { n } else { 0 }];
        let blocks = width.div_ceil(BLOCK_COLUMNS);
        // Pixels of each block (over the band's rows) not yet opaque.
        let mut open: Vec<usize> = (0..blocks)
            .map(|b| ((b + 1) * BLOCK_COLUMNS).min(width) - b * BLOCK_COLUMNS)
            .map(|w| w * (y1 - y0))
            .collect();
        // Ray directions of the band's pixels, for balls around the eye.
        let rays: Vec<[f64; 3]> = if any_around_eye {
            (y0..y1)
                .flat_map(|py| (0..width).map(move |px| view.ray(px as f64 + 0.5, py as f64 + 0.5).1))
                .collect()
        } else {
            Vec::new()
        };
        for it in &items {
            match &it.draw {
                Draw::Splat(f) => {
                    let (x, y, r_px) = (f.x, f.y, f.r_px);
                    let top = ((y - r_px - 0.5).floor().max(y0 as f64)) as usize;
                    let bottom = ((y + r_px + 0.5).ceil().min(y1 as f64)) as usize;
                    if top >= bottom {
                        continue;
                    }
                    let left = ((x - r_px - 0.5).floor().max(0.0)) as usize;
                    let right = ((x + r_px + 0.5).ceil().min(width as f64)) as usize;
                    if left >= right || (left / BLOCK_COLUMNS..=(right - 1) / BLOCK_COLUMNS).all(|b| open[b] == 0) {
                        continue;
                    }
                    for py in top..bottom {
                        let dy = (py as f64 + 0.5 - y) / r_px;
                        for px in left..right {
                            let i = (py - y0) * width + px;
                            if 1.0 - acc_a[i] < OPAQUE_TRANSMITTANCE {
                                continue;
                            }
                            let dx = (px as f64 + 0.5 - x) / r_px;
                            let a = f.alpha(dx, dy);
                            if a <= 0.0 {
                                continue;
                            }
                            let w = (1.0 - acc_a[i]) * a;
                            if erosion > 0.0 {
                                let n = if f.detail_octaves > 0 {
                                    detail::noise(f.point(dx, dy), f.radius, f.detail_octaves)
                                } else {
                                    0.0
                                };
                                acc_at[i][0] += w * n;
                                acc_at[i][1] += w;
                            }
                            take(&mut acc[i], &mut acc_a[i], &mut open[px / BLOCK_COLUMNS], a, f.colour);
                        }
                    }
                }
                &Draw::AroundEye {
                    centre,
                    radius,
                    tau,
                    colour,
                    tau_sun,
                } => {
                    if open.iter().all(|&o| o == 0) {
                        continue;
                    }
                    // The centre relative to the eye, in radii.
                    let w = [0, 1, 2].map(|c| (centre[c] - view.origin[c]) / radius);
                    let ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
                    for (i, u) in rays.iter().enumerate() {
                        if 1.0 - acc_a[i] < OPAQUE_TRANSMITTANCE {
                            continue;
                        }
                        // Along the ray the closest approach is at s_c radii; the eye
                        // is at v = −s_c from it, so the chord in front is v >= −s_c.
                        let s_c = w[0] * u[0] + w[1] * u[1] + w[2] * u[2];
                        let p2 = (ww - s_c * s_c).max(0.0);
                        if !(p2 < 1.0) {
                            continue;
                        }
                        let a = 1.0 - (-tau * line_integral_beyond(p2.sqrt(), -s_c) / s0).exp();
                        if a > 0.0 {
                            let corr = lighting.phase_correction(tau_sun, *u);
                            let c = [0, 1, 2].map(|k| (colour[k] + corr[k]).max(0.0));
                            take(&mut acc[i], &mut acc_a[i], &mut open[(i % width) / BLOCK_COLUMNS], a, c);
                        }
                    }
                }
            }
        }
        // Detail erosion of the accumulated opacity, then the background (already in
        // the image) under everything.
        for i in 0..n {
            if erosion > 0.0 && acc_a[i] > 0.0 {
                let a = eroded(acc_a[i], &acc_at[i], erosion);
                let k = a / acc_a[i];
                for c in acc[i].iter_mut() {
                    *c *= k;
                }
                acc_a[i] = a;
            }
            let t = 1.0 - acc_a[i];
            for ch in 0..3 {
                rgb[i][ch] = (acc[i][ch] + t * rgb[i][ch] as f64) as f32;
            }
            alpha[i] = (acc_a[i] + t * alpha[i] as f64) as f32;
        }
    });
}

/// The `under` operator for one pixel: a layer of opacity `a` and colour `colour`
/// behind what the pixel holds (`C += (1 − A)·a·c`, `A += (1 − A)·a`); closes the
/// pixel in its block's count when it turns opaque.
#[inline]
fn take(acc: &mut [f64; 3], acc_a: &mut f64, open: &mut usize, a: f64, colour: [f64; 3]) {
    let w = (1.0 - *acc_a) * a;
    for ch in 0..3 {
        acc[ch] += w * colour[ch];
    }
    *acc_a += w;
    if 1.0 - *acc_a < OPAQUE_TRANSMITTANCE {
        *open -= 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::camera::Camera;
    use crate::render::light::{BillboardLight, ShadingParams};
    use crate::render::splats::SplatSheet;
    use crate::render::sun::Sun;

    /// The textbook client: sort back to front, blend each billboard `over`.
    fn back_to_front(image: &mut Image, bbs: &[Billboard], lighting: &Lighting, view: &View) {
        let mut sorted: Vec<&Billboard> = bbs.iter().collect();
        sorted.sort_by(|a, b| view.sort_distance(b.centre).total_cmp(&view.sort_distance(a.centre)));
        for b in sorted {
            let Some(f) = Footprint::new(b, lighting, view) else {
                continue;
            };
            let colour = f.colour;
            for py in 0..view.height {
                for px in 0..view.width {
                    let a = f.alpha((px as f64 + 0.5 - f.x) / f.r_px, (py as f64 + 0.5 - f.y) / f.r_px);
                    let i = py * view.width + px;
                    for (out, &c) in image.rgb[i].iter_mut().zip(&colour) {
                        *out = (a * c + (1.0 - a) * *out as f64) as f32;
                    }
                    image.alpha[i] = (a + (1.0 - a) * image.alpha[i] as f64) as f32;
                }
            }
        }
    }

    #[test]
    fn detail_erosion_only_removes_opacity_and_bites_edges() {
        let sheet = SplatSheet::new(64, 17);
        let view = View::perspective(&Camera::parse("0,0,1000,0,0,60").unwrap(), 96, 64);
        // A row of overlapping balls 3 km ahead: a soft-edged cloud filling the middle.
        let bbs: Vec<Billboard> = (0..12)
            .map(|i| Billboard {
                index: [i, 0, 0],
                centre: [-1100.0 + 200.0 * i as f64, 3000.0, 1000.0],
                radius: 300.0,
                density: 0.5,
                tau: 2.0,
                splat: 63,
                splat_tau: sheet.tau(63) as f32,
                opacity: 0.9,
                tau_sun: 1.0,
                sun_transmittance: (-1.0f32).exp(),
                colour: [0.6; 3],
            })
            .collect();
        let draw = |erosion: f64| {
            let params = ShadingParams {
                light: Some(BillboardLight {
                    detail_erosion: erosion,
                    ..BillboardLight::default()
                }),
                ..ShadingParams::default()
            };
            let lighting = Lighting::new(Sun::new(100.0, 30.0).unwrap(), params);
            let mut img = Image::new(96, 64);
            img.alpha.iter_mut().for_each(|a| *a = 0.0);
            composite(&mut img, &bbs, &lighting, &view);
            img
        };
        let (smooth, eroded) = (draw(0.0), draw(0.8));
        let mut bitten = 0;
        for (i, (&a, &b)) in smooth.alpha.iter().zip(&eroded.alpha).enumerate() {
            assert!(b <= a + 1e-6, "pixel {i}: {b} > {a}");
            if a > 0.05 && a < 0.9 && b < 0.8 * a {
                bitten += 1;
            }
            // The colour is scaled with the opacity (premultiplied), never brightened.
            for ch in 0..3 {
                assert!(eroded.rgb[i][ch] <= smooth.rgb[i][ch] + 1e-6);
            }
        }
        assert!(bitten > 20, "only {bitten} edge pixels eroded");
        // Opaque cores are left alone.
        let core = smooth.alpha.iter().zip(&eroded.alpha).filter(|(a, _)| **a > 0.999);
        assert!(core.clone().count() > 0 && core.clone().all(|(a, b)| (a - b).abs() < 1e-3));
    }

    #[test]
    fn front_to_back_equals_back_to_front_over() {
        let sheet = SplatSheet::new(64, 17);
        // The textbook client has no detail erosion (tested on its own below).
        let params = ShadingParams {
            light: Some(BillboardLight {
                detail_erosion: 0.0,
                ..BillboardLight::default()
            }),
            ..ShadingParams::default()
        };
        let lighting = Lighting::new(Sun::new(100.0, 30.0).unwrap(), params);
        let view = View::perspective(&Camera::parse("0,0,0,0,10,60").unwrap(), 40, 30);
        // A pseudo-random cloud of billboards in front of the camera, some dense.
        let bbs: Vec<Billboard> = (0..300u64)
            .map(|i| {
                let h = |k: u64| ((i * 7919 + k * 104_729) % 1000) as f64 / 1000.0;
                let splat = (h(5) * 63.0) as u16;
                Billboard {
                    index: [i as i64, 0, 0],
                    centre: [h(1) * 2000.0 - 1000.0, 1500.0 + h(2) * 3000.0, h(3) * 1200.0],
                    radius: 150.0 + 200.0 * h(4) as f32,
                    density: 0.5,
                    tau: 1.0,
                    splat,
                    splat_tau: sheet.tau(splat as usize) as f32,
                    opacity: 0.5,
                    tau_sun: -(h(6) as f32).max(1e-6).ln(),
                    sun_transmittance: h(6) as f32,
                    colour: [0.5; 3],
                }
            })
            .collect();
        let background = |img: &mut Image| {
            for (i, c) in img.rgb.iter_mut().enumerate() {
                *c = [0.2, 0.3, (i % 7) as f32 / 7.0];
            }
            // Alpha 0 so the final alpha is the billboards' own coverage.
            img.alpha.iter_mut().for_each(|a| *a = 0.0);
        };
        let (mut fast, mut naive) = (Image::new(40, 30), Image::new(40, 30));
        background(&mut fast);
        background(&mut naive);
        composite(&mut fast, &bbs, &lighting, &view);
        back_to_front(&mut naive, &bbs, &lighting, &view);
        let mut max = 0.0f32;
        for (a, b) in fast.rgb.iter().zip(&naive.rgb) {
            for ch in 0..3 {
                max = max.max((a[ch] - b[ch]).abs());
            }
        }
        // Skipped contributions are below OPAQUE_TRANSMITTANCE × the brightest colour (~1.5).
        assert!(max < 2e-3, "{max}");
        // The scene is dense enough that some pixels are opaque (the early exit is exercised).
        assert!(fast.alpha.iter().any(|&a| a > 0.999), "no opaque pixel");
    }
}
