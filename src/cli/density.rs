//! `cloudscape density`: the grid of a region, written to a file.

use clap::Args;

use cloudscape_core::density::{self, FieldKind, Grid, Region, check_time};
use cloudscape_core::products::grid::{GridFormat, encode_cells, encode_density};
use cloudscape_core::weather::column_rate;

#[derive(Args)]
pub struct DensityArgs {
    /// World name from the config, or a decimal u64 seed (default climate).
    #[arg(long)]
    world: String,
    /// Region in world metres: X0,Y0,X1,Y1 (X0 < X1, Y0 < Y1).
    #[arg(long, allow_hyphen_values = true)]
    bbox: String,
    /// World-clock time in seconds, 0 <= t <= 1e12.
    #[arg(long, allow_hyphen_values = true)]
    t: String,
    /// Level: a level-Z column is 2^Z cells wide. Level 0 is the exact automaton.
    #[arg(long, default_value_t = 0)]
    level: u32,
    /// Layer name (default: the world's first layer).
    #[arg(long)]
    layer: Option<String>,
    /// density (continuous, [0,1]), cld (the automaton's cloud bit; level 0 only) or
    /// precipitation (each column's rate in mm/h, one level; npy or f32 only).
    #[arg(long, default_value = "density")]
    field: String,
    /// npy, f32 (raw little-endian) or u8.
    #[arg(long, default_value = "npy")]
    format: String,
    /// Config file (default: the embedded config).
    #[arg(long)]
    config: Option<String>,
    /// Output file, `-` for stdout. A regular file is replaced whole or not at all;
    /// a symlink is followed; a FIFO or device is written in place.
    #[arg(long)]
    out: String,
}

pub fn run(a: DensityArgs) -> Result<(), String> {
    let config = super::load_config(a.config.as_deref())?;
    let world = config
        .world(&a.world)
        .ok_or_else(|| format!("unknown world `{}`", a.world))?;
    let (layer_index, layer) = world.layer(a.layer.as_deref()).ok_or_else(|| {
        format!(
            "unknown layer `{}` in world `{}`",
            a.layer.as_deref().unwrap_or(""),
            world.name
        )
    })?;
    let t: f64 =
        a.t.trim()
            .parse()
            .map_err(|_| format!("--t is not a number: `{}`", a.t))?;
    check_time(t).map_err(|e| e.to_string())?;
    let b = super::parse_numbers("--bbox", &a.bbox, 4)?;
    let bbox = [b[0], b[1], b[2], b[3]];
    let field = match a.field.as_str() {
        "density" => Some(FieldKind::Density),
        "cld" => Some(FieldKind::Cld),
        "precipitation" => None,
        other => return Err(format!("--field must be density, cld or precipitation, got `{other}`")),
    };
    let format =
        GridFormat::parse(&a.format).ok_or_else(|| format!("--format must be npy, f32 or u8, got `{}`", a.format))?;
    if field.is_none() && format == GridFormat::U8 {
        return Err("--field precipitation is in mm/h: --format npy or f32".into());
    }
    if field == Some(FieldKind::Cld) && a.level != 0 {
        return Err("--field cld exists only at level 0 (the automaton's own cells)".into());
    }
    let region = Region::from_bbox(layer, a.level, bbox, &config.limits).map_err(|e| e.to_string())?;
    let bytes = match field {
        None => {
            let g = density::density(&world, layer_index, a.level, region, t).map_err(|e| e.to_string())?;
            let mut rates = Grid::new(1, g.rows, g.cols);
            for r in 0..g.rows {
                for c in 0..g.cols {
                    rates.data[r * g.cols + c] = column_rate(layer, &g, r, c) as f32;
                }
            }
            encode_density(&rates, format)
        }
        Some(FieldKind::Density) => {
            let g = density::density(&world, layer_index, a.level, region, t).map_err(|e| e.to_string())?;
            encode_density(&g, format)
        }
        Some(FieldKind::Cld) => {
            let g = density::cloud_cells(&world, layer_index, region, t).map_err(|e| e.to_string())?;
            encode_cells(&g, format)
        }
    };
    super::write_out(&a.out, &bytes)
}
