//! What each quality preset buys: time and error against the reference path tracer
//! (at [`REFERENCE_SAMPLES`] samples per pixel) on the scene set of
//! `benches/render_trade.rs` (which also measures the reference's own convergence;
//! this section is its speed–accuracy table).

use std::time::Instant;

use crate::chart::{Mark, PALETTE, Panel, Series, render};
use crate::density::{self, Region};
use crate::render::image::{Image, rmse, ssim};
use crate::render::scene::{self, RenderRequest};
use crate::render::tile::{ShadedTile, shade_density, tile_halo};
use crate::render::{Camera, Quality, ShadingParams, Sun};
use crate::world::{Config, World};

use super::{BenchRun, Effort, Plot, Section};

/// Samples per pixel of the reference the presets are measured against.
pub const REFERENCE_SAMPLES: u32 = 64;

/// One-layer worlds of the scene set (shared with `benches/render_trade.rs`).
pub const SCENE_WORLDS: &str = r#"
[worlds.stratus]
seed = 11
[[worlds.stratus.layers]]
name = "stratus"
preset = "stratus"
base = 600.0
cell_size = 100.0
cell_height = 80.0
depth = 6
dt = 20.0
wind = [5.0, 1.0]

[worlds.cumulus]
seed = 12
[[worlds.cumulus.layers]]
name = "cumulus"
preset = "cumulus"
base = 1200.0
cell_size = 100.0
cell_height = 100.0
depth = 12
dt = 20.0
wind = [6.0, 0.0]

[worlds.altocumulus]
seed = 13
[[worlds.altocumulus.layers]]
name = "altocumulus"
preset = "altocumulus"
base = 4000.0
cell_size = 80.0
cell_height = 80.0
depth = 8
dt = 20.0
wind = [12.0, -2.0]
"#;

/// A camera over one of [`SCENE_WORLDS`], with the sun (azimuth, elevation in degrees).
pub struct Scene {
    pub name: &'static str,
    pub world: &'static str,
    pub camera: &'static str,
    pub sun: (f64, f64),
}

/// The speed–accuracy scene set.
pub const SCENES: [Scene; 4] = [
    Scene {
        name: "stratus deck from below",
        world: "stratus",
        camera: "12800,12800,20,0,35,70",
        sun: (150.0, 45.0),
    },
    Scene {
        name: "cumulus field at 45°",
        world: "cumulus",
        camera: "12800,6000,5000,0,-45,60",
        sun: (200.0, 45.0),
    },
    Scene {
        name: "altocumulus from above",
        world: "altocumulus",
        camera: "10240,10240,7000,30,-60,60",
        sun: (120.0, 50.0),
    },
    Scene {
        name: "low sun at the horizon",
        world: "cumulus",
        camera: "12800,3000,700,0,6,70",
        sun: (5.0, 1.0),
    },
];

struct Measured {
    density_s: f64,
    billboards_s: f64,
    draw_s: f64,
    image: Image,
    tiles: Vec<ShadedTile>,
}

fn request(s: &Scene, q: Quality, size: usize) -> Result<RenderRequest, String> {
    Ok(RenderRequest {
        camera: Camera::parse(s.camera)?,
        width: size,
        height: size,
        t: 1800.0,
        quality: q,
        sun: Sun::new(s.sun.0, s.sun.1),
        params: ShadingParams::default(),
        samples: REFERENCE_SAMPLES,
    })
}

/// Plans, computes density, shades, and draws (billboards, or the volume for
/// `Reference` and `ReferenceSingle`), timing each stage.
fn measure(world: &World, config: &Config, req: &RenderRequest) -> Result<Measured, String> {
    let sun = req.sun.ok_or("the scene has no sun")?;
    let plan = scene::plan(world, config, req).map_err(|e| e.to_string())?;
    let t0 = Instant::now();
    let mut grids = Vec::new();
    for &(li, tile) in &plan {
        let l = &world.layers[li];
        let halo = tile_halo(l, tile.z, req.quality, sun);
        let r = tile.region().map_err(|e| e.to_string())?;
        let h = halo as i64;
        let region = Region {
            x0: r.x0 - h,
            y0: r.y0 - h,
            cols: r.cols + 2 * halo,
            rows: r.rows + 2 * halo,
        };
        grids.push((
            density::density(world, li, tile.z, region, req.t).map_err(|e| e.to_string())?,
            halo,
        ));
    }
    let density_s = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let tiles: Vec<ShadedTile> = plan
        .iter()
        .zip(grids)
        .map(|(&(li, tile), (g, halo))| {
            shade_density(
                li,
                &world.layers[li],
                tile,
                req.t,
                req.quality,
                sun,
                &req.params,
                g,
                halo,
            )
        })
        .collect();
    let billboards_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let (image, _) = scene::draw(&tiles, req, sun);
    let draw_s = t2.elapsed().as_secs_f64();
    Ok(Measured {
        density_s,
        billboards_s,
        draw_s,
        image,
        tiles,
    })
}

