//! OGC API – EDR (issue 24 item 4) over real sockets: the landing page, conformance
//! and collections, and the position, area and cube queries answered as CoverageJSON,
//! each checked against the other queries at the same place and time (`/sample`,
//! `/region`, `/series`, density tiles), and bad input answered with a JSON 4xx
//! before any work. (tests/ext/coveragejson_schema.sh validates the answers against
//! the published CoverageJSON schema.)

mod common;

use common::InProcess;
use serde_json::Value;

/// The test layers (tests/data/small.toml): low 1000–1200 m, 100 m cells, depth 2,
/// dt 10 s; high 5000–5200 m, 200 m cells, depth 1, dt 20 s.
const LOW_CELL: f64 = 100.0;

async fn start() -> InProcess {
    InProcess::start(&common::test_config(&[
        ("server.max_series", "8"),
        (
            "presets.puffy.precipitation",
            "{ liquid_water = 3.0, droplets = 50.0, onset = 100.0, efficiency = 1.0 }",
        ),
    ]))
    .await
}

fn numbers(v: &Value) -> Vec<Option<f64>> {
    v.as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(Value::as_f64)
        .collect()
}

fn present(v: &[Option<f64>]) -> Vec<f64> {
    v.iter().flatten().copied().collect()
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1.0)
}

