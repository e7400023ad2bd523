//! The gallery behind `cloudscape gallery`: a fixed set of views of the default world,
//! each drawn by every billboard preset beside the reference path tracer (split into
//! two independent halves, so its own noise is stated: the split-half SSIM), measured
//! as the quality table measures ([`quality::table_rows`]: time, SSIM, τ-bin ratios,
//! thick cloud's colour, sharpness, cloud-covered pixels), and a labelled contact
//! sheet of them all: rows = views, columns = qualities, then the reference, then (when
//! given) the viewer's own screenshot of the view.

use std::path::{Path, PathBuf};

use super::quality::{self, PRESETS, PresetFigures, Reference, ReferenceCache, Scene};
use crate::chart::{SheetCell, contact_sheet};
use cloudscape_core::render::image::{ssim, to_u8};
use cloudscape_core::render::{Quality, Sun};
use cloudscape_core::world::Config;
/// One view of the gallery.
#[derive(Clone, Copy, Debug)]
pub struct GalleryView {
    /// File-name stem (`<name>-<quality>.png`).
    pub name: &'static str,
    /// Row label on the contact sheet.
    pub title: &'static str,
    /// `X,Y,Z,YAW,PITCH,FOV` (see `render --camera`).
    pub camera: &'static str,
    /// Sun azimuth and elevation, degrees.
    pub sun: (f64, f64),
    /// World time, seconds.
    pub t: f64,
}

/// The world every view looks at.
pub const WORLD: &str = "default";

/// The views, in the default world (fair-weather cumulus 1200–2600 m, a broken
/// stratocumulus deck 3000–3600 m, cirrus 8000–9000 m). Cameras and suns are chosen
/// where that world shows clouds well; the inside view sits in a thin cloud of the
/// cumulus layer, with denser cloud and clear air around it.
pub const VIEWS: [GalleryView; 7] = [
    GalleryView {
        name: "ground-noon",
        title: "ground, noon",
        camera: "12800,-5000,2,0,20,75",
        sun: (180.0, 60.0),
        t: 43_200.0,
    },
    GalleryView {
        name: "up-60",
        title: "looking up 60°",
        camera: "12800,12800,2,0,60,75",
        sun: (150.0, 55.0),
        t: 43_200.0,
    },
    GalleryView {
        name: "above-10km",
        title: "above, 10 km",
        camera: "12800,-8000,10000,0,-40,70",
        sun: (200.0, 45.0),
        t: 43_200.0,
    },
    GalleryView {
        name: "backlit",
        title: "backlit, low sun",
        camera: "12800,12800,500,250,10,70",
        sun: (250.0, 12.0),
        t: 43_200.0,
    },
    GalleryView {
        name: "sunset",
        title: "sunset",
        camera: "12800,12800,300,270,6,75",
        sun: (270.0, 2.0),
        t: 43_200.0,
    },
    GalleryView {
        name: "inside-layer",
        title: "inside a layer",
        camera: "5550,1050,1850,0,5,70",
        sun: (180.0, 60.0),
        t: 43_200.0,
    },
    GalleryView {
        name: "horizon",
        title: "far horizon",
        camera: "12800,-20000,400,0,4,60",
        sun: (135.0, 35.0),
        t: 43_200.0,
    },
];

/// The columns of the gallery's pictures: every billboard preset, then the reference.
pub const QUALITIES: [Quality; 4] = [Quality::Fast, Quality::Balanced, Quality::Accurate, Quality::Reference];

/// Title of the contact sheet's column of viewer screenshots.
pub const VIEWER_COLUMN: &str = "viewer";

/// How the gallery is drawn.
#[derive(Clone, Debug)]
pub struct GallerySetup {
    /// Width and height of every picture, pixels.
    pub size: (usize, usize),
    /// Samples per pixel of the reference (both halves together).
    pub samples: u32,
    /// A directory of the viewer's screenshots, `gallery-<view>.png` (as
    /// `tests/browser/gallery.mjs` writes them to `target/browser/`): a column of the
    /// contact sheet, scaled to cover the cell and cropped to it.
    pub viewer_dir: Option<PathBuf>,
    /// Where references are kept between runs (`None`: path-traced every run).
    pub cache: Option<ReferenceCache>,
}

/// One picture of the gallery.
pub struct Shot {
    /// The view's name ([`GalleryView::name`]).
    pub view: &'static str,
    /// The preset it was drawn with (or the reference).
    pub quality: Quality,
    /// The PNG, as `cloudscape render` writes it.
    pub png: Vec<u8>,
}

