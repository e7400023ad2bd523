//! Calibration harness of the billboard presets' light and edges against the path
//! tracer (`--quality reference`): for each preset, the figures the fit answers to,
//! and a grid search over the light model's constants.
//!
//! Scenes: the four of `bench::quality::SCENES` (SIZE × SIZE, t = 1800 s) and the
//! seven views of `bench::gallery::VIEWS` (SIZE × 9/16 SIZE, t = 43 200 s). The
//! reference of each (path-traced at SAMPLES per pixel) and the optical depth of its
//! view rays are rendered once and cached under `target/calibrate/` (keyed by scene,
//! size and samples; delete the folder after a change to the path tracer or the tile
//! planning). Each candidate re-shades the preset's tiles from density computed once.
//!
//! Figures per scene and preset:
//! - mean-radiance ratio (preset / reference, linear luminance) per bin of view optical
//!   depth, τ < 0.5, 0.5–2, 2–5, > 5 (`bench::quality::compare`);
//! - linear B/G and R/G of thick cloud (view τ > 2), preset (reference);
//! - contrast: the mean of the darkest tenth and of the brightest twentieth of the
//!   thick pixels' luminance (τ > 2; each picture's own quantile), preset / reference;
//! - coverage: pixels whose cloud opacity exceeds ½ (the preset's composited opacity,
//!   the reference's `1 − e^{−τ}`), preset / reference, and the edge band (opacity
//!   within 0.1–0.9) likewise.
//!
//! The objective of a candidate is the mean over scenes of: the mean of `ln²(ratio)`
//! over the scene's occupied τ bins, plus `ln²` of the B/G ratio and of the coverage
//! ratio.
//!
//!     cargo run --release --example calibrate_scattering -- SIZE SAMPLES PRESETS [KEY=V1,V2,…]…
//!
//! PRESETS is a comma list (`fast,balanced,accurate`); `set=quality` or
//! `set=gallery` restricts the scene set; `set=one-layer` draws the gallery views over
//! the default world's cumulus layer alone ([`CUMULUS_ONLY`]), which tells what the
//! layers above (which the billboards' light does not see) do to the figures. The
//! other keys override `ShadingParams` for every candidate of the grid (their
//! cartesian product): `n`, `a`, `b`, `c` (the octaves), `sky` (the sky-light
//! attenuation scale), `erosion` (detail erosion), `opacity` (the splat opacity
//! scale). Without keys it measures each preset's own light (`ShadingParams` left to
//! the preset).

use std::path::PathBuf;

use cloudscape_core::render::image::Image;
use cloudscape_core::render::scene::RenderRequest;
use cloudscape_core::render::{Camera, Quality, ShadingParams, Sun};
use cloudscape_core::world::{Config, DEFAULT_CONFIG, World};
use cloudscape_tools::bench::gallery::VIEWS;
use cloudscape_tools::bench::quality::{
    SCENE_WORLDS, SCENES, billboard_opacity, compare, luminance, scene_density, shade_grids, view_tau,
};

/// The default world's cumulus layer alone (the same seed and layer index, so the
/// same cumulus), for `set=one-layer`.
const CUMULUS_ONLY: &str = include_str!("../tests/data/cumulus_only.toml");

/// One view the fit answers to.
struct Scene {
    name: String,
    world: &'static str,
    camera: &'static str,
    sun: (f64, f64),
    t: f64,
    width: usize,
    height: usize,
}

impl Scene {
    fn request(&self, quality: Quality, samples: u32) -> Result<RenderRequest, String> {
        Ok(RenderRequest {
            camera: Camera::parse(self.camera).map_err(|e| e.to_string())?,
            width: self.width,
            height: self.height,
            t: self.t,
            quality,
            sun: Sun::new(self.sun.0, self.sun.1),
            params: ShadingParams::default(),
            samples,
        })
    }
}

