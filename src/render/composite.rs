//! The billboard compositor: draws shaded metaballs the way a game client would —
//! camera-facing quads textured with their splat, sorted back to front and blended
//! with `over` (premultiplied: `C = α·c + (1 − α)·C`).
//!
//! Each billboard's colour is `albedo · (sun · T · p(cos θ) + ambient)` with the
//! pre-computed sun transmittance `T` and the phase function evaluated for the
//! direction from the eye to the billboard's centre. The opacity is the splat's.
//! Because every splat's opacity is `1 − exp(−τ S(p)/S(0))`, the product of
//! `(1 − α)` along a pixel is exactly the Beer–Lambert transmittance of the metaball
//! field: the compositor and the ray marcher agree on coverage by construction.

use rayon::prelude::*;

use super::camera::View;
use super::image::Image;
use super::light::Lighting;
use super::shade::Billboard;
use super::splats::SplatSheet;

/// Rows per band drawn in parallel; each band is drawn independently, so the result
/// does not depend on the thread count.
const BAND_ROWS: usize = 16;

/// Billboards nearer than this fraction of their radius to the eye are skipped
/// (the near clip: the eye is inside them).
const NEAR_CLIP_RADII: f64 = 0.5;

/// Draws `billboards` over `image` (which holds the background, premultiplied).
pub fn composite(image: &mut Image, billboards: &[Billboard], sheet: &SplatSheet, lighting: &Lighting, view: &View) {
    struct Item {
        dist: f64,
        x: f64,
        y: f64,
        r_px: f64,
        colour: [f64; 3],
        splat: usize,
    }
    let mut items: Vec<Item> = billboards
        .iter()
        .filter_map(|b| {
            let p = view.project(b.centre)?;
            let r = b.radius as f64;
            if p.depth < NEAR_CLIP_RADII * r && matches!(view.kind, super::camera::ViewKind::Perspective { .. }) {
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
                dist: view.sort_distance(b.centre),
                x: p.x,
                y: p.y,
                r_px,
                colour,
                splat: b.splat as usize,
            })
        })
        .collect();
    // Back to front; a stable sort keeps the input order for equal distances.
    items.sort_by(|a, b| b.dist.total_cmp(&a.dist));

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
        for it in &items {
            let top = ((it.y - it.r_px - 0.5).floor().max(y0 as f64)) as usize;
            let bottom = ((it.y + it.r_px + 0.5).ceil().min(y1 as f64)) as usize;
            if top >= bottom {
                continue;
            }
            let left = ((it.x - it.r_px - 0.5).floor().max(0.0)) as usize;
            let right = ((it.x + it.r_px + 0.5).ceil().min(width as f64)) as usize;
            for py in top..bottom {
                let dy = (py as f64 + 0.5 - it.y) / it.r_px;
                for px in left..right {
                    let dx = (px as f64 + 0.5 - it.x) / it.r_px;
                    let a = sheet.sample(it.splat, dx, dy);
                    if a <= 0.0 {
                        continue;
                    }
                    let i = (py - y0) * width + px;
                    let c = &mut rgb[i];
                    for ch in 0..3 {
                        c[ch] = (a * it.colour[ch] + (1.0 - a) * c[ch] as f64) as f32;
                    }
                    alpha[i] = (a + (1.0 - a) * alpha[i] as f64) as f32;
                }
            }
        }
    });
}
