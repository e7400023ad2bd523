//! Precipitation over a day (issue 24): what a game server's `/series` query of a
//! 10 km box under the storm-front world's storm answers. The queries go over HTTP to
//! an in-process `cloudscape serve` (embedded config, default `[server]` settings), as
//! a user's would; the answers are plotted against time and written beside the plot
//! as CSV.

use std::time::{Duration, Instant};

use serde::Deserialize;

use super::http::{LocalServer, client};
use super::{BenchRun, Effort, fmt_s};
use crate::chart::{Mark, PALETTE, Panel, Series, render};

const WORLD: &str = "storm-front";
const LAYER: &str = "cumulonimbus";
/// X0, Y0, X1, Y1 in metres. The storm-front's rain band (an ellipsoid 24 km across
/// in y, centred on y = 30 km at t = 0) moves north with the wind at 1.5 m/s, 130 km a
/// day, so a fixed box lies under it for a few hours only; this one, 65 km north of
/// the band's centre at t = 0, lies under it around midday, so the day shows the
/// storm arrive, pass and leave.
const BBOX: [f64; 4] = [0.0, 90_000.0, 10_000.0, 100_000.0];
/// Points per `/series` request: well under `server.max_series` (256 by default) and
/// a computation well inside the default 10 s request budget.
const CHUNK_POINTS: u64 = 60;
/// How often a request shed with 503 is tried again (after its `Retry-After`).
const RETRIES: u32 = 5;

/// The parts of a `/series` answer this section reads.
#[derive(Deserialize)]
struct SeriesAnswer {
    level: u32,
    columns: Columns,
    points: Vec<SeriesPoint>,
}

#[derive(Deserialize)]
struct Columns {
    cols: usize,
    rows: usize,
}

#[derive(Clone, Debug, Deserialize)]
struct SeriesPoint {
    t: f64,
    frame_t: f64,
    coverage: f64,
    precipitating: f64,
    mean_precipitation_mm_h: f64,
    max_precipitation_mm_h: f64,
}

/// The span, step and level an effort asks for.
struct Plan {
    t0: f64,
    t1: f64,
    dt: f64,
    level: u32,
}

impl Plan {
    fn of(effort: Effort) -> Plan {
        match effort {
            Effort::Smoke => Plan {
                t0: 43_200.0,
                t1: 46_800.0,
                dt: 1200.0,
                level: 3,
            },
            Effort::Quick => Plan {
                t0: 0.0,
                t1: 86_400.0,
                dt: 600.0,
                level: 0,
            },
            Effort::Full => Plan {
                t0: 0.0,
                t1: 86_400.0,
                dt: 60.0,
                level: 0,
            },
        }
    }

    /// The (t0, t1) of each request: [`CHUNK_POINTS`] points each, the last one
    /// ending at the plan's t1.
    fn chunks(&self) -> Vec<(f64, f64)> {
        let points = ((self.t1 - self.t0) / self.dt).floor() as u64 + 1;
        (0..points)
            .step_by(CHUNK_POINTS as usize)
            .map(|first| {
                let last = (first + CHUNK_POINTS - 1).min(points - 1);
                (self.t0 + first as f64 * self.dt, self.t0 + last as f64 * self.dt)
            })
            .collect()
    }

    fn url(&self, base: &str, (t0, t1): (f64, f64)) -> String {
        let [x0, y0, x1, y1] = BBOX;
        format!(
            "{base}/v1/worlds/{WORLD}/series?bbox={x0},{y0},{x1},{y1}&t0={t0}&t1={t1}&dt={}&layer={LAYER}&level={}",
            self.dt, self.level
        )
    }
}

