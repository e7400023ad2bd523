//! The optional second-level cache that replicas share: Redis, configured by
//! `server.redis_url`.
//!
//! A product's bytes are a pure function of its [`CacheKey`] (which holds the
//! algorithm version and the world fingerprint), so any replica may use bytes that
//! another one computed, and the ETag, derived from the same key, is the same too.
//! The response cache looks here after an in-process miss and before computing, and
//! writes here after computing, in a task of its own so no response waits for it.
//!
//! Redis is an optimisation, never a dependency: every call has a deadline
//! (`redis_timeout_ms`, connecting included), and after a failure requests skip Redis
//! for `redis_retry_ms` while the connection manager reconnects in the background, so
//! a dead, slow or silent Redis costs at most one deadline per retry period; the
//! request computes instead.
//!
//! Redis is not trusted either. Whatever can write to it (a client of the same
//! instance, a bug, a restore of the wrong dump) must not make every replica, and
//! every CDN behind them, serve its bytes under our immutable ETags. So every value is
//! sealed ([`Seal`]): a BLAKE3 tag over the Redis key and the bytes, keyed by
//! `server.redis_secret` when one is set (a MAC: only replicas holding the secret can
//! write a value that passes), else by a fixed key (a digest: garbage, truncation and
//! a value under another key's name are caught, a forger is not). A value whose seal
//! does not hold is a miss, counted in `cloudscape_redis_rejected_total`, and the
//! request computes and writes the genuine bytes over it.
//!
//! Values are bounded both ways by `server.redis_max_value_bytes`: larger products are
//! not written (a 24 MB `billboards.json` costs Redis, the network and the deadline
//! more than computing it again), and a lookup reads at most that many bytes
//! (`GETRANGE`), so an oversized value planted in Redis is refused without being
//! held in memory. Writes go over a connection of their own, with a deadline that
//! grows with the bytes written, so a large write neither times out nor holds up the
//! lookups queued behind it on one connection.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::body::Bytes;
use redis::aio::{ConnectionManager, ConnectionManagerConfig};

use crate::config::ServerConfig;

use crate::key::CacheKey;
use crate::metrics::Metrics;

/// The rate a write's deadline assumes on top of `redis_timeout_ms`: 64 MB/s, well
/// under what loopback or a LAN carries, so only a Redis that has stalled misses it.
const WRITE_NANOS_PER_BYTE: u64 = 16;

/// Longest CA file `server.redis_ca_file` may name, bytes (a bundle of a few hundred
/// certificates).
const MAX_CA_FILE_BYTES: u64 = 4 << 20;

/// The seal of a value in Redis: `MAGIC`, a 32-byte BLAKE3 tag, then the bytes.
///
/// The tag is BLAKE3 in keyed mode over the Redis key's length (8 bytes, little
/// endian), the Redis key, and the bytes: the key's length first, so no split of
/// (key, bytes) into two other strings gives the same input. The 32-byte BLAKE3 key
/// is derived from `server.redis_secret` (`blake3::derive_key`, a KDF, so a short or
/// textual secret becomes a uniform key), or from the empty string when none is set.
pub struct Seal {
    key: [u8; 32],
}

impl Seal {
    /// Marks a sealed value (and its format: a new format gets a new magic, and old
    /// values are then misses).
    const MAGIC: &'static [u8; 4] = b"CSs1";
    const HEADER: usize = 4 + blake3::OUT_LEN;
    /// The context string of the key derivation: this application, this purpose.
    const CONTEXT: &'static str = "cloudscape 2026-12 shared-cache value seal v1";

    pub fn new(secret: &str) -> Seal {
        Seal {
            key: blake3::derive_key(Self::CONTEXT, secret.as_bytes()),
        }
    }

    fn tag(&self, redis_key: &str, bytes: &[u8]) -> blake3::Hash {
        let mut h = blake3::Hasher::new_keyed(&self.key);
        h.update(&(redis_key.len() as u64).to_le_bytes());
        h.update(redis_key.as_bytes());
        h.update(bytes);
        h.finalize()
    }

