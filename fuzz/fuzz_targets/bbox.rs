//! `bbox=X0,Y0,X1,Y1` at any level: parsing, then the columns it covers.
#![no_main]

use cloudscape_core::density::Region;
use cloudscape_server::params::parse_list;
use cloudscape_core::world::Config;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&level, rest)) = data.split_first() else { return };
    let Ok(text) = std::str::from_utf8(rest) else { return };
    let Ok(b) = parse_list("bbox", text, 4) else { return };
    let config = Config::embedded();
    let world = config.world("default").unwrap();
    for layer in &world.layers {
        if let Ok(r) = Region::from_bbox(layer, level as u32 % 48, [b[0], b[1], b[2], b[3]], &config.limits) {
            assert!(r.cols > 0 && r.rows > 0);
            assert!(r.check(level as u32 % 48, layer.depth, &config.limits).is_ok());
        }
    }
});