/// The values of parameter `name` of a coverage.
fn range(coverage: &Value, name: &str) -> Vec<Option<f64>> {
    numbers(&coverage["ranges"][name]["values"])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn landing_conformance_and_collections_describe_every_world() {
    let s = start().await;
    let landing = s.json("/v1/edr").await;
    let rels: Vec<(&str, &str)> = landing["links"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| (l["rel"].as_str().unwrap(), l["href"].as_str().unwrap()))
        .collect();
    assert!(rels.contains(&("conformance", "/v1/edr/conformance")), "{rels:?}");
    assert!(rels.contains(&("data", "/v1/edr/collections")), "{rels:?}");
    assert!(
        landing["title"]
            .as_str()
            .unwrap()
            .contains("Environmental Data Retrieval")
    );

    let conformance = s.json("/v1/edr/conformance").await.to_string();
    for class in [
        "http://www.opengis.net/spec/ogcapi-common-1/1.0/conf/core",
        "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/core",
        "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/collections",
        "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/covjson",
        "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/json",
    ] {
        assert!(conformance.contains(class), "{class}");
    }

    let worlds = common::world_names(&s.json("/v1/worlds").await);
    let list = s.json("/v1/edr/collections").await;
    let ids: Vec<&str> = list["collections"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, worlds);

    let c = s.json("/v1/edr/collections/default").await;
    assert_eq!(c, list["collections"][0]);
    assert_eq!(c["output_formats"], serde_json::json!(["CoverageJSON"]));
    let names: Vec<&String> = c["parameter_names"].as_object().unwrap().keys().collect();
    assert_eq!(
        names,
        [
            "cloud_base",
            "cloud_cover",
            "cloud_top",
            "density",
            "precipitation_rate"
        ]
    );
    assert_eq!(
        c["parameter_names"]["precipitation_rate"]["unit"]["symbol"]["value"],
        "mm/h"
    );
    assert_eq!(c["parameter_names"]["cloud_base"]["unit"]["symbol"]["value"], "m");
    for q in ["position", "area", "cube"] {
        let link = &c["data_queries"][q]["link"];
        assert!(
            link["href"]
                .as_str()
                .unwrap()
                .starts_with(&format!("/v1/edr/collections/default/{q}?")),
            "{link}"
        );
        assert_eq!(link["variables"]["query_type"], q);
    }
    // Vertical extent: everything first, then each layer's band.
    assert_eq!(
        c["extent"]["vertical"]["interval"],
        serde_json::json!([["1000", "5200"], ["1000", "1200"], ["5000", "5200"]])
    );
    assert_eq!(c["extent"]["temporal"]["interval"][0][0], "1970-01-01T00:00:00Z");
    assert!(c["extent"]["spatial"]["crs"].as_str().unwrap().starts_with("ENGCRS["));

    // A seed names a collection too, unlisted.
    assert_eq!(s.json("/v1/edr/collections/7").await["id"], "7");

    // Revalidation costs nothing.
    let r = s.get("/v1/edr/collections/default").await;
    let etag = r.headers()["etag"].to_str().unwrap().to_string();
    let again = s
        .client
        .get(format!("{}/v1/edr/collections/default", s.base))
        .header("if-none-match", etag)
        .send()
        .await
        .unwrap();
    assert_eq!(again.status().as_u16(), 304);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_position_answers_what_sample_answers() {
    let s = start().await;
    let mut clouds = 0;
    let mut rain = 0;
    for (z, layer) in [
        (1050.0f64, ""),
        (1150.0, ""),
        (0.0, ""),
        (3000.0, ""),
        (5100.0, "&layer=high"),
    ] {
        for t in [0.0, 20.0] {
            for i in 0..6 {
                for j in 0..6 {
                    let (x, y) = (150.0 + 1000.0 * i as f64, 250.0 + 1000.0 * j as f64);
                    let sample = s
                        .json(&format!("/v1/worlds/default/sample?x={x}&y={y}&z={z}&t={t}{layer}"))
                        .await;
                    let path = format!(
                        "/v1/edr/collections/default/position?coords=POINT({x}%20{y})&z={z}&datetime={t}{layer}"
                    );
                    let r = s.get(&path).await;
                    assert_eq!(r.status().as_u16(), 200, "{path}");
                    assert_eq!(r.headers()["content-type"], "application/prs.coverage+json");
                    let c: Value = serde_json::from_slice(&r.bytes().await.unwrap()).unwrap();
                    assert_eq!(c["type"], "Coverage");
                    assert_eq!(c["domain"]["domainType"], "Point");
                    assert_eq!(c["domain"]["axes"]["x"]["values"][0], x);
                    assert_eq!(c["domain"]["axes"]["z"]["values"][0], z);
                    let density = range(&c, "density")[0].unwrap();
                    let rate = range(&c, "precipitation_rate")[0].unwrap();
                    assert_eq!(density, sample["density"].as_f64().unwrap(), "{path}");
                    assert_eq!(rate, sample["precipitation_mm_h"].as_f64().unwrap(), "{path}");
                    // A cloudy cell is in a covered column, between its base and top.
                    let cover = range(&c, "cloud_cover")[0].unwrap();
                    if sample["cloud"] == true {
                        assert_eq!(cover, 1.0, "{path}");
                        assert!(range(&c, "cloud_base")[0].unwrap() <= z.max(1000.0));
                    }
                    if cover == 0.0 {
                        assert_eq!(range(&c, "cloud_top")[0], None, "{path}");
                    }
                    clouds += usize::from(density > 0.0);
                    rain += usize::from(rate > 0.0);
                }
            }
        }
    }
    assert!(
        clouds > 0 && rain > 0,
        "the test points saw no cloud ({clouds}) or no rain ({rain})"
    );

    // ISO 8601 and plain seconds name the same instant, and the same bytes.
    let iso = s
        .get("/v1/edr/collections/default/position?coords=POINT(150%20250)&z=1050&datetime=1970-01-01T00:00:20Z")
        .await;
    let etag = iso.headers()["etag"].clone();
    let iso = iso.bytes().await.unwrap();
    let seconds = s
        .get("/v1/edr/collections/default/position?coords=POINT(150%20250)&z=1050&datetime=20")
        .await
        .bytes()
        .await
        .unwrap();
    assert_eq!(iso, seconds);
    let c: Value = serde_json::from_slice(&iso).unwrap();
    assert_eq!(
        c["domain"]["axes"]["t"]["values"],
        serde_json::json!(["1970-01-01T00:00:20Z"])
    );
    let again = s
        .client
        .get(format!(
            "{}/v1/edr/collections/default/position?coords=POINT(150%20250)&z=1050&datetime=20",
            s.base
        ))
        .header("if-none-match", etag)
        .send()
        .await
        .unwrap();
    assert_eq!(again.status().as_u16(), 304);

    // An interval is a PointSeries, one step per dt of the layer holding z.
    let series = s
        .json("/v1/edr/collections/default/position?coords=POINT(2150%203250)&z=1050&datetime=0/40&parameter-name=density,precipitation_rate")
        .await;
    assert_eq!(series["domain"]["domainType"], "PointSeries");
    let times = series["domain"]["axes"]["t"]["values"].as_array().unwrap().clone();
    assert_eq!(times.len(), 5);
    assert_eq!(times[4], "1970-01-01T00:00:40Z");
    assert_eq!(series["ranges"]["density"]["shape"], serde_json::json!([5]));
    assert_eq!(series["parameters"].as_object().unwrap().len(), 2);
    for (i, t) in [0, 10, 20, 30, 40].into_iter().enumerate() {
        let sample = s
            .json(&format!("/v1/worlds/default/sample?x=2150&y=3250&z=1050&t={t}"))
            .await;
        assert_eq!(range(&series, "density")[i], sample["density"].as_f64(), "t = {t}");
        assert_eq!(
            range(&series, "precipitation_rate")[i],
            sample["precipitation_mm_h"].as_f64(),
            "t = {t}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_area_aggregates_to_the_region_statistics() {
    let s = start().await;
    for (level, t) in [(0, 0.0), (0, 20.0), (1, 10.0)] {
        let region = s
            .json(&format!(
                "/v1/worlds/default/region?bbox=0,0,6400,4800&t={t}&level={level}"
            ))
            .await;
        let c = s
            .json(&format!(
                "/v1/edr/collections/default/area?coords=POLYGON((0%200,6400%200,6400%204800,0%204800,0%200))&datetime={t}&level={level}"
            ))
            .await;
        assert_eq!(c["domain"]["domainType"], "Grid");
        let (cols, rows) = (
            region["columns"]["cols"].as_u64().unwrap(),
            region["columns"]["rows"].as_u64().unwrap(),
        );
        assert_eq!(c["ranges"]["density"]["shape"], serde_json::json!([1, rows, cols]));
        assert_eq!(c["ranges"]["density"]["axisNames"], serde_json::json!(["t", "y", "x"]));
        let w = LOW_CELL * f64::from(1 << level);
        assert_eq!(c["domain"]["axes"]["x"]["start"], w / 2.0);
        assert_eq!(c["domain"]["axes"]["x"]["num"], cols);
        let what = format!("level {level}, t {t}");
        let density = present(&range(&c, "density"));
        assert_eq!(density.len() as u64, rows * cols, "{what}");
        assert!(
            close(mean(&density), region["mean_density"].as_f64().unwrap()),
            "{what}"
        );
        let cover = present(&range(&c, "cloud_cover"));
        assert!(close(mean(&cover), region["coverage"].as_f64().unwrap()), "{what}");
        let rate = present(&range(&c, "precipitation_rate"));
        assert!(
            close(mean(&rate), region["mean_precipitation_mm_h"].as_f64().unwrap()),
            "{what}"
        );
        assert_eq!(
            rate.iter().copied().fold(0.0, f64::max),
            region["max_precipitation_mm_h"].as_f64().unwrap()
        );
        let base = present(&range(&c, "cloud_base")).into_iter().reduce(f64::min);
        let top = present(&range(&c, "cloud_top")).into_iter().reduce(f64::max);
        assert_eq!(base, region["cloud_base"].as_f64(), "{what}");
        assert_eq!(top, region["cloud_top"].as_f64(), "{what}");
        if level == 0 {
            assert!(
                region["coverage"].as_f64().unwrap() > 0.0,
                "no cloud in the test area at t = {t}"
            );
        }
    }

    // A triangle with the same bbox: the columns whose centres lie inside keep the
    // rectangle's values, the others are null.
    let rect = s
        .json("/v1/edr/collections/default/area?coords=POLYGON((0%200,6400%200,6400%204800,0%204800))&datetime=0&parameter-name=density")
        .await;
    let tri = s
        .json("/v1/edr/collections/default/area?coords=POLYGON((0%200,6400%200,0%204800,0%200))&datetime=0&parameter-name=density")
        .await;
    let (rect, tri) = (range(&rect, "density"), range(&tri, "density"));
    assert_eq!(rect.len(), tri.len());
    let (cols, mut inside) = (64, 0);
    for (i, (r, t)) in rect.iter().zip(&tri).enumerate() {
        let (x, y) = ((i % cols) as f64 * 100.0 + 50.0, (i / cols) as f64 * 100.0 + 50.0);
        if x / 6400.0 + y / 4800.0 < 1.0 {
            assert_eq!(t, r, "column {i}");
            inside += 1;
        } else {
            assert_eq!(*t, None, "column {i}");
        }
    }
    assert!(inside > 1000, "{inside}");
}

/// A level-0 density tile of the low layer, `(2, 256, 256)` row-major.
async fn density_tile(s: &InProcess, t: f64) -> Vec<f32> {
    let r = s
        .get(&format!("/v1/worlds/default/tiles/0/0/0/density.f32?t={t}&layer=low"))
        .await;
    assert_eq!(r.status().as_u16(), 200);
    r.bytes()
        .await
        .unwrap()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cube_steps_by_dt_and_equals_the_series() {
    let s = start().await;
    let series = s.json("/v1/worlds/default/series?bbox=0,0,3000,2000&t0=0&t1=30").await;
    let c = s
        .json("/v1/edr/collections/default/cube?bbox=0,0,3000,2000&datetime=1970-01-01T00:00:00Z/1970-01-01T00:00:30Z")
        .await;
    let times = c["domain"]["axes"]["t"]["values"].clone();
    assert_eq!(
        times,
        serde_json::json!([
            "1970-01-01T00:00:00Z",
            "1970-01-01T00:00:10Z",
            "1970-01-01T00:00:20Z",
            "1970-01-01T00:00:30Z"
        ])
    );
    let points = series["points"].as_array().unwrap();
    assert_eq!(points.len(), 4);
    let per_step = 30 * 20;
    assert_eq!(c["ranges"]["cloud_cover"]["shape"], serde_json::json!([4, 20, 30]));
    for (i, p) in points.iter().enumerate() {
        let step = |name: &str| present(&range(&c, name)[i * per_step..(i + 1) * per_step]);
        assert!(
            close(mean(&step("density")), p["mean_density"].as_f64().unwrap()),
            "step {i}"
        );
        assert!(
            close(mean(&step("cloud_cover")), p["coverage"].as_f64().unwrap()),
            "step {i}"
        );
        assert!(
            close(
                mean(&step("precipitation_rate")),
                p["mean_precipitation_mm_h"].as_f64().unwrap()
            ),
            "step {i}"
        );
        assert_eq!(
            step("cloud_base").into_iter().reduce(f64::min),
            p["cloud_base"].as_f64()
        );
        assert_eq!(step("cloud_top").into_iter().reduce(f64::max), p["cloud_top"].as_f64());
    }

    // The high layer steps by its own dt (20 s).
    let high = s
        .json("/v1/edr/collections/default/cube?bbox=0,0,3000,2000&datetime=0/40&layer=high&parameter-name=density")
        .await;
    assert_eq!(high["domain"]["axes"]["t"]["values"].as_array().unwrap().len(), 3);

    // With z, density and cloud cover per cell of the selected levels: the density
    // tile's values.
    for t in [0.0, 20.0] {
        let tile = density_tile(&s, t).await;
        for (z, levels) in [
            ("1000/1200", vec![0usize, 1]),
            ("1150", vec![1]),
            ("1190,1010", vec![0, 1]),
        ] {
            let cube = s
                .json(&format!(
                    "/v1/edr/collections/default/cube?bbox=0,0,3000,2000&datetime={t}&z={z}"
                ))
                .await;
            let centres: Vec<f64> = levels.iter().map(|&k| 1050.0 + 100.0 * k as f64).collect();
            assert_eq!(
                cube["domain"]["axes"]["z"]["values"],
                serde_json::json!(centres),
                "z={z}"
            );
            assert_eq!(
                cube["ranges"]["density"]["axisNames"],
                serde_json::json!(["t", "z", "y", "x"])
            );
            let density = range(&cube, "density");
            let cover = range(&cube, "cloud_cover");
            assert_eq!(density.len(), levels.len() * per_step);
            for (n, &k) in levels.iter().enumerate() {
                for row in 0..20 {
                    for col in 0..30 {
                        let i = (n * 20 + row) * 30 + col;
                        let d = tile[(k * 256 + row) * 256 + col];
                        // Written as f32 (the shortest text that reads back as the same f32).
                        assert_eq!(
                            density[i].map(|v| v as f32),
                            Some(d),
                            "t {t} z {z} k {k} ({row}, {col})"
                        );
                        assert_eq!(cover[i], Some(if d >= 0.1 { 1.0 } else { 0.0 }));
                    }
                }
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_edr_requests_get_clear_errors_before_any_work() {
    let s = start().await;
    let computations = || async {
        let text = s.get("/metrics").await.text().await.unwrap();
        common::parse_metric(&text, "cloudscape_computations_total", &[("kind", "edr")])
    };
    let before = computations().await;
    let base = "/v1/edr/collections/default";
    let point = "coords=POINT(150%20150)";
    let square = "coords=POLYGON((0%200,1000%200,1000%201000,0%201000))";
    for (path, status, code) in [
        (
            format!("{base}/position?coords=POINT(1)&datetime=0"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?coords=POINT(a%20b)&datetime=0"),
            400,
            "invalid_number",
        ),
        (
            format!("{base}/position?coords=POINT(nan%200)&datetime=0"),
            400,
            "not_finite",
        ),
        (
            format!("{base}/position?coords=MULTIPOINT((1%202))&datetime=0"),
            400,
            "invalid_parameter",
        ),
        (format!("{base}/position?datetime=0"), 400, "missing_parameter"),
        (format!("{base}/position?{point}"), 400, "missing_parameter"),
        (
            format!("{base}/position?{point}&datetime=0&parameter-name=temperature"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=../1970-01-01T00:00:10Z"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=0/.."),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=30/0"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=1970-01-01T00:00:00"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=1969-12-31T23:59:59Z"),
            422,
            "time_out_of_range",
        ),
        (
            format!("{base}/position?{point}&datetime=1e12"),
            422,
            "time_out_of_range",
        ),
        (
            format!("{base}/position?{point}&datetime=0&f=xml"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=0&crs=CRS84"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=0&layer=nope"),
            404,
            "unknown_layer",
        ),
        (
            format!("{base}/position?coords=POINT(1e300%200)&datetime=0"),
            422,
            "coordinates_out_of_range",
        ),
        (
            format!("{base}/position?{point}&datetime=0/1000"),
            413,
            "series_too_long",
        ),
        (
            format!("{base}/area?coords=POLYGON((0%200,1%201))&datetime=0"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/area?coords=LINESTRING(0%200,1%201)&datetime=0"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/area?coords=POLYGON((0%200,1000%200,1000%201000)&datetime=0"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/area?coords=POLYGON((0%200,1e9%200,1e9%201e9,0%201e9))&datetime=0"),
            413,
            "region_too_large",
        ),
        (
            format!("{base}/area?{square}&datetime=0&level=99"),
            422,
            "level_out_of_range",
        ),
        (format!("{base}/area?{square}&datetime=0/1000"), 413, "series_too_long"),
        (
            format!("{base}/area?{square}&datetime=0&f=html"),
            400,
            "invalid_parameter",
        ),
        (format!("{base}/cube?bbox=10,0,0,10&datetime=0"), 400, "invalid_bbox"),
        (format!("{base}/cube?bbox=0,0,10&datetime=0"), 400, "invalid_parameter"),
        (
            format!("{base}/cube?bbox=0,0,1000,1000&datetime=0&z=5000"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/cube?bbox=0,0,1000,1000&datetime=0&z=3000/4000"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/cube?bbox=0,0,1000,1000&datetime=0&z=R2/1000/100"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/cube?bbox=0,0,1000,1000&datetime=0&z=1050&parameter-name=cloud_base"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/cube?bbox=0,0,1000,1000&datetime=0/1000"),
            413,
            "series_too_long",
        ),
        (
            format!("{base}/cube?bbox=0,0,1000,1000&datetime=0/1000&layer=high"),
            413,
            "series_too_long",
        ),
        ("/v1/edr/collections/nope".to_string(), 404, "unknown_world"),
        (
            format!("/v1/edr/collections/nope/position?{point}&datetime=0"),
            404,
            "unknown_world",
        ),
        (format!("{base}/radius?{point}&datetime=0"), 404, "not_found"),
        ("/v1/edr?f=html".to_string(), 400, "invalid_parameter"),
        ("/v1/edr/conformance?f=xml".to_string(), 400, "invalid_parameter"),
    ] {
        s.assert_error(&path, status, code).await;
    }
    // The unknown parameter is named.
    let (_, body) = s
        .status_json(&format!(
            "{base}/position?{point}&datetime=0&parameter-name=density,temperature"
        ))
        .await;
    assert!(body["message"].as_str().unwrap().contains("`temperature`"), "{body}");
    assert_eq!(computations().await, before, "a refused request computed something");
}
