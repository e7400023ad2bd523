//! Numerical extremes: coordinates at ±2^40 cells; t ∈ {0, the smallest positive f64,
//! just below a step boundary, an epoch boundary, 1e12}; probabilities {0, 1, 1 − ε};
//! wind 0 and 300 m/s; cell sizes 1 m and 10 km; sun elevation from −90° to 90°; phase
//! g → ±1; densities whose optical depth → ∞. Every float of every product is finite and
//! within its documented range, and the products stay seamless there: a 2L×L region
//! equals its two L×L halves, bit for bit.

use cloudscape_core::cancel::Cancel;
use cloudscape_core::density::{self, Grid, Region};
use cloudscape_core::products::{atlas, billboards, coverage, shadow};
use cloudscape_core::render::{Camera, Phase, Quality, RenderRequest, ShadingParams, Sun, TileId, shade_tile};
use cloudscape_core::view::render;
use cloudscape_core::world::{Config, Keyframe, Limits, World};

/// 2^40 cells.
const FAR: i64 = 1 << 40;
/// Half-width of the seam regions, columns.
const L: usize = 12;

/// A config with one world per extreme; `{P}` fields are filled per world below.
fn config() -> Config {
    let preset = |name: &str, hum: &str, act: &str, ext: &str| {
        format!(
            r#"
[presets.{name}]
mode = "dobashi"
top_narrowing = 0.3
humidity   = {{ frequency = 0.5, octaves = 2, cutoff = [0.2, 0.7], range = {hum} }}
activation = {{ frequency = 0.8, octaves = 2, cutoff = [0.3, 0.8], range = {act} }}
extinction = {{ frequency = 0.5, octaves = 1, cutoff = [0.0, 1.0], range = {ext} }}
"#
        )
    };
    let world = |name: &str, preset: &str, cell: f64, wind: f64, dt: f64| {
        format!(
            r#"
[worlds.{name}]
seed = 12345

[[worlds.{name}.layers]]
name = "l"
preset = "{preset}"
base = 1000.0
cell_size = {cell:?}
cell_height = {cell:?}
depth = 3
dt = {dt:?}
wind = [{wind:?}, {:?}]
epoch = {{ length = 4, warmup = 4, fade = 2 }}
"#,
            -wind / 2.0
        )
    };
    let one_minus_eps = "[0.9999999999999998, 0.9999999999999998]";
    let mut text = String::from("[limits]\nmax_columns = 4096\nmax_cells = 16777216\nmax_level = 40\n");
    text += &preset("normal", "[0.0, 0.4]", "[0.0, 0.05]", "[0.1, 0.03]");
    text += &preset("zero", "[0.0, 0.0]", "[0.0, 0.0]", "[0.0, 0.0]");
    text += &preset("one", "[1.0, 1.0]", "[1.0, 1.0]", "[1.0, 1.0]");
    text += &preset("overcast", "[1.0, 1.0]", "[1.0, 1.0]", "[0.0, 0.0]");
    text += &preset("almost", one_minus_eps, one_minus_eps, one_minus_eps);
    text += r#"
[presets.rosa]
mode = "rosa"
rosa_iterations = 3
rosa_thresholds = [0.0, 1.0, 0.9999999999999998]
humidity   = { frequency = 0.5, octaves = 2, range = [0.0, 1.0] }
activation = { frequency = 0.8, octaves = 2, range = [0.0, 1.0] }
extinction = { frequency = 0.5, octaves = 1, range = [0.0, 1.0] }
"#;
    text += &world("default", "normal", 100.0, 8.0, 20.0);
    text += &world("calm_fine", "normal", 1.0, 0.0, 20.0);
    text += &world("gale_fine", "normal", 1.0, 300.0, 0.01);
    text += &world("gale_coarse", "overcast", 10000.0, 300.0, 86400.0);
    text += &world("never", "zero", 100.0, 8.0, 20.0);
    text += &world("always", "one", 100.0, 8.0, 20.0);
    text += &world("almost", "almost", 100.0, 8.0, 20.0);
    text += &world("rosa", "rosa", 10000.0, 300.0, 20.0);
    Config::parse(&text).expect("the extremes config is valid")
}