/// One view of the gallery: its reference and every preset's figures against it.
pub struct ViewFigures {
    pub view: &'static GalleryView,
    pub reference: Reference,
    pub presets: Vec<PresetFigures>,
}

/// Pixels per side of the blocks of the gallery's second SSIM: a 640×360 gallery
/// scored at 160×90, where each block of the reference averages 16 pixels' paths, so
/// a reference too noisy to score single pixels can still score the shapes.
pub const SCORE_BLOCK: usize = 4;

/// SSIM of display luma of `a` against `b` (`width` × `height`) on `k` × `k`-pixel
/// block means.
fn block_ssim(a: &[[f32; 3]], b: &[[f32; 3]], width: usize, height: usize, k: usize) -> f64 {
    let (ba, bw, bh) = quality::binned(a, width, height, k);
    let (bb, _, _) = quality::binned(b, width, height, k);
    ssim(&ba, &bb, bw, bh)
}

impl ViewFigures {
    /// Every preset's SSIM against the reference on [`SCORE_BLOCK`]-pixel blocks, and
    /// the reference's split-half SSIM on them.
    pub fn block_ssims(&self) -> (Vec<f64>, f64) {
        let (w, h) = (self.reference.image.width, self.reference.image.height);
        let r = self.reference.image.display();
        let presets = self
            .presets
            .iter()
            .map(|p| block_ssim(&p.image.display(), &r, w, h, SCORE_BLOCK))
            .collect();
        let [a, b] = &self.reference.halves;
        (presets, block_ssim(&a.display(), &b.display(), w, h, SCORE_BLOCK))
    }
}

/// Every shot (view-major, in [`QUALITIES`] order), the figures and the contact sheet.
pub struct Gallery {
    /// Size of every picture, pixels.
    pub width: usize,
    pub height: usize,
    /// Every picture, view-major, in [`QUALITIES`] order.
    pub shots: Vec<Shot>,
    /// Per view, the reference and the presets' figures.
    pub views: Vec<ViewFigures>,
    /// The viewer's screenshots found, of the views asked (`None` without a directory).
    pub viewer_found: Option<usize>,
    /// The labelled contact sheet, PNG.
    pub contact: Vec<u8>,
}

impl Gallery {
    /// A Markdown table per view and quality (the quality table's columns).
    pub fn table(&self) -> String {
        let samples = self.views.first().map_or(0, |v| v.reference.samples);
        let mut md = format!("Gallery, world `{WORLD}`. ");
        md += &quality::table_header((self.width, self.height), samples);
        for v in &self.views {
            md += &quality::table_rows(v.view.name, &v.reference, &v.presets);
        }
        let (bw, bh) = (self.width / SCORE_BLOCK, self.height / SCORE_BLOCK);
        md += &format!(
            "\nSSIM of display luma on {SCORE_BLOCK}×{SCORE_BLOCK}-pixel block means ({bw}×{bh}), where the \
             reference's noise is averaged over {SCORE_BLOCK}² pixels: preset against reference, and the \
             reference's split-half SSIM.\n\n| view | {} | reference split half |\n|---|{}---|\n",
            PRESETS.map(|q| q.as_str()).join(" | "),
            "---|".repeat(PRESETS.len())
        );
        for v in &self.views {
            let (presets, split) = v.block_ssims();
            let cells: Vec<String> = presets.iter().map(|s| format!("{s:.3}")).collect();
            md += &format!("| {} | {} | {split:.3} |\n", v.view.name, cells.join(" | "));
        }
        md
    }
}

