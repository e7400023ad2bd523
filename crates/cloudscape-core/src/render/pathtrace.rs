//! The reference renderer: an unbiased volumetric path tracer over the density grids.
//!
//! It estimates the radiance reaching the eye along each pixel's centre ray through the
//! same medium as the single-scattering marcher ([`super::march`]): the trilinear
//! density of the [`Volume`]s, extinction σ = `extinction · ρ`, single-scattering
//! albedo, the dual-lobe Henyey–Greenstein [`Phase`](super::light::Phase), the sun as a
//! directional light, the sky, and the ground at altitude 0 — with every order of
//! scattering, and with sky light that the cloud occludes.
//!
//! One sample is one path (the random-walk estimator of the volume rendering equation;
//! Novák et al. 2018, "Monte Carlo methods for volumetric light transport simulation",
//! §4–5). Along each straight segment of a path, to the ground or out of the clouds,
//! the radiance is
//!
//! ```text
//! L = ∫ T σ_s (sun · T_sun · p) dt  +  ∫ T σ_s ∫ p L_in dω dt  +  T(end) · L_behind
//! ```
//!
//! and the three terms are estimated from one Poisson process of tentative collisions
//! at the majorant rate σ̄ (per 4×4×4-cell brick, the marcher's occupancy bricks; empty
//! bricks cost nothing):
//! - the **collision** by delta (Woodcock) tracking (Woodcock et al. 1965; Novák et al.
//!   2018 §5.1): the first tentative collision accepted with probability σ/σ̄. There the
//!   throughput is multiplied by the albedo and the path goes on in a direction drawn
//!   from the phase function ([`Phase::sample_cos`](super::light::Phase::sample_cos)),
//!   so it needs no weight: that estimates the second term. A segment without a
//!   collision has transmittance 1 for the third term, else 0 — the two complement
//!   each other, so an albedo-1 medium under a uniform sky gives every path exactly the
//!   sky's radiance;
//! - the **sun** term as Σ over tentative collisions of T̂ · (σ/σ̄) · T̂_sun — unbiased
//!   by Mecke's formula for Poisson processes, E Σ g(tᵢ) = ∫ σ̄ E g(t) dt — times
//!   `albedo · sun_scatter · phase.eval(cos θ)` with cos θ = (path direction) · (sun
//!   direction): the marcher's single-scattering source term in the same units
//!   (`phase.eval` is 4π·p, so an isotropic medium gives 1, and
//!   [`Lighting::sun_scatter`] is `E_sun / 4π` for the sun's irradiance `π · sun_rgb`,
//!   the irradiance the ground sees). T̂ is the running
//!   ratio-tracking transmittance (Novák, Selle & Jarosz 2014, "Residual ratio tracking
//!   for estimating attenuation in participating media", §3: the product of (1 − σ/σ̄)
//!   over the tentative collisions so far, with Russian roulette below 0.1), and T̂_sun
//!   a ratio-tracking estimate toward the sun (as in the marcher, the sun ray sees
//!   cloud only); shadow rays of weight below `NEE_WEIGHT` are taken by Russian
//!   roulette. Against one shadow ray at the collision, the sun term is gathered along
//!   the whole segment, so thin cloud is not a coin toss between "hit" and "missed" (the
//!   majorant is at least 1 / brick size: about one tentative collision per non-empty
//!   brick crossed);
//! - **behind** the segment: the sky ([`Sky`]) for a segment that leaves the clouds
//!   upward — that is how sky light reaches cloud, occluded by the cloud itself — or the
//!   ground, where a path ends, with the ground model of [`Lighting::background`]
//!   (albedo 0.25, the sun through the cloud — a ratio-tracking estimate — times cos θ,
//!   plus ambient).
//!
//! Russian roulette on the throughput from the [`ROULETTE_AFTER`]-th scattering on
//! (survival probability min(1, throughput), then divided by it: unbiased), and a cap of
//! [`MAX_SCATTERINGS`] scatterings (the last segment then sees what lies behind through
//! a ratio-tracking transmittance and gathers no more light). The cap's bias is at most
//! the light of paths longer than that: ≤ albedo^N of the radiance (10⁻⁴⁶ at albedo
//! 0.9), and for albedo 1 the chance that a walk lasts N steps: below 10⁻⁵ in a white
//! furnace of optical radius 10 (the furnace test sees none of it), and in a
//! conservative deck of optical thickness 150 about the chance that a random walk
//! returns after N steps, ~1/√(πN): 0.4 % at N = 16 384 (at 1024 it took 5 % of the
//! deck's reflection; `one_sun_a_conservative_deck_reflects_what_a_white_ground_does`).
//! [`PathParams::single_scattering`] allows one scattering: the sun term of the first
//! segment and the sky or ground seen after one scattering, nothing more.
//!
//! Each pixel's centre ray is traced (no anti-aliasing), so the expectation is what
//! the marcher approximates, with every order of scattering. Randomness is
//! counter-based: a sample's numbers are a splitmix64 stream keyed by a hash of (pixel
//! x, pixel y, sample index), and a path draws them in order (bounce and dimension are
//! the position in that stream); nothing is shared between pixels, so the image is the
//! same bytes on any number of threads. The renderer states its noise ([`Noise`]):
//! the mean over pixels of the standard error of the pixel's luminance, from the
//! per-pixel sample variance.

use rayon::prelude::*;

use crate::cancel::Cancel;
use crate::fields::noise::mix64;

use super::camera::View;
use super::image::Image;
use super::light::{Lighting, dot};
use super::march::{Volume, intervals};

/// Samples per pixel when a request gives none.
pub const DEFAULT_SAMPLES: u32 = 32;
/// Most samples per pixel one render may ask for (the pixel × sample budget of
/// `[limits] max_path_samples` applies as well).
pub const MAX_SAMPLES: u32 = 65_536;
/// Most scatterings along one path (see the module comment for its bias).
pub const MAX_SCATTERINGS: u32 = 16_384;
/// Russian roulette on the throughput starts at this scattering.
pub const ROULETTE_AFTER: u32 = 4;
/// Largest extinction used, per metre: a mean free path of 10 cm at density 1, opaque
/// at any scale a cloud grid resolves. Bounding it bounds the tentative collisions of
/// delta and ratio tracking in a partly empty brick (an extinction of 1e300 would ask
/// for steps too small to move a ray).
pub const MAX_EXTINCTION: f64 = 10.0;
/// Sun shadow rays along a segment whose weight T̂·σ/σ̄ is below this are taken by
/// Russian roulette with this weight.
const NEE_WEIGHT: f64 = 0.25;

