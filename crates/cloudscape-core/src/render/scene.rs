//! A camera's view: which tiles and levels it needs, and the picture from them —
//! by the billboard compositor (what a client draws), the reference path tracer, or
//! the single-scattering ray marcher.
//!
//! Level choice (far = coarser): per layer, a quadtree over tiles. It starts from the
//! coarsest tiles that cover [`VIEW_DISTANCE`] around the camera and splits a tile into
//! its four children while one of its columns, at the tile's nearest distance from
//! the eye, would span more than the preset's `lod_pixels` pixels. A tile is kept
//! when its clouds or its shadow on the ground ([`ShadowReach`]) lie within the view
//! frustum and within `VIEW_DISTANCE` horizontally; its shadow matters because a
//! ground point reads the shadow of the tile its sun ray crosses, which is not the
//! tile above it (without it, a layer whose clouds are out of view left the ground
//! they shadow sunlit: a straight seam along the tile's shadowed edge). The work is
//! bounded: at most [`MAX_RENDER_TILES`] tiles and [`MAX_RENDER_PIXELS`] pixels (the
//! volumetric renderers at most [`MAX_REFERENCE_PIXELS`], and the path tracer at most
//! `[limits] max_path_samples` samples × pixels); a bigger request is refused up front.

use rayon::prelude::*;

use crate::cancel::Cancel;
use crate::world::{Config, Keyframe, World};

use super::camera::{Camera, View};
use super::image::Image;
use super::light::{Lighting, ShadingParams};
use super::march::{self, MarchParams, Volume};
use super::pathtrace::{self, Environment, Noise, PathParams};
use super::sun::Sun;
use super::tile::{ShadedTile, TILE_COLUMNS, TileId, shade_tile};
use super::{ParseError, Quality, RenderError};

/// Clouds farther than this (horizontally, metres) from the camera are not drawn.
pub const VIEW_DISTANCE: f64 = 30_000.0;
/// Where the ground's cloud shadow starts to fade into the tiles' mean shadow, as a
/// fraction of [`VIEW_DISTANCE`] (see [`background`]). Seen from low altitude the
/// ground between here and the view distance spans a few rows of pixels only; a fade
/// over the last 30 % drew as a line across the picture at the horizon, over the last
/// 60 % it spans about three times as many rows.
pub const SHADOW_FADE_START: f64 = 0.4;
/// Most tiles (over all layers) one render may compute.
pub const MAX_RENDER_TILES: usize = 24;
/// Largest image, pixels, for billboard presets.
pub const MAX_RENDER_PIXELS: usize = 4096 * 4096;
/// Largest image, pixels, for the volumetric renderers (path tracer and marcher).
pub const MAX_REFERENCE_PIXELS: usize = 1024 * 1024;

/// What to draw.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderRequest {
    /// Where the eye is and where it looks.
    pub camera: Camera,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// World-clock seconds.
    pub t: f64,
    /// The quality preset.
    pub quality: Quality,
    /// The sun; `None` follows the world clock.
    pub sun: Option<Sun>,
    /// The cloud's optical properties.
    pub params: ShadingParams,
    /// Samples per pixel of the path tracer (`reference`; other presets ignore it).
    pub samples: u32,
}

/// A rendered view and what went into it.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// The picture, linear RGB.
    pub image: Image,
    /// (layer, tile) of every tile drawn.
    pub tiles: Vec<(usize, TileId)>,
    /// Billboards drawn (0 for the volumetric renderers).
    pub billboards: usize,
    /// The sun used.
    pub sun: Sun,
    /// The path tracer's stated noise (`reference` only).
    pub noise: Option<Noise>,
}

/// Parses `WxH`.
pub fn parse_size(s: &str) -> Result<(usize, usize), ParseError> {
    let parts: Vec<&str> = s.split(['x', 'X']).collect();
    let nums: Vec<usize> = parts.iter().filter_map(|p| p.trim().parse::<usize>().ok()).collect();
    if parts.len() != 2 || nums.len() != 2 || nums[0] == 0 || nums[1] == 0 {
        return Err(ParseError::Size(s.to_string()));
    }
    Ok((nums[0], nums[1]))
}

