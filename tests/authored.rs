//! Authored weather (issue 24 item 3) over real sockets: a storm placed to cross from
//! one play area to another arrives at the stated place and time, seamless across
//! tiles, with the same bytes on every thread count; regional overrides clear or
//! thicken what they cover; events are part of the world's fingerprint (ETags change
//! with them); malformed events are refused with errors that name the key.

mod common;

use cloudscape_core::density::{self, Region};
use cloudscape_core::world::Config;
use common::InProcess;
use reqwest::StatusCode;

/// The storm: centre (20 km, 12.8 km, 1.1 km) at t = 0, moving east at 6 m/s, so its
/// centre is at x = 20 000 + 6t: over play area A (tile x = 0) at t = 0, on the seam
/// between tiles 0 and 1 (x = 25 600) at t ≈ 933 s, over play area B (tile x = 1) at
/// t = 2000 s.
const STORM: &str = "[{ kind = \"storm\", preset = \"puffy\", centre = [20000.0, 12800.0, 1100.0], \
                     radii = [5000.0, 5000.0, 3000.0], velocity = [6.0, 0.0] }]";
/// No cloud of the test preset anywhere, except what the storm brings.
const CLEAR: &str = "[{ box = [-1.0e8, -1.0e8, 1.0e8, 1.0e8], blend = 0.0, mix = { puffy = -1.0 } }]";
const SPEED: f64 = 6.0;
const START_X: f64 = 20_000.0;

/// Play areas, as /region bboxes 10 km square around the storm's track.
const AREA_A: &str = "15000,7800,25000,17800";
const AREA_B: &str = "27000,7800,37000,17800";

fn config() -> String {
    common::test_config(&[("worlds.default.regions", CLEAR), ("worlds.default.events", STORM)])
}

/// `/region` of the `low` layer.
async fn region(s: &InProcess, bbox: &str, t: f64) -> serde_json::Value {
    s.json(&format!("/v1/worlds/default/region?bbox={bbox}&t={t}&layer=low"))
        .await
}

/// The ETag of a density tile far from the storm (its bytes are those of the cleared world).
async fn etag(s: &InProcess) -> String {
    let r = s.get("/v1/worlds/default/tiles/0/-3/-3/density.u8?t=0&layer=low").await;
    assert_eq!(r.status(), StatusCode::OK);
    r.headers()["etag"].to_str().unwrap().to_string()
}

/// The level-0 `low` density tile (tx, 0): `(2, 256, 256)` row-major.
async fn tile(s: &InProcess, tx: i64, t: f64) -> Vec<f32> {
    s.f32s(&format!(
        "/v1/worlds/default/tiles/0/{tx}/0/density.f32?t={t}&layer=low"
    ))
    .await
}

