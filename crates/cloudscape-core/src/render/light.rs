//! The light model shared by both renderers: sun colour, sky ambient, the
//! dual-lobe Henyey–Greenstein phase function, and the sky/ground background, all
//! from one clear-sky atmosphere ([`super::sky`]).
//!
//! Radiance is linear RGB in units where a white surface facing a clear noon sun
//! reads about 1; [`tone_map`] maps it to [0, 1) for display.

use std::sync::Arc;

use super::sky::{GROUND_ALBEDO, SUN_ANGULAR_RADIUS, SUN_REFERENCE_ALTITUDE, Sky};
use super::sun::Sun;

/// Largest |g| used by the phase function: g → ±1 is a delta lobe; clamping keeps
/// the peak finite (at |g| = 0.99 the normalised peak is about 2·10⁴).
pub const MAX_ABS_G: f64 = 0.99;

/// Dual-lobe Henyey–Greenstein phase function (Henyey & Greenstein 1941):
/// `p = mix · HG(g1) + (1 − mix) · HG(g2)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phase {
    /// Forward lobe asymmetry, default 0.7.
    pub g1: f64,
    /// Backward lobe asymmetry, default −0.2.
    pub g2: f64,
    /// Weight of the first lobe in [0, 1], default 0.5.
    pub mix: f64,
}

impl Default for Phase {
    fn default() -> Self {
        Phase {
            g1: 0.7,
            g2: -0.2,
            mix: 0.5,
        }
    }
}

impl Phase {
    /// The phase function times 4π (so an isotropic medium gives 1), for the cosine
    /// of the scattering angle between the light's travel direction and the direction
    /// toward the viewer. Finite and non-negative for any input (g is clamped to
    /// ±[`MAX_ABS_G`], mix to [0, 1], NaN inputs count as 0).
    pub fn eval(&self, cos_theta: f64) -> f64 {
        let c = if cos_theta.is_finite() {
            cos_theta.clamp(-1.0, 1.0)
        } else {
            0.0
        };
        let mix = if self.mix.is_finite() {
            self.mix.clamp(0.0, 1.0)
        } else {
            0.5
        };
        mix * henyey_greenstein(self.g1, c) + (1.0 - mix) * henyey_greenstein(self.g2, c)
    }

    /// Draws the cosine of a scattering angle with density `eval(cos) / 4π` from two
    /// uniform numbers in [0, 1): `u_lobe` picks the first lobe with probability `mix`,
    /// `u` inverts that lobe's CDF ([`sample_henyey_greenstein`]). The same clamping
    /// as [`Phase::eval`], so the sampled density is exactly the evaluated one and an
    /// estimator that samples it needs no phase weight.
    pub fn sample_cos(&self, u_lobe: f64, u: f64) -> f64 {
        let mix = if self.mix.is_finite() {
            self.mix.clamp(0.0, 1.0)
        } else {
            0.5
        };
        let g = if u_lobe < mix { self.g1 } else { self.g2 };
        sample_henyey_greenstein(g, u)
    }
}

/// Inverse CDF of the Henyey–Greenstein distribution of cos θ for `u` in [0, 1]
/// (Henyey & Greenstein 1941; the inversion as in Pharr, Jakob & Humphreys, *Physically
/// Based Rendering* 3rd ed., §15.2.3, with θ measured from the forward direction):
/// `cos θ = (1 + g² − ((1 − g²) / (1 − g + 2g u))²) / 2g`, and `1 − 2u` (isotropic)
/// for |g| < 10⁻³ where that form loses precision. g is clamped as in
/// [`henyey_greenstein`]; the result lies in [−1, 1].
pub fn sample_henyey_greenstein(g: f64, u: f64) -> f64 {
    let g = if g.is_finite() {
        g.clamp(-MAX_ABS_G, MAX_ABS_G)
    } else {
        0.0
    };
    let u = if u.is_finite() { u.clamp(0.0, 1.0) } else { 0.5 };
    let c = if g.abs() < 1e-3 {
        1.0 - 2.0 * u
    } else {
        let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
        (1.0 + g * g - s * s) / (2.0 * g)
    };
    c.clamp(-1.0, 1.0)
}

/// 4π × the Henyey–Greenstein phase function: `(1 − g²) / (1 + g² − 2g cosθ)^{3/2}`.
pub fn henyey_greenstein(g: f64, cos_theta: f64) -> f64 {
    let g = if g.is_finite() {
        g.clamp(-MAX_ABS_G, MAX_ABS_G)
    } else {
        0.0
    };
    let denom = (1.0 + g * g - 2.0 * g * cos_theta).max(1e-12);
    (1.0 - g * g) / (denom * denom.sqrt())
}

/// Multiple scattering by scattering octaves (Wrenninge, Kulla & Lundqvist 2013,
/// "Oz: the great and volumetric", SIGGRAPH talk, §"Multiple scattering"; used by
/// Hillaire 2016, "Physically based sky, atmosphere and cloud rendering in
/// Frostbite", §5.1.4, and by Schneider's Nubis): the single-scattering sun term is
/// summed over `count` octaves, octave `i` with its extinction scaled by `aⁱ`, its
/// contribution by `bⁱ` and its phase asymmetry by `cⁱ`:
///
/// ```text
/// L_sun = Σ_{i<N} bⁱ · sun · p(θ; cⁱ·g) · exp(−aⁱ · τ_sun)
/// ```
///
/// Each octave stands for light that has scattered more often: it reaches deeper
/// (smaller effective extinction), it is weaker, and it is more isotropic. With
/// `count = 1` the sum is the single-scattering term. Hillaire's energy condition
/// `a ≤ b` keeps the sum of a deep point below that of a shallow one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Octaves {
    /// Number of octaves N (1 = single scattering only), at most [`MAX_OCTAVES`].
    pub count: u32,
    /// Extinction scale per octave `a` in (0, 1].
    pub attenuation: f64,
    /// Contribution scale per octave `b` in [0, 1).
    pub contribution: f64,
    /// Phase-asymmetry scale per octave `c` in [0, 1].
    pub eccentricity: f64,
}

