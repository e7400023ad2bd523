//! What each quality preset buys: time and error against the reference path tracer
//! (at [`REFERENCE_SAMPLES`] samples per pixel) on the scene set of
//! `benches/render_trade.rs` (which also measures the reference's own convergence;
//! this section is its speed–accuracy table).
//!
//! Beside RMSE and SSIM, two figures that a single score hides:
//! - **radiance by optical depth**: the pixels are binned by the optical depth of the
//!   reference's view ray through the density (τ < 0.5, 0.5–2, 2–5, > 5; from
//!   [`march::view_optical_depth`]), and per bin the preset's mean linear luminance is
//!   divided by the reference's. Thin edges and deep cores fail differently (multiple
//!   scattering matters most where τ is large); 1 is right.
//! - **sharpness**: the high-frequency energy of the display luma (the mean square
//!   of its 5-point Laplacian), preset over reference. Below 1 is blur, above is
//!   detail the reference does not have. The reference's own is measured without its
//!   Monte Carlo noise: it is rendered as two independent halves `A`, `B` (disjoint
//!   sample ranges, [`PathParams::first_sample`]) and its energy taken as the mean of
//!   `∇²A · ∇²B`, in which the independent noises cancel in expectation
//!   ([`cross_high_frequency_energy`]); the mean square of one noisy image would count
//!   the noise as detail. The same halves give the noise ceiling of SSIM: `SSIM(A, B)`.

use std::time::Instant;

use crate::chart::{Mark, PALETTE, Panel, Series, render};
use cloudscape_core::cancel::Cancel;
use cloudscape_core::density;
use cloudscape_core::render::camera::View;
use cloudscape_core::render::image::{Image, rmse, ssim};
use cloudscape_core::render::march;
use cloudscape_core::render::pathtrace::PathParams;
use cloudscape_core::render::scene::{self, RenderRequest};
use cloudscape_core::render::tile::{ShadedTile, shade_density, tile_density};
use cloudscape_core::render::{Camera, Quality, ShadingParams, Sun};
use cloudscape_core::world::{Config, DEFAULT_CONFIG, World};

use super::{BenchRun, Effort};

/// Samples per pixel of the reference the presets are measured against.
pub const REFERENCE_SAMPLES: u32 = 64;

/// One-layer worlds of the scene set (shared with `benches/render_trade.rs`).
pub const SCENE_WORLDS: &str = include_str!("scene_worlds.toml");

/// A camera over one of [`SCENE_WORLDS`], with the sun (azimuth, elevation in degrees).
pub struct Scene {
    /// Row label in the tables and plots.
    pub name: &'static str,
    /// The world of [`SCENE_WORLDS`] it looks at.
    pub world: &'static str,
    /// `X,Y,Z,YAW,PITCH,FOV` (see `render --camera`).
    pub camera: &'static str,
    /// Sun azimuth and elevation, degrees.
    pub sun: (f64, f64),
}

/// The speed–accuracy scene set.
#[rustfmt::skip] // one scene a line
pub const SCENES: [Scene; 4] = [
    Scene { name: "stratus deck from below", world: "stratus", camera: "12800,12800,20,0,35,70", sun: (150.0, 45.0) },
    Scene { name: "cumulus field at 45°", world: "cumulus", camera: "12800,6000,5000,0,-45,60", sun: (200.0, 45.0) },
    Scene { name: "altocumulus from above", world: "altocumulus", camera: "10240,10240,7000,30,-60,60", sun: (120.0, 50.0) },
    Scene { name: "low sun at the horizon", world: "cumulus", camera: "12800,3000,700,0,6,70", sun: (5.0, 1.0) },
];

/// Upper edges of the view optical-depth bins (the last bin is open).
pub const TAU_BIN_EDGES: [f64; 3] = [0.5, 2.0, 5.0];
/// Labels of the bins.
pub const TAU_BIN_LABELS: [&str; 4] = ["τ < 0.5", "0.5–2", "2–5", "> 5"];

