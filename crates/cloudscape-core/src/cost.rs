//! What a computation will cost, estimated before it starts: CPU-seconds and bytes
//! of working memory. The service refuses (413) what cannot finish inside its time
//! budget on its compute threads, or would need more memory than one request may
//! have, and reserves the memory of what it admits.
//!
//! The estimates count the units of work from the same planning code the work
//! uses (the automaton's dependency cones, the metaball lattice of a tile, the
//! tiles a view plans, its pixels) and turn them into seconds and bytes with the
//! constants below.
//!
//! Calibration: `cargo test --release -p cloudscape-core --lib cost::tests::calibrate
//! -- --ignored --nocapture` runs each kind of work on the default world, prints its
//! units, its measured CPU time (user + system of the process, from `/proc/self/stat`)
//! and peak RSS growth, and the estimate. The constants were fitted from that run on the
//! 2-core development machine (AMD EPYC, loaded by other work, so on the slow side)
//! and rounded up (the fitted values are beside each constant).

use crate::density::{self, Region, SimError};
use crate::render::scene::{RenderRequest, plan};
use crate::render::tile::{TILE_COLUMNS, tile_halo};
use crate::render::{Quality, RenderError, Sun, TileId};
use crate::world::{Config, Keyframe, Layer, World};

/// Estimated CPU time and working memory of one computation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Work {
    /// CPU-seconds, summed over threads.
    pub cpu_s: f64,
    /// Peak bytes it allocates.
    pub bytes: u64,
}

impl std::ops::Add for Work {
    type Output = Work;
    fn add(self, o: Work) -> Work {
        Work {
            cpu_s: self.cpu_s + o.cpu_s,
            bytes: self.bytes.saturating_add(o.bytes),
        }
    }
}

impl std::iter::Sum for Work {
    fn sum<I: Iterator<Item = Work>>(iter: I) -> Work {
        iter.fold(Work::default(), |a, b| a + b)
    }
}

/// CPU-seconds per automaton cell-step (a cell of a run's cone at one step: the
/// packed kernel and its draws). Measured 4e-10.
const CPU_S_PER_CELL_STEP: f64 = 5.0e-10;
/// CPU-seconds per output cell: fields, smoothing and encoding of the grid (level 0),
/// or the mean-field model (levels above 0). Measured 1e-8.
const CPU_S_PER_CELL: f64 = 1.5e-8;
/// Bytes per cell of the density grid and the automaton state behind it while it
/// is computed, and of the grid alone (`f32`) once it is.
const BYTES_PER_CELL: u64 = 24;
const KEPT_BYTES_PER_CELL: u64 = 4;

/// CPU-seconds per metaball lattice point of a shaded tile (collecting, shading,
/// encoding the products). Fitted to whole views (1.2e-6 for balanced and accurate,
/// whose tiles are partly clear sky); a tile full of dense cloud costs up to 3e-6 a
/// point (2.1 s for an `accurate` level-0 tile of the default world at noon), so a
/// view of nothing but dense cloud can take ~2.5× its estimate: the time budget and
/// cancellation catch those.
const CPU_S_PER_BALL: f64 = 1.2e-6;
/// Bytes per lattice point that a shaded tile keeps (its billboards), and that
/// shading it needs for a while (metaballs, the light buffer).
const KEPT_BYTES_PER_BALL: u64 = 72;
const SHADING_BYTES_PER_BALL: u64 = 300;
/// Bytes per lattice point of the encoded tile products (JSON, binary, atlas).
const ENCODED_BYTES_PER_BALL: u64 = 300;

/// Compositing, by preset (fast, balanced, accurate): CPU-seconds per pixel per tile
/// in view (the overdraw of billboards grows with both). Measured 2.8e-8, 1e-7, 3e-7.
const CPU_S_PER_PIXEL_TILE: [f64; 3] = [3.0e-8, 1.0e-7, 3.0e-7];
/// The reference ray marcher: CPU-seconds per pixel per march step across the
/// layers' thickness. Measured 1.3e-6 (96 steps in the default world).
const CPU_S_PER_PIXEL_STEP: f64 = 1.5e-6;
/// The reference path tracer: CPU-seconds per path (sample) of a pixel, measured on
/// the README's ground view of the default world (see BENCHMARKS.md "Rendering").
const CPU_S_PER_PATH: f64 = 4.0e-6;
/// Bytes per pixel of a rendered image: linear RGB + alpha in f32, and its PNG.
const BYTES_PER_PIXEL: u64 = 24;

