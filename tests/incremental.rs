//! Incremental keyframes (issue 34): a tile's next keyframe computed from what the
//! server kept of its last one gives the bytes of a cold computation of the same
//! keyframe, for every tile product, at levels 0 to 3, across epoch boundaries, on
//! one thread and several.
//!
//! The cold computation is the independent source: it runs every automaton run from
//! its epoch's empty start, computes both ends' density and shades both ends from
//! scratch, sharing nothing with the kept path but the pure functions they both call.

mod common;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::density;
use cloudscape_core::products::Product;
use cloudscape_core::products::catalogue::encode_shaded;
use cloudscape_core::render::tile::{KeptTile, shade_tile_staged};
use cloudscape_core::render::{Quality, ShadingParams, Sun, TileId};
use cloudscape_core::stages::Stages;
use cloudscape_core::world::{Config, Keyframe, World, keyframe_span};

use common::{ServeProcess, metric, test_config};

/// The test world with wind shear on the low layer (so the lattice's levels drift
/// apart) and a Rosa layer beside the Dobashi ones.
fn config_text() -> String {
    test_config(&[
        ("worlds.default.layers.0.shear", "[0.004, -0.002]"),
        (
            "presets.wisp",
            "{ mode = \"rosa\", rosa_iterations = 4, \
             humidity = { frequency = 0.3, octaves = 3, cutoff = [0.2, 0.9], range = [0.0, 1.0] }, \
             activation = { frequency = 0.6, octaves = 2, cutoff = [0.3, 0.9], range = [0.0, 1.0] }, \
             extinction = { frequency = 0.4, octaves = 1, range = [0.0, 1.0] } }",
        ),
        ("worlds.default.layers.1.preset", "\"wisp\""),
    ])
}

/// Every product of one keyframe of `tile`, in [`Product::ALL`] order: the shaded
/// ones from one shading, the grids from the density at the span's start; from
/// `kept` where given (as the server's jobs do, all of a tile's jobs sharing it).
/// The impostor atlas (half a second a tile: it renders every cluster) only `with_atlas`.
#[allow(clippy::too_many_arguments)]
fn products(
    world: &World,
    layer: usize,
    tile: TileId,
    keyframe: Keyframe,
    quality: Quality,
    sun: Sun,
    mut kept: Option<&mut KeptTile>,
    with_atlas: bool,
) -> Vec<(Product, Vec<u8>)> {
    let limits = cloudscape_core::world::Limits::default();
    let cancel = Cancel::never();
    let mut stages = Stages::default();
    let shaded = shade_tile_staged(
        world,
        layer,
        tile,
        keyframe,
        quality,
        sun,
        &ShadingParams::default(),
        &limits,
        &cancel,
        kept.as_deref_mut(),
        &mut stages,
    )
    .unwrap_or_else(|e| panic!("{tile:?} {keyframe:?}: {e}"));
    let region = tile.region().unwrap();
    let grid = match kept {
        Some(k) => k
            .density
            .density(world, region, keyframe.t0, true, &cancel, &mut stages),
        None => density::density(world, layer, tile.z, region, keyframe.t0),
    }
    .unwrap();
    // Billboards (every encoding) and shadow in a few calls, the atlas and its manifest
    // in another, as the server encodes them.
    let mut shaded_bytes = Vec::new();
    for wanted in [Product::BillboardsJson, Product::BillboardsV2, Product::ShadowPng] {
        shaded_bytes.extend(encode_shaded(&shaded, u64::MAX, true, wanted));
    }
    if with_atlas {
        shaded_bytes.extend(encode_shaded(&shaded, u64::MAX, true, Product::AtlasPng));
    }
    Product::ALL
        .iter()
        .filter(|p| with_atlas || !matches!(p, Product::AtlasPng | Product::AtlasJson))
        .map(|&p| {
            let bytes = if p.needs_shading() {
                let i = shaded_bytes
                    .iter()
                    .position(|(q, _)| *q == p)
                    .unwrap_or_else(|| panic!("{} is encoded", p.name()));
                shaded_bytes[i].1.clone()
            } else {
                p.encode_grid(&world.layers[layer], &grid)
                    .unwrap_or_else(|| panic!("{} is a grid product", p.name()))
            };
            (p, bytes)
        })
        .collect()
}

/// What a tile is asked for, in order, at level `z`: a run of keyframes across an
/// epoch boundary (the test layers' epochs are 4 steps; a level-z span is 2^z steps),
/// a second quality and a second sun of one of them, and a keyframe the kept state
/// has moved past.
fn asks(z: u32, dt: f64) -> Vec<(Keyframe, Quality, Sun)> {
    let span = keyframe_span(dt, z);
    let steps = 1u64 << z.min(4);
    // The keyframe that starts 2 steps before the epoch boundary at step 4·1000.
    let first = (4 * 1000 - 2) / steps;
    let kf = |k: u64| Keyframe::on_grid(k as f64 * span, span);
    let (sun, low) = (Sun::new(200.0, 35.0).unwrap(), Sun::new(95.0, 4.0).unwrap());
    let mut out: Vec<(Keyframe, Quality, Sun)> = (first..first + 6).map(|k| (kf(k), Quality::Fast, sun)).collect();
    out.insert(2, (kf(first + 1), Quality::Balanced, sun));
    out.insert(4, (kf(first + 2), Quality::Fast, low));
    out.push((kf(first + 1), Quality::Fast, sun));
    out
}

