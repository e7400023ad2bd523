//! `cloudscape probe`: a health check for images without curl (the container's
//! `HEALTHCHECK`). GETs a URL of a running server and succeeds on a 2xx answer.

use std::time::Duration;

use clap::Args;

#[derive(Args)]
pub struct ProbeArgs {
    /// URL to GET.
    #[arg(long, default_value = "http://127.0.0.1:8080/healthz")]
    url: String,
    /// Give up after this many milliseconds.
    #[arg(long, default_value_t = 2000)]
    timeout_ms: u64,
}

pub fn run(a: ProbeArgs) -> Result<(), String> {
    let client = reqwest::blocking::Client::builder()
        .no_proxy()
        .timeout(Duration::from_millis(a.timeout_ms))
        .build()
        .map_err(|e| format!("cannot make an HTTP client: {e}"))?;
    let response = client
        .get(&a.url)
        .send()
        .map_err(|e| format!("{} did not answer: {e}", a.url))?;
    let status = response.status();
    if status.is_success() {
        Ok(())
    } else {
        Err(format!("{} answered {status}", a.url))
    }
}