    /// The value to store under `redis_key` for `bytes`.
    pub fn seal(&self, redis_key: &str, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::with_capacity(Self::HEADER + bytes.len());
        out.extend_from_slice(Self::MAGIC);
        out.extend_from_slice(self.tag(redis_key, bytes).as_bytes());
        out.extend_from_slice(bytes);
        out
    }

    /// The bytes of a value read under `redis_key`, or `None` when its seal does not
    /// hold (no magic, truncated, another key's value, garbage, or sealed with
    /// another secret). The comparison takes constant time (`blake3::Hash`'s `eq`).
    pub fn open(&self, redis_key: &str, value: Bytes) -> Option<Bytes> {
        if value.len() < Self::HEADER || &value[..4] != Self::MAGIC {
            return None;
        }
        let tag = blake3::Hash::from_bytes(value[4..Self::HEADER].try_into().ok()?);
        let bytes = value.slice(Self::HEADER..);
        (self.tag(redis_key, &bytes) == tag).then_some(bytes)
    }
}

/// A Redis connection (made lazily, remade after failures) with the deadlines and the
/// back-off that keep it off the request path when it misbehaves.
pub struct SharedCache {
    /// Lookups and claims: small, and never queued behind a write.
    connection: ConnectionManager,
    /// Writes, whose values may be megabytes.
    writer: ConnectionManager,
    /// Prefix of every Redis key: keeps our entries apart from anything else in the
    /// database, and replicas whose frame grids differ apart from each other.
    namespace: String,
    /// Deadline of one lookup, claim or small write.
    timeout: Duration,
    /// How long to leave Redis alone after a failure.
    retry: Duration,
    /// Expiry of written entries, seconds (0: none).
    ttl_s: u64,
    /// Largest product written or read, bytes (`server.redis_max_value_bytes`).
    max_value: usize,
    /// What every value is sealed with.
    seal: Seal,
    /// Redis is skipped until this many milliseconds after `started`.
    skip_until_ms: AtomicU64,
    started: Instant,
    /// This process, as its claims name it (`pid@unix-ms` of its start): what a
    /// claim's holder is, for an operator reading Redis, and what
    /// [`SharedCache::release`] checks before it deletes a claim.
    replica: String,
}

/// What a lookup found.
pub enum Lookup {
    Hit(Bytes),
    Miss,
    /// Redis failed, timed out, or is being left alone after a failure.
    Unavailable,
}

/// `url` with the password of its user information replaced by `***`, for messages.
pub fn redacted(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else {
        return url.to_string();
    };
    let (authority, path) = match rest.split_once('/') {
        Some((authority, path)) => (authority, Some(path)),
        None => (rest, None),
    };
    let Some((userinfo, host)) = authority.rsplit_once('@') else {
        return url.to_string();
    };
    let user = userinfo.split(':').next().unwrap_or("");
    let path = path.map_or(String::new(), |p| format!("/{p}"));
    format!("{scheme}://{user}:***@{host}{path}")
}

