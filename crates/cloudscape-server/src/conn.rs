//! The connection layer: accepts sockets and serves HTTP/1.1 on each one with the
//! limits an open port needs (issue 25), which `axum::serve` has no knobs for.
//!
//! - **Header-read timeout** and a **bounded header buffer**: hyper's own
//!   `header_read_timeout` (it runs from the moment hyper waits for a request head
//!   until the head is complete, so it also bounds slowloris) and `max_buf_size`
//!   (a head larger than the buffer gets `431` and the connection closes).
//! - **Idle timeout**: a connection with no request being handled, nothing waiting to
//!   be written and no byte in either direction for `idle_timeout` is closed. (hyper's
//!   header timer also runs while a kept-alive connection waits for its next request,
//!   so such a connection is closed after the shorter of the two.)
//! - **Write timeout**: a connection whose socket accepted no byte for
//!   `write_timeout` while a write waited (a client that does not read) is closed,
//!   and the response it held is freed.
//! - **Connection cap**: a semaphore over accepted sockets. Past the cap a socket gets
//!   a canned `503` with `Retry-After` and is closed; nothing waits.
//! - **Accept errors** (EMFILE, ENFILE, ENOBUFS…): back off 10 ms doubling to 1 s,
//!   log at most once per interval, keep accepting once descriptors free up.
//! - **Refusals of the HTTP layer**: hyper answers a request it cannot parse itself
//!   (400 for a malformed request line or header, 414 for a target over 65 534
//!   bytes, 431 for a head over the buffer), with no body and no hook to give it
//!   one. The socket wrapper recognises such an answer (exactly a bodiless 400, 414
//!   or 431 head, written while no handler runs) and sends the JSON error of
//!   [`ApiError`] in its place; then, closing, it reads what the client still sends
//!   (at most 64 KiB for at most a second), so that the answer is not destroyed by
//!   the reset a close with unread bytes causes.
//! - **Shutdown**: every connection gets hyper's `graceful_shutdown` (idle ones close
//!   at once); after `shutdown_grace` the ones not running a handler are closed
//!   (slowloris, slow readers); handlers still running get up to `shutdown_timeout`.
//!
//! Each connection is one task that owns the hyper connection and a watchdog that
//! reads the connection's [`Activity`], which the socket wrapper [`Watched`] and the
//! service wrapper update.

use std::future::Future;
use std::io;
use std::pin::{Pin, pin};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::task::{Context, Poll, ready};
use std::time::{Duration, Instant};

use axum::Router;
use hyper::server::conn::http1;
use hyper::service::Service;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Semaphore, watch};

use crate::config::ServerConfig;
use crate::error::ApiError;
use crate::metrics::{CloseReason, Metrics};

/// The connection limits, resolved from `[server]` and the process's file limit.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConnLimits {
    /// Longest time from waiting for a request head to having all of it.
    pub header_read_timeout: Duration,
    /// Longest a kept-alive connection may sit without a request or a byte moving.
    pub idle_timeout: Duration,
    /// Longest a write may wait without the client taking a byte.
    pub write_timeout: Duration,
    /// Connections served at once; the next ones get a 503 and are closed.
    pub max_connections: usize,
    /// hyper's read buffer: the largest request head (start line and headers).
    pub max_header_bytes: usize,
    /// After shutdown begins, how long connections not running a handler may stay.
    pub shutdown_grace: Duration,
    /// After shutdown begins, how long a running handler may take to finish.
    pub shutdown_timeout: Duration,
}

/// Sockets that may be held at once just to answer "503, over the connection cap".
const REFUSALS: usize = 16;

/// hyper's smallest read buffer (`max_buf_size` panics below it).
pub const MIN_HEADER_BYTES: usize = 8192;

impl ConnLimits {
    pub fn new(s: &ServerConfig) -> ConnLimits {
        let max_connections = match s.max_connections {
            0 => auto_max_connections(open_file_limit()),
            n => n as usize,
        };
        ConnLimits {
            header_read_timeout: Duration::from_millis(s.header_read_timeout_ms),
            idle_timeout: Duration::from_millis(s.idle_timeout_ms),
            write_timeout: Duration::from_millis(s.write_timeout_ms),
            max_connections,
            max_header_bytes: (s.max_header_bytes as usize).max(MIN_HEADER_BYTES),
            shutdown_grace: Duration::from_millis(s.shutdown_grace_ms),
            shutdown_timeout: Duration::from_millis(s.shutdown_timeout_ms),
        }
    }

