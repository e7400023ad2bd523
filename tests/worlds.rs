//! The embedded config's worlds over a real socket: discovery lists the showcase worlds,
//! and each has the weather it is named for, measured by `/region` coverage (the
//! fraction of columns with a cell of density >= 0.1).

mod common;

use common::{ServeProcess, client};

fn coverage(server: &ServeProcess, world: &str, layer: &str, bbox: &str, t: f64) -> f64 {
    let url = format!(
        "{}/v1/worlds/{world}/region?bbox={bbox}&t={t}&layer={layer}",
        server.base
    );
    let r = client().get(&url).send().unwrap();
    assert_eq!(r.status().as_u16(), 200, "{url}");
    let v: serde_json::Value = serde_json::from_slice(&r.bytes().unwrap()).unwrap();
    v["coverage"].as_f64().unwrap()
}

#[test]
fn the_showcase_worlds_are_listed_and_have_their_weather() {
    let server = ServeProcess::start(&[], &[]);
    let list: serde_json::Value = serde_json::from_slice(&server.get("/v1/worlds").bytes().unwrap()).unwrap();
    let names = common::world_names(&list);
    for w in ["default", "overcast", "storm-front", "archipelago"] {
        assert!(names.iter().any(|n| n == w), "{w} missing from {names:?}");
    }
    // Default: fair-weather cumulus, 30–50 % of columns covered in every box and time
    // (measured 0.385–0.493 over five boxes and three times; the box gave 0.854
    // under the old default), with a broken deck above and cirrus.
    for (bbox, t) in [
        ("0,0,20000,20000", 60.0),
        ("40000,-30000,60000,-10000", 4000.0),
        ("-80000,50000,-60000,70000", 43200.0),
    ] {
        let c = coverage(&server, "default", "cumulus", bbox, t);
        assert!((0.3..=0.5).contains(&c), "default cumulus {bbox} t={t}: {c}");
        let deck = coverage(&server, "default", "stratocumulus", bbox, t);
        assert!(
            (0.15..=0.5).contains(&deck),
            "default stratocumulus {bbox} t={t}: {deck}"
        );
    }
    // Overcast: the old default's heavy deck.
    let c = coverage(&server, "overcast", "stratocumulus", "0,0,20000,20000", 60.0);
    assert!(c > 0.75, "overcast {c}");
    // Storm front: a band of deep cloud centred on y = 30 km + 1.5 m/s · t, about
    // 24 km across; clear air ahead of it (north) and behind it.
    let t = 60.0;
    let band = coverage(&server, "storm-front", "cumulonimbus", "0,26000,20000,34000", t);
    assert!(band > 0.8, "in the band: {band}");
    for clear in ["0,60000,20000,80000", "0,-20000,20000,0"] {
        assert_eq!(
            coverage(&server, "storm-front", "cumulonimbus", clear, t),
            0.0,
            "{clear}"
        );
        assert_eq!(coverage(&server, "storm-front", "anvil", clear, t), 0.0, "{clear}");
    }
    // The front moves north with the wind: an hour later the band is 5.4 km farther.
    let later = 3600.0;
    let ahead_now = coverage(&server, "storm-front", "cumulonimbus", "0,40000,20000,46000", t);
    let ahead_later = coverage(&server, "storm-front", "cumulonimbus", "0,40000,20000,46000", later);
    assert!(
        ahead_later > ahead_now + 0.1,
        "the front advances: {ahead_now} then {ahead_later}"
    );

    // The far-field levels place the band where level 0 does (Dobashi ellipsoids
    // drift with the wind at every level): at t = 11 h it is 59 km farther north.
    let url = |level: u32, bbox: &str| {
        format!(
            "{}/v1/worlds/storm-front/region?bbox={bbox}&t=39600&layer=cumulonimbus&level={level}",
            server.base
        )
    };
    for level in [0, 1, 3] {
        for (bbox, covered) in [("0,90000,10000,100000", true), ("0,25000,10000,35000", false)] {
            let v: serde_json::Value =
                serde_json::from_slice(&client().get(url(level, bbox)).send().unwrap().bytes().unwrap()).unwrap();
            let c = v["coverage"].as_f64().unwrap();
            assert_eq!(c > 0.8, covered, "level {level} {bbox} at 11 h: {c}");
        }
    }
    // Archipelago: the authored thunderstorm (centre x = 5000 + 8 (t − 1800), y = 4000)
    // is over the harbour at t = 2400 and over the highlands at t = 5550; nothing
    // convects anywhere else.
    let harbour = "5000,-1000,15000,9000";
    let highlands = "30000,-1000,40000,9000";
    let storm = |bbox: &str, t: f64| coverage(&server, "archipelago", "cumulonimbus", bbox, t);
    let (h0, g0) = (storm(harbour, 2400.0), storm(highlands, 2400.0));
    let (h1, g1) = (storm(harbour, 5550.0), storm(highlands, 5550.0));
    assert!(h0 > 0.5 && g0 == 0.0, "storm over the harbour first: {h0} {g0}");
    assert!(g1 > 0.5 && h1 == 0.0, "then over the highlands: {h1} {g1}");
    assert_eq!(storm("60000,-1000,70000,9000", 5550.0), 0.0, "no convection elsewhere");
}

/// `default` (seed 1) and the seed world `1` compute the same bytes, but the JSON
/// answers that print the world's name print the name asked for, whichever was asked
/// first (they do not share those cache entries).
#[test]
fn answers_name_the_world_they_were_asked_for() {
    let server = ServeProcess::start(&[], &[]);
    for (route, query) in [
        ("region", "bbox=0,0,1000,1000&t=0"),
        ("series", "bbox=0,0,1000,1000&t0=0&t1=20"),
        ("sample", "x=50&y=50&z=1300&t=0"),
        ("lightning", "bbox=0,0,1000,1000&t0=0&t1=60"),
    ] {
        for world in ["default", "1", "default", "01"] {
            let url = format!("{}/v1/worlds/{world}/{route}?{query}", server.base);
            let v: serde_json::Value =
                serde_json::from_slice(&client().get(&url).send().unwrap().bytes().unwrap()).unwrap();
            let want = if world == "default" { "default" } else { "1" };
            assert_eq!(v["world"], want, "{url}: {v}");
        }
    }
}
