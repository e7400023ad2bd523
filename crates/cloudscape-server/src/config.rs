//! The `[server]` section of the configuration: HTTP settings, read from the same TOML
//! text as the worlds (`cloudscape_core::world::Config` allows the section and leaves
//! it to this crate).

use serde::Deserialize;

use cloudscape_core::world::ConfigError;

fn invalid(key: &str, message: &str) -> ConfigError {
    ConfigError::invalid(key, message)
}

/// HTTP server settings (`[server]`), read by this crate. Every key has a default.
#[derive(Clone, Debug, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct ServerConfig {
    /// Address to listen on.
    pub listen: String,
    /// Memory budget of what the server holds: the computations running or queued
    /// (their estimated working memory, `compute_memory_bytes`, up to a quarter of
    /// this), the state tiles keep between keyframes (`kept_share` of the rest) and the
    /// encoded responses (the remainder). Peak RSS stays within this plus 512 MiB
    /// (replies being sent, the process itself, the allocator's overhead).
    pub cache_bytes: u64,
    /// The share of `cache_bytes` (less the computations' part) that tiles may keep
    /// between keyframes (the density grids of their latest keyframe ends and, at level
    /// 0, the automaton's runs: `crate::kept`), in [0, 0.9]; the responses get the
    /// rest. 0 keeps nothing, and every keyframe is computed as if the tile had never
    /// been seen.
    pub kept_share: f64,
    /// Compute jobs that may be running or queued at once; 0 means 4 × cores.
    /// A request that finds the queue full is shed with 503.
    pub compute_queue: u32,
    /// Time budget of one request, milliseconds.
    pub request_timeout_ms: u64,
    /// Canonical frames per automaton step: `t` is snapped to a grid of `dt / frames_per_step`.
    pub frames_per_step: u32,
    /// `Cache-Control` of responses whose `t` is already a canonical frame time.
    pub cache_control: String,
    /// `Cache-Control` of everything else (non-canonical `t`, discovery).
    pub cache_control_other: String,
    /// After SIGTERM, how long `/readyz` says 503 while requests are still served.
    pub drain_ms: u64,
    /// How long in-flight requests may take to finish once listening stops.
    pub shutdown_timeout_ms: u64,
    /// Once listening stops, how long connections not running a handler (idle,
    /// half-sent headers, slow readers) may stay before they are closed, ms.
    pub shutdown_grace_ms: u64,
    /// Longest time to receive a whole request head (start line and headers), ms,
    /// from when the server waits for it: bounds slowloris clients.
    pub header_read_timeout_ms: u64,
    /// A kept-alive connection with no request and no byte moving for this long is
    /// closed, ms. (The header-read timeout also runs while a connection waits for
    /// its next request: the shorter one applies.) Proxies in front should drop idle
    /// upstream connections sooner (nginx `keepalive_timeout` in the upstream block).
    pub idle_timeout_ms: u64,
    /// A connection whose client takes no byte of its response for this long is
    /// closed and the response freed, ms.
    pub write_timeout_ms: u64,
    /// Connections served at once; past it a new connection gets 503 with
    /// `Retry-After` and is closed. 0 means what the open-file limit leaves after a
    /// reserve (at most 4096).
    pub max_connections: u32,
    /// Largest request head (start line and headers) in bytes, the connection's read
    /// buffer: a larger one gets 431. Within [8192, 1048576]. The default, 96 KiB, has
    /// room for the longest target the URI parser accepts (64 KiB, else 414) and
    /// 32 KiB of headers.
    pub max_header_bytes: u32,
    /// Most time points one `/series` request may ask for.
    pub max_series: u32,
    /// URL of an optional Redis shared by replicas as a second-level cache
    /// (`redis://HOST:PORT/DB`, `rediss://` for TLS, `redis+unix:///PATH`; a user and
    /// password for Redis `AUTH` go in it: `redis://USER:PASSWORD@HOST:PORT/DB`); empty
    /// means none.
    pub redis_url: String,
    /// Key of the MAC that seals every value written to Redis (`crate::shared::Seal`):
    /// with it, only replicas that hold it can write a value the others will serve.
    /// Empty: values carry a digest only (garbage, truncated values and values under
    /// another key's name are refused; a deliberate forger is not). At least 16 bytes.
    pub redis_secret: String,
    /// PEM certificates to trust for a `rediss://` Redis instead of the system's roots;
    /// empty means the system's.
    pub redis_ca_file: String,
    /// Largest product written to Redis, bytes; larger ones are computed by each replica
    /// that needs them (and lookups read no more than this).
    pub redis_max_value_bytes: u64,
    /// Longest a Redis lookup or write may take (connecting included) before the
    /// request goes on without it, milliseconds.
    pub redis_timeout_ms: u64,
    /// After a Redis failure, how long requests skip Redis before trying it again, ms.
    pub redis_retry_ms: u64,
    /// Expiry of the entries written to Redis, seconds; 0 means none (rely on Redis's
    /// `maxmemory-policy`).
    pub redis_ttl_s: u64,
    /// Estimated working memory that the admitted compute jobs may hold together,
    /// bytes; a job that does not fit is shed with 503 (one that needs more than all of
    /// it runs only while no other job does). Taken out of `cache_bytes` up to a
    /// quarter of it. 0 (the default): a quarter of `cache_bytes`, at least 256 MiB.
    pub compute_memory_bytes: u64,
    /// Bytes that replies still being sent may hold together; past it a request is
    /// answered 503 with `Retry-After` instead of another large body.
    pub reply_bytes: u64,
    /// Compute threads that compute-ahead may use at once (the next keyframes of the
    /// tiles being watched, `ahead`): a bounded share, so requests keep priority.
    /// 0 turns compute-ahead off.
    pub ahead_threads: u32,
    /// Most tile variants the hot set follows for compute-ahead; the least watched are
    /// forgotten first.
    pub ahead_tiles: u32,
    /// Compute threads that keeping play areas warm may use at once once the server is
    /// ready (`crate::warm`; before, it may use them all): the current and next
    /// keyframes of `[[worlds.NAME.warm]]` areas. 0 keeps no area warm (nor lists any
    /// in discovery, nor waits for any before readiness).
    pub warm_threads: u32,
    /// Most tile variants (tile × layer × computation × quality) the play areas of all
    /// worlds may keep warm together; a config whose areas need more is refused.
    pub max_warm_tiles: u32,
    /// Origins whose scripts may read the answers (CORS, [`crate::cors`]): `["*"]`
    /// (the default) is any origin; a list such as `["https://game.example"]` only
    /// those; `[]` sends no CORS headers. A string is read as a comma-separated list
    /// (`CLOUDSCAPE_SERVER_CORS_ORIGINS=https://a.example,https://b.example`).
    #[serde(deserialize_with = "origin_list")]
    pub cors_origins: Vec<String>,
    /// The scheme and authority clients reach the server at (`https://clouds.example`),
    /// for the absolute URLs of TileJSON documents; empty means the request's `Host`.
    pub public_url: String,
}

