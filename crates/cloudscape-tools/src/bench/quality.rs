//! What each quality preset buys: time and error against the reference path tracer,
//! per view of the quality set ([`SCENES`]) and of the gallery ([`gallery::VIEWS`]).
//! [`QualitySetup`] says at which size, against how many samples per pixel and on
//! which views; `cloudscape bench --only quality` publishes the full setup, the
//! issue's condition: 160×120 pixels against a 512-spp reference.
//!
//! Beside RMSE and SSIM of display luma, the figures a single score hides:
//! - **radiance by optical depth**: the pixels are binned by the optical depth τ of
//!   the reference's view ray through the density (τ 0.05–0.5, 0.5–2, 2–5, > 5; from
//!   [`march::view_optical_depth`]; below [`CLEAR_TAU`] a ray sees clear sky and is in
//!   no bin), and per bin the preset's mean linear luminance is divided by the
//!   reference's. Thin edges and deep cores fail differently (multiple scattering
//!   matters most where τ is large); 1 is right.
//! - **the colour of thick cloud**: linear B/G and R/G of the summed radiance of the
//!   pixels whose view ray has τ > [`THICK_TAU`] (= 2: at most e⁻² = 13.5 % of what is
//!   behind shows through, so the colour is the cloud's own, and both pictures are
//!   summed over the same pixels), preset's beside reference's.
//! - **cloud-covered pixels**: pixels whose cloud hides at least [`COVER_OPACITY`] of
//!   what is behind it, preset's count over the reference's ([`cover_ratio`]): the area
//!   a person sees as cloud, inside the outline. The reference's opacity is that of its
//!   view ray, 1 − e^(−τ); a preset's is its billboards' coverage alpha
//!   ([`billboard_opacity`]), the fraction of the sky and ground it hides.
//! - **sharpness**: the high-frequency energy of the display luma (the mean square
//!   of its 5-point Laplacian), preset over reference. Below 1 is blur, above is
//!   detail the reference does not have. The reference's own is measured without its
//!   Monte Carlo noise: it is rendered as two independent halves `A`, `B` (disjoint
//!   sample ranges, [`PathParams::first_sample`]) and its energy taken as the mean of
//!   `∇²A · ∇²B`, in which the independent noises cancel in expectation
//!   ([`cross_high_frequency_energy`]); the mean square of one noisy image would count
//!   the noise as detail. The same halves give the noise ceiling of SSIM: `SSIM(A, B)`,
//!   the split-half SSIM.
//!
//! Reference renders are the cost of this table (minutes each at 512 spp), so they
//! are kept on disk ([`ReferenceCache`], `target/quality-ref/` from the CLI), keyed
//! by view, size, samples, `ALGORITHM_VERSION` and a hash of the scene's inputs.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::gallery::{self, GalleryView};
use crate::chart::{Mark, PALETTE, Panel, Series, render};
use cloudscape_core::cancel::Cancel;
use cloudscape_core::density;
use cloudscape_core::products::keyframe_bin::Quantisation;
use cloudscape_core::render::camera::View;
use cloudscape_core::render::composite::composite;
use cloudscape_core::render::image::{Image, rmse, ssim};
use cloudscape_core::render::light::Lighting;
use cloudscape_core::render::march;
use cloudscape_core::render::pathtrace::{DEFAULT_SAMPLES, PathParams};
use cloudscape_core::render::scene::{self, RenderRequest};
use cloudscape_core::render::tile::{ShadedTile, shade_density, tile_density};
use cloudscape_core::render::{Camera, Quality, ShadingParams, Sun};
use cloudscape_core::view::held_tiles;
use cloudscape_core::world::{ALGORITHM_VERSION, Config, DEFAULT_CONFIG, World};

use super::{BenchRun, Effort};

/// Samples per pixel of the reference of [`request`] (the calibration's).
pub const REFERENCE_SAMPLES: u32 = 64;

/// One-layer worlds of the scene set (shared with `benches/render_trade.rs`).
pub const SCENE_WORLDS: &str = include_str!("scene_worlds.toml");

/// A camera over a world of [`scene_config`], with the sun and the time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scene {
    /// Row label in the tables and plots.
    pub name: &'static str,
    /// The world it looks at.
    pub world: &'static str,
    /// `X,Y,Z,YAW,PITCH,FOV` (see `render --camera`).
    pub camera: &'static str,
    /// Sun azimuth and elevation, degrees.
    pub sun: (f64, f64),
    /// World time, seconds.
    pub t: f64,
}

/// The speed–accuracy scene set.
#[rustfmt::skip] // one scene a line
pub const SCENES: [Scene; 4] = [
    Scene { name: "stratus deck from below", world: "stratus", camera: "12800,12800,20,0,35,70", sun: (150.0, 45.0), t: 1800.0 },
    Scene { name: "cumulus field at 45°", world: "cumulus", camera: "12800,6000,5000,0,-45,60", sun: (200.0, 45.0), t: 1800.0 },
    Scene { name: "altocumulus from above", world: "altocumulus", camera: "10240,10240,7000,30,-60,60", sun: (120.0, 50.0), t: 1800.0 },
    Scene { name: "low sun at the horizon", world: "cumulus", camera: "12800,3000,700,0,6,70", sun: (5.0, 1.0), t: 1800.0 },
];

