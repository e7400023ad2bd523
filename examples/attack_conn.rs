//! The connection attacks of issue 25 against a fresh `cloudscape serve` each, on
//! loopback, bounded in time; prints one JSON line per attack for BENCHMARKS.md
//! "Hostile inputs and overload" / "Connections". Run it once per binary to compare
//! (before = main's, after = this branch's):
//!
//!     cargo run --release --example attack_conn -- BIN [ATTACK...]
//!
//! ATTACK is `idle` (2,000 idle + 2,000 slowloris connections, held after 15 s),
//! `headers` (2,000 unfinished 400 KB heads: peak RSS), `sigterm` (50 slow clients:
//! exit time; drain 1 s), `ulimit` (server under `prlimit --nofile=256`: a new client
//! while 1,000 idle connections stay open); default all. The server runs with its
//! default `[server]` settings (header-read 10 s, idle 5 s, drain 1 s) and
//! `RUST_LOG=warn`, stderr discarded.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use cloudscape_tools::soak::conn_attacks::{self, Held};
use cloudscape_tools::soak::http::Connection;

struct Server {
    child: Child,
    addr: String,
}

impl Server {
    fn start(bin: &str, nofile: Option<u32>) -> Server {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let addr = format!("127.0.0.1:{port}");
        let mut cmd = match nofile {
            Some(n) => {
                let mut c = Command::new("prlimit");
                c.arg(format!("--nofile={n}:{n}")).arg(bin);
                c
            }
            None => Command::new(bin),
        };
        cmd.args(["serve", "--listen", &addr])
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        let child = cmd.spawn().expect("spawn the server");
        let start = Instant::now();
        loop {
            let ok = Connection::open(&addr, Duration::from_secs(2)).ok().and_then(|mut c| {
                c.exchange(b"GET /readyz HTTP/1.1\r\nhost: a\r\nconnection: close\r\n\r\n", false)
                    .ok()
            });
            if matches!(ok, Some((a, _)) if a.status == 200) {
                break;
            }
            assert!(start.elapsed() < Duration::from_secs(60), "server not ready");
            std::thread::sleep(Duration::from_millis(100));
        }
        Server { child, addr }
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn line(bin: &str, attack: &str, figures: serde_json::Value) {
    println!(
        "{}",
        serde_json::json!({"binary": bin, "attack": attack, "figures": figures})
    );
}

fn main() {
    let mut args = std::env::args().skip(1);
    let bin = args
        .next()
        .expect("usage: attack_conn BIN [idle|headers|sigterm|ulimit ...]");
    let mut attacks: Vec<String> = args.collect();
    if attacks.is_empty() {
        attacks = ["idle", "headers", "sigterm", "ulimit"].map(String::from).to_vec();
    }
    for attack in &attacks {
        match attack.as_str() {
            "idle" => {
                let s = Server::start(&bin, None);
                let hold = Duration::from_secs(15);
                let (idle, slow): (Held, Held) = conn_attacks::idle_and_slowloris(&s.addr, 2000, hold).unwrap();
                line(
                    &bin,
                    "idle",
                    serde_json::json!({"after_s": hold.as_secs(), "idle": idle, "slowloris": slow}),
                );
            }
            "headers" => {
                let s = Server::start(&bin, None);
                let (peak_kb, held) =
                    conn_attacks::unfinished_headers(&s.addr, s.pid(), 2000, 400 << 10, Duration::from_secs(2))
                        .unwrap();
                line(
                    &bin,
                    "headers",
                    serde_json::json!({"peak_rss_mb": peak_kb / 1024, "connections": held}),
                );
            }
            "sigterm" => {
                let mut s = Server::start(&bin, None);
                let pid = s.pid();
                // Reap the child as it exits, so that it does not linger as a zombie.
                let took = std::thread::scope(|scope| {
                    let waiter = scope.spawn(|| s.child.wait());
                    let took =
                        conn_attacks::sigterm_with_slow_clients(&s.addr, pid, 50, Duration::from_secs(60)).unwrap();
                    if took.is_none() {
                        let _ = Command::new("kill").args(["-KILL", &pid.to_string()]).status();
                    }
                    let _ = waiter.join();
                    took
                });
                line(
                    &bin,
                    "sigterm",
                    serde_json::json!({"drain_ms": 1000, "exit_ms": took.map(|d| d.as_millis() as u64)}),
                );
            }
            "ulimit" => {
                let s = Server::start(&bin, Some(256));
                let r = conn_attacks::recovery_after_flood(&s.addr, 1000, Duration::from_secs(60)).unwrap();
                line(&bin, "ulimit", serde_json::to_value(r).unwrap());
            }
            other => panic!("unknown attack {other}"),
        }
    }
}
