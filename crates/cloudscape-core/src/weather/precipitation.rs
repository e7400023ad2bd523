//! Precipitation from the cloud column: a rate in mm/h and a kind (rain, snow, none).
//!
//! The rule, for one column of one layer (densities `ρ_k` in [0, 1], cell height `Δz`):
//!
//! 1. **Liquid water path** `LWP = Σ_k ρ_k · q · Δz` (g/m²), with `q` the preset's
//!    liquid water content at density 1 ([`PrecipitationSpec::liquid_water`]): density
//!    stands for the fraction of the preset's in-cloud water a cell holds.
//! 2. **Rate** `R = ε · 0.0156 · ((LWP − LWP₀)⁺ / N)^1.75` mm/h, with `N` the droplet
//!    concentration (cm⁻³), `LWP₀` the onset ([`PrecipitationSpec::onset`]) and `ε` the
//!    precipitation efficiency. The power law is Comstock, Hartmann & Mather 2004
//!    (QJRMS 130, "Precipitation in the stratocumulus-topped boundary layer")
//!    `R_cb = 0.0156 (LWP/N)^1.75`, the cloud-base drizzle rate of the EPIC
//!    stratocumulus; Geoffroy et al. 2008 (ACP 8, 4641) find the same family
//!    (`R ∝ LWP^α / N`, equivalently `∝ H³/N` with cloud thickness H) across
//!    stratocumulus fields. Interpretation taken: LWP is measured *in excess of* an
//!    onset threshold, Kessler's (1969) autoconversion threshold carried over to the
//!    column, so the rate is continuous (nothing pops as a cloud deepens) and exactly
//!    zero for thin clouds.
//! 3. **Kind** at altitude `z`: none where `R = 0`; snow where `z` is at or above the
//!    snow level `freezing_level − 300 m` ([`MELTING_DEPTH`]: falling snow takes about
//!    300 m below the 0 °C isotherm to melt, the forecasters' rule that the snow
//!    level lies ~1000 ft below the freezing level); rain below it.
//!
//! **Calibration.** The relation is fitted on stratocumulus drizzle; for deep
//! convection it is an extrapolation, so the presets' parameters (config/default.toml)
//! were chosen so that the rates land in the published intensity classes (AMS
//! Glossary of Meteorology, "rain": light ≤ 2.5 mm/h, moderate 2.6–7.6 mm/h, heavy
//! above 7.6 mm/h): a full stratocumulus deck drizzles (< 0.5 mm/h), fair-weather cumulus
//! barely precipitates (< 2.5 mm/h), a full cumulonimbus column rains heavily
//! (7.6–100 mm/h), cirrus (ice, evaporating fall streaks) gives nothing. The unit
//! tests below check those classes and the rule's invariants (zero below the onset,
//! monotone in depth and density, bounded by the full column).

use serde::Serialize;

use crate::density::{CLOUD_THRESHOLD, Grid};
use crate::world::{Layer, PrecipitationSpec};

/// Comstock et al. 2004: `R_cb = 0.0156 (LWP/N)^1.75` (mm/h; LWP in g/m², N in cm⁻³).
pub const COMSTOCK_COEFFICIENT: f64 = 0.0156;
/// The exponent of Comstock et al. 2004's relation.
pub const COMSTOCK_EXPONENT: f64 = 1.75;
/// How far below the freezing level falling snow turns to rain, metres.
pub const MELTING_DEPTH: f64 = 300.0;

/// What falls at a point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum PrecipitationKind {
    /// Nothing: the rate is 0.
    None,
    /// Liquid: the point is below the snow level.
    Rain,
    /// Frozen: the point is at or above the snow level.
    Snow,
}

impl PrecipitationKind {
    /// The name the API uses (`none`, `rain`, `snow`).
    pub fn as_str(self) -> &'static str {
        match self {
            PrecipitationKind::None => "none",
            PrecipitationKind::Rain => "rain",
            PrecipitationKind::Snow => "snow",
        }
    }
}

/// The liquid water path (g/m²) of a column of densities of `layer`.
pub fn liquid_water_path(layer: &Layer, column: impl IntoIterator<Item = f32>) -> f64 {
    let q = layer.preset.precipitation.liquid_water;
    // NaN (never produced by the density, but cheap to refuse) counts as no water.
    let sum: f64 = column
        .into_iter()
        .map(|d| if d > 0.0 { d.min(1.0) as f64 } else { 0.0 })
        .sum();
    sum * q * layer.cell_height
}

