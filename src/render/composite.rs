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
//! Each billboard's colour is `albedo · (sun · T · p(cos θ) + ambient)` with the
//! pre-computed sun transmittance `T` and the phase function evaluated for the
//! direction from the eye to the billboard's centre. The opacity is the splat's.
//! Because every splat's opacity is `1 − exp(−τ S(p)/S(0))`, the product of
//! `(1 − α)` along a pixel is exactly the Beer–Lambert transmittance of the metaball
//! field: the compositor and the ray marcher agree on coverage by construction.
//!
//! A ball within [`AROUND_EYE_RADII`] of the eye is not a quad: its field is integrated
//! along each pixel's ray over the part of the chord in front of the eye (closed form,
//! [`line_integral_beyond`]), and shaded for that ray's direction. Inside a cloud layer
//! that is fog, thicker toward nearby ball centres, with the same opacity as the ray
//! marcher sees through the same field.

use rayon::prelude::*;

use super::camera::View;
use super::image::Image;
use super::light::Lighting;
use super::shade::Billboard;
use super::splats::{SplatSheet, centre_line_integral, line_integral_beyond};

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

/// Draws `billboards` over `image` (which holds the background, premultiplied).
pub fn composite(image: &mut Image, billboards: &[Billboard], sheet: &SplatSheet, lighting: &Lighting, view: &View) {
    /// How a billboard covers the screen.
    enum Footprint {
        /// A splat on a quad of `r_px` pixels around its projected centre, shaded
        /// for the direction from the eye to the centre.
        Splat { x: f64, y: f64, r_px: f64, splat: usize, colour: [f64; 3] },
        /// A ball near the eye, integrated along each pixel's ray: centre, radius
        /// (metres), the splat's centre optical depth and the sun transmittance.
        AroundEye { centre: [f64; 3], radius: f64, tau: f64, sun_transmittance: f64 },
    }
    struct Item {
        dist: f64,
        footprint: Footprint,
    }
    let perspective = matches!(view.kind, super::camera::ViewKind::Perspective { .. });
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
                    footprint: Footprint::AroundEye {
                        centre: b.centre,
                        radius: r,
                        tau: sheet.tau(b.splat as usize),
                        sun_transmittance: b.sun_transmittance as f64,
                    },
                });
            }
            let p = view.project(b.centre)?;
            if p.depth < NEAR_CLIP_RADII * r && perspective {
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
            let colour = lighting.cloud_source(b.sun_transmittance as f64, dir);
            Some(Item {
                dist,
                footprint: Footprint::Splat {
                    x: p.x,
                    y: p.y,
                    r_px,
                    splat: b.splat as usize,
                    colour,
                },
            })
        })
        .collect();
    let s0 = centre_line_integral();
    // Front to back, the exact reverse of a stable back-to-front sort (which keeps the
    // input order for equal distances).
    let mut order: Vec<usize> = (0..items.len()).collect();
    order.sort_by(|&a, &b| items[a].dist.total_cmp(&items[b].dist).then(b.cmp(&a)));
    let items: Vec<&Item> = order.iter().map(|&i| &items[i]).collect();

    let width = image.width;
    let bands: Vec<(usize, usize)> = (0..image.height)
        .step_by(BAND_ROWS)
        .map(|y0| (y0, (y0 + BAND_ROWS).min(image.height)))
        .collect();
    let mut rgb_chunks: Vec<&mut [[f32; 3]]> = image.rgb.chunks_mut(BAND_ROWS * width).collect();
    let mut a_chunks: Vec<&mut [f32]> = image.alpha.chunks_mut(BAND_ROWS * width).collect();
    let work: Vec<((usize, usize), (&mut [[f32; 3]], &mut [f32]))> = bands
        .into_iter()
        .zip(rgb_chunks.drain(..).zip(a_chunks.drain(..)))
        .collect();
    work.into_par_iter().for_each(|((y0, y1), (rgb, alpha))| {
        let n = (y1 - y0) * width;
        let mut acc = vec![[0.0f64; 3]; n];
        let mut acc_a = vec![0.0f64; n];
        let blocks = width.div_ceil(BLOCK_COLUMNS);
        // Pixels of each block (over the band's rows) not yet opaque.
        let mut open: Vec<usize> = (0..blocks)
            .map(|b| ((b + 1) * BLOCK_COLUMNS).min(width) - b * BLOCK_COLUMNS)
            .map(|w| w * (y1 - y0))
            .collect();
        // Ray directions of the band's pixels, for balls around the eye.
        let rays: Vec<[f64; 3]> = if items.iter().any(|it| matches!(it.footprint, Footprint::AroundEye { .. })) {
            (y0..y1)
                .flat_map(|py| (0..width).map(move |px| view.ray(px as f64 + 0.5, py as f64 + 0.5).1))
                .collect()
        } else {
            Vec::new()
        };
        for it in &items {
            match it.footprint {
                Footprint::Splat { x, y, r_px, splat, colour } => {
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
                            let a = sheet.sample(splat, dx, dy);
                            if a > 0.0 {
                                take(&mut acc[i], &mut acc_a[i], &mut open[px / BLOCK_COLUMNS], a, colour);
                            }
                        }
                    }
                }
                Footprint::AroundEye { centre, radius, tau, sun_transmittance } => {
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
                            let colour = lighting.cloud_source(sun_transmittance, *u);
                            take(&mut acc[i], &mut acc_a[i], &mut open[(i % width) / BLOCK_COLUMNS], a, colour);
                        }
                    }
                }
            }
        }
        // The background (already in the image) goes under everything.
        for i in 0..n {
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
    use crate::render::light::ShadingParams;
    use crate::render::sun::Sun;

    /// The textbook client: sort back to front, blend each billboard `over`.
    fn back_to_front(image: &mut Image, bbs: &[Billboard], sheet: &SplatSheet, lighting: &Lighting, view: &View) {
        let mut sorted: Vec<&Billboard> = bbs.iter().collect();
        sorted.sort_by(|a, b| view.sort_distance(b.centre).total_cmp(&view.sort_distance(a.centre)));
        for b in sorted {
            let Some(p) = view.project(b.centre) else { continue };
            let r_px = b.radius as f64 * p.scale;
            let colour = lighting.cloud_source(b.sun_transmittance as f64, view.direction_to(b.centre));
            for py in 0..view.height {
                for px in 0..view.width {
                    let a = sheet.sample(
                        b.splat as usize,
                        (px as f64 + 0.5 - p.x) / r_px,
                        (py as f64 + 0.5 - p.y) / r_px,
                    );
                    let i = py * view.width + px;
                    for ch in 0..3 {
                        image.rgb[i][ch] = (a * colour[ch] + (1.0 - a) * image.rgb[i][ch] as f64) as f32;
                    }
                    image.alpha[i] = (a + (1.0 - a) * image.alpha[i] as f64) as f32;
                }
            }
        }
    }

    #[test]
    fn front_to_back_equals_back_to_front_over() {
        let sheet = SplatSheet::new(64, 17);
        let lighting = Lighting::new(Sun::new(100.0, 30.0).unwrap(), ShadingParams::default());
        let view = View::perspective(&Camera::parse("0,0,0,0,10,60").unwrap(), 40, 30);
        // A pseudo-random cloud of billboards in front of the camera, some dense.
        let bbs: Vec<Billboard> = (0..300u64)
            .map(|i| {
                let h = |k: u64| ((i * 7919 + k * 104_729) % 1000) as f64 / 1000.0;
                Billboard {
                    centre: [h(1) * 2000.0 - 1000.0, 1500.0 + h(2) * 3000.0, h(3) * 1200.0],
                    radius: 150.0 + 200.0 * h(4) as f32,
                    density: 0.5,
                    tau: 1.0,
                    splat: (h(5) * 63.0) as u16,
                    opacity: 0.5,
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
        composite(&mut fast, &bbs, &sheet, &lighting, &view);
        back_to_front(&mut naive, &bbs, &sheet, &lighting, &view);
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
