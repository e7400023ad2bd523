//! Precipitation (issue 24 item 1) over real sockets: `precipitation.png` tiles, the
//! `precipitation_mm_h`/`precipitation_kind` of `/sample` and the precipitation
//! statistics of `/region` and `/series`, each checked against an independent
//! recomputation from the served density tiles (the rule of
//! `cloudscape_core::weather::precipitation`, written out again here by hand), at
//! tile seams, and with bad input.

mod common;

use common::InProcess;

/// The test world with a preset wet enough to rain from its two thin layers, and a
/// freezing level of 1200 m (snow level 900 m: snow inside the low layer at 1000 m
/// and above, rain at the ground).
const WET: &str = "{ liquid_water = 3.0, droplets = 50.0, onset = 100.0, efficiency = 1.0 }";
const FREEZING_LEVEL: f64 = 1200.0;

/// The test layers (tests/data/small.toml): low 1000–1200 m at 100 m cells, depth 2;
/// high 5000–5200 m at 200 m cells, depth 1.
const LOW: (f64, f64, usize) = (100.0, 100.0, 2);
const HIGH: (f64, f64, usize) = (200.0, 200.0, 1);

async fn start() -> InProcess {
    let text = common::test_config(&[
        ("server.max_series", "8"),
        ("presets.puffy.precipitation", WET),
        ("worlds.default.freezing_level", &FREEZING_LEVEL.to_string()),
    ]);
    InProcess::start(&text).await
}

/// A level-0 density tile of `layer`, `(depth, 256, 256)` row-major.
async fn density(s: &InProcess, layer: &str, tx: i64, ty: i64, t: f64) -> Vec<f32> {
    s.f32s(&format!(
        "/v1/worlds/default/tiles/0/{tx}/{ty}/density.f32?t={t}&layer={layer}"
    ))
    .await
}

/// The RGBA pixels of a level-0 precipitation tile of `layer`.
async fn precipitation(s: &InProcess, layer: &str, tx: i64, ty: i64, t: f64) -> Vec<u8> {
    let b = s
        .bytes(&format!(
            "/v1/worlds/default/tiles/0/{tx}/{ty}/precipitation.png?t={t}&layer={layer}"
        ))
        .await;
    let mut reader = png::Decoder::new(std::io::Cursor::new(b)).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (256, 256));
    assert_eq!(info.color_type, png::ColorType::Rgba);
    buf.truncate(info.buffer_size());
    buf
}

/// The rule by hand: LWP = Σ ρ · 3 g/m³ · Δz; R = 0.0156 ((LWP − 100) / 50)^1.75 mm/h.
fn rate_by_hand(column: &[f32], cell_height: f64) -> f64 {
    let lwp: f64 = column.iter().map(|&d| d as f64 * 3.0 * cell_height).sum();
    if lwp <= 100.0 {
        0.0
    } else {
        0.0156 * ((lwp - 100.0) / 50.0).powf(1.75)
    }
}

/// The column (row, col) of a `(depth, 256, 256)` tile.
fn column(tile: &[f32], depth: usize, row: usize, col: usize) -> Vec<f32> {
    (0..depth).map(|k| tile[(k * 256 + row) * 256 + col]).collect()
}

/// The documented R channel: round(255 · sqrt(min(R, 100) / 100)).
fn r_channel(rate: f64) -> u8 {
    ((rate.min(100.0) / 100.0).sqrt() * 255.0).round() as u8
}

