//! `cloudscape fuzz`: a hostile-input soak against a running server (see `crate::fuzz`).
//! Exits non-zero when an answer breaks the contract or the server is unhealthy after.

use std::time::Duration;

use clap::Args;

use crate::fuzz::{SoakOptions, soak};

#[derive(Args)]
pub struct FuzzArgs {
    /// The server, http://HOST:PORT.
    #[arg(long)]
    target: String,
    /// Number of generated requests to send.
    #[arg(long, default_value_t = 100_000)]
    requests: u64,
    /// Generator seed: request i of seed s is always the same request.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Connections sending at once.
    #[arg(long, default_value_t = 8)]
    concurrency: usize,
    /// The server's process id, to report its peak RSS (VmHWM, from /proc/PID/status).
    #[arg(long)]
    pid: Option<u32>,
    /// Seconds an answer may take before it counts as a hang.
    #[arg(long, default_value_t = 60.0)]
    timeout: f64,
    /// A path that must answer 200 after the soak.
    #[arg(long, default_value = "/v1/worlds/default/tiles/0/0/0/density.u8?t=0")]
    good: String,
    /// Also write the report as JSON to FILE.
    #[arg(long)]
    json: Option<String>,
}

pub fn run(a: FuzzArgs) -> Result<(), String> {
    if a.concurrency == 0 || a.concurrency > 1024 {
        return Err(format!("--concurrency must be within [1, 1024], got {}", a.concurrency));
    }
    if !(a.timeout.is_finite() && a.timeout > 0.0 && a.timeout <= 3600.0) {
        return Err(format!("--timeout must be within (0, 3600] seconds, got {}", a.timeout));
    }
    let report = soak(&SoakOptions {
        target: a.target,
        requests: a.requests,
        seed: a.seed,
        concurrency: a.concurrency,
        timeout: Duration::from_secs_f64(a.timeout),
        pid: a.pid,
        good_path: a.good,
        progress: true,
    })?;
    print!("{}", report.summary());
    if let Some(path) = &a.json {
        let text = serde_json::to_string_pretty(&report).map_err(|e| format!("cannot encode the report: {e}"))?;
        super::write_out(path, text.as_bytes())?;
    }
    if report.passed() {
        Ok(())
    } else {
        Err(format!(
            "{} contract violations; server {}",
            report.violation_count,
            if report.health_after.healthy {
                "healthy after"
            } else {
                "NOT healthy after"
            }
        ))
    }
}