fn check_request(req: &RenderRequest) -> Result<(), RenderError> {
    crate::density::check_time(req.t)?;
    if req.width == 0 || req.height == 0 {
        return Err(RenderError::BadRequest("the image must be at least 1×1 pixels".into()));
    }
    let pixels = req.width.saturating_mul(req.height);
    let max = if req.quality.is_volumetric() {
        MAX_REFERENCE_PIXELS
    } else {
        MAX_RENDER_PIXELS
    };
    if pixels > max || req.width > 8192 || req.height > 8192 {
        return Err(RenderError::TooMuchWork(format!(
            "the image has {pixels} pixels; the limit for quality {} is {max}",
            req.quality.as_str()
        )));
    }
    if req.quality == Quality::Reference {
        if req.samples < 2 {
            return Err(RenderError::BadRequest(format!(
                "samples must be at least 2 (the noise estimate needs two), got {}",
                req.samples
            )));
        }
        if req.samples > pathtrace::MAX_SAMPLES {
            return Err(RenderError::TooMuchWork(format!(
                "{} samples per pixel; the limit is {}",
                req.samples,
                pathtrace::MAX_SAMPLES
            )));
        }
    }
    Ok(())
}

/// The path tracer's budget: samples × pixels within `max_path_samples`.
fn check_samples(req: &RenderRequest, max_path_samples: u64) -> Result<(), RenderError> {
    if req.quality != Quality::Reference {
        return Ok(());
    }
    let work = (req.width as u64)
        .saturating_mul(req.height as u64)
        .saturating_mul(req.samples as u64);
    if work > max_path_samples {
        return Err(RenderError::TooMuchWork(format!(
            "{} samples per pixel × {} pixels is {work} paths; the limit is {max_path_samples} \
             (lower the samples or the size)",
            req.samples,
            req.width * req.height
        )));
    }
    Ok(())
}

/// The geometry of a layer that the level choice needs: what a remote client learns
/// from `/v1/worlds/{world}` without the layer's full spec.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerBand {
    /// Altitude of the layer's bottom and top, metres.
    pub base: f64,
    /// Altitude of the layer's top, metres.
    pub top: f64,
    /// Level-0 column width, metres.
    pub cell_size: f64,
}

/// The tiles (layer, tile) the camera sees, per the level choice above, for the
/// request's sun (from the world clock when it names none).
pub fn plan(world: &World, config: &Config, req: &RenderRequest) -> Result<Vec<(usize, TileId)>, RenderError> {
    let bands: Vec<LayerBand> = world
        .layers
        .iter()
        .map(|l| LayerBand {
            base: l.base,
            top: l.top(),
            cell_size: l.cell_size,
        })
        .collect();
    check_samples(req, config.limits.max_path_samples)?;
    let req = RenderRequest {
        sun: Some(request_sun(config, req)),
        ..*req
    };
    plan_bands(&bands, config.limits.max_level, &req)
}

/// Where a tile's shadow falls on the ground, for the level choice: the tile moved
/// away from the sun by `(s_x, s_y) · z / s_z` for the altitudes `z` of its layer,
/// each move at most [`VIEW_DISTANCE`] long (a lower sun throws shadows farther than
/// the view reaches; their clouds are not fetched, and that ground stays sunlit).
/// The sun is the centre of the request's sun bucket, which the tiles are shaded for
/// (`render::tile::shadow_shift` reads the maps with it); with no sun, or the sun at
/// or below the horizon, shadows fall straight down.
#[derive(Clone, Copy, Debug, PartialEq)]
struct ShadowReach {
    /// Horizontal move of a shadow per metre of altitude, away from the sun.
    per_metre: [f64; 2],
}

impl ShadowReach {
    fn new(sun: Option<Sun>) -> ShadowReach {
        let per_metre = match sun.map(|s| s.bucket().centre().direction()) {
            Some(s) if s[2] > 0.0 => {
                let k = 1.0 / s[2].max(1f64.to_radians().sin());
                [-s[0] * k, -s[1] * k]
            }
            _ => [0.0, 0.0],
        };
        ShadowReach { per_metre }
    }

    /// The move of the shadow of a point at altitude `z`.
    fn offset(&self, z: f64) -> [f64; 2] {
        let [x, y] = self.per_metre.map(|k| k * z.max(0.0));
        let len = (x * x + y * y).sqrt();
        let scale = if len > VIEW_DISTANCE { VIEW_DISTANCE / len } else { 1.0 };
        [x * scale, y * scale]
    }