/// Every product at every asked keyframe, warm and cold, on a pool of `threads`.
fn run_on(threads: usize, world: &World) -> Vec<Vec<(Product, Vec<u8>)>> {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let mut all = Vec::new();
        for (layer, l) in world.layers.iter().enumerate() {
            for z in 0..=3u32 {
                let tile = TileId { z, x: -1, y: 2 };
                let mut kept = KeptTile::for_tile(l, layer, tile);
                for (i, (keyframe, quality, sun)) in asks(z, l.dt).into_iter().enumerate() {
                    // The atlas once per level, at a keyframe computed from kept state.
                    let atlas = i == 5;
                    let warm = products(world, layer, tile, keyframe, quality, sun, Some(&mut kept), atlas);
                    let cold = products(world, layer, tile, keyframe, quality, sun, None, atlas);
                    for ((p, w), (_, c)) in warm.iter().zip(&cold) {
                        assert!(
                            w == c,
                            "{} of layer {} level {z} at {keyframe:?} ({quality:?}, {sun:?}) on {threads} thread(s): \
                             kept {} bytes, cold {} bytes",
                            p.name(),
                            l.name,
                            w.len(),
                            c.len()
                        );
                    }
                    all.push(warm);
                }
                // The kept state did the work it exists for.
                let d = kept.density.counts();
                let s = kept.shading_counts();
                assert!(d.reused > 0 && s.reused > 0, "layer {} level {z}: {d:?} {s:?}", l.name);
                if z == 0 {
                    assert!(
                        d.live > 0 && kept.density.live_steps() > 0,
                        "layer {} level 0: {d:?}",
                        l.name
                    );
                }
            }
        }
        all
    })
}

#[test]
fn kept_keyframes_give_the_bytes_of_cold_ones_on_any_thread_count() {
    let config = Config::parse(&config_text()).expect("the test world parses");
    let world = config.world("default").unwrap();
    let one = run_on(1, &world);
    let three = run_on(3, &world);
    assert!(one == three, "1 and 3 threads give different bytes");
    assert!(
        one.iter()
            .flatten()
            .any(|(p, b)| *p == Product::BillboardsBin && b.len() > 200)
    );
    // Every product was compared.
    for p in Product::ALL {
        assert!(
            one.iter().flatten().any(|(q, _)| *q == p),
            "{} never compared",
            p.name()
        );
    }
}

/// The keyframe URLs a game client walks through: every product of a tile, at levels
/// 0 to 3, keyframe after keyframe across an epoch boundary.
fn urls(z: u32, dt: f64) -> Vec<String> {
    let span = keyframe_span(dt, z);
    let first = (4 * 1000 - 2) / (1u64 << z);
    let mut out = Vec::new();
    for k in first..first + 5 {
        // The atlas (half a second a tile) at the last keyframe only.
        let atlas = |p: &Product| matches!(p, Product::AtlasPng | Product::AtlasJson);
        for p in Product::ALL.iter().filter(|p| k == first + 4 || !atlas(p)) {
            out.push(format!(
                "/v1/worlds/default/tiles/{z}/-1/2/{}?t={}&layer=low&quality=fast&sun=200,35",
                p.name(),
                k as f64 * span
            ));
        }
    }
    out
}

#[test]
fn servers_that_keep_state_serve_the_bytes_of_one_that_keeps_none() {
    let path = std::env::temp_dir().join(format!("cloudscape-incremental-{}.toml", std::process::id()));
    std::fs::write(&path, config_text()).unwrap();
    let config = path.to_str().unwrap();
    let quiet = [("CLOUDSCAPE_SERVER_AHEAD_THREADS", "0")];
    let kept_one = ServeProcess::start(&["--config", config], &[quiet[0], ("RAYON_NUM_THREADS", "1")]);
    let kept_three = ServeProcess::start(&["--config", config], &[quiet[0], ("RAYON_NUM_THREADS", "3")]);
    let cold = ServeProcess::start(
        &["--config", config],
        &[
            quiet[0],
            ("RAYON_NUM_THREADS", "2"),
            ("CLOUDSCAPE_SERVER_KEPT_SHARE", "0"),
        ],
    );
    let dt = 10.0;
    let mut asked = 0;
    for z in 0..=3u32 {
        for url in urls(z, dt) {
            let body = |s: &ServeProcess| {
                let r = s.get(&url);
                assert_eq!(r.status(), 200, "{url}");
                r.bytes().unwrap()
            };
            let want = body(&cold);
            assert!(body(&kept_one) == want, "{url}: 1 thread, kept state");
            assert!(body(&kept_three) == want, "{url}: 3 threads, kept state");
            asked += 1;
        }
    }
    assert!(asked > 100);
    for server in [&kept_one, &kept_three] {
        let reused = metric(server, "cloudscape_kept_shadings_total", &[("how", "reused")]);
        let live = metric(server, "cloudscape_kept_grids_total", &[("source", "live")]);
        let bytes = metric(server, "cloudscape_kept_bytes", &[]);
        assert!(
            reused > 0.0 && live > 0.0 && bytes > 0.0,
            "reused {reused}, live {live}, bytes {bytes}"
        );
    }
    // The server that keeps nothing computed every keyframe cold.
    assert_eq!(
        metric(&cold, "cloudscape_kept_shadings_total", &[("how", "reused")]),
        0.0
    );
    assert_eq!(metric(&cold, "cloudscape_kept_bytes", &[]), 0.0);
    let _ = std::fs::remove_file(&path);
}