impl Scene {
    /// A view of the gallery, in its world.
    pub fn from_gallery(v: &GalleryView) -> Scene {
        Scene {
            name: v.name,
            world: gallery::WORLD,
            camera: v.camera,
            sun: v.sun,
            t: v.t,
        }
    }

    /// The request for `quality` at `size` (width, height) pixels; the path tracer
    /// takes `samples` per pixel.
    pub fn request(&self, quality: Quality, size: (usize, usize), samples: u32) -> Result<RenderRequest, String> {
        Ok(RenderRequest {
            camera: Camera::parse(self.camera).map_err(|e| e.to_string())?,
            width: size.0,
            height: size.1,
            t: self.t,
            quality,
            sun: Some(Sun::new(self.sun.0, self.sun.1).ok_or("a scene's sun is out of range")?),
            params: ShadingParams::default(),
            samples,
        })
    }

    /// The name as a file-name stem and `--quality-views` key: lower-case words joined
    /// by `-` (`stratus-deck-from-below`; a gallery view's name is one already).
    pub fn slug(&self) -> String {
        let mut s = String::new();
        for w in self
            .name
            .split(|c: char| !c.is_alphanumeric())
            .filter(|w| !w.is_empty())
        {
            if !s.is_empty() {
                s.push('-');
            }
            s.push_str(&w.to_lowercase());
        }
        s
    }
}

/// Every view the quality table covers: the scene set, then the gallery's views.
pub fn all_scenes() -> Vec<Scene> {
    SCENES
        .iter()
        .copied()
        .chain(gallery::VIEWS.iter().map(Scene::from_gallery))
        .collect()
}

/// The embedded config with [`SCENE_WORLDS`]: every world of [`all_scenes`].
pub fn scene_config() -> Result<Config, String> {
    Config::parse(&format!("{DEFAULT_CONFIG}\n{SCENE_WORLDS}")).map_err(|e| e.to_string())
}

/// The request of scene `s` for preset `q` at `size` × `size` pixels, the reference at
/// [`REFERENCE_SAMPLES`] (the calibration's and `benches/render_trade.rs`'s).
pub fn request(s: &Scene, q: Quality, size: usize) -> Result<RenderRequest, String> {
    s.request(q, (size, size), REFERENCE_SAMPLES)
}

/// View rays thinner than this see clear sky: they are in no radiance bin.
pub const CLEAR_TAU: f64 = 0.05;
/// Upper edges of the view optical-depth bins above [`CLEAR_TAU`] (the last is open).
pub const TAU_BIN_EDGES: [f64; 3] = [0.5, 2.0, 5.0];
/// Labels of the bins.
pub const TAU_BIN_LABELS: [&str; 4] = ["τ 0.05–0.5", "0.5–2", "2–5", "> 5"];
/// View rays thicker than this are thick cloud, whose colour is compared.
pub const THICK_TAU: f64 = 2.0;
/// A pixel is cloud-covered when its cloud hides at least this fraction of what is
/// behind it. A tenth (τ ≥ 0.105 on a view ray) is where an outline shows on a
/// picture: a cloud two to four times as bright as the sky behind it raises the
/// pixel's luminance by 10–30 %, well above the few per cent a person notices at an
/// edge, while a wisp hiding a twentieth (the lowest radiance bin's edge) is barely
/// there.
pub const COVER_OPACITY: f64 = 0.1;

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
    /// The colour of thick cloud (view rays with τ > [`THICK_TAU`]): linear B/G and
    /// R/G of the summed radiance of those pixels, preset's and reference's (`None`
    /// without any).
    pub thick_colour: Option<([f64; 2], [f64; 2])>,
}

/// Linear B/G and R/G of the summed radiance `sum`.
fn colour_ratios(sum: [f64; 3]) -> [f64; 2] {
    [sum[2] / sum[1], sum[0] / sum[1]]
}

/// Linear luminance (Rec. 709 weights) of a linear RGB radiance.
pub fn luminance(c: [f32; 3]) -> f64 {
    0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64
}

