//! `cloudscape density` through the binary: seams, determinism, extremes, bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_cloudscape");

fn run(args: &[&str], envs: &[(&str, &str)]) -> Output {
    let mut c = Command::new(BIN);
    c.arg("density").args(args);
    for (k, v) in envs {
        c.env(k, v);
    }
    c.output().expect("run cloudscape")
}

/// Runs `density` writing raw f32 (density) or u8 (cld) and returns the bytes.
fn grid(
    dir: &Path,
    name: &str,
    world: &str,
    layer: &str,
    bbox: &str,
    t: &str,
    field: &str,
    envs: &[(&str, &str)],
) -> Vec<u8> {
    let out = dir.join(name);
    let fmt = if field == "cld" { "u8" } else { "f32" };
    let o = run(
        &[
            "--world",
            world,
            "--layer",
            layer,
            "--bbox",
            bbox,
            "--t",
            t,
            "--field",
            field,
            "--format",
            fmt,
            "--out",
            out.to_str().unwrap(),
        ],
        envs,
    );
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
    // Default stratocumulus: 100 m cells, depth 10, dt 20 s, epochs of 16 steps
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
                let whole = grid(
                    d.path(),
                    "w",
                    "default",
                    "stratocumulus",
                    &format!("{},{},{},{}", x0, y0, x0 + 2.0 * l, y0 + l),
                    t,
                    field,
                    &[],
                );
                let left = grid(
                    d.path(),
                    "l",
                    "default",
                    "stratocumulus",
                    &format!("{},{},{},{}", x0, y0, x0 + l, y0 + l),
                    t,
                    field,
                    &[],
                );
                let right = grid(
                    d.path(),
                    "r",
                    "default",
                    "stratocumulus",
                    &format!("{},{},{},{}", x0 + l, y0, x0 + 2.0 * l, y0 + l),
                    t,
                    field,
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
        let whole = grid(
            d.path(),
            "w",
            "default",
            layer,
            &format!("0,0,{},{}", 2.0 * l, l),
            "4321.5",
            "density",
            &[],
        );
        let left = grid(
            d.path(),
            "l",
            "default",
            layer,
            &format!("0,0,{},{}", l, l),
            "4321.5",
            "density",
            &[],
        );
        let right = grid(
            d.path(),
            "r",
            "default",
            layer,
            &format!("{},0,{},{}", l, 2.0 * l, l),
            "4321.5",
            "density",
            &[],
        );
        let depth = whole.len() / 4 / (24 * 48);
        assert_eq!(columns(&whole, depth, 24, 48, 4, 0, 24), left, "{layer}");
        assert_eq!(columns(&whole, depth, 24, 48, 4, 24, 48), right, "{layer}");
    }
}

#[test]
fn output_is_identical_across_thread_counts_and_runs() {
    let d = tmp();
    let bbox = "-3000,-3000,3400,3400";
    let a = grid(
        d.path(),
        "a",
        "default",
        "stratocumulus",
        bbox,
        "777.7",
        "density",
        &[("RAYON_NUM_THREADS", "1")],
    );
    let b = grid(
        d.path(),
        "b",
        "default",
        "stratocumulus",
        bbox,
        "777.7",
        "density",
        &[("RAYON_NUM_THREADS", "2")],
    );
    let c = grid(
        d.path(),
        "c",
        "default",
        "stratocumulus",
        bbox,
        "777.7",
        "density",
        &[("RAYON_NUM_THREADS", "2")],
    );
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
    // 100 m cells: 30 columns (x), 20 rows (y), depth 10.
    assert!(header.contains("'shape': (10, 20, 30)"), "{header}");
    assert!(header.contains("'descr': '<f4'"));
    assert_eq!(b.len(), 10 + hl + 10 * 20 * 30 * 4);
}

/// A world whose only layer has the given probability ranges (hum, act, ext).
fn extreme_config(dir: &Path, hum: [f64; 2], act: [f64; 2], ext: [f64; 2]) -> PathBuf {
    let base = include_str!("../config/default.toml");
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
    let out = dir.join("x");
    let fmt = if field == "cld" { "u8" } else { "f32" };
    let o = run(
        &[
            "--config",
            cfg.to_str().unwrap(),
            "--world",
            "x",
            "--bbox",
            bbox,
            "--t",
            t,
            "--field",
            field,
            "--format",
            fmt,
            "--out",
            out.to_str().unwrap(),
        ],
        &[],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::read(out).unwrap()
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
    let v = grid(d.path(), "f", "default", "stratocumulus", &bbox, "1e12", "density", &[]);
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
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["--world", "default", "--bbox", "0,0,100,100", "--t", "NaN", "--out", o],
            "t",
        ),
        (
            vec!["--world", "default", "--bbox", "0,0,100,100", "--t", "inf", "--out", o],
            "t",
        ),
        (
            vec!["--world", "default", "--bbox", "0,0,100,100", "--t", "-1", "--out", o],
            "t",
        ),
        (
            vec!["--world", "default", "--bbox", "0,0,100,100", "--t", "1e13", "--out", o],
            "t",
        ),
        (
            vec!["--world", "default", "--bbox", "100,0,0,100", "--t", "0", "--out", o],
            "bbox",
        ),
        (
            vec!["--world", "default", "--bbox", "0,0,1e7,1e7", "--t", "0", "--out", o],
            "limit",
        ),
        (
            vec!["--world", "default", "--bbox", "0,0,nan,100", "--t", "0", "--out", o],
            "bbox",
        ),
        (
            vec!["--world", "default", "--bbox", "0,0,100", "--t", "0", "--out", o],
            "bbox",
        ),
        (
            vec!["--world", "nowhere", "--bbox", "0,0,100,100", "--t", "0", "--out", o],
            "world",
        ),
        (
            vec![
                "--world",
                "default",
                "--layer",
                "fog",
                "--bbox",
                "0,0,100,100",
                "--t",
                "0",
                "--out",
                o,
            ],
            "layer",
        ),
        (
            vec![
                "--world",
                "default",
                "--bbox",
                "0,0,100,100",
                "--t",
                "0",
                "--level",
                "99",
                "--out",
                o,
            ],
            "level",
        ),
        (
            vec![
                "--world",
                "default",
                "--bbox",
                "0,0,100,100",
                "--t",
                "0",
                "--format",
                "png",
                "--out",
                o,
            ],
            "format",
        ),
        (
            vec![
                "--world",
                "default",
                "--bbox",
                "1e300,0,2e300,100",
                "--t",
                "0",
                "--out",
                o,
            ],
            "range",
        ),
    ];
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
