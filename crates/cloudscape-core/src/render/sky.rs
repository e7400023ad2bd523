//! The clear sky: a small precomputed Rayleigh + Mie + ozone atmosphere over a
//! spherical Earth, evaluated once per sun into look-up tables, then read per pixel.
//!
//! Model (Hillaire 2020, "A Scalable and Production Ready Sky and Atmosphere
//! Rendering Technique", EGSR; constants of its Table 1, which are those of
//! Bruneton's 2017 reimplementation of Bruneton & Neyret 2008):
//! - Rayleigh scattering `β_R = (5.802, 13.558, 33.1)·10⁻⁶ /m` for (680, 550, 440) nm,
//!   density `exp(−h / 8 km)`, phase `3/(16π) (1 + cos²θ)`.
//! - Mie scattering `3.996·10⁻⁶ /m`, extinction `4.40·10⁻⁶ /m`, density
//!   `exp(−h / 1.2 km)`, Cornette–Shanks phase with g = 0.8.
//! - Ozone absorption `(0.650, 1.881, 0.085)·10⁻⁶ /m`, a tent of density 1 at 25 km
//!   falling to 0 at 10 and 40 km.
//! - Ground radius 6360 km, top of the atmosphere 6420 km.
//!
//! Per sun, [`Sky::new`] precomputes:
//! 1. the transmittance to the top of the atmosphere `T(r, μ)` (Bruneton & Neyret
//!    2008 eq. 2; zero for rays that hit the ground, with the sun's disc fading
//!    across the local horizon);
//! 2. Hillaire 2020's multiple-scattering term Ψ_ms (its eqs. 5–10: second-order
//!    isotropic light `L_2` from 64 directions, including the ground's reflection,
//!    and the infinite series of higher orders `1 / (1 − f_ms)`) at a set of
//!    altitudes for this sun;
//! 3. the sky seen from the ground: single scattering plus `σ_s · Ψ_ms`, marched
//!    along view rays (Hillaire eq. 11), on a grid of view elevation (non-linear,
//!    `u = √(e / 90°)`, so the bright horizon gets rows) × azimuth relative to the
//!    sun (the sky is symmetric about the sun's vertical plane).
//!
//! Units: radiance in the renderer's units (a white Lambertian surface facing a
//! clear sun reads about 1): the sun's irradiance at the top of the atmosphere is
//! `π · sun_intensity`, so a white surface under it reads `sun_intensity`. The air is
//! lit by that same irradiance (there is no display calibration inside the physics:
//! how bright a picture is comes from the tone map's exposure,
//! [`crate::render::light::EXPOSURE`]).
//!
//! Why not a crate: the one Rust sky crate found (`hw-skymodel`, Hosek–Wilkie 2012)
//! is f32 by design, has no sun radiance or transmittance and no model below the
//! horizon (night, twilight), and no aerial perspective. This module is f64,
//! deterministic (fixed sample counts, no threads, no globals) and gives the sun
//! colour, the sky, the ambient and the aerial perspective from one atmosphere.
//!
//! The observer of the sky table stands at sea level; directions below the horizon
//! see the horizon's radiance. A night floor ([`NIGHT_RADIANCE`], a dim blue of
//! starlight and airglow exaggerated for display) keeps night pictures from being
//! pure black.

use std::f64::consts::PI;
use std::sync::{Arc, Mutex};

/// How many skies [`Sky::shared`] keeps (a few suns in flight at once).
pub const SHARED_SKIES: usize = 16;

/// Ground radius, metres (Hillaire 2020 Table 1).
pub const GROUND_RADIUS: f64 = 6_360_000.0;
/// Radius of the top of the atmosphere, metres.
pub const TOP_RADIUS: f64 = 6_420_000.0;
/// Rayleigh scattering at sea level per metre for (680, 550, 440) nm.
pub const RAYLEIGH_SCATTERING: [f64; 3] = [5.802e-6, 13.558e-6, 33.1e-6];
/// Rayleigh density scale height, metres.
pub const RAYLEIGH_SCALE_HEIGHT: f64 = 8_000.0;
/// Mie scattering and extinction at sea level per metre.
pub const MIE_SCATTERING: f64 = 3.996e-6;
/// Mie extinction at sea level per metre (scattering plus absorption).
pub const MIE_EXTINCTION: f64 = 4.40e-6;
/// Mie density scale height, metres.
pub const MIE_SCALE_HEIGHT: f64 = 1_200.0;
/// Mie phase asymmetry (Cornette–Shanks).
pub const MIE_G: f64 = 0.8;
/// Ozone absorption at the peak of its layer, per metre.
pub const OZONE_ABSORPTION: [f64; 3] = [0.650e-6, 1.881e-6, 0.085e-6];
/// Reflectance of the ground (linear RGB): what the background draws below the horizon.
pub const GROUND_ALBEDO: [f64; 3] = [0.26, 0.25, 0.21];
/// Radiance added to every sky direction so a night sky is not pure black.
pub const NIGHT_RADIANCE: [f64; 3] = [0.0015, 0.0022, 0.0045];
/// Angular radius of the sun's disc, radians (0.2666°).
pub const SUN_ANGULAR_RADIUS: f64 = 0.004_653;
/// Altitude at which [`Sky::sun_rgb_at`] is usually is taken: the middle of typical cloud layers.
pub const SUN_REFERENCE_ALTITUDE: f64 = 2_000.0;