/// GETs `url`, trying again after `Retry-After` when the server sheds it (503).
/// Returns the body and how many times it was shed.
fn get_json(client: &reqwest::blocking::Client, url: &str) -> Result<(serde_json::Value, u32), String> {
    let mut shed = 0;
    loop {
        let r = client.get(url).send().map_err(|e| format!("{url}: {e}"))?;
        let status = r.status().as_u16();
        let retry_after = r
            .headers()
            .get(reqwest::header::RETRY_AFTER)
            .and_then(|v| v.to_str().ok()?.parse::<u64>().ok());
        let body = r.text().map_err(|e| format!("{url}: {e}"))?;
        match status {
            200 => return Ok((serde_json::from_str(&body).map_err(|e| format!("{url}: {e}"))?, shed)),
            503 if shed < RETRIES => {
                shed += 1;
                std::thread::sleep(Duration::from_secs(retry_after.unwrap_or(1).clamp(1, 30)));
            }
            _ => return Err(format!("{url} answered {status}: {body}")),
        }
    }
}

/// The day's figures, from points evenly spaced `dt` apart.
#[derive(Debug, PartialEq)]
struct DayFigures {
    /// Accumulation over the box (the box mean rate integrated over time), mm.
    total_mm: f64,
    /// `total_mm` over the span, mm/h.
    mean_mm_h: f64,
    /// The largest rate of any column, and its time.
    max: (f64, f64),
    /// The largest box mean rate, and its time.
    peak_mean: (f64, f64),
    /// Share of the points at which some column of the box precipitates.
    wet_time: f64,
    /// First and last such point's time.
    wet_span: Option<(f64, f64)>,
    /// Mean over the points of the precipitating share of the box's columns
    /// (the share of the box and the day that precipitates).
    wet_area_time: f64,
}

fn day_figures(points: &[SeriesPoint]) -> DayFigures {
    let n = points.len().max(1) as f64;
    // Trapezoid rule over the sample times (rates in mm/h, times in s).
    let total_mm: f64 = points
        .windows(2)
        .map(|w| 0.5 * (w[0].mean_precipitation_mm_h + w[1].mean_precipitation_mm_h) * (w[1].t - w[0].t) / 3600.0)
        .sum();
    let hours = match (points.first(), points.last()) {
        (Some(a), Some(b)) if b.t > a.t => (b.t - a.t) / 3600.0,
        _ => 1.0,
    };
    let largest = |f: fn(&SeriesPoint) -> f64| {
        points
            .iter()
            .map(|p| (f(p), p.t))
            .fold((0.0, f64::NAN), |a, b| if b.0 > a.0 { b } else { a })
    };
    let wet: Vec<f64> = points.iter().filter(|p| p.precipitating > 0.0).map(|p| p.t).collect();
    DayFigures {
        total_mm,
        mean_mm_h: total_mm / hours,
        max: largest(|p| p.max_precipitation_mm_h),
        peak_mean: largest(|p| p.mean_precipitation_mm_h),
        wet_time: wet.len() as f64 / n,
        wet_span: wet.first().zip(wet.last()).map(|(a, b)| (*a, *b)),
        wet_area_time: points.iter().map(|p| p.precipitating).sum::<f64>() / n,
    }
}

/// `HH:MM` of a time in seconds (hours may pass 24).
fn clock(t: f64) -> String {
    if !t.is_finite() {
        return "–".into();
    }
    let m = (t / 60.0).round() as i64;
    format!("{:02}:{:02}", m / 60, m % 60)
}

fn csv(points: &[SeriesPoint]) -> String {
    let mut s = String::from("t_s,frame_t_s,coverage,precipitating_fraction,mean_mm_h,max_mm_h\n");
    for p in points {
        s += &format!(
            "{},{},{:.4},{:.4},{:.4},{:.4}\n",
            p.t, p.frame_t, p.coverage, p.precipitating, p.mean_precipitation_mm_h, p.max_precipitation_mm_h
        );
    }
    s
}

