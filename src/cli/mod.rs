//! The `cloudscape` command line: one file per subcommand. Errors go to stderr as
//! one sentence and the process exits non-zero.

mod bench;
mod density;
mod fuzz;
mod gallery;
mod loadtest;
mod out;
mod probe;
mod render;
mod serve;
mod weather;

use std::io::Write;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use cloudscape_core::world::{Config, read_config_text};

pub(crate) use out::write_out;

/// Noise-driven Dobashi cloud simulation for large game worlds.
#[derive(Parser)]
#[command(name = "cloudscape", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Measure the pipeline and regenerate BENCHMARKS.md sections and plots.
    Bench(bench::BenchArgs),
    /// Write the density or cloud grid of a region to a file.
    Density(density::DensityArgs),
    /// Render the gallery: fixed views of the default world at every quality, and a contact sheet.
    Gallery(gallery::GalleryArgs),
    /// Load-test a running server with simulated MMO players and game servers.
    Loadtest(loadtest::LoadtestArgs),
    /// Check that a running server answers (exit 0 on a 2xx from its /healthz).
    Probe(probe::ProbeArgs),
    /// Render what a client would see from a camera to a PNG.
    Render(render::RenderArgs),
    /// Serve tiles, region queries and metrics over HTTP.
    Serve(serve::ServeArgs),
    /// Send generated hostile requests to a running server and judge every answer.
    Fuzz(fuzz::FuzzArgs),
    /// Print a region's weather over time as CSV (the numbers of `/series`).
    Weather(weather::WeatherArgs),
    /// Print the lightning strikes of a box and span as CSV (those of `/lightning`).
    Lightning(weather::LightningArgs),
}

/// Runs the command line and returns the process exit code.
pub fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let code = if e.use_stderr() { 2 } else { 0 };
            let _ = e.print();
            return ExitCode::from(code);
        }
    };
    let result = match cli.command {
        Command::Bench(args) => bench::run(args),
        Command::Density(args) => density::run(args),
        Command::Gallery(args) => gallery::run(args),
        Command::Loadtest(args) => loadtest::run(args),
        Command::Probe(args) => probe::run(args),
        Command::Render(args) => render::run(args),
        Command::Serve(args) => serve::run(args),
        Command::Fuzz(args) => fuzz::run(args),
        Command::Weather(args) => weather::run_weather(args),
        Command::Lightning(args) => weather::run_lightning(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            // One line whatever the message quotes (a world name may hold a newline).
            let line: String = message
                .chars()
                .flat_map(|c| {
                    let escaped = c.is_control().then(|| c.escape_default());
                    escaped.into_iter().flatten().chain((!c.is_control()).then_some(c))
                })
                .collect();
            // Not eprintln!: it panics when stderr is a closed pipe.
            let _ = writeln!(std::io::stderr(), "error: {line}");
            ExitCode::FAILURE
        }
    }
}

/// Loads `--config FILE` or the embedded default. The `[server]` section is checked
/// too, so a file that `serve` would refuse is refused by every command.
pub(crate) fn load_config(path: Option<&str>) -> Result<Config, String> {
    let Some(p) = path else {
        return Ok(Config::embedded());
    };
    // Read once: a pipe (`--config <(…)`) gives its text only once.
    let text = read_config_text(p).map_err(|e| e.to_string())?;
    let config = Config::parse(&text).map_err(|e| e.to_string())?;
    let settings = cloudscape_server::ServerConfig::parse(&text).map_err(|e| e.to_string())?;
    cloudscape_server::check_config(&config, &settings).map_err(|e| e.to_string())?;
    Ok(config)
}

/// Parses `N,N,...` into exactly `n` finite numbers.
pub(crate) fn parse_numbers(what: &str, s: &str, n: usize) -> Result<Vec<f64>, String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != n {
        return Err(format!("{what} needs {n} comma-separated numbers, got `{s}`"));
    }
    parts
        .iter()
        .map(|p| match p.trim().parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(format!(
                "{what} has a value that is not a finite number: `{}`",
                p.trim()
            )),
        })
        .collect()
}