    /// How often a connection's watchdog looks at it: a quarter of the shortest
    /// timeout that applies (the shutdown grace only once shutdown began), so a
    /// timeout is acted on within 25 % of its length, and at least once a second.
    fn tick(&self, shutting_down: bool) -> Duration {
        let shortest = match shutting_down {
            false => self.idle_timeout.min(self.write_timeout),
            true => self.idle_timeout.min(self.write_timeout).min(self.shutdown_grace),
        };
        shortest
            .div_f64(4.0)
            .clamp(Duration::from_millis(20), Duration::from_secs(1))
    }
}

/// The connection cap when `max_connections = 0`: what the soft file limit leaves
/// after a reserve for everything else (listener, Redis, logs, config, the
/// [`REFUSALS`] sockets), at most 4096. Without a known limit, 1024.
fn auto_max_connections(nofile: Option<u64>) -> usize {
    const MOST: usize = 4096;
    match nofile {
        None => 1024,
        Some(n) => {
            let n = n.min(1 << 20) as usize;
            let reserve = REFUSALS + 8 + n / 8;
            n.saturating_sub(reserve).clamp(1, MOST)
        }
    }
}

/// The soft `RLIMIT_NOFILE`, if the platform says.
fn open_file_limit() -> Option<u64> {
    #[cfg(unix)]
    {
        let mut limit = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: getrlimit writes one rlimit struct, which `limit` is.
        let ok = unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) } == 0;
        // `rlim_t` is u64 here but i64 on FreeBSD and u32 on 32-bit Android.
        #[allow(clippy::unnecessary_cast)]
        let soft = limit.rlim_cur as u64;
        (ok && limit.rlim_cur != libc::RLIM_INFINITY).then_some(soft)
    }
    #[cfg(not(unix))]
    None
}

/// What one connection is doing, as its watchdog needs to know. Times are
/// milliseconds since the connection was accepted, plus one (0 means "never").
struct Activity {
    accepted: Instant,
    /// Last byte read or written, or last handler finished.
    last_io: AtomicU64,
    /// Since when a write has been waiting for the client to take bytes (0: none waits).
    write_blocked: AtomicU64,
    /// Handlers (service futures) running for this connection.
    handlers: AtomicUsize,
    /// When the last handler finished.
    handler_done: AtomicU64,
}

impl Activity {
    fn new() -> Activity {
        Activity {
            accepted: Instant::now(),
            last_io: AtomicU64::new(1),
            write_blocked: AtomicU64::new(0),
            handlers: AtomicUsize::new(0),
            handler_done: AtomicU64::new(1),
        }
    }

    fn now(&self) -> u64 {
        self.accepted.elapsed().as_millis() as u64 + 1
    }

    fn moved(&self) {
        self.last_io.store(self.now(), Ordering::Relaxed);
    }

    fn wrote(&self) {
        self.moved();
        self.write_blocked.store(0, Ordering::Relaxed);
    }

    fn write_waits(&self) {
        let now = self.now();
        let _ = self
            .write_blocked
            .compare_exchange(0, now, Ordering::Relaxed, Ordering::Relaxed);
    }

    /// Why the watchdog closes the connection now, if it does. `shutdown` is how long
    /// ago shutdown began.
    fn verdict(&self, limits: &ConnLimits, shutdown: Option<Duration>) -> Option<CloseReason> {
        let now = self.now();
        let ago = |t: u64| Duration::from_millis(now.saturating_sub(t));
        let blocked = self.write_blocked.load(Ordering::Relaxed);
        if blocked != 0 && ago(blocked) >= limits.write_timeout {
            return Some(CloseReason::WriteTimeout);
        }
        let handlers = self.handlers.load(Ordering::Relaxed);
        if handlers == 0 && blocked == 0 && ago(self.last_io.load(Ordering::Relaxed)) >= limits.idle_timeout {
            return Some(CloseReason::IdleTimeout);
        }
        let since = shutdown?;
        let handler_quiet = handlers == 0 && ago(self.handler_done.load(Ordering::Relaxed)) >= limits.shutdown_grace;
        (since >= limits.shutdown_timeout || (since >= limits.shutdown_grace && handler_quiet))
            .then_some(CloseReason::Shutdown)
    }
}

