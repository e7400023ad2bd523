//! Why the noise is our own: the failure that made us, kept as a test.
//!
//! The `noise` crate hashes lattice points through a 256-entry permutation table,
//! so its fields repeat every 256 lattice units: two storms 256 noise units apart
//! would be identical (fastnoise-lite has the same kind of limit at 2^31, with
//! `i32` lattice indices). Ours hashes full `i64` lattice indices and keeps the
//! fraction exact, so a field 2^40 cells out is as well-formed as at the origin.

use cloudscape_core::fields::noise::{Coord, Fbm, simplex2, simplex3};
use noise::{NoiseFn, Perlin, Simplex};

#[test]
fn the_noise_crate_repeats_every_256_lattice_units() {
    // Perlin: a square lattice, so the period is 256 input units (equal up to the
    // rounding of x + 256 in f64).
    let p = Perlin::new(7);
    // Simplex: the lattice is skewed, so the period is the lattice vector (256, 0)
    // unskewed: (256·(1 − G2), −256·G2), with G2 = (3 − √3)/6.
    let s = Simplex::new(7);
    let g2 = (3.0 - 3f64.sqrt()) / 6.0;
    let (mut perlin_repeats, mut simplex_repeats) = (0, 0);
    for i in 0..100 {
        let (x, y) = (i as f64 * 0.731 + 0.1, i as f64 * 0.377 + 0.2);
        let same = |a: f64, b: f64| (a - b).abs() < 1e-9;
        if same(p.get([x, y]), p.get([x + 256.0, y])) && same(p.get([x, y]), p.get([x, y + 256.0 * 1024.0])) {
            perlin_repeats += 1;
        }
        if same(s.get([x, y]), s.get([x + 256.0 * (1.0 - g2), y - 256.0 * g2])) {
            simplex_repeats += 1;
        }
    }
    assert_eq!(
        perlin_repeats, 100,
        "the crate's Perlin field is periodic: the failure that made us"
    );
    assert_eq!(simplex_repeats, 100, "the crate's Simplex field is periodic too");
}

#[test]
fn ours_does_not_repeat_at_any_power_of_two() {
    for shift in [256i64, 1 << 16, 1 << 31, 1 << 32, 1 << 40] {
        let mut same = 0;
        for i in 0..100 {
            let (x, y) = (
                Coord::new(0, i as f64 * 0.731 + 0.1),
                Coord::new(0, i as f64 * 0.377 + 0.2),
            );
            let far = Coord::new(shift, x.frac + x.int as f64);
            if simplex2(7, x, y) == simplex2(7, far, y) {
                same += 1;
            }
        }
        assert!(same < 5, "shift {shift}: {same} of 100 samples repeat");
    }
}

#[test]
fn f32_coordinates_lose_the_fraction_far_out() {
    // What a float-coordinate pipeline does to a cell centre 2^40 cells out.
    let x = (1u64 << 40) as f64 + 0.5;
    assert_eq!(x as f32 as f64, (1u64 << 40) as f64, "the half cell is gone in f32");
    // Ours keeps it exactly.
    let c = Coord::scaled(1 << 40, 0.5, 1.0);
    assert_eq!((c.int, c.frac), (1 << 40, 0.5));
}

fn stats(origin: i64) -> (f64, f64, f64) {
    let fbm = Fbm {
        seed: 11,
        scale: 0.02,
        octaves: 4,
        lacunarity: 2.0,
        gain: 0.5,
        offset: [0.0, 0.0],
    };
    let mut v = Vec::new();
    let mut max_step: f64 = 0.0;
    for j in 0..96 {
        let mut prev: Option<f64> = None;
        for i in 0..96 {
            let s = fbm.sample(
                4,
                (origin + i * 3, 0.5),
                (origin - j * 3, 0.5),
                Some(Coord::new(origin / 7, 0.25)),
            );
            if let Some(p) = prev {
                max_step = max_step.max((s - p).abs());
            }
            prev = Some(s);
            v.push(s);
        }
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
    (mean, sd, max_step)
}

#[test]
fn fields_far_out_are_as_well_formed_as_near_the_origin() {
    let (m0, s0, d0) = stats(0);
    for origin in [1i64 << 40, -(1i64 << 40), (1i64 << 46) - 12345] {
        let (m, s, d) = stats(origin);
        assert!(m.is_finite() && s.is_finite());
        assert!((m - m0).abs() < 0.15, "mean {m} vs {m0} at {origin}");
        assert!(s > 0.5 * s0 && s < 2.0 * s0, "spread {s} vs {s0} at {origin}");
        // Still continuous: neighbouring samples 3 cells apart change as little as near 0.
        assert!(d < 2.0 * d0 + 0.05, "step {d} vs {d0} at {origin}");
    }
    let v = simplex3(
        1,
        Coord::new(1 << 46, 0.3),
        Coord::new(-(1 << 46), 0.9),
        Coord::new(1 << 40, 0.1),
    );
    assert!(v.is_finite() && (-1.0..=1.0).contains(&v));
}