/// Sky table: rows over view elevation, columns over azimuth relative to the sun.
pub const SKY_ROWS: usize = 48;
/// Columns of the sky table (azimuth relative to the sun).
pub const SKY_COLUMNS: usize = 48;
/// Altitudes of the multiple-scattering table, metres (0 to 60 km, denser low).
const MS_ALTITUDES: usize = 12;
/// Transmittance table size: altitude × angle above the local horizon.
const T_ROWS: usize = 24;
const T_COLUMNS: usize = 64;
/// Samples along a ray when building the tables.
const TRANSMITTANCE_STEPS: usize = 40;
const VIEW_STEPS: usize = 32;
const MS_STEPS: usize = 20;
const MS_DIRECTIONS: usize = 64;
/// The sun transmittance by altitude that aerial perspective reads: every
/// [`SUN_TABLE_STEP`] metres from 0 to `(SUN_TABLE_LEN − 1) · SUN_TABLE_STEP`.
pub const SUN_TABLE_LEN: usize = 41;
/// Metres between entries of the sun transmittance table.
pub const SUN_TABLE_STEP: f64 = 500.0;

/// Rayleigh phase function normalised over the sphere: `3/(16π) (1 + μ²)`.
pub fn rayleigh_phase(mu: f64) -> f64 {
    3.0 / (16.0 * PI) * (1.0 + mu * mu)
}

/// Cornette & Shanks 1992 phase function normalised over the sphere (their eq. 4;
/// Bruneton 2017): `3/(8π) (1 − g²)(1 + μ²) / ((2 + g²)(1 + g² − 2gμ)^{3/2})`.
pub fn mie_phase(mu: f64, g: f64) -> f64 {
    let g2 = g * g;
    let d = (1.0 + g2 - 2.0 * g * mu).max(1e-12);
    3.0 / (8.0 * PI) * (1.0 - g2) * (1.0 + mu * mu) / ((2.0 + g2) * d * d.sqrt())
}

/// Scattering and extinction of the air at altitude `h` (metres above the ground).
#[derive(Clone, Copy, Debug)]
struct Medium {
    rayleigh: [f64; 3],
    mie: f64,
    extinction: [f64; 3],
}

fn medium(h: f64) -> Medium {
    let h = h.max(0.0);
    let rho_r = (-h / RAYLEIGH_SCALE_HEIGHT).exp();
    let rho_m = (-h / MIE_SCALE_HEIGHT).exp();
    let rho_o = (1.0 - (h - 25_000.0).abs() / 15_000.0).max(0.0);
    let rayleigh = RAYLEIGH_SCATTERING.map(|b| b * rho_r);
    let mie = MIE_SCATTERING * rho_m;
    let extinction = [0, 1, 2].map(|c| rayleigh[c] + MIE_EXTINCTION * rho_m + OZONE_ABSORPTION[c] * rho_o);
    Medium {
        rayleigh,
        mie,
        extinction,
    }
}

/// Distance from radius `r` along a ray of zenith cosine `mu` to the sphere of
/// radius `radius` (outgoing intersection), or `None` when the ray misses it.
fn distance_to_sphere(r: f64, mu: f64, radius: f64) -> Option<f64> {
    let disc = r * r * (mu * mu - 1.0) + radius * radius;
    if disc < 0.0 {
        return None;
    }
    Some((-r * mu + disc.sqrt()).max(0.0))
}

/// Distance to the ground along (r, μ), if the ray hits it.
fn distance_to_ground(r: f64, mu: f64) -> Option<f64> {
    if mu >= 0.0 {
        return None;
    }
    let disc = r * r * (mu * mu - 1.0) + GROUND_RADIUS * GROUND_RADIUS;
    if disc < 0.0 {
        return None;
    }
    let t = -r * mu - disc.sqrt();
    if t >= 0.0 { Some(t) } else { None }
}

/// Cosine of the zenith angle of the horizon seen from radius `r`.
fn horizon_mu(r: f64) -> f64 {
    let s = (GROUND_RADIUS / r).min(1.0);
    -(1.0 - s * s).max(0.0).sqrt()
}

/// Optical depth (per channel) from radius `r` along zenith cosine `mu` to the top
/// of the atmosphere, by the midpoint rule (ignoring the ground).
fn optical_depth_to_top(r: f64, mu: f64, steps: usize) -> [f64; 3] {
    let len = distance_to_sphere(r, mu, TOP_RADIUS).unwrap_or(0.0);
    let dt = len / steps as f64;
    let mut tau = [0.0; 3];
    for i in 0..steps {
        let t = (i as f64 + 0.5) * dt;
        let ri = (r * r + t * t + 2.0 * r * t * mu).sqrt();
        let m = medium(ri - GROUND_RADIUS);
        for (t, e) in tau.iter_mut().zip(m.extinction) {
            *t += e * dt;
        }
    }
    tau
}

/// Transmittance to the top of the atmosphere, tabulated over altitude (rows,
/// `h = H_top · u²`) and the angle above the local horizon (columns,
/// `μ = μ_h + (1 − μ_h) v²`, so grazing rays get columns).
#[derive(Clone, Debug, PartialEq)]
struct TransmittanceTable {
    values: Vec<[f64; 3]>,
}

