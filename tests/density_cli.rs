//! `cloudscape density` through the binary: seams, determinism, extremes, bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use cloudscape_core::world::DEFAULT_CONFIG;

const BIN: &str = env!("CARGO_BIN_EXE_cloudscape");

fn run(args: &[&str], envs: &[(&str, &str)]) -> Output {
    let mut c = Command::new(BIN);
    c.arg("density").args(args);
    for (k, v) in envs {
        c.env(k, v);
    }
    c.output().expect("run cloudscape")
}

/// What a `density` run asks for besides its box: the same across the boxes a test compares.
struct Request<'a> {
    world: &'a str,
    layer: &'a str,
    t: &'a str,
    field: &'a str,
}

/// Runs `density` for `req` over `bbox`, writing raw f32 (density) or u8 (cld) to
/// `dir/name`, and returns the bytes.
fn grid(dir: &Path, name: &str, req: &Request, bbox: &str, envs: &[(&str, &str)]) -> Vec<u8> {
    let Request { world, layer, t, field } = *req;
    grid_of(dir, name, &["--world", world, "--layer", layer], bbox, t, field, envs)
}

/// Runs `density` with the flags `head` (world, layer or config) over `bbox` at `t`,
/// writing raw f32 (density) or u8 (cld) to `dir/name`, and returns the bytes.
fn grid_of(dir: &Path, name: &str, head: &[&str], bbox: &str, t: &str, field: &str, envs: &[(&str, &str)]) -> Vec<u8> {
    let out = dir.join(name);
    let fmt = if field == "cld" { "u8" } else { "f32" };
    let mut args = head.to_vec();
    let out_s = out.to_str().unwrap();
    args.extend([
        "--bbox", bbox, "--t", t, "--field", field, "--format", fmt, "--out", out_s,
    ]);
    let o = run(&args, envs);
    assert!(
        o.status.success(),
        "density failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::read(out).unwrap()
}

/// Columns [c0, c1) of a (depth, rows, cols) grid of `item`-byte values.
fn columns(data: &[u8], depth: usize, rows: usize, cols: usize, item: usize, c0: usize, c1: usize) -> Vec<u8> {
    let mut out = Vec::new();
    for k in 0..depth {
        for r in 0..rows {
            let row = (k * rows + r) * cols;
            out.extend_from_slice(&data[(row + c0) * item..(row + c1) * item]);
        }
    }
    out
}

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

#[test]
fn seams_two_halves_equal_the_whole() {
    // The overcast world's stratocumulus: 100 m cells, depth 10, dt 20 s, epochs of 16 steps
    // (320 s) with 8 fade steps. L = 24 cells = 2400 m.
    let d = tmp();
    let l = 2400.0;
    // t = 0; inside an epoch; in the cross-fade; exactly at an epoch boundary; 1e12.
    let times = ["0", "117.3", "250", "320", "1e12"];
    // Near the origin (and straddling it), and at x ≈ 1e9 m.
    let origins = [(-1200.0, -700.0), (1.0e9, 3.0e5)];
    for (x0, y0) in origins {
        for t in times {
            for field in ["cld", "density"] {
                let item = if field == "cld" { 1 } else { 4 };
                let req = Request {
                    world: "overcast",
                    layer: "stratocumulus",
                    t,
                    field,
                };
                let whole = grid(
                    d.path(),
                    "w",
                    &req,
                    &format!("{},{},{},{}", x0, y0, x0 + 2.0 * l, y0 + l),
                    &[],
                );
                let left = grid(
                    d.path(),
                    "l",
                    &req,
                    &format!("{},{},{},{}", x0, y0, x0 + l, y0 + l),
                    &[],
                );
                let right = grid(
                    d.path(),
                    "r",
                    &req,
                    &format!("{},{},{},{}", x0 + l, y0, x0 + 2.0 * l, y0 + l),
                    &[],
                );
                assert_eq!(whole.len(), 2 * left.len());
                assert_eq!(
                    columns(&whole, 10, 24, 48, item, 0, 24),
                    left,
                    "left half, field {field} t={t} x0={x0}"
                );
                assert_eq!(
                    columns(&whole, 10, 24, 48, item, 24, 48),
                    right,
                    "right half, field {field} t={t} x0={x0}"
                );
            }
        }
    }
}

#[test]
fn seams_hold_for_rosa_layers_and_other_layers() {
    let d = tmp();
    for (layer, l) in [("cirrus", 4800.0), ("altocumulus", 1920.0)] {
        let req = Request {
            world: "overcast",
            layer,
            t: "4321.5",
            field: "density",
        };
        let whole = grid(d.path(), "w", &req, &format!("0,0,{},{}", 2.0 * l, l), &[]);
        let left = grid(d.path(), "l", &req, &format!("0,0,{},{}", l, l), &[]);
        let right = grid(d.path(), "r", &req, &format!("{},0,{},{}", l, 2.0 * l, l), &[]);
        let depth = whole.len() / 4 / (24 * 48);
        assert_eq!(columns(&whole, depth, 24, 48, 4, 0, 24), left, "{layer}");
        assert_eq!(columns(&whole, depth, 24, 48, 4, 24, 48), right, "{layer}");
    }
}

#[test]
fn output_is_identical_across_thread_counts_and_runs() {
    let d = tmp();
    let bbox = "-3000,-3000,3400,3400";
    let req = Request {
        world: "default",
        layer: "stratocumulus",
        t: "777.7",
        field: "density",
    };
    let a = grid(d.path(), "a", &req, bbox, &[("RAYON_NUM_THREADS", "1")]);
    let b = grid(d.path(), "b", &req, bbox, &[("RAYON_NUM_THREADS", "2")]);
    let c = grid(d.path(), "c", &req, bbox, &[("RAYON_NUM_THREADS", "2")]);
    assert_eq!(a, b);
    assert_eq!(b, c);
    assert!(
        a.chunks(4).any(|v| f32::from_le_bytes(v.try_into().unwrap()) > 0.0),
        "the region has cloud"
    );
}

#[test]
fn npy_output_has_the_documented_shape() {
    let d = tmp();
    let out = d.path().join("g.npy");
    let o = run(
        &[
            "--world",
            "42",
            "--bbox",
            "0,0,3000,2000",
            "--t",
            "60",
            "--out",
            out.to_str().unwrap(),
        ],
        &[],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let b = std::fs::read(&out).unwrap();
    assert_eq!(&b[..6], b"\x93NUMPY");
    let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
    let header = std::str::from_utf8(&b[10..10 + hl]).unwrap();
    // The default climate's first layer (cumulus): 100 m cells, so 30 columns (x),
    // 20 rows (y), and a depth of 14 cells.
    assert!(header.contains("'shape': (14, 20, 30)"), "{header}");
    assert!(header.contains("'descr': '<f4'"));
    assert_eq!(b.len(), 10 + hl + 14 * 20 * 30 * 4);
}

/// A world whose only layer has the given probability ranges (hum, act, ext).
fn extreme_config(dir: &Path, hum: [f64; 2], act: [f64; 2], ext: [f64; 2]) -> PathBuf {
    let base = DEFAULT_CONFIG;
    let preset = format!(
        "[presets.extreme]\nmode = \"dobashi\"\nhumidity = {{ frequency = 0.1, range = [{}, {}] }}\nactivation = {{ frequency = 0.1, range = [{}, {}] }}\nextinction = {{ frequency = 0.1, range = [{}, {}] }}\n",
        hum[0], hum[1], act[0], act[1], ext[0], ext[1]
    );
    let world = "[worlds.x]\nseed = 5\n[[worlds.x.layers]]\nname = \"only\"\npreset = \"extreme\"\nbase = 1000.0\ncell_size = 1.0\ncell_height = 10000.0\ndepth = 3\ndt = 0.01\nwind = [300.0, -300.0]\n";
    let text = format!("{base}\n{preset}\n{world}");
    let p = dir.join("extreme.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn grid_with_config(dir: &Path, cfg: &Path, bbox: &str, t: &str, field: &str) -> Vec<u8> {
    grid_of(
        dir,
        "x",
        &["--config", cfg.to_str().unwrap(), "--world", "x"],
        bbox,
        t,
        field,
        &[],
    )
}

#[test]
fn zero_probabilities_never_make_cloud() {
    let d = tmp();
    let cfg = extreme_config(d.path(), [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]);
    for t in ["0", "0.015", "1e12"] {
        let cells = grid_with_config(d.path(), &cfg, "-40,-40,40,40", t, "cld");
        assert!(cells.iter().all(|&c| c == 0), "t={t}");
        let dens = grid_with_config(d.path(), &cfg, "-40,-40,40,40", t, "density");
        assert!(dens.iter().all(|&b| b == 0), "t={t}");
    }
}

#[test]
fn certain_activation_without_extinction_saturates() {
    // act fires every step, so cld = cld ∨ act is set from the second step of a run
    // on and is never removed: every cell is cloud and the density is exactly 1.
    let d = tmp();
    let cfg = extreme_config(d.path(), [0.0, 1.0], [1.0, 1.0], [0.0, 0.0]);
    for t in ["0.5", "1e12"] {
        let cells = grid_with_config(
            d.path(),
            &cfg,
            "10000000000000,-10000000000000,10000000000064,-9999999999936",
            t,
            "cld",
        );
        assert!(!cells.is_empty() && cells.iter().all(|&c| c == 1), "t={t}");
        let dens = grid_with_config(d.path(), &cfg, "-30,-30,30,30", t, "density");
        assert!(
            dens.chunks(4).all(|v| f32::from_le_bytes(v.try_into().unwrap()) == 1.0),
            "t={t}"
        );
    }
}

#[test]
fn huge_coordinates_and_times_give_finite_well_formed_density() {
    let d = tmp();
    // 2^40 cells of 100 m from the origin, at t = 1e12.
    let far = (1u64 << 40) as f64 * 100.0;
    let bbox = format!("{},{},{},{}", far, -far, far + 6400.0, -far + 6400.0);
    let req = Request {
        world: "default",
        layer: "stratocumulus",
        t: "1e12",
        field: "density",
    };
    let v = grid(d.path(), "f", &req, &bbox, &[]);
    let vals: Vec<f32> = v.chunks(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
    assert!(vals.iter().all(|x| x.is_finite() && (0.0..=1.0).contains(x)));
    let distinct = vals
        .iter()
        .map(|x| x.to_bits())
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    assert!(distinct > 10, "the far field still varies ({distinct} distinct values)");
}

#[test]
fn bad_input_is_one_clear_line_and_leaves_no_file() {
    let d = tmp();
    let out = d.path().join("never.npy");
    let o = out.to_str().unwrap();
    // Each case's flags (split at spaces), then `--out`, and a word the error names.
    let cases: [(&str, &str); 14] = [
        ("--world default --bbox 0,0,100,100 --t NaN", "t"),
        ("--world default --bbox 0,0,100,100 --t inf", "t"),
        ("--world default --bbox 0,0,100,100 --t -1", "t"),
        ("--world default --bbox 0,0,100,100 --t 1e13", "t"),
        ("--world default --bbox 100,0,0,100 --t 0", "bbox"),
        ("--world default --bbox 0,0,1e7,1e7 --t 0", "limit"),
        ("--world default --bbox 0,0,nan,100 --t 0", "bbox"),
        ("--world default --bbox 0,0,100 --t 0", "bbox"),
        ("--world nowhere --bbox 0,0,100,100 --t 0", "world"),
        ("--world default --layer fog --bbox 0,0,100,100 --t 0", "layer"),
        ("--world default --bbox 0,0,100,100 --t 0 --level 99", "level"),
        ("--world default --bbox 0,0,100,100 --t 0 --format png", "format"),
        ("--world default --bbox 1e300,0,2e300,100 --t 0", "range"),
        ("--world default --bbox 0,0,100,100 --t 0 --field nope", "field"),
    ];
    let cases = cases.map(|(flags, word)| {
        let mut args: Vec<&str> = flags.split(' ').collect();
        args.extend(["--out", o]);
        (args, word)
    });
    for (args, word) in cases {
        let r = run(&args, &[]);
        assert!(!r.status.success(), "{args:?} should fail");
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(err.trim().lines().count(), 1, "one line for {args:?}: {err}");
        assert!(
            err.to_lowercase().contains(word),
            "{args:?}: `{err}` should mention {word}"
        );
        assert!(!err.contains("panicked"));
        assert!(!out.exists(), "no file after {args:?}");
    }
    // An unwritable destination fails cleanly too.
    let r = run(
        &[
            "--world",
            "default",
            "--bbox",
            "0,0,100,100",
            "--t",
            "0",
            "--out",
            "/nonexistent-dir/x.npy",
        ],
        &[],
    );
    assert!(!r.status.success());
    assert_eq!(String::from_utf8_lossy(&r.stderr).trim().lines().count(), 1);
}

#[test]
fn seams_hold_in_a_saturated_humid_world() {
    // Humidity everywhere and rare activation seeds: activation spreads through every
    // cell, so any region edge that leaked into the result would show.
    let d = tmp();
    let cfg = extreme_config(d.path(), [1.0, 1.0], [0.0, 0.002], [0.02, 0.02]);
    for t in ["0.23", "77.77"] {
        let whole = grid_with_config(d.path(), &cfg, "0,0,64,32", t, "cld");
        let left = grid_with_config(d.path(), &cfg, "0,0,32,32", t, "cld");
        let right = grid_with_config(d.path(), &cfg, "32,0,64,32", t, "cld");
        let top = grid_with_config(d.path(), &cfg, "0,16,64,32", t, "cld");
        assert_eq!(columns(&whole, 3, 32, 64, 1, 0, 32), left, "t={t}");
        assert_eq!(columns(&whole, 3, 32, 64, 1, 32, 64), right, "t={t}");
        let upper: Vec<u8> = (0..3)
            .flat_map(|k| whole[(k * 32 + 16) * 64..(k * 32 + 32) * 64].to_vec())
            .collect();
        assert_eq!(upper, top, "t={t}");
        let frac = whole.iter().filter(|&&c| c == 1).count() as f64 / whole.len() as f64;
        assert!(frac > 0.05 && frac < 0.999, "a mixed field, cloud fraction {frac}");
    }
}

/// `density --level Z` as f32 values, with an optional config file.
fn level_grid(
    dir: &Path,
    cfg: Option<&Path>,
    world: &str,
    layer: Option<&str>,
    bbox: &str,
    t: &str,
    level: u32,
) -> Vec<f32> {
    let out = dir.join(format!("level{level}"));
    let level = level.to_string();
    let mut args = vec![
        "--world", world, "--bbox", bbox, "--t", t, "--level", &level, "--format", "f32",
    ];
    if let Some(c) = cfg {
        args.extend(["--config", c.to_str().unwrap()]);
    }
    if let Some(l) = layer {
        args.extend(["--layer", l]);
    }
    args.extend(["--out", out.to_str().unwrap()]);
    let o = run(&args, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::read(out)
        .unwrap()
        .chunks(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}

#[test]
fn far_levels_make_no_cloud_where_the_automaton_cannot() {
    let d = tmp();
    // No humidity and no activation: the automaton never makes a cloud, and no level
    // may either (the far-field model once floored activation everywhere: haze).
    let cfg = extreme_config(d.path(), [0.0, 0.0], [0.0, 0.0], [0.01, 0.01]);
    for level in 0..=5 {
        let v = level_grid(d.path(), Some(&cfg), "x", None, "0,0,1024,1024", "100", level);
        assert!(!v.is_empty() && v.iter().all(|&x| x == 0.0), "level {level}");
    }
    // A cloudy layer bounded by an extent with a feather: outside the extent every
    // field is 0, so every level is clear there, while inside it is cloudy.
    let base = DEFAULT_CONFIG;
    let feather = "feather = { start = 0.0, depth = 2000.0 }";
    let preset = format!(
        "[presets.bounded]\nmode = \"dobashi\"\nhumidity = {{ frequency = 0.12, cutoff = [0.3, 0.7], range = [0.0, 0.4], {feather} }}\nactivation = {{ frequency = 0.25, cutoff = [0.3, 0.8], range = [0.0, 0.03], {feather} }}\nextinction = {{ frequency = 0.2, range = [0.04, 0.01] }}\n"
    );
    let world = "[worlds.x]\nseed = 3\n[[worlds.x.layers]]\nname = \"only\"\npreset = \"bounded\"\nbase = 1000.0\ncell_size = 100.0\ncell_height = 100.0\ndepth = 4\ndt = 20.0\nwind = [0.0, 0.0]\nextent = [0.0, 0.0, 25600.0, 25600.0]\n";
    let cfg = d.path().join("bounded.toml");
    std::fs::write(&cfg, format!("{base}\n{preset}\n{world}")).unwrap();
    for level in 0..=4 {
        let outside = level_grid(d.path(), Some(&cfg), "x", None, "-25600,-25600,0,25600", "1000", level);
        assert!(
            !outside.is_empty() && outside.iter().all(|&x| x == 0.0),
            "level {level} outside"
        );
        let inside = level_grid(d.path(), Some(&cfg), "x", None, "0,0,25600,25600", "1000", level);
        let mean = inside.iter().sum::<f32>() / inside.len() as f32;
        assert!(mean > 0.05, "level {level}: the extent itself is cloudy (mean {mean})");
    }
}

#[test]
fn far_levels_track_the_level_0_mean_and_stay_clear_in_clear_columns() {
    // The held-out region of BENCHMARKS.md "Far-field levels": 512×512 cells of the
    // stratocumulus layer, seed 1, t = 1000 s. Level Z's mean over the region must
    // follow level 0's (the published bias is at most +0.028 up to level 4), and
    // columns where level 0 has no cloud at all must stay (nearly) clear.
    let d = tmp();
    let bbox = "-51200,25600,0,76800";
    let (world, layer) = ("overcast", Some("stratocumulus"));
    let full = level_grid(d.path(), None, world, layer, bbox, "1000", 0);
    let (depth, n) = (10usize, 512usize);
    assert_eq!(full.len(), depth * n * n);
    let mean0 = full.iter().map(|&x| x as f64).sum::<f64>() / full.len() as f64;
    assert!(mean0 > 0.1, "a cloudy region ({mean0})");
    for level in 1..=4u32 {
        let s = 1usize << level;
        let m = n / s;
        let z = level_grid(d.path(), None, world, layer, bbox, "1000", level);
        assert_eq!(z.len(), depth * m * m);
        let mean_z = z.iter().map(|&x| x as f64).sum::<f64>() / z.len() as f64;
        assert!(
            (mean_z - mean0).abs() < 0.03,
            "level {level}: mean {mean_z} against level 0's {mean0}"
        );
        // Level-Z columns whose 2^Z × 2^Z level-0 cells are all clear.
        let (mut clear_sum, mut clear_n) = (0f64, 0usize);
        for k in 0..depth {
            for r in 0..m {
                for c in 0..m {
                    let empty = (0..s).all(|dy| (0..s).all(|dx| full[(k * n + r * s + dy) * n + c * s + dx] == 0.0));
                    if empty {
                        clear_sum += z[(k * m + r) * m + c] as f64;
                        clear_n += 1;
                    }
                }
            }
        }
        assert!(clear_n > 0 || level > 2, "level {level}: the region has clear columns");
        if clear_n > 0 {
            let haze = clear_sum / clear_n as f64;
            // Before the fix this was 0.04-0.05 (activation floored where p_hum = 0).
            assert!(
                haze < 0.01,
                "level {level}: mean density {haze} in {clear_n} clear columns"
            );
        }
    }
}
