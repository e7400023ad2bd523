//! `cloudscape loadtest`: simulated MMO players and game servers against a running
//! server (the generator is `cloudscape_tools::loadtest`); prints a summary, optionally writes
//! the report as JSON and a latency plot.

use std::time::Duration;

use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use cloudscape_tools::loadtest::{self, FetchMode, GeometryKind, LoadSpec, Placement, Scenario};

#[derive(Args)]
pub struct LoadtestArgs {
    /// The server, http://HOST:PORT.
    #[arg(long)]
    target: String,
    /// Simulated players (mmo, mixed; in groups of 8) or game servers (queries).
    #[arg(long, default_value_t = 32)]
    players: usize,
    /// How long to send: 30s, 2m, 500ms, or plain seconds.
    #[arg(long, default_value = "30s")]
    duration: String,
    /// mmo (players fetching tiles), queries (/region and /series) or mixed.
    #[arg(long, default_value = "mmo")]
    scenario: String,
    /// Open loop at this many requests per second, latency from the intended send
    /// time (coordinated-omission corrected). Default: closed loop.
    #[arg(long, allow_hyphen_values = true)]
    rate: Option<f64>,
    /// World name or decimal seed.
    #[arg(long, default_value = "default")]
    world: String,
    /// World-clock time at the start, seconds. Default: the server's clock now (its
    /// discovery's `clock.now`, the keyframes it keeps warm), else 43200.
    #[arg(long, allow_hyphen_values = true)]
    t: Option<f64>,
    /// World seconds per real second (0 freezes the clock, so views only revalidate).
    /// Default: the server's clock rate, else 1.
    #[arg(long, allow_hyphen_values = true)]
    clock: Option<f64>,
    /// Seed of the players' itineraries and views.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Where the mmo groups are: towns (start in the server's warm areas or nine
    /// generated towns, walk, ride and fly between them along roads) or spread (each
    /// group its own path, 30 km from the next: every group a new place).
    #[arg(long, default_value = "towns")]
    geometry: String,
    /// Run the generator at this nice value, 0 to 19 (every thread; higher yields the
    /// CPU to the server), so the figures describe the server.
    #[arg(long, allow_hyphen_values = true)]
    nice: Option<String>,
    /// Pin the generator's threads to these cores: 1, 0,2 or 0-3.
    #[arg(long, allow_hyphen_values = true)]
    cpu: Option<String>,
    /// Write the full report (figures, status counts, per-second timeline) as JSON.
    #[arg(long)]
    json: Option<String>,
    /// Write a latency plot (PNG); with --sweep, players against latency, CPU and lag.
    #[arg(long)]
    plot: Option<String>,
    /// Players re-plan and revalidate every tile every second at the current time
    /// (before keyframes). Default: fetch each keyframe URL once, as the viewer does.
    #[arg(long)]
    poll: bool,
    /// Groups share this many places: more players watching the same tiles.
    #[arg(long)]
    places: Option<usize>,
    /// The preset players fetch: fast (the viewer's default), balanced or accurate.
    #[arg(long, default_value = "fast")]
    quality: String,
    /// The tile format players fetch: v3 (billboards.bin for a tile's first keyframe,
    /// billboards.delta.bin after, as the viewer) or v2 (billboards.v2.bin and
    /// shadow.png for every keyframe, as clients did before version 3).
    #[arg(long, default_value = "v3")]
    wire: String,
    /// Send from the start but measure only after this long (the first views are cold).
    #[arg(long, default_value = "0s")]
    warmup: String,
    /// The server's process id, for its CPU time when its /metrics has none.
    #[arg(long)]
    pid: Option<u32>,
    /// Capacity sweep: runs of --duration (after --warmup) with 8, 16, 32, … players until
    /// p99 passes 50 ms or a request is shed; prints the curve.
    #[arg(long)]
    sweep: bool,
    /// The players of each sweep step, comma-separated (default 8,16,32,…,1024, stopping at the first step that does not hold); steps given here all run, for a whole curve.
    #[arg(long, value_delimiter = ',')]
    steps: Option<Vec<usize>>,
    /// With --sweep: write the curve into this Markdown file between
    /// `<!-- bench:capacity:begin/end -->` (`capacity-poll` with --poll; BENCHMARKS.md).
    #[arg(long)]
    markdown: Option<String>,
}

/// Parses `30s`, `2m`, `1h`, `500ms` or plain seconds.
pub(crate) fn parse_duration(s: &str) -> Result<Duration, String> {
    let t = s.trim();
    let (num, unit) = match t.find(|c: char| c.is_ascii_alphabetic()) {
        Some(i) => t.split_at(i),
        None => (t, "s"),
    };
    let scale = match unit {
        "ms" => 1e-3,
        "s" => 1.0,
        "m" => 60.0,
        "h" => 3600.0,
        _ => return Err(format!("duration must look like 30s, 2m, 1h or 500ms, got `{s}`")),
    };
    match num.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v * scale <= 7.0 * 86_400.0 => Ok(Duration::from_secs_f64(v * scale)),
        _ => Err(format!(
            "duration must be a positive time up to a week, like 30s or 2m, got `{s}`"
        )),
    }
}