/// A preset's picture against the reference's.
#[derive(Clone, Debug, PartialEq)]
pub struct Comparison {
    /// RMSE of display RGB in [0, 1].
    pub rmse: f64,
    /// SSIM of display luma.
    pub ssim: f64,
    /// Mean linear luminance of the preset over the reference's, per optical-depth
    /// bin ([`TAU_BIN_LABELS`]); `None` for a bin with no pixel.
    pub radiance_ratio: [Option<f64>; 4],
    /// High-frequency energy of the display luma, preset over reference.
    pub sharpness: f64,
    /// The colour of thick cloud (view rays with τ > 2): linear B/G and R/G of the
    /// mean radiance of those pixels, preset's and reference's (`None` without any).
    pub thick_colour: Option<([f64; 2], [f64; 2])>,
}

/// Linear B/G and R/G of the summed radiance `sum`.
fn colour_ratios(sum: [f64; 3]) -> [f64; 2] {
    [sum[2] / sum[1], sum[0] / sum[1]]
}

fn luminance(c: [f32; 3]) -> f64 {
    0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64
}

/// The bin of optical depth `tau`.
pub fn tau_bin(tau: f64) -> usize {
    TAU_BIN_EDGES.iter().take_while(|&&e| tau >= e).count()
}

/// Mean square of the 5-point Laplacian of the luma of `display` (interior pixels).
pub fn high_frequency_energy(display: &[[f32; 3]], width: usize, height: usize) -> f64 {
    if width < 3 || height < 3 {
        return 0.0;
    }
    let l = |x: usize, y: usize| luminance(display[y * width + x]);
    let mut sum = 0.0;
    for y in 1..height - 1 {
        for x in 1..width - 1 {
            let lap = 4.0 * l(x, y) - l(x - 1, y) - l(x + 1, y) - l(x, y - 1) - l(x, y + 1);
            sum += lap * lap;
        }
    }
    sum / ((width - 2) * (height - 2)) as f64
}

/// The mean of `∇²a · ∇²b` over interior pixels of the display lumas `a`, `b` (5-point
/// Laplacian), and the standard error of that mean: for two independent noisy
/// estimates of one picture, its high-frequency energy without the noise (the cross
/// term of independent zero-mean noises vanishes in expectation; its spread is what
/// the standard error states). `a` with itself is [`high_frequency_energy`].
pub fn cross_high_frequency_energy(a: &[[f32; 3]], b: &[[f32; 3]], width: usize, height: usize) -> (f64, f64) {
    if width < 3 || height < 3 || a.len() != width * height || b.len() != a.len() {
        return (0.0, 0.0);
    }
    let lap = |d: &[[f32; 3]], x: usize, y: usize| {
        let l = |x: usize, y: usize| luminance(d[y * width + x]);
        4.0 * l(x, y) - l(x - 1, y) - l(x + 1, y) - l(x, y - 1) - l(x, y + 1)
    };
    let (mut sum, mut sq) = (0.0, 0.0);
    for y in 1..height - 1 {
        for x in 1..width - 1 {
            let v = lap(a, x, y) * lap(b, x, y);
            sum += v;
            sq += v * v;
        }
    }
    let n = ((width - 2) * (height - 2)) as f64;
    let mean = sum / n;
    (mean, ((sq / n - mean * mean).max(0.0) / n).sqrt())
}

/// `display` (`width` × `height`) averaged over `k` × `k` blocks (edges that do not
/// fill a block are dropped), with its new size.
pub fn binned(display: &[[f32; 3]], width: usize, height: usize, k: usize) -> (Vec<[f32; 3]>, usize, usize) {
    let k = k.max(1);
    let (w, h) = (width / k, height / k);
    let mut out = vec![[0.0f32; 3]; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut c = [0.0f64; 3];
            for dy in 0..k {
                for dx in 0..k {
                    let p = display[(y * k + dy) * width + x * k + dx];
                    (0..3).for_each(|i| c[i] += p[i] as f64);
                }
            }
            out[y * w + x] = c.map(|v| (v / (k * k) as f64) as f32);
        }
    }
    (out, w, h)
}