/// A list of strings, or one string of comma-separated entries.
fn origin_list<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<String>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Origins {
        List(Vec<String>),
        Text(String),
    }
    Ok(match Origins::deserialize(d)? {
        Origins::List(l) => l,
        Origins::Text(t) => t
            .split(',')
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(str::to_string)
            .collect(),
    })
}

/// URL schemes of the Redis connections the server can open (plain TCP or a Unix socket).
const REDIS_SCHEMES: [&str; 4] = ["redis://", "rediss://", "redis+unix://", "unix://"];

fn default_listen() -> String {
    "127.0.0.1:8080".to_string()
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            listen: default_listen(),
            cache_bytes: 3 << 30,
            kept_share: 0.5,
            compute_queue: 0,
            request_timeout_ms: 10_000,
            frames_per_step: 4,
            cache_control: "public, max-age=31536000, immutable".to_string(),
            cache_control_other: "public, max-age=60".to_string(),
            drain_ms: 1000,
            shutdown_timeout_ms: 30_000,
            shutdown_grace_ms: 1000,
            header_read_timeout_ms: 10_000,
            idle_timeout_ms: 5_000,
            write_timeout_ms: 15_000,
            max_connections: 0,
            max_header_bytes: 96 << 10,
            max_series: 256,
            redis_url: String::new(),
            redis_secret: String::new(),
            redis_ca_file: String::new(),
            redis_max_value_bytes: 8 << 20,
            redis_timeout_ms: 100,
            redis_retry_ms: 1000,
            redis_ttl_s: 86_400,
            compute_memory_bytes: 0,
            reply_bytes: 128 << 20,
            ahead_threads: 1,
            ahead_tiles: 4096,
            warm_threads: 1,
            max_warm_tiles: 4096,
            cors_origins: vec!["*".to_string()],
            public_url: String::new(),
        }
    }
}