/// Counts a handler as running until dropped (also when its request is abandoned).
struct Handling(Arc<Activity>);

impl Handling {
    fn enter(a: &Arc<Activity>) -> Handling {
        a.handlers.fetch_add(1, Ordering::Relaxed);
        Handling(Arc::clone(a))
    }
}

impl Drop for Handling {
    fn drop(&mut self) {
        let now = self.0.now();
        self.0.handler_done.store(now, Ordering::Relaxed);
        self.0.last_io.store(now, Ordering::Relaxed);
        self.0.handlers.fetch_sub(1, Ordering::Relaxed);
    }
}

/// A socket that records in [`Activity`] when bytes move and when a write waits, and
/// that answers hyper's own refusals with the JSON error (see the module notes).
struct Watched {
    stream: TcpStream,
    activity: Arc<Activity>,
    /// The largest request head, for the message of a 431.
    max_header_bytes: usize,
    /// The JSON answer sent in place of a refusal of hyper's, and how much of it is
    /// written.
    answer: Option<(Vec<u8>, usize)>,
    /// Once a refusal is answered and the write side shut: until when closing reads
    /// what the client still sends.
    linger: Option<(Pin<Box<tokio::time::Sleep>>, usize)>,
}

/// What closing after a refusal reads at most before the socket is dropped.
const LINGER_BYTES: usize = 64 << 10;
const LINGER: Duration = Duration::from_secs(1);

impl Watched {
    fn new(stream: TcpStream, activity: Arc<Activity>, max_header_bytes: usize) -> Watched {
        Watched {
            stream,
            activity,
            max_header_bytes,
            answer: None,
            linger: None,
        }
    }

    fn note_write(activity: &Activity, r: &Poll<io::Result<usize>>) {
        match r {
            Poll::Pending => activity.write_waits(),
            Poll::Ready(Ok(n)) if *n > 0 => activity.wrote(),
            Poll::Ready(_) => {}
        }
    }

    /// Writes what is left of the answer to a refusal, if any.
    fn poll_answer(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        if let Some((bytes, done)) = &mut self.answer {
            while *done < bytes.len() {
                let r = Pin::new(&mut self.stream).poll_write(cx, &bytes[*done..]);
                Self::note_write(&self.activity, &r);
                match ready!(r)? {
                    0 => return Poll::Ready(Err(io::ErrorKind::WriteZero.into())),
                    n => *done += n,
                }
            }
        }
        Poll::Ready(Ok(()))
    }

    /// Takes `bytes`, which hyper is writing, in place of a refusal of its own: true
    /// when they were one (the JSON answer then goes out instead).
    fn answered_refusal(&mut self, bytes: &[u8]) -> bool {
        // A refusal is only ever written while no handler runs: hyper answers it
        // instead of calling the service.
        if self.answer.is_some() || self.activity.handlers.load(Ordering::Relaxed) != 0 {
            return false;
        }
        match hyper_refusal(bytes, self.max_header_bytes) {
            Some(error) => {
                self.answer = Some((error.http1_response(), 0));
                true
            }
            None => false,
        }
    }
}

/// The error of a refusal hyper writes by itself, if `head` is exactly one: the head
/// of a bodiless `400`, `414` or `431` with no headers but `content-length: 0`,
/// `date` and `connection` (hyper's `on_error` answer to a parse error). A response of
/// a handler is never that: every error of ours has a JSON body.
fn hyper_refusal(head: &[u8], max_header_bytes: usize) -> Option<ApiError> {
    if head.len() > 512 {
        return None;
    }
    let text = std::str::from_utf8(head).ok()?.strip_suffix("\r\n\r\n")?;
    let mut lines = text.split("\r\n");
    let status = lines.next()?.strip_prefix("HTTP/1.1 ")?.get(..3)?;
    let mut bodiless = false;
    for line in lines {
        let (name, value) = line.split_once(": ")?;
        match name {
            "content-length" if value == "0" => bodiless = true,
            "date" | "connection" => {}
            _ => return None,
        }
    }
    if !bodiless {
        return None;
    }
    match status {
        "400" => Some(ApiError::MalformedRequest),
        "414" => Some(ApiError::UriTooLong { max: MAX_TARGET_BYTES }),
        "431" => Some(ApiError::HeadersTooLarge { max: max_header_bytes }),
        _ => None,
    }
}