/// Pixels per side of the blocks sharpness is measured on: the scale of a 128-pixel
/// picture. Finer, the path tracer's noise at 64 samples outweighs the detail (its
/// Laplacian energy per pixel falls with the pixel's size, the noise's does not) and
/// the cross energy is within its own standard error.
pub fn sharpness_block(size: usize) -> usize {
    (size / 128).max(1)
}

/// The reference drawn as two independent halves of `req.samples` (disjoint sample
/// ranges) and their mean, which is the full render's estimate.
pub struct SplitReference {
    pub image: Image,
    pub halves: [Image; 2],
}

/// Path-traces `tiles` for `req` as a [`SplitReference`].
pub fn split_reference(tiles: &[ShadedTile], req: &RenderRequest, sun: Sun) -> SplitReference {
    let vols = scene::volumes(tiles);
    let half = (req.samples / 2).max(2);
    let draw = |first: u32| {
        let params = PathParams {
            first_sample: first,
            ..PathParams::new(half)
        };
        scene::draw_path_traced_with(&vols, req, sun, &params, &Cancel::never()).image
    };
    let halves = [draw(0), draw(half)];
    let mut image = halves[0].clone();
    for (p, q) in image.rgb.iter_mut().zip(&halves[1].rgb) {
        for (p, &q) in p.iter_mut().zip(q) {
            *p = 0.5 * (*p + q);
        }
    }
    SplitReference { image, halves }
}

/// Compares `preset` with `reference` (same size, `width` × `height`) whose view rays
/// have optical depths `tau` (row-major).
pub fn compare(preset: &Image, reference: &Image, tau: &[f64], width: usize, height: usize) -> Comparison {
    let (d, r) = (preset.display(), reference.display());
    let mut sums = [(0.0f64, 0.0f64, 0usize); 4];
    let (mut thick_p, mut thick_r) = ([0.0f64; 3], [0.0f64; 3]);
    for (i, &t) in tau.iter().enumerate() {
        let b = tau_bin(t);
        sums[b].0 += luminance(preset.rgb[i]);
        sums[b].1 += luminance(reference.rgb[i]);
        sums[b].2 += 1;
        if t > 2.0 {
            for c in 0..3 {
                thick_p[c] += preset.rgb[i][c] as f64;
                thick_r[c] += reference.rgb[i][c] as f64;
            }
        }
    }
    let hf_ref = high_frequency_energy(&r, width, height);
    Comparison {
        rmse: rmse(&d, &r),
        ssim: ssim(&d, &r, width, height),
        radiance_ratio: sums.map(|(p, q, n)| if n > 0 && q > 0.0 { Some(p / q) } else { None }),
        sharpness: if hf_ref > 0.0 {
            high_frequency_energy(&d, width, height) / hf_ref
        } else {
            0.0
        },
        thick_colour: (thick_p[1] > 0.0 && thick_r[1] > 0.0).then(|| (colour_ratios(thick_p), colour_ratios(thick_r))),
    }
}

/// The optical depth of every view ray of `req` through the reference volumes of
/// `tiles` (capped at 50, far beyond the last bin).
pub fn view_tau(tiles: &[ShadedTile], req: &RenderRequest) -> Vec<f64> {
    let vols = scene::volumes(tiles);
    let step = scene::reference_step(tiles, Quality::Reference);
    let view = View::perspective(&req.camera, req.width, req.height);
    march::view_optical_depth(&vols, req.params.extinction, &view, step, 50.0)
}

/// Wall-clock seconds of each stage of one render: the time columns of the
/// speed–accuracy table (`benches/render_trade.rs` prints the same).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageTimes {
    /// Density of the planned tiles: the simulation, shared by every preset.
    pub density_s: f64,
    /// Metaballs and shading (billboards).
    pub billboards_s: f64,
    /// Drawing: the billboard compositor, or the path tracer.
    pub draw_s: f64,
}

