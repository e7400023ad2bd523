//! Connection attacks (issue 25) against a running server, loopback only and bounded
//! in time: idle and slowloris connections, unfinished huge headers, SIGTERM with slow
//! clients open, and a flood of idle connections against a low descriptor limit. Each
//! returns the figure BENCHMARKS.md "Hostile inputs and overload" reports;
//! `examples/attack_conn.rs` runs them against a fresh server each.

use std::io::{self, ErrorKind, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use super::http::Connection;
use super::process_memory_kb;

/// How many of the attacker's connections the server still held at the end.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Held {
    /// Connections the attacker opened.
    pub opened: usize,
    /// Of those, the ones the server had not closed.
    pub held: usize,
}

/// Whether the server still holds `s` open: reads what is there without waiting;
/// end of stream or a reset means closed.
fn still_open(s: &mut TcpStream) -> bool {
    if s.set_nonblocking(true).is_err() {
        return false;
    }
    let mut buf = [0u8; 16 * 1024];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return false,
            Ok(_) => {}
            Err(e) if e.kind() == ErrorKind::WouldBlock => return true,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(_) => return false,
        }
    }
}

fn held(conns: &mut [TcpStream]) -> Held {
    Held {
        opened: conns.len(),
        held: conns.iter_mut().map(still_open).filter(|&open| open).count(),
    }
}

fn connect(addr: &str) -> io::Result<TcpStream> {
    let s = TcpStream::connect(addr)?;
    s.set_nodelay(true)?;
    s.set_write_timeout(Some(Duration::from_secs(5)))?;
    Ok(s)
}

/// `n` connections that send nothing and `n` that send a request head a byte a
/// second; after `hold`, how many of each the server still holds.
pub fn idle_and_slowloris(addr: &str, n: usize, hold: Duration) -> io::Result<(Held, Held)> {
    let mut idle = Vec::with_capacity(n);
    let mut slow = Vec::with_capacity(n);
    for _ in 0..n {
        idle.push(connect(addr)?);
        let mut s = connect(addr)?;
        s.write_all(b"GET /healthz HTTP/1.1\r\nhost: attack\r\nx-slow: ")?;
        s.set_nonblocking(true)?;
        slow.push(s);
    }
    let start = Instant::now();
    while start.elapsed() < hold {
        std::thread::sleep(Duration::from_secs(1));
        for s in &mut slow {
            let _ = s.write(b"a");
        }
    }
    Ok((held(&mut idle), held(&mut slow)))
}

/// `n` connections each sending `bytes` of a request head that never ends. Returns
/// the server's peak RSS (kB, `VmHWM` of `pid`) and how many connections it still
/// holds after `hold`.
pub fn unfinished_headers(addr: &str, pid: u32, n: usize, bytes: usize, hold: Duration) -> io::Result<(u64, Held)> {
    let mut head = b"GET /healthz HTTP/1.1\r\nhost: attack\r\nx-huge: ".to_vec();
    head.resize(bytes, b'a');
    let mut conns = Vec::with_capacity(n);
    for _ in 0..n {
        let mut s = connect(addr)?;
        let _ = s.write_all(&head); // the server may refuse and close first
        conns.push(s);
    }
    std::thread::sleep(hold);
    let peak = process_memory_kb(pid).map_or(0, |(_, hwm)| hwm);
    Ok((peak, held(&mut conns)))
}

/// Whether process `pid` still runs (not gone, not a zombie).
pub fn process_running(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        // The state follows the parenthesised command name.
        Ok(stat) => stat.rsplit(')').next().and_then(|r| r.split_whitespace().next()) != Some("Z"),
        Err(_) => false,
    }
}

/// Opens `n` slow connections (a third each: half-sent heads, idle kept-alive
/// connections, clients that never read their answers), sends SIGTERM to `pid` and
/// returns how long the process took to exit (`None`: still running after `limit`).
pub fn sigterm_with_slow_clients(addr: &str, pid: u32, n: usize, limit: Duration) -> io::Result<Option<Duration>> {
    let mut conns = Vec::new();
    for i in 0..n {
        let mut s = connect(addr)?;
        match i % 3 {
            0 => s.write_all(b"GET /healthz HTTP/1.1\r\nhost: attack\r\nx-slow: a")?,
            1 => {
                // One small answer, read whole in one go; then the connection idles.
                s.write_all(b"GET /healthz HTTP/1.1\r\nhost: attack\r\n\r\n")?;
                s.set_read_timeout(Some(Duration::from_secs(5)))?;
                let _ = s.read(&mut [0u8; 4096]);
            }
            _ => {
                s.set_nonblocking(true)?;
                let pipelined = b"GET /openapi.json HTTP/1.1\r\nhost: attack\r\n\r\n".repeat(2000);
                let _ = s.write(&pipelined);
            }
        }
        conns.push(s);
    }
    std::thread::sleep(Duration::from_millis(500));
    let start = Instant::now();
    let _ = std::process::Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status();
    while process_running(pid) {
        if start.elapsed() > limit {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(Some(start.elapsed()))
}

/// What a new client saw while a flood of idle connections was open.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Recovery {
    /// Idle connections the attacker tried to open; they stay open.
    pub flood: usize,
    /// How many of them connected (a server that stops accepting leaves the rest
    /// unable to connect).
    pub flood_connected: usize,
    /// How long opening the flood took (the server may close early ones meanwhile).
    pub flood_ms: u64,
    /// Time until a new client got any answer (`None`: none within the limit).
    pub first_answer_ms: Option<u64>,
    /// The status of that first answer.
    pub first_status: Option<u16>,
    /// Time until a new client got a 200.
    pub first_ok_ms: Option<u64>,
}

/// Opens `flood` idle connections (each connect waits at most 2 s; three
/// failures in a row end the flood) and keeps them
/// open; then a new client asks `/healthz` (each try waits at most 5 s) until it gets
/// a 200 or `limit` passes.
pub fn recovery_after_flood(addr: &str, flood: usize, limit: Duration) -> io::Result<Recovery> {
    let target: std::net::SocketAddr = addr
        .parse()
        .map_err(|_| io::Error::new(ErrorKind::InvalidInput, "an IP:PORT address"))?;
    let mut attackers = Vec::with_capacity(flood);
    let mut failed_in_a_row = 0;
    let flooding = Instant::now();
    for _ in 0..flood {
        match TcpStream::connect_timeout(&target, Duration::from_secs(2)) {
            Ok(s) => {
                attackers.push(s);
                failed_in_a_row = 0;
            }
            // The listen queue is full: more tries would only wait.
            Err(_) if failed_in_a_row >= 2 => break,
            Err(_) => failed_in_a_row += 1,
        }
    }
    let start = Instant::now();
    let mut r = Recovery {
        flood,
        flood_connected: attackers.len(),
        flood_ms: flooding.elapsed().as_millis() as u64,
        first_answer_ms: None,
        first_status: None,
        first_ok_ms: None,
    };
    while start.elapsed() < limit {
        let answer = Connection::open(addr, Duration::from_secs(5)).ok().and_then(|mut c| {
            c.exchange(
                b"GET /healthz HTTP/1.1\r\nhost: attack\r\nconnection: close\r\n\r\n",
                false,
            )
            .ok()
        });
        if let Some((a, _)) = answer {
            let ms = start.elapsed().as_millis() as u64;
            if r.first_answer_ms.is_none() {
                r.first_answer_ms = Some(ms);
                r.first_status = Some(a.status);
            }
            if a.status == 200 {
                r.first_ok_ms = Some(ms);
                break;
            }
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    drop(attackers);
    Ok(r)
}
