//! Calibration harness of the billboard paths' light model against the reference:
//! fits the scattering octaves (a, b, c of `render::light::Octaves`) and the scale of
//! the sky-light attenuation (`ShadingParams::sky_extinction_scale`) by grid search.
//!
//! Scenes: the four views and suns of `bench::quality::SCENES` (stratus from below,
//! cumulus at 45°, altocumulus from above, cumulus toward a sun at 1°), one preset
//! (`balanced` by default), t = 1800 s. For each scene the reference image and the
//! optical depth of its view rays are computed once; each candidate re-shades the
//! preset's tiles. The objective is the mean over scenes and occupied optical-depth
//! bins (τ < 0.5, 0.5–2, 2–5, > 5) of `ln(mean-radiance ratio)²`, so every bin of
//! every scene counts alike whatever its pixel count: a fit over several views and
//! suns, not one picture. It prints every candidate's objective, its worst bin and
//! mean SSIM, then the best.
//!
//!     cargo run --release --example calibrate_scattering -- [SIZE] [PRESET] [REFERENCE_DIR]
//!
//! The reference is whatever `Quality::Reference` renders (`scene::draw_reference`),
//! or, with `REFERENCE_DIR`, the PNGs `scene0.png` … `scene3.png` there (SIZE × SIZE,
//! display RGB of `tone_map`, inverted to linear radiance: `x = −ln(1 − d^2.2)`), as an
//! external renderer such as a path tracer wrote them for the same scenes (the
//! config of the scene worlds is written to `REFERENCE_DIR/scenes.toml`, and the
//! `cloudscape render` command of each scene is printed).

use cloudscape_core::render::image::Image;
use cloudscape_core::render::light::Octaves;
use cloudscape_core::render::{Quality, ShadingParams};
use cloudscape_core::world::{Config, DEFAULT_CONFIG};
use cloudscape_tools::bench::quality::{SCENE_WORLDS, SCENES, compare, request, scene_density, shade_grids, view_tau};