/// The times of the issue for a layer with step `dt` and epoch length 4.
fn times(dt: f64) -> Vec<f64> {
    let step_boundary = dt * 1000.0;
    vec![
        0.0,
        f64::from_bits(1),
        f64::from_bits(step_boundary.to_bits() - 1),
        dt * 4.0 * 250.0,
        1e12,
    ]
}

/// Region origins (level-0 columns) at ±2^40 and the origin.
fn corners() -> [(i64, i64); 3] {
    [(FAR - L as i64, FAR - L as i64), (-FAR, -FAR), (-(L as i64), 0)]
}

fn columns<T: Copy + Default>(g: &Grid<T>, c0: usize, c1: usize) -> Vec<T> {
    let mut out = Vec::new();
    for k in 0..g.depth {
        for r in 0..g.rows {
            for c in c0..c1 {
                out.push(g.get(k, r, c));
            }
        }
    }
    out
}

fn world(c: &Config, name: &str) -> World {
    c.world(name).unwrap()
}

#[test]
fn density_and_cloud_bits_are_finite_bounded_and_seamless_at_the_extremes() {
    let c = config();
    for name in [
        "default",
        "calm_fine",
        "gale_fine",
        "gale_coarse",
        "never",
        "always",
        "almost",
        "rosa",
    ] {
        let w = world(&c, name);
        let dt = w.layers[0].dt;
        for t in times(dt) {
            for (x0, y0) in corners() {
                for level in [0u32, 4] {
                    let (x0, y0) = (x0 >> level, y0 >> level);
                    let whole = Region {
                        x0,
                        y0,
                        cols: 2 * L,
                        rows: L,
                    };
                    let left = Region {
                        x0,
                        y0,
                        cols: L,
                        rows: L,
                    };
                    let right = Region {
                        x0: x0 + L as i64,
                        y0,
                        cols: L,
                        rows: L,
                    };
                    let what = format!("world {name}, t = {t:e}, level {level}, region at ({x0}, {y0})");
                    let g = density::density(&w, 0, level, whole, t).unwrap_or_else(|e| panic!("{what}: {e}"));
                    for v in &g.data {
                        assert!(v.is_finite() && (0.0..=1.0).contains(v), "{what}: density {v}");
                    }
                    let a = density::density(&w, 0, level, left, t).unwrap();
                    let b = density::density(&w, 0, level, right, t).unwrap();
                    assert_eq!(columns(&g, 0, L), a.data, "{what}: left half differs");
                    assert_eq!(columns(&g, L, 2 * L), b.data, "{what}: right half differs");
                    if level == 0 {
                        let g = density::cloud_cells(&w, 0, whole, t).unwrap();
                        assert!(g.data.iter().all(|&v| v <= 1), "{what}: cld not a bit");
                        let a = density::cloud_cells(&w, 0, left, t).unwrap();
                        let b = density::cloud_cells(&w, 0, right, t).unwrap();
                        assert_eq!(columns(&g, 0, L), a.data, "{what}: cld left half differs");
                        assert_eq!(columns(&g, L, 2 * L), b.data, "{what}: cld right half differs");
                    }
                }
            }
        }
    }
    // The extreme probabilities do what they say: never any cloud, always cloud.
    let none = density::density(
        &world(&c, "never"),
        0,
        0,
        Region {
            x0: 0,
            y0: 0,
            cols: 8,
            rows: 8,
        },
        1e6,
    )
    .unwrap();
    assert!(none.data.iter().all(|&v| v == 0.0));
    let full = density::cloud_cells(
        &world(&c, "gale_coarse"),
        0,
        Region {
            x0: -FAR,
            y0: 0,
            cols: 8,
            rows: 8,
        },
        1e12,
    )
    .unwrap();
    assert!(
        full.data.iter().all(|&v| v == 1),
        "p_hum = p_act = 1, p_ext = 0 is overcast"
    );
}

