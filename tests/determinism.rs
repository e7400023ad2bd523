//! The determinism contract, pinned: the bytes of a fixed set of products (several
//! worlds, layers, levels, times, qualities and suns; density grids, cloud bits,
//! coverage maps, billboards, atlases, shadow maps, splat sheets, rendered views) hash
//! to the values in `tests/determinism/hashes.toml`, which records the
//! `ALGORITHM_VERSION` they belong to. Every product is computed on a one-thread rayon
//! pool, and the tile products again on a three-thread pool, which must agree.
//!
//! The table's source is the contract itself: it pins today's output, whose
//! correctness the seam, determinism and reference tests elsewhere justify (a region
//! equals its tiles, any tiling and thread count gives the same bits). What this test
//! adds is that the bytes do not drift silently. When a change alters output on
//! purpose, bump `ALGORITHM_VERSION` (crates/cloudscape-core/src/world/mod.rs) and
//! regenerate the table:
//!
//!     CLOUDSCAPE_REGENERATE_HASHES=1 cargo test --release --test determinism

use std::collections::BTreeMap;
use std::fmt::Write as _;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::density::{self, Region};
use cloudscape_core::products::grid::{GridFormat, encode_cells, encode_density};
use cloudscape_core::products::{atlas, billboards, coverage, keyframe_bin, precipitation, shadow, splats};
use cloudscape_core::render::{Camera, Quality, RenderRequest, ShadingParams, Sun, TileId, shade_tile};
use cloudscape_core::view::render;
use cloudscape_core::world::{ALGORITHM_VERSION, Config, Keyframe};

const TABLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/determinism/hashes.toml");
const REGENERATE: &str = "CLOUDSCAPE_REGENERATE_HASHES=1 cargo test --release --test determinism";

/// A small world (thin layers, short epochs) whose full tiles are cheap, with a
/// Dobashi and a Rosa layer.
const TINY: &str = include_str!("data/determinism.toml");

/// FNV-1a 64 from two offset bases: 128 bits, stable across machines and builds.
fn hash(bytes: &[u8]) -> String {
    let fnv = |basis: u64| {
        bytes
            .iter()
            .fold(basis, |h, &b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
    };
    format!("{:016x}{:016x}", fnv(0xcbf2_9ce4_8422_2325), fnv(0x6c62_272e_07bb_0142))
}

fn put(out: &mut BTreeMap<String, String>, key: String, bytes: Vec<u8>) {
    assert!(out.insert(key.clone(), hash(&bytes)).is_none(), "duplicate key {key}");
}

/// Every pinned product, by a key that says what it is.
fn products() -> BTreeMap<String, String> {
    let mut out = simulation_products();
    out.extend(tile_products());
    let mut put = |key: String, bytes: Vec<u8>| put(&mut out, key, bytes);
    let tiny = Config::parse(TINY).unwrap();
    let w = tiny.world("default").unwrap();
    for q in [Quality::Fast, Quality::Balanced] {
        put(format!("splats.png {}", q.as_str()), splats::encode_png_sheet(q));
        put(format!("splats.json {}", q.as_str()), splats::encode_json_sheet(q));
    }
    for (quality, t) in [(Quality::Fast, 300.0), (Quality::Reference, 43_200.0)] {
        let req = RenderRequest {
            camera: Camera::new([12_800.0, -2_000.0, 1_500.0], 10.0, 8.0, 70.0).unwrap(),
            width: 48,
            height: 27,
            t,
            quality,
            sun: None,
            params: ShadingParams::default(),
            samples: 8,
        };
        put(
            format!("render.png tiny/48x27/{}/t={t}", quality.as_str()),
            render(&w, &tiny, &req).unwrap().image.to_png(),
        );
    }
    out
}

/// Density grids and cloud bits of the embedded config.
fn simulation_products() -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    let mut put = |key: String, bytes: Vec<u8>| put(&mut out, key, bytes);
    // The embedded default config: every layer (two Dobashi, one Rosa), level 0 and a
    // far level, near the origin and 2^40 cells out, at several times; and a seed world.
    let embedded = Config::embedded();
    for world_name in ["default", "424242"] {
        let w = embedded.world(world_name).unwrap();
        for (li, layer) in w.layers.iter().enumerate() {
            for (level, x0, y0) in [(0u32, 0i64, 0i64), (0, -(1 << 40), 1 << 40), (6, -3, 2)] {
                for t in [0.0, 1234.5, 1e9] {
                    if world_name != "default" && t != 1234.5 {
                        continue;
                    }
                    let r = Region {
                        x0,
                        y0,
                        cols: 20,
                        rows: 12,
                    };
                    let g = density::density(&w, li, level, r, t).unwrap();
                    let key = format!("{world_name}/{}/z{level}/({x0},{y0})/20x12/t={t}", layer.name);
                    put(format!("density.npy {key}"), encode_density(&g, GridFormat::Npy));
                    if level == 0 && li == 0 {
                        let c = density::cloud_cells(&w, li, r, t).unwrap();
                        put(format!("cld.u8 {key}"), encode_cells(&c, GridFormat::U8));
                    }
                }
            }
        }
    }
    out
}