/// The rate (mm/h) of a column whose liquid water path is `lwp` (g/m²).
pub fn rate_from_lwp(spec: &PrecipitationSpec, lwp: f64) -> f64 {
    let excess = lwp - spec.onset;
    // `!(x > 0)` also takes NaN to the dry branch.
    if !(excess > 0.0) || spec.efficiency <= 0.0 {
        return 0.0;
    }
    spec.efficiency * COMSTOCK_COEFFICIENT * (excess / spec.droplets).powf(COMSTOCK_EXPONENT)
}

/// The rate (mm/h) of column (`row`, `col`) of `grid`, a density grid of `layer`.
pub fn column_rate(layer: &Layer, grid: &Grid<f32>, row: usize, col: usize) -> f64 {
    let lwp = liquid_water_path(layer, (0..grid.depth).map(|k| grid.get(k, row, col)));
    rate_from_lwp(&layer.preset.precipitation, lwp)
}

/// The largest rate a column of `layer` can have: every cell at density 1.
pub fn max_rate(layer: &Layer) -> f64 {
    let lwp = liquid_water_path(layer, (0..layer.depth).map(|_| 1.0));
    rate_from_lwp(&layer.preset.precipitation, lwp)
}

/// Altitude (metres) at and above which precipitation falls as snow.
pub fn snow_level(freezing_level: f64) -> f64 {
    freezing_level - MELTING_DEPTH
}

/// What falls at altitude `z` (metres) under a column raining `rate` mm/h.
pub fn kind_at(rate: f64, freezing_level: f64, z: f64) -> PrecipitationKind {
    if !(rate > 0.0) {
        PrecipitationKind::None
    } else if z >= snow_level(freezing_level) {
        PrecipitationKind::Snow
    } else {
        PrecipitationKind::Rain
    }
}

/// The lowest vertical level of column (`row`, `col`) holding cloud
/// (density ≥ [`CLOUD_THRESHOLD`]): where fall streaks start.
pub fn column_base(grid: &Grid<f32>, row: usize, col: usize) -> Option<usize> {
    (0..grid.depth).find(|&k| grid.get(k, row, col) >= CLOUD_THRESHOLD)
}

/// Precipitation statistics of a region: what `/region` and `/series` add.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct PrecipitationStats {
    /// Fraction of the region's columns with a rate above 0, in [0, 1].
    pub precipitating: f64,
    /// Mean rate over all columns of the region, mm/h.
    pub mean_precipitation_mm_h: f64,
    /// Largest rate of any column, mm/h.
    pub max_precipitation_mm_h: f64,
}

