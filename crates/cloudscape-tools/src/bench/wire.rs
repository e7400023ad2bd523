//! Bytes on the wire against the picture: `billboards.bin` version 3 (quantised lattice
//! states, self-contained and delta forms, ground shadows derived by the client)
//! against version 2 with `shadow.png` (full-precision records, served shadow maps).
//!
//! For each quality and each of the gallery's views, at a keyframe's start and in the
//! middle of its span: the picture a version-2 client draws (the old) and the one a
//! version-3 client draws (the new), both through `view::held`, compared pixel by
//! pixel on the displayed 8-bit values (PSNR, largest difference, share of pixels off
//! by more than 2/255); the same with the served shadow maps under version 3, which
//! isolates the quantisation from the derived shadow; and the bytes of the view's
//! tiles as served (zstd level 3, what `Accept-Encoding: zstd` gets). Then the curve
//! behind the default quantisation: bytes of a delta against the picture's error over
//! colour bits and `τ_sun` steps.

use std::collections::BTreeMap;

use cloudscape_core::products::billboards::encode_bin;
use cloudscape_core::products::keyframe_bin::{self, Form, Quantisation};
use cloudscape_core::products::shadow::encode_png_map;
use cloudscape_core::render::image::{Image, to_u8};
use cloudscape_core::render::scene::{RenderRequest, prepare};
use cloudscape_core::render::{Camera, Quality, ShadedTile, ShadingParams, Sun};
use cloudscape_core::view::{held, held_tiles, held_tiles_v2};
use cloudscape_core::world::Config;

use super::gallery::{GalleryView, VIEWS};
use super::{BenchRun, Effort};

/// How two pictures of one view differ, on displayed 8-bit values.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PictureError {
    /// Peak signal-to-noise ratio, dB (∞ for identical pictures).
    pub psnr_db: f64,
    /// Largest difference of a channel, in 1/255.
    pub max: u8,
    /// Share of pixels with a channel off by more than 2/255.
    pub over_2: f64,
}

impl PictureError {
    /// The error of `b` against `a`.
    pub fn of(a: &Image, b: &Image) -> PictureError {
        let (a, b) = (a.display(), b.display());
        let (mut se, mut max, mut over) = (0.0f64, 0u8, 0usize);
        for (p, q) in a.iter().zip(&b) {
            let mut worst = 0u8;
            for c in 0..3 {
                let d = to_u8(p[c]).abs_diff(to_u8(q[c]));
                worst = worst.max(d);
                se += (d as f64).powi(2);
            }
            max = max.max(worst);
            over += (worst > 2) as usize;
        }
        let mse = se / (3 * a.len().max(1)) as f64;
        PictureError {
            psnr_db: if mse == 0.0 {
                f64::INFINITY
            } else {
                10.0 * (255.0f64.powi(2) / mse).log10()
            },
            max,
            over_2: over as f64 / a.len().max(1) as f64,
        }
    }

    /// The worse of two errors, field by field.
    fn worst(self, o: PictureError) -> PictureError {
        PictureError {
            psnr_db: self.psnr_db.min(o.psnr_db),
            max: self.max.max(o.max),
            over_2: self.over_2.max(o.over_2),
        }
    }

    fn cell(&self) -> String {
        let psnr = if self.psnr_db.is_finite() {
            format!("{:.1} dB", self.psnr_db)
        } else {
            "∞".into()
        };
        format!("{psnr}, {}/255, {:.2} %", self.max, 100.0 * self.over_2)
    }
}

/// Bytes of a view's tiles as served with `Accept-Encoding: zstd`, summed.
#[derive(Clone, Copy, Debug, Default)]
struct ViewBytes {
    balls: usize,
    v2: usize,
    shadow: usize,
    full: usize,
    delta: usize,
}

fn zstd3(bytes: &[u8]) -> usize {
    zstd::bulk::compress(bytes, 3).map_or(bytes.len(), |c| c.len())
}

impl ViewBytes {
    fn of(tiles: &[ShadedTile], q: Quantisation) -> ViewBytes {
        let mut b = ViewBytes::default();
        for t in tiles {
            b.balls += t.billboards.len();
            b.v2 += zstd3(&encode_bin(t));
            b.shadow += encode_png_map(t).len();
            b.full += zstd3(&keyframe_bin::encode(t, Form::SelfContained, q));
            b.delta += zstd3(&keyframe_bin::encode(t, Form::Delta, q));
        }
        b
    }