impl StageTimes {
    /// The time after density: billboards and drawing, or for a volumetric quality
    /// (it draws the density volumes, not billboards) the drawing alone.
    pub fn after_density(&self, quality: Quality) -> f64 {
        if quality.is_volumetric() {
            self.draw_s
        } else {
            self.billboards_s + self.draw_s
        }
    }

    /// The whole render of `quality`.
    pub fn total(&self, quality: Quality) -> f64 {
        if quality.is_volumetric() {
            self.density_s + self.draw_s
        } else {
            self.density_s + self.billboards_s + self.draw_s
        }
    }

    /// How much faster `quality` drew than the `reference`: in total, and excluding
    /// density.
    pub fn speed_up(&self, quality: Quality, reference: &StageTimes) -> (f64, f64) {
        (
            reference.total(Quality::Reference) / self.total(quality),
            reference.after_density(Quality::Reference) / self.after_density(quality),
        )
    }

    /// A preset's cells of the table: density, billboards, draw and total (each time
    /// followed by `unit`), and the speed-ups against `reference`.
    pub fn preset_cells(&self, quality: Quality, reference: &StageTimes, unit: &str) -> String {
        let (speed, speed_ex) = self.speed_up(quality, reference);
        format!(
            "{:.2}{unit} | {:.2}{unit} | {:.3}{unit} | {:.2}{unit} | {speed:.0}× / {speed_ex:.0}×",
            self.density_s,
            self.billboards_s,
            self.draw_s,
            self.total(quality)
        )
    }
}

struct Measured {
    times: StageTimes,
    image: Image,
    tiles: Vec<ShadedTile>,
    /// The reference's independent halves (the path tracer only).
    halves: Option<[Image; 2]>,
}