fn preset_index(q: Quality) -> usize {
    match q {
        Quality::Fast => 0,
        Quality::Balanced => 1,
        Quality::Accurate | Quality::Reference | Quality::ReferenceSingle => 2,
    }
}

/// The work of `density::density(world, layer, level, region, t)`.
pub fn density(world: &World, layer: usize, level: u32, region: Region, t: f64) -> Result<Work, SimError> {
    let cell_steps = density::cell_steps(world, layer, level, region, t)?;
    let depth = world.layers.get(layer).map_or(1, |l| l.depth as u64);
    let cells = region.cols as u64 * region.rows as u64 * depth;
    Ok(Work {
        cpu_s: cell_steps as f64 * CPU_S_PER_CELL_STEP + cells as f64 * CPU_S_PER_CELL,
        bytes: cells.saturating_mul(BYTES_PER_CELL),
    })
}

/// Metaball lattice points of one tile of `l` at level `z` for preset `q`: the
/// upper bound of its billboards (every point full of cloud).
pub fn tile_balls(l: &Layer, z: u32, q: Quality) -> u64 {
    let s = q.settings();
    let per_side = (TILE_COLUMNS as f64 / s.spacing_columns).ceil() as u64;
    let column = l.cell_size * (z as f64).exp2();
    let levels = (((l.top() - l.base) / (s.spacing_columns * column)).round() as u64).max(1);
    per_side * per_side * levels
}

/// The work of one shaded tile over a keyframe span: at each end (one for an
/// instant), the density of the tile and its halo, then its metaballs and their
/// shading. `bytes` is what shading it needs at its peak; the second value is what the
/// [`crate::render::ShadedTile`] keeps afterwards.
fn shaded(
    world: &World,
    layer: usize,
    tile: TileId,
    keyframe: Keyframe,
    q: Quality,
    sun: Sun,
) -> Result<(Work, u64), RenderError> {
    let (start, kept) = shaded_at(world, layer, tile, keyframe.t0, q, sun)?;
    if keyframe.is_instant() {
        return Ok((start, kept));
    }
    // The end's density is taken over a box moved downwind: the same size.
    let (end, end_kept) = shaded_at(world, layer, tile, keyframe.t1, q, sun)?;
    let kept = kept.saturating_add(end_kept);
    Ok((
        Work {
            cpu_s: start.cpu_s + end.cpu_s,
            bytes: kept.saturating_add(start.bytes.max(end.bytes)),
        },
        kept,
    ))
}

/// [`shaded`] at one time.
fn shaded_at(
    world: &World,
    layer: usize,
    tile: TileId,
    t: f64,
    q: Quality,
    sun: Sun,
) -> Result<(Work, u64), RenderError> {
    let l = world
        .layers
        .get(layer)
        .ok_or_else(|| RenderError::BadRequest(format!("layer {layer} does not exist")))?;
    let halo = tile_halo(l, tile.z, q, sun);
    let region = tile.region()?;
    let h = halo as i64;
    let halo_region = Region::square(
        region.x0.saturating_sub(h),
        region.y0.saturating_sub(h),
        TILE_COLUMNS + 2 * halo,
    );
    let d = density(world, layer, tile.z, halo_region, t)?;
    let balls = tile_balls(l, tile.z, q);
    let cells = (halo_region.cols * halo_region.rows) as u64 * l.depth as u64;
    let kept = balls
        .saturating_mul(KEPT_BYTES_PER_BALL)
        .saturating_add(cells * KEPT_BYTES_PER_CELL);
    let work = Work {
        cpu_s: d.cpu_s + balls as f64 * CPU_S_PER_BALL,
        bytes: kept
            .saturating_add(balls.saturating_mul(SHADING_BYTES_PER_BALL))
            .max(d.bytes),
    };
    Ok((work, kept))
}

/// The work of a tile product: `render::shade_tile(world, layer, tile, keyframe, q,
/// sun, ..)` and the encoding of the tile's products.
pub fn shade_tile(
    world: &World,
    layer: usize,
    tile: TileId,
    keyframe: Keyframe,
    q: Quality,
    sun: Sun,
) -> Result<Work, RenderError> {
    let (work, _) = shaded(world, layer, tile, keyframe, q, sun)?;
    let l = &world.layers[layer];
    let encoded = tile_balls(l, tile.z, q).saturating_mul(ENCODED_BYTES_PER_BALL);
    Ok(Work {
        cpu_s: work.cpu_s,
        bytes: work.bytes.saturating_add(encoded),
    })
}