    fn add(&mut self, o: ViewBytes) {
        self.balls += o.balls;
        self.v2 += o.v2;
        self.shadow += o.shadow;
        self.full += o.full;
        self.delta += o.delta;
    }
}

/// A gallery view drawn at `t` in `quality` at `size`.
fn request(v: &GalleryView, quality: Quality, t: f64, size: (usize, usize)) -> Result<RenderRequest, String> {
    Ok(RenderRequest {
        camera: Camera::parse(v.camera).map_err(|e| e.to_string())?,
        width: size.0,
        height: size.1,
        t,
        quality,
        sun: Some(Sun::new(v.sun.0, v.sun.1).ok_or("a gallery sun is valid")?),
        params: ShadingParams::default(),
        samples: 2,
    })
}

pub fn wire(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let config = Config::embedded();
    let world = config.world("default").ok_or("the default world exists")?;
    let (size, qualities, views): ((usize, usize), &[Quality], &[GalleryView]) = match effort {
        Effort::Smoke => ((96, 54), &[Quality::Fast], &VIEWS[..2]),
        Effort::Quick => ((240, 135), &[Quality::Fast, Quality::Balanced], &VIEWS[..]),
        Effort::Full => (
            (240, 135),
            &[Quality::Fast, Quality::Balanced, Quality::Accurate],
            &VIEWS[..],
        ),
    };
    let q = Quantisation::DEFAULT;
    let mut md = format!(
        "The gallery's views of the default world at {}×{}, at a keyframe's start (t0 = 43 200 s) and in \
         the middle of the level-0 span (t0 + 10 s). *Old*: what a version-2 client draws (`billboards.v2.bin` \
         and `shadow.png`); *new*: what a version-3 client draws (`billboards.bin` and its deltas, colour on \
         {} bits, `τ_sun` on {} steps per e-fold, ground shadows derived from the billboards). Errors on the \
         displayed 8-bit pixels: PSNR, largest channel difference, share of pixels off by more than 2/255. \
         *Quantisation only*: version 3 drawn with the served shadow maps. Bytes: the view's tiles as served \
         with `Accept-Encoding: zstd` (level 3), per keyframe, summed; a delta is what a client holding the \
         previous keyframe of each tile fetches.\n\n\
         | quality | view | t | new vs old | quantisation only | billboards | v2 + shadow.png | v3 self-contained | v3 delta |\n\
         |---|---|---|---|---|---|---|---|---|\n",
        size.0, size.1, q.colour_bits, q.tau_sun_steps
    );
    let mut totals: BTreeMap<&str, (ViewBytes, PictureError, PictureError)> = BTreeMap::new();
    for &quality in qualities {
        for v in views {
            for dt in [0.0, 10.0] {
                let req = request(v, quality, v.t + dt, size)?;
                let sun = req.sun.ok_or("a sun")?;
                let tiles = prepare(&world, &config, &req).map_err(|e| e.to_string())?;
                let old = held::draw(&held_tiles_v2(&tiles), &req, sun);
                let mut new_tiles = held_tiles(&tiles, q);
                let new = held::draw(&new_tiles, &req, sun);
                for (h, t) in new_tiles.iter_mut().zip(&tiles) {
                    h.served_shadow = Some([t.shadow.clone(), t.shadow_end.clone()]);
                }
                let quantised = held::draw(&new_tiles, &req, sun);
                let (e, eq) = (PictureError::of(&old, &new), PictureError::of(&old, &quantised));
                let bytes = if dt == 0.0 {
                    ViewBytes::of(&tiles, q)
                } else {
                    ViewBytes::default()
                };
                let kb = |b: usize| format!("{:.0} KB", b as f64 / 1e3);
                md += &format!(
                    "| {} | {} | t0{} | {} | {} | {} | {} | {} | {} |\n",
                    quality.as_str(),
                    v.title,
                    if dt == 0.0 {
                        String::new()
                    } else {
                        format!(" + {dt:.0} s")
                    },
                    e.cell(),
                    eq.cell(),
                    if dt == 0.0 { bytes.balls.to_string() } else { "".into() },
                    if dt == 0.0 {
                        kb(bytes.v2 + bytes.shadow)
                    } else {
                        "".into()
                    },
                    if dt == 0.0 { kb(bytes.full) } else { "".into() },
                    if dt == 0.0 { kb(bytes.delta) } else { "".into() },
                );
                let entry = totals.entry(quality.as_str()).or_insert((
                    ViewBytes::default(),
                    PictureError {
                        psnr_db: f64::INFINITY,
                        ..PictureError::default()
                    },
                    PictureError {
                        psnr_db: f64::INFINITY,
                        ..PictureError::default()
                    },
                ));
                entry.0.add(bytes);
                entry.1 = entry.1.worst(e);
                entry.2 = entry.2.worst(eq);
            }
        }
    }
    md += "\nOver all the views of a quality (errors: the worst view):\n\n\
           | quality | new vs old | quantisation only | bytes a billboard: v2 + shadow.png | v3 self-contained | v3 delta | delta / old |\n\
           |---|---|---|---|---|---|---|\n";
    for (quality, (b, e, eq)) in &totals {
        let per = |x: usize| x as f64 / b.balls.max(1) as f64;
        md += &format!(
            "| {quality} | {} | {} | {:.2} | {:.2} | {:.2} | {:.3} |\n",
            e.cell(),
            eq.cell(),
            per(b.v2 + b.shadow),
            per(b.full),
            per(b.delta),
            b.delta as f64 / (b.v2 + b.shadow).max(1) as f64
        );
    }
    md += &curve(effort, &world, &config)?;
    out.add_section("wire", "Bytes on the wire against the picture", md);
    Ok(())
}