/// Most scattering octaves evaluated.
pub const MAX_OCTAVES: u32 = 8;

impl Default for Octaves {
    /// Three octaves with the attenuation and eccentricity of Wrenninge et al. 2013
    /// and Hillaire 2016 (a = c = ½) and contribution b = ¾: `balanced`'s fit to the
    /// path tracer (`Quality::light` has every preset's). The literature's b = ½
    /// gives deep cloud 0.64–0.79 of the reference's radiance: too little multiple
    /// scattering.
    fn default() -> Self {
        Octaves {
            count: 3,
            attenuation: 0.5,
            contribution: 0.75,
            eccentricity: 0.5,
        }
    }
}

impl Octaves {
    /// Single scattering only.
    pub const SINGLE: Octaves = Octaves {
        count: 1,
        attenuation: 1.0,
        contribution: 0.0,
        eccentricity: 1.0,
    };

    /// The octave constants with every value forced into its range (NaN → the
    /// single-scattering value): `(N, a, b, c)`.
    pub fn sanitised(&self) -> (u32, f64, f64, f64) {
        let fix = |v: f64, lo: f64, hi: f64, nan: f64| if v.is_finite() { v.clamp(lo, hi) } else { nan };
        (
            self.count.clamp(1, MAX_OCTAVES),
            fix(self.attenuation, 1e-3, 1.0, 1.0),
            fix(self.contribution, 0.0, 0.99, 0.0),
            fix(self.eccentricity, 0.0, 1.0, 1.0),
        )
    }

    /// `Σ bⁱ · p(cos θ; cⁱ g) · exp(−aⁱ τ)` for `phase` (p normalised to 1 over 4π
    /// as [`Phase::eval`]). `tau` NaN or negative counts as 0, +∞ gives 0.
    pub fn sun_sum(&self, phase: &Phase, cos_theta: f64, tau: f64) -> f64 {
        let (n, a, b, c) = self.sanitised();
        let tau = if tau > 0.0 { tau } else { 0.0 };
        let (mut w, mut att, mut ecc, mut sum) = (1.0, 1.0, 1.0, 0.0);
        for _ in 0..n {
            let p = Phase {
                g1: phase.g1 * ecc,
                g2: phase.g2 * ecc,
                mix: phase.mix,
            };
            sum += w * p.eval(cos_theta) * (-att * tau).exp();
            w *= b;
            att *= a;
            ecc *= c;
        }
        sum
    }

    /// [`Octaves::sun_sum`] for an isotropic phase (p = 1): the 4π-average of the
    /// sun term, which the pre-shaded billboard colour carries.
    pub fn isotropic_sum(&self, tau: f64) -> f64 {
        let (n, a, b, _) = self.sanitised();
        let tau = if tau > 0.0 { tau } else { 0.0 };
        let (mut w, mut att, mut sum) = (1.0, 1.0, 0.0);
        for _ in 0..n {
            sum += w * (-att * tau).exp();
            w *= b;
            att *= a;
        }
        sum
    }
}

/// The sun term of a pre-shaded (isotropic) billboard colour, `albedo · sun_rgb / 4 ·
/// Σ bⁱ e^{−aⁱ τ_sun}` per channel: the part of the colour a layer above dims
/// ([`Lighting::beneath_layers`]) and the part `billboards.bin`'s colour codes leave
/// out since ALGORITHM_VERSION 15 (`products::keyframe_bin`, which builds it from the
/// header's f32 lighting). The rest of the colour is the ambient.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunTerm {
    scale: [f64; 3],
    octaves: Octaves,
}

impl SunTerm {
    /// Of sun colour `sun_rgb`, albedo `albedo` and the scattering octaves. A value no
    /// light has (NaN, ±∞: damaged bytes) counts as 0 for the sun colour and the
    /// albedo, so the term stays finite; the octaves are sanitised as
    /// [`Octaves::sanitised`] does.
    pub fn new(sun_rgb: [f64; 3], albedo: f64, octaves: Octaves) -> SunTerm {
        let a = if albedo.is_finite() {
            albedo.clamp(0.0, 1.0)
        } else {
            0.0
        };
        SunTerm {
            scale: sun_rgb.map(|c| if c.is_finite() { a * (c * SUN_SCATTER) } else { 0.0 }),
            octaves,
        }
    }

    /// The sun term of each channel at sun optical depth `tau_sun`.
    pub fn at(&self, tau_sun: f64) -> [f64; 3] {
        let s = self.octaves.isotropic_sum(tau_sun);
        self.scale.map(|c| c * s)
    }
}

/// How clouds interact with light. Both renderers read the same values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadingParams {
    /// Extinction coefficient at density 1, per metre (Beer–Lambert σ = extinction · ρ).
    pub extinction: f64,
    /// Single-scattering albedo in [0, 1].
    pub albedo: f64,
    /// The phase function of the cloud droplets.
    pub phase: Phase,
    /// Sun radiance above the atmosphere, in units where a white surface facing it
    /// reads this (~1; the air takes ~10 % of it at a zenith sun).
    pub sun_intensity: f64,
    /// The billboard paths' light model; `None` (the default) takes each preset's own
    /// fit to the path tracer ([`crate::render::Quality::light`]). The volumetric
    /// renderers ignore it.
    pub light: Option<BillboardLight>,
}

impl Default for ShadingParams {
    fn default() -> Self {
        ShadingParams {
            extinction: 0.01,
            albedo: 0.9,
            phase: Phase::default(),
            sun_intensity: 1.2,
            light: None,
        }
    }
}

