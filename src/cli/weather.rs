//! `cloudscape weather` and `cloudscape lightning`: a region's weather over time and
//! its lightning strikes, as CSV, from the same functions `/series` and `/lightning`
//! answer with (so a designer can check when an authored storm reaches a play area
//! without running a server).

use std::fmt::Write as _;

use clap::Args;

use cloudscape_core::density::{self, Region, check_time, region_stats};
use cloudscape_core::weather::lightning::{self, LightningLimits, LightningPlan, StrikeKind};
use cloudscape_core::weather::precipitation_stats;
use cloudscape_core::world::{Config, World};

/// Most rows one `cloudscape weather` run prints.
const MAX_POINTS: f64 = 100_000.0;

/// Which world, box and span of time both commands read.
#[derive(Args)]
pub struct Query {
    /// World name from the config, or a decimal u64 seed (default climate).
    #[arg(long)]
    world: String,
    /// Region in world metres: X0,Y0,X1,Y1 (X0 < X1, Y0 < Y1; `lightning`: sides up to 50 km).
    #[arg(long, allow_hyphen_values = true)]
    bbox: String,
    /// First time, seconds.
    #[arg(long)]
    t0: f64,
    /// Last time, seconds (`weather`: inclusive when on the step grid; `lightning`: exclusive,
    /// at most 3600 s after t0).
    #[arg(long)]
    t1: f64,
}

/// Where both commands read the world from and write their CSV to.
#[derive(Args)]
pub struct Files {
    /// Config file (default: the embedded config).
    #[arg(long)]
    config: Option<String>,
    /// Output file, `-` (the default) for stdout.
    #[arg(long, default_value = "-")]
    out: String,
}

#[derive(Args)]
pub struct WeatherArgs {
    #[command(flatten)]
    query: Query,
    /// Step between rows, seconds (default: the layer's dt).
    #[arg(long)]
    dt: Option<f64>,
    /// Level of the columns (as `/region`'s `level`).
    #[arg(long, default_value_t = 0)]
    level: u32,
    /// Layer name (default: the world's first layer).
    #[arg(long)]
    layer: Option<String>,
    #[command(flatten)]
    files: Files,
}

#[derive(Args)]
pub struct LightningArgs {
    #[command(flatten)]
    query: Query,
    /// Layer name (default: every layer whose preset makes lightning).
    #[arg(long)]
    layer: Option<String>,
    #[command(flatten)]
    files: Files,
}

fn world_of(config: &Config, name: &str) -> Result<World, String> {
    config.world(name).ok_or_else(|| format!("unknown world `{name}`"))
}

fn layer_of<'w>(world: &'w World, name: Option<&str>) -> Result<(usize, &'w cloudscape_core::world::Layer), String> {
    world
        .layer(name)
        .ok_or_else(|| format!("unknown layer `{}` in world `{}`", name.unwrap_or(""), world.name))
}

fn bbox_of(s: &str) -> Result<[f64; 4], String> {
    let b = super::parse_numbers("--bbox", s, 4)?;
    Ok([b[0], b[1], b[2], b[3]])
}

/// An optional number as CSV: empty when absent.
fn cell(v: Option<f64>) -> String {
    v.map_or(String::new(), |v| v.to_string())
}

pub fn run_weather(a: WeatherArgs) -> Result<(), String> {
    let config = super::load_config(a.files.config.as_deref())?;
    let world = world_of(&config, &a.query.world)?;
    let (li, layer) = layer_of(&world, a.layer.as_deref())?;
    let (t0, t1) = (
        check_time(a.query.t0).map_err(|e| format!("--t0: {e}"))?,
        check_time(a.query.t1).map_err(|e| format!("--t1: {e}"))?,
    );
    if t1 < t0 {
        return Err("--t1 must be >= --t0".into());
    }
    let step = a.dt.unwrap_or(layer.dt);
    if !(step.is_finite() && step > 0.0) {
        return Err("--dt must be a number of seconds > 0".into());
    }
    let points = ((t1 - t0) / step).floor() + 1.0;
    if points > MAX_POINTS {
        return Err(format!("{points} rows is over {MAX_POINTS}: use a larger --dt"));
    }
    let region =
        Region::from_bbox(layer, a.level, bbox_of(&a.query.bbox)?, &config.limits).map_err(|e| e.to_string())?;
    let mut csv = String::from(
        "t,coverage,mean_density,max_density,cloud_base,cloud_top,clusters,precipitating,mean_precipitation_mm_h,max_precipitation_mm_h\n",
    );
    for i in 0..points as u64 {
        let t = (t0 + i as f64 * step).min(t1);
        let grid = density::density(&world, li, a.level, region, t).map_err(|e| e.to_string())?;
        let (s, p) = (region_stats(&grid, layer), precipitation_stats(&grid, layer));
        let _ = writeln!(
            csv,
            "{t},{},{},{},{},{},{},{},{},{}",
            s.coverage,
            s.mean_density,
            s.max_density,
            cell(s.cloud_base),
            cell(s.cloud_top),
            s.clusters,
            p.precipitating,
            p.mean_precipitation_mm_h,
            p.max_precipitation_mm_h
        );
    }
    super::write_out(&a.files.out, csv.as_bytes())
}

pub fn run_lightning(a: LightningArgs) -> Result<(), String> {
    let config = super::load_config(a.files.config.as_deref())?;
    let world = world_of(&config, &a.query.world)?;
    let layers: Vec<usize> = match a.layer.as_deref() {
        Some(name) => vec![layer_of(&world, Some(name))?.0],
        None => (0..world.layers.len())
            .filter(|&i| world.layers[i].preset.makes_lightning())
            .collect(),
    };
    let (bbox, t0, t1) = (bbox_of(&a.query.bbox)?, a.query.t0, a.query.t1);
    let limits = LightningLimits::default();
    // Every check before any work, as `/lightning` does.
    let plans = layers
        .iter()
        .map(|&i| LightningPlan::new(&world, i, bbox, t0, t1, &limits).map(|p| (i, p)))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    if plans.is_empty() {
        LightningPlan::new(&world, 0, bbox, t0, t1, &limits).map_err(|e| e.to_string())?;
    }
    let mut strikes = Vec::new();
    for (i, p) in &plans {
        strikes.extend(lightning::strikes(&world, *i, bbox, t0, t1, p).map_err(|e| e.to_string())?);
    }
    strikes.sort_by(|a, b| a.t.total_cmp(&b.t).then(a.x.total_cmp(&b.x)).then(a.y.total_cmp(&b.y)));
    let mut csv = String::from("t,x,y,z,kind\n");
    for s in &strikes {
        let kind = match s.kind {
            StrikeKind::Cg => "cg",
            StrikeKind::Ic => "ic",
        };
        let _ = writeln!(csv, "{},{},{},{},{kind}", s.t, s.x, s.y, s.z);
    }
    super::write_out(&a.files.out, csv.as_bytes())
}