/// How many samples and how many scatterings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PathParams {
    /// Samples (paths) per pixel, at least 2 (the noise estimate needs two).
    pub samples: u32,
    /// Most scatterings along a path: [`MAX_SCATTERINGS`] for full transport, 1 for
    /// single scattering.
    pub max_scatterings: u32,
    /// Index of the first sample: the image takes samples `first_sample ..
    /// first_sample + samples` of each pixel's sequence, so two renders with disjoint
    /// ranges are independent estimates (and their mean is the render of both ranges).
    pub first_sample: u32,
}

impl PathParams {
    /// Every order of scattering with `samples` samples per pixel.
    pub fn new(samples: u32) -> PathParams {
        PathParams {
            samples,
            max_scatterings: MAX_SCATTERINGS,
            first_sample: 0,
        }
    }

    /// Single scattering only (what the marcher computes, with the sky occluded).
    pub fn single_scattering(samples: u32) -> PathParams {
        PathParams {
            samples,
            max_scatterings: 1,
            first_sample: 0,
        }
    }
}

/// The light a path gathers when it leaves the clouds without reaching the ground.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sky {
    /// [`Lighting::sky_radiance`]: the one clear sky every renderer uses.
    Clear,
    /// The same radiance from every direction (the white-furnace test).
    Uniform([f64; 3]),
}

/// What lights the clouds and what lies behind them.
#[derive(Clone, Copy, Debug)]
pub struct Environment<'a> {
    /// Sun direction and colour, extinction, albedo, phase, and the ground model.
    pub lighting: &'a Lighting,
    /// The sky seen behind the clouds and lighting them.
    pub sky: Sky,
    /// Whether the ground at altitude 0 is there (no ground: paths going down see the sky).
    pub ground: bool,
}

impl Environment<'_> {
    /// What a user sees: the clear sky of `lighting` and the ground.
    pub fn world(lighting: &Lighting) -> Environment<'_> {
        Environment {
            lighting,
            sky: Sky::Clear,
            ground: true,
        }
    }

    fn sky(&self, dir: [f64; 3]) -> [f64; 3] {
        match self.sky {
            Sky::Clear => self.lighting.sky_radiance(dir),
            Sky::Uniform(l) => l,
        }
    }
}

/// How converged a path-traced image is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Noise {
    /// Samples per pixel.
    pub samples: u32,
    /// Mean over pixels of the standard error of the pixel's linear luminance
    /// (Rec. 709 weights), from the per-pixel sample variance: the typical distance of
    /// a pixel from its converged value, in radiance units.
    pub std_error: f64,
    /// Mean linear luminance of the image, to put `std_error` in proportion.
    pub mean_luminance: f64,
}

impl Noise {
    /// `std_error` relative to the mean luminance (0 for a black image).
    pub fn relative(&self) -> f64 {
        if self.mean_luminance > 0.0 {
            self.std_error / self.mean_luminance
        } else {
            0.0
        }
    }
}

/// A path-traced image and its stated noise.
#[derive(Clone, Debug)]
pub struct Traced {
    /// Mean radiance per pixel; opaque (the sky or ground is behind every pixel).
    pub image: Image,
    /// The noise the image is stated to have.
    pub noise: Noise,
}

/// Rec. 709 luminance of linear RGB (ITU-R BT.709).
fn luminance(c: [f64; 3]) -> f64 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

/// A splitmix64 stream (Steele, Lea & Flood 2014) keyed by one sample: the n-th number
/// is `mix64(key + n·φ)`, a pure function of (key, n).
struct Stream {
    key: u64,
    n: u64,
}

impl Stream {
    pub(super) const GOLDEN: u64 = 0x9e37_79b9_7f4a_7c15;

    fn new(x: usize, y: usize, sample: u32) -> Stream {
        let key = mix64(mix64(mix64(0x7061_7468_7472_6163 ^ x as u64) ^ y as u64) ^ sample as u64);
        Stream { key, n: 0 }
    }

