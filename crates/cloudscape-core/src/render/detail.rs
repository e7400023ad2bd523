//! Detail erosion of metaball edges: the cauliflower edges of cumulus that a lattice
//! of smooth balls cannot carry.
//!
//! Schneider's Nubis erosion (Schneider & Vos 2015, "The real-time volumetric
//! cloudscapes of Horizon Zero Dawn", SIGGRAPH course; Schneider 2017, "Nubis"):
//! a base density `d` in [0, 1] is remapped by a detail noise `n` in [0, 1] as
//! `remap(d, n · (1 − d), 1, 0, 1) = (d − n(1 − d)) / (1 − n(1 − d))` (clamped to
//! [0, 1]), which eats the thin rims (`d` small) and leaves the core (`d` → 1)
//! alone. The noise is Rosa 2013 §4.1's fBm (Perlin's "sum of octaves", as in
//! Ragnemalm's cloud noise) over the project's 3-D simplex noise on split
//! coordinates (`fields::noise`): a pure function of the world point, so two tiles
//! give the same value at a shared point, and exact at any distance from the origin
//! (the lattice index is an `i64`, the fraction an `f64`).
//!
//! Here `d` is a billboard's normalised column density `S(p)/S(0)` at the pixel
//! (1 at the centre, 0 at the rim), and the noise is sampled at the pixel's point on
//! the billboard's plane. Octaves start at a wavelength of one metaball radius and
//! halve; only octaves whose wavelength spans at least [`MIN_WAVELENGTH_PIXELS`] of
//! the pixel footprint are summed (Szécsi's footprint rule: detail finer than the
//! pixel would only alias), so far billboards cost one octave and near ones up to
//! [`MAX_DETAIL_OCTAVES`].

use crate::fields::noise::{Coord, mix64, simplex3};

/// Seed of the detail noise (a presentation detail, the same for every world).
pub const DETAIL_SEED: u64 = 0x6465_7461_696c_2d31;

/// Most fBm octaves of the detail noise.
pub const MAX_DETAIL_OCTAVES: u32 = 4;

/// An octave is summed while its wavelength spans at least this many pixels.
pub const MIN_WAVELENGTH_PIXELS: f64 = 2.0;

/// Nubis's erosion: `remap(d, n·(1 − d), 1, 0, 1)` for `d`, `n` in [0, 1] (inputs
/// clamped; NaN counts as 0). Never more than `d`: erosion only removes density.
pub fn erode(d: f64, n: f64) -> f64 {
    let d = if d.is_finite() { d.clamp(0.0, 1.0) } else { 0.0 };
    let n = if n.is_finite() { n.clamp(0.0, 1.0) } else { 0.0 };
    let lo = n * (1.0 - d);
    if lo >= 1.0 {
        return 0.0;
    }
    ((d - lo) / (1.0 - lo)).clamp(0.0, d)
}

/// The number of octaves whose wavelength (`wavelength`, then halving) spans at
/// least [`MIN_WAVELENGTH_PIXELS`] pixels of `metres_per_pixel`; 0 when even the
/// first does not (or for non-finite input).
pub fn octaves_for(wavelength: f64, metres_per_pixel: f64) -> u32 {
    if !(wavelength > 0.0 && wavelength.is_finite() && metres_per_pixel > 0.0) {
        return 0;
    }
    let mut n = 0;
    let mut w = wavelength;
    while n < MAX_DETAIL_OCTAVES && w >= MIN_WAVELENGTH_PIXELS * metres_per_pixel {
        n += 1;
        w *= 0.5;
    }
    n
}

/// A world coordinate divided by `wavelength`, as a lattice coordinate.
fn lattice(x: f64, inv_wavelength: f64) -> Coord {
    let v = x * inv_wavelength;
    let f = v.floor();
    Coord::new(f as i64, v - f)
}