/// The longest request target hyper reads (its `MAX_URI_LEN`); a longer one gets 414.
pub const MAX_TARGET_BYTES: usize = u16::MAX as usize - 1;

impl AsyncRead for Watched {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        let r = Pin::new(&mut self.stream).poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            self.activity.moved();
        }
        r
    }
}

impl AsyncWrite for Watched {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        ready!(this.poll_answer(cx))?;
        if this.answered_refusal(buf) {
            // hyper's bytes count as written; ours go out now or at the flush.
            if let Poll::Ready(Err(e)) = this.poll_answer(cx) {
                return Poll::Ready(Err(e));
            }
            return Poll::Ready(Ok(buf.len()));
        }
        let r = Pin::new(&mut this.stream).poll_write(cx, buf);
        Self::note_write(&this.activity, &r);
        r
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        ready!(this.poll_answer(cx))?;
        let total: usize = bufs.iter().map(|b| b.len()).sum();
        let first = bufs.iter().find(|b| !b.is_empty()).map_or(&[][..], |b| &b[..]);
        if total <= 512 && first.starts_with(b"HTTP/1.1 4") {
            let bytes: Vec<u8> = bufs.iter().flat_map(|b| b.iter().copied()).collect();
            if this.answered_refusal(&bytes) {
                if let Poll::Ready(Err(e)) = this.poll_answer(cx) {
                    return Poll::Ready(Err(e));
                }
                return Poll::Ready(Ok(total));
            }
        }
        let r = Pin::new(&mut this.stream).poll_write_vectored(cx, bufs);
        Self::note_write(&this.activity, &r);
        r
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        ready!(this.poll_answer(cx))?;
        Pin::new(&mut this.stream).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        ready!(this.poll_answer(cx))?;
        if this.answer.is_none() {
            return Pin::new(&mut this.stream).poll_shutdown(cx);
        }
        // After a refusal: shut the write side, then read what the client still
        // sends before the socket is dropped (see the module notes).
        if this.linger.is_none() {
            ready!(Pin::new(&mut this.stream).poll_shutdown(cx))?;
            this.linger = Some((Box::pin(tokio::time::sleep(LINGER)), 0));
        }
        let Some((deadline, read)) = &mut this.linger else {
            return Poll::Ready(Ok(()));
        };
        if deadline.as_mut().poll(cx).is_ready() {
            return Poll::Ready(Ok(()));
        }
        let mut sink = [0u8; 4096];
        while *read < LINGER_BYTES {
            let mut buf = ReadBuf::new(&mut sink);
            match ready!(Pin::new(&mut this.stream).poll_read(cx, &mut buf)) {
                Ok(()) if buf.filled().is_empty() => break,
                Ok(()) => *read += buf.filled().len(),
                Err(_) => break,
            }
        }
        Poll::Ready(Ok(()))
    }
}