/// The bin of optical depth `tau`; `None` for clear sky (below [`CLEAR_TAU`]).
pub fn tau_bin(tau: f64) -> Option<usize> {
    (tau >= CLEAR_TAU).then(|| TAU_BIN_EDGES.iter().take_while(|&&e| tau >= e).count())
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
/// have optical depths `tau` (row-major). Its sharpness is that of the noisy
/// reference at full resolution; [`Reference::sharpness`] measures it without the
/// reference's noise.
pub fn compare(preset: &Image, reference: &Image, tau: &[f64], width: usize, height: usize) -> Comparison {
    let (d, r) = (preset.display(), reference.display());
    let mut sums = [(0.0f64, 0.0f64, 0usize); 4];
    let (mut thick_p, mut thick_r) = ([0.0f64; 3], [0.0f64; 3]);
    for (i, &t) in tau.iter().enumerate() {
        if let Some(b) = tau_bin(t) {
            sums[b].0 += luminance(preset.rgb[i]);
            sums[b].1 += luminance(reference.rgb[i]);
            sums[b].2 += 1;
        }
        if t > THICK_TAU {
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

/// The coverage of the billboards of `tiles` in each pixel of `req`, row-major: the
/// alpha of `view::held::draw`'s compositing pass (the same billboards, as a client
/// holds them, at `req.t`, lit by the centre of `sun`'s bucket) drawn over nothing,
/// so it is the fraction of the sky and ground the cloud hides.
pub fn billboard_opacity(tiles: &[ShadedTile], req: &RenderRequest, sun: Sun) -> Vec<f32> {
    let view = View::perspective(&req.camera, req.width, req.height);
    let lighting = Lighting::for_quality(sun.bucket().centre(), req.params, req.quality);
    let billboards: Vec<_> = held_tiles(tiles, Quantisation::DEFAULT)
        .iter()
        .flat_map(|t| t.billboards_at(req.t))
        .collect();
    let mut image = Image::new(req.width, req.height);
    composite(&mut image, &billboards, &lighting, &view);
    image.alpha
}

/// Pixels of `opacity` at or above [`COVER_OPACITY`].
pub fn covered(opacity: impl IntoIterator<Item = f64>) -> usize {
    opacity.into_iter().filter(|&a| a >= COVER_OPACITY).count()
}

/// The reference's cloud-covered pixels: view rays of optical depth `tau` whose
/// opacity 1 − e^(−τ) reaches [`COVER_OPACITY`].
pub fn covered_by_tau(tau: &[f64]) -> usize {
    covered(tau.iter().map(|&t| 1.0 - (-t).exp()))
}

/// The preset's cloud-covered pixels over the reference's (`None` when the reference
/// has none).
pub fn cover_ratio(preset_opacity: &[f32], tau: &[f64]) -> Option<f64> {
    let r = covered_by_tau(tau);
    (r > 0).then(|| covered(preset_opacity.iter().map(|&a| a as f64)) as f64 / r as f64)
}

/// FNV-1a, 64 bits: a stable hash (the same on every machine and build) for file names.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Reference renders kept on disk, one file a view, size and sample count:
/// `<slug>-<W>x<H>-<N>spp-v<ALGORITHM_VERSION>-<hash>.ref`, the hash over the whole
/// config (as JSON), the world, camera, sun, time and shading parameters. A change
/// to any of them, or a new algorithm version, is a new file; a change to the path
/// tracer must bump `ALGORITHM_VERSION` anyway (its bytes are served). A file holds
/// the two halves (linear RGB, f32), the view rays' optical depths (f32) and the
/// times the run that made it measured.
#[derive(Clone, Debug)]
pub struct ReferenceCache {
    dir: PathBuf,
}

/// First line of a cache file.
const CACHE_MAGIC: &str = "cloudscape-reference 1";

impl ReferenceCache {
    /// A cache in `dir` (created when the first reference is stored).
    pub fn new(dir: impl Into<PathBuf>) -> ReferenceCache {
        ReferenceCache { dir: dir.into() }
    }

    /// Where the reference of `req` (a scene of `config`) is kept.
    pub fn path(&self, config: &Config, scene: &Scene, req: &RenderRequest) -> PathBuf {
        let inputs = format!(
            "{}\n{}\n{}\n{:?}\n{}\n{:?}",
            serde_json::to_value(config).map(|v| v.to_string()).unwrap_or_default(),
            scene.world,
            scene.camera,
            scene.sun,
            scene.t,
            req.params
        );
        self.dir.join(format!(
            "{}-{}x{}-{}spp-v{ALGORITHM_VERSION}-{:016x}.ref",
            scene.slug(),
            req.width,
            req.height,
            req.samples,
            fnv1a(inputs.as_bytes())
        ))
    }

    /// The reference kept at `path`; `None` if there is none or it does not read as
    /// one of `width` × `height` pixels.
    fn load(path: &Path, width: usize, height: usize, samples: u32) -> Option<Reference> {
        let bytes = std::fs::read(path).ok()?;
        let nl = bytes.iter().position(|&b| b == b'\n')?;
        let header = std::str::from_utf8(&bytes[..nl]).ok()?;
        let fields: Vec<&str> = header.strip_prefix(CACHE_MAGIC)?.split_whitespace().collect();
        let [w, h, tiles, density_s, draw_s] = fields[..] else {
            return None;
        };
        if (w.parse::<usize>().ok()?, h.parse::<usize>().ok()?) != (width, height) {
            return None;
        }
        let n = width * height;
        let body = &bytes[nl + 1..];
        if body.len() != (2 * 3 * n + n) * 4 {
            return None;
        }
        let mut floats = body
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
        let mut half = || {
            let mut img = Image::new(width, height);
            for p in img.rgb.iter_mut() {
                *p = [(); 3].map(|_| floats.next().unwrap_or(f32::NAN));
            }
            img.alpha.iter_mut().for_each(|a| *a = 1.0);
            img
        };
        let halves = [half(), half()];
        let tau: Vec<f64> = floats.map(|v| v as f64).collect();
        Some(Reference::from_halves(
            halves,
            tau,
            StageTimes {
                density_s: density_s.parse().ok()?,
                billboards_s: 0.0,
                draw_s: draw_s.parse().ok()?,
            },
            tiles.parse().ok()?,
            samples,
            true,
        ))
    }

    /// Keeps `r` at `path`, whole or not at all (written aside, then renamed).
    fn store(path: &Path, r: &Reference) -> Result<(), String> {
        let dir = path.parent().unwrap_or(Path::new("."));
        std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
        let mut bytes = format!(
            "{CACHE_MAGIC} {} {} {} {} {}\n",
            r.image.width, r.image.height, r.tiles, r.times.density_s, r.times.draw_s
        )
        .into_bytes();
        for h in &r.halves {
            bytes.extend(h.rgb.iter().flatten().flat_map(|v| v.to_le_bytes()));
        }
        bytes.extend(r.tau.iter().flat_map(|&t| (t as f32).to_le_bytes()));
        let tmp = path.with_extension("ref.tmp");
        std::fs::write(&tmp, &bytes).map_err(|e| format!("cannot write {}: {e}", tmp.display()))?;
        std::fs::rename(&tmp, path).map_err(|e| format!("cannot write {}: {e}", path.display()))
    }
}

/// The reference of one view: path-traced as two independent halves of its samples,
/// the optical depth of its view rays, and its times.
pub struct Reference {
    /// The mean of the halves: the render at all the samples.
    pub image: Image,
    /// Two independent renders, each at half the samples (disjoint sample ranges).
    pub halves: [Image; 2],
    /// Optical depth of every view ray (row-major, capped at 50).
    pub tau: Vec<f64>,
    /// Density and drawing times (no billboards).
    pub times: StageTimes,
    /// Tiles drawn.
    pub tiles: usize,
    /// Samples per pixel, both halves together.
    pub samples: u32,
    /// Read from a [`ReferenceCache`]: its times are those of the run that stored it.
    pub cached: bool,
}

impl Reference {
    fn from_halves(
        halves: [Image; 2],
        tau: Vec<f64>,
        times: StageTimes,
        tiles: usize,
        samples: u32,
        cached: bool,
    ) -> Reference {
        let mut image = halves[0].clone();
        for (p, q) in image.rgb.iter_mut().zip(&halves[1].rgb) {
            for (p, &q) in p.iter_mut().zip(q) {
                *p = 0.5 * (*p + q);
            }
        }
        Reference {
            image,
            halves,
            tau,
            times,
            tiles,
            samples,
            cached,
        }
    }

    /// SSIM of display luma of one half against the other: what the reference's own
    /// noise leaves of a perfect score (a preset is compared with the mean of both
    /// halves, which is less noisy, so this is a lower bound of its ceiling).
    pub fn split_half_ssim(&self) -> f64 {
        let [a, b] = &self.halves;
        ssim(&a.display(), &b.display(), a.width, a.height)
    }

    /// Seconds a `cloudscape render --quality reference` of this view would take at
    /// `samples` per pixel: density plus the drawing scaled by samples (the path
    /// tracer's time is its samples' time; this leaves out its fixed costs, so it
    /// errs fast).
    pub fn total_at(&self, samples: u32) -> f64 {
        self.times.density_s + self.times.draw_s * samples as f64 / self.samples as f64
    }

    /// The preset picture `image`'s high-frequency energy over the reference's, on
    /// [`sharpness_block`]-pixel blocks, the reference's measured across its halves
    /// so its noise does not count as detail; `None` where the reference's detail is
    /// within three standard errors of 0 (it does not stand out of its noise).
    pub fn sharpness(&self, image: &Image) -> Option<f64> {
        let (w, h) = (self.image.width, self.image.height);
        let k = sharpness_block(w.min(h));
        let [a, b] = &self.halves;
        let (ba, bw, bh) = binned(&a.display(), w, h, k);
        let (bb, _, _) = binned(&b.display(), w, h, k);
        let (hf, se) = cross_high_frequency_energy(&ba, &bb, bw, bh);
        let (bp, _, _) = binned(&image.display(), w, h, k);
        (hf > 3.0 * se).then(|| high_frequency_energy(&bp, bw, bh) / hf)
    }

    /// Pixels per optical-depth bin (clear sky left out).
    pub fn bin_counts(&self) -> [usize; 4] {
        let mut counts = [0usize; 4];
        self.tau.iter().filter_map(|&t| tau_bin(t)).for_each(|b| counts[b] += 1);
        counts
    }
}

/// The reference of `scene` at `size` pixels and `samples` per pixel: from `cache`
/// when it holds it, else path-traced (and kept there).
pub fn reference(
    world: &World,
    config: &Config,
    scene: &Scene,
    size: (usize, usize),
    samples: u32,
    cache: Option<&ReferenceCache>,
) -> Result<Reference, String> {
    let req = scene.request(Quality::Reference, size, samples)?;
    let path = cache.map(|c| c.path(config, scene, &req));
    if let Some(r) = path
        .as_deref()
        .and_then(|p| ReferenceCache::load(p, size.0, size.1, samples))
    {
        return Ok(r);
    }
    let (density_s, grids, plan) = scene_density(world, config, &req)?;
    let tiles = shade_grids(world, &req, &plan, grids)?;
    let sun = req.sun.ok_or("the scene has no sun")?;
    let t = Instant::now();
    let split = split_reference(&tiles, &req, sun);
    let draw_s = t.elapsed().as_secs_f64();
    // At the precision the cache keeps, so a cached reference measures as a fresh one.
    let tau = view_tau(&tiles, &req).into_iter().map(|t| t as f32 as f64).collect();
    let r = Reference::from_halves(
        split.halves,
        tau,
        StageTimes {
            density_s,
            billboards_s: 0.0,
            draw_s,
        },
        tiles.len(),
        samples,
        false,
    );
    if let Some(p) = &path {
        ReferenceCache::store(p, &r)?;
    }
    Ok(r)
}

/// A billboard preset's picture of one view and its figures against the reference.
pub struct PresetFigures {
    pub quality: Quality,
    pub times: StageTimes,
    /// Billboards drawn.
    pub billboards: usize,
    /// The picture, linear RGB.
    pub image: Image,
    /// Against the reference; its sharpness is [`Reference::sharpness`] (NaN where
    /// the reference's detail is noise).
    pub comparison: Comparison,
    /// Cloud-covered pixels, preset over reference ([`cover_ratio`]).
    pub cover: Option<f64>,
}

/// Renders `scene` with the billboard preset `quality` at the reference's size,
/// timing each stage, and compares it with `reference`.
pub fn measure_preset(
    world: &World,
    config: &Config,
    scene: &Scene,
    quality: Quality,
    reference: &Reference,
) -> Result<PresetFigures, String> {
    let (w, h) = (reference.image.width, reference.image.height);
    let req = scene.request(quality, (w, h), reference.samples)?;
    let sun = req.sun.ok_or("the scene has no sun")?;
    let (density_s, grids, plan) = scene_density(world, config, &req)?;
    let t1 = Instant::now();
    let tiles = shade_grids(world, &req, &plan, grids)?;
    let billboards_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let (image, _) = cloudscape_core::view::draw(&tiles, &req, sun);
    let draw_s = t2.elapsed().as_secs_f64();
    let mut comparison = compare(&image, &reference.image, &reference.tau, w, h);
    comparison.sharpness = reference.sharpness(&image).unwrap_or(f64::NAN);
    let cover = cover_ratio(&billboard_opacity(&tiles, &req, sun), &reference.tau);
    Ok(PresetFigures {
        quality,
        times: StageTimes {
            density_s,
            billboards_s,
            draw_s,
        },
        billboards: tiles.iter().map(|t| t.billboards.len()).sum(),
        image,
        comparison,
        cover,
    })
}

/// What the quality table measures: the picture size, the reference's samples, the
/// presets and the views, and where references are kept.
#[derive(Clone, Debug)]
pub struct QualitySetup {
    /// Width and height of every picture, pixels.
    pub size: (usize, usize),
    /// Samples per pixel of the reference.
    pub samples: u32,
    /// The billboard presets compared.
    pub presets: Vec<Quality>,
    /// The views, each a row group of the table.
    pub scenes: Vec<Scene>,
    /// Where references are kept between runs (`None`: path-traced every run).
    pub cache: Option<ReferenceCache>,
}

/// Every billboard preset, the columns of the quality table and the gallery.
pub const PRESETS: [Quality; 3] = [Quality::Fast, Quality::Balanced, Quality::Accurate];

impl QualitySetup {
    /// `Full` is the condition for the SSIM targets: 160×120 against a 512-spp
    /// reference, on the scene set and the gallery's views. `Quick` is one view of
    /// each at 96×72 against 64 spp; `Smoke` one scene, `fast`, 32×24 against 8 spp.
    pub fn for_effort(effort: Effort) -> QualitySetup {
        let (size, samples, presets, scenes) = match effort {
            Effort::Smoke => ((32, 24), 8, vec![Quality::Fast], vec![SCENES[0]]),
            Effort::Quick => (
                (96, 72),
                64,
                PRESETS.to_vec(),
                vec![SCENES[0], Scene::from_gallery(&gallery::VIEWS[0])],
            ),
            Effort::Full => ((160, 120), 512, PRESETS.to_vec(), all_scenes()),
        };
        QualitySetup {
            size,
            samples,
            presets,
            scenes,
            cache: None,
        }
    }

    /// Only the views named (a scene's name, or its [`Scene::slug`]), from every view
    /// of [`all_scenes`], in that order.
    pub fn only_views(mut self, names: &[String]) -> Result<QualitySetup, String> {
        let all = all_scenes();
        self.scenes = names
            .iter()
            .map(|n| {
                all.iter()
                    .find(|s| s.name == n || s.slug() == *n)
                    .copied()
                    .ok_or_else(|| {
                        let known: Vec<String> = all.iter().map(Scene::slug).collect();
                        format!("no quality view `{n}` (views: {})", known.join(", "))
                    })
            })
            .collect::<Result<_, _>>()?;
        Ok(self)
    }

    /// References kept in `cache` between runs.
    pub fn with_cache(mut self, cache: ReferenceCache) -> QualitySetup {
        self.cache = Some(cache);
        self
    }
}

/// The prose and header of a table of [`table_rows`] at `size` against `samples` spp.
pub fn table_header(size: (usize, usize), samples: u32) -> String {
    format!(
        "{w}×{h} pixels against `reference` (path tracer, {samples} samples per pixel) on the same tiles. \
         Time: the whole render (density, billboards, drawing); speed-up: against `cloudscape render \
         --quality reference` at its default {DEFAULT_SAMPLES} samples per pixel, the measured reference's \
         drawing time scaled by samples (its fixed costs left out, so the speed-up errs low), and against the \
         {samples}-spp reference in brackets. RMSE of display RGB in [0, 1], SSIM of display luma. \
         Mean-radiance ratio (preset / reference, linear luminance) per bin of the reference view ray's \
         optical depth τ (clear sky, τ < {CLEAR_TAU}, in none; target 0.85–1.15). Thick cloud (τ > {THICK_TAU}): \
         linear B/G and R/G of its summed radiance, preset (reference) (target: B/G within 3 % of the \
         reference's). Sharpness: high-frequency energy of display luma (mean square of its Laplacian), preset / \
         reference, on {k}×{k}-pixel blocks, the reference's without its noise (from two independent halves of \
         its samples; \"– (noise)\" where it is within three standard errors of 0). Cloud px: pixels whose cloud \
         hides at least {COVER_OPACITY} of what is behind (reference: view-ray opacity 1 − e^(−τ); presets: the \
         billboards' coverage alpha), preset / reference. The reference row: its time at {samples} spp (\
         \"cached\": measured by the run that stored it), its split-half SSIM (one half of its samples against \
         the other: the noise ceiling), its pixels per τ bin, its thick cloud's colour, its cloud-covered \
         pixels.\n\n\
         | view | quality | time | RMSE | SSIM | speed-up | {} | {} | {} | {} | thick B/G | thick R/G | sharpness | cloud px |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
        TAU_BIN_LABELS[0],
        TAU_BIN_LABELS[1],
        TAU_BIN_LABELS[2],
        TAU_BIN_LABELS[3],
        w = size.0,
        h = size.1,
        k = sharpness_block(size.0.min(size.1)),
    )
}

/// A speed-up, `12×` or `0.4×`.
fn fmt_ratio(r: f64) -> String {
    if r < 9.95 {
        format!("{r:.1}×")
    } else {
        format!("{r:.0}×")
    }
}

/// The rows of one view: every preset's, then the reference's.
pub fn table_rows(name: &str, reference: &Reference, presets: &[PresetFigures]) -> String {
    let f = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |v| format!("{v:.d$}"));
    let mut md = String::new();
    for p in presets {
        let c = &p.comparison;
        let total = p.times.total(p.quality);
        let bins: Vec<String> = c.radiance_ratio.iter().map(|&r| f(r, 2)).collect();
        let (bg, rg) = c.thick_colour.map_or(("–".into(), "–".into()), |(p, r)| {
            (
                format!("{:.3} ({:.3})", p[0], r[0]),
                format!("{:.3} ({:.3})", p[1], r[1]),
            )
        });
        md += &format!(
            "| {name} | {} | {:.2} s | {:.4} | {:.3} | {} ({}) | {} | {bg} | {rg} | {} | {} |\n",
            p.quality.as_str(),
            total,
            c.rmse,
            c.ssim,
            fmt_ratio(reference.total_at(DEFAULT_SAMPLES) / total),
            fmt_ratio(reference.times.total(Quality::Reference) / total),
            bins.join(" | "),
            if c.sharpness.is_finite() {
                format!("{:.2}", c.sharpness)
            } else {
                "– (noise)".into()
            },
            f(p.cover, 2),
        );
    }
    let colour = presets
        .iter()
        .find_map(|p| p.comparison.thick_colour)
        .map_or(("–".into(), "–".into()), |(_, r)| {
            (format!("{:.3}", r[0]), format!("{:.3}", r[1]))
        });
    md += &format!(
        "| {name} | reference | {:.1} s{} | – | split half {:.3} | 1 ({DEFAULT_SAMPLES} spp: {:.1} s) | {} | {} | {} | 1 | {} px |\n",
        reference.times.total(Quality::Reference),
        if reference.cached { " (cached)" } else { "" },
        reference.split_half_ssim(),
        reference.total_at(DEFAULT_SAMPLES),
        reference.bin_counts().map(|n| format!("{n} px")).join(" | "),
        colour.0,
        colour.1,
        covered_by_tau(&reference.tau),
    );
    md
}

/// `lo – hi` of the finite values of `v`, each written by `f` (`–` if none).
fn range_of(v: &[f64], f: impl Fn(f64) -> String) -> String {
    let v: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return "–".to_string();
    }
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    format!("{} – {}", f(lo), f(hi))
}

/// Each preset's range over the views (each view's reference and presets) against
/// the targets.
fn target_summary(views: &[(Reference, Vec<PresetFigures>)]) -> String {
    let samples = views.first().map_or(0, |v| v.0.samples);
    let mut md = format!(
        "\nEach preset over every view above (min – max; targets: τ-bin ratios 0.85–1.15, thick B/G within \
         3 % of the reference's, SSIM `balanced` ≥ 0.95 and `accurate` ≥ 0.97 at 160×120 against 512 spp, \
         `balanced` ≥ 20× faster than the reference at the same size):\n\n\
         | quality | SSIM | split-half SSIM of the references | τ-bin ratios | thick B/G / reference's | cloud px | \
         speed-up against {DEFAULT_SAMPLES} spp | against {samples} spp |\n\
         |---|---|---|---|---|---|---|---|\n"
    );
    let range = |v: &[f64], d: usize| range_of(v, |x| format!("{x:.d$}"));
    let ceilings: Vec<f64> = views.iter().map(|(r, _)| r.split_half_ssim()).collect();
    for q in PRESETS {
        let figs: Vec<(&PresetFigures, &Reference)> = views
            .iter()
            .flat_map(|(r, ps)| ps.iter().filter(|p| p.quality == q).map(move |p| (p, r)))
            .collect();
        if figs.is_empty() {
            continue;
        }
        let ssims: Vec<f64> = figs.iter().map(|(p, _)| p.comparison.ssim).collect();
        let bins: Vec<f64> = figs
            .iter()
            .flat_map(|(p, _)| p.comparison.radiance_ratio.iter().flatten().copied())
            .collect();
        let bg: Vec<f64> = figs
            .iter()
            .filter_map(|(p, _)| p.comparison.thick_colour.map(|(a, b)| a[0] / b[0]))
            .collect();
        let cover: Vec<f64> = figs.iter().filter_map(|(p, _)| p.cover).collect();
        let speed = |at: &dyn Fn(&Reference) -> f64| -> Vec<f64> {
            figs.iter().map(|(p, r)| at(r) / p.times.total(q)).collect()
        };
        md += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
            q.as_str(),
            range(&ssims, 3),
            range(&ceilings, 3),
            range(&bins, 2),
            range(&bg, 3),
            range(&cover, 2),
            range_of(&speed(&|r| r.total_at(DEFAULT_SAMPLES)), fmt_ratio),
            range_of(&speed(&|r| r.times.total(Quality::Reference)), fmt_ratio),
        );
    }
    md
}

/// The speed–accuracy table: every preset against the reference, per view of `setup`.
pub fn speed_accuracy(setup: &QualitySetup, out: &mut BenchRun, progress: &mut dyn FnMut(&str)) -> Result<(), String> {
    let config = scene_config()?;
    let mut md = format!(
        "Views: the scene set of `benches/render_trade.rs` (one-layer worlds, t = 1800 s) and the gallery's \
         (`cloudscape gallery`, world `default`, t = 43200 s), {} in all. ",
        setup.scenes.len()
    );
    md += &table_header(setup.size, setup.samples);
    let mut points: Vec<(Quality, f64, f64)> = Vec::new();
    let mut summary = Vec::new();
    for s in &setup.scenes {
        let world = config.world(s.world).ok_or_else(|| format!("no world `{}`", s.world))?;
        let t = Instant::now();
        let r = reference(&world, &config, s, setup.size, setup.samples, setup.cache.as_ref())?;
        progress(&format!(
            "quality: {} reference, {} spp: {} ({:.1} s)",
            s.name,
            setup.samples,
            if r.cached { "cached" } else { "path-traced" },
            t.elapsed().as_secs_f64()
        ));
        let mut presets = Vec::new();
        for &q in &setup.presets {
            let p = measure_preset(&world, &config, s, q, &r)?;
            points.push((q, p.times.after_density(q), p.comparison.ssim));
            presets.push(p);
        }
        md += &table_rows(s.name, &r, &presets);
        points.push((Quality::Reference, r.times.after_density(Quality::Reference), 1.0));
        summary.push((r, presets));
    }
    md += &target_summary(&summary);
    if let Some(c) = &setup.cache {
        md += &format!(
            "\nReferences are kept in `{}` (one file a view, size and sample count, keyed by \
             ALGORITHM_VERSION and a hash of the scene's inputs): a rerun path-traces only what is \
             missing.\n",
            c.dir.display()
        );
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

    #[test]
    fn clear_sky_is_in_no_bin_and_the_bins_meet_at_their_edges() {
        assert_eq!(tau_bin(0.0), None);
        assert_eq!(tau_bin(0.049), None);
        assert_eq!(tau_bin(0.05), Some(0));
        assert_eq!(tau_bin(0.5), Some(1));
        assert_eq!(tau_bin(4.99), Some(2));
        assert_eq!(tau_bin(50.0), Some(3));
        // A picture of clear sky and one cloud pixel: only that pixel is binned, and
        // a preset twice as bright there reads 2 in its bin, whatever the sky does.
        let mut reference = Image::new(2, 1);
        reference.rgb = vec![[0.2, 0.3, 0.6], [0.5, 0.5, 0.5]];
        let mut preset = reference.clone();
        preset.rgb = vec![[0.9, 0.9, 0.9], [1.0, 1.0, 1.0]];
        let c = compare(&preset, &reference, &[0.0, 3.0], 2, 1);
        assert_eq!(c.radiance_ratio[0], None);
        assert!((c.radiance_ratio[2].unwrap() - 2.0).abs() < 1e-9);
        let (p, r) = c.thick_colour.unwrap();
        assert_eq!((p, r), ([1.0, 1.0], [1.0, 1.0]));
    }

    #[test]
    fn cloud_cover_counts_what_hides_a_tenth_of_the_background() {
        // Opacity 1 − e^(−τ) reaches 0.1 at τ = ln(10/9) = 0.1054.
        assert_eq!(covered_by_tau(&[0.0, 0.1, 0.106, 3.0]), 2);
        assert_eq!(covered([0.0, 0.0999, 0.1, 1.0]), 2);
        assert_eq!(cover_ratio(&[0.5, 0.5, 0.0], &[1.0, 0.0, 0.0]), Some(2.0));
        assert_eq!(cover_ratio(&[0.5], &[0.0]), None, "no reference cloud, no ratio");
    }

    #[test]
    fn an_overcast_deck_covers_the_sky_in_every_picture() {
        // From below the stratus deck of the scene set, the reference sees cloud in
        // nearly every pixel, and `fast`'s billboards hide the sky there too.
        let config = scene_config().unwrap();
        let s = &SCENES[0];
        let world = config.world(s.world).unwrap();
        let r = reference(&world, &config, s, (24, 16), 4, None).unwrap();
        assert!(covered_by_tau(&r.tau) > 24 * 16 * 9 / 10, "{:?}", r.bin_counts());
        let p = measure_preset(&world, &config, s, Quality::Fast, &r).unwrap();
        let cover = p.cover.unwrap();
        assert!((0.9..=1.1).contains(&cover), "{cover}");
        // With no billboards nothing is hidden.
        let req = s.request(Quality::Fast, (8, 6), 4).unwrap();
        assert!(billboard_opacity(&[], &req, req.sun.unwrap()).iter().all(|&a| a == 0.0));
    }

    #[test]
    fn a_cached_reference_reads_back_as_it_was_stored() {
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
        let dir = std::env::temp_dir().join(format!("cloudscape-ref-cache-{}", std::process::id()));
        let cache = ReferenceCache::new(&dir);
        let config = scene_config().unwrap();
        let (w, h) = (3, 2);
        let half = |v: f32| {
            let mut img = Image::new(w, h);
            img.rgb = (0..w * h).map(|i| [v, v + i as f32, 0.25]).collect();
            img.alpha = vec![1.0; w * h];
            img
        };
        let times = StageTimes {
            density_s: 0.5,
            billboards_s: 0.0,
            draw_s: 12.25,
        };
        // Optical depths are kept as f32, as `reference` rounds them.
        let tau = [0.0, 0.1, 1.0, 2.0, 6.0, 50.0].map(|t: f64| t as f32 as f64).to_vec();
        let r = Reference::from_halves([half(1.0), half(3.0)], tau, times, 4, 8, false);
        assert_eq!(r.image.rgb[1], [2.0, 3.0, 0.25], "the mean of the halves");
        let req = SCENES[0].request(Quality::Reference, (w, h), 8).unwrap();
        let path = cache.path(&config, &SCENES[0], &req);
        ReferenceCache::store(&path, &r).unwrap();
        let back = ReferenceCache::load(&path, w, h, 8).unwrap();
        assert!(back.cached && !r.cached);
        assert_eq!(back.halves, r.halves);
        assert_eq!(back.image, r.image);
        assert_eq!(back.tau, r.tau);
        assert_eq!((back.times, back.tiles, back.samples), (times, 4, 8));
        // Another size does not read as this one; a truncated file reads as none.
        assert!(ReferenceCache::load(&path, 2, 3, 8).is_none());
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 1]).unwrap();
        assert!(ReferenceCache::load(&path, w, h, 8).is_none());
        // Another view, sample count or world config is another file.
        let other = |s: &Scene, samples: u32, c: &Config| {
            cache.path(c, s, &s.request(Quality::Reference, (w, h), samples).unwrap())
        };
        assert_ne!(other(&SCENES[1], 8, &config), path);
        assert_ne!(other(&SCENES[0], 16, &config), path);
        let mut changed = config.clone();
        changed.worlds.get_mut("stratus").unwrap().seed += 1;
        assert_ne!(other(&SCENES[0], 8, &changed), path);
        assert_eq!(
            other(&SCENES[0], 8, &config.clone()),
            path,
            "the same inputs, the same file"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn views_are_chosen_by_name_or_slug() {
        assert_eq!(SCENES[0].slug(), "stratus-deck-from-below");
        assert_eq!(SCENES[1].slug(), "cumulus-field-at-45");
        let all = all_scenes();
        assert_eq!(all.len(), SCENES.len() + gallery::VIEWS.len());
        let setup = QualitySetup::for_effort(Effort::Full)
            .only_views(&[
                "backlit".into(),
                "stratus deck from below".into(),
                "low-sun-at-the-horizon".into(),
            ])
            .unwrap();
        let names: Vec<&str> = setup.scenes.iter().map(|s| s.name).collect();
        assert_eq!(names, ["backlit", "stratus deck from below", "low sun at the horizon"]);
        assert_eq!((setup.size, setup.samples), ((160, 120), 512));
        let err = QualitySetup::for_effort(Effort::Full)
            .only_views(&["nowhere".into()])
            .unwrap_err();
        assert!(err.contains("nowhere") && err.contains("ground-noon"), "{err}");
        let config = scene_config().unwrap();
        for s in &all {
            assert!(config.world(s.world).is_some(), "{}", s.name);
        }
    }
}