pub fn run(a: LoadtestArgs) -> Result<(), String> {
    let scenario = Scenario::parse(&a.scenario)
        .ok_or_else(|| format!("--scenario must be mmo, queries or mixed, got `{}`", a.scenario))?;
    let geometry = GeometryKind::parse(&a.geometry)
        .ok_or_else(|| format!("--geometry must be towns or spread, got `{}`", a.geometry))?;
    let nice = match &a.nice {
        Some(n) => Some(Placement::check_nice(n.trim().parse().map_err(|_| {
            format!("--nice must be a whole number between 0 and 19, got `{n}`")
        })?)?),
        None => None,
    };
    let cpus = a.cpu.as_deref().map(Placement::parse_cpus).transpose()?;
    let warmup = if a.warmup.trim() == "0s" || a.warmup.trim() == "0" {
        Duration::ZERO
    } else {
        parse_duration(&a.warmup)?
    };
    let spec = LoadSpec {
        target: a.target,
        world: a.world,
        players: a.players,
        duration: parse_duration(&a.duration)?,
        scenario,
        rate: a.rate,
        t0: a.t,
        clock: a.clock,
        seed: a.seed,
        geometry,
        placement: Placement { nice, cpus },
        fetch: if a.poll { FetchMode::Poll } else { FetchMode::Keyframes },
        places: a.places,
        server_pid: a.pid,
        warmup,
        wire: loadtest::Wire::parse(&a.wire).ok_or_else(|| format!("--wire must be v3 or v2, got `{}`", a.wire))?,
        quality: match cloudscape_core::render::Quality::parse(&a.quality) {
            Some(q) if !q.is_volumetric() => q,
            _ => {
                return Err(format!(
                    "--quality must be fast, balanced or accurate, got `{}`",
                    a.quality
                ));
            }
        },
    };
    if a.sweep {
        // Steps given by hand run to the last, for a whole curve; the default steps
        // stop at the first that does not hold.
        let every_step = a.steps.is_some();
        return sweep(
            &spec,
            (a.steps.unwrap_or_else(loadtest::sweep_steps), every_step),
            &a.json,
            &a.plot,
            &a.markdown,
        );
    }
    // Hidden when stderr is not a terminal (indicatif checks).
    let bar = ProgressBar::with_draw_target(
        Some(spec.duration.as_millis() as u64),
        ProgressDrawTarget::stderr_with_hz(5),
    );
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {elapsed}/{duration} {msg}")
            .expect("a valid template")
            .progress_chars("=> "),
    );
    let report = loadtest::run(&spec, |p| {
        bar.set_position(((p.elapsed_s * 1000.0) as u64).min(spec.duration.as_millis() as u64));
        bar.set_message(format!("{} requests, {} shed (503)", p.requests, p.shed));
    })
    .map_err(|e| e.to_string())?;
    bar.finish_and_clear();
    print!("{}", report.summary());
    if let Some(path) = &a.json {
        let json = serde_json::to_vec_pretty(&report).map_err(|e| format!("cannot encode the report: {e}"))?;
        super::write_out(path, &json)?;
    }
    if let Some(path) = &a.plot {
        super::write_out(path, &report.plot()?)?;
    }
    if report.totals.requests == 0 {
        return Err(match &report.first_error {
            Some(e) => format!("no request was answered: {e}"),
            None => "no request was sent (is the duration shorter than the first tick?)".into(),
        });
    }
    Ok(())
}

/// `--sweep`: the capacity curve, printed, and written where asked.
fn sweep(
    spec: &LoadSpec,
    (steps, every_step): (Vec<usize>, bool),
    json: &Option<String>,
    plot: &Option<String>,
    markdown: &Option<String>,
) -> Result<(), String> {
    if steps.is_empty() || steps.iter().any(|&n| n == 0 || n > 100_000) {
        return Err("--steps must list player counts between 1 and 100000".into());
    }
    let report = loadtest::sweep(spec, &steps, every_step, |players, p| {
        eprint!(
            "\r{players} players: {:.0} s, {} requests, {} shed   ",
            p.elapsed_s, p.requests, p.shed
        );
    })
    .map_err(|e| e.to_string())?;
    eprintln!();
    let md = report.markdown();
    print!("{md}");
    if let Some(path) = json {
        let bytes = serde_json::to_vec_pretty(&report).map_err(|e| format!("cannot encode the report: {e}"))?;
        super::write_out(path, &bytes)?;
    }
    if let Some(path) = plot {
        super::write_out(path, &report.plot()?)?;
    }
    if let Some(path) = markdown {
        let doc = std::fs::read_to_string(path).map_err(|e| format!("cannot read {path}: {e}"))?;
        // The `--poll` baseline has a section of its own, beside the keyframe curve.
        let section = match spec.fetch {
            FetchMode::Keyframes => cloudscape_tools::bench::Section {
                id: "capacity",
                title: "Capacity: players per box",
                markdown: md,
            },
            FetchMode::Poll => cloudscape_tools::bench::Section {
                id: "capacity-poll",
                title: "Capacity: players per box, polling every second (before keyframes)",
                markdown: md,
            },
        };
        let merged = cloudscape_tools::bench::merge_sections(&doc, &[section])?;
        super::write_out(path, merged.as_bytes())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_parse_with_units() {
        assert_eq!(parse_duration("30s").unwrap(), Duration::from_secs(30));
        assert_eq!(parse_duration("2m").unwrap(), Duration::from_secs(120));
        assert_eq!(parse_duration("500ms").unwrap(), Duration::from_millis(500));
        assert_eq!(parse_duration("3").unwrap(), Duration::from_secs(3));
        for bad in ["", "-1s", "0", "3x", "nan", "1e9h"] {
            assert!(parse_duration(bad).is_err(), "{bad}");
        }
    }
}