/// Accepts connections on `listener` and serves `app` on them until `close`
/// resolves; then shuts every connection down (see the module doc) and returns once
/// they are all closed, or `shutdown_timeout` plus a second has passed.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    limits: ConnLimits,
    metrics: Arc<Metrics>,
    close: impl Future<Output = ()>,
) {
    tracing::info!(
        max_connections = limits.max_connections,
        header_read_timeout_ms = limits.header_read_timeout.as_millis() as u64,
        idle_timeout_ms = limits.idle_timeout.as_millis() as u64,
        write_timeout_ms = limits.write_timeout.as_millis() as u64,
        max_header_bytes = limits.max_header_bytes,
        "connection limits"
    );
    let limits = Arc::new(limits);
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let refusals = Arc::new(Semaphore::new(REFUSALS));
    let (closing_tx, closing_rx) = watch::channel(false);
    // Every connection task holds a receiver; `closed()` resolves when all are gone.
    let (alive_tx, alive_rx) = watch::channel(());
    let mut close = pin!(close);
    let mut backoff = AcceptBackoff::default();
    loop {
        let accepted = tokio::select! {
            r = listener.accept() => r,
            () = &mut close => break,
        };
        match accepted {
            Ok((stream, _)) => {
                backoff.reset();
                metrics.connections_accepted.inc();
                match Arc::clone(&slots).try_acquire_owned() {
                    Ok(slot) => {
                        let conn = Connection {
                            app: app.clone(),
                            limits: Arc::clone(&limits),
                            metrics: Arc::clone(&metrics),
                            closing: closing_rx.clone(),
                        };
                        let alive = alive_rx.clone();
                        tokio::spawn(async move {
                            conn.run(stream).await;
                            drop((slot, alive));
                        });
                    }
                    Err(_) => {
                        metrics
                            .connections_closed
                            .with_label_values(&[CloseReason::OverCap.label()])
                            .inc();
                        refuse(stream, &refusals);
                    }
                }
            }
            // The peer gave up between connecting and our accept: nothing to do.
            Err(e) if is_connection_error(&e) => {}
            Err(e) => {
                metrics.accept_errors.inc();
                let wait = backoff.failed(&e);
                tokio::select! {
                    () = tokio::time::sleep(wait) => {}
                    () = &mut close => break,
                }
            }
        }
    }
    drop(listener);
    closing_tx.send_replace(true);
    drop(alive_rx);
    let open = alive_tx.receiver_count();
    tracing::info!(open, "shutdown: closing connections");
    let limit = limits.shutdown_timeout + Duration::from_secs(1);
    if tokio::time::timeout(limit, alive_tx.closed()).await.is_err() {
        tracing::warn!(
            open = alive_tx.receiver_count(),
            "shutdown: connections still open after {limit:?}; stopping anyway"
        );
    }
}

/// Errors of one connection that `accept` reports; the listener itself is fine.
fn is_connection_error(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::ConnectionRefused | io::ErrorKind::ConnectionAborted | io::ErrorKind::ConnectionReset
    )
}

/// Exponential backoff after accept errors (out of descriptors, of buffers), with a
/// log line at most every [`AcceptBackoff::LOG_EVERY`].
#[derive(Default)]
struct AcceptBackoff {
    delay: Duration,
    last_log: Option<Instant>,
    /// Errors not logged since the last line.
    quiet: u64,
}

impl AcceptBackoff {
    const FIRST: Duration = Duration::from_millis(10);
    const MOST: Duration = Duration::from_secs(1);
    const LOG_EVERY: Duration = Duration::from_secs(10);

    fn reset(&mut self) {
        self.delay = Duration::ZERO;
    }

    /// Records a failed accept; returns how long to wait before the next one.
    fn failed(&mut self, e: &io::Error) -> Duration {
        self.delay = (self.delay * 2).clamp(Self::FIRST, Self::MOST);
        if self.last_log.is_none_or(|t| t.elapsed() >= Self::LOG_EVERY) {
            tracing::warn!(error = %e, more = self.quiet, "cannot accept connections; backing off up to 1 s");
            self.last_log = Some(Instant::now());
            self.quiet = 0;
        } else {
            self.quiet += 1;
        }
        self.delay
    }
}

/// Answers a socket over the connection cap with a 503 and closes it. At most
/// [`REFUSALS`] are answered at once, for at most a second each; past that the socket
/// is closed at once (the client sees the connection closed, never a hang).
fn refuse(mut stream: TcpStream, refusals: &Arc<Semaphore>) {
    let Ok(permit) = Arc::clone(refusals).try_acquire_owned() else {
        return;
    };
    tokio::spawn(async move {
        let _permit = permit;
        let answer = ApiError::ConnectionCap.http1_response();
        let answered = tokio::time::timeout(Duration::from_millis(500), async {
            stream.write_all(&answer).await?;
            stream.shutdown().await
        });
        if !matches!(answered.await, Ok(Ok(()))) {
            return;
        }
        // Read what the client sent (until it closes, 64 KiB or half a second):
        // closing with unread bytes would reset the connection and could destroy the
        // answer before the client reads it.
        let _ = tokio::time::timeout(Duration::from_millis(500), async {
            let mut sink = [0u8; 4096];
            let mut total = 0;
            while total < 64 * 1024 {
                match stream.read(&mut sink).await? {
                    0 => break,
                    n => total += n,
                }
            }
            Ok::<(), io::Error>(())
        })
        .await;
    });
}