/// A viewer screenshot `path` as 8-bit RGB of `size`: scaled (box filter over the
/// source pixels each cell pixel covers) to cover the cell, centred and cropped.
/// `None` when there is no such file or it does not decode.
pub fn viewer_cell(path: &Path, size: (usize, usize)) -> Option<Vec<u8>> {
    let mut decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).ok()?));
    decoder.set_transformations(png::Transformations::normalize_to_color8());
    let mut reader = decoder.read_info().ok()?;
    let mut buf = vec![0; reader.output_buffer_size()?];
    let info = reader.next_frame(&mut buf).ok()?;
    let (sw, sh) = (info.width as usize, info.height as usize);
    let channels = info.color_type.samples();
    if sw == 0 || sh == 0 {
        return None;
    }
    let rgb_at = |x: usize, y: usize| -> [f64; 3] {
        let p = &buf[(y * sw + x) * channels..];
        match channels {
            1 | 2 => [p[0] as f64; 3],
            _ => [p[0] as f64, p[1] as f64, p[2] as f64],
        }
    };
    let (cw, ch) = size;
    // Cover: the larger scale, so the cell is filled; the overflow is cropped evenly.
    let scale = (cw as f64 / sw as f64).max(ch as f64 / sh as f64);
    let (x0, y0) = (
        (sw as f64 * scale - cw as f64) / 2.0,
        (sh as f64 * scale - ch as f64) / 2.0,
    );
    let mut out = Vec::with_capacity(cw * ch * 3);
    for y in 0..ch {
        for x in 0..cw {
            // The source rectangle under this cell pixel (at least one source pixel).
            let span = |c: usize, o: f64, n: usize| {
                let a = ((c as f64 + o) / scale).floor().max(0.0) as usize;
                let b = (((c as f64 + 1.0 + o) / scale).ceil() as usize).clamp(a + 1, n);
                (a.min(n - 1), b)
            };
            let ((xa, xb), (ya, yb)) = (span(x, x0, sw), span(y, y0, sh));
            let mut sum = [0.0; 3];
            for sy in ya..yb {
                for sx in xa..xb {
                    let p = rgb_at(sx, sy);
                    (0..3).for_each(|i| sum[i] += p[i]);
                }
            }
            let n = ((xb - xa) * (yb - ya)) as f64;
            out.extend(sum.map(|v| (v / n).round() as u8));
        }
    }
    Some(out)
}