impl TransmittanceTable {
    /// The table, computed once per process: it depends on no sun or setting (a
    /// pure function of the constants above, so the same bytes everywhere; the
    /// splat profile table of `shade.rs` is kept the same way).
    fn shared() -> &'static TransmittanceTable {
        static TABLE: std::sync::OnceLock<TransmittanceTable> = std::sync::OnceLock::new();
        TABLE.get_or_init(TransmittanceTable::new)
    }

    fn new() -> TransmittanceTable {
        let mut values = Vec::with_capacity(T_ROWS * T_COLUMNS);
        for i in 0..T_ROWS {
            let u = i as f64 / (T_ROWS - 1) as f64;
            let r = GROUND_RADIUS + (TOP_RADIUS - GROUND_RADIUS) * u * u;
            let mu_h = horizon_mu(r);
            for j in 0..T_COLUMNS {
                let v = j as f64 / (T_COLUMNS - 1) as f64;
                let mu = mu_h + (1.0 - mu_h) * v * v;
                values.push(optical_depth_to_top(r, mu, TRANSMITTANCE_STEPS).map(|t| (-t).exp()));
            }
        }
        TransmittanceTable { values }
    }

    /// Transmittance from radius `r` toward zenith cosine `mu` to space, with the
    /// sun's disc fading out across the local horizon (0 once wholly below it).
    fn sun(&self, r: f64, mu: f64) -> [f64; 3] {
        let r = r.clamp(GROUND_RADIUS, TOP_RADIUS);
        let mu = mu.clamp(-1.0, 1.0);
        let mu_h = horizon_mu(r);
        // The disc's fade over the sun's centre's elevation above the local horizon
        // within ±SUN_ANGULAR_RADIUS; outside that band (compared on cosines:
        // sin(asin μ_h ± ρ) = μ_h cos ρ ± (R/r) sin ρ, as √(1 − μ_h²) = R/r) no asin.
        let (c, sr) = (SUN_ANGULAR_RADIUS.cos(), SUN_ANGULAR_RADIUS.sin() * GROUND_RADIUS / r);
        let visible = if mu >= mu_h * c + sr {
            1.0
        } else if mu <= mu_h * c - sr {
            0.0
        } else {
            smoothstep(-SUN_ANGULAR_RADIUS, SUN_ANGULAR_RADIUS, mu.asin() - mu_h.asin())
        };
        if visible <= 0.0 {
            return [0.0; 3];
        }
        let u = ((r - GROUND_RADIUS) / (TOP_RADIUS - GROUND_RADIUS)).max(0.0).sqrt();
        let v = ((mu.max(mu_h) - mu_h) / (1.0 - mu_h)).max(0.0).sqrt();
        bilinear(&self.values, T_ROWS, T_COLUMNS, u, v).map(|t| t * visible)
    }
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Bilinear look-up at fractional coordinates `u`, `v` in [0, 1] (clamped) of a
/// row-major table.
fn bilinear(values: &[[f64; 3]], rows: usize, cols: usize, u: f64, v: f64) -> [f64; 3] {
    let y = (if u.is_finite() { u } else { 0.0 }).clamp(0.0, 1.0) * (rows - 1) as f64;
    let x = (if v.is_finite() { v } else { 0.0 }).clamp(0.0, 1.0) * (cols - 1) as f64;
    let (y0, x0) = ((y as usize).min(rows - 2), (x as usize).min(cols - 2));
    let (fy, fx) = (y - y0 as f64, x - x0 as f64);
    let at = |r: usize, c: usize| values[r * cols + c];
    [0, 1, 2].map(|k| {
        let a = at(y0, x0)[k] * (1.0 - fx) + at(y0, x0 + 1)[k] * fx;
        let b = at(y0 + 1, x0)[k] * (1.0 - fx) + at(y0 + 1, x0 + 1)[k] * fx;
        a * (1.0 - fy) + b * fy
    })
}

/// Altitude of the multiple-scattering table's entry `i`, metres.
fn ms_altitude(i: usize) -> f64 {
    let u = i as f64 / (MS_ALTITUDES - 1) as f64;
    (TOP_RADIUS - GROUND_RADIUS) * u * u
}

/// A deterministic, nearly uniform set of unit directions (spherical Fibonacci).
fn sphere_directions(n: usize) -> Vec<[f64; 3]> {
    let golden = PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let s = (1.0 - z * z).max(0.0).sqrt();
            let phi = golden * i as f64;
            [s * phi.cos(), s * phi.sin(), z]
        })
        .collect()
}

/// The clear sky for one sun: tables built once, read per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Sky {
    /// Unit vector toward the sun.
    sun_dir: [f64; 3],
    /// Sun irradiance at the top of the atmosphere, in units where a white surface
    /// facing it reads `sun_intensity` (that is `π · sun_intensity` W-like units).
    irradiance: f64,
    transmittance: &'static TransmittanceTable,
    /// Ψ_ms (Hillaire 2020 eq. 10) per altitude of [`ms_altitude`], for this sun.
    multiple: Vec<[f64; 3]>,
    /// Sky radiance seen from the ground, SKY_ROWS × SKY_COLUMNS (night floor excluded).
    table: Vec<[f64; 3]>,
    /// Sun transmittance at altitudes `i · SUN_TABLE_STEP` (for aerial perspective).
    sun_table: Vec<[f64; 3]>,
}

impl Sky {
    /// [`Sky::new`], shared: the last [`SHARED_SKIES`] skies built are kept, keyed by
    /// the exact bits of their inputs, so the tiles of one sun bucket (every tile a
    /// request shades) build the tables once instead of once each (~15 ms). The value
    /// is the same as `Sky::new`'s whichever thread built it first.
    pub fn shared(sun_dir: [f64; 3], sun_intensity: f64) -> Arc<Sky> {
        type Key = ([u64; 3], u64);
        static CACHE: Mutex<Vec<(Key, Arc<Sky>)>> = Mutex::new(Vec::new());
        let key: Key = (sun_dir.map(f64::to_bits), sun_intensity.to_bits());
        let found = CACHE
            .lock()
            .ok()
            .and_then(|c| c.iter().find(|(k, _)| *k == key).map(|(_, s)| s.clone()));
        if let Some(sky) = found {
            return sky;
        }
        let sky = Arc::new(Sky::new(sun_dir, sun_intensity));
        if let Ok(mut c) = CACHE.lock()
            && !c.iter().any(|(k, _)| *k == key)
        {
            if c.len() >= SHARED_SKIES {
                c.remove(0);
            }
            c.push((key, sky.clone()));
        }
        sky
    }

