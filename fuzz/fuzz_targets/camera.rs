//! `camera=`, `size=` and `sun=` of a render: parsing, then the render plan (the level
//! choice and the limits, everything before the expensive work).
#![no_main]

use cloudscape_core::render::scene::{RenderRequest, parse_size, plan};
use cloudscape_core::render::{Camera, Quality, ShadingParams, Sun};
use cloudscape_core::world::Config;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let mut parts = text.splitn(3, '|');
    let Ok(camera) = Camera::parse(parts.next().unwrap_or("")) else { return };
    let (width, height) = parse_size(parts.next().unwrap_or("64x36")).unwrap_or((64, 36));
    let sun = parts.next().and_then(|s| Sun::parse(s).ok());
    let config = Config::embedded();
    let world = config.world("default").unwrap();
    for quality in Quality::ALL {
        let req = RenderRequest {
            camera,
            width,
            height,
            t: 0.0,
            quality,
            sun,
            params: ShadingParams::default(),
        };
        let _ = plan(&world, &config, &req);
    }
});