/// Every JSON number is finite (serde_json writes NaN and ±inf as `null`): no `null`.
fn assert_no_null(v: &serde_json::Value, path: &str, what: &str) {
    match v {
        serde_json::Value::Null => panic!("{what}: null (a non-finite number?) at {path}"),
        serde_json::Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, x)| assert_no_null(x, &format!("{path}[{i}]"), what)),
        serde_json::Value::Object(o) => o
            .iter()
            .for_each(|(k, x)| assert_no_null(x, &format!("{path}.{k}"), what)),
        _ => {}
    }
}

fn unit(v: f64) -> bool {
    v.is_finite() && (0.0..=1.0).contains(&v)
}

#[test]
fn shaded_tile_products_are_finite_and_in_range_for_every_sun_phase_and_optical_depth() {
    let c = config();
    let limits = Limits {
        max_columns: 4096,
        max_cells: 1 << 24,
        max_level: 40,
        ..Limits::default()
    };
    let phases = [
        Phase::default(),
        Phase {
            g1: 1.0,
            g2: -1.0,
            mix: 0.5,
        },
        Phase {
            g1: 1.0 - f64::EPSILON,
            g2: -(1.0 - f64::EPSILON),
            mix: 1.0,
        },
        Phase {
            g1: -1.0,
            g2: 1.0,
            mix: 0.0,
        },
    ];
    let extinctions = [0.01, 1e3, 1e300];
    let mut cases = Vec::new();
    // Every sun elevation band, with the default light on a cloudy world.
    for el in [-90.0, -45.0, -6.0, -0.1, 0.0, 0.1, 5.0, 30.0, 60.0, 89.9, 90.0] {
        cases.push(("gale_coarse", FAR >> 8, el, Phase::default(), 0.01, Quality::Fast));
    }
    // Phase g → ±1 and optical depth → ∞ under a low and a high sun.
    for (i, phase) in phases.iter().enumerate() {
        for (j, &ext) in extinctions.iter().enumerate() {
            let el = if (i + j) % 2 == 0 { 2.0 } else { 70.0 };
            cases.push(("gale_coarse", -(FAR >> 8), el, *phase, ext, Quality::Fast));
        }
    }
    // The other worlds once each, at the far corner.
    for name in ["default", "almost", "always", "never", "rosa", "calm_fine"] {
        cases.push((
            name,
            FAR >> 8,
            35.0,
            Phase {
                g1: 1.0,
                g2: -1.0,
                mix: 0.5,
            },
            1e300,
            Quality::Balanced,
        ));
    }
    for (name, tx, el, phase, extinction, quality) in cases {
        let w = world(&c, name);
        let t = 1e12;
        let params = ShadingParams {
            extinction,
            phase,
            ..ShadingParams::default()
        };
        let sun = Sun::new(123.0, el).unwrap();
        let tile = TileId { z: 0, x: tx, y: tx };
        let what = format!("world {name}, tile {tx}, sun el {el}, {phase:?}, extinction {extinction:e}");
        // The last keyframe span before the end of time: both ends shaded.
        let keyframe = Keyframe::containing(t - 1.0, &w.layers[0], tile.z);
        assert!(!keyframe.is_instant() && keyframe.t1 == t, "{what}: {keyframe:?}");
        let shaded = shade_tile(&w, 0, tile, keyframe, quality, sun, &params, &limits, &Cancel::never())
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        let l = &shaded.lighting;
        for v in l.sun_dir.iter().chain(&l.sun_rgb).chain(&l.ambient_rgb) {
            assert!(v.is_finite(), "{what}: lighting {l:?}");
        }
        assert!(
            l.sun_rgb.iter().chain(&l.ambient_rgb).all(|&v| v >= 0.0),
            "{what}: {l:?}"
        );
        assert!(unit(l.daylight), "{what}: daylight {}", l.daylight);
        assert_eq!(shaded.billboards.len(), shaded.end.len(), "{what}");
        let between = shaded.billboards_at(t - 1.0);
        for b in shaded.billboards.iter().chain(&shaded.end).chain(&between) {
            assert!(b.centre.iter().all(|v| v.is_finite()), "{what}: {b:?}");
            assert!(b.splat_tau.is_finite() && b.splat_tau >= 0.0, "{what}: splat_tau {b:?}");
            assert!(b.radius.is_finite() && b.radius > 0.0, "{what}: {b:?}");
            assert!(unit(b.density as f64), "{what}: {b:?}");
            assert!(b.tau.is_finite() && b.tau >= 0.0, "{what}: tau {b:?}");
            assert!(
                b.opacity.is_finite() && (0.0..1.0).contains(&b.opacity),
                "{what}: opacity {b:?}"
            );
            assert!(unit(b.sun_transmittance as f64), "{what}: {b:?}");
            assert!(
                b.colour.iter().all(|v| v.is_finite() && (0.0..=2.0).contains(v)),
                "{what}: {b:?}"
            );
            assert!((b.splat as usize) < quality.settings().splat_count, "{what}: {b:?}");
        }
        assert!(
            shaded.shadow.iter().chain(&shaded.shadow_end).all(|&v| unit(v as f64)),
            "{what}: shadow map"
        );
        if name == "gale_coarse" {
            assert!(!shaded.billboards.is_empty(), "{what}: an overcast tile has billboards");
        }
        let json: serde_json::Value = serde_json::from_slice(&billboards::encode_json(&shaded)).unwrap();
        assert_no_null(&json, "billboards.json", &what);
        let bin = billboards::decode_bin(&billboards::encode_bin(&shaded)).unwrap_or_else(|e| panic!("{what}: {e}"));
        assert_eq!(bin.records.len(), shaded.billboards.len(), "{what}");
        let a = atlas::build(&shaded);
        assert!(a.png.starts_with(b"\x89PNG"), "{what}");
        let manifest: serde_json::Value = serde_json::from_slice(&a.manifest).unwrap();
        assert_no_null(&manifest, "atlas.json", &what);
        assert!(shadow::encode_png_map(&shaded).starts_with(b"\x89PNG"), "{what}");
    }
}

