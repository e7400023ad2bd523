//! Splats: the footprint of one metaball seen from any direction (Rosa 2013 §4.2.3,
//! 256 splats of 65×65; Dobashi 2000 §5).
//!
//! The line integral of Wyvill's field function through a unit ball at impact
//! parameter `p` (distance of the line from the centre, in radii) is, with `q = p²`
//! and `L = √(1 − q)`, the closed form
//!
//! ```text
//! S(p) = −4/9·2(q³L + q²L³ + 3qL⁵/5 + L⁷/7) + 17/9·2(q²L + 2qL³/3 + L⁵/5)
//!        − 22/9·2(qL + L³/3) + 2L
//! ```
//!
//! (expand `f(√(q + t²))` in t and integrate over `[−L, L]`); `S(0) = 0.998942…`.
//!
//! A ball whose line of sight through the centre has optical depth `τ` has opacity
//! `α(p) = 1 − exp(−τ · S(p) / S(0))` at impact parameter `p`. Splat `k` of a sheet of
//! `N` is that opacity for `τ_k = TAU_MAX · ((k + 1) / N)²` — squared so that thin,
//! nearly transparent balls get fine steps. Within a layer τ is proportional to the
//! metaball's density, so the splat index is the density, quantised.

/// Centre optical depth of the densest splat. Balls beyond it use the last splat
/// (opacity at the centre 1 − e⁻⁸ ≈ 0.9997).
pub const TAU_MAX: f64 = 8.0;

/// The line integral of the field function through a unit ball at impact parameter
/// `p` (0 at the centre, 1 at the rim); 0 for `|p| >= 1` or NaN.
pub fn line_integral(p: f64) -> f64 {
    if !(p.abs() < 1.0) {
        return 0.0;
    }
    let q = p * p;
    let l = (1.0 - q).sqrt();
    let (l2, l3) = (l * l, l * l * l);
    let (l5, l7) = (l3 * l2, l3 * l2 * l2);
    let a3 = 2.0 * (q * q * q * l + q * q * l3 + 3.0 * q * l5 / 5.0 + l7 / 7.0);
    let a2 = 2.0 * (q * q * l + 2.0 * q * l3 / 3.0 + l5 / 5.0);
    let a1 = 2.0 * (q * l + l3 / 3.0);
    ((-4.0 / 9.0) * a3 + (17.0 / 9.0) * a2 - (22.0 / 9.0) * a1 + 2.0 * l).max(0.0)
}

/// The part of [`line_integral`] that lies beyond `v0` along the line: the integral
/// of the field function over `v ∈ [v0, L]`, where `v` is the signed distance along
/// the line from its closest approach to the centre (in radii) and `L = √(1 − p²)`.
/// `v0 <= −L` gives the whole chord, `v0 >= L` nothing. This is what an eye inside (or
/// beside) a ball sees along a ray: only the chord in front of it.
///
/// Same expansion as `S(p)`: with `q = p²`, `f(√(q + v²)) = c0 + c2 v² + c4 v⁴ + c6 v⁶`
/// where `c0 = f(√q)`, `c2 = −22/9 + 34/9 q − 4/3 q²`, `c4 = 17/9 − 4/3 q`,
/// `c6 = −4/9`; its antiderivative is odd, `P(v) = c0 v + c2 v³/3 + c4 v⁵/5 + c6 v⁷/7`.
pub fn line_integral_beyond(p: f64, v0: f64) -> f64 {
    if !(p.abs() < 1.0) || v0.is_nan() {
        return 0.0;
    }
    let q = p * p;
    let l = (1.0 - q).sqrt();
    let c0 = 1.0 - 22.0 / 9.0 * q + 17.0 / 9.0 * q * q - 4.0 / 9.0 * q * q * q;
    let c2 = -22.0 / 9.0 + 34.0 / 9.0 * q - 4.0 / 3.0 * q * q;
    let c4 = 17.0 / 9.0 - 4.0 / 3.0 * q;
    let c6 = -4.0 / 9.0;
    let antiderivative = |v: f64| {
        let v2 = v * v;
        v * (c0 + v2 * (c2 / 3.0 + v2 * (c4 / 5.0 + v2 * c6 / 7.0)))
    };
    (antiderivative(l) - antiderivative(v0.clamp(-l, l))).max(0.0)
}