impl ShadingParams {
    /// The fraction of the extinction that attenuates diffuse light travelling into a
    /// cloud by diffusion theory: the effective attenuation coefficient
    /// `σ_tr = √(3 σ_a σ_t')` with `σ_a = (1 − ω)σ` and the reduced extinction
    /// `σ_t' = (1 − ω ḡ)σ` (Ishimaru 1978, ch. 9; Jensen et al. 2001, eq. 5), ḡ the
    /// mean cosine of the phase function, over σ. Defaults (ω = 0.9, ḡ = 0.25) give
    /// 0.48: diffuse light penetrates about twice as deep as a collimated beam.
    /// Finite and in [0, 1] for any input.
    pub fn diffusion_attenuation(&self) -> f64 {
        let w = if self.albedo.is_finite() {
            self.albedo.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let mix = if self.phase.mix.is_finite() {
            self.phase.mix.clamp(0.0, 1.0)
        } else {
            0.5
        };
        let g = |g: f64| {
            if g.is_finite() {
                g.clamp(-MAX_ABS_G, MAX_ABS_G)
            } else {
                0.0
            }
        };
        let mean_cos = mix * g(self.phase.g1) + (1.0 - mix) * g(self.phase.g2);
        (3.0 * (1.0 - w) * (1.0 - w * mean_cos)).sqrt().clamp(0.0, 1.0)
    }
}

/// The light model of the billboard paths (the presets `fast`, `balanced`,
/// `accurate`), whose constants are fitted per preset to the path tracer
/// ([`crate::render::Quality::light`]): a metaball stands for a whole region of
/// cloud, so how deep light reaches into it and how soft its edge is depend on its
/// size, which differs between presets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BillboardLight {
    /// Multiple scattering of sunlight (Wrenninge's octaves).
    pub octaves: Octaves,
    /// Scale of the sky- and ground-light attenuation coefficient,
    /// [`ShadingParams::diffusion_attenuation`] times this (1 = diffusion theory).
    pub sky_extinction_scale: f64,
    /// Strength in [0, 1] of the detail erosion of billboard edges
    /// (`render::detail`; 0 = smooth metaballs).
    pub detail_erosion: f64,
    /// Scale of the optical depth a ball's splat is drawn with (its opacity), against
    /// the optical depth its density gives (which its light and shadows keep): below 1
    /// a coarse preset's large, soft balls cover no more than the cloud they stand for.
    pub opacity_scale: f64,
}

impl Default for BillboardLight {
    /// The `balanced` preset's light.
    fn default() -> Self {
        crate::render::Quality::Balanced.light()
    }
}

/// Everything a renderer needs about light for one sun: direction, colours, phase,
/// and the clear sky they all come from ([`Sky`], a Rayleigh + Mie atmosphere).
#[derive(Clone, Debug, PartialEq)]
pub struct Lighting {
    /// Unit vector toward the sun.
    pub sun_dir: [f64; 3],
    /// The direct sun reaching the clouds (linear RGB, ≥ 0) as the radiance a white
    /// Lambertian surface facing it reads (its irradiance over π): the atmosphere's
    /// transmittance toward the sun at [`SUN_REFERENCE_ALTITUDE`], so a low sun is
    /// red and a sun whose disc is below the horizon there (about −1.7°) is 0. Cloud
    /// scatters [`Lighting::sun_scatter`] of it.
    pub sun_rgb: [f64; 3],
    /// Uniform-equivalent radiance of the sky's upper hemisphere, `E_sky↓ / π`
    /// (E_sky↓ the clear sky's irradiance on an upward-facing surface): what lights
    /// cloud tops from the sky.
    pub sky_ambient_above: [f64; 3],
    /// Uniform-equivalent radiance from below: the ground's reflection,
    /// `albedo_ground · (E_sun + E_sky↓) / π` at the ground (no cloud shadow): what
    /// lights cloud bases.
    pub sky_ambient_below: [f64; 3],
    /// Mean radiance over the whole sphere around an unoccluded point, the average of
    /// the two above: the ambient an isotropic scatterer sees, added unoccluded by
    /// [`Lighting::source_with_phase`].
    pub ambient_rgb: [f64; 3],
    /// The cloud's optical properties.
    pub params: ShadingParams,
    /// The billboard paths' light model: `params.light`, or the preset's own.
    pub billboard: BillboardLight,
    /// Global horizontal illuminance (sun + sky on an upward surface at the ground)
    /// relative to the sun above the atmosphere, in [0, 1]: 0 at night, ~0.9 at noon.
    pub daylight: f64,
    /// The clear sky of this sun.
    pub sky: Arc<Sky>,
}

fn luminance(c: [f64; 3]) -> f64 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

impl Lighting {
    /// Light for `sun` and the billboard light of `quality` (unless `params` names
    /// one): [`Lighting::new`] for a preset.
    pub fn for_quality(sun: Sun, params: ShadingParams, quality: crate::render::Quality) -> Lighting {
        let mut l = Lighting::new(sun, params);
        l.billboard = params.light.unwrap_or_else(|| quality.light());
        l
    }

    /// Light for `sun`: builds the sky tables for it (about a millisecond) and takes
    /// the sun colour and the ambients from them; the billboard light of `params`, or
    /// `balanced`'s. Finite at every elevation.
    pub fn new(sun: Sun, params: ShadingParams) -> Lighting {
        let sun_dir = sun.direction();
        let sky = Sky::shared(sun_dir, params.sun_intensity);
        let sun_rgb = sky.sun_rgb_at(SUN_REFERENCE_ALTITUDE);
        let above = sky.ambient_above();
        let sun_ground = sky.sun_rgb_at(0.0);
        let cos = sun_dir[2].max(0.0);
        let below = [0, 1, 2].map(|c| GROUND_ALBEDO[c] * (sun_ground[c] * cos + above[c]));
        let ambient_rgb = [0, 1, 2].map(|c| 0.5 * (above[c] + below[c]));
        let intensity = if params.sun_intensity.is_finite() && params.sun_intensity > 0.0 {
            params.sun_intensity
        } else {
            0.0
        };
        let global = luminance([0, 1, 2].map(|c| sun_ground[c] * cos + above[c]));
        let daylight = if intensity > 0.0 {
            (global / intensity).clamp(0.0, 1.0)
        } else {
            0.0
        };
        Lighting {
            sun_dir,
            sun_rgb,
            sky_ambient_above: above,
            sky_ambient_below: below,
            ambient_rgb,
            params,
            billboard: params.light.unwrap_or_default(),
            daylight,
            sky,
        }
    }

