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

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::body::Bytes;
use redis::aio::{ConnectionManager, ConnectionManagerConfig};

use crate::config::ServerConfig;

use crate::key::CacheKey;
use crate::metrics::Metrics;

/// A Redis connection (made lazily, remade after failures) with the deadlines and the
/// back-off that keep it off the request path when it misbehaves.
pub struct SharedCache {
    connection: ConnectionManager,
    /// Prefix of every Redis key: keeps our entries apart from anything else in the
    /// database, and replicas whose frame grids differ apart from each other.
    namespace: String,
    /// Deadline of one lookup or write.
    timeout: Duration,
    /// How long to leave Redis alone after a failure.
    retry: Duration,
    /// Expiry of written entries, seconds (0: none).
    ttl_s: u64,
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

impl SharedCache {
    /// The shared cache `settings` ask for, or `None` when `redis_url` is empty. Does not
    /// connect: the first lookup does, so a replica starts even while Redis is down.
    pub fn new(settings: &ServerConfig) -> Result<Option<SharedCache>, String> {
        if settings.redis_url.is_empty() {
            return Ok(None);
        }
        let client = redis::Client::open(settings.redis_url.as_str())
            .map_err(|e| format!("invalid server.redis_url {:?}: {e}", settings.redis_url))?;
        let timeout = Duration::from_millis(settings.redis_timeout_ms);
        let config = ConnectionManagerConfig::new()
            .set_connection_timeout(Some(timeout))
            .set_response_timeout(Some(timeout))
            .set_number_of_retries(2)
            .set_min_delay(Duration::from_millis(50))
            .set_max_delay(Duration::from_millis(settings.redis_retry_ms.max(50)));
        let connection = ConnectionManager::new_lazy_with_config(client, config)
            .map_err(|e| format!("cannot set up the Redis connection to {}: {e}", settings.redis_url))?;
        Ok(Some(SharedCache {
            connection,
            namespace: format!("cloudscape:fps{}:", settings.frames_per_step),
            timeout,
            retry: Duration::from_millis(settings.redis_retry_ms),
            ttl_s: settings.redis_ttl_s,
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

    /// The bytes of `key` if another replica (or this one) stored them.
    pub async fn get(&self, metrics: &Metrics, kind: &str, key: &CacheKey) -> Lookup {
        if self.skipping() {
            metrics.redis_skipped.inc();
            return Lookup::Unavailable;
        }
        let mut connection = self.connection.clone();
        let cmd = redis::cmd("GET").arg(self.redis_key(key)).clone();
        let reply = tokio::time::timeout(self.timeout, cmd.query_async::<Option<Vec<u8>>>(&mut connection)).await;
        match reply {
            Ok(Ok(Some(bytes))) => {
                metrics.redis_hits.with_label_values(&[kind]).inc();
                Lookup::Hit(Bytes::from(bytes))
            }
            Ok(Ok(None)) => {
                metrics.redis_misses.with_label_values(&[kind]).inc();
                Lookup::Miss
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

    /// Stores `entries` in a task of its own; the caller does not wait.
    pub fn put(self: &Arc<Self>, metrics: &Arc<Metrics>, entries: Vec<(CacheKey, Bytes)>) {
        if entries.is_empty() || self.skipping() {
            return;
        }
        let this = Arc::clone(self);
        let metrics = Arc::clone(metrics);
        tokio::spawn(async move {
            let mut pipe = redis::pipe();
            for (key, bytes) in &entries {
                let set = pipe.cmd("SET").arg(this.redis_key(key)).arg(bytes.as_ref());
                if this.ttl_s > 0 {
                    set.arg("EX").arg(this.ttl_s);
                }
                set.ignore();
            }
            let mut connection = this.connection.clone();
            match tokio::time::timeout(this.timeout, pipe.query_async::<()>(&mut connection)).await {
                Ok(Ok(())) => metrics.redis_writes.inc_by(entries.len() as u64),
                Ok(Err(e)) => this.failed(&metrics, "set", &e.to_string()),
                Err(_) => this.failed(&metrics, "set", "timed out"),
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::process::{Command, Stdio};

    /// A real `redis-server` on a free port, stopped when dropped.
    struct Redis(std::process::Child, u16);

    impl Redis {
        fn start() -> Redis {
            let port = std::net::TcpListener::bind("127.0.0.1:0")
                .and_then(|l| l.local_addr())
                .map(|a| a.port())
                .unwrap();
            let child = Command::new("redis-server")
                .args(["--port", &port.to_string(), "--bind", "127.0.0.1", "--save", ""])
                .args(["--appendonly", "no", "--loglevel", "warning"])
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