/// The work of `render::scene::render(world, config, req)`: every tile the view
/// plans (shaded a compute thread at a time, all kept until drawn), then
/// compositing (or ray marching) its pixels.
pub fn render(world: &World, config: &Config, req: &RenderRequest) -> Result<Work, RenderError> {
    let tiles = plan(world, config, req)?;
    let sun = crate::render::scene::request_sun(config, req);
    let mut cpu_s = 0.0;
    let mut kept = 0u64;
    let mut peak_shading = 0u64;
    for &(layer, tile) in &tiles {
        let keyframe = crate::render::scene::tile_keyframe(world, layer, tile, req);
        let (w, k) = shaded(world, layer, tile, keyframe, req.quality, sun)?;
        cpu_s += w.cpu_s;
        kept = kept.saturating_add(k);
        peak_shading = peak_shading.max(w.bytes - k);
    }
    let threads = rayon::current_num_threads().clamp(1, tiles.len().max(1)) as u64;
    let pixels = (req.width * req.height) as u64;
    cpu_s += if req.quality == Quality::Reference {
        pixels as f64 * req.samples.max(2) as f64 * CPU_S_PER_PATH
    } else if req.quality == Quality::ReferenceSingle {
        pixels as f64 * march_steps(world, req.quality) * CPU_S_PER_PIXEL_STEP
    } else {
        pixels as f64 * tiles.len() as f64 * CPU_S_PER_PIXEL_TILE[preset_index(req.quality)]
    };
    Ok(Work {
        cpu_s,
        bytes: kept
            .saturating_add(peak_shading.saturating_mul(threads))
            .saturating_add(pixels.saturating_mul(BYTES_PER_PIXEL)),
    })
}

/// Ray-marcher steps across every layer's thickness (the view step of `q`).
fn march_steps(world: &World, q: Quality) -> f64 {
    world
        .layers
        .iter()
        .map(|l| (l.top() - l.base) / (l.cell_height * q.settings().march_step_cells))
        .sum()
}