#[test]
fn coverage_maps_and_renders_are_finite_at_the_extremes() {
    let c = config();
    for name in ["gale_coarse", "always", "never", "gale_fine"] {
        let w = world(&c, name);
        for tile in [
            TileId {
                z: 0,
                x: FAR >> 8,
                y: -(FAR >> 8),
            },
            TileId {
                z: 16,
                x: -(FAR >> 24),
                y: 0,
            },
        ] {
            let png = coverage::encode_png_for_tile(&w, 0, tile, 1e12, &c.limits).unwrap();
            assert!(png.starts_with(b"\x89PNG"), "{name} {tile:?}");
        }
    }
    // Cameras at the edge of the accepted range, looking straight up and down, with the
    // sun below the horizon, at the zenith, and g → ±1.
    let w = world(&c, "gale_coarse");
    for (pos, pitch, el, quality) in [
        ([1e12, -1e12, 500.0], 90.0, 90.0, Quality::Fast),
        ([-1e12, 1e12, 30000.0], -90.0, -90.0, Quality::Balanced),
        ([1e12, 1e12, 1200.0], 10.0, 0.0, Quality::Reference),
        ([1e12, -1e12, 1200.0], 10.0, -3.0, Quality::ReferenceSingle),
        ([-1e12, -1e12, 50.0], 0.0, 0.1, Quality::Accurate),
    ] {
        let req = RenderRequest {
            camera: Camera::new(pos, 45.0, pitch, 60.0).unwrap(),
            width: 24,
            height: 16,
            t: 1e12,
            quality,
            sun: Sun::new(300.0, el),
            params: ShadingParams {
                extinction: 1e300,
                phase: Phase {
                    g1: 1.0,
                    g2: -1.0,
                    mix: 0.5,
                },
                ..ShadingParams::default()
            },
            samples: 4,
        };
        let r = render(&w, &c, &req).unwrap_or_else(|e| panic!("{pos:?} {pitch} {el}: {e}"));
        let img = &r.image;
        assert!(
            img.rgb.iter().flatten().all(|v| v.is_finite() && *v >= 0.0),
            "{pos:?} pitch {pitch} sun {el}: non-finite radiance"
        );
        assert!(
            img.alpha.iter().all(|&a| unit(a as f64)),
            "{pos:?} pitch {pitch} sun {el}: alpha"
        );
        assert!(img.to_png().starts_with(b"\x89PNG"));
    }
}