/// Renders every view at every quality from `config`'s default world as `setup` says;
/// `progress` is told each view and quality as it starts.
pub fn render_gallery(
    config: &Config,
    setup: &GallerySetup,
    mut progress: impl FnMut(&GalleryView, Quality),
) -> Result<Gallery, String> {
    let (width, height) = setup.size;
    // The gallery is an offline tool: the work its reference does is what its flags ask
    // for (its default, 640×360 at 256 samples, is 59 M paths), not the budget a
    // server holds one request to (`limits.max_path_samples`), so that budget is
    // raised to the gallery's own for its renders.
    let mut config = config.clone();
    let paths = (width as u64)
        .saturating_mul(height as u64)
        .saturating_mul(setup.samples as u64);
    config.limits.max_path_samples = config.limits.max_path_samples.max(paths);
    let config = &config;
    let world = config
        .world(WORLD)
        .ok_or_else(|| format!("the config has no world `{WORLD}`"))?;
    let mut shots = Vec::new();
    let mut views = Vec::new();
    let mut cells = Vec::new();
    let mut viewer_found = 0;
    for v in &VIEWS {
        Sun::new(v.sun.0, v.sun.1).ok_or("a gallery sun is out of range")?;
        let scene = Scene::from_gallery(v);
        // The reference first, so every preset can be compared with it.
        progress(v, Quality::Reference);
        let reference = quality::reference(&world, config, &scene, setup.size, setup.samples, setup.cache.as_ref())
            .map_err(|e| format!("view `{}`, reference: {e}", v.name))?;
        let mut presets = Vec::new();
        for q in PRESETS {
            progress(v, q);
            presets.push(
                quality::measure_preset(&world, config, &scene, q, &reference)
                    .map_err(|e| format!("view `{}`, {}: {e}", v.name, q.as_str()))?,
            );
        }
        let rgb = |img: &cloudscape_core::render::image::Image| -> Vec<u8> {
            img.display().iter().flat_map(|c| c.map(to_u8)).collect()
        };
        let figures = ViewFigures {
            view: v,
            reference,
            presets,
        };
        let (block, block_split) = figures.block_ssims();
        let ViewFigures { reference, presets, .. } = &figures;
        for (p, b) in presets.iter().zip(&block) {
            let c = &p.comparison;
            let cover = p.cover.map_or(String::new(), |c| format!("  cover {c:.2}"));
            cells.push(SheetCell {
                rgb: rgb(&p.image),
                caption: format!(
                    "{:.1} s  SSIM {:.2} ({SCORE_BLOCK}×{SCORE_BLOCK}: {b:.2}){cover}",
                    p.times.total(p.quality),
                    c.ssim
                ),
            });
            shots.push(Shot {
                view: v.name,
                quality: p.quality,
                png: p.image.to_png(),
            });
        }
        cells.push(SheetCell {
            rgb: rgb(&reference.image),
            caption: format!(
                "{:.0} s{}, {} spp  split half {:.2} ({SCORE_BLOCK}×{SCORE_BLOCK}: {block_split:.2})",
                reference.times.total(Quality::Reference),
                if reference.cached { " (cached)" } else { "" },
                reference.samples,
                reference.split_half_ssim()
            ),
        });
        shots.push(Shot {
            view: v.name,
            quality: Quality::Reference,
            png: reference.image.to_png(),
        });
        if let Some(dir) = &setup.viewer_dir {
            let file = format!("gallery-{}.png", v.name);
            let cell = viewer_cell(&dir.join(&file), setup.size);
            viewer_found += usize::from(cell.is_some());
            cells.push(match cell {
                Some(rgb) => SheetCell {
                    rgb,
                    caption: format!("viewer: {file}"),
                },
                None => SheetCell {
                    rgb: vec![128; width * height * 3],
                    caption: format!("no {file}"),
                },
            });
        }
        views.push(figures);
    }
    let rows: Vec<&str> = VIEWS.iter().map(|v| v.title).collect();
    let mut columns: Vec<&str> = QUALITIES.iter().map(|q| q.as_str()).collect();
    if setup.viewer_dir.is_some() {
        columns.push(VIEWER_COLUMN);
    }
    let contact = contact_sheet(&rows, &columns, &cells, setup.size)?;
    Ok(Gallery {
        width,
        height,
        shots,
        views,
        viewer_found: setup.viewer_dir.as_ref().map(|_| viewer_found),
        contact,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use cloudscape_core::render::Camera;
    use cloudscape_core::render::image::{PngSpace, encode_png};

    #[test]
    fn a_viewer_screenshot_covers_its_cell_centred_and_cropped() {
        let dir = std::env::temp_dir().join(format!("cloudscape-viewer-cell-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // 8×2, left half red, right half blue, one green column at x = 0 and x = 7.
        let (w, h) = (8, 2);
        let mut px = Vec::new();
        for _ in 0..h {
            for x in 0..w {
                px.extend(match x {
                    0 | 7 => [0u8, 255, 0],
                    1..=3 => [255, 0, 0],
                    _ => [0, 0, 255],
                });
            }
        }
        let path = dir.join("gallery-test.png");
        std::fs::write(&path, encode_png(w, h, png::ColorType::Rgb, PngSpace::Srgb, &px)).unwrap();
        // A 3×3 cell: scale 1.5 (the height fills it), 12 px wide cropped to the middle
        // 3, which span source x 3.5–5.5: red on the left, blue on the right, no green.
        let cell = viewer_cell(&path, (3, 3)).unwrap();
        assert_eq!(cell.len(), 3 * 3 * 3);
        for y in 0..3 {
            let p = |x: usize| &cell[(y * 3 + x) * 3..(y * 3 + x) * 3 + 3];
            assert!(p(0)[0] > 100 && p(0)[1] == 0, "{:?}", p(0));
            assert_eq!(p(2), &[0, 0, 255]);
        }
        // Enlarged: every pixel of a 16×4 cell comes from the picture, green at both ends.
        let big = viewer_cell(&path, (16, 4)).unwrap();
        assert_eq!(&big[..3], &[0, 255, 0]);
        assert_eq!(&big[15 * 3..16 * 3], &[0, 255, 0]);
        assert!(viewer_cell(&dir.join("missing.png"), (3, 3)).is_none());
        std::fs::write(dir.join("bad.png"), b"not a png").unwrap();
        assert!(viewer_cell(&dir.join("bad.png"), (3, 3)).is_none());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_browser_test_shoots_the_same_views() {
        // tests/browser/gallery.mjs keeps the viewer's screenshots of these views.
        let js = include_str!("../../../../tests/browser/gallery.mjs");
        for v in &VIEWS {
            let line = format!(
                "{{ name: '{}', camera: '{}', sun: '{},{}', t: {} }}",
                v.name, v.camera, v.sun.0, v.sun.1, v.t
            );
            assert!(js.contains(&line), "tests/browser/gallery.mjs lacks `{line}`");
        }
    }

    #[test]
    fn every_view_is_a_valid_camera_and_sun() {
        for v in &VIEWS {
            assert!(Camera::parse(v.camera).is_ok(), "{}", v.name);
            assert!(Sun::new(v.sun.0, v.sun.1).is_some(), "{}", v.name);
        }
        let mut names: Vec<&str> = VIEWS.iter().map(|v| v.name).collect();
        names.dedup();
        assert_eq!(names.len(), VIEWS.len());
    }
}