/// The pixel of column (row, col) of a tile (PNG rows run north to south).
fn pixel(png: &[u8], row: usize, col: usize) -> [u8; 4] {
    let i = ((255 - row) * 256 + col) * 4;
    png[i..i + 4].try_into().unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn precipitation_tiles_follow_the_rule_and_the_queries_agree_with_them() {
    let s = start().await;
    let t = 40.0;
    let (_, height, depth) = LOW;
    // Two tiles side by side: every pixel is the rule applied to the density column.
    let mut wet_columns = 0;
    let (mut sum, mut max, mut wet_in_bbox, mut n_bbox) = (0.0, 0.0f64, 0, 0);
    for tx in [-1i64, 0] {
        let density = density(&s, "low", tx, 0, t).await;
        let png = precipitation(&s, "low", tx, 0, t).await;
        for row in 0..256 {
            for col in 0..256 {
                let c = column(&density, depth, row, col);
                let rate = rate_by_hand(&c, height);
                let [r, g, b, a] = pixel(&png, row, col);
                if rate > 0.0 {
                    wet_columns += 1;
                    assert!(r.abs_diff(r_channel(rate)) <= 1, "({tx}) {row},{col}: {r} for {rate}");
                    assert_eq!(a, 255);
                    // Sea level is below the snow level (900 m): rain there.
                    assert_eq!(g, 0);
                    let base = c
                        .iter()
                        .position(|&d| d >= 0.1)
                        .map_or(0, |k| ((k as f64 + 0.5) / depth as f64 * 255.0).round() as u8);
                    assert_eq!(b, base, "{row},{col}");
                } else {
                    assert_eq!([r, g, b, a], [0, 0, 0, 0], "({tx}) {row},{col} is dry");
                }
                // The bbox below: columns -40..40, rows 100..160.
                let gcol = tx * 256 + col as i64;
                if (-40..40).contains(&gcol) && (100..160).contains(&row) {
                    n_bbox += 1;
                    sum += rate;
                    max = max.max(rate);
                    wet_in_bbox += (rate > 0.0) as u32;
                }
            }
        }
    }
    assert!(
        wet_columns > 1000 && wet_columns < 2 * 65536 - 1000,
        "the test world should rain in part of the tiles: {wet_columns} wet columns"
    );

    // /region over a bbox straddling the seam: the statistics of the tiles' columns.
    let region = s
        .json(&format!(
            "/v1/worlds/default/region?bbox=-4000,10000,4000,16000&t={t}&layer=low"
        ))
        .await;
    assert_eq!(n_bbox, 80 * 60);
    let frac = region["precipitating"].as_f64().unwrap();
    assert!((frac - wet_in_bbox as f64 / n_bbox as f64).abs() < 1e-12, "{region}");
    let mean = region["mean_precipitation_mm_h"].as_f64().unwrap();
    assert!(
        (mean - sum / n_bbox as f64).abs() < 1e-9,
        "{mean} vs {}",
        sum / n_bbox as f64
    );
    let rmax = region["max_precipitation_mm_h"].as_f64().unwrap();
    assert!((rmax - max).abs() < 1e-9, "{rmax} vs {max}");
    assert!(frac > 0.0 && frac < 1.0, "the bbox should be partly wet: {frac}");

    // /series at t equals /region.
    let series = s
        .json("/v1/worlds/default/series?bbox=-4000,10000,4000,16000&t0=20&t1=40&dt=20&layer=low")
        .await;
    let point = &series["points"][1];
    assert_eq!(point["t"], 40.0);
    for k in ["precipitating", "mean_precipitation_mm_h", "max_precipitation_mm_h"] {
        assert_eq!(point[k], region[k], "{k}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sample_reads_the_tile_pixel_on_both_sides_of_a_seam() {
    let s = start().await;
    let t = 40.0;
    let (cell, height, depth) = LOW;
    let d_left = density(&s, "low", -1, 0, t).await;
    let d_right = density(&s, "low", 0, 0, t).await;
    let p_left = precipitation(&s, "low", -1, 0, t).await;
    let p_right = precipitation(&s, "low", 0, 0, t).await;
    let high_tile = density(&s, "high", 0, 0, t).await;
    let mut wet = 0;
    // Columns −1 and 0 (either side of the seam at x = 0) and the far edge, rows 0..256
    // in steps: each /sample (a one-column computation) gives the tile's rate.
    for row in (0..256).step_by(17) {
        for (col, density, png, tile_col) in [
            (-1i64, &d_left, &p_left, 255usize),
            (0, &d_right, &p_right, 0),
            (255, &d_right, &p_right, 255),
        ] {
            let (x, y) = ((col as f64 + 0.5) * cell, (row as f64 + 0.5) * cell);
            let a = s
                .json(&format!("/v1/worlds/default/sample?x={x}&y={y}&z=1050&t={t}&layer=low"))
                .await;
            let rate = a["precipitation_mm_h"].as_f64().unwrap();
            let by_hand = rate_by_hand(&column(density, depth, row, tile_col), height);
            assert!(
                (rate - by_hand).abs() <= 1e-9 * by_hand.max(1.0),
                "{x},{y}: {rate} vs {by_hand}"
            );
            let [r, _, _, alpha] = pixel(png, row, tile_col);
            assert_eq!(alpha == 255, rate > 0.0, "{x},{y}");
            assert!(r.abs_diff(r_channel(rate)) <= 1, "{x},{y}: {r} vs {rate}");
            // 1050 m is above the snow level (900 m).
            let kind = if rate > 0.0 { "snow" } else { "none" };
            assert_eq!(a["precipitation_kind"], kind, "{a}");
            wet += (rate > 0.0) as u32;

            // At the ground, under both layers: the sum of their column rates, as rain.
            if col == 0 {
                let g = s
                    .json(&format!("/v1/worlds/default/sample?x={x}&y={y}&z=0&t={t}"))
                    .await;
                assert!(g["layer"].is_null() && g["cell"].is_null(), "{g}");
                // The high layer's 200 m columns: column 0, row ⌊y / 200⌋.
                let (hc, hh, hd) = HIGH;
                let high = rate_by_hand(&column(&high_tile, hd, (y / hc) as usize, 0), hh);
                let total = g["precipitation_mm_h"].as_f64().unwrap();
                assert!((total - (by_hand + high)).abs() <= 1e-9 * total.max(1.0), "{g}");
                let kind = if total > 0.0 { "rain" } else { "none" };
                assert_eq!(g["precipitation_kind"], kind, "{g}");
            }
        }
    }
    assert!(wet > 0, "some sampled columns should rain");
    // Above every layer nothing falls.
    let sky = s.json("/v1/worlds/default/sample?x=50&y=50&z=30000&t=40").await;
    assert_eq!(
        (sky["precipitation_mm_h"].as_f64(), sky["precipitation_kind"].as_str()),
        (Some(0.0), Some("none"))
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_precipitation_requests_get_clear_errors() {
    let s = start().await;
    #[rustfmt::skip] // one case a line: (path, status, error code)
    let cases = [
        ("/v1/worlds/default/tiles/0/0/0/precipitation.png?t=-1", 422, "time_out_of_range"),
        ("/v1/worlds/default/tiles/0/0/0/precipitation.png?t=nan", 400, "not_finite"),
        ("/v1/worlds/default/tiles/0/0/0/precipitation.png?t=0&layer=nope", 404, "unknown_layer"),
        ("/v1/worlds/default/tiles/99/0/0/precipitation.png?t=0", 422, "level_out_of_range"),
        ("/v1/worlds/nope/tiles/0/0/0/precipitation.png?t=0", 404, "unknown_world"),
        ("/v1/worlds/default/tiles/0/0/0/precipitation.jpg?t=0", 404, "unknown_product"),
        ("/v1/worlds/default/sample?x=0&y=0&z=nan&t=0", 400, "not_finite"),
        ("/v1/worlds/default/sample?x=1e300&y=0&z=0&t=0", 422, "coordinates_out_of_range"),
        ("/v1/worlds/default/sample?x=0&y=0&t=0", 400, "missing_parameter"),
        ("/v1/worlds/default/region?bbox=0,0,1e9,1e9&t=0", 413, "region_too_large"),
    ];
    for (path, status, code) in cases {
        s.assert_error(path, status, code).await;
    }
    // Discovery states where snow starts, so a client can read the tile at its altitude.
    let world = s.json("/v1/worlds/default").await;
    assert_eq!(world["freezing_level"], FREEZING_LEVEL);
    assert_eq!(world["snow_level"], FREEZING_LEVEL - 300.0);
    assert!(world["products"].to_string().contains("precipitation.png"));
    assert!(world["lightning"].as_str().unwrap().contains("/lightning?bbox="));
    // The product is documented in the OpenAPI document, and so are the new fields.
    let doc = s.json("/openapi.json").await;
    let products = doc["components"]["schemas"]["TileProduct"]["enum"].to_string();
    assert!(products.contains("precipitation.png"), "{products}");
    let sample = doc["components"]["schemas"]["SampleAnswer"].to_string();
    assert!(sample.contains("precipitation_mm_h") && sample.contains("precipitation_kind"));
    assert!(
        doc["components"]["schemas"]["PrecipitationStats"]
            .to_string()
            .contains("precipitating")
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_shading_leaves_the_tiles_precipitation_map_in_the_cache() {
    // Two servers of one config: `a` shades the tile first and answers its
    // precipitation.png from the density that shading was built from; `b` computes
    // precipitation.png from the tile's own density. Same bytes, and `a` computed none.
    let (a, b) = (start().await, start().await);
    let world = a.json("/v1/worlds/default").await;
    assert_eq!(world["layers"][0]["precipitates"], true, "{}", world["layers"][0]);
    assert_eq!(world["layers"][0]["lightning"], false);
    let tile = "/v1/worlds/default/tiles/0/-1/0";
    let q = "?t=60&layer=low";
    a.bytes(&format!("{tile}/billboards.bin{q}")).await;
    let from_shading = a.bytes(&format!("{tile}/precipitation.png{q}")).await;
    let direct = b.bytes(&format!("{tile}/precipitation.png{q}")).await;
    assert!(
        from_shading == direct,
        "precipitation.png differs between the sibling and the direct computation"
    );
    let computed =
        |s: String| common::parse_metric(&s, "cloudscape_computations_total", &[("kind", "tile_precipitation")]);
    let text = |s: &InProcess| {
        let url = format!("{}/metrics", s.base);
        let c = s.client.clone();
        async move { c.get(url).send().await.unwrap().text().await.unwrap() }
    };
    assert_eq!(computed(text(&a).await), 0.0);
    assert_eq!(computed(text(&b).await), 1.0);
}
