//! Request keys: what identifies a response's bytes before anything is computed.
//!
//! A key names the world by a fingerprint of everything that shapes its output (seed
//! and every layer parameter), so two replicas with the same config agree, and a
//! changed config never serves old bytes under an old ETag. Time enters as a
//! canonical frame ([`cloudscape_core::world::SnappedTime`]): the bytes are computed
//! for that frame's time, which the response reports in `X-Cloudscape-T`.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use cloudscape_core::density::Region;
use cloudscape_core::world::{ALGORITHM_VERSION, Config, World};

use crate::error::ApiError;

/// FNV-1a, 64 bits, from the given offset basis. Stable across builds and machines,
/// which is what ETags shared by replicas need (std's hasher promises neither).
fn fnv1a(bytes: &[u8], basis: u64) -> u64 {
    let mut h = basis;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// 128 bits of stable hash as 32 hex digits.
pub fn stable_hash_hex(bytes: &[u8]) -> String {
    format!(
        "{:016x}{:016x}",
        fnv1a(bytes, 0xcbf2_9ce4_8422_2325),
        fnv1a(bytes, 0x6c62_272e_07bb_0142)
    )
}

/// A world resolved for a request, with the fingerprint its keys use.
#[derive(Clone)]
pub struct ResolvedWorld {
    pub world: World,
    /// Hash of seed + climate + the server's frame grid (`frames_per_step`, which
    /// decides what time a frame index stands for): equal fingerprints compute equal
    /// bytes, so replicas configured alike share ETags and shared-cache entries, and
    /// replicas configured differently never do.
    pub fingerprint: String,
}

/// The worlds of a config and the fingerprints of their climates, computed once.
pub struct Worlds {
    config: Config,
    /// `server.frames_per_step`: part of every fingerprint.
    frames_per_step: u32,
    /// Hash of each configured world's layers (its climate), by world name.
    climates: BTreeMap<String, String>,
}

fn climate_hash(world: &World) -> String {
    let json = serde_json::to_vec(&world.layers).expect("layers serialise");
    stable_hash_hex(&json)
}

impl Worlds {
    pub fn new(config: Config, frames_per_step: u32) -> Worlds {
        let climates = config
            .worlds
            .iter()
            .map(|(n, w)| (n.clone(), climate_hash(w)))
            .collect();
        Worlds {
            config,
            frames_per_step,
            climates,
        }
    }

    pub fn config(&self) -> &Config {
        &self.config
    }

    /// A configured world, or a decimal u64 seed with the default climate. Numeric
    /// names are canonicalised (`007` is `7`) so they share keys.
    pub fn resolve(&self, name: &str) -> Result<ResolvedWorld, ApiError> {
        let unknown = || ApiError::UnknownWorld(name.chars().take(64).collect());
        let (world, climate) = if let Some(w) = self.config.worlds.get(name) {
            (w.clone(), &self.climates[name])
        } else if !name.is_empty() && name.bytes().all(|b| b.is_ascii_digit()) {
            let seed: u64 = name.trim_start_matches('0').parse().or_else(|_| {
                if name.bytes().all(|b| b == b'0') {
                    Ok(0)
                } else {
                    Err(unknown())
                }
            })?;
            let mut w = self.config.world(&seed.to_string()).ok_or_else(unknown)?;
            w.name = seed.to_string();
            (w, &self.climates["default"])
        } else {
            return Err(unknown());
        };
        let fps = self.frames_per_step;
        let fingerprint = stable_hash_hex(format!("{}:{climate}:fps{fps}", world.seed).as_bytes());
        Ok(ResolvedWorld { world, fingerprint })
    }
}

/// A cache key: a canonical string naming everything the bytes depend on.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct CacheKey(pub String);

impl CacheKey {
    /// Starts a key for `kind` in `world`, layer `layer`: the algorithm version and the
    /// world fingerprint come first so that nothing else can make two keys collide.
    pub fn new(kind: &str, world: &ResolvedWorld, layer: usize) -> CacheKey {
        CacheKey(format!("{kind}|a{ALGORITHM_VERSION}|w{}|l{layer}", world.fingerprint))
    }

    /// As [`CacheKey::new`], for answers that print the world's name: `default` and
    /// `1` share every other key (same seed, same climate, same bytes), not these.
    pub fn naming(kind: &str, world: &ResolvedWorld, layer: usize) -> CacheKey {
        CacheKey::new(kind, world, layer).with("name", &world.world.name)
    }

    /// A key that depends on no world (splat sheets).
    pub fn global(kind: &str) -> CacheKey {
        CacheKey(format!("{kind}|a{ALGORITHM_VERSION}"))
    }

    /// Appends `|name=value`.
    pub fn with(mut self, name: &str, value: impl std::fmt::Display) -> CacheKey {
        let _ = write!(self.0, "|{name}={value}");
        self
    }

    /// Appends the columns of `region` at `level` (`/region`, `/series`, EDR `area` and
    /// `cube`): `|z=level|r=x0,y0,cols,rows`.
    pub fn with_region(self, level: u32, region: Region) -> CacheKey {
        let r = region;
        self.with("z", level)
            .with("r", format_args!("{},{},{},{}", r.x0, r.y0, r.cols, r.rows))
    }

    /// The strong ETag of the identity-encoded bytes of this key.
    pub fn etag(&self) -> String {
        format!("\"{}\"", stable_hash_hex(self.0.as_bytes()))
    }
}

/// Content codings the compression layer may add; the ETag of a compressed
/// representation is the identity ETag with `-coding` appended inside the quotes.
pub const CODINGS: [&str; 4] = ["gzip", "br", "zstd", "deflate"];

/// Whether an `If-None-Match` header value matches `etag` (weak comparison, RFC 9110
/// §13.1.2), accepting the tags of compressed representations of the same bytes.
pub fn if_none_match(header: &str, etag: &str) -> bool {
    let base = etag.strip_prefix("W/").unwrap_or(etag).trim_matches('"');
    header.split(',').map(str::trim).any(|tag| {
        if tag == "*" {
            return true;
        }
        let tag = tag.strip_prefix("W/").unwrap_or(tag).trim_matches('"');
        tag == base
            || CODINGS
                .iter()
                .any(|c| tag.strip_suffix(c).and_then(|t| t.strip_suffix('-')) == Some(base))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn a_default(w: &Worlds) -> String {
        w.resolve("default").unwrap().fingerprint
    }

    #[test]
    fn numeric_worlds_share_keys_and_configured_worlds_differ() {
        let w = Worlds::new(Config::embedded(), 4);
        let a = w.resolve("7").unwrap();
        let b = w.resolve("0007").unwrap();
        assert_eq!(a.fingerprint, b.fingerprint);
        assert_eq!(b.world.name, "7");
        assert_eq!(w.resolve("0").unwrap().world.seed, 0);
        assert_ne!(a.fingerprint, w.resolve("8").unwrap().fingerprint);
        // `default` has seed 1 and the default climate: the same bytes as world 1.
        assert_eq!(
            w.resolve("default").unwrap().fingerprint,
            w.resolve("1").unwrap().fingerprint
        );
        assert!(w.resolve("99999999999999999999").is_err());
        // Another frame grid gives other times for the same frame index: other keys.
        assert_ne!(
            Worlds::new(Config::embedded(), 5)
                .resolve("default")
                .unwrap()
                .fingerprint,
            a_default(&w)
        );
        assert!(w.resolve("nope").is_err());
        assert!(w.resolve("").is_err());
    }

    #[test]
    fn if_none_match_accepts_lists_weak_tags_and_coded_variants() {
        let e = "\"abc\"";
        assert!(if_none_match("\"abc\"", e));
        assert!(if_none_match("\"x\", W/\"abc\"", e));
        assert!(if_none_match("\"abc-gzip\"", e));
        assert!(if_none_match("*", e));
        assert!(!if_none_match("\"abcd\"", e));
        assert!(!if_none_match("\"abc-foo\"", e));
        // A weak ETag (discovery's) matches itself, strong or weak, and its coded forms.
        let weak = "W/\"abc\"";
        assert!(if_none_match("W/\"abc\"", weak) && if_none_match("\"abc\"", weak));
        assert!(if_none_match("W/\"abc-gzip\"", weak));
        assert!(!if_none_match("W/\"abd\"", weak));
    }
}
