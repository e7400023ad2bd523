//! Lightning (issue 24 item 2) over real sockets: `/v1/worlds/{world}/lightning` on the
//! embedded config's storm front. A box's strikes are the union of its halves' (in
//! space and in time), repeated queries agree, fair weather has none, and the limits
//! (span, box side) and malformed input get clear 4xx before any work.

mod common;

use cloudscape_core::world::DEFAULT_CONFIG;
use common::InProcess;

async fn start() -> InProcess {
    let text = DEFAULT_CONFIG.replacen("listen = \"127.0.0.1:8080\"", "listen = \"127.0.0.1:0\"", 1);
    InProcess::start(&text).await
}

async fn strikes(s: &InProcess, world: &str, bbox: [f64; 4], t0: f64, t1: f64) -> Vec<serde_json::Value> {
    let path = format!(
        "/v1/worlds/{world}/lightning?bbox={},{},{},{}&t0={t0}&t1={t1}",
        bbox[0], bbox[1], bbox[2], bbox[3]
    );
    s.json(&path).await["strikes"].as_array().unwrap().clone()
}

fn sorted(mut v: Vec<serde_json::Value>) -> Vec<String> {
    let mut s: Vec<String> = v.drain(..).map(|s| s.to_string()).collect();
    s.sort();
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn strikes_are_deterministic_and_a_box_is_the_union_of_its_halves() {
    let s = start().await;
    // The storm band is centred on y = 30 km (+1.5 m/s · t).
    let bbox = [-10_000.0, 20_000.0, 10_000.0, 40_000.0];
    let all = strikes(&s, "storm-front", bbox, 0.0, 900.0).await;
    assert!(all.len() > 5, "the storm should flash: {} strikes", all.len());
    let mut last = f64::MIN;
    for st in &all {
        let t = st["t"].as_f64().unwrap();
        let (x, y, z) = (
            st["x"].as_f64().unwrap(),
            st["y"].as_f64().unwrap(),
            st["z"].as_f64().unwrap(),
        );
        assert!(t >= last && (0.0..900.0).contains(&t), "{st}");
        last = t;
        assert!(
            (bbox[0]..bbox[2]).contains(&x) && (bbox[1]..bbox[3]).contains(&y),
            "{st}"
        );
        match st["kind"].as_str().unwrap() {
            "cg" => assert_eq!(z, 0.0),
            "ic" => assert!((800.0..=6800.0).contains(&z), "{st}"),
            k => panic!("kind {k}"),
        }
    }
    let kinds: Vec<&str> = all.iter().map(|s| s["kind"].as_str().unwrap()).collect();
    assert!(kinds.contains(&"cg") && kinds.contains(&"ic"), "{kinds:?}");
    // Space: west and east of x = 1234.5; time: before and after t = 456.7.
    let west = strikes(&s, "storm-front", [bbox[0], bbox[1], 1234.5, bbox[3]], 0.0, 900.0).await;
    let east = strikes(&s, "storm-front", [1234.5, bbox[1], bbox[2], bbox[3]], 0.0, 900.0).await;
    let early = strikes(&s, "storm-front", bbox, 0.0, 456.7).await;
    let late = strikes(&s, "storm-front", bbox, 456.7, 900.0).await;
    assert!(!west.is_empty() && !east.is_empty() && !early.is_empty() && !late.is_empty());
    assert_eq!(sorted([west, east].concat()), sorted(all.clone()));
    assert_eq!(sorted([early, late].concat()), sorted(all.clone()));
    // A fair-weather world has no lightning; the same query again gives the same list.
    assert!(strikes(&s, "default", bbox, 0.0, 900.0).await.is_empty());
    assert_eq!(strikes(&s, "storm-front", bbox, 0.0, 900.0).await, all);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lightning_limits_and_bad_input_get_clear_errors() {
    let s = start().await;
    #[rustfmt::skip] // one case a line: (path, status, error code)
    let cases = [
        ("/v1/worlds/storm-front/lightning?bbox=0,0,1000,1000&t0=0&t1=3601", 413, "region_too_large"),
        ("/v1/worlds/storm-front/lightning?bbox=0,0,50001,1000&t0=0&t1=60", 413, "region_too_large"),
        ("/v1/worlds/storm-front/lightning?bbox=0,0,1000,1000&t0=60&t1=60", 400, "invalid_parameter"),
        ("/v1/worlds/storm-front/lightning?bbox=0,0,1000,1000&t0=-1&t1=60", 422, "time_out_of_range"),
        ("/v1/worlds/storm-front/lightning?bbox=1000,0,0,1000&t0=0&t1=60", 400, "invalid_bbox"),
        ("/v1/worlds/storm-front/lightning?bbox=0,0,1000&t0=0&t1=60", 400, ""),
        ("/v1/worlds/storm-front/lightning?bbox=0,0,1000,1000&t0=0", 400, "missing_parameter"),
        ("/v1/worlds/storm-front/lightning?bbox=1e17,0,100000000000001000,1000&t0=0&t1=60", 422, "coordinates_out_of_range"),
        ("/v1/worlds/storm-front/lightning?bbox=0,0,1000,1000&t0=0&t1=60&layer=nope", 404, "unknown_layer"),
        ("/v1/worlds/nope/lightning?bbox=0,0,1000,1000&t0=0&t1=60", 404, "unknown_world"),
        // Checked even where nothing could flash.
        ("/v1/worlds/default/lightning?bbox=0,0,1000,1000&t0=0&t1=7200", 413, "region_too_large"),
    ];
    for (path, status, code) in cases {
        s.assert_error(path, status, code).await;
    }
    let (_, doc) = s.status_json("/openapi.json").await;
    assert!(doc["paths"]["/v1/worlds/{world}/lightning"].is_object());
}