    /// The longest move of a layer reaching up to `top`, metres.
    fn longest(&self, top: f64) -> f64 {
        let [x, y] = self.offset(top);
        (x * x + y * y).sqrt()
    }
}

/// [`plan`] over layer bands, with levels up to `max_level`; shadows fall for the
/// request's sun (straight down when it names none: a client that does not know the
/// clock's sun yet plans that first, and the same tiles and more once it knows it).
pub fn plan_bands(
    layers: &[LayerBand],
    max_level: u32,
    req: &RenderRequest,
) -> Result<Vec<(usize, TileId)>, RenderError> {
    check_request(req)?;
    let lod_pixels = req.quality.settings().lod_pixels;
    let cam = &req.camera;
    let (forward, right, up) = cam.basis();
    let tan_h = (cam.fov_deg.to_radians() / 2.0).tan();
    let tan_v = tan_h * req.height as f64 / req.width as f64;
    let pixel_angle = 2.0 * tan_h / req.width as f64;
    let p = cam.position;
    let reach = ShadowReach::new(req.sun);
    let mut out = Vec::new();
    for (li, l) in layers.iter().enumerate() {
        let (zb, zt) = (l.base, l.top);
        let tile_size = |z: u32| TILE_COLUMNS as f64 * l.cell_size * (z as f64).exp2();
        let mut z_top = 0;
        while tile_size(z_top) < 2.0 * VIEW_DISTANCE && z_top < max_level {
            z_top += 1;
        }
        let s = tile_size(z_top);
        let far = VIEW_DISTANCE + reach.longest(zt);
        let range = |c: f64| ((c - far) / s).floor() as i64..=((c + far) / s).floor() as i64;
        // The shadow's moves for the layer's base and top.
        let moves = [reach.offset(zb), reach.offset(zt)];
        let mut stack: Vec<TileId> = Vec::new();
        for y in range(p[1]) {
            for x in range(p[0]) {
                stack.push(TileId { z: z_top, x, y });
            }
        }
        while let Some(t) = stack.pop() {
            let size = tile_size(t.z);
            let (x0, y0) = (t.x as f64 * size, t.y as f64 * size);
            let (x1, y1) = (x0 + size, y0 + size);
            let dx = (x0 - p[0]).max(0.0).max(p[0] - x1);
            let dy = (y0 - p[1]).max(0.0).max(p[1] - y1);
            let dz = (zb - p[2]).max(0.0).max(p[2] - zt);
            // The shadow's bounding rectangle on the ground.
            let (mx0, mx1) = (moves[0][0].min(moves[1][0]), moves[0][0].max(moves[1][0]));
            let (my0, my1) = (moves[0][1].min(moves[1][1]), moves[0][1].max(moves[1][1]));
            let sdx = (x0 + mx0 - p[0]).max(0.0).max(p[0] - x1 - mx1);
            let sdy = (y0 + my0 - p[1]).max(0.0).max(p[1] - y1 - my1);
            if (dx * dx + dy * dy).sqrt() > VIEW_DISTANCE && (sdx * sdx + sdy * sdy).sqrt() > VIEW_DISTANCE {
                continue;
            }
            // Frustum culling: drop the tile if all corners of its box, of the ground
            // under it and of its shadow on the ground are outside one plane.
            let mut outside = [true; 5];
            for &cx in &[x0, x1] {
                for &cy in &[y0, y1] {
                    let corners = [
                        [cx, cy, zb.min(0.0)],
                        [cx, cy, zt],
                        [cx + moves[0][0], cy + moves[0][1], 0.0],
                        [cx + moves[1][0], cy + moves[1][1], 0.0],
                    ];
                    for [cx, cy, cz] in corners {
                        let r = [cx - p[0], cy - p[1], cz - p[2]];
                        let (a, b, f) = (
                            r[0] * right[0] + r[1] * right[1] + r[2] * right[2],
                            r[0] * up[0] + r[1] * up[1] + r[2] * up[2],
                            r[0] * forward[0] + r[1] * forward[1] + r[2] * forward[2],
                        );
                        let tests = [f < 0.0, a > f * tan_h, a < -f * tan_h, b > f * tan_v, b < -f * tan_v];
                        for i in 0..5 {
                            outside[i] &= tests[i];
                        }
                    }
                }
            }
            if outside.iter().any(|&o| o) {
                continue;
            }
            let dist = (dx * dx + dy * dy + dz * dz).sqrt().max(1.0);
            let column = l.cell_size * (t.z as f64).exp2();
            if t.z > 0 && column / (dist * pixel_angle) > lod_pixels {
                for (ox, oy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    stack.push(TileId {
                        z: t.z - 1,
                        x: t.x * 2 + ox,
                        y: t.y * 2 + oy,
                    });
                }
                if out.len() + stack.len() > 64 * MAX_RENDER_TILES {
                    return Err(RenderError::TooMuchWork(format!(
                        "the view needs more than {} tiles; the limit is {MAX_RENDER_TILES}",
                        64 * MAX_RENDER_TILES
                    )));
                }
                continue;
            }
            out.push((li, t));
        }
    }
    if out.len() > MAX_RENDER_TILES {
        return Err(RenderError::TooMuchWork(format!(
            "the view needs {} tiles; the limit is {MAX_RENDER_TILES} (narrow the view or lower the quality)",
            out.len()
        )));
    }
    out.sort_by_key(|(l, t)| (*l, t.z, t.y, t.x));
    Ok(out)
}

