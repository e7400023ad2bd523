//! Shared by the integration tests that need a real `cloudscape serve` process: start it
//! on a free loopback port, wait until `/readyz` answers 200, stop it when dropped.
#![allow(dead_code)]

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A `cloudscape serve` child process on 127.0.0.1; killed when dropped.
pub struct ServeProcess {
    pub child: Child,
    /// `http://127.0.0.1:PORT`
    pub base: String,
    pub port: u16,
}

/// A port nothing listens on right now (the OS picks it; the listener is closed again).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .expect("bind 127.0.0.1:0")
        .local_addr()
        .unwrap()
        .port()
}

impl ServeProcess {
    /// Starts `cloudscape serve --listen 127.0.0.1:PORT` with `args` and `env` added and
    /// waits (up to 60 s) for `/readyz`. Panics with the server's stderr if it never
    /// becomes ready.
    pub fn start(args: &[&str], env: &[(&str, &str)]) -> ServeProcess {
        Self::start_on(free_port(), args, env)
    }

    /// As [`ServeProcess::start`] on a chosen port.
    pub fn start_on(port: u16, args: &[&str], env: &[(&str, &str)]) -> ServeProcess {
        let listen = format!("127.0.0.1:{port}");
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_cloudscape"));
        cmd.arg("serve").args(["--listen", &listen]).args(args);
        cmd.env("CLOUDSCAPE_SERVER_DRAIN_MS", "0");
        for (k, v) in env {
            cmd.env(k, v);
        }
        let child = cmd
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn cloudscape serve");
        let mut server = ServeProcess {
            child,
            base: format!("http://{listen}"),
            port,
        };
        server.wait_ready(Duration::from_secs(60));
        server
    }

    fn wait_ready(&mut self, limit: Duration) {
        let client = reqwest::blocking::Client::builder()
            .no_proxy()
            .timeout(Duration::from_secs(5))
            .build()
            .unwrap();
        let start = Instant::now();
        while start.elapsed() < limit {
            if let Ok(Some(status)) = self.child.try_wait() {
                let mut err = String::new();
                if let Some(mut e) = self.child.stderr.take() {
                    use std::io::Read;
                    let _ = e.read_to_string(&mut err);
                }
                panic!("cloudscape serve exited before it was ready ({status}): {err}");
            }
            if let Ok(r) = client.get(format!("{}/readyz", self.base)).send()
                && r.status().as_u16() == 200
            {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        panic!("cloudscape serve on {} was not ready within {limit:?}", self.base);
    }

    /// Sends SIGTERM and waits for the process; returns whether it exited with success.
    pub fn terminate(mut self) -> bool {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        self.child.wait().map(|s| s.success()).unwrap_or(false)
    }
}

impl Drop for ServeProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A blocking HTTP client for the tests: no proxy, 30 s timeout.
pub fn client() -> reqwest::blocking::Client {
    reqwest::blocking::Client::builder()
        .no_proxy()
        .timeout(Duration::from_secs(30))
        .build()
        .unwrap()
}

/// Sum of every sample of the Prometheus metric `name` on `server` whose labels include
/// all of `labels`.
pub fn metric(server: &ServeProcess, name: &str, labels: &[(&str, &str)]) -> f64 {
    let text = client()
        .get(format!("{}/metrics", server.base))
        .send()
        .unwrap()
        .text()
        .unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .filter(|l| l.starts_with(name) && l[name.len()..].starts_with(['{', ' ']))
        .filter(|l| labels.iter().all(|(k, v)| l.contains(&format!("{k}=\"{v}\""))))
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}
