//! Where a keyframe's time goes, stage by stage: one tile's keyframe computed cold
//! (as if the tile had never been seen) against its next keyframe computed from what
//! the tile kept (`density::kept`: the grids of the last keyframe's ends and, at level
//! 0, the automaton's runs advanced a step).
//!
//! The stages are those the pipeline times itself (`cloudscape_core::stages`, the
//! same figures as the server's `cloudscape_stage_seconds_total`), plus the encoding
//! of the products a shading makes at once and the zstd compression of
//! `billboards.bin`, as the server does them.

use std::time::{Duration, Instant};

use cloudscape_core::cancel::Cancel;
use cloudscape_core::products::Product;
use cloudscape_core::products::catalogue::encode_shaded;
use cloudscape_core::render::tile::{KeptTile, shade_tile_staged};
use cloudscape_core::render::{Quality, ShadedTile, ShadingParams, Sun, TileId};
use cloudscape_core::stages::{Stage, Stages};
use cloudscape_core::world::{Config, Keyframe, World};
use cloudscape_server::Coding;

use super::{BenchRun, Effort, fmt_s};

/// One keyframe's time per stage, with the encoding and compression after it.
#[derive(Clone, Copy, Default)]
struct Profile {
    stages: Stages,
    encoding: Duration,
    compression: Duration,
    total: Duration,
}

/// Encodes and compresses a shaded tile as the server does, timing both.
fn encode(shaded: &ShadedTile, p: &mut Profile) {
    let t = Instant::now();
    let all = encode_shaded(shaded, u64::MAX, true, Product::BillboardsBin);
    p.encoding = t.elapsed();
    let t = Instant::now();
    for (product, bytes) in &all {
        if *product == Product::BillboardsBin {
            std::hint::black_box(Coding::Zstd.compress(bytes).expect("zstd compresses"));
        }
    }
    p.compression = t.elapsed();
}

/// One keyframe of `tile`, from `kept` if given, profiled.
#[allow(clippy::too_many_arguments)]
fn keyframe(
    world: &World,
    config: &Config,
    layer: usize,
    tile: TileId,
    keyframe: Keyframe,
    quality: Quality,
    sun: Sun,
    kept: Option<&mut KeptTile>,
) -> Result<Profile, String> {
    let mut p = Profile::default();
    let start = Instant::now();
    let shaded = shade_tile_staged(
        world,
        layer,
        tile,
        keyframe,
        quality,
        sun,
        &ShadingParams::default(),
        &config.limits,
        &Cancel::never(),
        kept,
        &mut p.stages,
    )
    .map_err(|e| e.to_string())?;
    encode(&shaded, &mut p);
    p.total = start.elapsed();
    Ok(p)
}

/// The mean of each figure over `runs`, and the median total.
fn mean(runs: &[Profile]) -> (Profile, Duration) {
    let n = runs.len().max(1) as u32;
    let mut m = Profile::default();
    for r in runs {
        for stage in Stage::ALL {
            m.stages.add(stage, r.stages.get(stage) / n);
        }
        m.encoding += r.encoding / n;
        m.compression += r.compression / n;
        m.total += r.total / n;
    }
    let mut totals: Vec<Duration> = runs.iter().map(|r| r.total).collect();
    totals.sort();
    (m, totals[totals.len() / 2])
}

/// A cell of the table: ms, or – for nothing.
fn cell(d: Duration) -> String {
    if d.is_zero() {
        "–".into()
    } else {
        fmt_s(d.as_secs_f64())
    }
}