/// A tone-mapped PNG back to linear radiance.
fn read_reference(path: &std::path::Path, size: usize) -> Result<Image, String> {
    let file = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut decoder = png::Decoder::new(std::io::BufReader::new(file));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let mut buf = vec![0; reader.output_buffer_size().ok_or("PNG too large")?];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    if info.width as usize != size || info.height as usize != size {
        return Err(format!(
            "{} is {}x{}, expected {size}x{size}",
            path.display(),
            info.width,
            info.height
        ));
    }
    let ch = info.color_type.samples();
    let mut img = Image::new(size, size);
    let inv = |d: u8| {
        let d = (d as f64 / 255.0).powf(2.2).min(1.0 - 1e-4);
        (-(1.0 - d).ln()) as f32
    };
    for i in 0..size * size {
        img.rgb[i] = [inv(buf[i * ch]), inv(buf[i * ch + 1]), inv(buf[i * ch + 2])];
        img.alpha[i] = 1.0;
    }
    Ok(img)
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let size: usize = args
        .first()
        .map(|s| s.parse().map_err(|_| "SIZE must be a number"))
        .transpose()?
        .unwrap_or(128);
    let preset = args
        .get(1)
        .map(|s| Quality::parse(s).ok_or("PRESET must be fast | balanced | accurate"))
        .transpose()?
        .unwrap_or(Quality::Balanced);
    let text = format!("{DEFAULT_CONFIG}\n{SCENE_WORLDS}");
    let config = Config::parse(&text).map_err(|e| e.to_string())?;
    let external = args.get(2).map(std::path::PathBuf::from);
    if let Some(dir) = &external {
        std::fs::write(dir.join("scenes.toml"), &text).map_err(|e| e.to_string())?;
        for (i, s) in SCENES.iter().enumerate() {
            println!(
                "scene{i}: cloudscape render --config {}/scenes.toml --world {} --camera {} --t 1800 --size {size}x{size} --sun {},{} --out {}/scene{i}.png",
                dir.display(),
                s.world,
                s.camera,
                s.sun.0,
                s.sun.1,
                dir.display()
            );
        }
    }
    struct Prepared {
        world: cloudscape_core::world::World,
        reference: Image,
        tau: Vec<f64>,
        grids: Vec<(cloudscape_core::density::Grid<f32>, usize)>,
        plan: Vec<(usize, cloudscape_core::render::TileId)>,
    }
    let mut scenes = Vec::new();
    for (i, s) in SCENES.iter().enumerate() {
        let world = config.world(s.world).ok_or("a scene world is missing")?;
        let ref_req = request(s, Quality::Reference, size)?;
        let (_, grids, plan) = scene_density(&world, &config, &ref_req)?;
        let tiles = shade_grids(&world, &ref_req, &plan, grids)?;
        let sun = ref_req.sun.ok_or("no sun")?;
        // The path tracer (`Quality::Reference`), or PNGs of an external renderer.
        let reference = match &external {
            Some(dir) => read_reference(&dir.join(format!("scene{i}.png")), size)?,
            None => cloudscape_core::view::draw(&tiles, &ref_req, sun).0,
        };
        let tau = view_tau(&tiles, &ref_req);
        let req = request(s, preset, size)?;
        let (_, grids, plan) = scene_density(&world, &config, &req)?;
        eprintln!("prepared {}", s.name);
        scenes.push((
            s,
            Prepared {
                world,
                reference,
                tau,
                grids,
                plan,
            },
        ));
    }
    let defaults = std::env::var_os("CALIBRATE_DEFAULTS_ONLY").is_some();
    let mut best: Option<(f64, String)> = None;
    for count in [1u32, 2, 3, 4, 6] {
        for a in [0.25, 0.5, 0.75, 1.0] {
            for b in [0.25, 0.5, 0.75, 0.9] {
                if count == 1 && (a != 0.5 || b != 0.5) {
                    continue;
                }
                for sky in [0.25, 0.5, 1.0, 2.0, 4.0, 8.0] {
                    let d = ShadingParams::default();
                    if defaults
                        && (count != d.octaves.count
                            || a != d.octaves.attenuation
                            || b != d.octaves.contribution
                            || sky != d.sky_extinction_scale)
                    {
                        continue;
                    }
                    let params = ShadingParams {
                        octaves: Octaves {
                            count,
                            attenuation: a,
                            contribution: b,
                            eccentricity: 0.5,
                        },
                        sky_extinction_scale: sky,
                        ..ShadingParams::default()
                    };
                    let (mut sum, mut n, mut worst, mut ssim) = (0.0, 0, 1.0f64, 0.0);
                    let mut bins = String::new();
                    for (s, p) in &scenes {
                        let mut req = request(s, preset, size)?;
                        req.params = params;
                        let tiles = shade_grids(&p.world, &req, &p.plan, p.grids.clone())?;
                        let img = cloudscape_core::view::draw_billboards(&tiles, &req, req.sun.ok_or("no sun")?);
                        let c = compare(&img, &p.reference, &p.tau, size, size);
                        for r in c.radiance_ratio.iter().flatten() {
                            sum += r.ln().powi(2);
                            n += 1;
                            if (r.ln()).abs() > worst.ln().abs() {
                                worst = *r;
                            }
                        }
                        ssim += c.ssim / scenes.len() as f64;
                        let r: Vec<String> = c
                            .radiance_ratio
                            .iter()
                            .map(|r| r.map_or("-".into(), |r| format!("{r:.2}")))
                            .collect();
                        bins += &format!("\n    {}: SSIM {:.3}, bins {}", s.name, c.ssim, r.join(" "));
                    }
                    let objective = sum / n.max(1) as f64;
                    let line = format!(
                        "N={count} a={a} b={b} sky_scale={sky}: mean ln² {objective:.4}, worst bin {worst:.3}, mean SSIM {ssim:.3}"
                    );
                    println!("{line}");
                    if best.as_ref().is_none_or(|(o, _)| objective < *o) {
                        best = Some((objective, format!("{line}{bins}")));
                    }
                }
            }
        }
    }
    if let Some((_, line)) = best {
        println!("best: {line}");
    }
    Ok(())
}