    /// The sky for the sun in direction `sun_dir` (unit, z up) with `sun_intensity`
    /// (the renderer's units: a white surface facing the sun above the atmosphere
    /// reads this). Non-finite or negative intensity counts as 0.
    pub fn new(sun_dir: [f64; 3], sun_intensity: f64) -> Sky {
        let intensity = if sun_intensity.is_finite() {
            sun_intensity.max(0.0)
        } else {
            0.0
        };
        let norm = (sun_dir[0] * sun_dir[0] + sun_dir[1] * sun_dir[1] + sun_dir[2] * sun_dir[2]).sqrt();
        let sun_dir = if norm.is_finite() && norm > 0.0 {
            sun_dir.map(|v| v / norm)
        } else {
            [0.0, 0.0, 1.0]
        };
        let mut sky = Sky {
            sun_dir,
            irradiance: PI * intensity,
            transmittance: TransmittanceTable::shared(),
            multiple: Vec::new(),
            table: Vec::new(),
            sun_table: Vec::new(),
        };
        sky.sun_table = (0..SUN_TABLE_LEN)
            .map(|i| sky.sun_transmittance(GROUND_RADIUS + i as f64 * SUN_TABLE_STEP, sun_dir[2]))
            .collect();
        sky.multiple = (0..MS_ALTITUDES)
            .map(|i| sky.multiple_scattering_at(ms_altitude(i)))
            .collect();
        let mut table = Vec::with_capacity(SKY_ROWS * SKY_COLUMNS);
        for i in 0..SKY_ROWS {
            let u = i as f64 / (SKY_ROWS - 1) as f64;
            let e = u * u * PI / 2.0;
            for j in 0..SKY_COLUMNS {
                let phi = j as f64 / (SKY_COLUMNS - 1) as f64 * PI;
                let d = sky.local_direction(e, phi);
                table.push(sky.march_view(d));
            }
        }
        sky.table = table;
        sky
    }

    /// The view direction of elevation `e` and azimuth `phi` from the sun's azimuth.
    fn local_direction(&self, e: f64, phi: f64) -> [f64; 3] {
        let s = self.sun_dir;
        let h = (s[0] * s[0] + s[1] * s[1]).sqrt();
        // Horizontal unit vector toward the sun (north when the sun is at the zenith).
        let (fx, fy) = if h > 1e-12 { (s[0] / h, s[1] / h) } else { (0.0, 1.0) };
        let (ce, se) = (e.cos(), e.sin());
        let (cp, sp) = (phi.cos(), phi.sin());
        // Rotate the sun's horizontal direction by phi (clockwise: the side is symmetric).
        [ce * (fx * cp + fy * sp), ce * (fy * cp - fx * sp), se]
    }

    /// Sun transmittance from a point at radius `r` whose local zenith cosine toward
    /// the sun is `mu_s`.
    fn sun_transmittance(&self, r: f64, mu_s: f64) -> [f64; 3] {
        self.transmittance.sun(r, mu_s)
    }

    /// Ψ_ms at altitude `h` by linear interpolation in the table.
    fn multiple_at(&self, h: f64) -> [f64; 3] {
        let u = (h.max(0.0) / (TOP_RADIUS - GROUND_RADIUS)).min(1.0).sqrt();
        let x = u * (MS_ALTITUDES - 1) as f64;
        let i = (x as usize).min(MS_ALTITUDES - 2);
        let f = x - i as f64;
        [0, 1, 2].map(|c| self.multiple[i][c] * (1.0 - f) + self.multiple[i + 1][c] * f)
    }

    /// Hillaire 2020 eqs. 5–10 at altitude `h` (sun zenith as seen from the ground
    /// below): `Ψ_ms = L_2 / (1 − f_ms)`, second-order light from a uniform set of
    /// directions with an isotropic phase, the ground reflecting Lambertianly.
    fn multiple_scattering_at(&self, h: f64) -> [f64; 3] {
        let r0 = GROUND_RADIUS + h.clamp(0.0, TOP_RADIUS - GROUND_RADIUS - 1.0);
        let s = self.sun_dir;
        let iso = 1.0 / (4.0 * PI);
        let mut l2 = [0.0; 3];
        let mut fms = [0.0; 3];
        for d in sphere_directions(MS_DIRECTIONS) {
            let mu = d[2];
            let ground = distance_to_ground(r0, mu);
            let len = ground.unwrap_or_else(|| distance_to_sphere(r0, mu, TOP_RADIUS).unwrap_or(0.0));
            let dt = len / MS_STEPS as f64;
            let mut trans = [1.0; 3];
            let mut lum = [0.0; 3];
            let mut f = [0.0; 3];
            for k in 0..MS_STEPS {
                let t = (k as f64 + 0.5) * dt;
                let p = [d[0] * t, d[1] * t, r0 + d[2] * t];
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let m = medium(r - GROUND_RADIUS);
                let mu_s = (p[0] * s[0] + p[1] * s[1] + p[2] * s[2]) / r;
                let ts = self.sun_transmittance(r, mu_s);
                for c in 0..3 {
                    let half = (-m.extinction[c] * dt * 0.5).exp();
                    let tm = trans[c] * half;
                    let sigma_s = m.rayleigh[c] + m.mie;
                    lum[c] += tm * sigma_s * iso * self.irradiance * ts[c] * dt;
                    f[c] += tm * sigma_s * dt;
                    trans[c] = tm * half;
                }
            }
            if let Some(tg) = ground {
                let p = [d[0] * tg, d[1] * tg, r0 + d[2] * tg];
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                let mu_s = (p[0] * s[0] + p[1] * s[1] + p[2] * s[2]) / r;
                let ts = self.sun_transmittance(r, mu_s);
                for c in 0..3 {
                    lum[c] += trans[c] * self.irradiance * ts[c] * mu_s.max(0.0) * GROUND_ALBEDO[c] / PI;
                }
            }
            for c in 0..3 {
                l2[c] += lum[c] / MS_DIRECTIONS as f64;
                fms[c] += f[c] / MS_DIRECTIONS as f64;
            }
        }
        [0, 1, 2].map(|c| l2[c] / (1.0 - fms[c].min(0.99)))
    }