    /// What the sun adds to the radiance a unit of cloud scattering coefficient
    /// scatters, per unit of the 4π-normalised phase [`Phase::eval`]:
    /// `E_sun · p / (σ_s)` with the sun's irradiance `E_sun = π · sun_rgb` (the
    /// irradiance under which a white Lambertian surface facing the sun reads
    /// `sun_rgb`, as the ground does) and `p = eval / 4π`, so `sun_rgb / 4`
    /// ([`SUN_SCATTER`]). The cloud, the ground and the air see one sun in one unit:
    /// a conservative cloud deck returns what a white ground returns
    /// (`pathtrace::tests::one_sun_a_conservative_deck_reflects_what_a_white_ground_does`).
    pub fn sun_scatter(&self) -> [f64; 3] {
        self.sun_rgb.map(|c| c * SUN_SCATTER)
    }

    /// Source radiance of cloud at a point that receives sunlight transmittance
    /// `sun_transmittance`, for the phase value `phase` (single scattering, unoccluded
    /// ambient; the reference marcher's): `albedo · (sun_scatter · T · p + ambient)`.
    pub fn source_with_phase(&self, sun_transmittance: f64, phase: f64) -> [f64; 3] {
        let t = if sun_transmittance.is_finite() {
            sun_transmittance.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let a = self.params.albedo.clamp(0.0, 1.0);
        let sun = self.sun_scatter();
        [0, 1, 2].map(|i| a * (sun[i] * t * phase + self.ambient_rgb[i]))
    }

    /// The scattered sunlight of the billboard paths for a point whose sun ray has
    /// optical depth `tau_sun`, seen along `view_dir` (camera → point): the octave sum
    /// of [`Octaves`] times the sun colour (no albedo). With one octave it is
    /// `sun · p(cos θ) · exp(−τ_sun)`, the single-scattering term of
    /// [`Lighting::source_with_phase`].
    pub fn sun_octaves(&self, tau_sun: f64, view_dir: [f64; 3]) -> [f64; 3] {
        let cos = dot(view_dir, self.sun_dir);
        let s = self.billboard.octaves.sun_sum(&self.params.phase, cos, tau_sun);
        self.sun_scatter().map(|c| c * s)
    }

    /// What a client adds to a billboard's pre-shaded (isotropic) colour to apply the
    /// phase function per octave: `albedo · sun · (Σ bⁱ pᵢ(cos θ) e^{−aⁱτ} − Σ bⁱ e^{−aⁱτ})`.
    pub fn phase_correction(&self, tau_sun: f64, view_dir: [f64; 3]) -> [f64; 3] {
        let cos = dot(view_dir, self.sun_dir);
        let o = &self.billboard.octaves;
        let d = o.sun_sum(&self.params.phase, cos, tau_sun) - o.isotropic_sum(tau_sun);
        let a = self.params.albedo.clamp(0.0, 1.0);
        self.sun_scatter().map(|c| a * c * d)
    }

    /// A pre-shaded billboard colour (`colour`, sun optical depth `tau_sun`, both as
    /// its own layer's light buffer shaded them) under other layers whose clouds the
    /// sun ray from the ball crosses with optical depth `tau_above`, and which stand
    /// between the ball and the sky with vertical optical depth `tau_above_vertical`.
    /// Returns the colour and sun optical depth to draw.
    ///
    /// The layers above are part of the medium the sun's beam crosses, so the octave
    /// sum takes them as it takes the ball's own layer: `τ_sun' = τ_sun + τ_above`, and
    /// the sun term `albedo · sun · Σ bⁱ e^{−aⁱ τ}` is re-evaluated there (the later
    /// octaves stand for the light the deck scatters forward, its diffuse
    /// transmission). The rest of the colour is the ambient (sky above, ground
    /// below); a deck above dims both (the ground under the ball lies in the deck's
    /// shadow too), at the rate sky light is attenuated inside a cloud
    /// ([`Lighting::sky_extinction`], diffusion theory's): `e^{−k τ_above_vertical}`.
    pub fn beneath_layers(
        &self,
        colour: [f32; 3],
        tau_sun: f32,
        tau_above: f64,
        tau_above_vertical: f64,
    ) -> ([f32; 3], f32) {
        let ok = |t: f64| if t.is_finite() { t.max(0.0) } else { 0.0 };
        let (tau_above, vertical) = (ok(tau_above), ok(tau_above_vertical));
        if tau_above <= 0.0 && vertical <= 0.0 {
            return (colour, tau_sun);
        }
        let tau_sun = ok(tau_sun as f64);
        let below = (tau_sun + tau_above).min(1e6);
        let sun = self.sun_term();
        let (before, after) = (sun.at(tau_sun), sun.at(below));
        let sky = (-self.sky_extinction() * vertical).exp();
        let out = [0, 1, 2].map(|i| {
            let ambient = (colour[i] as f64 - before[i]).max(0.0);
            (after[i] + ambient * sky).clamp(0.0, 2.0) as f32
        });
        (out, below as f32)
    }

    /// The sun term of this light's pre-shaded billboard colours ([`SunTerm`]).
    pub fn sun_term(&self) -> SunTerm {
        SunTerm::new(self.sun_rgb, self.params.albedo, self.billboard.octaves)
    }

    /// The radiance of the ground seen from below a cloud: the ground of
    /// [`Lighting::ground_radiance`] under sun transmittance `ground_t`.
    pub fn ground_below(&self, ground_t: f64) -> [f64; 3] {
        self.ground_radiance(ground_t)
    }

    /// Sky and ground light reaching a point inside a cloud, as isotropic in-scattered
    /// radiance (no albedo): half the sphere sees the sky above through optical depth
    /// `tau_up`, half the ground below through `tau_down`, each attenuated by
    /// `exp(−k τ)` with `k` = [`ShadingParams::sky_extinction`]:
    /// `½ · sky · e^{−k τ_up} + ½ · ground · e^{−k τ_down}`. Cloud bases see the dark
    /// ground and a sky through the whole cloud, so they are darker than tops. Never
    /// more than the unoccluded `½ (sky + ground)` (with sky = ground = L it is at most
    /// L: the white furnace's value).
    pub fn ambient_source(&self, sky: [f64; 3], ground: [f64; 3], tau_up: f64, tau_down: f64) -> [f64; 3] {
        let k = self.sky_extinction();
        let att = |t: f64| if t > 0.0 { (-k * t).exp() } else { 1.0 };
        let (u, d) = (att(tau_up), att(tau_down));
        let ok = |v: f64| if v.is_finite() { v.max(0.0) } else { 0.0 };
        [0, 1, 2].map(|i| 0.5 * ok(sky[i]) * u + 0.5 * ok(ground[i]) * d)
    }

    /// The fraction of the extinction that attenuates sky and ground light travelling
    /// into a cloud in the billboard paths: diffusion theory's
    /// ([`ShadingParams::diffusion_attenuation`]) times the preset's
    /// `sky_extinction_scale`, within [0, 1].
    pub fn sky_extinction(&self) -> f64 {
        let scale = self.billboard.sky_extinction_scale;
        let scale = if scale.is_finite() { scale.max(0.0) } else { 1.0 };
        (self.params.diffusion_attenuation() * scale).clamp(0.0, 1.0)
    }

    /// Radiance of the clear sky seen along `dir` (a unit vector, z up), without the
    /// sun's disc. Directions below the horizon see the horizon's radiance. Every
    /// renderer takes its sky from here: the background, the light that reaches
    /// clouds from the sky (escaping rays of a path tracer).
    pub fn sky_radiance(&self, dir: [f64; 3]) -> [f64; 3] {
        self.sky.radiance(dir)
    }

    /// Aerial perspective from `eye` to `point` (world metres): the air's
    /// transmittance `T` and in-scattered radiance `L_in`; a surface of radiance `L`
    /// at `point` is seen as `L · T + L_in` ([`Sky::aerial`]).
    pub fn aerial(&self, eye: [f64; 3], point: [f64; 3]) -> ([f64; 3], [f64; 3]) {
        self.sky.aerial(eye, point)
    }

    /// `colour` seen through the air from `eye` at `point`: `colour · T + L_in`.
    pub fn hazed(&self, colour: [f64; 3], eye: [f64; 3], point: [f64; 3]) -> [f64; 3] {
        let (t, l) = self.aerial(eye, point);
        [0, 1, 2].map(|c| colour[c] * t[c] + l[c])
    }

    /// Radiance of the background along `dir` from `eye`: the sky (with the sun's
    /// disc) above the horizon; below it, when the eye is above the ground (altitude
    /// 0), the ground (albedo [`GROUND_ALBEDO`]) lit by the sun through cloud
    /// transmittance `ground_t` and by the sky, seen through the air between (whose
    /// sunlit in-scatter is shadowed by `ground_t` too).
    pub fn background(&self, eye: [f64; 3], dir: [f64; 3], ground_t: f64) -> [f64; 3] {
        if dir[2] >= 0.0 || eye[2] <= 0.0 {
            let mut c = self.sky_radiance(dir);
            // The sun's disc, anti-aliased over a quarter of its radius. Its radiance
            // is a display choice (the true one, ~4.6·10⁴ × sun_rgb, saturates anyway).
            let cos = dot(dir, self.sun_dir);
            let angle = cos.clamp(-1.0, 1.0).acos();
            let disc = 1.0 - smoothstep(0.75 * SUN_ANGULAR_RADIUS, 1.25 * SUN_ANGULAR_RADIUS, angle);
            if disc > 0.0 {
                let s = self.sky.sun_rgb_at(eye[2].max(0.0));
                for i in 0..3 {
                    c[i] += disc * SUN_DISC_GAIN * s[i];
                }
            }
            c
        } else {
            let s = -eye[2] / dir[2];
            let point = [eye[0] + dir[0] * s, eye[1] + dir[1] * s, 0.0];
            // The air near the ground is in the same cloud shadow as the ground:
            // its sunlit in-scatter is scaled by the ground's transmittance.
            let (tr, l) = self.sky.aerial_lit(eye, point, ground_t);
            let g = self.ground_radiance(ground_t);
            [0, 1, 2].map(|i| g[i] * tr[i] + l[i])
        }
    }

    /// Radiance of the ground (albedo [`GROUND_ALBEDO`]) under sun transmittance
    /// `t` through the clouds: `albedo · (sun_ground · t · cos θ_sun + sky)`, where the
    /// sky light is `sky_ambient_above` where the sun is unshadowed and turns grey
    /// (the same luminance, the colour of a cloud base) as the shadow deepens: the
    /// cloud that shadows a point also hides most of its blue sky. (A stand-in for
    /// sky light occluded by the actual cloud, which only the path tracer has.)
    pub fn ground_radiance(&self, t: f64) -> [f64; 3] {
        let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
        let s = self.sky.sun_rgb_at(0.0);
        let cos = self.sun_dir[2].max(0.0);
        let grey = luminance(self.sky_ambient_above);
        [0, 1, 2].map(|i| {
            let sky = t * self.sky_ambient_above[i] + (1.0 - t) * grey;
            GROUND_ALBEDO[i] * (s[i] * t * cos + sky)
        })
    }
}

/// The share of the sun ray's optical depth through the layers above a billboard
/// (read from their shadow maps, the direct beam's) that [`Lighting::beneath_layers`]
/// takes as `τ_above`: all of it. The layers above are part of the medium the sun's
/// beam crosses, and the octaves already stand for what they scatter on (the later
/// octaves' smaller attenuation). Measured with `examples/calibrate_scattering`
/// (`set=gallery`) against `--quality reference`: the objective over the gallery's
/// views falls from 0.054 at the earlier fitted 0.4 to 0.026 at 1 (`balanced`; `fast`
/// 0.087 → 0.059, `accurate` 0.051 → 0.024), with [`LAYERS_ABOVE_SKY_DEPTH`] at 0.
pub const LAYERS_ABOVE_SUN_DEPTH: f64 = 1.0;

/// The share of the layers above's vertical optical depth that
/// [`Lighting::beneath_layers`] dims sky and ground light with (at
/// [`Lighting::sky_extinction`]'s rate): none. A deck of albedo near 1 loses little
/// of the light it receives; what it takes from the direct beam and the sky above it
/// leaves its base as diffuse light, which stands in for the sky it hides. Measured
/// with [`LAYERS_ABOVE_SUN_DEPTH`]: every share tried above 0 (0.03–0.25) raised the
/// objective and dimmed the view from inside the cumulus below the reference's. The
/// mechanism stays for a world whose upper layers absorb (lower albedo).
pub const LAYERS_ABOVE_SKY_DEPTH: f64 = 0.0;

/// The sun's share of the in-scattered radiance per unit `sun_rgb` and unit
/// 4π-normalised phase value: the irradiance `π · sun_rgb` times the phase function's
/// normalisation `1 / 4π` (see [`Lighting::sun_scatter`]).
pub const SUN_SCATTER: f64 = 0.25;

/// The tone map's exposure: the factor linear radiance is multiplied by before
/// [`tone_map`]'s curve, a camera setting and not part of the light. A fixed
/// photographic exposure (as a game camera's manual mode), chosen so that the clear
/// noon sky reads the medium blue of a photograph exposed for sunlit cloud: at 3 the
/// noon zenith (about 1/20 of a white surface facing the sun) maps to about 0.4 and a
/// sunlit cloud top to 0.95. Every renderer, the viewer and the three.js example apply
/// the same exposure (served as `exposure` in `/v1/sky.json`).
pub const EXPOSURE: f64 = 3.0;

/// Radiance of the sun's disc drawn in the background, as a multiple of `sun_rgb`.
pub const SUN_DISC_GAIN: f64 = 40.0;

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Display mapping from linear radiance to [0, 1): the [`EXPOSURE`], then
/// `1 − exp(−x)`, then gamma 1/2.2. NaN or negative input maps to 0, +∞ to 1.
pub fn tone_map(x: f64) -> f64 {
    if x.is_nan() || x <= 0.0 {
        return 0.0;
    }
    (1.0 - (-EXPOSURE * x).exp()).powf(1.0 / 2.2)
}

#[inline]
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layers_above_only_dim_a_billboard() {
        let l = Lighting::new(Sun::new(180.0, 50.0).unwrap(), ShadingParams::default());
        let tau_sun = 1.5f32;
        let iso = l.billboard.octaves.isotropic_sum(tau_sun as f64);
        let ambient = [0.05, 0.07, 0.1];
        let colour = [0, 1, 2].map(|i| (l.params.albedo * (l.sun_scatter()[i] * iso + ambient[i])) as f32);
        // Nothing above: unchanged.
        assert_eq!(l.beneath_layers(colour, tau_sun, 0.0, 0.0), (colour, tau_sun));
        // Deeper decks above: darker in every channel, the sun ray's depth summed.
        let mut last = colour;
        for tau in [0.5, 2.0, 8.0, 30.0] {
            let (c, t) = l.beneath_layers(colour, tau_sun, tau, tau * 0.77);
            assert!((t - (tau_sun + tau as f32)).abs() < 1e-4);
            for ch in 0..3 {
                assert!(c[ch] < last[ch], "{tau}: {c:?} vs {last:?}");
            }
            last = c;
        }
        // Under an opaque deck almost nothing is left of either term.
        let (c, _) = l.beneath_layers(colour, tau_sun, 1e4, 1e4);
        assert!(c.iter().all(|&v| v < 1e-3), "{c:?}");
        // Bad input leaves it unchanged rather than poisoning it.
        assert_eq!(l.beneath_layers(colour, tau_sun, f64::NAN, -1.0), (colour, tau_sun));
    }

