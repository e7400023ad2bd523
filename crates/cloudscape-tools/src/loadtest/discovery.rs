//! What the load generator reads from the server's discovery (`GET /v1/worlds/{world}`):
//! the layers (for the players' level choice), the warm areas (the towns of the
//! [`super::geometry::GeometryKind::Towns`] world) and the world clock (where the run
//! starts when `--t` is not given).

use serde::{Deserialize, Serialize};

use cloudscape_client::RemoteWorld;

use super::geometry::Town;

/// The server's world clock (`clock` in discovery): world seconds are
/// `offset + rate · (seconds since the epoch)`, `now` when discovery was answered.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq)]
pub struct ServerClock {
    #[serde(default)]
    pub offset: f64,
    pub rate: f64,
    pub now: f64,
}

/// One warm area as discovery lists it (the fields the generator uses; `levels`,
/// `products`, `qualities` and `layers` say what the server keeps warm there).
#[derive(Deserialize)]
struct WarmArea {
    name: String,
    bbox: [f64; 4],
    #[serde(default)]
    polygon: Option<Vec<[f64; 2]>>,
}

/// The parts of discovery beyond [`RemoteWorld`]; both absent on servers before issue 34.
#[derive(Deserialize)]
struct Extras {
    #[serde(default)]
    warm: Vec<WarmArea>,
    #[serde(default)]
    clock: Option<ServerClock>,
}

/// A world as the generator knows it from discovery.
#[derive(Clone, Debug)]
pub struct Discovery {
    pub world: RemoteWorld,
    /// The warm areas as towns, in the server's order (empty when it lists none).
    pub towns: Vec<Town>,
    pub clock: Option<ServerClock>,
}

impl Discovery {
    /// Parses a discovery document; the message says what is wrong with it.
    pub fn parse(text: &str) -> Result<Discovery, String> {
        let world: RemoteWorld = serde_json::from_str(text).map_err(|e| format!("not a world description: {e}"))?;
        if world.layers.is_empty() {
            return Err("the world has no layers".into());
        }
        let extras: Extras =
            serde_json::from_str(text).map_err(|e| format!("its warm areas or clock are malformed: {e}"))?;
        let towns = extras
            .warm
            .iter()
            .map(|a| {
                Town::from_area(&a.name, a.bbox, a.polygon.as_deref())
                    .ok_or_else(|| format!("warm area `{}` has an empty bbox {:?}", a.name, a.bbox))
            })
            .collect::<Result<_, _>>()?;
        let clock = extras.clock.filter(|c| c.now.is_finite() && c.rate.is_finite());
        Ok(Discovery { world, towns, clock })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::loadtest::geometry::{Geometry, GeometryKind};

    const LAYERS: &str = r#""name": "default", "maxzoom": 8, "layers": [
        {"name": "cumulus", "base": 1200, "top": 2600, "cell_size": 100, "dt": 20}]"#;

    #[test]
    fn warm_areas_become_towns_and_the_clock_is_read() {
        let text = format!(
            r#"{{{LAYERS}, "warm": [
                {{"name": "harbour", "bbox": [0, 0, 4000, 2000], "polygon": null,
                  "levels": [0, 1], "products": ["billboards.bin"], "qualities": ["fast"], "layers": null}},
                {{"name": "keep", "bbox": [10000, 10000, 13000, 13000],
                  "polygon": [[10000, 10000], [13000, 10000], [10000, 13000]],
                  "levels": [0], "products": ["shadow.png"], "qualities": ["fast"], "layers": ["cumulus"]}}],
              "clock": {{"offset": 100, "rate": 2, "now": 86500.5}}}}"#
        );
        let d = Discovery::parse(&text).unwrap();
        assert_eq!(d.world.layers.len(), 1);
        assert_eq!(d.towns.len(), 2);
        assert_eq!(
            (d.towns[0].name.as_str(), d.towns[0].centre, d.towns[0].radius),
            ("harbour", [2000.0, 1000.0], 500.0)
        );
        // The triangle's centroid, a third of the way in.
        assert!((d.towns[1].centre[0] - 11_000.0).abs() < 1e-9 && (d.towns[1].centre[1] - 11_000.0).abs() < 1e-9);
        assert_eq!(d.towns[1].radius, 750.0);
        // The towns geometry uses them: every group starts in one of the two.
        let geo = Geometry::new(GeometryKind::Towns, 32, 9, d.towns.clone(), 60.0);
        assert!(geo.towns_from_server && geo.towns == d.towns);
        for g in 0..32 {
            let p = geo.position(g, 0.0);
            assert!(d.towns.iter().any(|t| t.contains([p[0], p[1]])), "group {g} at {p:?}");
        }
        assert_eq!(
            d.clock,
            Some(ServerClock {
                offset: 100.0,
                rate: 2.0,
                now: 86_500.5
            })
        );
    }

    #[test]
    fn servers_without_warm_areas_or_clock_are_read_too() {
        let d = Discovery::parse(&format!("{{{LAYERS}}}")).unwrap();
        assert!(d.towns.is_empty() && d.clock.is_none());
        let d = Discovery::parse(&format!(r#"{{{LAYERS}, "warm": []}}"#)).unwrap();
        assert!(d.towns.is_empty());
    }

    #[test]
    fn malformed_documents_say_what_is_wrong() {
        let e = Discovery::parse(r#"{"name": "x", "maxzoom": 3, "layers": []}"#).unwrap_err();
        assert!(e.contains("no layers"), "{e}");
        let e = Discovery::parse(&format!(r#"{{{LAYERS}, "warm": [{{"name": "a", "bbox": [0, 0]}}]}}"#)).unwrap_err();
        assert!(e.contains("warm areas"), "{e}");
        let e = Discovery::parse(&format!(
            r#"{{{LAYERS}, "warm": [{{"name": "a", "bbox": [5, 0, 5, 9]}}]}}"#
        ))
        .unwrap_err();
        assert!(e.contains("`a`"), "{e}");
        assert!(
            Discovery::parse("<html>")
                .unwrap_err()
                .starts_with("not a world description")
        );
    }
}
