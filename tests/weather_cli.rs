//! The weather through the binary (issue 24): `cloudscape weather` prints the numbers
//! `/series` serves, `cloudscape lightning` the strikes `/lightning` lists (both from a
//! real `cloudscape serve` on the same config), `cloudscape density --field
//! precipitation` each column's rate by the documented rule recomputed by hand from the
//! density grid, and bad input gets one clear line and a non-zero exit.

mod common;

use common::{ServeProcess, client, cloudscape};

fn stdout_of(args: &[&str]) -> String {
    let o = cloudscape(args);
    assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8(o.stdout).unwrap()
}

fn get(server: &ServeProcess, path: &str) -> serde_json::Value {
    let r = client().get(format!("{}{path}", server.base)).send().unwrap();
    assert_eq!(r.status().as_u16(), 200, "{path}");
    serde_json::from_slice(&r.bytes().unwrap()).unwrap()
}

/// The embedded config's storm front: its cumulonimbus rains and flashes.
const STORM: [&str; 4] = ["--world", "storm-front", "--layer", "cumulonimbus"];
const BBOX: &str = "0,26000,4000,30000";

#[test]
fn weather_and_lightning_print_what_the_server_serves() {
    let server = ServeProcess::start(&[], &[]);
    let csv = stdout_of(
        &[
            &["weather"][..],
            &STORM,
            &["--bbox", BBOX, "--t0", "0", "--t1", "100", "--dt", "40", "--level", "1"],
        ]
        .concat(),
    );
    let series = get(
        &server,
        &format!("/v1/worlds/storm-front/series?bbox={BBOX}&t0=0&t1=100&dt=40&level=1&layer=cumulonimbus"),
    );
    let rows: Vec<&str> = csv.lines().collect();
    let header: Vec<&str> = rows[0].split(',').collect();
    let points = series["points"].as_array().unwrap();
    assert_eq!(rows.len() - 1, points.len(), "{csv}");
    assert_eq!(points.len(), 3, "t = 0, 40, 80");
    for (row, point) in rows[1..].iter().zip(points) {
        for (name, value) in header.iter().zip(row.split(',')) {
            let served = &point[*name];
            if value.is_empty() {
                assert!(served.is_null(), "{name}: {served}");
            } else {
                let (a, b) = (value.parse::<f64>().unwrap(), served.as_f64().unwrap());
                assert!(
                    (a - b).abs() <= 1e-6 * b.abs().max(1e-9),
                    "{name}: CLI {a}, /series {b}"
                );
            }
        }
    }
    assert!(
        points
            .iter()
            .any(|p| p["mean_precipitation_mm_h"].as_f64().unwrap() > 0.0),
        "the box rains: {series}"
    );

    let bbox = "-10000,20000,10000,40000";
    let csv = stdout_of(&[
        "lightning",
        "--world",
        "storm-front",
        "--bbox",
        bbox,
        "--t0",
        "0",
        "--t1",
        "300",
    ]);
    let served = get(
        &server,
        &format!("/v1/worlds/storm-front/lightning?bbox={bbox}&t0=0&t1=300"),
    );
    let strikes = served["strikes"].as_array().unwrap();
    assert!(!strikes.is_empty(), "the storm flashes");
    let lines: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(lines.len(), strikes.len(), "{csv}");
    for (line, s) in lines.iter().zip(strikes) {
        let f: Vec<&str> = line.split(',').collect();
        for (i, k) in ["t", "x", "y", "z"].iter().enumerate() {
            // serde_json's default float parsing may be an ulp off the printed value.
            let (a, b) = (f[i].parse::<f64>().unwrap(), s[*k].as_f64().unwrap());
            assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "{k} of {line} vs {s}");
        }
        assert_eq!(f[4], s["kind"].as_str().unwrap().to_lowercase(), "{line}");
    }
}

#[test]
fn density_field_precipitation_is_the_rule_applied_to_the_density() {
    let dir = std::env::temp_dir().join(format!("cloudscape-weather-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (d, p) = (dir.join("d.f32"), dir.join("p.f32"));
    let common = [
        &STORM[..],
        &["--bbox", BBOX, "--t", "60", "--level", "2", "--format", "f32"],
    ]
    .concat();
    stdout_of(&[&["density"][..], &common, &["--out", d.to_str().unwrap()]].concat());
    stdout_of(
        &[
            &["density"][..],
            &common,
            &["--field", "precipitation", "--out", p.to_str().unwrap()],
        ]
        .concat(),
    );
    let floats = |b: Vec<u8>| -> Vec<f32> {
        b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    };
    let (density, rates) = (floats(std::fs::read(&d).unwrap()), floats(std::fs::read(&p).unwrap()));
    let _ = std::fs::remove_dir_all(&dir);
    // Level 2: 400 m columns, so 10 × 10 of them; the cumulonimbus layer is 30 cells of 200 m.
    let (cols, depth) = (10, 30);
    assert_eq!(rates.len(), cols * cols);
    assert_eq!(density.len(), depth * cols * cols);
    // The cumulonimbus preset: 1.5 g/m³ at density 1, 100 droplets/cm³, onset 500 g/m²,
    // efficiency 1 (config/default.toml); R = 0.0156 ((LWP − onset) / N)^1.75 mm/h.
    let mut wet = 0;
    for i in 0..cols * cols {
        let lwp: f64 = (0..depth)
            .map(|k| density[k * cols * cols + i] as f64 * 1.5 * 200.0)
            .sum();
        let want = if lwp <= 500.0 {
            0.0
        } else {
            0.0156 * ((lwp - 500.0) / 100.0).powf(1.75)
        };
        assert!(
            (rates[i] as f64 - want).abs() <= 1e-4 * want.max(1.0),
            "column {i}: {} vs {want}",
            rates[i]
        );
        wet += usize::from(want > 0.0);
    }
    assert!(wet > 0, "the band rains");
}

#[test]
fn bad_weather_requests_get_one_clear_line() {
    // The command, its world and box, the rest of its arguments, and what the line says.
    for (command, world, bbox, rest, says) in [
        ("weather", "nope", BBOX, "--t0 0 --t1 1", "unknown world"),
        ("weather", "storm-front", BBOX, "--t0 10 --t1 1", "--t1"),
        ("weather", "storm-front", BBOX, "--t0 0 --t1 1e9 --dt 1", "--dt"),
        ("weather", "storm-front", BBOX, "--t0 0 --t1 1 --dt 0", "--dt"),
        ("weather", "storm-front", "0,0,1e9,1e9", "--t0 0 --t1 1", "column"),
        ("lightning", "storm-front", BBOX, "--t0 0 --t1 4000", "3600"),
        ("lightning", "storm-front", "0,0,60000,1000", "--t0 0 --t1 10", "50"),
        (
            "density",
            "storm-front",
            BBOX,
            "--t 0 --field precipitation --format u8 --out -",
            "mm/h",
        ),
    ] {
        let mut args = vec![command, "--world", world, "--bbox", bbox];
        args.extend(rest.split(' '));
        let o = cloudscape(&args);
        assert!(!o.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
}