/// fBm detail noise in [0, 1] at world point `p` (metres): `octaves` octaves of 3-D
/// simplex noise, the first of wavelength `wavelength` metres, lacunarity 2, gain ½,
/// mapped from [−1, 1] to [0, 1]. 0.5 for no octaves. Deterministic, a pure
/// function of its arguments.
pub fn noise(p: [f64; 3], wavelength: f64, octaves: u32) -> f64 {
    let octaves = octaves.min(MAX_DETAIL_OCTAVES);
    if octaves == 0 || !(wavelength > 0.0 && wavelength.is_finite()) || !p.iter().all(|v| v.is_finite()) {
        return 0.5;
    }
    let (mut sum, mut norm, mut amp, mut inv) = (0.0, 0.0, 1.0, 1.0 / wavelength);
    for o in 0..octaves {
        let seed = mix64(DETAIL_SEED.wrapping_add(o as u64));
        let n = simplex3(seed, lattice(p[0], inv), lattice(p[1], inv), lattice(p[2], inv));
        sum += amp * n;
        norm += amp;
        amp *= 0.5;
        inv *= 2.0;
    }
    (0.5 + 0.5 * sum / norm).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erosion_only_removes_and_keeps_the_ends() {
        for i in 0..=100 {
            let d = i as f64 / 100.0;
            for j in 0..=100 {
                let n = j as f64 / 100.0;
                let e = erode(d, n);
                assert!(e.is_finite() && (0.0..=d).contains(&e), "d={d} n={n}: {e}");
            }
            // No noise, no erosion; the core (d = 1) is never eroded.
            assert!((erode(d, 0.0) - d).abs() < 1e-12);
        }
        assert_eq!(erode(1.0, 1.0), 1.0);
        assert_eq!(erode(0.0, 0.3), 0.0);
        // Hand value: d = 0.5, n = 0.5: lo = 0.25, (0.5 − 0.25) / 0.75 = 1/3.
        assert!((erode(0.5, 0.5) - 1.0 / 3.0).abs() < 1e-12);
        for bad in [f64::NAN, f64::INFINITY, -1.0, 2.0] {
            assert!(erode(bad, 0.5).is_finite() && erode(0.5, bad).is_finite());
        }
    }

    #[test]
    fn noise_is_bounded_varied_and_a_function_of_the_world_point() {
        let mut lo: f64 = 1.0;
        let mut hi: f64 = 0.0;
        for i in 0..2000 {
            let p = [
                i as f64 * 37.3,
                (i * 7 % 101) as f64 * 11.1,
                1500.0 + (i % 13) as f64 * 9.0,
            ];
            let v = noise(p, 150.0, 4);
            assert!((0.0..=1.0).contains(&v));
            lo = lo.min(v);
            hi = hi.max(v);
        }
        assert!(hi - lo > 0.5, "{lo}..{hi}");
        // Far from the origin (1e9 m) the field is still detailed (no lost fraction):
        // neighbours 10 m apart differ, and a point has one value.
        let far = [1e9 + 3.0, -2e9 + 5.0, 2000.0];
        let a = noise(far, 150.0, 4);
        let b = noise([far[0] + 10.0, far[1], far[2]], 150.0, 4);
        assert!(a != b && a == noise(far, 150.0, 4));
        assert_eq!(noise([f64::NAN, 0.0, 0.0], 150.0, 4), 0.5);
        assert_eq!(noise(far, 150.0, 0), 0.5);
    }

    #[test]
    fn noise_is_seamless_across_tile_boundaries() {
        // A tile edge at level 0 (256 columns of 100 m) and one 2^40 m out: walking
        // across it in 1 m steps the field moves by a little each step (no seam), and
        // the point on the edge has one value whichever tile's origin it is taken from.
        for edge in [25_600.0, 1_099_511_627_776.0] {
            let wavelength = 187.5;
            let mut last = noise([edge - 50.0, 3_000.0, 1_500.0], wavelength, 4);
            for i in -49..=50 {
                let v = noise([edge + i as f64, 3_000.0, 1_500.0], wavelength, 4);
                assert!((v - last).abs() < 0.06, "edge {edge} step {i}: {last} -> {v}");
                last = v;
            }
            let from_west = (edge - 25_600.0) + 25_600.0;
            let from_east = edge + 0.0;
            assert_eq!(
                noise([from_west, 10.0, 1_200.0], wavelength, 3),
                noise([from_east, 10.0, 1_200.0], wavelength, 3)
            );
        }
    }

    #[test]
    fn octaves_follow_the_pixel_footprint() {
        assert_eq!(octaves_for(200.0, 1000.0), 0);
        assert_eq!(octaves_for(200.0, 100.0), 1);
        assert_eq!(octaves_for(200.0, 50.0), 2);
        assert_eq!(octaves_for(200.0, 0.01), MAX_DETAIL_OCTAVES);
        assert_eq!(octaves_for(f64::NAN, 1.0), 0);
        assert_eq!(octaves_for(200.0, 0.0), 0);
    }
}