    fn integrate_over_sphere(f: impl Fn(f64) -> f64) -> f64 {
        // ∫ p dω = 2π ∫_{-1}^{1} p(μ) dμ, midpoint rule.
        let n = 200_000;
        let h = 2.0 / n as f64;
        (0..n).map(|i| f(-1.0 + (i as f64 + 0.5) * h)).sum::<f64>() * h * 2.0 * std::f64::consts::PI
    }

    #[test]
    fn phase_is_normalised() {
        for g in [-0.5, 0.0, 0.3, 0.7] {
            let total = integrate_over_sphere(|mu| henyey_greenstein(g, mu)) / (4.0 * std::f64::consts::PI);
            assert!((total - 1.0).abs() < 1e-4, "g={g}: {total}");
        }
        let p = Phase::default();
        let total = integrate_over_sphere(|mu| p.eval(mu)) / (4.0 * std::f64::consts::PI);
        assert!((total - 1.0).abs() < 1e-4, "{total}");
        // Forward peak larger than backward.
        assert!(p.eval(1.0) > p.eval(-1.0));
    }

    #[test]
    fn phase_samples_follow_the_evaluated_density() {
        // Histogram of 400 000 sampled cosines in 20 bins against ∫ eval/4π over each bin
        // (midpoint rule on 1000 sub-intervals): the sampler and eval are independent
        // code paths, so agreement tests both.
        for phase in [
            Phase::default(),
            Phase {
                g1: 0.95,
                g2: -0.6,
                mix: 0.8,
            },
            Phase {
                g1: 0.0,
                g2: 0.0005,
                mix: 0.3,
            },
        ] {
            let (n, bins) = (400_000usize, 20usize);
            let mut hist = vec![0usize; bins];
            for i in 0..n {
                let h = crate::fields::noise::mix64(i as u64 ^ 0x5eed);
                let u1 = (h >> 11) as f64 / (1u64 << 53) as f64;
                let u2 = (crate::fields::noise::mix64(h) >> 11) as f64 / (1u64 << 53) as f64;
                let c = phase.sample_cos(u1, u2);
                hist[(((c + 1.0) / 2.0 * bins as f64) as usize).min(bins - 1)] += 1;
            }
            for (b, &count) in hist.iter().enumerate() {
                let (lo, w) = (-1.0 + 2.0 * b as f64 / bins as f64, 2.0 / bins as f64);
                let sub = 1000;
                let want: f64 = (0..sub)
                    .map(|k| phase.eval(lo + (k as f64 + 0.5) * w / sub as f64))
                    .sum::<f64>()
                    * (w / sub as f64)
                    / 2.0;
                let got = count as f64 / n as f64;
                let sigma = (want * (1.0 - want) / n as f64).sqrt();
                assert!(
                    (got - want).abs() < 5.0 * sigma + 1e-4,
                    "{phase:?} bin {b}: {got} vs {want}"
                );
            }
        }
        for g in [-1.0, -0.99, 0.0, 0.5, 1.0, f64::NAN] {
            for u in [0.0, 1e-300, 0.5, 1.0, f64::NAN] {
                let c = sample_henyey_greenstein(g, u);
                assert!(c.is_finite() && (-1.0..=1.0).contains(&c), "g={g} u={u}: {c}");
            }
        }
    }