/// The sun of a request: given, or from the world clock.
pub fn request_sun(config: &Config, req: &RenderRequest) -> Sun {
    req.sun.unwrap_or_else(|| Sun::from_clock(req.t, &config.sun))
}

/// Plans the view and shades its tiles (in parallel).
pub fn prepare(world: &World, config: &Config, req: &RenderRequest) -> Result<Vec<ShadedTile>, RenderError> {
    prepare_cancellable(world, config, req, &Cancel::never())
}

/// [`prepare`] that stops shading tiles once `cancel` fires (then an error).
pub fn prepare_cancellable(
    world: &World,
    config: &Config,
    req: &RenderRequest,
    cancel: &Cancel,
) -> Result<Vec<ShadedTile>, RenderError> {
    let tiles = plan(world, config, req)?;
    let sun = request_sun(config, req);
    tiles
        .par_iter()
        .map(|&(layer, tile)| {
            shade_tile(
                world,
                layer,
                tile,
                tile_keyframe(world, layer, tile, req),
                req.quality,
                sun,
                &req.params,
                &config.limits,
                cancel,
            )
        })
        .collect()
}

/// The span a render's tile is shaded for: the keyframe containing the request's
/// time for the billboard presets (drawn between its ends by the animation rule,
/// [`crate::render::keyframe`], as a client draws it), the request's time itself for
/// the volumetric references (ground truth, no keyframes).
pub fn tile_keyframe(world: &World, layer: usize, tile: TileId, req: &RenderRequest) -> Keyframe {
    if req.quality.is_volumetric() {
        Keyframe::instant(req.t)
    } else {
        Keyframe::containing(req.t, &world.layers[layer], tile.z)
    }
}

/// The reference volumes of shaded tiles: each tile's density (with its halo, so
/// interpolation is seamless) answering for the tile's own box.
pub fn volumes(tiles: &[ShadedTile]) -> Vec<Volume> {
    tiles
        .iter()
        .map(|t| {
            let top = t.place.base + t.density.depth as f64 * t.place.cell_height;
            let bounds = [
                t.origin[0],
                t.origin[1],
                t.place.base,
                t.origin[0] + t.size,
                t.origin[1] + t.size,
                top,
            ];
            Volume::new(t.density.clone(), t.place, bounds)
        })
        .collect()
}

/// The ray-marcher step for a set of tiles: the preset's step in cell heights, of the
/// thinnest cells.
pub fn reference_step(tiles: &[ShadedTile], quality: Quality) -> f64 {
    let h = tiles
        .iter()
        .map(|t| t.place.cell_height.min(t.column))
        .fold(f64::INFINITY, f64::min);
    let h = if h.is_finite() { h } else { 100.0 };
    h * quality.settings().march_step_cells
}

/// Draws `volumes` with the single-scattering ray marcher for the exact `sun`.
pub fn draw_single(volumes: &[Volume], req: &RenderRequest, sun: Sun, params: &MarchParams) -> Image {
    draw_single_cancellable(volumes, req, sun, params, &Cancel::never())
}

