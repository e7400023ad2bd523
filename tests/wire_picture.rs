//! The same picture from the new wire format (issue 38): a gallery view drawn from
//! `billboards.bin` version 3 (quantised states, ground shadows derived from the
//! billboards) against the same view drawn from version 2 (full-precision records,
//! the served `shadow.png` maps), both through `view::held` as clients draw them, at
//! `fast` and `balanced`, mid-span (the animation rule at work).
//!
//! The bounds: the quantisation alone keeps every displayed channel within 3/255
//! (PSNR ≥ 50 dB), and the whole new picture, derived shadows included, stays
//! ≥ 44.5 dB from the old. The error is computed here, on the 8-bit display values,
//! independently of the bench's. Under another layer a billboard is split into its sun
//! and ambient parts by its `τ_sun` when drawn (`view::held::beneath_layers`), and the
//! sun ray takes the whole depth of the layers above (`LAYERS_ABOVE_SUN_DEPTH` = 1):
//! under a deck the drawn colour is mostly the ambient. Since ALGORITHM_VERSION 15 the
//! colour codes carry that ambient (docs/formats.md "Ambient codes"), so it keeps one
//! step's precision (measured: 2–3/255, 56–57 dB; with the whole colour on the codes
//! it was 4–5/255, 48.4–55.6 dB). The derived shadows' bound is 44.5 dB: the backlit
//! low sun's long, stretched shadows (measured 44.9 dB at `balanced`).
use cloudscape_core::products::keyframe_bin::Quantisation;
use cloudscape_core::render::image::{Image, to_u8};
use cloudscape_core::render::scene::{RenderRequest, prepare};
use cloudscape_core::render::{Camera, Quality, ShadingParams, Sun};
use cloudscape_core::view::{held, held_tiles, held_tiles_v2};
use cloudscape_core::world::Config;

/// PSNR (dB) and the largest channel difference (1/255) of `b` against `a`.
fn error(a: &Image, b: &Image) -> (f64, u8) {
    let (a, b) = (a.display(), b.display());
    assert_eq!(a.len(), b.len());
    let mut se = 0.0f64;
    let mut max = 0u8;
    for (p, q) in a.iter().zip(&b) {
        for c in 0..3 {
            let d = to_u8(p[c]).abs_diff(to_u8(q[c]));
            max = max.max(d);
            se += f64::from(d) * f64::from(d);
        }
    }
    let mse = se / (3 * a.len()) as f64;
    let psnr = if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    };
    (psnr, max)
}

#[test]
fn version_3_draws_the_picture_version_2_drew_within_the_stated_error() {
    let config = Config::embedded();
    let world = config.world("default").expect("the default world");
    // The gallery's ground view at noon and its backlit low-sun view (the worst for
    // the derived shadow in `cloudscape bench --only wire`).
    let views = [
        ("ground, noon", "12800,-5000,2,0,20,75", (180.0, 60.0)),
        ("backlit, low sun", "12800,12800,500,250,10,70", (250.0, 12.0)),
    ];
    let mut failures = Vec::new();
    for quality in [Quality::Fast, Quality::Balanced] {
        for (name, camera, (azimuth, elevation)) in views {
            let sun = Sun::new(azimuth, elevation).expect("a valid sun");
            let req = RenderRequest {
                camera: Camera::parse(camera).expect("a valid camera"),
                width: 120,
                height: 68,
                t: 43_210.0,
                quality,
                sun: Some(sun),
                params: ShadingParams::default(),
                samples: 2,
            };
            let tiles = prepare(&world, &config, &req).expect("the view's tiles");
            assert!(
                tiles.iter().any(|t| !t.billboards.is_empty()),
                "{name}: a view with clouds"
            );
            let old = held::draw(&held_tiles_v2(&tiles), &req, sun);
            let mut new_tiles = held_tiles(&tiles, Quantisation::DEFAULT);
            let new = held::draw(&new_tiles, &req, sun);
            for (h, t) in new_tiles.iter_mut().zip(&tiles) {
                h.served_shadow = Some([t.shadow.clone(), t.shadow_end.clone()]);
            }
            let quantised = held::draw(&new_tiles, &req, sun);

            let (psnr_q, max_q) = error(&old, &quantised);
            let q = quality.as_str();
            eprintln!("{q} {name}: quantisation {max_q}/255, PSNR {psnr_q:.1} dB");
            if !(max_q <= 3 && psnr_q >= 50.0) {
                failures.push(format!(
                    "{q} {name}: the quantisation alone puts a channel {max_q}/255 off, PSNR {psnr_q:.1} dB"
                ));
            }
            let (psnr, max) = error(&old, &new);
            eprintln!("{q} {name}: derived shadows {max}/255, PSNR {psnr:.1} dB");
            if psnr < 44.5 {
                failures.push(format!(
                    "{q} {name}: version 3 with derived shadows is {psnr:.1} dB from version 2 (largest {max}/255)"
                ));
            }
            // The pictures are pictures: a blank or constant image would pass the bounds.
            let lum: Vec<f32> = old.display().iter().map(|c| c[0] + c[1] + c[2]).collect();
            let (lo, hi) = lum.iter().fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
            assert!(hi - lo > 0.1, "{q} {name}: the view has contrast");
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