    #[test]
    fn phase_extremes_are_finite_and_bounded() {
        for g in [1.0, -1.0, 0.999_999, f64::INFINITY, f64::NAN, 5.0] {
            for mu in [-1.0, 0.0, 1.0, f64::NAN] {
                let v = Phase {
                    g1: g,
                    g2: -g,
                    mix: 0.5,
                }
                .eval(mu);
                assert!(v.is_finite() && (0.0..=2.0e4).contains(&v), "g={g} mu={mu}: {v}");
            }
        }
    }

    #[test]
    fn lighting_at_and_below_horizon_is_finite() {
        for el in [-90.0, -10.0, -6.0, -0.0, 0.0, 1e-9, 2.0, 90.0] {
            let l = Lighting::new(Sun::new(0.0, el).unwrap(), ShadingParams::default());
            for c in l.sun_rgb.iter().chain(l.ambient_rgb.iter()) {
                assert!(c.is_finite() && *c >= 0.0 && *c <= 2.0);
            }
            if el <= -6.0 {
                assert_eq!(l.sun_rgb, [0.0; 3]);
            }
            let s = l.source_with_phase(f64::NAN, l.params.phase.eval(1.0));
            assert!(s.iter().all(|v| v.is_finite()));
        }
        let noon = Lighting::new(Sun::new(0.0, 60.0).unwrap(), ShadingParams::default());
        let low = Lighting::new(Sun::new(0.0, 1.0).unwrap(), ShadingParams::default());
        // Low sun is dimmer and redder.
        assert!(low.sun_rgb[2] / low.sun_rgb[0] < noon.sun_rgb[2] / noon.sun_rgb[0]);
    }