/// The density summed over each column x of tiles 0 and 1 side by side (512 columns
/// of 100 m from x = 0), over rows `rows`.
fn column_mass(left: &[f32], right: &[f32], rows: std::ops::Range<usize>) -> Vec<f64> {
    let mut mass = vec![0.0; 512];
    for (half, tile) in [left, right].iter().enumerate() {
        for k in 0..2 {
            for r in rows.clone() {
                for c in 0..256 {
                    mass[half * 256 + c] += tile[(k * 256 + r) * 256 + c] as f64;
                }
            }
        }
    }
    mass
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_storm_crosses_from_one_play_area_to_the_other_on_time_and_seamlessly() {
    let s = InProcess::start(&config()).await;
    for t in [0.0, 1000.0, 2000.0] {
        let (left, right) = (tile(&s, 0, t).await, tile(&s, 1, t).await);
        // Where the cloud is: the mass-weighted mean x of the two tiles' columns.
        let mass = column_mass(&left, &right, 0..256);
        let total: f64 = mass.iter().sum();
        assert!(total > 100.0, "t = {t}: the storm makes cloud ({total})");
        let centre = mass
            .iter()
            .enumerate()
            .map(|(c, m)| (c as f64 + 0.5) * 100.0 * m)
            .sum::<f64>()
            / total;
        let want = START_X + SPEED * t;
        assert!(
            (centre - want).abs() < 1000.0,
            "t = {t}: the cloud is centred at x = {centre:.0} m, the storm at {want:.0} m"
        );
        // Nothing outside the storm: the region override clears the rest of the world.
        let far: f64 = mass
            .iter()
            .enumerate()
            .filter(|(c, _)| ((*c as f64 + 0.5) * 100.0 - want).abs() > 7000.0)
            .map(|(_, m)| m)
            .sum();
        assert_eq!(far, 0.0, "t = {t}: cloud more than 1.4 radii from the storm");

        // A /region straddling the seam equals the two tiles' cells inside it.
        let region = region(&s, "20000,7800,32000,17800", t).await;
        let (mut sum, mut n) = (0.0f64, 0usize);
        for (half, tile) in [&left, &right].iter().enumerate() {
            for k in 0..2 {
                for r in 78..178 {
                    for c in 0..256 {
                        let x = half * 256 + c;
                        if (200..320).contains(&x) {
                            sum += tile[(k * 256 + r) * 256 + c] as f64;
                            n += 1;
                        }
                    }
                }
            }
        }
        assert_eq!(n, 2 * 120 * 100);
        let mean = region["mean_density"].as_f64().unwrap();
        assert!(
            (mean - sum / n as f64).abs() < 1e-9,
            "t = {t}: /region {mean} vs tiles {}",
            sum / n as f64
        );
    }

    // The play areas: A is stormy and B clear at t = 0; the other way round at 2000 s.
    let (a0, b0) = (region(&s, AREA_A, 0.0).await, region(&s, AREA_B, 0.0).await);
    let (a1, b1) = (region(&s, AREA_A, 2000.0).await, region(&s, AREA_B, 2000.0).await);
    let cover = |v: &serde_json::Value| v["coverage"].as_f64().unwrap();
    assert!(cover(&a0) > 0.2 && cover(&b1) > 0.2, "storm over A then B: {a0} {b1}");
    assert_eq!(cover(&b0), 0.0, "B before the storm: {b0}");
    assert_eq!(cover(&a1), 0.0, "A after the storm: {a1}");

    // The high layer places the same preset but lies above the storm's 3 km semi-axis:
    // the region override clears it everywhere.
    let high = s
        .bytes("/v1/worlds/default/region?bbox=15000,7800,25000,17800&t=0&layer=high")
        .await;
    let high: serde_json::Value = serde_json::from_slice(&high).unwrap();
    assert_eq!(high["coverage"], 0.0, "{high}");
}

/// The mean density of a box under `regions` from t = 320 s to 1000 s, averaged over each
/// epoch: the test layer's epochs are 4 steps (40 s) and its cloud swings within each
/// (every run starts from an empty grid a few steps earlier).
async fn epoch_means(regions: &str) -> Vec<f64> {
    let s = InProcess::start(&common::test_config(&[("worlds.default.regions", regions)])).await;
    let series = s
        .json("/v1/worlds/default/series?bbox=2000,2000,8000,8000&t0=300&t1=1000&dt=10&layer=low")
        .await;
    let density: Vec<f64> = series["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["mean_density"].as_f64().unwrap())
        .collect();
    // From the epoch that starts at step 32 (t = 320).
    density[2..]
        .chunks_exact(4)
        .map(|e| e.iter().sum::<f64>() / 4.0)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_regional_override_fades_in_without_a_pop() {
    // The clear world, and then a box where the preset's cloud is pushed to the full
    // from t = 400 s over a ramp of 400 s.
    let regions = "[{ box = [-1.0e8, -1.0e8, 1.0e8, 1.0e8], blend = 0.0, mix = { puffy = -1.0 } }, \
                   { box = [0.0, 0.0, 10000.0, 10000.0], blend = 1000.0, mix = { puffy = 2.0e-0 }, start = 400.0, ramp = 400.0 }]";
    // Pushes add up: -1 + 1 = the preset's own climate inside the box; +2 is refused.
    let err = cloudscape_core::world::Config::parse(&common::test_config(&[("worlds.default.regions", regions)]))
        .unwrap_err()
        .to_string();
    assert!(err.contains("worlds.default.regions[1].mix.puffy"), "{err}");
    let regions = regions.replace("puffy = 2.0e-0", "puffy = 1.0");
    let epochs = epoch_means(&regions).await;
    let (first, last) = (epochs[0], *epochs.last().unwrap());
    assert_eq!(first, 0.0, "cleared before the override starts");
    assert!(last > 0.05, "the box's own climate after the ramp: {last}");
    let biggest = epochs.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
    assert!(
        biggest < 0.3 * (last - first),
        "no epoch changes the mean density by 30 % of the whole fade: {biggest} of {} ({epochs:?})",
        last - first
    );
    // And the same override without a ramp does jump (what the ramp is for).
    let abrupt = regions.replace("ramp = 400.0", "ramp = 0.0");
    let epochs = epoch_means(&abrupt).await;
    let jump = epochs.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max);
    assert!(
        jump > 2.0 * biggest,
        "without a ramp the override arrives in one go: {jump} vs {biggest}"
    );
}

#[test]
fn the_storm_has_the_same_bytes_on_every_thread_count() {
    let config = Config::parse(&config()).unwrap();
    let world = config.world("default").unwrap();
    // The seam: tile 0's last columns and tile 1's first ones, at the storm's crossing.
    let region = Region {
        x0: 200,
        y0: 60,
        cols: 120,
        rows: 140,
    };
    let grid = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                [0u32, 2].map(|level| {
                    let r = if level == 0 {
                        region
                    } else {
                        Region {
                            x0: 50,
                            y0: 15,
                            cols: 30,
                            rows: 35,
                        }
                    };
                    density::density(&world, 0, level, r, 933.0).unwrap().data
                })
            })
    };
    let one = grid(1);
    assert!(one[0].iter().any(|&d| d > 0.0), "the storm is in the region");
    assert!(one[1].iter().any(|&d| d > 0.0), "and in the far-field model");
    for threads in [2, 3, 4] {
        assert_eq!(grid(threads), one, "{threads} threads");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn events_are_part_of_the_fingerprint() {
    let a = InProcess::start(&config()).await;
    let same = InProcess::start(&config()).await;
    let slower = InProcess::start(&common::test_config(&[
        ("worlds.default.regions", CLEAR),
        (
            "worlds.default.events",
            &STORM.replace("velocity = [6.0, 0.0]", "velocity = [5.0, 0.0]"),
        ),
    ]))
    .await;
    let (ea, esame, eslower) = (etag(&a).await, etag(&same).await, etag(&slower).await);
    assert_eq!(ea, esame, "replicas with the same events agree");
    assert_ne!(
        ea, eslower,
        "a tile far from the storm still changes its ETag with the events"
    );
}

#[test]
fn malformed_events_and_regions_are_refused_naming_the_key() {
    let cases: [(&str, &str, &str); 12] = [
        (
            "worlds.default.events",
            "[{ kind = \"tornado\", preset = \"puffy\" }]",
            "worlds.default.events[0].kind",
        ),
        (
            "worlds.default.events",
            "[{ kind = \"storm\", preset = \"nimbus\", centre = [0.0, 0.0, 0.0], radii = [1.0, 1.0, 1.0] }]",
            "worlds.default.events[0].preset",
        ),
        (
            "worlds.default.events",
            "[{ kind = \"storm\", preset = \"puffy\", centre = [0.0, 0.0, 0.0] }]",
            "worlds.default.events[0].radii",
        ),
        (
            "worlds.default.events",
            "[{ kind = \"storm\", preset = \"puffy\", centre = [0.0, 0.0, 0.0], radii = [0.0, 1.0, 1.0] }]",
            "worlds.default.events[0].radii",
        ),
        (
            "worlds.default.events",
            "[{ kind = \"storm\", preset = \"puffy\", centre = [nan, 0.0, 0.0], radii = [1.0, 1.0, 1.0] }]",
            "worlds.default.events[0].centre",
        ),
        (
            "worlds.default.events",
            "[{ kind = \"storm\", preset = \"puffy\", centre = [0.0, 0.0, 0.0], radii = [1.0, 1.0, 1.0], start = 100.0, end = 50.0 }]",
            "worlds.default.events[0].end",
        ),
        (
            "worlds.default.events",
            "[{ kind = \"storm\", preset = \"puffy\", centre = [0.0, 0.0, 0.0], radii = [1.0, 1.0, 1.0], path = [[10.0, 0.0, 0.0], [5.0, 1.0, 1.0]] }]",
            "worlds.default.events[0].path[1]",
        ),
        (
            "worlds.default.events",
            "[{ kind = \"front\", preset = \"puffy\", origin = [0.0, 0.0], velocity = [0.0, 0.0], width = 100.0 }]",
            "worlds.default.events[0].velocity",
        ),
        (
            "worlds.default.events",
            "[{ kind = \"front\", preset = \"puffy\", origin = [0.0, 0.0], velocity = [1.0, 0.0], width = 100.0, intensity = 2.0 }]",
            "worlds.default.events[0].intensity",
        ),
        (
            "worlds.default.regions",
            "[{ box = [0.0, 0.0, 1.0, 1.0], polygon = [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], mix = { puffy = 1.0 } }]",
            "worlds.default.regions[0]",
        ),
        (
            "worlds.default.regions",
            "[{ polygon = [[0.0, 0.0], [1.0, 0.0]], mix = { puffy = 1.0 } }]",
            "worlds.default.regions[0].polygon",
        ),
        (
            "worlds.default.regions",
            "[{ box = [0.0, 0.0, 1.0, 1.0], mix = { puffy = -1.5 } }]",
            "worlds.default.regions[0].mix.puffy",
        ),
    ];
    for (path, value, key) in cases {
        let err = Config::parse(&common::test_config(&[(path, value)]))
            .unwrap_err()
            .to_string();
        assert!(err.contains(key), "{value}: {err}");
    }
    // An unknown key inside an event is named by the TOML parser.
    let err = Config::parse(&common::test_config(&[(
        "worlds.default.events",
        "[{ kind = \"storm\", preset = \"puffy\", centre = [0.0, 0.0, 0.0], radii = [1.0, 1.0, 1.0], speed = 3.0 }]",
    )]))
    .unwrap_err()
    .to_string();
    assert!(err.contains("speed"), "{err}");
}

/// What an operator sees: `cloudscape serve` on a config with a malformed event exits
/// with the key in its message, before it listens.
#[test]
fn serve_refuses_a_malformed_event_with_the_key() {
    let dir = std::env::temp_dir().join(format!("cloudscape-authored-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.toml");
    std::fs::write(
        &path,
        common::test_config(&[(
            "worlds.default.events",
            "[{ kind = \"front\", preset = \"puffy\", origin = [0.0, 0.0], velocity = [1.0, 0.0] }]",
        )]),
    )
    .unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cloudscape"))
        .args(["serve", "--config", path.to_str().unwrap(), "--listen", "127.0.0.1:0"])
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("worlds.default.events[0].width"), "{err}");
}