/// The request of scene `s` for preset `q` at `size` × `size` pixels.
pub fn request(s: &Scene, q: Quality, size: usize) -> Result<RenderRequest, String> {
    Ok(RenderRequest {
        camera: Camera::parse(s.camera).map_err(|e| e.to_string())?,
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
    let (density_s, grids, plan) = scene_density(world, config, req)?;
    let t1 = Instant::now();
    let tiles = shade_grids(world, req, &plan, grids)?;
    let billboards_s = t1.elapsed().as_secs_f64();
    let sun = req.sun.ok_or("the scene has no sun")?;
    let t2 = Instant::now();
    let (image, halves) = if req.quality == Quality::Reference {
        let r = split_reference(&tiles, req, sun);
        (r.image, Some(r.halves))
    } else {
        (cloudscape_core::view::draw(&tiles, req, sun).0, None)
    };
    let draw_s = t2.elapsed().as_secs_f64();
    Ok(Measured {
        times: StageTimes {
            density_s,
            billboards_s,
            draw_s,
        },
        image,
        tiles,
        halves,
    })
}

/// The density grids (with halos) of the tiles `req` plans, and the time it took.
#[allow(clippy::type_complexity)]
pub fn scene_density(
    world: &World,
    config: &Config,
    req: &RenderRequest,
) -> Result<
    (
        f64,
        Vec<(density::Grid<f32>, usize)>,
        Vec<(usize, cloudscape_core::render::TileId)>,
    ),
    String,
> {
    let sun = req.sun.ok_or("the scene has no sun")?;
    let plan = scene::plan(world, config, req).map_err(|e| e.to_string())?;
    let t0 = Instant::now();
    let mut grids = Vec::new();
    for &(li, tile) in &plan {
        grids.push(
            tile_density(
                world,
                li,
                tile,
                req.t,
                req.quality,
                sun,
                &config.limits,
                &Cancel::never(),
            )
            .map_err(|e| e.to_string())?,
        );
    }
    Ok((t0.elapsed().as_secs_f64(), grids, plan))
}

/// Shades the density grids of [`scene_density`] for `req` (its preset and params).
pub fn shade_grids(
    world: &World,
    req: &RenderRequest,
    plan: &[(usize, cloudscape_core::render::TileId)],
    grids: Vec<(density::Grid<f32>, usize)>,
) -> Result<Vec<ShadedTile>, String> {
    let sun = req.sun.ok_or("the scene has no sun")?;
    Ok(plan
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
        .collect())
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
    let config = Config::parse(&format!("{DEFAULT_CONFIG}\n{SCENE_WORLDS}")).map_err(|e| e.to_string())?;
    let mut md = format!(
        "Scene set of `benches/render_trade.rs` (one-layer worlds, t = 1800 s), {size}×{size} pixels. Error against \
         `reference` (path tracer, {REFERENCE_SAMPLES} samples per pixel) on the same tiles: RMSE of display RGB in [0, 1], SSIM of luma. \
         Times: density (shared by every preset), billboards (metaballs + shading), draw. Speed-up against the \
         reference: total / excluding density. The reference's convergence is in `cargo bench --bench render_trade`. \
         Mean-radiance ratio (preset / reference, linear luminance) per bin of the reference view ray's optical \
         depth τ (targets 0.85–1.15), and the sharpness ratio (high-frequency energy of display luma, the mean \
         square of its Laplacian, preset / reference, on {k}×{k}-pixel blocks; the reference's without its noise, \
         from two independent halves of its samples, and \"– (noise)\" where that is within three standard errors \
         of 0). The reference row's SSIM is its noise ceiling: one half against the other. Colour of thick \
         cloud (view rays with τ > 2): linear B/G and R/G of its mean radiance, preset (reference) (target: B/G \
         within 3 % of the reference's).\n\n\
         | scene | preset | tiles | billboards | density | billboards | draw | total | speed-up | RMSE | SSIM | {} | {} | {} | {} | sharpness | B/G | R/G |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
        TAU_BIN_LABELS[0],
        TAU_BIN_LABELS[1],
        TAU_BIN_LABELS[2],
        TAU_BIN_LABELS[3],
        k = sharpness_block(size)
    );
    let mut points: Vec<(Quality, f64, f64)> = Vec::new();
    for s in scenes {
        let world = config.world(s.world).ok_or("a scene world is missing")?;
        let ref_req = request(s, Quality::Reference, size)?;
        let reference = measure(&world, &config, &ref_req)?;
        let tau = view_tau(&reference.tiles, &ref_req);
        let [ha, hb] = reference.halves.as_ref().ok_or("the reference has no halves")?;
        let (da, db) = (ha.display(), hb.display());
        let k = sharpness_block(size);
        let (ba, bw, bh) = binned(&da, size, size, k);
        let (bb, _, _) = binned(&db, size, size, k);
        let (hf_ref, hf_se) = cross_high_frequency_energy(&ba, &bb, bw, bh);
        // The reference's detail is measured only where it stands out of its noise.
        let hf_ref = if hf_ref > 3.0 * hf_se { hf_ref } else { f64::NAN };
        let ceiling = ssim(&da, &db, size, size);
        let mut counts = [0usize; 4];
        tau.iter().for_each(|&t| counts[tau_bin(t)] += 1);
        for &q in presets {
            let m = measure(&world, &config, &request(s, q, size)?)?;
            let mut c = compare(&m.image, &reference.image, &tau, size, size);
            let (bp, _, _) = binned(&m.image.display(), size, size, k);
            c.sharpness = high_frequency_energy(&bp, bw, bh) / hf_ref;
            let (e, ss) = (c.rmse, c.ssim);
            let bins: Vec<String> = c
                .radiance_ratio
                .iter()
                .map(|r| r.map_or("–".into(), |v| format!("{v:.2}")))
                .collect();
            let n: usize = m.tiles.iter().map(|t| t.billboards.len()).sum();
            let (bg, rg) = c.thick_colour.map_or(("–".into(), "–".into()), |(p, r)| {
                (
                    format!("{:.3} ({:.3})", p[0], r[0]),
                    format!("{:.3} ({:.3})", p[1], r[1]),
                )
            });
            md += &format!(
                "| {} | {} | {} | {n} | {} | {e:.4} | {ss:.3} | {} | {} | {bg} | {rg} |\n",
                s.name,
                q.as_str(),
                m.tiles.len(),
                m.times.preset_cells(q, &reference.times, " s"),
                bins.join(" | "),
                if c.sharpness.is_finite() {
                    format!("{:.2}", c.sharpness)
                } else {
                    "– (noise)".into()
                }
            );
            points.push((q, m.times.after_density(q), ss));
        }
        md += &format!(
            "| {} | reference | {} | – | {:.2} s | – | {:.2} s | {:.2} s | 1× | – | half vs half {ceiling:.3} | {} | 1 | | |\n",
            s.name,
            reference.tiles.len(),
            reference.times.density_s,
            reference.times.draw_s,
            reference.times.total(Quality::Reference),
            counts.map(|n| format!("{n} px")).join(" | ")
        );
        points.push((
            Quality::Reference,
            reference.times.after_density(Quality::Reference),
            1.0,
        ));
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
    out.add_plot("quality.png", png);
    out.add_section("quality", "Quality presets: speed against accuracy", md);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use cloudscape_core::fields::noise::mix64;

    /// Uniform noise in [−½, ½) from a counter.
    fn noise(i: u64) -> f32 {
        ((mix64(i) >> 40) as f32 / (1u64 << 24) as f32) - 0.5
    }

    #[test]
    fn cross_energy_keeps_detail_and_drops_independent_noise() {
        let (w, h) = (64, 64);
        // A checkerboard of period 8 px: detail both images share.
        let signal = |x: usize, y: usize| if (x / 4 + y / 4).is_multiple_of(2) { 0.7 } else { 0.3 };
        let img = |seed: u64, amp: f32| -> Vec<[f32; 3]> {
            (0..w * h)
                .map(|i| {
                    let v = signal(i % w, i / w) + amp * noise(seed * 1_000_003 + i as u64);
                    [v; 3]
                })
                .collect()
        };
        let clean = img(0, 0.0);
        let hf = high_frequency_energy(&clean, w, h);
        // Without noise the cross energy is the energy.
        assert!((cross_high_frequency_energy(&clean, &clean, w, h).0 - hf).abs() < 1e-12);
        // With noise as large as the detail, each image's own energy more than doubles,
        // while the cross energy of two independent draws stays within 10 % of the
        // clean one (the noise terms have mean 0 and a spread ~1/√pixels).
        let (a, b) = (img(1, 0.4), img(2, 0.4));
        let own = high_frequency_energy(&a, w, h);
        let (cross, se) = cross_high_frequency_energy(&a, &b, w, h);
        assert!(se > 0.0 && cross > 3.0 * se, "{cross} ± {se}");
        assert!(own > 1.5 * hf, "own {own} vs clean {hf}");
        assert!((cross / hf - 1.0).abs() < 0.1, "cross {cross} vs clean {hf}");
        // Flat picture, pure noise: no detail.
        let flat = |seed: u64| -> Vec<[f32; 3]> {
            (0..w * h)
                .map(|i| [0.5 + 0.3 * noise(seed + i as u64 * 7); 3])
                .collect()
        };
        let (fa, fb) = (flat(10), flat(20_000));
        let (flat_cross, flat_se) = cross_high_frequency_energy(&fa, &fb, w, h);
        assert!(flat_cross.abs() < 0.1 * high_frequency_energy(&fa, w, h));
        assert!(
            flat_cross.abs() < 4.0 * flat_se,
            "pure noise is within its standard error"
        );
        // Mismatched sizes are no detail, not a panic.
        assert_eq!(cross_high_frequency_energy(&fa, &fb[..10], w, h), (0.0, 0.0));
        // Blocks average: a 2×2 checkerboard of 0 and 1 bins to 0.5 everywhere.
        let board: Vec<[f32; 3]> = (0..16).map(|i| [((i % 4 + i / 4) % 2) as f32; 3]).collect();
        let (b, bw, bh) = binned(&board, 4, 4, 2);
        assert_eq!((bw, bh), (2, 2));
        assert!(b.iter().all(|p| p[0] == 0.5));
        assert_eq!(sharpness_block(512), 4);
        assert_eq!(sharpness_block(96), 1);
    }
}
