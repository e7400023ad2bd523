//! Config TOML text: parse and validate (the worlds and the `[server]` section); a
//! valid config resolves its worlds.
#![no_main]

use cloudscape_core::world::Config;
use cloudscape_server::ServerConfig;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let _ = ServerConfig::parse(text);
    if let Ok(config) = Config::parse(text) {
        for name in config.worlds.keys() {
            assert!(config.world(name).is_some());
        }
        let _ = config.world("18446744073709551615");
    }
});