/// The trade behind [`Quantisation::DEFAULT`]: for colour bits and `τ_sun` steps, a
/// delta's bytes a billboard and the worst error of the picture (quantisation only, the
/// served shadow maps) over a few views.
fn curve(effort: Effort, world: &cloudscape_core::world::World, config: &Config) -> Result<String, String> {
    type Plan<'a> = ((usize, usize), &'a [GalleryView], Vec<(u8, u8)>);
    let (size, views, settings): Plan = match effort {
        Effort::Smoke => ((96, 54), &VIEWS[..1], vec![(5, 8), (7, 12)]),
        _ => (
            (240, 135),
            &VIEWS[..],
            vec![(5, 8), (6, 8), (6, 12), (7, 8), (7, 12), (7, 16), (8, 12), (8, 16)],
        ),
    };
    let mut md = format!(
        "\nThe curve behind the default: for colour bits and `τ_sun` steps per e-fold, the bytes of a delta \
         (zstd level 3) a billboard and the worst error of the picture against version 2 with the served \
         shadow maps (quantisation only), over {} views at t0 and t0 + 10 s, `fast` and `balanced`.\n\n\
         | colour bits | τ_sun steps | delta bytes a billboard | worst PSNR | largest difference | pixels off > 2/255 |\n\
         |---|---|---|---|---|---|\n",
        views.len()
    );
    // Shade once per view; quantise many ways.
    let mut shaded = Vec::new();
    for quality in [Quality::Fast, Quality::Balanced] {
        for v in views {
            for dt in [0.0, 10.0] {
                let req = request(v, quality, v.t + dt, size)?;
                let tiles = prepare(world, config, &req).map_err(|e| e.to_string())?;
                let old = held::draw(&held_tiles_v2(&tiles), &req, req.sun.ok_or("a sun")?);
                shaded.push((req, tiles, old, dt == 0.0));
            }
        }
    }
    for (colour_bits, tau_sun_steps) in settings {
        let q = Quantisation {
            colour_bits,
            tau_sun_steps,
        };
        let (mut bytes, mut balls) = (0usize, 0usize);
        let mut worst = PictureError {
            psnr_db: f64::INFINITY,
            ..PictureError::default()
        };
        for (req, tiles, old, count) in &shaded {
            let mut held = held_tiles(tiles, q);
            for (h, t) in held.iter_mut().zip(tiles) {
                h.served_shadow = Some([t.shadow.clone(), t.shadow_end.clone()]);
            }
            worst = worst.worst(PictureError::of(old, &held::draw(&held, req, req.sun.ok_or("a sun")?)));
            if *count {
                for t in tiles {
                    balls += t.billboards.len();
                    bytes += zstd3(&keyframe_bin::encode(t, Form::Delta, q));
                }
            }
        }
        let marker = if q == Quantisation::DEFAULT { " (default)" } else { "" };
        md += &format!(
            "| {colour_bits}{marker} | {tau_sun_steps} | {:.2} | {:.1} dB | {}/255 | {:.2} % |\n",
            bytes as f64 / balls.max(1) as f64,
            worst.psnr_db,
            worst.max,
            100.0 * worst.over_2
        );
    }
    Ok(md)
}