    /// Single plus multiple scattering along a view ray from sea level (Hillaire 2020
    /// eq. 11), samples spaced quadratically so the dense low air gets most of them.
    fn march_view(&self, d: [f64; 3]) -> [f64; 3] {
        let r0 = GROUND_RADIUS;
        let mu = d[2].max(0.0);
        let len = distance_to_sphere(r0, mu, TOP_RADIUS).unwrap_or(0.0);
        let s = self.sun_dir;
        let cos = d[0] * s[0] + d[1] * s[1] + d[2] * s[2];
        let (pr, pm) = (rayleigh_phase(cos), mie_phase(cos, MIE_G));
        let mut trans = [1.0; 3];
        let mut lum = [0.0; 3];
        for k in 0..VIEW_STEPS {
            let (a, b) = (k as f64 / VIEW_STEPS as f64, (k + 1) as f64 / VIEW_STEPS as f64);
            let (ta, tb) = (len * a * a, len * b * b);
            let (t, dt) = (0.5 * (ta + tb), tb - ta);
            let p = [d[0] * t, d[1] * t, r0 + mu * t];
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            let h = r - GROUND_RADIUS;
            let m = medium(h);
            let mu_s = (p[0] * s[0] + p[1] * s[1] + p[2] * s[2]) / r;
            let ts = self.sun_transmittance(r, mu_s);
            let ms = self.multiple_at(h);
            for c in 0..3 {
                let half = (-m.extinction[c] * dt * 0.5).exp();
                let tm = trans[c] * half;
                let single = (m.rayleigh[c] * pr + m.mie * pm) * self.irradiance * ts[c];
                let multi = (m.rayleigh[c] + m.mie) * ms[c];
                lum[c] += tm * (single + multi) * dt;
                trans[c] = tm * half;
            }
        }
        lum
    }

    /// Radiance of the clear sky along `dir` (unit, z up) seen from the ground;
    /// directions below the horizon see the horizon. Includes the night floor.
    pub fn radiance(&self, dir: [f64; 3]) -> [f64; 3] {
        let (u, v) = self.table_coords(dir);
        let l = bilinear(&self.table, SKY_ROWS, SKY_COLUMNS, u, v);
        [0, 1, 2].map(|c| l[c] + NIGHT_RADIANCE[c])
    }

    /// Table coordinates in [0, 1]² of a direction: `(√(e / 90°), φ / 180°)`.
    fn table_coords(&self, dir: [f64; 3]) -> (f64, f64) {
        let n = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
        if !(n.is_finite() && n > 0.0) {
            return (0.0, 0.0);
        }
        let d = dir.map(|v| v / n);
        let e = d[2].clamp(0.0, 1.0).asin();
        let s = self.sun_dir;
        let (hd, hs) = ((d[0] * d[0] + d[1] * d[1]).sqrt(), (s[0] * s[0] + s[1] * s[1]).sqrt());
        let phi = if hd > 1e-12 && hs > 1e-12 {
            ((d[0] * s[0] + d[1] * s[1]) / (hd * hs)).clamp(-1.0, 1.0).acos()
        } else if hd > 1e-12 {
            // Sun at the zenith or nadir: the table's reference azimuth is north.
            (d[1] / hd).clamp(-1.0, 1.0).acos()
        } else {
            0.0
        };
        ((e / (PI / 2.0)).sqrt(), phi / PI)
    }

    /// Direct sun radiance (white-surface units, linear RGB) reaching altitude `h`:
    /// `sun_intensity · T(h, sun)`, reddened by the air on the way, 0 once the sun's
    /// disc is below the local horizon.
    pub fn sun_rgb_at(&self, h: f64) -> [f64; 3] {
        let h = if h.is_finite() { h } else { 0.0 };
        let t = self.sun_transmittance(GROUND_RADIUS + h.max(0.0), self.sun_dir[2]);
        t.map(|v| v * self.irradiance / PI)
    }