/// Counts an open connection until dropped.
struct Open(prometheus::IntGauge);

impl Open {
    fn count(gauge: &prometheus::IntGauge) -> Open {
        gauge.inc();
        Open(gauge.clone())
    }
}

impl Drop for Open {
    fn drop(&mut self) {
        self.0.dec();
    }
}

/// What one connection task needs.
struct Connection {
    app: Router,
    limits: Arc<ConnLimits>,
    metrics: Arc<Metrics>,
    closing: watch::Receiver<bool>,
}

impl Connection {
    async fn run(mut self, stream: TcpStream) {
        let metrics = Arc::clone(&self.metrics);
        // A guard, so that the count comes back however the connection ends (a panic
        // that escaped the router's catch unwinds through here).
        let _open = Open::count(&metrics.connections_open);
        let reason = self.serve(stream).await;
        metrics.connections_closed.with_label_values(&[reason.label()]).inc();
    }

    async fn serve(&mut self, stream: TcpStream) -> CloseReason {
        let activity = Arc::new(Activity::new());
        let io = TokioIo::new(Watched::new(
            stream,
            Arc::clone(&activity),
            self.limits.max_header_bytes,
        ));
        let service = {
            let activity = Arc::clone(&activity);
            let app = TowerToHyperService::new(self.app.clone());
            hyper::service::service_fn(move |req| {
                let handling = Handling::enter(&activity);
                let response = app.call(req);
                async move {
                    let response = response.await;
                    drop(handling);
                    response
                }
            })
        };
        let limits = &self.limits;
        let mut builder = http1::Builder::new();
        builder
            .timer(TokioTimer::new())
            .header_read_timeout(limits.header_read_timeout)
            .max_buf_size(limits.max_header_bytes);
        let mut conn = pin!(builder.serve_connection(io, service));
        let watchdog = |shutting_down| {
            let mut t = tokio::time::interval(limits.tick(shutting_down));
            t.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            t
        };
        let mut tick = watchdog(false);
        let mut shutdown: Option<Instant> = None;
        loop {
            tokio::select! {
                result = conn.as_mut() => {
                    return match result {
                        Ok(()) if shutdown.is_some() => CloseReason::Shutdown,
                        Ok(()) => CloseReason::Done,
                        Err(e) if e.is_timeout() => CloseReason::HeaderTimeout,
                        Err(e) if e.is_parse_too_large() => CloseReason::HeaderTooLarge,
                        Err(_) => CloseReason::Error,
                    };
                }
                _ = self.closing.wait_for(|&c| c), if shutdown.is_none() => {
                    conn.as_mut().graceful_shutdown();
                    shutdown = Some(Instant::now());
                    tick = watchdog(true);
                }
                _ = tick.tick() => {
                    if let Some(reason) = activity.verdict(limits, shutdown.map(|t| t.elapsed())) {
                        return reason;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn automatic_cap_leaves_descriptors_for_the_rest() {
        assert_eq!(auto_max_connections(Some(64)), 64 - (16 + 8 + 8));
        assert_eq!(auto_max_connections(Some(256)), 256 - (16 + 8 + 32));
        assert_eq!(auto_max_connections(Some(1024)), 1024 - (16 + 8 + 128));
        assert_eq!(auto_max_connections(Some(1 << 20)), 4096);
        assert_eq!(auto_max_connections(Some(3)), 1);
        assert_eq!(auto_max_connections(None), 1024);
    }

    #[test]
    fn backoff_doubles_to_a_second_and_resets() {
        let mut b = AcceptBackoff::default();
        let e = io::Error::from_raw_os_error(24);
        let waits: Vec<u64> = (0..9).map(|_| b.failed(&e).as_millis() as u64).collect();
        assert_eq!(waits, [10, 20, 40, 80, 160, 320, 640, 1000, 1000]);
        b.reset();
        assert_eq!(b.failed(&e), Duration::from_millis(10));
    }

    fn limits() -> ConnLimits {
        ConnLimits {
            header_read_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_millis(300),
            write_timeout: Duration::from_millis(200),
            max_connections: 1,
            max_header_bytes: MIN_HEADER_BYTES,
            shutdown_grace: Duration::from_millis(100),
            shutdown_timeout: Duration::from_secs(5),
        }
    }

    #[test]
    fn hyper_refusals_are_recognised_and_nothing_else() {
        let date = "date: Sun, 06 Dec 2026 18:17:09 GMT\r\n";
        for (status, want) in [
            ("400 Bad Request", ApiError::MalformedRequest),
            ("414 URI Too Long", ApiError::UriTooLong { max: 65_534 }),
            (
                "431 Request Header Fields Too Large",
                ApiError::HeadersTooLarge { max: 9000 },
            ),
        ] {
            let head = format!("HTTP/1.1 {status}\r\nconnection: close\r\ncontent-length: 0\r\n{date}\r\n");
            assert_eq!(hyper_refusal(head.as_bytes(), 9000), Some(want), "{head}");
        }
        for head in [
            // A body, a type, another status, another version, a head cut short.
            format!("HTTP/1.1 400 Bad Request\r\ncontent-length: 12\r\n{date}\r\n"),
            "HTTP/1.1 400 Bad Request\r\ncontent-type: application/json\r\ncontent-length: 0\r\n\r\n".to_string(),
            format!("HTTP/1.1 404 Not Found\r\ncontent-length: 0\r\n{date}\r\n"),
            format!("HTTP/1.0 400 Bad Request\r\ncontent-length: 0\r\n{date}\r\n"),
            "HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n".to_string(),
            "HTTP/1.1 400 Bad Request\r\n\r\n".to_string(),
        ] {
            assert_eq!(hyper_refusal(head.as_bytes(), 9000), None, "{head}");
        }
        // The answer that replaces one: a JSON error that says so.
        let answer = ApiError::HeadersTooLarge { max: 9000 }.http1_response();
        let text = String::from_utf8(answer).unwrap();
        let (head, body) = text.split_once("\r\n\r\n").unwrap();
        assert!(
            head.starts_with("HTTP/1.1 431 Request Header Fields Too Large\r\n"),
            "{head}"
        );
        assert!(head.contains(&format!("content-length: {}", body.len())), "{head}");
        let body: serde_json::Value = serde_json::from_str(body).unwrap();
        assert_eq!(body["error"], "headers_too_large");
        assert!(body["message"].as_str().unwrap().contains("9000 bytes"));
    }

    #[test]
    fn watchdog_verdicts() {
        let l = limits();
        let a = Arc::new(Activity::new());
        assert_eq!(a.verdict(&l, None), None, "fresh");
        // A running handler is never idle, and survives the shutdown grace.
        let h = Handling::enter(&a);
        std::thread::sleep(Duration::from_millis(350));
        assert_eq!(a.verdict(&l, None), None);
        assert_eq!(a.verdict(&l, Some(Duration::from_secs(1))), None);
        assert_eq!(a.verdict(&l, Some(Duration::from_secs(6))), Some(CloseReason::Shutdown));
        drop(h);
        // Just finished: neither idle nor past the grace.
        assert_eq!(a.verdict(&l, None), None);
        assert_eq!(a.verdict(&l, Some(Duration::from_secs(1))), None);
        a.write_waits();
        std::thread::sleep(Duration::from_millis(350));
        assert_eq!(a.verdict(&l, None), Some(CloseReason::WriteTimeout));
        a.wrote();
        assert_eq!(a.verdict(&l, None), None, "bytes moved");
        assert_eq!(a.verdict(&l, Some(Duration::from_secs(1))), Some(CloseReason::Shutdown));
        std::thread::sleep(Duration::from_millis(350));
        assert_eq!(a.verdict(&l, None), Some(CloseReason::IdleTimeout));
    }
}