    fn sphere_mean(f: impl Fn(f64) -> f64) -> f64 {
        integrate_over_sphere(f) / (4.0 * std::f64::consts::PI)
    }

    #[test]
    fn one_octave_is_single_scattering() {
        // Whatever a, b, c are, N = 1 is the single-scattering term p(cos θ)·e^{−τ}.
        let phase = Phase::default();
        for (a, b, c) in [(0.5, 0.5, 0.5), (0.1, 0.9, 0.0), (1.0, 0.0, 1.0)] {
            let o = Octaves {
                count: 1,
                attenuation: a,
                contribution: b,
                eccentricity: c,
            };
            for tau in [0.0f64, 0.3, 2.0, 17.0] {
                for cos in [-1.0, -0.3, 0.0, 0.8, 1.0] {
                    let single = phase.eval(cos) * (-tau).exp();
                    assert!(
                        (o.sun_sum(&phase, cos, tau) - single).abs() < 1e-15,
                        "{a} {b} {c} {tau} {cos}"
                    );
                }
                assert!((o.isotropic_sum(tau) - (-tau).exp()).abs() < 1e-15);
            }
        }
        // And the billboard path's sun term with one octave is the marcher's.
        let params = ShadingParams {
            light: Some(BillboardLight {
                octaves: Octaves::SINGLE,
                ..BillboardLight::default()
            }),
            ..ShadingParams::default()
        };
        let l = Lighting::new(Sun::new(40.0, 30.0).unwrap(), params);
        let dir = [0.3, 0.9, 0.3f64];
        let n = dot(dir, dir).sqrt();
        let dir = dir.map(|v| v / n);
        let tau: f64 = 1.7;
        let ss = l.source_with_phase((-tau).exp(), params.phase.eval(dot(dir, l.sun_dir)));
        let oct = l.sun_octaves(tau, dir);
        for i in 0..3 {
            let expected = ss[i] - params.albedo * l.ambient_rgb[i];
            assert!((params.albedo * oct[i] - expected).abs() < 1e-12);
        }
    }

    #[test]
    fn octaves_conserve_what_their_series_allows() {
        let phase = Phase::default();
        let o = Octaves::default();
        let (n, a, b, _) = o.sanitised();
        assert!(a <= b, "Hillaire's energy condition a <= b");
        let series = (1.0 - b.powi(n as i32)) / (1.0 - b);
        let mut last = f64::INFINITY;
        for tau in [0.0, 0.1, 1.0, 4.0, 20.0, 1e3, f64::INFINITY] {
            // Each octave's phase is normalised, so the 4π-mean of the sun term is the
            // isotropic sum the pre-shaded colour carries...
            let mean = sphere_mean(|mu| o.sun_sum(&phase, mu, tau));
            let iso = o.isotropic_sum(tau);
            assert!((mean - iso).abs() < 1e-3 * iso.max(1e-3), "tau={tau}: {mean} vs {iso}");
            // ...never more than the geometric series 1 + b + … + b^{N−1}, falling with depth.
            assert!(iso <= series + 1e-12 && iso <= last + 1e-15, "tau={tau}: {iso}");
            last = iso;
        }
        assert_eq!(o.isotropic_sum(f64::INFINITY), 0.0);
    }