    /// Uniform-equivalent radiance of the sky's upper hemisphere, `E_sky / π` (E the
    /// irradiance on an upward-facing surface), by midpoint quadrature of the table.
    pub fn ambient_above(&self) -> [f64; 3] {
        let (ne, np) = (32, 32);
        let mut e_sky = [0.0; 3];
        for i in 0..ne {
            let e = (i as f64 + 0.5) / ne as f64 * PI / 2.0;
            let de = PI / 2.0 / ne as f64;
            for j in 0..np {
                let phi = (j as f64 + 0.5) / np as f64 * PI;
                let dphi = PI / np as f64;
                let l = self.radiance(self.local_direction(e, phi));
                // Both sides of the sun's plane: ×2. dω = cos e de dφ, cosθ = sin e.
                let w = 2.0 * e.sin() * e.cos() * de * dphi;
                for c in 0..3 {
                    e_sky[c] += l[c] * w;
                }
            }
        }
        e_sky.map(|v| v / PI)
    }

    /// Unit vector toward the sun.
    pub fn sun_dir(&self) -> [f64; 3] {
        self.sun_dir
    }

    /// The sky table, row-major: rows `i` over view elevation `e = 90° · (i / (rows−1))²`,
    /// columns `j` over azimuth from the sun `φ = 180° · j / (cols−1)` (night floor
    /// excluded).
    pub fn table(&self) -> &[[f64; 3]] {
        &self.table
    }

    /// Ψ_ms at altitudes `h_i = 60 km · (i / (n − 1))²` (for clients that apply aerial
    /// perspective themselves: linear in `√(h / 60 km)`).
    pub fn multiple_table(&self) -> &[[f64; 3]] {
        &self.multiple
    }

    /// Sun transmittance at altitudes `i · SUN_TABLE_STEP` (linear in between,
    /// clamped at the ends), what [`Sky::aerial`] reads.
    pub fn sun_table(&self) -> &[[f64; 3]] {
        &self.sun_table
    }

    fn sun_table_at(&self, h: f64) -> [f64; 3] {
        let x = (h.max(0.0) / SUN_TABLE_STEP).min((SUN_TABLE_LEN - 1) as f64);
        let i = (x as usize).min(SUN_TABLE_LEN - 2);
        let f = x - i as f64;
        [0, 1, 2].map(|c| self.sun_table[i][c] * (1.0 - f) + self.sun_table[i + 1][c] * f)
    }

    /// The irradiance the air's scattering is lit by: the sun's, `π · sun_intensity`,
    /// the same the ground and the clouds see.
    pub fn scatter_irradiance(&self) -> f64 {
        self.irradiance
    }

    /// Aerial perspective between an eye and a point (world metres, z = altitude):
    /// the air's transmittance `T` and the light it scatters toward the eye `L_in`,
    /// so a surface of radiance `L` there is seen as `L · T + L_in`.
    ///
    /// Hoffman & Preetham 2002 ("Rendering outdoor light scattering in real time",
    /// eqs. 1–3: `L = L₀ F_ex(s) + L_in(s, θ)`, `L_in = β_sc(θ)/β_ex · E_sun (1 − F_ex)`),
    /// with this atmosphere's coefficients: the path is straight over a flat Earth,
    /// its optical depth exact for the exponential profiles (`∫ρ = d · H (e^{−z₀/H} −
    /// e^{−z₁/H}) / (z₁ − z₀)`), and the source per unit extinction — sun single
    /// scattering times the sun's transmittance, plus `σ_s Ψ_ms` — taken at the
    /// path's middle altitude (the sun's transmittance from [`Sky::sun_table`]).
    /// Ozone (above 10 km) is left out. Altitudes are clamped
    /// to 0..60 km; finite for any input.
    pub fn aerial(&self, eye: [f64; 3], point: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        self.aerial_lit(eye, point, 1.0)
    }

