//! The gallery behind `cloudscape gallery`: a fixed set of views of the default world,
//! each drawn by every billboard preset beside the reference, timed and compared with
//! it (RMSE and SSIM of the display images, as in the speed–accuracy section), and a
//! labelled contact sheet of them all (rows = views, columns = qualities).

use std::time::Instant;

use crate::chart::{SheetCell, contact_sheet};
use cloudscape_core::render::image::{rmse, ssim, to_u8};
use cloudscape_core::render::scene::RenderRequest;
use cloudscape_core::render::{Camera, Quality, ShadingParams, Sun};
use cloudscape_core::view::render;
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

/// The columns of the gallery: every billboard preset, then the reference.
pub const QUALITIES: [Quality; 4] = [Quality::Fast, Quality::Balanced, Quality::Accurate, Quality::Reference];

/// One picture of the gallery and how it compares with the reference of its view.
pub struct Shot {
    /// The view's name ([`GalleryView::name`]).
    pub view: &'static str,
    /// The preset it was drawn with (or the reference).
    pub quality: Quality,
    /// Wall-clock seconds of the whole render (planning, density, shading, drawing).
    pub seconds: f64,
    /// The PNG, as `cloudscape render` writes it.
    pub png: Vec<u8>,
    /// RMSE of display RGB against the reference of the same view; `None` for the
    /// reference itself.
    pub rmse: Option<f64>,
    /// SSIM of luma against the same reference.
    pub ssim: Option<f64>,
    /// The display image, 8-bit RGB, for the contact sheet.
    rgb: Vec<u8>,
}

/// Every shot (view-major, in [`QUALITIES`] order) and the contact sheet.
pub struct Gallery {
    /// Size of every picture, pixels.
    pub width: usize,
    pub height: usize,
    /// Every picture, view-major, in [`QUALITIES`] order.
    pub shots: Vec<Shot>,
    /// The labelled contact sheet, PNG.
    pub contact: Vec<u8>,
}

impl Gallery {
    /// A Markdown table of time, RMSE and SSIM per view and preset.
    pub fn table(&self) -> String {
        let mut md = format!(
            "Gallery, world `{WORLD}`, {}×{} pixels. RMSE of display RGB in [0, 1] and SSIM of luma, \
             against `reference` of the same view.\n\n\
             | view | quality | time | RMSE | SSIM |\n|---|---|---|---|---|\n",
            self.width, self.height
        );
        for s in &self.shots {
            let f = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |v| format!("{v:.d$}"));
            md += &format!(
                "| {} | {} | {:.2} s | {} | {} |\n",
                s.view,
                s.quality.as_str(),
                s.seconds,
                f(s.rmse, 4),
                f(s.ssim, 3)
            );
        }
        md
    }
}

/// Renders every view at every quality (`width × height` pixels) from `config`'s
/// default world; `progress` is told each picture as it starts.
pub fn render_gallery(
    config: &Config,
    width: usize,
    height: usize,
    samples: u32,
    mut progress: impl FnMut(&GalleryView, Quality),
) -> Result<Gallery, String> {
    let world = config
        .world(WORLD)
        .ok_or_else(|| format!("the config has no world `{WORLD}`"))?;
    let mut shots = Vec::new();
    for v in &VIEWS {
        // The reference first, so every preset can be compared with it.
        let mut row: Vec<Shot> = Vec::new();
        let mut reference_display: Option<Vec<[f32; 3]>> = None;
        for &q in QUALITIES.iter().rev() {
            progress(v, q);
            let req = RenderRequest {
                camera: Camera::parse(v.camera).map_err(|e| e.to_string())?,
                width,
                height,
                t: v.t,
                quality: q,
                sun: Some(Sun::new(v.sun.0, v.sun.1).ok_or("a gallery sun is out of range")?),
                params: ShadingParams::default(),
                samples,
            };
            let start = Instant::now();
            let rendered =
                render(&world, config, &req).map_err(|e| format!("view `{}`, {}: {e}", v.name, q.as_str()))?;
            let seconds = start.elapsed().as_secs_f64();
            let display = rendered.image.display();
            let (e, s) = match &reference_display {
                Some(r) => (Some(rmse(&display, r)), Some(ssim(&display, r, width, height))),
                None => (None, None),
            };
            row.push(Shot {
                view: v.name,
                quality: q,
                seconds,
                png: rendered.image.to_png(),
                rmse: e,
                ssim: s,
                rgb: display.iter().flat_map(|c| c.map(to_u8)).collect(),
            });
            if q == Quality::Reference {
                reference_display = Some(display);
            }
        }
        row.reverse();
        shots.extend(row);
    }
    let cells: Vec<SheetCell> = shots
        .iter()
        .map(|s| SheetCell {
            rgb: s.rgb.clone(),
            caption: match s.ssim {
                Some(ss) => format!("{:.1} s  SSIM {ss:.2}", s.seconds),
                None => format!("{:.1} s", s.seconds),
            },
        })
        .collect();
    let rows: Vec<&str> = VIEWS.iter().map(|v| v.title).collect();
    let columns: Vec<&str> = QUALITIES.iter().map(|q| q.as_str()).collect();
    let contact = contact_sheet(&rows, &columns, &cells, (width, height))?;
    Ok(Gallery {
        width,
        height,
        shots,
        contact,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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
