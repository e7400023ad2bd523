//! A query string as the server receives it: URI parsing, percent-decoding, then every
//! parameter parser the handlers use. None may panic.
#![no_main]

use cloudscape_core::render::scene::parse_size;
use cloudscape_core::render::{Camera, Quality, Sun};
use cloudscape_server::params::{Params, parse_level, parse_tile_coordinate};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(uri) = format!("/v1/worlds/default/region?{text}").parse::<axum::http::Uri>() else {
        return;
    };
    let Ok(p) = Params::from_uri(&uri) else { return };
    let _ = p.time("t");
    let _ = p.time("t0");
    let _ = p.f64("dt");
    let _ = p.required_f64("x");
    let _ = p.level(40);
    let _ = p.bbox();
    for (name, value) in &p.0 {
        let _ = parse_level(value, 40);
        let _ = parse_tile_coordinate(name, value);
        let _ = Sun::parse(value).map(|s| s.bucket().centre().direction());
        let _ = Quality::parse(value);
        let _ = Camera::parse(value).map(|c| c.basis());
        let _ = parse_size(value);
    }
});