    #[test]
    fn ambient_is_below_the_white_furnace() {
        // Sky and ground of one radiance L (a white furnace): the ambient source is L
        // with no cloud around, less with cloud, never more.
        let l = Lighting::new(Sun::new(0.0, 45.0).unwrap(), ShadingParams::default());
        let lum = [0.7, 0.8, 0.9];
        let open = l.ambient_source(lum, lum, 0.0, 0.0);
        assert!((0..3).all(|i| (open[i] - lum[i]).abs() < 1e-15));
        for (up, down) in [
            (0.5, 0.0),
            (3.0, 1.0),
            (1e9, 1e9),
            (f64::INFINITY, 0.0),
            (f64::NAN, 2.0),
        ] {
            let s = l.ambient_source(lum, lum, up, down);
            assert!(
                (0..3).all(|i| s[i].is_finite() && s[i] >= 0.0 && s[i] <= lum[i]),
                "{up} {down}: {s:?}"
            );
        }
        // The attenuation is diffusion theory's σ_tr / σ for the defaults, √(3·0.1·0.775),
        // times the preset's scale.
        let diffusion = (3.0f64 * 0.1 * 0.775).sqrt();
        assert!((ShadingParams::default().diffusion_attenuation() - diffusion).abs() < 1e-12);
        for scale in [0.5, 1.0, 2.0] {
            let params = ShadingParams {
                light: Some(BillboardLight {
                    sky_extinction_scale: scale,
                    ..BillboardLight::default()
                }),
                ..ShadingParams::default()
            };
            let l = Lighting::new(Sun::new(0.0, 45.0).unwrap(), params);
            assert!((l.sky_extinction() - (scale * diffusion).min(1.0)).abs() < 1e-12);
        }
    }

    #[test]
    fn octaves_are_finite_at_extremes() {
        for g in [-1.0, 1.0, f64::NAN, 5.0] {
            let phase = Phase {
                g1: g,
                g2: -g,
                mix: 0.5,
            };
            for o in [
                Octaves::default(),
                Octaves {
                    count: 99,
                    attenuation: f64::NAN,
                    contribution: 2.0,
                    eccentricity: -1.0,
                },
                Octaves {
                    count: 0,
                    attenuation: 0.0,
                    contribution: f64::INFINITY,
                    eccentricity: f64::NAN,
                },
            ] {
                for tau in [0.0, -1.0, 1e300, f64::INFINITY, f64::NAN] {
                    for mu in [-1.0, 0.0, 1.0, f64::NAN] {
                        let v = o.sun_sum(&phase, mu, tau);
                        assert!(
                            v.is_finite() && (0.0..2.0e5).contains(&v),
                            "{o:?} g={g} tau={tau} mu={mu}: {v}"
                        );
                    }
                }
            }
        }
        for el in [-90.0, -3.0, 0.0, 1e-9, 90.0] {
            let l = Lighting::new(Sun::new(0.0, el).unwrap(), ShadingParams::default());
            for tau in [0.0, f64::INFINITY, f64::NAN] {
                let c = l.phase_correction(tau, [0.0, 1.0, 0.0]);
                assert!(c.iter().all(|v| v.is_finite()), "{el} {tau}");
            }
            assert!(l.ground_below(f64::NAN).iter().all(|v| v.is_finite() && *v >= 0.0));
        }
    }

    #[test]
    fn ambients_come_from_the_sky_and_the_ground_is_hazed() {
        let l = Lighting::new(Sun::new(180.0, 45.0).unwrap(), ShadingParams::default());
        // Above is the blue sky; below is the ground's (yellowish-grey) reflection.
        assert!(l.sky_ambient_above[2] > l.sky_ambient_above[0]);
        assert!(l.sky_ambient_below[0] >= l.sky_ambient_below[2]);
        for c in 0..3 {
            let mean = 0.5 * (l.sky_ambient_above[c] + l.sky_ambient_below[c]);
            assert!((l.ambient_rgb[c] - mean).abs() < 1e-15);
        }
        // The ground just below the eye is the ground; far away it takes the horizon's haze.
        let eye = [0.0, 0.0, 500.0];
        let near = l.background(eye, [0.0, 0.05, -0.9987], 1.0);
        let g = l.ground_radiance(1.0);
        for c in 0..3 {
            assert!((near[c] - g[c]).abs() < 0.05 * g[c] + 0.01, "{near:?} vs {g:?}");
        }
        let far = l.background(eye, [0.0, 0.9999, -0.004], 1.0);
        let horizon = l.sky_radiance([0.0, 1.0, 0.0]);
        let lum = |c: [f64; 3]| luminance(c);
        assert!(
            (lum(far) - lum(horizon)).abs() < (lum(near) - lum(horizon)).abs(),
            "{far:?} {near:?} {horizon:?}"
        );
        // The sun's disc is bright; a degree away it is the sky.
        let disc = l.background(eye, l.sun_dir, 1.0);
        assert!(disc[0] > 10.0 * l.sky_radiance(l.sun_dir)[0]);
        let s = l.sun_dir;
        let off = [s[0], s[1] + 0.02, s[2]];
        let n = dot(off, off).sqrt();
        let off = off.map(|v| v / n);
        assert_eq!(l.background(eye, off, 1.0), l.sky_radiance(off));
    }

    #[test]
    fn tone_map_is_bounded() {
        assert_eq!(tone_map(f64::NAN), 0.0);
        assert_eq!(tone_map(-1.0), 0.0);
        assert_eq!(tone_map(f64::INFINITY), 1.0);
        assert!(tone_map(1e300) <= 1.0 && tone_map(0.5) > 0.0);
    }
}