impl SharedCache {
    /// The shared cache `settings` ask for, or `None` when `redis_url` is empty. Does not
    /// connect: the first lookup does, so a replica starts even while Redis is down.
    /// The URL may carry a user and password (`redis://user:secret@host:6379/0`, sent
    /// with `AUTH`), and `rediss://` connects over TLS, trusting the system's roots or
    /// the certificates of `server.redis_ca_file`.
    pub fn new(settings: &ServerConfig) -> Result<Option<SharedCache>, String> {
        if settings.redis_url.is_empty() {
            return Ok(None);
        }
        let shown = redacted(&settings.redis_url);
        let tls = settings.redis_url.starts_with("rediss://");
        if tls {
            // The one provider compiled in; a second install (another server in this
            // process) is refused harmlessly. Deprecated only for lacking post-quantum
            // key exchange, which a link to a cache holding public tiles can do without.
            #[allow(deprecated)]
            let _ = rustls::crypto::ring::default_provider().install_default();
        }
        let client = if tls && !settings.redis_ca_file.is_empty() {
            let pem = read_ca_file(&settings.redis_ca_file)?;
            let certificates = redis::TlsCertificates {
                client_tls: None,
                root_cert: Some(pem),
            };
            redis::Client::build_with_tls(settings.redis_url.as_str(), certificates)
        } else {
            redis::Client::open(settings.redis_url.as_str())
        }
        .map_err(|e| format!("invalid server.redis_url {shown}: {e}"))?;
        let timeout = Duration::from_millis(settings.redis_timeout_ms);
        let manager = |response: Duration| {
            let config = ConnectionManagerConfig::new()
                .set_connection_timeout(Some(timeout))
                .set_response_timeout(Some(response))
                .set_number_of_retries(2)
                .set_min_delay(Duration::from_millis(50))
                .set_max_delay(Duration::from_millis(settings.redis_retry_ms.max(50)));
            ConnectionManager::new_lazy_with_config(client.clone(), config)
                .map_err(|e| format!("cannot set up the Redis connection to {shown}: {e}"))
        };
        let max_value = usize::try_from(settings.redis_max_value_bytes).unwrap_or(usize::MAX);
        Ok(Some(SharedCache {
            connection: manager(timeout)?,
            writer: manager(write_deadline(timeout, max_value))?,
            namespace: format!("cloudscape:fps{}:", settings.frames_per_step),
            timeout,
            retry: Duration::from_millis(settings.redis_retry_ms),
            ttl_s: settings.redis_ttl_s,
            max_value,
            seal: Seal::new(&settings.redis_secret),
            skip_until_ms: AtomicU64::new(0),
            started: Instant::now(),
            replica: format!(
                "{}@{}",
                std::process::id(),
                std::time::SystemTime::now()
                    .duration_since(std::time::UNIX_EPOCH)
                    .map_or(0, |d| d.as_millis())
            ),
        }))
    }

    fn redis_key(&self, key: &CacheKey) -> String {
        format!("{}{}", self.namespace, key.0)
    }

    fn now_ms(&self) -> u64 {
        self.started.elapsed().as_millis() as u64
    }

    /// True while Redis is being left alone after a failure.
    fn skipping(&self) -> bool {
        self.now_ms() < self.skip_until_ms.load(Ordering::Relaxed)
    }

    fn failed(&self, metrics: &Metrics, op: &str, error: &str) {
        metrics.redis_errors.with_label_values(&[op]).inc();
        let until = self.now_ms() + self.retry.as_millis() as u64;
        let before = self.skip_until_ms.swap(until, Ordering::Relaxed);
        if before <= self.now_ms() {
            tracing::warn!(
                op,
                error,
                retry_ms = self.retry.as_millis() as u64,
                "redis unavailable: computing instead"
            );
        }
    }

    /// The bytes of `key` if another replica (or this one) stored them and their seal
    /// holds. A value that fails the check (or is longer than any value written) is a
    /// miss, counted in `cloudscape_redis_rejected_total`; at most
    /// `redis_max_value_bytes` of it are read.
    pub async fn get(&self, metrics: &Metrics, kind: &str, key: &CacheKey) -> Lookup {
        if self.skipping() {
            metrics.redis_skipped.inc();
            return Lookup::Unavailable;
        }
        let redis_key = self.redis_key(key);
        let mut connection = self.connection.clone();
        // One byte past the largest sealed value written: a longer value is refused
        // without reading the rest.
        let last = Seal::HEADER.saturating_add(self.max_value);
        let cmd = redis::cmd("GETRANGE").arg(&redis_key).arg(0).arg(last).clone();
        let reply = tokio::time::timeout(self.timeout, cmd.query_async::<Vec<u8>>(&mut connection)).await;
        match reply {
            // GETRANGE answers "" for a missing key; a sealed value is never empty.
            Ok(Ok(value)) if value.is_empty() => {
                metrics.redis_misses.with_label_values(&[kind]).inc();
                Lookup::Miss
            }
            Ok(Ok(value)) => {
                let opened = (value.len() <= last)
                    .then(|| self.seal.open(&redis_key, Bytes::from(value)))
                    .flatten();
                match opened {
                    Some(bytes) => {
                        metrics.redis_hits.with_label_values(&[kind]).inc();
                        Lookup::Hit(bytes)
                    }
                    None => {
                        metrics.redis_rejected.with_label_values(&[kind]).inc();
                        metrics.redis_misses.with_label_values(&[kind]).inc();
                        tracing::warn!(key = %redis_key, "redis: a value failed its seal check; computing instead");
                        Lookup::Miss
                    }
                }
            }
            Ok(Err(e)) => {
                self.failed(metrics, "get", &e.to_string());
                Lookup::Unavailable
            }
            Err(_) => {
                self.failed(metrics, "get", "timed out");
                Lookup::Unavailable
            }
        }
    }