/// Reads `VmRSS` and `VmHWM` (kB) of a process from `/proc/PID/status` (Linux).
pub fn process_memory_kb(pid: u32) -> Option<(u64, u64)> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| {
        text.lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse::<u64>().ok())
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Camera, ShadingParams};

    /// User + system CPU seconds of this process so far (`/proc/self/stat`, 100 Hz ticks).
    fn cpu_seconds() -> f64 {
        let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
        let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
        let tick = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
        (tick(11) + tick(12)) / 100.0
    }

    /// Resets the peak RSS and returns the current RSS, kB.
    fn reset_peak() -> u64 {
        let _ = std::fs::write("/proc/self/clear_refs", "5");
        super::process_memory_kb(std::process::id()).map_or(0, |m| m.0)
    }

    fn peak_kb() -> u64 {
        super::process_memory_kb(std::process::id()).map_or(0, |m| m.1)
    }

    fn view(quality: Quality, size: usize) -> RenderRequest {
        RenderRequest {
            camera: Camera::parse("12800,-20000,1200,0,8,70").unwrap(),
            width: size,
            height: size,
            t: 43200.0,
            quality,
            sun: None,
            params: ShadingParams::default(),
            samples: crate::render::pathtrace::DEFAULT_SAMPLES,
        }
    }

    #[test]
    fn run_cells_is_the_closed_form_of_the_cone_without_wind() {
        use crate::automaton::{LayerSim, Rect, RunSpec};
        let config = Config::embedded();
        let mut world = config.world("default").unwrap();
        world.layers[0].wind = [0.0, 0.0];
        world.layers[0].shear = [0.0, 0.0];
        let sim = LayerSim::new(&world, 0);
        let depth = world.layers[0].depth as u64;
        let (w, h, steps) = (40u64, 25u64, 7i64);
        let window = Rect {
            x0: -3,
            x1: -3 + w as i64,
            y0: 11,
            y1: 11 + h as i64,
        };
        let spec = RunSpec {
            reference_step: 0,
            start: 100,
            snapshots: vec![100 + steps],
            windows: vec![window; depth as usize],
        };
        // Step s (1..=S) computes the window grown by 2 cells a side per step left.
        let expected: u64 = (0..steps as u64).map(|j| (w + 4 * j) * (h + 4 * j) * depth).sum();
        assert_eq!(sim.run_cells(&spec), expected);
    }

    #[test]
    fn the_issue_render_is_over_a_two_thread_budget_and_estimates_grow_with_the_work() {
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        let est = |q, size| render(&world, &config, &view(q, size)).unwrap();
        // render.png?size=4096x4096&quality=accurate: ~55 CPU-s measured; the default
        // budget is 10 s on 2 threads.
        let huge = est(Quality::Accurate, 4096);
        assert!(huge.cpu_s > 20.0, "{huge:?}");
        assert!(huge.bytes > 1 << 30, "{huge:?}");
        for q in [Quality::Fast, Quality::Balanced, Quality::Accurate] {
            let (small, big) = (est(q, 256), est(q, 1024));
            assert!(small.cpu_s < big.cpu_s && small.bytes < big.bytes, "{q:?}");
        }
        assert!(est(Quality::Fast, 512).cpu_s < est(Quality::Balanced, 512).cpu_s);
        assert!(est(Quality::Balanced, 512).cpu_s < est(Quality::Accurate, 512).cpu_s);
        // A density tile costs what its cone costs: more steps since the epoch's start
        // run, more work.
        let region = Region::square(0, 0, 64);
        let wide = Region {
            cols: 128,
            rows: 128,
            ..region
        };
        let d = density(&world, 0, 0, region, 1000.0).unwrap();
        assert!(d.cpu_s > 0.0 && d.cpu_s < density(&world, 0, 0, wide, 1000.0).unwrap().cpu_s);
    }

    /// Prints units, measured CPU and memory, and the estimate, for each kind of work
    /// (see the module docs). Run by hand: it takes minutes.
    #[test]
    #[ignore = "calibrates the cost constants against measured CPU and memory; takes minutes, run by hand"]
    fn calibrate() {
        let config = Config::embedded();
        let world = config.world("default").unwrap();
        let measure = |what: &str, est: Work, f: &mut dyn FnMut()| {
            let base = reset_peak();
            let c0 = cpu_seconds();
            f();
            let cpu = cpu_seconds() - c0;
            let mib = peak_kb().saturating_sub(base) as f64 / 1024.0;
            println!(
                "{what:<40} cpu {cpu:7.2} s (est {:7.2})  mem {mib:7.1} MiB (est {:7.1})",
                est.cpu_s,
                est.bytes as f64 / 1048576.0
            );
        };
        for (t, side) in [(43200.0, 256), (43213.0, 256), (1000.0, 512)] {
            let region = Region::square(0, 0, side);
            let cs = density::cell_steps(&world, 0, 0, region, t).unwrap();
            let est = density(&world, 0, 0, region, t).unwrap();
            measure(&format!("density {side}² t={t} ({cs} cell-steps)"), est, &mut || {
                density::density(&world, 0, 0, region, t).unwrap();
            });
        }
        for q in [Quality::Fast, Quality::Balanced, Quality::Accurate] {
            let tile = TileId { z: 0, x: 0, y: 0 };
            let sun = Sun::new(180.0, 40.0).unwrap();
            let keyframe = Keyframe::containing(43200.0, &world.layers[0], 0);
            let est = shade_tile(&world, 0, tile, keyframe, q, sun).unwrap();
            println!(
                "  (march steps of the world: {})",
                march_steps(&world, Quality::Reference)
            );
            let balls = tile_balls(&world.layers[0], 0, q);
            measure(&format!("shade_tile {} ({balls} balls)", q.as_str()), est, &mut || {
                let s = crate::render::shade_tile(
                    &world,
                    0,
                    tile,
                    keyframe,
                    q,
                    sun,
                    &ShadingParams::default(),
                    &config.limits,
                    &crate::cancel::Cancel::never(),
                )
                .unwrap();
                crate::products::billboards::encode_json(&s);
                crate::products::atlas::build(&s);
            });
        }
        for (q, size) in [
            (Quality::Fast, 512),
            (Quality::Fast, 1024),
            (Quality::Balanced, 512),
            (Quality::Balanced, 1024),
            (Quality::Accurate, 512),
            (Quality::Accurate, 1024),
            (Quality::Reference, 128),
            (Quality::Reference, 256),
        ] {
            let req = view(q, size);
            let tiles = plan(&world, &config, &req).unwrap().len();
            let est = render(&world, &config, &req).unwrap();
            measure(
                &format!("render {} {size}² ({tiles} tiles)", q.as_str()),
                est,
                &mut || {
                    crate::view::render(&world, &config, &req).unwrap().image.to_png();
                },
            );
        }
    }
}
