//! OGC API – EDR over real sockets: the landing page, conformance and collections in
//! the forms OGC clients read (absolute links, the OpenAPI document in 3.0 and 3.1,
//! data links), the position, radius, area and cube queries answered as CoverageJSON,
//! each checked against the other queries at the same place and time (`/sample`,
//! `/region`, `/series`, density tiles), the items query against `/lightning`, OWSLib's
//! spelling of `parameter-name`, and bad input (unknown parameters included) answered
//! with a JSON 4xx before any work. (tests/ext/coveragejson_schema.sh,
//! tests/ext/edr_pydantic.sh and tests/ext/owslib_edr.sh run the published schema, the
//! validators and OWSLib against the same routes.)

mod common;

use cloudscape_core::world::DEFAULT_CONFIG;
use common::InProcess;
use serde_json::{Value, json};

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
    let rels: Vec<(&str, String)> = landing["links"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| (l["rel"].as_str().unwrap(), l["href"].as_str().unwrap().to_string()))
        .collect();
    assert!(
        rels.contains(&("conformance", format!("{}/v1/edr/conformance", s.base))),
        "{rels:?}"
    );
    assert!(
        rels.contains(&("data", format!("{}/v1/edr/collections", s.base))),
        "{rels:?}"
    );
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
    assert_eq!(c["output_formats"], json!(["CoverageJSON", "GeoJSON"]));
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
    for q in ["position", "radius", "area", "cube", "items"] {
        let link = &c["data_queries"][q]["link"];
        assert!(
            link["href"]
                .as_str()
                .unwrap()
                .starts_with(&format!("{}/v1/edr/collections/default/{q}?", s.base)),
            "{link}"
        );
        assert_eq!(link["variables"]["query_type"], q);
    }
    // Vertical extent: everything first, then each layer's band; the level centres.
    assert_eq!(
        c["extent"]["vertical"]["interval"],
        serde_json::json!([["1000", "5200"], ["1000", "1200"], ["5000", "5200"]])
    );
    assert_eq!(c["extent"]["vertical"]["values"], json!(["1050", "1150", "5100"]));
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
        (format!("{base}/radius?{point}&datetime=0"), 400, "missing_parameter"),
        (
            format!("{base}/radius?{point}&within=0&datetime=0"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/radius?{point}&within=nan&datetime=0"),
            400,
            "not_finite",
        ),
        (
            format!("{base}/radius?{point}&within=5&within-units=mi&datetime=0"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/radius?{point}&within=1e7&datetime=0"),
            413,
            "region_too_large",
        ),
        (
            format!("{base}/radius?coords=POINT(100%20100)&within=1&datetime=0"),
            422,
            "empty_region",
        ),
        (format!("{base}/trajectory?{point}&datetime=0"), 404, "not_found"),
        ("/v1/edr?f=html".to_string(), 400, "invalid_parameter"),
        ("/v1/edr/conformance?f=xml".to_string(), 400, "invalid_parameter"),
        // A parameter a route does not read is named, on every EDR route.
        ("/v1/edr/?colour=blue".to_string(), 400, "unknown_parameter"),
        ("/v1/edr/conformance?lang=en".to_string(), 400, "unknown_parameter"),
        ("/v1/edr/collections?limit=5".to_string(), 400, "unknown_parameter"),
        (format!("{base}?datetime=0"), 400, "unknown_parameter"),
        (
            format!("{base}/position?{point}&datetime=0&resolution-x=3"),
            400,
            "unknown_parameter",
        ),
        (
            format!("{base}/area?{square}&datetime=0&z=1100"),
            400,
            "unknown_parameter",
        ),
        (
            format!("{base}/cube?bbox=0,0,1000,1000&datetime=0&within=5"),
            400,
            "unknown_parameter",
        ),
        (
            format!("{base}/radius?{point}&within=500&datetime=0&bbox=0,0,1,1"),
            400,
            "unknown_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=0&parameter-name=density&parameter_names=density"),
            400,
            "invalid_parameter",
        ),
        (
            format!("{base}/position?{point}&datetime=0&parameter_names=rain"),
            400,
            "invalid_parameter",
        ),
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
    let (_, body) = s.status_json(&format!("{base}/area?{square}&datetime=0&z=1100")).await;
    let message = body["message"].as_str().unwrap();
    assert!(
        message.contains("`z`") && message.contains("reads coords, level, datetime"),
        "the refusal names the parameter and what the route reads: {body}"
    );
    assert_eq!(computations().await, before, "a refused request computed something");
}

/// The JSON body of an answer.
async fn json_of(r: reqwest::Response) -> Value {
    serde_json::from_slice(&r.bytes().await.unwrap()).unwrap()
}