    /// Claims `key` for this replica's background computation for `ttl`: true when no
    /// other replica holds a claim on it (a `SET NX PX` of `claim:` and the key), or
    /// when Redis cannot say (then computing twice is the safe side). Replicas keeping
    /// the same play areas warm, or computing the same keyframes ahead, compute each
    /// once: the one that lost takes the bytes from Redis when they are there, and a
    /// claim whose replica died lapses after `ttl`.
    pub async fn claim(&self, metrics: &Metrics, key: &CacheKey, ttl: Duration) -> bool {
        if self.skipping() {
            return true;
        }
        let mut connection = self.connection.clone();
        let cmd = redis::cmd("SET")
            .arg(format!("{}claim:{}", self.namespace, key.0))
            .arg(self.replica.as_str())
            .arg("NX")
            .arg("PX")
            .arg(ttl.as_millis() as u64)
            .clone();
        let won = match tokio::time::timeout(self.timeout, cmd.query_async::<Option<String>>(&mut connection)).await {
            Ok(Ok(reply)) => reply.is_some(),
            Ok(Err(e)) => {
                self.failed(metrics, "claim", &e.to_string());
                true
            }
            Err(_) => {
                self.failed(metrics, "claim", "timed out");
                true
            }
        };
        metrics
            .redis_claims
            .with_label_values(&[if won { "won" } else { "lost" }])
            .inc();
        won
    }

    /// Gives back this replica's claim on `key` (from [`SharedCache::claim`]) when its
    /// computation did not finish (shed, failed), so that the next try, here or on
    /// another replica, does not wait for the claim to lapse. A claim another replica
    /// holds by then is left alone (compare and delete in one script).
    pub async fn release(&self, metrics: &Metrics, key: &CacheKey) {
        if self.skipping() {
            return;
        }
        let mut connection = self.connection.clone();
        let cmd = redis::cmd("EVAL")
            .arg("if redis.call('GET', KEYS[1]) == ARGV[1] then return redis.call('DEL', KEYS[1]) else return 0 end")
            .arg(1)
            .arg(format!("{}claim:{}", self.namespace, key.0))
            .arg(self.replica.as_str())
            .clone();
        match tokio::time::timeout(self.timeout, cmd.query_async::<i64>(&mut connection)).await {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => self.failed(metrics, "release", &e.to_string()),
            Err(_) => self.failed(metrics, "release", "timed out"),
        }
    }

