//! Keyframes: what the animation rule costs in accuracy and what it saves in compute.
//!
//! The rule's error is measured against the model itself: the same view drawn from
//! tiles shaded at the very time (`Keyframe::instant`), which is what the server drew
//! before keyframes, frame by frame. The picture held at the span's start (a client
//! that does not animate) is the baseline the rule should beat.

use std::time::Instant;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::render::image::rmse;
use cloudscape_core::render::scene::{RenderRequest, plan, prepare, request_sun};
use cloudscape_core::render::{Camera, Quality, ShadedTile, ShadingParams, TileId, shade_tile};
use cloudscape_core::view::draw_billboards;
use cloudscape_core::world::{Config, Keyframe, MAX_KEYFRAME_DOUBLINGS, World, keyframe_span};

use super::{BenchRun, Effort, fmt_s, time};

/// A view's tiles, each shaded for the very time of the request.
fn instant_tiles(world: &World, config: &Config, req: &RenderRequest) -> Result<Vec<ShadedTile>, String> {
    let sun = request_sun(config, req);
    plan(world, config, req)
        .map_err(|e| e.to_string())?
        .into_iter()
        .map(|(layer, tile)| {
            shade_tile(
                world,
                layer,
                tile,
                Keyframe::instant(req.t),
                req.quality,
                sun,
                &req.params,
                &config.limits,
                &Cancel::never(),
            )
            .map_err(|e| e.to_string())
        })
        .collect()
}

/// RMSE between two pictures of the same view, displayed (sRGB, 0–255).
fn picture_rmse(a: &cloudscape_core::render::image::Image, b: &cloudscape_core::render::image::Image) -> f64 {
    255.0 * rmse(&a.display(), &b.display())
}