/// The `href` of each link of `doc` with relation `rel`, with its media type.
fn links<'a>(doc: &'a Value, rel: &str) -> Vec<(&'a str, &'a str)> {
    doc["links"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|l| l["rel"] == rel)
        .map(|l| (l["href"].as_str().unwrap(), l["type"].as_str().unwrap()))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ogc_clients_find_the_landing_page_the_api_and_the_data_as_they_form_urls() {
    let s = start().await;
    // OWSLib asks for the landing page with a slash after the URL it is given.
    let plain = s.get("/v1/edr").await;
    let cache_control = plain.headers()["cache-control"].to_str().unwrap().to_string();
    let plain = plain.bytes().await.unwrap();
    assert_eq!(s.bytes("/v1/edr/").await, plain.to_vec());
    let landing: Value = serde_json::from_slice(&plain).unwrap();
    // Links name the request's Host, so the document is that client's alone.
    assert!(cache_control.starts_with("private"), "{cache_control}");

    // One API definition per OpenAPI version, each what its media type says.
    let apis = links(&landing, "service-desc");
    assert_eq!(
        apis,
        [
            (
                format!("{}/v1/edr/api", s.base).as_str(),
                "application/vnd.oai.openapi+json;version=3.0"
            ),
            (
                format!("{}/openapi.json", s.base).as_str(),
                "application/vnd.oai.openapi+json;version=3.1"
            ),
        ]
    );
    for (href, media) in apis {
        let r = s.client.get(href).send().await.unwrap();
        assert_eq!(r.status().as_u16(), 200, "{href}");
        let content_type = r.headers()["content-type"].to_str().unwrap().to_string();
        let doc = json_of(r).await;
        let version = media.rsplit('=').next().unwrap();
        assert!(
            doc["openapi"].as_str().unwrap().starts_with(version),
            "{href}: {}",
            doc["openapi"]
        );
        assert!(doc["paths"]["/v1/edr/collections/{world}/radius"].is_object(), "{href}");
        if version == "3.0" {
            assert_eq!(content_type, media);
        }
    }

    // A collection links its data: one `data` link per query, as OWSLib's data() reads.
    let c = s.json("/v1/edr/collections/default").await;
    let data: Vec<&str> = links(&c, "data").into_iter().map(|(href, _)| href).collect();
    let collection = format!("{}/v1/edr/collections/default", s.base);
    assert_eq!(
        data,
        ["position", "radius", "area", "cube", "items"].map(|q| format!("{collection}/{q}"))
    );
    assert_eq!(links(&c, "self"), [(collection.as_str(), "application/json")]);
    // Instances are not served: a world is one deterministic run.
    assert!(links(&c, "instances").is_empty() && c["data_queries"].get("instances").is_none());

    // Behind a proxy, the configured public URL is named, and the documents are shared.
    let s = InProcess::start(&common::test_config(&[(
        "server.public_url",
        "\"https://cdn.example/clouds/\"",
    )]))
    .await;
    let r = s.get("/v1/edr/collections").await;
    assert!(
        !r.headers()["cache-control"].to_str().unwrap().contains("private"),
        "{:?}",
        r.headers()
    );
    let list = json_of(r).await;
    assert_eq!(
        links(&list, "self"),
        [("https://cdn.example/clouds/v1/edr/collections", "application/json")]
    );
    assert_eq!(
        links(&list["collections"][0], "data")[0].0,
        "https://cdn.example/clouds/v1/edr/collections/default/position"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn collections_and_coverages_take_the_forms_the_standards_give() {
    let s = start().await;
    let c = s.json("/v1/edr/collections/default").await;
    // EDR: the steps of the times as ISO 8601 repeating intervals (one per layer dt),
    // vertical values as strings, parameters with plain-string labels, no member of
    // our own (the layers are in the description and the discovery document).
    assert_eq!(
        c["extent"]["temporal"]["values"],
        json!([
            "R25340230080/1970-01-01T00:00:00Z/PT10S",
            "R12670115040/1970-01-01T00:00:00Z/PT20S"
        ])
    );
    assert!(c.get("layers").is_none(), "{c}");
    let density = &c["parameter_names"]["density"];
    assert_eq!(density["label"], "Cloud density");
    assert!(density["description"].as_str().unwrap().contains("[0, 1]"));
    assert_eq!(density["observedProperty"]["label"], "Cloud density");
    assert_eq!(density["unit"]["label"], "dimensionless");
    assert_eq!(
        c["parameter_names"]["cloud_top"]["observedProperty"]["id"],
        "http://vocab.nerc.ac.uk/standard_name/cloud_top_altitude/"
    );
    assert_eq!(c["distanceunits"], json!(["m", "km"]));
    assert_eq!(
        c["data_queries"]["radius"]["link"]["variables"]["within_units"],
        json!(["m", "km"])
    );
    assert!(
        c["description"]
            .as_str()
            .unwrap()
            .contains("low (1000–1200 m, dt 10 s)")
    );

    // CoverageJSON: the parameters keep internationalised strings; the plane's
    // reference system is a type CoverageJSON defines.
    let coverage = s
        .json("/v1/edr/collections/default/position?coords=POINT(150%20250)&z=1050&datetime=0")
        .await;
    assert_eq!(
        coverage["parameters"]["density"]["observedProperty"]["label"]["en"],
        "Cloud density"
    );
    let referencing = coverage["domain"]["referencing"].as_array().unwrap();
    assert_eq!(referencing[0]["coordinates"], json!(["x", "y"]));
    assert_eq!(referencing[0]["system"]["type"], "ProjectedCRS");
    assert!(referencing[0]["system"].get("id").is_none());
    assert_eq!(referencing[1]["system"]["type"], "VerticalCRS");
    assert_eq!(referencing[2]["system"]["type"], "TemporalRS");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn owslib_spelling_of_parameter_name_filters_the_same() {
    let s = start().await;
    let position = "/v1/edr/collections/default/position?coords=POINT(150%20250)&z=1050&datetime=20";
    let edr = s.get(&format!("{position}&parameter-name=density,cloud_top")).await;
    let owslib = s.get(&format!("{position}&parameter_names=density,cloud_top")).await;
    assert_eq!(edr.headers()["etag"], owslib.headers()["etag"]);
    let owslib = json_of(owslib).await;
    assert_eq!(owslib, json_of(edr).await);
    let names: Vec<&String> = owslib["ranges"].as_object().unwrap().keys().collect();
    assert_eq!(names, ["cloud_top", "density"]);
    for (path, parameters) in [
        (
            "area?coords=POLYGON((0%200,1000%200,0%201000))&datetime=0&parameter_names=cloud_cover",
            vec!["cloud_cover"],
        ),
        (
            "cube?bbox=0,0,1000,1000&datetime=0&z=1000/1200&parameter_names=density",
            vec!["density"],
        ),
        (
            "radius?coords=POINT(500%20500)&within=300&datetime=0&parameter_names=precipitation_rate,cloud_base",
            vec!["cloud_base", "precipitation_rate"],
        ),
    ] {
        let c = s.json(&format!("/v1/edr/collections/default/{path}")).await;
        let names: Vec<&String> = c["ranges"].as_object().unwrap().keys().collect();
        assert_eq!(names, parameters, "{path}");
    }
    // Cache busters and tracking parameters stay harmless on the other routes.
    s.json("/v1/worlds/default/sample?x=0&y=0&z=1050&t=0&_=1699999999")
        .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_radius_is_the_area_of_its_disc() {
    let s = start().await;
    let (x, y, r) = (1500.0, 1500.0, 800.0);
    let radius = s
        .json(&format!(
            "/v1/edr/collections/default/radius?coords=POINT({x}%20{y})&within={r}&datetime=0/20"
        ))
        .await;
    // The disc's bbox as a rectangle: the same columns, every one with a value.
    let (x0, y0, x1, y1) = (x - r, y - r, x + r, y + r);
    let rect = s
        .json(&format!(
            "/v1/edr/collections/default/area?coords=POLYGON(({x0}%20{y0},{x1}%20{y0},{x1}%20{y1},{x0}%20{y1}))&datetime=0/20"
        ))
        .await;
    assert_eq!(radius["domain"], rect["domain"]);
    assert_eq!(radius["domain"]["domainType"], "Grid");
    let axes = &radius["domain"]["axes"];
    let (cols, rows) = (
        axes["x"]["num"].as_u64().unwrap() as usize,
        axes["y"]["num"].as_u64().unwrap() as usize,
    );
    assert_eq!((cols, rows), (16, 16));
    let centre = |i: usize, axis: &str| axes[axis]["start"].as_f64().unwrap() + i as f64 * LOW_CELL;
    let mut inside = 0;
    for name in [
        "cloud_cover",
        "density",
        "cloud_base",
        "cloud_top",
        "precipitation_rate",
    ] {
        let (disc, square) = (range(&radius, name), range(&rect, name));
        assert_eq!(disc.len(), 3 * rows * cols, "{name}");
        for (i, (d, q)) in disc.iter().zip(&square).enumerate() {
            let (col, row) = (i % cols, i / cols % rows);
            let (cx, cy) = (centre(col, "x"), centre(row, "y"));
            if (cx - x).powi(2) + (cy - y).powi(2) <= r * r {
                assert_eq!(d, q, "{name} column ({cx}, {cy})");
                inside += 1;
            } else {
                assert_eq!(*d, None, "{name} column ({cx}, {cy}) is outside the disc");
            }
        }
    }
    // 208 column centres (about π r² / cell², 201) per quantity and time.
    assert_eq!(inside, 5 * 3 * 208, "columns inside");
    // The same disc in kilometres, or with no unit (metres, as OWSLib sends it).
    let base = format!("/v1/edr/collections/default/radius?coords=POINT({x}%20{y})&datetime=0/20");
    let bytes = s.bytes(&format!("{base}&within={r}")).await;
    assert_eq!(s.bytes(&format!("{base}&within=0.8&within-units=km")).await, bytes);
    assert_eq!(s.bytes(&format!("{base}&within={r}&within-units=m")).await, bytes);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn items_are_the_lightning_strikes_as_geojson() {
    let text = DEFAULT_CONFIG.replacen("listen = \"127.0.0.1:8080\"", "listen = \"127.0.0.1:0\"", 1);
    let s = InProcess::start(&text).await;
    // The storm band is centred on y = 30 km.
    let bbox = "-10000,20000,10000,40000";
    let strikes = s
        .json(&format!("/v1/worlds/storm-front/lightning?bbox={bbox}&t0=0&t1=900"))
        .await;
    let strikes = strikes["strikes"].as_array().unwrap();
    assert!(strikes.len() > 5, "the storm should flash: {}", strikes.len());
    let items = "/v1/edr/collections/storm-front/items";
    let r = s
        .get(&format!(
            "{items}?bbox={bbox}&datetime=1970-01-01T00:00:00Z/1970-01-01T00:15:00Z"
        ))
        .await;
    assert_eq!(r.headers()["content-type"], "application/geo+json");
    let fc = json_of(r).await;
    assert_eq!(fc["type"], "FeatureCollection");
    assert_eq!(fc["numberMatched"], strikes.len());
    assert_eq!(fc["numberReturned"], strikes.len());
    assert_eq!(fc["links"], json!([]));
    let features = fc["features"].as_array().unwrap();
    for (f, st) in features.iter().zip(strikes) {
        assert_eq!(f["type"], "Feature");
        assert_eq!(f["geometry"]["type"], "Point");
        assert_eq!(f["geometry"]["coordinates"], json!([st["x"], st["y"], st["z"]]));
        assert_eq!(f["properties"]["t"], st["t"]);
        assert_eq!(f["properties"]["kind"], st["kind"]);
        assert!(
            f["properties"]["datetime"]
                .as_str()
                .unwrap()
                .starts_with("1970-01-01T00:")
        );
    }
    // Pages: limit and offset, the next one linked.
    let page = s
        .json(&format!("{items}?bbox={bbox}&datetime=0/900&limit=2&offset=1"))
        .await;
    assert_eq!(page["numberMatched"], strikes.len());
    assert_eq!(page["numberReturned"], 2);
    assert_eq!(page["features"].as_array().unwrap()[..], features[1..3]);
    assert_eq!(
        page["links"][0]["href"],
        format!("items?bbox={bbox}&datetime=0%2F900&limit=2&offset=3")
    );
    assert_eq!(page["links"][0]["rel"], "next");
    // Fair weather has none.
    let calm = s
        .json(&format!("/v1/edr/collections/default/items?bbox={bbox}&datetime=0/900"))
        .await;
    assert_eq!(
        (
            calm["numberMatched"].as_u64(),
            calm["features"].as_array().map(Vec::len)
        ),
        (Some(0), Some(0))
    );
    // The limits of /lightning, and what an items query must be.
    for (query, status, code) in [
        (format!("bbox={bbox}&datetime=0/3601"), 413, "region_too_large"),
        ("bbox=0,0,60000,1000&datetime=0/60".to_string(), 413, "region_too_large"),
        (format!("bbox={bbox}&datetime=60"), 400, "invalid_parameter"),
        (format!("bbox={bbox}&datetime=60/60"), 400, "invalid_parameter"),
        (format!("bbox={bbox}&datetime=0/60&limit=0"), 400, "invalid_parameter"),
        (format!("bbox={bbox}&datetime=0/60&offset=-1"), 400, "invalid_parameter"),
        (
            format!("bbox={bbox}&datetime=0/60&f=CoverageJSON"),
            400,
            "invalid_parameter",
        ),
        (format!("bbox={bbox}&datetime=0/60&layer=nope"), 404, "unknown_layer"),
        (format!("bbox={bbox}&datetime=0/60&q=storm"), 400, "unknown_parameter"),
        ("datetime=0/60".to_string(), 400, "missing_parameter"),
    ] {
        s.assert_error(&format!("{items}?{query}"), status, code).await;
    }
}
