//! The speed/accuracy trade of the quality presets, measured (BENCHMARKS.md,
//! "Rendering").
//!
//! `cargo bench --bench render_trade` renders a fixed scene set with every preset and
//! with the reference path tracer, and prints a Markdown table: per preset and scene,
//! the time (density, billboards, drawing) and the error against the reference (RMSE
//! of display RGB in [0, 1], SSIM of luma); then per-tile time to billboards + atlas;
//! then the reference's own convergence (error and stated noise of 4, 16, 64 samples
//! per pixel against 256). It writes the plot to `benches/render_trade.png` and the images
//! to `target/render_trade/`. Under `cargo test` (no `--bench` argument) it does nothing.

use std::time::Instant;

use cloudscape_core::products::atlas;
use cloudscape_core::render::Quality;
use cloudscape_core::render::image::{Image, PngSpace, encode_png, rmse, ssim};
use cloudscape_core::render::scene::RenderRequest;
use cloudscape_core::render::tile::ShadedTile;
use cloudscape_core::view;
use cloudscape_core::world::{Config, DEFAULT_CONFIG, World};

use cloudscape_tools::bench::quality::{
    REFERENCE_SAMPLES, SCENE_WORLDS, SCENES, StageTimes, request, scene_density, shade_grids,
};

const SIZE: usize = 512;
const CONVERGENCE_SIZE: usize = 192;
/// Sample counts of the convergence table (each against 256).
const CONVERGENCE_SAMPLES: [u32; 4] = [4, 16, 64, 128];

struct Measured {
    times: StageTimes,
    image: Image,
    /// The path tracer's stated noise (0 for billboards).
    noise: f64,
    tiles: Vec<ShadedTile>,
}

/// One preset's figures over the scene set, one entry per scene.
struct PresetSummary {
    quality: Quality,
    speed_up: Vec<f64>,
    speed_up_excl_density: Vec<f64>,
    ssim: Vec<f64>,
}

/// Plans, computes density, shades, and draws with the renderer of the preset (the
/// billboard compositor, or the path tracer for `Reference`), timing each stage.
fn measure(world: &World, config: &Config, req: &RenderRequest) -> Measured {
    let sun = req.sun.unwrap();
    let (density_s, grids, plan) = scene_density(world, config, req).unwrap();
    let t1 = Instant::now();
    let tiles: Vec<ShadedTile> = shade_grids(world, req, &plan, grids).unwrap();
    let billboards_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let (image, noise) = view::draw(&tiles, req, sun);
    let draw_s = t2.elapsed().as_secs_f64();
    Measured {
        times: StageTimes {
            density_s,
            billboards_s,
            draw_s,
        },
        image,
        noise: noise.map_or(0.0, |n| n.std_error),
        tiles,
    }
}