fn draw_single_cancellable(
    volumes: &[Volume],
    req: &RenderRequest,
    sun: Sun,
    params: &MarchParams,
    cancel: &Cancel,
) -> Image {
    let view = View::perspective(&req.camera, req.width, req.height);
    let lighting = Lighting::new(sun, req.params);
    march::render_cancellable(volumes, &lighting, params, &view, true, cancel)
}

/// Draws `volumes` with the path tracer for the exact `sun`, `req.samples` samples
/// per pixel, under the clear sky over the ground.
pub fn draw_path_traced(volumes: &[Volume], req: &RenderRequest, sun: Sun) -> pathtrace::Traced {
    draw_path_traced_cancellable(volumes, req, sun, &Cancel::never())
}

fn draw_path_traced_cancellable(
    volumes: &[Volume],
    req: &RenderRequest,
    sun: Sun,
    cancel: &Cancel,
) -> pathtrace::Traced {
    draw_path_traced_with(volumes, req, sun, &PathParams::new(req.samples), cancel)
}

/// [`draw_path_traced`] with explicit path-tracer parameters (a sample range of its
/// own, say), stopping early once `cancel` fires.
pub fn draw_path_traced_with(
    volumes: &[Volume],
    req: &RenderRequest,
    sun: Sun,
    params: &PathParams,
    cancel: &Cancel,
) -> pathtrace::Traced {
    let view = View::perspective(&req.camera, req.width, req.height);
    let lighting = Lighting::new(sun, req.params);
    pathtrace::render_cancellable(volumes, Environment::world(&lighting), params, &view, cancel)
}

/// Draws shaded tiles with a volumetric renderer: the path tracer (`reference`, with
/// its noise) or the marcher (`reference-single`); `None` for a billboard preset,
/// which a client draws from the served products (`view::draw`).
pub fn draw_volumetric(
    tiles: &[ShadedTile],
    req: &RenderRequest,
    sun: Sun,
    cancel: &Cancel,
) -> Option<(Image, Option<Noise>)> {
    match req.quality {
        Quality::Reference => {
            let traced = draw_path_traced_cancellable(&volumes(tiles), req, sun, cancel);
            Some((traced.image, Some(traced.noise)))
        }
        Quality::ReferenceSingle => {
            let params = MarchParams::with_step(reference_step(tiles, req.quality));
            Some((
                draw_single_cancellable(&volumes(tiles), req, sun, &params, cancel),
                None,
            ))
        }
        Quality::Fast | Quality::Balanced | Quality::Accurate => None,
    }
}

/// Sky and ground (shadowed by `ground_t(x, y)`, the sun transmittance at a ground
/// point, and hazed by the air between the eye and it) behind the clouds. Beyond the
/// tiles the shadow is unknown: from [`SHADOW_FADE_START`] of [`VIEW_DISTANCE`] on it
/// turns into `far_t`, the mean shadow of the tiles drawn ([`mean_shadow`]), so the far
/// ground has neither a hard edge nor a sunlit band.
pub fn background(view: &View, lighting: &Lighting, far_t: f64, ground_t: impl Fn(f64, f64) -> f64 + Sync) -> Image {
    let mut img = Image::new(view.width, view.height);
    let w = view.width;
    img.rgb.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, px) in row.iter_mut().enumerate() {
            let (o, d) = view.ray(x as f64 + 0.5, y as f64 + 0.5);
            let t = if d[2] < 0.0 && o[2] > 0.0 && lighting.sun_dir[2] > 0.0 {
                let s = -o[2] / d[2];
                let (gx, gy) = (o[0] + d[0] * s, o[1] + d[1] * s);
                let r = ((gx - o[0]).powi(2) + (gy - o[1]).powi(2)).sqrt();
                let fade = smoothstep(SHADOW_FADE_START * VIEW_DISTANCE, VIEW_DISTANCE, r);
                let near = if fade < 1.0 { ground_t(gx, gy) } else { far_t };
                near + fade * (far_t - near)
            } else {
                1.0
            };
            *px = lighting.background(o, d, t).map(|v| v as f32);
        }
    });
    img.alpha.iter_mut().for_each(|a| *a = 1.0);
    img
}