/// Whole tiles of every tile product of the tiny config.
fn tile_products() -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    let mut put = |key: String, bytes: Vec<u8>| put(&mut out, key, bytes);
    let tiny = Config::parse(TINY).unwrap();
    let w = tiny.world("default").unwrap();
    for (li, layer) in w.layers.iter().enumerate() {
        for (tile, t) in [
            (TileId { z: 0, x: 0, y: 0 }, 60.0),
            (TileId { z: 2, x: -1, y: 3 }, 86_400.0 * 3.0 + 7.5),
        ] {
            let key = format!("tiny/{}/{}/{}/{}/t={t}", layer.name, tile.z, tile.x, tile.y);
            let r = tile.region().unwrap();
            let g = density::density(&w, li, tile.z, r, t).unwrap();
            put(format!("density.u8 {key}"), encode_density(&g, GridFormat::U8));
            put(format!("precipitation.png {key}"), precipitation::encode_png(layer, &g));
            put(
                format!("coverage.png {key}"),
                coverage::encode_png_for_tile(&w, li, tile, t, &tiny.limits).unwrap(),
            );
            for (quality, sun) in [
                (Quality::Fast, Sun::new(135.0, 40.0)),
                (Quality::Balanced, Sun::new(250.0, 12.0)),
            ] {
                let sun = sun.unwrap();
                let s = shade_tile(
                    &w,
                    li,
                    tile,
                    Keyframe::containing(t, layer, tile.z),
                    quality,
                    sun,
                    &ShadingParams::default(),
                    &tiny.limits,
                    &Cancel::never(),
                )
                .unwrap();
                let key = format!("{key}/{}/{}", quality.as_str(), sun.bucket().id());
                put(format!("billboards.json {key}"), billboards::encode_json(&s));
                put(format!("billboards.v2.bin {key}"), billboards::encode_bin(&s));
                for (form, name) in [
                    (keyframe_bin::Form::SelfContained, "billboards.bin"),
                    (keyframe_bin::Form::Delta, "billboards.delta.bin"),
                ] {
                    put(
                        format!("{name} {key}"),
                        keyframe_bin::encode(&s, form, keyframe_bin::Quantisation::DEFAULT),
                    );
                }
                put(format!("shadow.png {key}"), shadow::encode_png_map(&s));
                let a = atlas::build(&s);
                put(format!("atlas.png {key}"), a.png);
                put(format!("atlas.json {key}"), a.manifest);
            }
        }
    }
    out
}

fn in_pool(threads: usize, f: fn() -> BTreeMap<String, String>) -> BTreeMap<String, String> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

fn table_text(hashes: &BTreeMap<String, String>) -> String {
    let mut s = String::from(
        "# The determinism contract: hashes (two FNV-1a 64) of product bytes for fixed keys.\n\
         # Pins today's output; correctness is argued by the seam and determinism tests.\n\
         # Written by `CLOUDSCAPE_REGENERATE_HASHES=1 cargo test --release --test determinism`;\n\
         # bump ALGORITHM_VERSION (crates/cloudscape-core/src/world/mod.rs) first whenever these change.\n",
    );
    writeln!(s, "algorithm_version = {ALGORITHM_VERSION}\n\n[hashes]").unwrap();
    for (k, v) in hashes {
        writeln!(s, "{} = \"{v}\"", toml::Value::String(k.clone())).unwrap();
    }
    s
}

#[test]
fn product_bytes_match_the_committed_table_on_any_thread_count() {
    let one = in_pool(1, products);
    // The tile products (the most parallel code: automaton rows, metaballs, shading)
    // again on three threads.
    let three = in_pool(3, tile_products);
    let differ: Vec<&String> = three.keys().filter(|k| one[*k] != three[*k]).collect();
    assert!(
        differ.is_empty(),
        "one and three threads give different bytes for {differ:?}"
    );

    if std::env::var_os("CLOUDSCAPE_REGENERATE_HASHES").is_some() {
        std::fs::write(TABLE, table_text(&one)).unwrap();
        eprintln!("wrote {} hashes to {TABLE}", one.len());
        return;
    }
    let text = std::fs::read_to_string(TABLE).unwrap_or_else(|e| panic!("{TABLE}: {e}; create it with {REGENERATE}"));
    let table: toml::Table = toml::from_str(&text).unwrap();
    let version = table["algorithm_version"].as_integer().unwrap();
    let pinned: BTreeMap<String, String> = table["hashes"]
        .as_table()
        .unwrap()
        .iter()
        .map(|(k, v)| (k.clone(), v.as_str().unwrap().to_string()))
        .collect();
    let changed: Vec<String> = one
        .keys()
        .chain(pinned.keys())
        .filter(|k| one.get(*k) != pinned.get(*k))
        .cloned()
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    if version != ALGORITHM_VERSION as i64 {
        panic!(
            "ALGORITHM_VERSION is {ALGORITHM_VERSION} but the hash table records version {version}: \
             regenerate it with {REGENERATE} ({} products differ)",
            changed.len()
        );
    }
    assert!(
        changed.is_empty(),
        "the bytes of {} pinned products changed under ALGORITHM_VERSION {ALGORITHM_VERSION}, \
         e.g. {:?}.\nIf intended: bump ALGORITHM_VERSION in crates/cloudscape-core/src/world/mod.rs and regenerate with {REGENERATE}.\n\
         If not: the change broke the determinism contract (README \"Determinism contract\").",
        changed.len(),
        &changed[..changed.len().min(8)]
    );
}