fn main() {
    if !std::env::args().any(|a| a == "--bench") {
        return;
    }
    let config = Config::parse(&format!("{DEFAULT_CONFIG}\n{SCENE_WORLDS}")).unwrap();
    let out_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/render_trade");
    std::fs::create_dir_all(&out_dir).unwrap();
    let threads = rayon::current_num_threads();
    println!("## Rendering: speed against accuracy\n");
    println!("Command: `cargo bench --bench render_trade` ({threads} threads, {SIZE}×{SIZE} pixels, t = 1800 s).");
    println!(
        "Error is against `reference` (path tracer, {REFERENCE_SAMPLES} samples per pixel) on the same tiles; RMSE of display RGB in [0, 1], SSIM of luma."
    );
    println!(
        "Times in seconds: density (the simulation, shared by all presets), billboards (metaballs + shading), draw.\n"
    );
    println!(
        "| scene | preset | tiles | billboards | density s | billboards s | draw s | total s | speed-up vs reference (total / excl. density) | RMSE | SSIM |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let mut points: Vec<(Quality, f64, f64)> = Vec::new();
    let mut per_tile: Vec<(Quality, f64, usize)> = Vec::new();
    let mut summary: Vec<PresetSummary> = [Quality::Fast, Quality::Balanced, Quality::Accurate]
        .map(|quality| PresetSummary {
            quality,
            speed_up: vec![],
            speed_up_excl_density: vec![],
            ssim: vec![],
        })
        .into();
    for s in &SCENES {
        let world = config.world(s.world).unwrap();
        let rref = measure(&world, &config, &request(s, Quality::Reference, SIZE).unwrap());
        let ref_display = rref.image.display();
        write_png(&out_dir, s.name, "reference", &rref.image);
        for (qi, q) in [Quality::Fast, Quality::Balanced, Quality::Accurate]
            .into_iter()
            .enumerate()
        {
            let m = measure(&world, &config, &request(s, q, SIZE).unwrap());
            let d = m.image.display();
            let (e, ss) = (rmse(&d, &ref_display), ssim(&d, &ref_display, SIZE, SIZE));
            let n: usize = m.tiles.iter().map(|t| t.billboards.len()).sum();
            let (speed, speed_ex) = m.times.speed_up(q, &rref.times);
            println!(
                "| {} | {} | {} | {} | {} | {:.4} | {:.3} |",
                s.name,
                q.as_str(),
                m.tiles.len(),
                n,
                m.times.preset_cells(q, &rref.times, ""),
                e,
                ss
            );
            points.push((q, m.times.after_density(q), ss));
            summary[qi].speed_up.push(speed);
            summary[qi].speed_up_excl_density.push(speed_ex);
            summary[qi].ssim.push(ss);
            write_png(&out_dir, s.name, q.as_str(), &m.image);
            // Per-tile time to billboards + atlas.
            let t = Instant::now();
            for tile in &m.tiles {
                atlas::build(tile);
            }
            let atlas_s = t.elapsed().as_secs_f64();
            per_tile.push((q, m.times.billboards_s + atlas_s, m.tiles.len()));
        }
        points.push((Quality::Reference, rref.times.after_density(Quality::Reference), 1.0));
        println!(
            "| {} | reference | {} | – | {:.2} | – | {:.2} | {:.2} | 1× | 0 | 1 |",
            s.name,
            rref.tiles.len(),
            rref.times.density_s,
            rref.times.draw_s,
            rref.times.total(Quality::Reference)
        );
    }
    println!("\nSummary over the scene set (geometric mean of speed-ups, minimum SSIM):\n");
    println!("| preset | speed-up total | speed-up excl. density | min SSIM | mean SSIM |");
    println!("|---|---|---|---|---|");
    for p in &summary {
        let gm = |v: &[f64]| (v.iter().map(|x| x.ln()).sum::<f64>() / v.len() as f64).exp();
        let ss = &p.ssim;
        let min = ss.iter().cloned().fold(f64::INFINITY, f64::min);
        let mean = ss.iter().sum::<f64>() / ss.len() as f64;
        println!(
            "| {} | {:.0}× | {:.0}× | {:.3} | {:.3} |",
            p.quality.as_str(),
            gm(&p.speed_up),
            gm(&p.speed_up_excl_density),
            min,
            mean
        );
    }

    println!("\nPer-tile time to billboards + atlas (density excluded), mean over the scene set's tiles:\n");
    println!("| preset | tiles | seconds per tile |");
    println!("|---|---|---|");
    for q in [Quality::Fast, Quality::Balanced, Quality::Accurate] {
        let (s, n) = per_tile
            .iter()
            .filter(|p| p.0 == q)
            .fold((0.0, 0), |a, p| (a.0 + p.1, a.1 + p.2));
        println!("| {} | {} | {:.3} |", q.as_str(), n, s / n.max(1) as f64);
    }

    println!(
        "\nReference convergence ({CONVERGENCE_SIZE}×{CONVERGENCE_SIZE}): error of each sample count against 256 samples per pixel, \
         and the noise the renderer states (mean standard error of pixel luminance, linear).\n"
    );
    println!("| scene | samples | draw s | stated noise | RMSE | SSIM |");
    println!("|---|---|---|---|---|---|");
    let mut convergence: Vec<(f64, f64)> = Vec::new();
    for s in [&SCENES[0], &SCENES[1]] {
        let world = config.world(s.world).unwrap();
        let mut req = request(s, Quality::Reference, CONVERGENCE_SIZE).unwrap();
        req.samples = 256;
        let truth = measure(&world, &config, &req).image.display();
        for samples in CONVERGENCE_SAMPLES {
            req.samples = samples;
            let m = measure(&world, &config, &req);
            let d = m.image.display();
            let (e, ss) = (rmse(&d, &truth), ssim(&d, &truth, CONVERGENCE_SIZE, CONVERGENCE_SIZE));
            println!(
                "| {} | {samples} | {:.2} | {:.5} | {:.4} | {:.4} |",
                s.name, m.times.draw_s, m.noise, e, ss
            );
            convergence.push((samples as f64, e));
        }
    }
    let plot = plot(&points, &convergence);
    let plot_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/render_trade.png");
    std::fs::write(&plot_path, plot).unwrap();
    println!("\nPlot: `benches/render_trade.png`; images: `target/render_trade/`.");
}

fn write_png(dir: &std::path::Path, scene: &str, q: &str, img: &Image) {
    let name: String = scene
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    std::fs::write(dir.join(format!("{name}-{q}.png")), img.to_png()).unwrap();
}

/// A 640×320 plot without text (legend in BENCHMARKS.md). Left panel: SSIM (y, 0.9 to
/// 1, a tick per 0.02) against rendering time without density (billboards + draw, or
/// path tracing; x, log10 from 0.1 s to 1000 s, a tick per decade); one dot per
/// scene, red = fast, green = balanced, blue = accurate, black = reference (SSIM 1).
/// Right panel: reference RMSE against 256 samples (y, 0 to 0.05, a tick per 0.01)
/// against samples per pixel (x, log2, a tick at 4, 16, 64, 256, 1024), one polyline
/// per scene.
fn plot(points: &[(Quality, f64, f64)], convergence: &[(f64, f64)]) -> Vec<u8> {
    let (w, h) = (640usize, 320usize);
    let mut px = vec![255u8; w * h * 3];
    let put = |x: i64, y: i64, c: [u8; 3], px: &mut Vec<u8>| {
        if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
            let i = (y as usize * w + x as usize) * 3;
            px[i..i + 3].copy_from_slice(&c);
        }
    };
    let grey = [170, 170, 170];
    // Panel frames and ticks.
    for (x0, x1) in [(40i64, 300i64), (360, 620)] {
        for x in x0..=x1 {
            put(x, 290, [0, 0, 0], &mut px);
            put(x, 20, grey, &mut px);
        }
        for y in 20..=290 {
            put(x0, y, [0, 0, 0], &mut px);
            put(x1, y, grey, &mut px);
        }
    }
    for d in 0..=4 {
        let x = 40 + d * 65;
        for y in 285..295 {
            put(x, y, [0, 0, 0], &mut px);
        }
    }
    for o in 0..=4 {
        let x = 360 + o * 65;
        for y in 285..295 {
            put(x, y, [0, 0, 0], &mut px);
        }
    }
    for k in 0..=5 {
        let y = 290 - k * 54;
        for x in 35..45 {
            put(x, y, [0, 0, 0], &mut px);
            put(x + 320, y, [0, 0, 0], &mut px);
        }
    }
    let colour = |q: Quality| match q {
        Quality::Fast => [220, 30, 30],
        Quality::Balanced => [30, 160, 30],
        Quality::Accurate => [30, 60, 220],
        Quality::Reference | Quality::ReferenceSingle => [0, 0, 0],
    };
    for &(q, t, s) in points {
        let x = 40.0 + (t.max(0.1).log10() + 1.0) * 65.0;
        let y = 290.0 - ((s - 0.9) / 0.1).clamp(0.0, 1.0) * 270.0;
        for dy in -3..=3 {
            for dx in -3..=3 {
                put(x as i64 + dx, y as i64 + dy, colour(q), &mut px);
            }
        }
    }
    for chunk in convergence.chunks(CONVERGENCE_SAMPLES.len()) {
        let pts: Vec<(f64, f64)> = chunk
            .iter()
            .map(|&(samples, e)| {
                (
                    360.0 + (samples.log2() - 2.0) / 2.0 * 65.0,
                    290.0 - (e / 0.05).clamp(0.0, 1.0) * 270.0,
                )
            })
            .collect();
        for win in pts.windows(2) {
            for i in 0..=100 {
                let f = i as f64 / 100.0;
                let (x, y) = (
                    win[0].0 + (win[1].0 - win[0].0) * f,
                    win[0].1 + (win[1].1 - win[0].1) * f,
                );
                put(x as i64, y as i64, [0, 0, 0], &mut px);
            }
        }
        for &(x, y) in &pts {
            for d in -2..=2 {
                put(x as i64 + d, y as i64, [0, 0, 0], &mut px);
                put(x as i64, y as i64 + d, [0, 0, 0], &mut px);
            }
        }
    }
    encode_png(w, h, png::ColorType::Rgb, PngSpace::Srgb, &px)
}
