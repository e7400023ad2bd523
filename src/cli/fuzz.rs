//! `cloudscape fuzz`: a hostile-input soak against a running server (see `cloudscape_tools::soak`),
//! or with `--scenario attack` the compute and memory attacks of `cloudscape_tools::soak::attack`.
//! Exits non-zero when an answer breaks the contract, the server is unhealthy after,
//! or (attack) the server did not hold.

use std::time::Duration;

use clap::Args;

use cloudscape_tools::soak::attack::{self, AttackOptions};
use cloudscape_tools::soak::{SoakOptions, soak};

/// What `cloudscape fuzz` runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Scenario {
    /// Generated hostile requests, every answer judged against the contract.
    Soak,
    /// The compute and memory attacks: render bursts, amplification, peak RSS.
    Attack,
}

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
    /// `soak` (generated requests) or `attack` (compute and memory attacks).
    #[arg(long, value_enum, default_value_t = Scenario::Soak)]
    scenario: Scenario,
    /// attack: the server's request budget (server.request_timeout_ms), seconds.
    #[arg(long, default_value_t = 10.0)]
    budget: f64,
    /// attack: the peak RSS the server may reach, MiB (the cache budget + 512 MiB).
    #[arg(long, default_value_t = 768)]
    rss_limit_mib: u64,
    /// attack: requests per burst.
    #[arg(long, default_value_t = 8)]
    burst: usize,
    /// attack: image size of the admitted burst's renders (heavy, within the limits).
    #[arg(long, default_value = "2048x2048")]
    heavy_size: String,
    /// attack: quality of the admitted burst's renders.
    #[arg(long, default_value = "balanced")]
    heavy_quality: String,
    /// attack: run only these attacks (comma-separated names; all by default).
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// attack: tile requests of the crawl over random seeds, levels, times and
    /// products (0: no crawl); set --rss-limit-mib to the cache budget + 512.
    #[arg(long, default_value_t = 0)]
    crawl: usize,
    /// attack: seconds of quiet after the crawl before its RSS is read again.
    #[arg(long, default_value_t = 30.0)]
    crawl_idle: f64,
}

pub fn run(a: FuzzArgs) -> Result<(), String> {
    if a.scenario == Scenario::Attack {
        return run_attack(a);
    }
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
        write_report(path, &report)?;
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

fn run_attack(a: FuzzArgs) -> Result<(), String> {
    if a.burst == 0 || a.burst > 64 {
        return Err(format!("--burst must be within [1, 64], got {}", a.burst));
    }
    if a.crawl > 1_000_000 {
        return Err(format!("--crawl must be within [0, 1000000], got {}", a.crawl));
    }
    if !(a.crawl_idle.is_finite() && (0.0..=3600.0).contains(&a.crawl_idle)) {
        return Err(format!(
            "--crawl-idle must be within [0, 3600] seconds, got {}",
            a.crawl_idle
        ));
    }
    let report = attack::run(&AttackOptions {
        target: a.target.trim_end_matches('/').to_string(),
        pid: a.pid,
        budget_s: a.budget,
        rss_limit_mib: a.rss_limit_mib,
        burst: a.burst,
        heavy_size: a.heavy_size,
        heavy_quality: a.heavy_quality,
        only: a.only,
        crawl: a.crawl,
        crawl_idle_s: a.crawl_idle,
        world: "default".to_string(),
        progress: true,
    })?;
    print!("{}", report.summary());
    if let Some(path) = &a.json {
        write_report(path, &report)?;
    }
    if report.held {
        Ok(())
    } else {
        Err("the server did not hold under the attack scenario".to_string())
    }
}

/// Writes a report as pretty JSON to `path` (`--json`).
fn write_report(path: &str, report: &impl serde::Serialize) -> Result<(), String> {
    let text = serde_json::to_string_pretty(report).map_err(|e| format!("cannot encode the report: {e}"))?;
    super::write_out(path, text.as_bytes())
}