fn plot(points: &[SeriesPoint], title: &str) -> Result<Vec<u8>, String> {
    let at = |f: fn(&SeriesPoint) -> f64| points.iter().map(|p| (p.t / 3600.0, f(p))).collect::<Vec<_>>();
    let line = |name: &str, points, colour| Series {
        name: name.into(),
        points,
        colour,
        mark: Mark::Line,
    };
    render(
        &[
            Panel {
                title: format!("{title}: precipitation rate"),
                x_label: "world time (h)".into(),
                y_label: "rate (mm/h)".into(),
                series: vec![
                    line("largest column rate", at(|p| p.max_precipitation_mm_h), PALETTE[1]),
                    line("mean over the box", at(|p| p.mean_precipitation_mm_h), PALETTE[0]),
                ],
                ..Panel::default()
            },
            Panel {
                title: format!("{title}: precipitating columns"),
                x_label: "world time (h)".into(),
                y_label: "share of the box's columns (%)".into(),
                series: vec![line("precipitating", at(|p| 100.0 * p.precipitating), PALETTE[2])],
                ..Panel::default()
            },
        ],
        1,
        (960, 340),
    )
}

pub fn precipitation_day(effort: Effort, out: &mut BenchRun) -> Result<(), String> {
    let started = Instant::now();
    let plan = Plan::of(effort);
    let server = LocalServer::start()?;
    let client = client()?;
    let (world, _) = get_json(&client, &format!("{}/v1/worlds/{WORLD}", server.base))?;
    let version = world["algorithm_version"]
        .as_u64()
        .ok_or("discovery names no algorithm version")?;
    let chunks = plan.chunks();
    let mut points: Vec<SeriesPoint> = Vec::new();
    let mut columns = (0, 0);
    let mut level = plan.level;
    let (mut shed, mut slowest) = (0, 0.0f64);
    let queries = Instant::now();
    for &chunk in &chunks {
        let url = plan.url(&server.base, chunk);
        let t = Instant::now();
        let (body, s) = get_json(&client, &url)?;
        slowest = slowest.max(t.elapsed().as_secs_f64());
        shed += s;
        let answer: SeriesAnswer = serde_json::from_value(body).map_err(|e| format!("{url}: {e}"))?;
        columns = (answer.columns.cols, answer.columns.rows);
        level = answer.level;
        points.extend(answer.points);
    }
    let query_s = queries.elapsed().as_secs_f64();
    drop(server);
    if points.len() < 2 {
        return Err(format!("the series answered {} points", points.len()));
    }
    let f = day_figures(&points);
    let [x0, y0, x1, y1] = BBOX;
    let title = format!(
        "{WORLD} {LAYER}, box x {}–{} km, y {}–{} km",
        x0 / 1e3,
        x1 / 1e3,
        y0 / 1e3,
        y1 / 1e3
    );
    out.add_plot("precipitation-day.png", plot(&points, &title)?);
    out.add_plot("precipitation-day.csv", csv(&points).into_bytes());
    let column_m = 100.0 * f64::from(1u32 << level);
    let mut md = format!(
        "`cloudscape bench --only precipitation-day` ({} effort) started an in-process `cloudscape serve` \
         (embedded config, default `[server]` settings, ALGORITHM_VERSION {version}) on a loopback port and asked \
         it, over HTTP, for the `/series` of the {WORLD} world's `{LAYER}` layer over the box `bbox={x0},{y0},{x1},\
         {y1}` (10 km × 10 km; level {level}: {}×{} columns of {column_m} m), t = {} … {} s every {} s: {} points \
         in {} requests of at most {CHUNK_POINTS} points, one after another on a cold cache, the first:\n\n    {}\n\n\
         The requests took {} in all (slowest {}; {shed} shed with 503 and tried again); the section, server \
         start included, {}. The rain band moves north at 1.5 m/s, so this box, 65 km north of the band's \
         centre at t = 0, lies under it around midday. Data: [precipitation-day.csv](@plots@/precipitation-day.csv) \
         (one row per point).\n\n![precipitation over a day](@plots@/precipitation-day.png)\n\n\
         | figure (over the {} h, sampled every {} s) | value |\n|---|---|\n",
        effort.name(),
        columns.0,
        columns.1,
        plan.t0,
        plan.t1,
        plan.dt,
        points.len(),
        chunks.len(),
        plan.url("", chunks[0]),
        fmt_s(query_s),
        fmt_s(slowest),
        fmt_s(started.elapsed().as_secs_f64()),
        (plan.t1 - plan.t0) / 3600.0,
        plan.dt,
    );
    md += &format!(
        "| mean rate over the box | {:.2} mm/h ({:.1} mm accumulated) |\n",
        f.mean_mm_h, f.total_mm
    );
    md += &format!(
        "| largest box mean rate | {:.1} mm/h at {} |\n",
        f.peak_mean.0,
        clock(f.peak_mean.1)
    );
    md += &format!(
        "| largest rate of any column | {:.1} mm/h at {} |\n",
        f.max.0,
        clock(f.max.1)
    );
    md += &format!(
        "| time with some column of the box precipitating | {:.1} % of the points{} |\n",
        100.0 * f.wet_time,
        f.wet_span
            .map(|(a, b)| format!(" (first {}, last {})", clock(a), clock(b)))
            .unwrap_or_default()
    );
    md += &format!(
        "| share of the box and the time precipitating (mean precipitating fraction) | {:.1} % |\n",
        100.0 * f.wet_area_time
    );
    out.add_section("precipitation-day", "Weather: precipitation over a day (`/series`)", md);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(t: f64, wet: f64, mean: f64, max: f64) -> SeriesPoint {
        SeriesPoint {
            t,
            frame_t: t,
            coverage: wet,
            precipitating: wet,
            mean_precipitation_mm_h: mean,
            max_precipitation_mm_h: max,
        }
    }

    #[test]
    fn a_day_is_asked_for_in_chunks_that_cover_every_point_once() {
        let plan = Plan::of(Effort::Full);
        let chunks = plan.chunks();
        let points: u64 = chunks.iter().map(|(a, b)| ((b - a) / plan.dt).round() as u64 + 1).sum();
        assert_eq!(points, 1441);
        assert_eq!(chunks[0], (0.0, 3540.0));
        assert_eq!(chunks[1].0, 3600.0);
        assert_eq!(*chunks.last().unwrap(), (86_400.0, 86_400.0));
        assert!(chunks.windows(2).all(|w| w[1].0 == w[0].1 + plan.dt));
        let url = plan.url("", chunks[0]);
        assert_eq!(
            url,
            "/v1/worlds/storm-front/series?bbox=0,90000,10000,100000&t0=0&t1=3540&dt=60&layer=cumulonimbus&level=0"
        );
    }

    #[test]
    fn day_figures_integrate_the_box_mean() {
        // Dry, then 2 h of 6 mm/h over half the box, then dry: 3 points of 4 are wet.
        let p = [
            point(0.0, 0.0, 0.0, 0.0),
            point(3600.0, 0.5, 6.0, 20.0),
            point(7200.0, 0.5, 6.0, 30.0),
            point(10_800.0, 0.0, 0.0, 0.0),
        ];
        let f = day_figures(&p);
        // Trapezoids: 3 + 6 + 3 mm over 3 h.
        assert!(
            (f.total_mm - 12.0).abs() < 1e-9 && (f.mean_mm_h - 4.0).abs() < 1e-9,
            "{f:?}"
        );
        assert_eq!(f.max, (30.0, 7200.0));
        assert_eq!(f.peak_mean, (6.0, 3600.0));
        assert_eq!(f.wet_time, 0.5);
        assert_eq!(f.wet_span, Some((3600.0, 7200.0)));
        assert_eq!(f.wet_area_time, 0.25);
        assert_eq!(clock(7200.0), "02:00");
        assert_eq!(clock(86_400.0), "24:00");
        let dry = day_figures(&[point(0.0, 0.0, 0.0, 0.0), point(60.0, 0.0, 0.0, 0.0)]);
        assert_eq!((dry.total_mm, dry.wet_span), (0.0, None));
        assert!(csv(&p).lines().count() == 5 && csv(&p).starts_with("t_s,"));
    }
}