impl ServerConfig {
    /// Estimated working memory the admitted compute jobs may hold together.
    pub fn compute_bytes(&self) -> u64 {
        match self.compute_memory_bytes {
            0 => (self.cache_bytes / 4).max(256 << 20),
            n => n,
        }
    }

    /// The part of `cache_bytes` the computations take: theirs, up to a quarter.
    fn computing_share(&self) -> u64 {
        self.compute_bytes().min(self.cache_bytes / 4)
    }

    /// Bytes the tiles' kept state may hold: `kept_share` of `cache_bytes` less the
    /// computations' part.
    pub fn kept_bytes(&self) -> u64 {
        ((self.cache_bytes - self.computing_share()) as f64 * self.kept_share) as u64
    }

    /// Bytes the encoded responses may hold: the rest of `cache_bytes`.
    pub fn response_bytes(&self) -> u64 {
        self.cache_bytes - self.computing_share() - self.kept_bytes()
    }

    /// Checks the values that serde cannot (ranges, header syntax, URL schemes).
    /// Every number has a range: a value past it would not mean more of the same but
    /// kill the process or hang it (a `/series` of 4e9 points allocates 32 GB at once;
    /// a `drain_ms` of 2^63 never lets SIGTERM finish). The byte budgets are also held
    /// to the machine's memory, by [`crate::check_config`].
    pub fn validate(&self) -> Result<(), ConfigError> {
        const MINUTE: u64 = 60_000;
        const HOUR: u64 = 60 * MINUTE;
        for (key, value, least, most) in [
            ("server.frames_per_step", self.frames_per_step as u64, 1, 64),
            ("server.compute_queue", self.compute_queue as u64, 0, 1 << 16),
            // The longest time a request may run, and the shutdown's phases: minutes.
            ("server.request_timeout_ms", self.request_timeout_ms, 1, 10 * MINUTE),
            ("server.drain_ms", self.drain_ms, 0, 10 * MINUTE),
            ("server.shutdown_timeout_ms", self.shutdown_timeout_ms, 0, 10 * MINUTE),
            ("server.shutdown_grace_ms", self.shutdown_grace_ms, 0, 10 * MINUTE),
            (
                "server.header_read_timeout_ms",
                self.header_read_timeout_ms,
                1,
                10 * MINUTE,
            ),
            ("server.idle_timeout_ms", self.idle_timeout_ms, 1, HOUR),
            ("server.write_timeout_ms", self.write_timeout_ms, 1, 10 * MINUTE),
            // The kernel's default limit of descriptors a process may have (nr_open).
            ("server.max_connections", self.max_connections as u64, 0, 1 << 20),
            ("server.max_header_bytes", self.max_header_bytes as u64, 8192, 1 << 20),
            // A point of a series holds about half a KiB between its key, its frames
            // and its JSON: 65 536 points are some 32 MiB, the most one request should.
            ("server.max_series", self.max_series as u64, 1, 1 << 16),
            ("server.redis_timeout_ms", self.redis_timeout_ms, 0, MINUTE),
            ("server.redis_retry_ms", self.redis_retry_ms, 0, HOUR),
            // Ten years, within Redis's own limit on EX.
            ("server.redis_ttl_s", self.redis_ttl_s, 0, 10 * 365 * 86_400),
            ("server.ahead_threads", self.ahead_threads as u64, 0, 64),
            ("server.ahead_tiles", self.ahead_tiles as u64, 0, 1 << 20),
            ("server.warm_threads", self.warm_threads as u64, 0, 64),
            ("server.max_warm_tiles", self.max_warm_tiles as u64, 0, 1 << 20),
            // 0: a quarter of `cache_bytes` (checked below: else at least 1 MiB).
            ("server.compute_memory_bytes", self.compute_memory_bytes, 0, u64::MAX),
            ("server.reply_bytes", self.reply_bytes, 1 << 20, u64::MAX),
        ] {
            if !(least..=most).contains(&value) {
                return Err(invalid(key, &format!("must be within [{least}, {most}], got {value}")));
            }
        }
        if self.shutdown_grace_ms > self.shutdown_timeout_ms {
            return Err(invalid(
                "server.shutdown_grace_ms",
                "must be at most server.shutdown_timeout_ms",
            ));
        }
        for (key, v) in [
            ("server.cache_control", &self.cache_control),
            ("server.cache_control_other", &self.cache_control_other),
        ] {
            if !v.bytes().all(|b| (0x20..0x7f).contains(&b)) {
                return Err(invalid(key, "must be printable ASCII (it is an HTTP header value)"));
            }
        }
        if !self.redis_url.is_empty() && !REDIS_SCHEMES.iter().any(|s| self.redis_url.starts_with(s)) {
            return Err(invalid(
                "server.redis_url",
                "must start with redis://, rediss:// or redis+unix:// (or be empty for no Redis)",
            ));
        }
        if !self.redis_secret.is_empty() && self.redis_secret.len() < 16 {
            return Err(invalid(
                "server.redis_secret",
                "must be at least 16 bytes (or empty for a digest without a key)",
            ));
        }
        if !self.redis_ca_file.is_empty() && !self.redis_url.starts_with("rediss://") {
            return Err(invalid(
                "server.redis_ca_file",
                "is for a TLS Redis: server.redis_url must start with rediss://",
            ));
        }
        if !(1 << 10..=512 << 20).contains(&self.redis_max_value_bytes) {
            return Err(invalid(
                "server.redis_max_value_bytes",
                "must be within [1024, 536870912] (Redis refuses larger values)",
            ));
        }
        if !(0.0..=0.9).contains(&self.kept_share) {
            return Err(invalid("server.kept_share", "must be within [0, 0.9]"));
        }
        if self.compute_memory_bytes != 0 && self.compute_memory_bytes < 1 << 20 {
            return Err(invalid(
                "server.compute_memory_bytes",
                "must be at least 1 MiB (or 0 for a quarter of server.cache_bytes)",
            ));
        }
        for origin in &self.cors_origins {
            crate::cors::check_origin(origin).map_err(|e| invalid("server.cors_origins", &e))?;
        }
        if !self.public_url.is_empty() {
            let rest = self
                .public_url
                .strip_prefix("https://")
                .or_else(|| self.public_url.strip_prefix("http://"));
            let ok = rest.is_some_and(|r| {
                let r = r.trim_end_matches('/');
                !r.is_empty()
                    && r.bytes()
                        .all(|b| b.is_ascii_graphic() && !matches!(b, b'?' | b'#' | b'"'))
            });
            if !ok {
                return Err(invalid(
                    "server.public_url",
                    "must be http(s)://host[:port][/path] with no query (or empty for the request's Host)",
                ));
            }
        }
        if !self.redis_url.is_empty() && self.redis_timeout_ms == 0 {
            return Err(invalid("server.redis_timeout_ms", "must be positive"));
        }
        Ok(())
    }
}

#[derive(Deserialize)]
struct RawServerSection {
    #[serde(default)]
    server: ServerConfig,
}

impl ServerConfig {
    /// Parses and validates the `[server]` section of a configuration's TOML text;
    /// every other section is left to `Config::parse`.
    pub fn parse(text: &str) -> Result<ServerConfig, ConfigError> {
        let raw: RawServerSection = toml::from_str(text).map_err(|e| ConfigError::toml(text, &e))?;
        raw.server.validate()?;
        Ok(raw.server)
    }

    /// The `[server]` section of the embedded default configuration.
    pub fn embedded() -> ServerConfig {
        ServerConfig::parse(cloudscape_core::world::DEFAULT_CONFIG).expect("the embedded default config is valid")
    }
}