    /// As [`Sky::aerial`] with the sun's single-scattering term scaled by
    /// `sun_visibility` in [0, 1]: the mean fraction of the path that cloud does not
    /// shadow (under a deck the air below it is in shade).
    pub fn aerial_lit(&self, eye: [f64; 3], point: [f64; 3], sun_visibility: f64) -> ([f64; 3], [f64; 3]) {
        let vis = if sun_visibility.is_finite() {
            sun_visibility.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let v = [point[0] - eye[0], point[1] - eye[1], point[2] - eye[2]];
        let d = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if !(d.is_finite() && d > 0.0) {
            return ([1.0; 3], [0.0; 3]);
        }
        let top = TOP_RADIUS - GROUND_RADIUS;
        let (z0, z1) = (eye[2].clamp(0.0, top), point[2].clamp(0.0, top));
        let mean = |scale: f64| {
            let dz = z1 - z0;
            if dz.abs() < 1e-3 * scale {
                (-(0.5 * (z0 + z1)) / scale).exp()
            } else {
                scale * ((-z0 / scale).exp() - (-z1 / scale).exp()) / dz
            }
        };
        let (m_r, m_m) = (mean(RAYLEIGH_SCALE_HEIGHT), mean(MIE_SCALE_HEIGHT));
        let dir = v.map(|x| x / d);
        let s = self.sun_dir;
        let cos = dir[0] * s[0] + dir[1] * s[1] + dir[2] * s[2];
        let (pr, pm) = (rayleigh_phase(cos), mie_phase(cos, MIE_G));
        let h = 0.5 * (z0 + z1);
        let ts = self.sun_table_at(h);
        let ms = self.multiple_at(h);
        let mut trans = [1.0; 3];
        let mut inscatter = [0.0; 3];
        for c in 0..3 {
            let sr = RAYLEIGH_SCATTERING[c] * m_r;
            let sm = MIE_SCATTERING * m_m;
            let ext = sr + MIE_EXTINCTION * m_m;
            let t = (-ext * d).exp();
            let source = (sr * pr + sm * pm) * self.irradiance * ts[c] * vis + (sr + sm) * ms[c];
            trans[c] = t;
            inscatter[c] = if ext > 0.0 { source / ext * (1.0 - t) } else { 0.0 };
        }
        (trans, inscatter)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sun(el_deg: f64) -> [f64; 3] {
        let (az, el) = (30f64.to_radians(), el_deg.to_radians());
        [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()]
    }

    fn luminance(c: [f64; 3]) -> f64 {
        0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
    }

    fn dir(el_deg: f64, az_deg: f64) -> [f64; 3] {
        let (az, el) = (az_deg.to_radians(), el_deg.to_radians());
        [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()]
    }

    /// Rayleigh optical depth of the whole atmosphere at the zenith against Hansen &
    /// Travis 1974 (eq. 2.32: τ_R = 0.008569 λ⁻⁴ (1 + 0.0113 λ⁻² + 0.00013 λ⁻⁴), λ in
    /// µm, the fit Bucholtz 1995 compares with): 0.0409, 0.0973, 0.2428 at 680, 550,
    /// 440 nm. The Bruneton constants are within 15 % of it.
    #[test]
    fn a_shared_sky_is_the_sky_it_stands_for() {
        let sun: [f64; 3] = [0.3, -0.5, 0.81];
        let norm = sun[0] * sun[0] + sun[1] * sun[1] + sun[2] * sun[2];
        let dir = sun.map(|c| c / norm.sqrt());
        let (a, b) = (Sky::shared(dir, 2.0), Sky::shared(dir, 2.0));
        assert!(Arc::ptr_eq(&a, &b), "the second call built its own");
        let fresh = Sky::new(dir, 2.0);
        for v in [[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 1.0, 0.0], [0.0, 0.6, -0.8]] {
            assert_eq!(a.radiance(v), fresh.radiance(v));
        }
        assert_eq!(a.ambient_above(), fresh.ambient_above());
        // Another intensity is another sky, and the cache stays bounded.
        assert!(!Arc::ptr_eq(&a, &Sky::shared(dir, 3.0)));
        for i in 0..2 * SHARED_SKIES {
            let _ = Sky::shared(dir, 10.0 + i as f64);
        }
    }

    #[test]
    fn rayleigh_zenith_optical_depth_matches_hansen_travis() {
        let n = 4000;
        let dt = (TOP_RADIUS - GROUND_RADIUS) / n as f64;
        let mut tau = [0.0; 3];
        for i in 0..n {
            let m = medium((i as f64 + 0.5) * dt);
            for (t, r) in tau.iter_mut().zip(m.rayleigh) {
                *t += r * dt;
            }
        }
        let hansen = |l: f64| 0.008569 * l.powi(-4) * (1.0 + 0.0113 * l.powi(-2) + 0.00013 * l.powi(-4));
        for (c, l) in [0.68, 0.55, 0.44].into_iter().enumerate() {
            let want = hansen(l);
            assert!((tau[c] / want - 1.0).abs() < 0.15, "channel {c}: {} vs {want}", tau[c]);
        }
        assert!((tau[1] - 0.0973).abs() < 0.015, "{tau:?}");
        // The table's integrator agrees with the closed form β·H·(1 − e^{−60/8}).
        let full = optical_depth_to_top(GROUND_RADIUS, 1.0, 400);
        let closed = RAYLEIGH_SCATTERING[1] * RAYLEIGH_SCALE_HEIGHT * (1.0 - (-60.0f64 / 8.0).exp())
            + MIE_EXTINCTION * MIE_SCALE_HEIGHT
            + OZONE_ABSORPTION[1] * 15_000.0;
        assert!((full[1] / closed - 1.0).abs() < 1e-3, "{} vs {closed}", full[1]);
    }

    #[test]
    fn noon_sky_is_blue_and_brighter_at_the_horizon() {
        let sky = Sky::new(sun(60.0), 1.2);
        let zenith = sky.radiance([0.0, 0.0, 1.0]);
        // Away from the sun, at 3° above the horizon.
        let horizon = sky.radiance(dir(3.0, 210.0));
        let blueness = |c: [f64; 3]| c[2] / c[0];
        assert!(blueness(zenith) > blueness(horizon), "{zenith:?} {horizon:?}");
        assert!(zenith[2] > zenith[1] && zenith[1] > zenith[0], "{zenith:?}");
        assert!(luminance(horizon) > luminance(zenith), "{zenith:?} {horizon:?}");
        // Scale: the zenith is a sky blue after the display mapping, neither white
        // nor navy: blue channel tone-mapped in 0.45..0.85, red well below it.
        let tm = |x: f64| crate::render::light::tone_map(x);
        let (r, b) = (tm(zenith[0]), tm(zenith[2]));
        assert!((0.45..0.85).contains(&b) && r < 0.75 * b, "zenith {zenith:?} → {r} {b}");
    }

    #[test]
    fn sunset_is_red_and_night_is_dark() {
        let high = Sky::new(sun(60.0), 1.2);
        let low = Sky::new(sun(2.0), 1.2);
        let red = |c: [f64; 3]| c[0] / c[2];
        let (sh, sl) = (
            high.sun_rgb_at(SUN_REFERENCE_ALTITUDE),
            low.sun_rgb_at(SUN_REFERENCE_ALTITUDE),
        );
        assert!(red(sl) > 2.0 * red(sh), "{sh:?} {sl:?}");
        assert!(sl[0] > sl[1] && sl[1] > sl[2], "{sl:?}");
        // The sky near the low sun is warm (red over blue larger than at noon).
        let near_low = low.radiance(dir(2.0, 40.0));
        let near_high = high.radiance(dir(2.0, 40.0));
        assert!(red(near_low) > red(near_high), "{near_low:?} {near_high:?}");
        // At −6° the sun is gone from the clouds' altitude; at −20° the sky is the floor.
        assert_eq!(Sky::new(sun(-6.0), 1.2).sun_rgb_at(SUN_REFERENCE_ALTITUDE), [0.0; 3]);
        let night = Sky::new(sun(-20.0), 1.2);
        let z = night.radiance([0.0, 0.0, 1.0]);
        for c in 0..3 {
            assert!(z[c] < 1.5 * NIGHT_RADIANCE[c], "{z:?}");
        }
        // A noon-facing white surface reads about 1 (the renderer's units).
        let s = Sky::new(sun(90.0), 1.2).sun_rgb_at(0.0);
        assert!(s.iter().all(|&v| (0.85..1.2).contains(&v)), "{s:?}");
    }

    #[test]
    fn ambient_increases_with_elevation_and_everything_is_finite() {
        let mut last = -1.0;
        for el in [-90.0, -30.0, -12.0, -6.0, -3.0, 0.0, 3.0, 10.0, 30.0, 60.0, 90.0] {
            let sky = Sky::new(sun(el), 1.2);
            let a = luminance(sky.ambient_above());
            assert!(a >= last - 1e-12, "el {el}: {a} after {last}");
            last = a;
            for d in [
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0],
                [0.0, 0.0, -1.0],
                [0.0, 0.0, 0.0],
                [f64::NAN, 1.0, 0.0],
            ] {
                assert!(
                    sky.radiance(d).iter().all(|v| v.is_finite() && *v >= 0.0),
                    "el {el} {d:?}"
                );
            }
            let (t, l) = sky.aerial([0.0, 0.0, 1000.0], [1e9, 0.0, -5.0]);
            assert!(t.iter().chain(&l).all(|v| v.is_finite() && *v >= 0.0), "el {el}");
            assert!(sky.sun_rgb_at(f64::NAN).iter().all(|v| v.is_finite()));
        }
        // Noon ambient: the sky is about a fifth of a white surface under the sun.
        let a = luminance(Sky::new(sun(60.0), 1.2).ambient_above());
        assert!((0.08..0.5).contains(&a), "{a}");
        // Degenerate inputs.
        let s = Sky::new([f64::NAN, 0.0, 0.0], f64::INFINITY);
        assert!(s.radiance([0.0, 0.0, 1.0]).iter().all(|v| v.is_finite()));
    }

    #[test]
    fn sky_is_symmetric_about_the_suns_azimuth() {
        let sky = Sky::new(sun(20.0), 1.2);
        for el in [1.0, 10.0, 45.0, 80.0] {
            for off in [5.0, 40.0, 120.0, 175.0] {
                let a = sky.radiance(dir(el, 30.0 + off));
                let b = sky.radiance(dir(el, 30.0 - off));
                for c in 0..3 {
                    assert!((a[c] - b[c]).abs() <= 1e-12 * a[c].max(1e-9), "{el} {off}: {a:?} {b:?}");
                }
            }
        }
        // Brightest toward the sun (the Mie aureole), at the sun's elevation.
        assert!(luminance(sky.radiance(dir(20.0, 35.0))) > luminance(sky.radiance(dir(20.0, 210.0))));
    }

    #[test]
    fn aerial_perspective_fades_to_haze_with_distance() {
        let sky = Sky::new(sun(40.0), 1.2);
        let eye = [0.0, 0.0, 500.0];
        let (t_near, l_near) = sky.aerial(eye, [0.0, 1000.0, 0.0]);
        let (t_far, l_far) = sky.aerial(eye, [0.0, 100_000.0, 0.0]);
        for c in 0..3 {
            assert!(t_near[c] > t_far[c] && l_near[c] < l_far[c]);
        }
        // Blue is extinguished first (Rayleigh ∝ λ⁻⁴).
        assert!(t_far[2] < t_far[0]);
        // Closed form for a horizontal path at 0 m: T = exp(−(β_R + β_Me) d).
        let (t, _) = sky.aerial([0.0, 0.0, 0.0], [20_000.0, 0.0, 0.0]);
        let want = (-(RAYLEIGH_SCATTERING[1] + MIE_EXTINCTION) * 20_000.0).exp();
        assert!((t[1] - want).abs() < 1e-12, "{} vs {want}", t[1]);
        // The exponential mean along a slant path against a midpoint sum.
        let (t, _) = sky.aerial([0.0, 0.0, 0.0], [0.0, 10_000.0, 5_000.0]);
        let d = (10_000f64.powi(2) + 5_000f64.powi(2)).sqrt();
        let n = 10_000;
        let tau: f64 = (0..n)
            .map(|i| {
                let z = 5_000.0 * (i as f64 + 0.5) / n as f64;
                let m = medium(z);
                m.extinction[1] * d / n as f64
            })
            .sum();
        assert!((t[1] / (-tau).exp() - 1.0).abs() < 1e-6, "{} vs {}", t[1], (-tau).exp());
        // Far hazy ground approaches the horizon sky's brightness (same atmosphere).
        let horizon = sky.radiance(dir(0.5, 200.0));
        let (_, l) = sky.aerial([0.0, 0.0, 10.0], [0.0, -300_000.0, 0.0]);
        let ratio = luminance(l) / luminance(horizon);
        assert!((0.4..1.6).contains(&ratio), "{ratio}: {l:?} vs {horizon:?}");
    }
}