/// The ground's mean sun transmittance under the tiles drawn, from each tile's mean
/// shadow `(layer, mean)`: the product over layers of the mean over each layer's
/// tiles (1 with no tiles).
pub fn mean_shadow(tiles: impl Iterator<Item = (usize, f64)>) -> f64 {
    let mut sums: Vec<(usize, f64, f64)> = Vec::new();
    for (layer, m) in tiles {
        let m = if m.is_finite() { m.clamp(0.0, 1.0) } else { 1.0 };
        match sums.iter_mut().find(|e| e.0 == layer) {
            Some(e) => {
                e.1 += m;
                e.2 += 1.0;
            }
            None => sums.push((layer, m, 1.0)),
        }
    }
    sums.iter().map(|e| e.1 / e.2).product()
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn req(camera: &str, quality: Quality) -> RenderRequest {
        RenderRequest {
            camera: Camera::parse(camera).unwrap(),
            width: 256,
            height: 128,
            t: 0.0,
            quality,
            sun: None,
            params: ShadingParams::default(),
            samples: pathtrace::DEFAULT_SAMPLES,
        }
    }

    #[test]
    fn plan_sees_tiles_in_front_and_bounds_work() {
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        let r = req("1000,1000,500,0,20,60", Quality::Balanced);
        let tiles = plan(&world, &config, &r).unwrap();
        assert!(!tiles.is_empty() && tiles.len() <= MAX_RENDER_TILES);
        // Looking north: no tile lies wholly south of the camera.
        for (li, t) in &tiles {
            let size = TILE_COLUMNS as f64 * world.layers[*li].cell_size * (t.z as f64).exp2();
            assert!((t.y + 1) as f64 * size > 1000.0, "{t:?}");
        }
        // Looking straight down from just above the clouds sees fewer tiles than a
        // wide view toward the horizon.
        let down = plan(&world, &config, &req("1000,1000,9000,0,-90,20", Quality::Balanced)).unwrap();
        assert!(down.len() <= tiles.len());
        let mut big = r;
        big.width = 100_000;
        assert!(matches!(plan(&world, &config, &big), Err(RenderError::TooMuchWork(_))));
        let mut bad_t = r;
        bad_t.t = -1.0;
        assert!(matches!(plan(&world, &config, &bad_t), Err(RenderError::Sim(_))));
    }

    #[test]
    fn plan_takes_the_tiles_whose_shadows_fall_in_view() {
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        let bands: Vec<LayerBand> = world
            .layers
            .iter()
            .map(|l| LayerBand {
                base: l.base,
                top: l.top(),
                cell_size: l.cell_size,
            })
            .collect();
        let cirrus = world.layers.iter().position(|l| l.name == "cirrus").unwrap();
        // The viewer's default view with a western sun at 28°: the cirrus tile south-west
        // of the eye is out of view, and its shadow (moved 15 km east) lies ahead.
        let mut r = req("12800,-6000,900,0,6,75", Quality::Fast);
        (r.width, r.height) = (1280, 720);
        r.sun = Some(Sun::new(275.0, 28.0).unwrap());
        let with_sun = plan(&world, &config, &r).unwrap();
        let straight_down = plan_bands(&bands, config.limits.max_level, &RenderRequest { sun: None, ..r }).unwrap();
        let west = (cirrus, TileId { z: 0, x: -1, y: -1 });
        assert!(with_sun.contains(&west), "{with_sun:?}");
        assert!(!straight_down.contains(&west), "{straight_down:?}");
        // Knowing the sun only adds tiles (a client that learns it later fetches more).
        assert!(straight_down.iter().all(|t| with_sun.contains(t)));
        // A sun at the horizon throws shadows at most the view distance far: the
        // gallery's sunset view stays within the work limit.
        let mut sunset = req("12800,12800,300,270,6,75", Quality::Balanced);
        (sunset.width, sunset.height) = (640, 360);
        sunset.sun = Some(Sun::new(270.0, 2.0).unwrap());
        let tiles = plan(&world, &config, &sunset).unwrap();
        assert!(tiles.len() <= MAX_RENDER_TILES, "{}", tiles.len());
    }

    #[test]
    fn size_parses() {
        assert_eq!(parse_size("512x256").unwrap(), (512, 256));
        assert_eq!(parse_size("0x5"), Err(ParseError::Size("0x5".into())));
        assert!(parse_size("5").is_err());
        assert!(parse_size("-5x5").is_err());
        assert_eq!(
            ParseError::Size("5".into()).to_string(),
            "size must be WxH with positive integers, got `5`"
        );
    }
}