/// The precipitation statistics of `grid` (a region of `layer`).
pub fn precipitation_stats(grid: &Grid<f32>, layer: &Layer) -> PrecipitationStats {
    let (mut wet, mut sum, mut max) = (0u64, 0.0f64, 0.0f64);
    for row in 0..grid.rows {
        for col in 0..grid.cols {
            let r = column_rate(layer, grid, row, col);
            if r > 0.0 {
                wet += 1;
            }
            sum += r;
            max = max.max(r);
        }
    }
    let columns = (grid.rows * grid.cols) as f64;
    PrecipitationStats {
        precipitating: if columns > 0.0 { wet as f64 / columns } else { 0.0 },
        mean_precipitation_mm_h: if columns > 0.0 { sum / columns } else { 0.0 },
        max_precipitation_mm_h: max,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Config;

    fn layer(world: &str, name: &str) -> Layer {
        let c = Config::embedded();
        c.worlds[world].layers.iter().find(|l| l.name == name).unwrap().clone()
    }

    /// A one-column grid of `layer`'s depth: `cloudy` levels of density `d` from the base.
    fn column(layer: &Layer, cloudy: usize, d: f32) -> Grid<f32> {
        let mut g = Grid::new(layer.depth as usize, 1, 1);
        for k in 0..cloudy.min(layer.depth as usize) {
            g.data[k] = d;
        }
        g
    }

    #[test]
    fn the_rate_is_comstocks_relation_above_the_onset() {
        // By hand: LWP 250 g/m², onset 50, N 100 → 0.0156 · 2^1.75 = 0.05247 mm/h.
        let spec = PrecipitationSpec {
            liquid_water: 0.5,
            droplets: 100.0,
            onset: 50.0,
            efficiency: 1.0,
        };
        assert!((rate_from_lwp(&spec, 250.0) - 0.0156 * 2f64.powf(1.75)).abs() < 1e-12);
        assert!((rate_from_lwp(&spec, 250.0) - 0.052_47).abs() < 1e-5);
        let half = PrecipitationSpec {
            efficiency: 0.5,
            ..spec.clone()
        };
        assert_eq!(rate_from_lwp(&half, 250.0), 0.5 * rate_from_lwp(&spec, 250.0));
        for lwp in [f64::NAN, -1.0, 0.0, 49.9, 50.0] {
            assert_eq!(rate_from_lwp(&spec, lwp), 0.0, "lwp {lwp}");
        }
    }

    #[test]
    fn the_liquid_water_path_is_density_times_content_times_depth() {
        let l = layer("storm-front", "cumulonimbus");
        let q = l.preset.precipitation.liquid_water;
        let g = column(&l, 5, 0.5);
        let lwp = liquid_water_path(&l, g.data.iter().copied());
        assert!((lwp - 5.0 * 0.5 * q * l.cell_height).abs() < 1e-9);
        // Out-of-range densities are clamped, NaN counts as nothing.
        assert_eq!(liquid_water_path(&l, [2.0, -1.0, f32::NAN]), q * l.cell_height);
    }

    #[test]
    fn thin_clouds_do_not_precipitate_and_deeper_ones_precipitate_more() {
        let config = Config::embedded();
        for world in config.worlds.values() {
            for l in &world.layers {
                let spec = &l.preset.precipitation;
                // Thin: one cell of full density holds less water than the onset, for
                // every shipped preset that rains at all.
                if spec.efficiency > 0.0 {
                    assert_eq!(column_rate(l, &column(l, 1, 1.0), 0, 0), 0.0, "{}", l.name);
                }
                let mut last = 0.0;
                for cloudy in 0..=l.depth as usize {
                    for d in [0.3f32, 1.0] {
                        let r = column_rate(l, &column(l, cloudy, d), 0, 0);
                        assert!(r >= 0.0 && r <= max_rate(l), "{} {cloudy} {d}: {r}", l.name);
                    }
                    let r = column_rate(l, &column(l, cloudy, 1.0), 0, 0);
                    assert!(r >= last, "{}: rate falls from {last} to {r} at {cloudy} cells", l.name);
                    last = r;
                }
                assert_eq!(last, max_rate(l));
            }
        }
    }

    #[test]
    fn the_presets_rain_in_the_published_intensity_classes() {
        // AMS Glossary: light <= 2.5 mm/h, heavy > 7.6 mm/h.
        let cb = max_rate(&layer("storm-front", "cumulonimbus"));
        assert!(cb > 7.6 && cb < 100.0, "cumulonimbus full column {cb} mm/h");
        let sc = max_rate(&layer("overcast", "stratocumulus"));
        assert!(sc > 0.0 && sc < 0.5, "stratocumulus deck {sc} mm/h");
        let cu = max_rate(&layer("default", "cumulus"));
        assert!(cu < 2.5, "fair-weather cumulus {cu} mm/h");
        assert_eq!(max_rate(&layer("default", "cirrus")), 0.0);
        // A half-density cumulonimbus column is still at least moderate.
        let l = layer("storm-front", "cumulonimbus");
        let half = column_rate(&l, &column(&l, l.depth as usize, 0.5), 0, 0);
        assert!(half > 2.5, "half-density cumulonimbus {half} mm/h");
    }

    #[test]
    fn snow_falls_at_and_above_the_snow_level() {
        assert_eq!(kind_at(0.0, 1000.0, 5000.0), PrecipitationKind::None);
        assert_eq!(kind_at(f64::NAN, 1000.0, 5000.0), PrecipitationKind::None);
        assert_eq!(kind_at(1.0, 1000.0, 699.0), PrecipitationKind::Rain);
        assert_eq!(kind_at(1.0, 1000.0, 700.0), PrecipitationKind::Snow);
        assert_eq!(kind_at(1.0, 0.0, 0.0), PrecipitationKind::Snow);
        assert_eq!(PrecipitationKind::Snow.as_str(), "snow");
    }

    #[test]
    fn region_statistics_of_a_known_grid() {
        let l = layer("storm-front", "cumulonimbus");
        // 1×3 columns: dry, half, full.
        let mut g = Grid::<f32>::new(l.depth as usize, 1, 3);
        for k in 0..l.depth as usize {
            let i = g.index(k, 0, 1);
            g.data[i] = 0.5;
            let i = g.index(k, 0, 2);
            g.data[i] = 1.0;
        }
        let s = precipitation_stats(&g, &l);
        let half = column_rate(&l, &column(&l, l.depth as usize, 0.5), 0, 0);
        assert_eq!(s.precipitating, 2.0 / 3.0);
        assert_eq!(s.max_precipitation_mm_h, max_rate(&l));
        assert!((s.mean_precipitation_mm_h - (half + max_rate(&l)) / 3.0).abs() < 1e-9);
        let empty = precipitation_stats(&Grid::new(2, 0, 0), &l);
        assert_eq!(empty.precipitating, 0.0);
        assert_eq!(column_base(&g, 0, 0), None);
        assert_eq!(column_base(&g, 0, 1), Some(0));
    }
}