/// `S(0)`, the line integral through the centre: `2 · (1 − 22/27 + 17/45 − 4/63)`.
pub fn centre_line_integral() -> f64 {
    2.0 * (1.0 - 22.0 / 27.0 + 17.0 / 45.0 - 4.0 / 63.0)
}

/// A sprite sheet of splat opacities: `count` sprites of `size × size` texels.
#[derive(Clone, Debug, PartialEq)]
pub struct SplatSheet {
    /// Number of sprites.
    pub count: usize,
    /// Side of one sprite in texels (odd, so there is a centre texel).
    pub size: usize,
    /// Opacities, sprite-major then row-major: `alpha[(k · size + v) · size + u]`.
    pub alpha: Vec<f32>,
}

impl SplatSheet {
    /// Builds `count` splats of `size × size` (size is rounded up to odd, at least 3).
    pub fn new(count: usize, size: usize) -> SplatSheet {
        let count = count.max(1);
        let size = (size.max(3)) | 1;
        let c = (size - 1) as f64 / 2.0;
        let s0 = centre_line_integral();
        let profile: Vec<f64> = (0..size * size)
            .map(|t| {
                let (u, v) = ((t % size) as f64, (t / size) as f64);
                let p = ((u - c).powi(2) + (v - c).powi(2)).sqrt() / c;
                line_integral(p) / s0
            })
            .collect();
        let mut alpha = Vec::with_capacity(count * size * size);
        for k in 0..count {
            let tau = splat_tau(k, count);
            alpha.extend(profile.iter().map(|&s| (1.0 - (-tau * s).exp()) as f32));
        }
        SplatSheet { count, size, alpha }
    }

    /// Centre optical depth of splat `k`.
    pub fn tau(&self, k: usize) -> f64 {
        splat_tau(k, self.count)
    }

    /// The splat whose centre optical depth is nearest `tau` (on the squared scale).
    pub fn index_for_tau(&self, tau: f64) -> usize {
        if !(tau > 0.0) {
            return 0;
        }
        let x = (tau.min(TAU_MAX) / TAU_MAX).sqrt() * self.count as f64 - 1.0;
        (x.round().max(0.0) as usize).min(self.count - 1)
    }

    /// Bilinear opacity of splat `k` at (`dx`, `dy`) in radii from the centre; 0 outside.
    pub fn sample(&self, k: usize, dx: f64, dy: f64) -> f64 {
        if !(dx * dx + dy * dy < 1.0) {
            return 0.0;
        }
        let n = self.size;
        let c = (n - 1) as f64 / 2.0;
        let u = (c + dx * c).clamp(0.0, (n - 1) as f64);
        let v = (c + dy * c).clamp(0.0, (n - 1) as f64);
        let (u0, v0) = ((u.floor() as usize).min(n - 2), (v.floor() as usize).min(n - 2));
        let (fu, fv) = (u - u0 as f64, v - v0 as f64);
        let base = k.min(self.count - 1) * n * n;
        let at = |uu: usize, vv: usize| self.alpha[base + vv * n + uu] as f64;
        let top = at(u0, v0) * (1.0 - fu) + at(u0 + 1, v0) * fu;
        let bottom = at(u0, v0 + 1) * (1.0 - fu) + at(u0 + 1, v0 + 1) * fu;
        top * (1.0 - fv) + bottom * fv
    }
}