/// The speed–accuracy table: every preset against the reference, per scene.
pub fn speed_accuracy(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let (scenes, size, presets): (&[Scene], usize, &[Quality]) = match effort {
        Effort::Smoke => (&SCENES[..1], 32, &[Quality::Fast]),
        Effort::Quick => (
            &SCENES[..1],
            128,
            &[Quality::Fast, Quality::Balanced, Quality::Accurate],
        ),
        Effort::Full => (&SCENES, 512, &[Quality::Fast, Quality::Balanced, Quality::Accurate]),
    };
    let config = Config::parse(&format!(
        "{}\n{SCENE_WORLDS}",
        include_str!("../../config/default.toml")
    ))
    .map_err(|e| e.to_string())?;
    let mut md = format!(
        "Scene set of `benches/render_trade.rs` (one-layer worlds, t = 1800 s), {size}×{size} pixels. Error against \
         `reference` (path tracer, {REFERENCE_SAMPLES} samples per pixel) on the same tiles: RMSE of display RGB in [0, 1], SSIM of luma. \
         Times: density (shared by every preset), billboards (metaballs + shading), draw. Speed-up against the \
         reference: total / excluding density. The reference's convergence is in `cargo bench --bench render_trade`.\n\n\
         | scene | preset | tiles | billboards | density | billboards | draw | total | speed-up | RMSE | SSIM |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n"
    );
    let mut points: Vec<(Quality, f64, f64)> = Vec::new();
    for s in scenes {
        let world = config.world(s.world).ok_or("a scene world is missing")?;
        let reference = measure(&world, &config, &request(s, Quality::Reference, size)?)?;
        let ref_display = reference.image.display();
        let ref_total = reference.density_s + reference.draw_s;
        for &q in presets {
            let m = measure(&world, &config, &request(s, q, size)?)?;
            let total = m.density_s + m.billboards_s + m.draw_s;
            let d = m.image.display();
            let (e, ss) = (rmse(&d, &ref_display), ssim(&d, &ref_display, size, size));
            let n: usize = m.tiles.iter().map(|t| t.billboards.len()).sum();
            md += &format!(
                "| {} | {} | {} | {n} | {:.2} s | {:.2} s | {:.3} s | {:.2} s | {:.0}× / {:.0}× | {e:.4} | {ss:.3} |\n",
                s.name,
                q.as_str(),
                m.tiles.len(),
                m.density_s,
                m.billboards_s,
                m.draw_s,
                total,
                ref_total / total,
                reference.draw_s / (m.billboards_s + m.draw_s)
            );
            points.push((q, m.billboards_s + m.draw_s, ss));
        }
        md += &format!(
            "| {} | reference | {} | – | {:.2} s | – | {:.2} s | {:.2} s | 1× | 0 | 1 |\n",
            s.name,
            reference.tiles.len(),
            reference.density_s,
            reference.draw_s,
            ref_total
        );
        points.push((Quality::Reference, reference.draw_s, 1.0));
    }
    md += "\n![quality](@plots@/quality.png)\n";
    let series: Vec<Series> = Quality::ALL
        .iter()
        .enumerate()
        .map(|(i, &q)| Series {
            name: q.as_str().into(),
            points: points.iter().filter(|p| p.0 == q).map(|p| (p.1, p.2)).collect(),
            colour: PALETTE[[1, 2, 0, 5, 3][i]],
            mark: Mark::Points,
        })
        .collect();
    let png = render(
        &[Panel {
            title: "what each preset buys".into(),
            x_label: "rendering time without density, s".into(),
            y_label: "SSIM against reference".into(),
            x_log: true,
            series,
            ..Panel::default()
        }],
        1,
        (560, 400),
    )?;
    out.plots.push(Plot {
        file: "quality.png".into(),
        png,
    });
    out.sections.push(Section {
        id: "quality",
        title: "Quality presets: speed against accuracy",
        markdown: md,
    });
    Ok(())
}