    /// A uniform number in [0, 1) with 53 random bits.
    #[inline]
    fn next(&mut self) -> f64 {
        self.n += 1;
        let z = mix64(self.key.wrapping_add(self.n.wrapping_mul(Self::GOLDEN)));
        (z >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// An exponential distance with rate `rate` (> 0): −ln(1 − u) / rate.
    #[inline]
    fn distance(&mut self, rate: f64) -> f64 {
        -(1.0 - self.next()).ln() / rate
    }
}

/// The clouds as a medium: the volumes and the extinction per unit density.
struct Medium<'a> {
    volumes: &'a [Volume],
    extinction: f64,
}

/// What one segment of a path gathers ([`Tracer::segment`]).
struct Segment {
    /// Σ over tentative collisions of T̂ · σ/σ̄ · T̂_sun: the sun scattered once on the
    /// segment, before albedo, phase and sun colour.
    sun: f64,
    /// With aerial perspective from the segment's origin (the eye): the same sum with
    /// each term times the air's transmittance between the eye and its collision
    /// point, per channel (`sun` × 1 without).
    sun_hazed: [f64; 3],
    /// An estimate of the segment's transmittance to its end: 1 or 0 (delta tracking
    /// escaped or collided) on a segment that scatters, ratio tracking otherwise.
    transmittance: f64,
    /// The delta-tracking collision (where the path scatters next), if sampled.
    collision: Option<f64>,
}

impl Medium<'_> {
    /// Generates the tentative collisions along (`o`, `d`) within [0, `t_max`]: a
    /// Poisson process of rate σ̄ (the majorant), calling `f(rng, t, σ(t), σ̄)` at each
    /// in order until it returns false. Per brick σ̄ = max(extinction · brick maximum,
    /// 1 / brick size) — at least about one tentative collision per non-empty brick
    /// crossed, so ratio tracking samples thin cloud like a marcher would; empty bricks
    /// cost nothing. Where volumes overlap, σ = Σ σ_v and σ̄ = Σ of the volumes'
    /// whole-volume majorants (the exponential's memorylessness lets every piece start
    /// afresh at its entry).
    fn tentative(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        t_max: f64,
        rng: &mut Stream,
        mut f: impl FnMut(&mut Stream, f64, f64, f64) -> bool,
    ) {
        let ext = self.extinction;
        if !(ext > 0.0) {
            return;
        }
        let at = |t: f64| [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
        let ivs = intervals(self.volumes, o, d, 0.0, t_max);
        let disjoint = ivs.windows(2).all(|w| w[1].1 >= w[0].2);
        if disjoint {
            for &(i, a, b) in &ivs {
                let vol = &self.volumes[i];
                let floor = 1.0 / vol.brick_size();
                let mut go = true;
                vol.visit_bricks(o, d, a, b, |ta, tb, max_density| {
                    if !(max_density > 0.0) {
                        return true;
                    }
                    let majorant = (ext * max_density).max(floor);
                    let mut t = ta;
                    loop {
                        t += rng.distance(majorant);
                        if !(t < tb) {
                            return true;
                        }
                        let sigma = ext * vol.density(at(t));
                        if !f(rng, t, sigma, majorant) {
                            go = false;
                            return false;
                        }
                    }
                });
                if !go {
                    return;
                }
            }
            return;
        }
        // Overlapping boxes: pieces between consecutive entry/exit points, each with the
        // volumes that cover it.
        let mut cuts: Vec<f64> = ivs.iter().flat_map(|&(_, a, b)| [a, b]).collect();
        cuts.sort_by(f64::total_cmp);
        cuts.dedup();
        for w in cuts.windows(2) {
            let (s, e) = (w[0], w[1]);
            let active: Vec<usize> = ivs.iter().filter(|iv| iv.1 <= s && iv.2 >= e).map(|iv| iv.0).collect();
            let max: f64 = active.iter().map(|&i| self.volumes[i].max_density()).sum();
            if active.is_empty() || !(max > 0.0) {
                continue;
            }
            let floor = active
                .iter()
                .map(|&i| 1.0 / self.volumes[i].brick_size())
                .fold(0.0, f64::max);
            let majorant = (ext * max).max(floor);
            let mut t = s;
            loop {
                t += rng.distance(majorant);
                if !(t < e) {
                    break;
                }
                let p = at(t);
                let sigma = ext * active.iter().map(|&i| self.volumes[i].density(p)).sum::<f64>();
                if !f(rng, t, sigma, majorant) {
                    return;
                }
            }
        }
    }

    /// An unbiased estimate of the transmittance along (`o`, `d`) up to `t_max` by
    /// ratio tracking: the product of (1 − σ/σ̄) over tentative collisions, with Russian
    /// roulette below 0.1 ([`roulette`]).
    fn transmittance(&self, o: [f64; 3], d: [f64; 3], t_max: f64, rng: &mut Stream) -> f64 {
        let mut tr = 1.0;
        self.tentative(o, d, t_max, rng, |rng, _, sigma, majorant| {
            if sigma > 0.0 {
                tr *= (1.0 - sigma / majorant).max(0.0);
                roulette(&mut tr, rng);
            }
            tr > 0.0
        });
        tr
    }
}

/// Russian roulette on a ratio-tracking transmittance below 0.1: it survives with
/// probability ½ and is doubled, so its expectation is unchanged (Novák et al. 2014, §3).
#[inline]
fn roulette(tr: &mut f64, rng: &mut Stream) {
    if *tr < 0.1 {
        if *tr <= 0.0 || rng.next() < 0.5 {
            *tr = 0.0;
        } else {
            *tr *= 2.0;
        }
    }
}

/// A unit vector at cosine `cos` from unit `d`, at azimuth `phi` around it; the frame
/// around `d` is the branchless orthonormal basis of Duff et al. 2017 ("Building an
/// orthonormal basis, revisited", JCGT 6(1), listing 3).
fn deflect(d: [f64; 3], cos: f64, phi: f64) -> [f64; 3] {
    let sign = 1.0f64.copysign(d[2]);
    let a = -1.0 / (sign + d[2]);
    let b = d[0] * d[1] * a;
    let t1 = [1.0 + sign * d[0] * d[0] * a, sign * b, -sign * d[0]];
    let t2 = [b, sign + d[1] * d[1] * a, -d[1]];
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let (s, c) = phi.sin_cos();
    let w = [0, 1, 2].map(|i| t1[i] * (sin * c) + t2[i] * (sin * s) + d[i] * cos);
    let n = dot(w, w).sqrt();
    if n > 0.0 && n.is_finite() { w.map(|v| v / n) } else { d }
}

/// The path tracer of one render.
struct Tracer<'a> {
    medium: Medium<'a>,
    env: Environment<'a>,
    params: PathParams,
    albedo: f64,
    sun_up: bool,
}

impl<'a> Tracer<'a> {
    fn new(volumes: &'a [Volume], env: Environment<'a>, params: PathParams) -> Tracer<'a> {
        let p = &env.lighting.params;
        let extinction = if p.extinction.is_nan() {
            0.0
        } else {
            p.extinction.clamp(0.0, MAX_EXTINCTION)
        };
        let albedo = if p.albedo.is_finite() {
            p.albedo.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let l = env.lighting;
        let sun_up = l.sun_rgb.iter().all(|c| c.is_finite()) && l.sun_rgb.iter().any(|&c| c > 0.0);
        Tracer {
            medium: Medium { volumes, extinction },
            env,
            params,
            albedo,
            sun_up,
        }
    }