/// The reference picture and the optical depth of its view rays, from the cache or
/// rendered (and cached).
fn reference(scene: &Scene, world: &World, config: &Config, samples: u32) -> Result<(Image, Vec<f64>), String> {
    let dir = PathBuf::from("target/calibrate");
    let path = dir.join(format!("{}-{}x{}-{samples}.bin", scene.name, scene.width, scene.height));
    let n = scene.width * scene.height;
    if let Ok(bytes) = std::fs::read(&path)
        && bytes.len() == n * 16
    {
        let f = |i: usize| f32::from_le_bytes(bytes[4 * i..4 * i + 4].try_into().unwrap());
        let mut img = Image::new(scene.width, scene.height);
        for i in 0..n {
            img.rgb[i] = [f(4 * i), f(4 * i + 1), f(4 * i + 2)];
            img.alpha[i] = 1.0;
        }
        let tau = (0..n).map(|i| f(4 * i + 3) as f64).collect();
        return Ok((img, tau));
    }
    let req = scene.request(Quality::Reference, samples)?;
    let (_, grids, plan) = scene_density(world, config, &req)?;
    let tiles = shade_grids(world, &req, &plan, grids)?;
    let img = cloudscape_core::view::draw(&tiles, &req, req.sun.ok_or("no sun")?).0;
    let tau = view_tau(&tiles, &req);
    let mut bytes = Vec::with_capacity(n * 16);
    for (rgb, &t) in img.rgb.iter().zip(&tau).take(n) {
        for v in [rgb[0], rgb[1], rgb[2], t as f32] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    std::fs::write(&path, bytes).map_err(|e| e.to_string())?;
    Ok((img, tau))
}

/// Mean of the lowest (`low`) or highest fraction `f` of `v`.
fn quantile_mean(mut v: Vec<f64>, f: f64, low: bool) -> Option<f64> {
    if v.len() < 20 {
        return None;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let k = ((v.len() as f64 * f).ceil() as usize).max(1);
    let s: &[f64] = if low { &v[..k] } else { &v[v.len() - k..] };
    Some(s.iter().sum::<f64>() / k as f64)
}

/// A preset's figures on one scene.
struct Figures {
    bins: [Option<f64>; 4],
    colour: Option<([f64; 2], [f64; 2])>,
    dark: Option<f64>,
    bright: Option<f64>,
    cover: (usize, usize),
    edge: (usize, usize),
    ssim: f64,
}

impl Figures {
    fn objective(&self) -> f64 {
        let occupied: Vec<f64> = self.bins.iter().flatten().map(|r| r.ln().powi(2)).collect();
        let mut o = occupied.iter().sum::<f64>() / occupied.len().max(1) as f64;
        if let Some((p, r)) = self.colour {
            o += (p[0] / r[0]).ln().powi(2);
        }
        if self.cover.1 > 0 {
            o += (self.cover.0.max(1) as f64 / self.cover.1 as f64).ln().powi(2);
        }
        o
    }

    fn line(&self) -> String {
        let f = |r: Option<f64>| r.map_or("–".to_string(), |v| format!("{v:.2}"));
        let (bg, rg) = self.colour.map_or(("–".into(), "–".into()), |(p, r)| {
            (
                format!("{:.3} ({:.3})", p[0], r[0]),
                format!("{:.3} ({:.3})", p[1], r[1]),
            )
        });
        let ratio = |(p, r): (usize, usize)| {
            if r > 0 {
                format!("{:.2}", p as f64 / r as f64)
            } else {
                "–".into()
            }
        };
        format!(
            "bins {} | B/G {bg} | R/G {rg} | dark {} bright {} | cover {} ({} px) edge {} | SSIM {:.3}",
            self.bins.map(f).join(" "),
            f(self.dark),
            f(self.bright),
            ratio(self.cover),
            self.cover.1,
            ratio(self.edge),
            self.ssim
        )
    }
}

fn measure(preset: &Image, opacity: &[f32], reference: &Image, tau: &[f64]) -> Figures {
    let (w, h) = (reference.width, reference.height);
    let c = compare(preset, reference, tau, w, h);
    let thick = |img: &Image| -> Vec<f64> {
        tau.iter()
            .enumerate()
            .filter(|(_, t)| **t > 2.0)
            .map(|(i, _)| luminance(img.rgb[i]))
            .collect()
    };
    let ratio = |a: Option<f64>, b: Option<f64>| Some(a? / b?);
    let dark = ratio(
        quantile_mean(thick(preset), 0.1, true),
        quantile_mean(thick(reference), 0.1, true),
    );
    let bright = ratio(
        quantile_mean(thick(preset), 0.05, false),
        quantile_mean(thick(reference), 0.05, false),
    );
    let covered_ref = tau.iter().filter(|t| **t > std::f64::consts::LN_2).count();
    let covered = opacity.iter().filter(|a| **a > 0.5).count();
    let band = |a: f64| a > 0.1 && a < 0.9;
    let edge_ref = tau.iter().filter(|t| band(1.0 - (-**t).exp())).count();
    let edge = opacity.iter().filter(|a| band(**a as f64)).count();
    Figures {
        bins: c.radiance_ratio,
        colour: c.thick_colour,
        dark,
        bright,
        cover: (covered, covered_ref),
        edge: (edge, edge_ref),
        ssim: c.ssim,
    }
}

/// The grid's keys and their values.
type Grid = Vec<(String, Vec<f64>)>;

fn candidates(grid: &Grid) -> Vec<Vec<(String, f64)>> {
    let mut out: Vec<Vec<(String, f64)>> = vec![Vec::new()];
    for (k, vs) in grid {
        out = out
            .into_iter()
            .flat_map(|c| {
                vs.iter().map(move |&v| {
                    let mut c = c.clone();
                    c.push((k.clone(), v));
                    c
                })
            })
            .collect();
    }
    out
}

/// The preset's own light with the candidate's overrides.
fn params_for(preset: Quality, candidate: &[(String, f64)]) -> Result<ShadingParams, String> {
    let mut p = ShadingParams::default();
    if candidate.is_empty() {
        return Ok(p);
    }
    let mut light = preset.light();
    for (k, v) in candidate {
        match k.as_str() {
            "n" => light.octaves.count = *v as u32,
            "a" => light.octaves.attenuation = *v,
            "b" => light.octaves.contribution = *v,
            "c" => light.octaves.eccentricity = *v,
            "sky" => light.sky_extinction_scale = *v,
            "erosion" => light.detail_erosion = *v,
            "opacity" => light.opacity_scale = *v,
            _ => return Err(format!("unknown key `{k}`")),
        }
    }
    p.light = Some(light);
    Ok(p)
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize, d: usize| -> Result<usize, String> {
        args.get(i)
            .map(|s| s.parse().map_err(|_| format!("argument {i} must be a number")))
            .transpose()
            .map(|v| v.unwrap_or(d))
    };
    let size = num(0, 128)?;
    let samples = num(1, 128)? as u32;
    let presets: Vec<Quality> = args
        .get(2)
        .map_or("fast,balanced,accurate", |s| s.as_str())
        .split(',')
        .map(|s| Quality::parse(s).ok_or(format!("unknown preset `{s}`")))
        .collect::<Result<_, _>>()?;
    let mut grid: Grid = Vec::new();
    let mut set = String::from("all");
    for a in args.iter().skip(3) {
        let (k, v) = a.split_once('=').ok_or(format!("`{a}` is not KEY=V1,V2"))?;
        if k == "set" {
            set = v.to_string();
            continue;
        }
        let vs = v
            .split(',')
            .map(|x| x.parse::<f64>().map_err(|_| format!("`{a}`: not numbers")))
            .collect::<Result<Vec<_>, _>>()?;
        grid.push((k.to_string(), vs));
    }
    let config =
        Config::parse(&format!("{DEFAULT_CONFIG}\n{SCENE_WORLDS}\n{CUMULUS_ONLY}")).map_err(|e| e.to_string())?;
    let mut scenes = Vec::new();
    if set == "one-layer" {
        for v in &VIEWS {
            scenes.push(Scene {
                name: format!("{}-cumulus-only", v.name),
                world: "cumulus_only",
                camera: v.camera,
                sun: v.sun,
                t: v.t,
                width: size,
                height: size * 9 / 16,
            });
        }
    }
    if set == "all" || set == "quality" {
        for s in &SCENES {
            scenes.push(Scene {
                name: s.name.replace(' ', "-").replace('°', ""),
                world: s.world,
                camera: s.camera,
                sun: s.sun,
                t: 1800.0,
                width: size,
                height: size,
            });
        }
    }
    if set == "all" || set == "gallery" {
        for v in &VIEWS {
            scenes.push(Scene {
                name: v.name.to_string(),
                world: cloudscape_tools::bench::gallery::WORLD,
                camera: v.camera,
                sun: v.sun,
                t: v.t,
                width: size,
                height: size * 9 / 16,
            });
        }
    }
    /// A preset's density grids (with their levels) and its plan.
    type PresetDensity = (
        Quality,
        Vec<(cloudscape_core::density::Grid<f32>, usize)>,
        Vec<(usize, cloudscape_core::render::TileId)>,
    );
    struct Prepared {
        world: World,
        reference: Image,
        tau: Vec<f64>,
        presets: Vec<PresetDensity>,
    }
    let mut prepared = Vec::new();
    for s in &scenes {
        let world = config.world(s.world).ok_or("a scene world is missing")?;
        let t0 = std::time::Instant::now();
        let (reference, tau) = reference(s, &world, &config, samples)?;
        let mut ps = Vec::new();
        for &q in &presets {
            let (_, grids, plan) = scene_density(&world, &config, &s.request(q, samples)?)?;
            ps.push((q, grids, plan));
        }
        eprintln!("prepared {} ({:.1} s)", s.name, t0.elapsed().as_secs_f64());
        prepared.push(Prepared {
            world,
            reference,
            tau,
            presets: ps,
        });
    }
    for (pi, &q) in presets.iter().enumerate() {
        let mut best: Option<(f64, String)> = None;
        for cand in candidates(&grid) {
            let params = params_for(q, &cand)?;
            let mut total = 0.0;
            let mut lines = String::new();
            for (s, p) in scenes.iter().zip(&prepared) {
                let mut req = s.request(q, samples)?;
                req.params = params;
                let (_, grids, plan) = &p.presets[pi];
                let tiles = shade_grids(&p.world, &req, plan, grids.clone())?;
                let sun = req.sun.ok_or("no sun")?;
                let img = cloudscape_core::view::draw_billboards(&tiles, &req, sun);
                let opacity = billboard_opacity(&tiles, &req, sun);
                let f = measure(&img, &opacity, &p.reference, &p.tau);
                total += f.objective() / scenes.len() as f64;
                lines += &format!("\n  {:<28} {}", s.name, f.line());
            }
            let label: Vec<String> = cand.iter().map(|(k, v)| format!("{k}={v}")).collect();
            let head = format!("{} [{}]: objective {total:.4}", q.as_str(), label.join(" "));
            println!("{head}{lines}");
            if best.as_ref().is_none_or(|(o, _)| total < *o) {
                best = Some((total, head));
            }
        }
        if let Some((_, head)) = best {
            println!("best {head}");
        }
    }
    Ok(())
}