pub fn keyframes(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let config = Config::embedded();
    let world = config.world("default").ok_or("the default world exists")?;
    let layer = &world.layers[0];
    let (width, height) = if effort == Effort::Smoke { (160, 90) } else { (480, 270) };
    let views = [
        (
            "a player 300 m up, looking at the horizon",
            Camera {
                position: [4000.0, 3000.0, 300.0],
                yaw_deg: 30.0,
                pitch_deg: 8.0,
                fov_deg: 70.0,
            },
        ),
        (
            "6 km up, looking down at 45°",
            Camera {
                position: [4000.0, 3000.0, 6000.0],
                yaw_deg: 30.0,
                pitch_deg: -45.0,
                fov_deg: 70.0,
            },
        ),
        (
            "40 km up, looking down at 60° (coarse tiles)",
            Camera {
                position: [4000.0, 3000.0, 40_000.0],
                yaw_deg: 30.0,
                pitch_deg: -60.0,
                fov_deg: 70.0,
            },
        ),
    ];
    let start = Keyframe::containing(43_200.0, layer, 0);
    let span0 = start.t1 - start.t0;
    let fractions: &[f64] = if effort == Effort::Smoke {
        &[0.5]
    } else {
        &[0.25, 0.5, 0.75]
    };
    let mut md = format!(
        "The default world, `balanced`, {width}×{height}, sun from the clock. A level-0 keyframe spans one \
         automaton step ({span0} s); level z spans `dt·2^min(z,{MAX_KEYFRAME_DOUBLINGS})`. At a time t inside the \
         span starting at t0 = {} s, three pictures: **rule**, the keyframe tiles drawn by the animation rule \
         (what `render.png`, `cloudscape render`, the Rust client and the viewer draw); **model**, every tile \
         shaded at t itself (the server before keyframes); **held**, the model at the span's start (a client \
         that does not animate). RMSE over displayed sRGB pixels, 0–255. Each view's times are fractions of \
         the span of the coarsest level it plans, so a coarse view measures the rule over its longer span.\n\n\
         | view | tiles (levels) | span | f = (t − t0)/span | rule vs model | held vs model |\n|---|---|---|---|---|---|\n",
        start.t0
    );
    let request = |camera: Camera, t: f64| RenderRequest {
        camera,
        width,
        height,
        t,
        quality: Quality::Balanced,
        sun: None,
        params: ShadingParams::default(),
        samples: 1,
    };
    let mut cost_rule = 0.0;
    let mut cost_model = 0.0;
    for (name, camera) in views {
        // The span of the coarsest level the view plans (at level 0: one step).
        let coarsest = plan(&world, &config, &request(camera, start.t0))
            .map_err(|e| e.to_string())?
            .iter()
            .map(|(_, tile)| tile.z)
            .max()
            .unwrap_or(0);
        let start = Keyframe::containing(43_200.0, layer, coarsest);
        let span = start.t1 - start.t0;
        let held_req = request(camera, start.t0);
        let held = draw_billboards(
            &instant_tiles(&world, &config, &held_req)?,
            &held_req,
            request_sun(&config, &held_req),
        );
        for &f in fractions {
            let req = request(camera, start.t0 + f * span);
            let sun = request_sun(&config, &req);
            let c0 = Instant::now();
            let rule_tiles = prepare(&world, &config, &req).map_err(|e| e.to_string())?;
            cost_rule += c0.elapsed().as_secs_f64();
            let rule = draw_billboards(&rule_tiles, &req, sun);
            let c1 = Instant::now();
            let model_tiles = instant_tiles(&world, &config, &req)?;
            cost_model += c1.elapsed().as_secs_f64();
            let model = draw_billboards(&model_tiles, &req, sun);
            let levels: std::collections::BTreeSet<u32> = rule_tiles.iter().map(|t| t.tile.z).collect();
            let levels: Vec<String> = levels.iter().map(u32::to_string).collect();
            md += &format!(
                "| {name} | {} ({}) | {span} s | {f} | {:.2} | {:.2} |\n",
                rule_tiles.len(),
                levels.join(", "),
                picture_rmse(&rule, &model),
                picture_rmse(&held, &model),
            );
        }
    }
    md += &format!(
        "\nShading a view's tiles for a keyframe (both ends) took {} against {} for one instant, summed over the \
         rows above: a keyframe costs about {:.1}× an instant, once per span instead of once per canonical frame.\n\n",
        fmt_s(cost_rule),
        fmt_s(cost_model),
        cost_rule / cost_model.max(1e-9)
    );

    // Compute per tile and world hour, per level: before, one shading per canonical
    // frame (dt / frames_per_step, 4 by default); now, one keyframe per span.
    let frames_per_step = 4.0;
    md += "One tile of the default world's first layer, `balanced`, per level: the time to shade it for a \
           keyframe and for an instant, and the shading time per world hour of a tile watched all the time \
           (before: an instant per canonical frame, `dt/4`; now: a keyframe per span).\n\n\
           | level | span | keyframe | instant | per world hour before | per world hour now | ratio |\n|---|---|---|---|---|---|---|\n";
    let levels: &[u32] = if effort == Effort::Smoke { &[4] } else { &[0, 2, 4, 6] };
    let sun = request_sun(&config, &request(views[0].1, start.t0));
    let params = ShadingParams::default();
    for &z in levels {
        let tile = TileId { z, x: 0, y: 0 };
        let key = Keyframe::containing(start.t0, layer, z);
        let shade = |k: Keyframe| {
            shade_tile(
                &world,
                0,
                tile,
                k,
                Quality::Balanced,
                sun,
                &params,
                &config.limits,
                &Cancel::never(),
            )
            .expect("a valid tile")
        };
        let kf = time(effort, || {
            std::hint::black_box(shade(key));
        });
        let inst = time(effort, || {
            std::hint::black_box(shade(Keyframe::instant(start.t0 + 0.5 * span0)));
        });
        let span = keyframe_span(layer.dt, z);
        let before = inst.median_s * 3600.0 / (layer.dt / frames_per_step);
        let now = kf.median_s * 3600.0 / span;
        md += &format!(
            "| {z} | {span} s | {} | {} | {} | {} | {:.1}× less |\n",
            fmt_s(kf.median_s),
            fmt_s(inst.median_s),
            fmt_s(before),
            fmt_s(now),
            before / now
        );
    }
    out.add_section(
        "keyframes",
        "Keyframes: the animation rule's error and compute per span",
        md,
    );
    Ok(())
}