    /// Stores `entries`, sealed, in a task of its own; the caller does not wait.
    /// Entries over `redis_max_value_bytes` are left out (counted in
    /// `cloudscape_redis_oversize_total`).
    pub fn put(self: &Arc<Self>, metrics: &Arc<Metrics>, entries: Vec<(CacheKey, Bytes)>) {
        if entries.is_empty() || self.skipping() {
            return;
        }
        let (entries, oversize): (Vec<_>, Vec<_>) = entries.into_iter().partition(|(_, b)| b.len() <= self.max_value);
        metrics.redis_oversize.inc_by(oversize.len() as u64);
        if entries.is_empty() {
            return;
        }
        let this = Arc::clone(self);
        let metrics = Arc::clone(metrics);
        tokio::spawn(async move {
            let mut pipe = redis::pipe();
            let mut bytes = 0;
            for (key, value) in &entries {
                let redis_key = this.redis_key(key);
                let sealed = this.seal.seal(&redis_key, value);
                bytes += sealed.len();
                let set = pipe.cmd("SET").arg(redis_key).arg(sealed);
                if this.ttl_s > 0 {
                    set.arg("EX").arg(this.ttl_s);
                }
                set.ignore();
            }
            let mut connection = this.writer.clone();
            let deadline = write_deadline(this.timeout, bytes);
            match tokio::time::timeout(deadline, pipe.query_async::<()>(&mut connection)).await {
                Ok(Ok(())) => metrics.redis_writes.inc_by(entries.len() as u64),
                Ok(Err(e)) => this.failed(&metrics, "set", &e.to_string()),
                Err(_) => this.failed(&metrics, "set", "timed out"),
            }
        });
    }
}

/// The deadline of a write of `bytes`: the configured one plus the time the bytes take
/// at a rate any working Redis beats ([`WRITE_NANOS_PER_BYTE`]).
fn write_deadline(timeout: Duration, bytes: usize) -> Duration {
    timeout + Duration::from_nanos((bytes as u64).saturating_mul(WRITE_NANOS_PER_BYTE))
}