fn splat_tau(k: usize, count: usize) -> f64 {
    let x = (k.min(count - 1) + 1) as f64 / count as f64;
    TAU_MAX * x * x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::density::metaballs::wyvill;

    #[test]
    fn line_integral_beyond_is_the_chord_in_front() {
        for &p in &[0.0, 0.3, 0.7, 0.95] {
            let l = (1.0f64 - p * p).sqrt();
            // The whole chord is S(p); nothing beyond the far end.
            assert!((line_integral_beyond(p, -2.0) - line_integral(p)).abs() < 1e-12, "{p}");
            assert_eq!(line_integral_beyond(p, l), 0.0);
            // Against a midpoint sum of the field function over [v0, L].
            for &v0 in &[-0.9 * l, -0.2, 0.0, 0.4 * l] {
                let n = 20_000;
                let h = (l - v0) / n as f64;
                let sum: f64 = (0..n)
                    .map(|i| {
                        let v = v0 + (i as f64 + 0.5) * h;
                        wyvill((p * p + v * v).sqrt()) * h
                    })
                    .sum();
                assert!((line_integral_beyond(p, v0) - sum).abs() < 1e-7, "p {p} v0 {v0}");
            }
        }
        // The field is symmetric: from the closest approach on is half the chord.
        assert!((line_integral_beyond(0.5, 0.0) - line_integral(0.5) / 2.0).abs() < 1e-12);
        assert_eq!(line_integral_beyond(1.0, 0.0), 0.0);
        assert_eq!(line_integral_beyond(f64::NAN, 0.0), 0.0);
        assert_eq!(line_integral_beyond(0.2, f64::NAN), 0.0);
    }

    fn numeric_line_integral(p: f64) -> f64 {
        // Midpoint rule over t in [−1, 1] of f(√(p² + t²)).
        let n = 200_000;
        let h = 2.0 / n as f64;
        (0..n)
            .map(|i| {
                let t = -1.0 + (i as f64 + 0.5) * h;
                wyvill((p * p + t * t).sqrt())
            })
            .sum::<f64>()
            * h
    }

    #[test]
    fn line_integral_matches_numeric_integration() {
        // Tolerance 1e-6 (absolute): the midpoint rule's error at 2·10⁵ steps is ~1e-10.
        for p in [0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 1.0] {
            let a = line_integral(p);
            let b = numeric_line_integral(p);
            assert!((a - b).abs() < 1e-6, "p={p}: {a} vs {b}");
        }
        assert!((line_integral(0.0) - centre_line_integral()).abs() < 1e-12);
        assert_eq!(line_integral(f64::NAN), 0.0);
    }

    #[test]
    fn sheet_profiles_equal_beer_lambert_of_the_line_integral() {
        let sheet = SplatSheet::new(256, 65);
        assert_eq!(sheet.alpha.len(), 256 * 65 * 65);
        let s0 = numeric_line_integral(0.0);
        for k in [0, 17, 128, 255] {
            let tau = sheet.tau(k);
            for (u, v) in [(32, 32), (40, 32), (50, 45), (0, 32), (64, 64)] {
                let p = (((u as f64 - 32.0).powi(2) + (v as f64 - 32.0).powi(2)).sqrt()) / 32.0;
                let expected = 1.0 - (-tau * numeric_line_integral(p) / s0).exp();
                let got = sheet.alpha[(k * 65 + v) * 65 + u] as f64;
                assert!((got - expected).abs() < 1e-5, "k={k} ({u},{v}): {got} vs {expected}");
            }
        }
        // Splats grow with index (density).
        assert!(sheet.sample(10, 0.5, 0.0) < sheet.sample(200, 0.5, 0.0));
        assert_eq!(sheet.sample(10, 1.0, 0.0), 0.0);
    }

    #[test]
    fn index_for_tau_inverts_tau() {
        let sheet = SplatSheet::new(128, 33);
        for k in [0, 5, 64, 127] {
            assert_eq!(sheet.index_for_tau(sheet.tau(k)), k);
        }
        assert_eq!(sheet.index_for_tau(f64::INFINITY), 127);
        assert_eq!(sheet.index_for_tau(f64::NAN), 0);
        assert_eq!(sheet.index_for_tau(0.0), 0);
    }
}