pub fn stages(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let config = Config::embedded();
    let world = config.world("default").ok_or("the default world exists")?;
    let sun = Sun::new(150.0, 40.0).expect("a valid sun");
    // (layer, level) of the rows; warm keyframes measured per row; cold ones per row.
    let (rows, warm_n, cold_n): (&[(usize, u32)], usize, usize) = match effort {
        Effort::Smoke => (&[(1, 3)], 2, 1),
        Effort::Quick => (&[(0, 0), (1, 0), (2, 0), (0, 2)], 8, 2),
        Effort::Full => (&[(0, 0), (1, 0), (2, 0), (0, 2)], 16, 4),
    };
    let mut md = format!(
        "One tile (x 1, y 0) of the default world, sun 150,40, per layer and level: a keyframe computed cold (as \
         if the tile had never been seen: every run from its epoch's start; {cold_n} keyframes, each in another epoch) \
         against the next keyframes computed from what the tile kept ({warm_n} in a row after a first one, so at level 0 \
         they cross an epoch boundary, whose new run is started then). Mean wall time per keyframe on all cores, by \
         stage: **automaton** runs from their epochs' empty grids, **steps** of the kept runs (new runs included), \
         **smoothing** of cloud bits to density, **far field** (levels above 0), **reused** density cut from a kept \
         grid, **metaballs**, **shading** (light sweep, billboards, shadow map) for both ends of the span, \
         **encoding** of the products a shading makes at once, **compression** of `billboards.bin` (zstd 3). The \
         total is measured around it all; warm/cold compares the mean totals (median in brackets).\n\n\
         | preset | layer | level | keyframe | automaton | steps | smoothing | far field | reused | metaballs | shading | encoding | compression | total | warm / cold | kept |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    );
    let mut t = 43_200.0;
    for quality in [Quality::Fast, Quality::Balanced] {
        for &(layer, z) in rows {
            let l = &world.layers[layer];
            let tile = TileId { z, x: 1, y: 0 };
            let span = cloudscape_core::world::keyframe_span(l.dt, z);
            let mut cold = Vec::new();
            for _ in 0..cold_n {
                t += 977.0 * span / l.dt;
                let k = Keyframe::containing(t, l, z);
                cold.push(keyframe(&world, &config, layer, tile, k, quality, sun, None)?);
            }
            let mut kept = KeptTile::for_tile(l, layer, tile);
            t += 977.0 * span / l.dt;
            let first = Keyframe::containing(t, l, z);
            keyframe(&world, &config, layer, tile, first, quality, sun, Some(&mut kept))?;
            let mut warm = Vec::new();
            for i in 1..=warm_n {
                let k = Keyframe::containing(first.t0 + i as f64 * span, l, z);
                warm.push(keyframe(
                    &world,
                    &config,
                    layer,
                    tile,
                    k,
                    quality,
                    sun,
                    Some(&mut kept),
                )?);
            }
            let ((c, c_med), (w, w_med)) = (mean(&cold), mean(&warm));
            let kept_mib = kept.bytes() as f64 / f64::from(1 << 20);
            for (name, p, med) in [("cold", c, c_med), ("warm", w, w_med)] {
                let stages: Vec<String> = Stage::ALL.iter().map(|&s| cell(p.stages.get(s))).collect();
                let (ratio, kept) = if name == "warm" {
                    (
                        format!(
                            "**{:.2}** ({:.2})",
                            w.total.as_secs_f64() / c.total.as_secs_f64(),
                            w_med.as_secs_f64() / c_med.as_secs_f64()
                        ),
                        format!("{kept_mib:.1} MiB"),
                    )
                } else {
                    (String::new(), String::new())
                };
                md += &format!(
                    "| {} | {} | {z} | {name} | {} | {} | {} | {} ({}) | {ratio} | {kept} |\n",
                    quality.as_str(),
                    l.name,
                    stages.join(" | "),
                    cell(p.encoding),
                    cell(p.compression),
                    fmt_s(p.total.as_secs_f64()),
                    fmt_s(med.as_secs_f64()),
                );
            }
        }
    }
    md += "\n`kept` is what the tile keeps after the warm keyframes (the two latest grids and, at level 0, the \
           runs): the server holds it under `server.kept_share` of `server.cache_bytes`.\n";
    out.add_section("stages", "Keyframes: where the time goes, cold against warm", md);
    Ok(())
}