    /// One segment of a path, from `o` along `d` to `t_max` (the ground) or out of the
    /// clouds, over one set of tentative collisions (see the module comment). When
    /// `scatter`: the delta-tracking collision where the path goes on (none: the path
    /// leaves the segment, transmittance 1), and the sun scattered once at every
    /// tentative collision, weighted by the running ratio-tracking transmittance.
    /// Otherwise (the last segment of a capped path) only the ratio-tracking
    /// transmittance to the end.
    fn segment(&self, o: [f64; 3], d: [f64; 3], t_max: f64, scatter: bool, hazed: bool, rng: &mut Stream) -> Segment {
        if !scatter {
            return Segment {
                sun: 0.0,
                sun_hazed: [0.0; 3],
                transmittance: self.medium.transmittance(o, d, t_max, rng),
                collision: None,
            };
        }
        let mut sun_sum = 0.0;
        let mut sun_hazed = [0.0; 3];
        let mut tr = if self.sun_up { 1.0 } else { 0.0 };
        let mut collision = None;
        let sun = self.env.lighting.sun_dir;
        self.medium.tentative(o, d, t_max, rng, |rng, t, sigma, majorant| {
            if sigma > 0.0 {
                let r = (sigma / majorant).min(1.0);
                if collision.is_none() && rng.next() < r {
                    collision = Some(t);
                }
                if tr > 0.0 {
                    // The shadow ray, with roulette below weight NEE_WEIGHT: at most
                    // 1/NEE_WEIGHT shadow rays per segment in expectation (Σ weights ≤ 1).
                    let w = tr * r;
                    let p = [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
                    let gathered = if w >= NEE_WEIGHT {
                        w * self.medium.transmittance(p, sun, f64::INFINITY, rng)
                    } else if rng.next() * NEE_WEIGHT < w {
                        NEE_WEIGHT * self.medium.transmittance(p, sun, f64::INFINITY, rng)
                    } else {
                        0.0
                    };
                    if gathered > 0.0 {
                        sun_sum += gathered;
                        let air = if hazed {
                            self.env.lighting.aerial(o, p).0
                        } else {
                            [1.0; 3]
                        };
                        for c in 0..3 {
                            sun_hazed[c] += gathered * air[c];
                        }
                    }
                    tr *= 1.0 - r;
                    roulette(&mut tr, rng);
                }
            }
            tr > 0.0 || collision.is_none()
        });
        Segment {
            sun: sun_sum,
            sun_hazed,
            transmittance: if collision.is_none() { 1.0 } else { 0.0 },
            collision,
        }
    }

    /// One path from `o` along `d`: its radiance estimate. With `aerial` (a
    /// perspective view: `o` is the eye), what the primary ray meets is seen through
    /// the air between the eye and it, as in the marcher and the compositor
    /// (`L · T_air + L_in`, [`Lighting::aerial`]): the sun gathered on the primary
    /// segment is hazed at each collision point, everything beyond the first
    /// collision p₁ is multiplied by `T_air(eye, p₁)` and `L_in(eye, p₁)` is added
    /// (whose expectation over p₁ is the marcher's `Σ T_k a_k L_in(p_k)`). The ground
    /// behind an escaping primary ray is hazed by [`Lighting::background`]; the sky
    /// needs none.
    fn path(&self, mut o: [f64; 3], mut d: [f64; 3], aerial: bool, rng: &mut Stream) -> [f64; 3] {
        let lighting = self.env.lighting;
        let (sun, sun_rgb) = (lighting.sun_dir, lighting.sun_scatter());
        let phase = lighting.params.phase;
        let eye = o;
        let mut radiance = [0.0; 3];
        // The primary segment's radiance and the air at the first collision.
        let mut primary = [0.0; 3];
        let mut air: Option<([f64; 3], [f64; 3])> = None;
        let finish = |radiance: [f64; 3], primary: [f64; 3], air: Option<([f64; 3], [f64; 3])>| match air {
            Some((tr, l)) => [0, 1, 2].map(|c| primary[c] + radiance[c] * tr[c] + l[c]),
            None => [0, 1, 2].map(|c| primary[c] + radiance[c]),
        };
        let mut throughput = 1.0;
        let mut scatterings = 0;
        loop {
            let ground_t = if self.env.ground && d[2] < 0.0 && o[2] > 0.0 {
                -o[2] / d[2]
            } else {
                f64::INFINITY
            };
            let first = scatterings == 0;
            let hazed = aerial && first;
            let seg = self.segment(o, d, ground_t, scatterings < self.params.max_scatterings, hazed, rng);
            if seg.sun > 0.0 {
                let w = throughput * self.albedo * phase.eval(dot(d, sun));
                let out = if first { &mut primary } else { &mut radiance };
                for c in 0..3 {
                    out[c] += w * seg.sun_hazed[c] * sun_rgb[c];
                }
            }
            if seg.transmittance > 0.0 {
                // What lies beyond the segment: the ground (below the horizon) or the sky.
                let behind = if self.env.ground && d[2] < 0.0 {
                    let t_sun = if ground_t.is_finite() && self.sun_up && sun[2] > 0.0 {
                        let g = [o[0] + d[0] * ground_t, o[1] + d[1] * ground_t, 0.0];
                        self.medium.transmittance(g, sun, f64::INFINITY, rng)
                    } else {
                        1.0
                    };
                    lighting.background(o, d, t_sun)
                } else {
                    self.env.sky(d)
                };
                let out = if first { &mut primary } else { &mut radiance };
                for c in 0..3 {
                    out[c] += throughput * seg.transmittance * behind[c];
                }
            }
            let Some(t) = seg.collision else {
                return finish(radiance, primary, air);
            };
            scatterings += 1;
            o = [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
            if hazed {
                air = Some(lighting.aerial(eye, o));
            }
            throughput *= self.albedo;
            if !(throughput > 0.0) {
                return finish(radiance, primary, air);
            }
            let cos = phase.sample_cos(rng.next(), rng.next());
            d = deflect(d, cos, 2.0 * std::f64::consts::PI * rng.next());
            if scatterings >= ROULETTE_AFTER {
                let survive = throughput.min(1.0);
                if rng.next() >= survive {
                    return finish(radiance, primary, air);
                }
                throughput /= survive;
            }
        }
    }
}

/// Path-traces `view` over `volumes` in `env` with `params.samples` samples per pixel
/// (at least 2 are taken). Rows are independent, so the image and its noise do not
/// depend on the thread count.
pub fn render(volumes: &[Volume], env: Environment, params: &PathParams, view: &View) -> Traced {
    render_cancellable(volumes, env, params, view, &Cancel::never())
}

/// [`render`] that leaves the remaining rows black once `cancel` fires (the caller
/// then discards the image).
pub fn render_cancellable(
    volumes: &[Volume],
    env: Environment,
    params: &PathParams,
    view: &View,
    cancel: &Cancel,
) -> Traced {
    let samples = params.samples.max(2);
    let tracer = Tracer::new(volumes, env, *params);
    // Perspective views have an eye, whose air hazes what it sees; orthographic ones
    // do not (as in the marcher). The air belongs to the clear sky: under a uniform
    // test sky (the white furnace) there is none.
    let aerial = matches!(view.kind, super::camera::ViewKind::Perspective { .. }) && matches!(env.sky, Sky::Clear);
    let width = view.width;
    let rows: Vec<(Vec<[f32; 3]>, f64, f64)> = (0..view.height)
        .into_par_iter()
        .map(|y| {
            let mut rgb = Vec::with_capacity(width);
            let (mut se_sum, mut lum_sum) = (0.0, 0.0);
            if cancel.is_fired() {
                return (vec![[0.0; 3]; width], 0.0, 0.0);
            }
            for x in 0..width {
                let (o, d) = view.ray(x as f64 + 0.5, y as f64 + 0.5);
                let mut sum = [0.0; 3];
                // Welford's running mean and squared deviations of the luminance.
                let (mut mean, mut m2) = (0.0, 0.0);
                for s in 0..samples {
                    let mut rng = Stream::new(x, y, params.first_sample.wrapping_add(s));
                    let c = tracer.path(o, d, aerial, &mut rng);
                    for i in 0..3 {
                        sum[i] += c[i];
                    }
                    let l = luminance(c);
                    let delta = l - mean;
                    mean += delta / (s + 1) as f64;
                    m2 += delta * (l - mean);
                }
                let n = samples as f64;
                let variance = (m2 / (n - 1.0)).max(0.0);
                se_sum += (variance / n).sqrt();
                lum_sum += mean;
                rgb.push(sum.map(|v| (v / n) as f32));
            }
            (rgb, se_sum, lum_sum)
        })
        .collect();
    let mut image = Image::new(view.width, view.height);
    let (mut se, mut lum) = (0.0, 0.0);
    for (y, (rgb, s, l)) in rows.into_iter().enumerate() {
        image.rgb[y * width..(y + 1) * width].copy_from_slice(&rgb);
        se += s;
        lum += l;
    }
    image.alpha.iter_mut().for_each(|a| *a = 1.0);
    let pixels = (view.width * view.height).max(1) as f64;
    Traced {
        image,
        noise: Noise {
            samples,
            std_error: se / pixels,
            mean_luminance: lum / pixels,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::density::Grid;
    use crate::density::metaballs::GridPlacement;
    use crate::render::Camera;
    use crate::render::light::{Phase, ShadingParams};
    use crate::render::march::{self, MarchParams};
    use crate::render::sun::Sun;

    /// A volume of `cols × rows × depth` cells (`column` × `column` × `cell_height`
    /// metres, origin at 0,0,`base`) with density `f(col, row, level)`, answering for the
    /// box between the outermost cell centres, where the trilinear density is `f`'s
    /// interpolation (a homogeneous `f` gives an exactly homogeneous slab there).
    fn volume(
        [cols, rows, depth]: [usize; 3],
        column: f64,
        cell_height: f64,
        base: f64,
        f: impl Fn(usize, usize, usize) -> f32,
    ) -> Volume {
        let mut grid = Grid::<f32>::new(depth, rows, cols);
        for k in 0..depth {
            for r in 0..rows {
                for c in 0..cols {
                    grid.data[(k * rows + r) * cols + c] = f(c, r, k);
                }
            }
        }
        let place = GridPlacement {
            x0: 0.0,
            y0: 0.0,
            column,
            base,
            cell_height,
        };
        let bounds = [
            0.5 * column,
            0.5 * column,
            base + 0.5 * cell_height,
            (cols as f64 - 0.5) * column,
            (rows as f64 - 0.5) * column,
            base + (depth as f64 - 0.5) * cell_height,
        ];
        Volume::new(grid, place, bounds)
    }

    /// A hash in [0, 1) of three cell indices (for uneven test densities).
    fn noise(c: usize, r: usize, k: usize) -> f32 {
        let h = mix64(mix64(mix64(c as u64 ^ 0xabc) ^ r as u64) ^ k as u64);
        (h >> 40) as f32 / (1u64 << 24) as f32
    }

    fn lighting(sun: Sun, params: ShadingParams) -> Lighting {
        Lighting::new(sun, params)
    }

    /// Sun from the zenith angle θs (azimuth 180°: the sun in the south, light going north).
    fn sun_at_zenith_angle(theta_s_deg: f64) -> Sun {
        Sun::new(180.0, 90.0 - theta_s_deg).unwrap()
    }

    /// An orthographic `n × n` view of a few metres per pixel centred on `centre`,
    /// looking down at zenith angle θv toward the north-east-ish azimuth `az_deg`.
    fn looking_down(centre: [f64; 3], theta_v_deg: f64, az_deg: f64, n: usize) -> View {
        let (tv, az) = (theta_v_deg.to_radians(), az_deg.to_radians());
        let forward = [tv.sin() * az.sin(), tv.sin() * az.cos(), -tv.cos()];
        // Screen up: perpendicular to forward, in the vertical plane through it.
        let up = [tv.cos() * az.sin(), tv.cos() * az.cos(), tv.sin()];
        View::orthographic(centre, forward, up, 2.0, n, n)
    }

    fn mean_luminance(img: &Image) -> f64 {
        img.rgb.iter().map(|c| luminance(c.map(|v| v as f64))).sum::<f64>() / img.rgb.len() as f64
    }

    #[test]
    fn white_furnace_gives_the_sky_radiance_everywhere() {
        // Albedo 1, no sun, a uniform sky L in every direction and no ground: light is
        // neither lost nor made, so every pixel is L whatever the (thick, uneven) density.
        let vol = volume([16, 16, 12], 100.0, 100.0, 1000.0, |c, r, k| 2.0 * noise(c, r, k));
        let params = ShadingParams {
            extinction: 0.01,
            albedo: 1.0,
            ..ShadingParams::default()
        };
        let mut l = lighting(Sun::new(0.0, 45.0).unwrap(), params);
        l.sun_rgb = [0.0; 3];
        let sky = [0.3, 0.5, 0.9];
        let env = Environment {
            lighting: &l,
            sky: Sky::Uniform(sky),
            ground: false,
        };
        // Looking at the volume (optical depth through it up to ~15) from the side, and
        // from inside it.
        for (eye, pitch) in [([800.0, -1500.0, 1600.0], 0.0), ([800.0, 800.0, 1500.0], -20.0)] {
            let camera = Camera::new(eye, 0.0, pitch, 60.0).unwrap();
            let view = View::perspective(&camera, 8, 6);
            let traced = render(std::slice::from_ref(&vol), env, &PathParams::new(64), &view);
            // Every path returns exactly L (a collision and an escape complement each
            // other, see the module comment), so only f32 rounding remains.
            for px in &traced.image.rgb {
                for c in 0..3 {
                    let rel = (px[c] as f64 - sky[c]).abs() / sky[c];
                    assert!(rel < 1e-5, "{eye:?}: pixel {px:?} against the sky {sky:?}");
                }
            }
            assert!(traced.noise.std_error < 1e-9, "{:?}", traced.noise);
        }
    }

    /// Reflected single scattering of a homogeneous plane-parallel slab of optical
    /// thickness τ seen from above (Chandrasekhar 1960, *Radiative Transfer*, §1.5, the
    /// first-order term; e.g. Liou, *An Introduction to Atmospheric Radiation*, 2nd ed.,
    /// eq. 6.2.5): `L = ω · F · p · μs / (μs + μv) · (1 − exp(−τ (1/μs + 1/μv)))`, with F
    /// the sun radiance in our units (`sun_rgb`, so the sun's irradiance is `π F`) and
    /// p = `phase.eval(cos Θ) / 4π` times π: the formula's `F p` with `F` the irradiance
    /// and `p` normalised over the sphere, which is `sun_rgb · phase.eval / 4`.
    fn slab_single_scattering(omega: f64, f: f64, p: f64, tau: f64, mu_s: f64, mu_v: f64) -> f64 {
        omega * f * p / 4.0 * mu_s / (mu_s + mu_v) * (1.0 - (-tau * (1.0 / mu_s + 1.0 / mu_v)).exp())
    }

    /// The test slab: 500 m thick (cell centres 50 m … 550 m above 1000 m), 39 km wide,
    /// density `rho`.
    fn slab(rho: f32) -> Volume {
        volume([40, 40, 6], 1000.0, 100.0, 1000.0, move |_, _, _| rho)
    }

    /// Extinction per metre at density 1 in the slab tests.
    const SLAB_EXTINCTION: f64 = 0.01;

    /// The optical thickness of [`slab`]`(rho)` lit with [`SLAB_EXTINCTION`].
    fn slab_tau(rho: f32) -> f64 {
        SLAB_EXTINCTION * rho as f64 * 500.0
    }

    /// The slab tests' lighting: the sun at zenith angle θs, [`SLAB_EXTINCTION`].
    fn slab_lighting(theta_s_deg: f64, albedo: f64, phase: Phase) -> Lighting {
        let params = ShadingParams {
            extinction: SLAB_EXTINCTION,
            albedo,
            phase,
            ..ShadingParams::default()
        };
        lighting(sun_at_zenith_angle(theta_s_deg), params)
    }

    /// Only the sun: a black sky and no ground.
    fn sun_only(lighting: &Lighting) -> Environment<'_> {
        Environment {
            lighting,
            sky: Sky::Uniform([0.0; 3]),
            ground: false,
        }
    }

    fn slab_centre() -> [f64; 3] {
        [20_000.0, 20_000.0, 1550.0]
    }

    #[test]
    fn thin_slab_matches_the_closed_form_single_scattering() {
        let (theta_s, theta_v): (f64, f64) = (30.0, 50.0);
        let (mu_s, mu_v) = (theta_s.to_radians().cos(), theta_v.to_radians().cos());
        for (rho, phase) in [
            (0.04f32, Phase::default()),
            (
                0.3,
                Phase {
                    g1: 0.0,
                    g2: 0.0,
                    mix: 0.5,
                },
            ),
        ] {
            let l = slab_lighting(theta_s, 0.9, phase);
            // Looking down toward the north-east, the sun behind-left in the south.
            let view = looking_down(slab_centre(), theta_v, 40.0, 6);
            let traced = render(&[slab(rho)], sun_only(&l), &PathParams::single_scattering(512), &view);
            let tau = slab_tau(rho);
            let d = view.ray(3.0, 3.0).1;
            let p = phase.eval(dot(d, l.sun_dir));
            for c in 0..3 {
                let want = slab_single_scattering(0.9, l.sun_rgb[c], p, tau, mu_s, mu_v);
                let got: f64 = traced.image.rgb.iter().map(|px| px[c] as f64).sum::<f64>() / 36.0;
                // Noise of the 36-pixel mean, from the stated per-pixel error (luminance;
                // the channels are within a factor 2 of it), plus 0.5 % for f32 and the
                // slab's finite width.
                let se = 2.0 * traced.noise.std_error / 6.0;
                assert!(
                    (got - want).abs() <= 3.0 * se + 0.005 * want,
                    "rho {rho} channel {c}: {got} vs closed form {want} (se {se})"
                );
            }
        }
    }

    /// Independent golden value for multiple scattering: a plane-parallel slab of
    /// optical thickness τ with an isotropic phase function, reflected radiance toward
    /// μv, by an analog one-dimensional Monte Carlo in optical depth with the local
    /// estimate (Marchuk et al. 1980, *The Monte Carlo Methods in Atmospheric Optics*,
    /// §2.4): photons enter at μs, each collision adds ω · e^{−τ'/μv} / μv (isotropic
    /// p = 1), the weight is multiplied by ω, new directions are uniform in μ.
    /// Returns the radiance per unit sun radiance (`F = 1`) and its standard error.
    fn slab_plane_parallel_mc(omega: f64, tau: f64, mu_s: f64, mu_v: f64, photons: u64) -> (f64, f64) {
        let mut state = 0x1234_5678u64;
        let mut uniform = || {
            state = state.wrapping_add(Stream::GOLDEN);
            (mix64(state) >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut sum, mut sum2) = (0.0, 0.0);
        for _ in 0..photons {
            let (mut depth, mut mu, mut w) = (0.0f64, -mu_s, 1.0f64);
            let mut score = 0.0;
            loop {
                let s = -(1.0 - uniform()).ln();
                depth -= s * mu;
                if !(0.0..=tau).contains(&depth) {
                    break;
                }
                score += w * omega * (-depth / mu_v).exp() / mu_v;
                w *= omega;
                if w < 1e-6 {
                    break;
                }
                mu = 2.0 * uniform() - 1.0;
            }
            // Photons per unit horizontal area: F₀ μs with F₀ = π F (the irradiance
            // under which a white surface reads F), and 1/4π of the isotropic phase
            // function: μs / 4 per unit F.
            let v = score * mu_s / 4.0;
            sum += v;
            sum2 += v * v;
        }
        let n = photons as f64;
        let mean = sum / n;
        (mean, ((sum2 / n - mean * mean) / n).max(0.0).sqrt())
    }

    #[test]
    fn thick_slab_matches_an_independent_plane_parallel_monte_carlo() {
        let (theta_s, theta_v): (f64, f64) = (30.0, 50.0);
        let (mu_s, mu_v) = (theta_s.to_radians().cos(), theta_v.to_radians().cos());
        let isotropic = Phase {
            g1: 0.0,
            g2: 0.0,
            mix: 0.5,
        };
        let (rho, omega) = (0.6f32, 0.9);
        let tau = slab_tau(rho);
        let l = slab_lighting(theta_s, omega, isotropic);
        let env = sun_only(&l);
        let view = looking_down(slab_centre(), theta_v, 40.0, 6);
        let full = render(&[slab(rho)], env, &PathParams::new(1024), &view);
        let single = render(&[slab(rho)], env, &PathParams::single_scattering(256), &view);
        let (golden, golden_se) = slab_plane_parallel_mc(omega, tau, mu_s, mu_v, 400_000);
        let ss = slab_single_scattering(omega, 1.0, 1.0, tau, mu_s, mu_v);
        // The golden value itself: multiple scattering adds a good part at τ = 3.
        assert!(
            golden > 1.3 * ss && golden < 1.0 / mu_v,
            "golden {golden} vs single {ss}"
        );
        let f = luminance(l.sun_rgb);
        let got = mean_luminance(&full.image) / f;
        let se = full.noise.std_error / 6.0 / f;
        assert!(
            (got - golden).abs() <= 3.0 * (se * se + golden_se * golden_se).sqrt() + 0.01 * golden,
            "path tracer {got} (se {se}) vs plane-parallel Monte Carlo {golden} (se {golden_se})"
        );
        let got_single = mean_luminance(&single.image) / f;
        assert!((got_single - ss).abs() <= 3.0 * single.noise.std_error / 6.0 / f + 0.005 * ss);
    }

    /// One sun for cloud and ground (issue 40): a conservative (albedo 1) deck thick
    /// enough to transmit under 2 % returns what it receives, so its cosine-weighted
    /// mean reflected radiance (its exitance over π) is that of a white Lambertian
    /// ground under the same sun, `sun_rgb · μs` (by the definition of `sun_rgb`: what
    /// a white surface facing the sun reads), less what the deck transmits. Energy
    /// conservation, whatever the code does: a cloud lit by four times the ground's
    /// sun (as before ALGORITHM_VERSION 13) returns four times what it receives.
    /// The hemisphere is integrated by 4-point Gauss–Legendre in μ = cos θv on [0, 1]
    /// (weights of ∫ L μ dμ) and 6 azimuths, each an orthographic view looking down.
    #[test]
    fn one_sun_a_conservative_deck_reflects_what_a_white_ground_does() {
        let theta_s: f64 = 30.0;
        let mu_s = theta_s.to_radians().cos();
        let isotropic = Phase {
            g1: 0.0,
            g2: 0.0,
            mix: 0.5,
        };
        // τ = 150: diffuse transmission ≈ (4/3)(μs + 0.71) / (τ + 1.42) ≈ 1.4 %
        // (the two-stream asymptote for a conservative isotropic slab).
        let rho = 30.0f32;
        let l = slab_lighting(theta_s, 1.0, isotropic);
        let env = sun_only(&l);
        // Gauss–Legendre nodes and weights on [0, 1].
        let nodes: [f64; 4] = [0.069_431_844_2, 0.330_009_478_2, 0.669_990_521_8, 0.930_568_155_8];
        let weights = [0.173_927_422_6, 0.326_072_577_4, 0.326_072_577_4, 0.173_927_422_6];
        let azimuths = 6;
        // Above the deck's top (1550 m), so no tilted ray starts inside it.
        let centre = [20_000.0, 20_000.0, 1700.0];
        let (mut sum, mut var) = (0.0, 0.0);
        for (&mu, w) in nodes.iter().zip(weights) {
            let theta_v = mu.acos().to_degrees();
            for a in 0..azimuths {
                let view = looking_down(centre, theta_v, 360.0 * a as f64 / azimuths as f64, 2);
                let traced = render(&[slab(rho)], env, &PathParams::new(512), &view);
                // ∫ L μ dμ dφ / π, with ∫ dφ taken as the mean over azimuths × 2π.
                let k = w * mu * 2.0 / azimuths as f64;
                sum += k * mean_luminance(&traced.image);
                var += (k * traced.noise.std_error / 2.0).powi(2);
            }
        }
        let ground = luminance(l.sun_rgb) * mu_s;
        let se = var.sqrt();
        assert!(se < 0.01 * ground, "noise {se} against {ground}");
        let ratio = sum / ground;
        // Returned: 1 − transmitted (≤ 2 %), within 5 % as the issue asks; a deck lit
        // by four times the ground's sun would read about 4.
        assert!(
            (0.95..=1.0 + 3.0 * se / ground).contains(&ratio),
            "deck {sum} (se {se}) against a white ground {ground}: ratio {ratio}"
        );
    }

    /// A lumpy cloud: 24 × 24 × 10 cells of 50 m, density up to 1 in a ball, uneven.
    fn lumpy() -> Volume {
        volume([24, 24, 10], 50.0, 50.0, 1000.0, |c, r, k| {
            let (x, y, z) = (c as f64 - 11.5, r as f64 - 11.5, (k as f64 - 4.5) * 2.0);
            let fall = (1.0 - (x * x + y * y + z * z).sqrt() / 11.0).max(0.0);
            (fall * (0.3 + 0.7 * noise(c, r, k) as f64)) as f32
        })
    }

    fn lumpy_view(width: usize, height: usize) -> View {
        let camera = Camera::new([600.0, -900.0, 1300.0], 0.0, -5.0, 50.0).unwrap();
        View::perspective(&camera, width, height)
    }

    #[test]
    fn single_scattering_equals_the_marcher_in_expectation() {
        // Sun only (no ambient, sky or ground): the marcher's Σ T (1 − e^{−σΔ}) · albedo ·
        // sun · T_sun · p, at a fine step, against the path tracer's one-scattering
        // estimate of the same integral.
        let params = ShadingParams {
            extinction: 0.004,
            ..ShadingParams::default()
        };
        let mut l = lighting(Sun::new(150.0, 35.0).unwrap(), params);
        l.ambient_rgb = [0.0; 3];
        let view = lumpy_view(12, 8);
        let vol = lumpy();
        // No air on either side: the uniform (black) test sky has none.
        let step = MarchParams::with_step(50.0 / 16.0);
        let never = Cancel::never();
        let marched = march::render_with_air(std::slice::from_ref(&vol), &l, &step, &view, false, false, &never);
        let traced = render(&[vol], sun_only(&l), &PathParams::single_scattering(1024), &view);
        let (a, b) = (mean_luminance(&traced.image), mean_luminance(&marched));
        let n = traced.image.rgb.len() as f64;
        let se = traced.noise.std_error / n.sqrt();
        assert!(b > 0.005, "the cloud is lit: {b}");
        assert!(
            (a - b).abs() <= 3.0 * se + 0.01 * b,
            "path tracer {a} (se {se}) vs marcher {b}"
        );
        // Per pixel, within 4 stated standard errors (the per-pixel error is within a
        // factor 2 of the mean one here) and 2 % for the marcher's step.
        for (p, q) in traced.image.rgb.iter().zip(&marched.rgb) {
            let (x, y) = (luminance(p.map(|v| v as f64)), luminance(q.map(|v| v as f64)));
            assert!((x - y).abs() <= 8.0 * traced.noise.std_error + 0.02 * y, "{x} vs {y}");
        }
    }

    fn world_like(l: &Lighting) -> Environment<'_> {
        Environment::world(l)
    }

    #[test]
    fn error_falls_as_one_over_root_samples() {
        let l = lighting(Sun::new(150.0, 35.0).unwrap(), ShadingParams::default());
        let (w, h) = (16, 12);
        let view = lumpy_view(w, h);
        let vols = [lumpy()];
        let truth = render(&vols, world_like(&l), &PathParams::new(1024), &view).image;
        let mut pts = Vec::new();
        for n in [4u32, 16, 64] {
            let img = render(&vols, world_like(&l), &PathParams::new(n), &view).image;
            let mse = img
                .rgb
                .iter()
                .zip(&truth.rgb)
                .map(|(a, b)| (luminance(a.map(|v| v as f64)) - luminance(b.map(|v| v as f64))).powi(2))
                .sum::<f64>()
                / (w * h) as f64;
            pts.push(((n as f64).ln(), mse.sqrt().ln()));
        }
        // Least-squares slope of log RMSE against log samples.
        let (mx, my) = (
            pts.iter().map(|p| p.0).sum::<f64>() / 3.0,
            pts.iter().map(|p| p.1).sum::<f64>() / 3.0,
        );
        let slope = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>()
            / pts.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>();
        assert!((-0.65..=-0.35).contains(&slope), "slope {slope}: {pts:?}");
    }

    #[test]
    fn the_same_bytes_on_one_and_three_threads() {
        let l = lighting(Sun::new(150.0, 35.0).unwrap(), ShadingParams::default());
        let view = lumpy_view(10, 7);
        let vols = [lumpy()];
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| render(&vols, world_like(&l), &PathParams::new(8), &view))
        };
        let (a, b) = (run(1), run(3));
        assert_eq!(a.image.to_png_with_noise(&a.noise), b.image.to_png_with_noise(&b.noise));
        assert_eq!(a.noise, b.noise);
        let bits = |t: &Traced| t.image.rgb.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a), bits(&b));
    }

    /// Near the largest accepted camera coordinate (1e12 m).
    const FAR: f64 = 1e12 - 5_000.0;

    #[test]
    fn extremes_are_finite() {
        let far = {
            let mut v = lumpy();
            let shift = FAR;
            v.place.x0 += shift;
            v.place.y0 += shift;
            Volume::new(
                v.grid,
                v.place,
                [
                    v.bounds[0] + shift,
                    v.bounds[1] + shift,
                    v.bounds[2],
                    v.bounds[3] + shift,
                    v.bounds[4] + shift,
                    v.bounds[5],
                ],
            )
        };
        let empty = volume([8, 8, 4], 50.0, 50.0, 1000.0, |_, _, _| 0.0);
        let wild = Phase {
            g1: 1.0,
            g2: -1.0,
            mix: f64::NAN,
        };
        for (vol, eye) in [
            (lumpy(), [600.0, -900.0, 1300.0]),
            (empty, [200.0, -500.0, 1100.0]),
            (far, [FAR + 600.0, FAR - 900.0, 1300.0]),
        ] {
            for el in [-90.0, -10.0, -3.0, 0.0, 1e-9, 90.0] {
                for (extinction, albedo) in [
                    (0.0, 0.9),
                    (1e300, 0.9),
                    (f64::INFINITY, 1.0),
                    (f64::NAN, f64::NAN),
                    (0.01, 1.0),
                ] {
                    let params = ShadingParams {
                        extinction,
                        albedo,
                        phase: wild,
                        ..ShadingParams::default()
                    };
                    let l = lighting(Sun::new(30.0, el).unwrap(), params);
                    let camera = Camera::new(eye, 0.0, -5.0, 50.0).unwrap();
                    let view = View::perspective(&camera, 4, 3);
                    let t = render(std::slice::from_ref(&vol), world_like(&l), &PathParams::new(4), &view);
                    assert!(
                        t.image
                            .rgb
                            .iter()
                            .flatten()
                            .all(|v| v.is_finite() && *v >= 0.0 && *v < 50.0),
                        "el {el} ext {extinction}: {:?}",
                        t.image.rgb
                    );
                    assert!(t.noise.std_error.is_finite() && t.noise.mean_luminance.is_finite());
                }
            }
        }
    }
}