/// The PEM certificates of `path` (`server.redis_ca_file`), read with a size limit.
fn read_ca_file(path: &str) -> Result<Vec<u8>, String> {
    use std::io::Read;
    let file = std::fs::File::open(path).map_err(|e| format!("cannot read server.redis_ca_file {path:?}: {e}"))?;
    let mut pem = Vec::new();
    file.take(MAX_CA_FILE_BYTES + 1)
        .read_to_end(&mut pem)
        .map_err(|e| format!("cannot read server.redis_ca_file {path:?}: {e}"))?;
    if pem.len() as u64 > MAX_CA_FILE_BYTES {
        return Err(format!(
            "server.redis_ca_file {path:?} is over {} MiB: it should hold a few PEM certificates",
            MAX_CA_FILE_BYTES >> 20
        ));
    }
    Ok(pem)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::process::{Command, Stdio};

    /// A real `redis-server` on a free port, stopped when dropped.
    struct Redis(std::process::Child, u16);

    impl Redis {
        fn start() -> Redis {
            Redis::start_with(&[])
        }

        /// With more arguments (`--requirepass`, TLS); `--port` is the TLS port when
        /// `args` has `--tls-port PORT` (then the plain port is 0 and this waits for
        /// the TLS port).
        fn start_with(args: &[&str]) -> Redis {
            let port = std::net::TcpListener::bind("127.0.0.1:0")
                .and_then(|l| l.local_addr())
                .map(|a| a.port())
                .unwrap();
            let tls = args.contains(&"--tls-port");
            let port_args: Vec<String> = if tls {
                vec!["--port".into(), "0".into(), "--tls-port".into(), port.to_string()]
            } else {
                vec!["--port".into(), port.to_string()]
            };
            let args: Vec<&str> = args.iter().copied().filter(|a| *a != "--tls-port").collect();
            let child = Command::new("redis-server")
                .args(&port_args)
                .args(["--bind", "127.0.0.1", "--save", ""])
                .args(["--appendonly", "no", "--loglevel", "warning"])
                .args(&args)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("these tests need redis-server (Debian: apt-get install redis-server)");
            let start = Instant::now();
            while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
                assert!(start.elapsed() < Duration::from_secs(10), "redis-server did not start");
                std::thread::sleep(Duration::from_millis(20));
            }
            Redis(child, port)
        }
    }

    impl Drop for Redis {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }

    fn replica(port: u16, name: &str) -> SharedCache {
        let settings = ServerConfig {
            redis_url: format!("redis://127.0.0.1:{port}/0"),
            ..ServerConfig::default()
        };
        let mut cache = SharedCache::new(&settings).unwrap().unwrap();
        cache.replica = name.into();
        cache
    }

    /// A replica of `settings` whose writes have landed: `put`, then wait for the key.
    async fn put_and_wait(cache: &Arc<SharedCache>, m: &Arc<Metrics>, key: &CacheKey, bytes: &[u8]) {
        let before = m.redis_writes.get();
        cache.put(m, vec![(key.clone(), Bytes::copy_from_slice(bytes))]);
        let start = Instant::now();
        while m.redis_writes.get() == before {
            assert!(start.elapsed() < Duration::from_secs(10), "the write never landed");
            assert_eq!(m.redis_errors.with_label_values(&["set"]).get(), 0, "the write failed");
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    /// Writes `value` under the Redis key of `key`, as anything with access to Redis could.
    async fn plant(cache: &SharedCache, key: &CacheKey, value: &[u8]) {
        let mut c = cache.connection.clone();
        let () = redis::cmd("SET")
            .arg(cache.redis_key(key))
            .arg(value)
            .query_async(&mut c)
            .await
            .unwrap();
    }

    fn hit(lookup: Lookup) -> Option<Bytes> {
        match lookup {
            Lookup::Hit(b) => Some(b),
            Lookup::Miss => None,
            Lookup::Unavailable => panic!("redis unavailable"),
        }
    }

    #[test]
    fn a_seal_binds_the_bytes_to_their_key_and_secret() {
        let (plain, keyed) = (Seal::new(""), Seal::new("0123456789abcdef"));
        let bytes = b"\x89PNG a tile".to_vec();
        let sealed = keyed.seal("k1", &bytes);
        assert_eq!(
            keyed.open("k1", Bytes::from(sealed.clone())).as_deref(),
            Some(&bytes[..])
        );
        // Another key's value, another secret, a flipped bit, a truncation, garbage.
        assert!(keyed.open("k2", Bytes::from(sealed.clone())).is_none());
        assert!(plain.open("k1", Bytes::from(sealed.clone())).is_none());
        assert!(
            Seal::new("0123456789abcdeF")
                .open("k1", Bytes::from(sealed.clone()))
                .is_none()
        );
        for i in [0, 5, sealed.len() - 1] {
            let mut flipped = sealed.clone();
            flipped[i] ^= 1;
            assert!(keyed.open("k1", Bytes::from(flipped)).is_none(), "bit flipped at {i}");
        }
        assert!(
            keyed
                .open("k1", Bytes::from(sealed[..sealed.len() - 1].to_vec()))
                .is_none()
        );
        assert!(keyed.open("k1", Bytes::from_static(b"garbage")).is_none());
        // The key's length is part of the input: moving bytes between key and value
        // does not give the same tag.
        let moved = plain.seal("k1x", b"yz");
        assert!(plain.open("k1", Bytes::from(moved)).is_none());
        // Without a secret the seal is still a digest of key and bytes.
        let digest = plain.seal("k1", &bytes);
        assert_eq!(plain.open("k1", Bytes::from(digest)).as_deref(), Some(&bytes[..]));
        assert_eq!(
            redacted("redis://cache:s3cret@host:6379/0"),
            "redis://cache:***@host:6379/0"
        );
        assert_eq!(redacted("rediss://:s3cret@host/0"), "rediss://:***@host/0");
        assert_eq!(redacted("redis://host:6379/0"), "redis://host:6379/0");
    }

    #[tokio::test]
    async fn values_that_fail_their_seal_are_misses_and_are_counted() {
        let redis = Redis::start();
        let settings = |secret: &str| ServerConfig {
            redis_url: format!("redis://127.0.0.1:{}/0", redis.1),
            redis_secret: secret.into(),
            redis_max_value_bytes: 1 << 20,
            ..ServerConfig::default()
        };
        let a = Arc::new(SharedCache::new(&settings("secret of the fleet")).unwrap().unwrap());
        let m = Arc::new(Metrics::new());
        let key = CacheKey("tile|z=0|p=shadow.png".into());
        // Garbage planted under a tile's key: a miss, never the garbage.
        plant(&a, &key, b"17 bytes of junk!").await;
        assert!(hit(a.get(&m, "tile_shaded", &key).await).is_none());
        assert_eq!(m.redis_rejected.with_label_values(&["tile_shaded"]).get(), 1);
        // The genuine bytes, written over it, are served.
        put_and_wait(&a, &m, &key, b"the genuine tile").await;
        assert_eq!(
            hit(a.get(&m, "tile_shaded", &key).await).as_deref(),
            Some(&b"the genuine tile"[..])
        );
        // Another key's genuine value, copied under this key, is refused.
        let other = CacheKey("tile|z=1|p=shadow.png".into());
        put_and_wait(&a, &m, &other, b"another tile").await;
        let mut c = a.connection.clone();
        let copied: Vec<u8> = redis::cmd("GET")
            .arg(a.redis_key(&other))
            .query_async(&mut c)
            .await
            .unwrap();
        plant(&a, &key, &copied).await;
        assert!(hit(a.get(&m, "tile_shaded", &key).await).is_none());
        // A value sealed without the secret (a digest anyone can compute) is refused by
        // a replica that has one, and one sealed with it by a replica that has none.
        plant(&a, &key, &Seal::new("").seal(&a.redis_key(&key), b"forged")).await;
        assert!(hit(a.get(&m, "tile_shaded", &key).await).is_none());
        let b = SharedCache::new(&settings("")).unwrap().unwrap();
        put_and_wait(&a, &m, &key, b"the genuine tile").await;
        assert!(hit(b.get(&m, "tile_shaded", &key).await).is_none());
        assert_eq!(m.redis_rejected.with_label_values(&["tile_shaded"]).get(), 4);
        // A value longer than any written is refused without reading it whole.
        plant(&a, &key, &vec![b'x'; 3 << 20]).await;
        assert!(hit(a.get(&m, "tile_shaded", &key).await).is_none());
        assert_eq!(m.redis_rejected.with_label_values(&["tile_shaded"]).get(), 5);
        // Products over the cap are not written.
        let before = m.redis_writes.get();
        a.put(&m, vec![(CacheKey("big".into()), Bytes::from(vec![0u8; 2 << 20]))]);
        assert_eq!(m.redis_oversize.get(), 1);
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert_eq!(m.redis_writes.get(), before);
        assert_eq!(m.redis_errors.with_label_values(&["get"]).get(), 0);
    }

    #[tokio::test]
    async fn a_large_value_is_written_within_its_deadline_and_lookups_go_on() {
        let redis = Redis::start();
        // The default 100 ms deadline and an 8 MiB product (the cap): the write's
        // deadline grows with its size, and it runs on a connection of its own.
        let settings = ServerConfig {
            redis_url: format!("redis://127.0.0.1:{}/0", redis.1),
            ..ServerConfig::default()
        };
        let a = Arc::new(SharedCache::new(&settings).unwrap().unwrap());
        let m = Arc::new(Metrics::new());
        let big: Vec<u8> = (0..settings.redis_max_value_bytes)
            .map(|i| (i * 7 % 251) as u8)
            .collect();
        let key = CacheKey("tile|p=billboards.json".into());
        put_and_wait(&a, &m, &key, &big).await;
        assert!(!a.skipping(), "a large write made the replica skip Redis");
        assert_eq!(hit(a.get(&m, "tile_shaded", &key).await).as_deref(), Some(&big[..]));
        assert_eq!(m.redis_errors.with_label_values(&["set"]).get(), 0);
    }

    #[tokio::test]
    async fn auth_with_a_password_in_the_url() {
        let redis = Redis::start_with(&["--requirepass", "fleet-password"]);
        let m = Arc::new(Metrics::new());
        let key = CacheKey("tile:auth".into());
        let with = |url: String| {
            Arc::new(
                SharedCache::new(&ServerConfig {
                    redis_url: url,
                    redis_timeout_ms: 1000,
                    ..ServerConfig::default()
                })
                .unwrap()
                .unwrap(),
            )
        };
        let good = with(format!("redis://:fleet-password@127.0.0.1:{}/0", redis.1));
        put_and_wait(&good, &m, &key, b"authenticated").await;
        assert_eq!(
            hit(good.get(&m, "tile_shaded", &key).await).as_deref(),
            Some(&b"authenticated"[..])
        );
        // Without the password (or with a wrong one) Redis is unavailable, not a hit.
        let m2 = Metrics::new();
        for url in [
            format!("redis://127.0.0.1:{}/0", redis.1),
            format!("redis://:wrong@127.0.0.1:{}/0", redis.1),
        ] {
            let bad = with(url);
            assert!(matches!(bad.get(&m2, "tile_shaded", &key).await, Lookup::Unavailable));
        }
        assert!(m2.redis_errors.with_label_values(&["get"]).get() >= 2);
    }

    #[tokio::test]
    async fn tls_with_a_private_ca() {
        // tests/data/tls: a test CA and a certificate for localhost and 127.0.0.1 it
        // signed (P-256, valid until 2126; `openssl req -x509`, then `openssl x509 -req`).
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/data/tls");
        let (cert, key, ca) = (
            format!("{dir}/redis.pem"),
            format!("{dir}/redis.key"),
            format!("{dir}/ca.pem"),
        );
        let redis = Redis::start_with(&[
            "--tls-port",
            "--tls-cert-file",
            &cert,
            "--tls-key-file",
            &key,
            "--tls-ca-cert-file",
            &ca,
            "--tls-auth-clients",
            "no",
        ]);
        let settings = ServerConfig {
            redis_url: format!("rediss://127.0.0.1:{}/0", redis.1),
            redis_ca_file: ca.clone(),
            redis_timeout_ms: 2000,
            ..ServerConfig::default()
        };
        settings.validate().unwrap();
        let tls = Arc::new(SharedCache::new(&settings).unwrap().unwrap());
        let m = Arc::new(Metrics::new());
        let key = CacheKey("tile:tls".into());
        put_and_wait(&tls, &m, &key, b"over tls").await;
        assert_eq!(
            hit(tls.get(&m, "tile_shaded", &key).await).as_deref(),
            Some(&b"over tls"[..])
        );
        // The system's roots do not know the test CA: the handshake fails, Redis is
        // unavailable, the request would compute.
        let untrusted = SharedCache::new(&ServerConfig {
            redis_ca_file: String::new(),
            ..settings
        })
        .unwrap()
        .unwrap();
        assert!(matches!(
            untrusted.get(&m, "tile_shaded", &key).await,
            Lookup::Unavailable
        ));
    }

    #[tokio::test]
    async fn a_claim_is_released_only_by_its_holder() {
        let redis = Redis::start();
        let (a, b) = (replica(redis.1, "a"), replica(redis.1, "b"));
        let m = Metrics::new();
        let key = CacheKey("tile:1".into());
        let ttl = Duration::from_secs(60);
        assert!(a.claim(&m, &key, ttl).await, "the first claim wins");
        assert!(!b.claim(&m, &key, ttl).await, "a held claim is lost");
        // b does not hold it: its release leaves a's claim in place.
        b.release(&m, &key).await;
        assert!(!b.claim(&m, &key, ttl).await, "a's claim survived b's release");
        // a gives it back (its computation was shed): the next try wins at once, not
        // after the claim lapses.
        a.release(&m, &key).await;
        assert!(b.claim(&m, &key, ttl).await, "released, the key is free");
        assert_eq!(m.redis_claims.with_label_values(&["won"]).get(), 2);
        assert_eq!(m.redis_claims.with_label_values(&["lost"]).get(), 2);
        assert_eq!(m.redis_errors.with_label_values(&["release"]).get(), 0);
    }
}
