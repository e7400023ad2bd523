//! `sky.json`: the clear sky of one sun as data, so a client draws the same sky,
//! sun colour, ambient and aerial perspective as `cloudscape render`
//! ([`crate::render::sky`]).
//!
//! Fields: `"sun"` (bucket id, azimuth, elevation, direction: the bucket's centre,
//! as every pre-shaded product), `"sun_rgb"` (at the clouds,
//! [`crate::render::sky::SUN_REFERENCE_ALTITUDE`]: what a white surface facing the
//! sun reads), `"sun_scatter"` (what cloud scatters of it per unit 4π-normalised
//! phase, `sun_rgb / 4`), `"exposure"` (the tone map's, multiplied into linear
//! radiance before `1 − exp(−x)` and gamma 1/2.2), `"sun_rgb_ground"`,
//! `"sky_ambient_above"`, `"sky_ambient_below"`, `"ambient_rgb"`, `"night_rgb"`,
//! `"ground_albedo"`, `"sun_disc"` (angular radius, gain over `sun_rgb`), `"sky"`
//! (the radiance table: `rows` over view elevation `e = 90° (i / (rows − 1))²`,
//! `columns` over azimuth from the sun `φ = 180° j / (columns − 1)`, `rgb` row-major
//! with 3 floats per entry; add `night_rgb`), and `"aerial"`: the constants and
//! tables of [`crate::render::sky::Sky::aerial`] (coefficients per metre, scale
//! heights, Mie g, the irradiance the air is lit by, the sun transmittance every
//! `sun_step_m` metres, Ψ_ms at `60 km · (i / (n − 1))²`).

use serde_json::json;

use super::json_f32 as f;
use crate::render::SunBucket;
use crate::render::light::{EXPOSURE, Lighting, SUN_DISC_GAIN};
use crate::render::sky::{self, GROUND_RADIUS, SKY_COLUMNS, SKY_ROWS, SUN_TABLE_STEP, TOP_RADIUS};
use crate::world::ALGORITHM_VERSION;

fn rgb(c: [f64; 3]) -> [f64; 3] {
    c.map(f)
}

/// Encodes the sky of `lighting`, lit for the centre of `bucket`.
pub fn encode_json(bucket: SunBucket, lighting: &Lighting) -> Vec<u8> {
    let sun = bucket.centre();
    let s = &lighting.sky;
    let table: Vec<f64> = s.table().iter().flat_map(|c| c.map(f)).collect();
    let v = json!({
        "algorithm_version": ALGORITHM_VERSION,
        "model": "Rayleigh + Mie + ozone single scattering with Hillaire 2020 multiple scattering, spherical Earth, observer at sea level",
        "sun": {
            "bucket": bucket.id(),
            "azimuth_deg": f(sun.azimuth_deg),
            "elevation_deg": f(sun.elevation_deg),
            "direction": lighting.sun_dir.map(f),
        },
        "sun_rgb": rgb(lighting.sun_rgb),
        "sun_scatter": rgb(lighting.sun_scatter()),
        "exposure": EXPOSURE,
        "sun_rgb_ground": rgb(s.sun_rgb_at(0.0)),
        "sky_ambient_above": rgb(lighting.sky_ambient_above),
        "sky_ambient_below": rgb(lighting.sky_ambient_below),
        "ambient_rgb": rgb(lighting.ambient_rgb),
        "night_rgb": rgb(sky::NIGHT_RADIANCE),
        "ground_albedo": rgb(sky::GROUND_ALBEDO),
        "sun_disc": { "angular_radius": sky::SUN_ANGULAR_RADIUS, "gain": SUN_DISC_GAIN },
        "sky": {
            "rows": SKY_ROWS,
            "columns": SKY_COLUMNS,
            "elevation": "e = 90 deg * (row / (rows - 1))^2",
            "azimuth": "from the sun's azimuth, 180 deg * column / (columns - 1)",
            "rgb": table,
        },
        "aerial": {
            "rayleigh_scattering": sky::RAYLEIGH_SCATTERING,
            "rayleigh_scale_height": sky::RAYLEIGH_SCALE_HEIGHT,
            "mie_scattering": sky::MIE_SCATTERING,
            "mie_extinction": sky::MIE_EXTINCTION,
            "mie_scale_height": sky::MIE_SCALE_HEIGHT,
            "mie_g": sky::MIE_G,
            "scatter_irradiance": f(s.scatter_irradiance()),
            "top_altitude": TOP_RADIUS - GROUND_RADIUS,
            "sun_step_m": SUN_TABLE_STEP,
            "sun_transmittance": s.sun_table().iter().flat_map(|c| c.map(f)).collect::<Vec<f64>>(),
            "multiple": s.multiple_table().iter().flat_map(|c| c.map(f)).collect::<Vec<f64>>(),
        },
    });
    serde_json::to_vec(&v).expect("a JSON value serialises")
}
