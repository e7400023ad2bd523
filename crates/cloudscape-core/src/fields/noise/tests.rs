use super::*;

fn c(v: f64) -> Coord {
    Coord::new(0, v)
}

/// Random numbers for the tests (splitmix64).
struct Draws(u64);

impl Draws {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        mix64(self.0)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
    fn pick<T: Copy>(&mut self, v: &[T]) -> T {
        v[(self.next() % v.len() as u64) as usize]
    }
    /// A lattice index near the origin, near ±2^40 or ±2^62, or at i64's ends.
    fn int(&mut self) -> i64 {
        let near = self.pick(&[0, 1 << 40, -(1 << 40), 1 << 62, -(1 << 62), i64::MAX, i64::MIN]);
        near.wrapping_add((self.next() % 2001) as i64 - 1000)
    }
    /// A fraction in [0, 1): 0, tiny, just below 1 or anything.
    fn frac(&mut self) -> f64 {
        match self.next() % 6 {
            0 => 0.0,
            1 => self.pick(&[5e-324, 1e-300, 1e-17, 2.0f64.powi(-53)]),
            2 => 1.0 - self.pick(&[2.0f64.powi(-53), 2.0f64.powi(-52), 1e-15]),
            _ => self.unit(),
        }
    }
    fn coord(&mut self) -> Coord {
        Coord {
            int: self.int(),
            frac: self.frac(),
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[test]
fn simplex_avx512_has_the_scalar_bits() {
    if !NoiseBackend::Avx512.runs_here() {
        eprintln!("skipped: this CPU has no AVX-512, so only the scalar noise runs here");
        return;
    }
    let mut d = Draws(1);
    for _ in 0..20_000 {
        let seed = d.next();
        // Mostly nearby lattice points, so that all four corners matter.
        let x: [Coord; 8] = if d.next().is_multiple_of(2) {
            std::array::from_fn(|_| d.coord())
        } else {
            let c = d.coord();
            std::array::from_fn(|_| Coord::new(c.int, c.frac + d.unit() * 3.0 - 1.5))
        };
        let (y, z) = (d.coord(), d.coord());
        // Half of the draws in 2D.
        let z = if d.next().is_multiple_of(2) { Some(z) } else { None };
        // SAFETY: the CPU has AVX-512 F and DQ (checked above).
        let fast = unsafe { avx512::noise_x8(seed, x, y, z) };
        for (l, &x) in x.iter().enumerate() {
            let want = match z {
                Some(z) => simplex3(seed, x, y, z),
                None => simplex2(seed, x, y),
            };
            assert_eq!(
                fast[l].to_bits(),
                want.to_bits(),
                "{seed} {x:?} {y:?} {z:?}: {} {want}",
                fast[l]
            );
        }
    }
}

#[test]
fn fbm_grid_has_the_bits_of_sample_table_on_every_backend() {
    let mut d = Draws(2);
    for round in 0..400 {
        let fbm = Fbm {
            seed: d.next(),
            scale: d.pick(&[1.0, 0.5, 0.05, 0.003, 1e-4]) * (0.5 + d.unit()),
            octaves: 1 + (d.next() % 5) as u32,
            lacunarity: d.pick(&[2.0, 2.3, 1.9]),
            gain: d.pick(&[0.5, 0.6]),
            offset: [d.unit() * 100.0 - 50.0, d.unit() * 100.0 - 50.0],
        };
        let table = fbm.table();
        let octaves = 1 + (d.next() % 6) as u32;
        let cols = 1 + (d.next() % 21) as usize;
        let xs: Vec<(i64, f64)> = (0..cols).map(|_| (d.int(), d.frac())).collect();
        let tau = match round % 4 {
            0 => None,
            1 => Some(Coord::new(0, d.unit() * 1000.0)),
            2 => Some(Coord::new(0, -d.unit() * 1000.0)),
            _ => Some(d.coord()),
        };
        for &backend in NoiseBackend::available() {
            let grid = FbmGrid::new(&table, octaves, &xs, backend);
            let mut out = vec![0.0; cols];
            for _ in 0..3 {
                let y = (d.int(), d.frac());
                grid.row(y, tau, &mut out);
                for (c, &x) in xs.iter().enumerate() {
                    let want = sample_table(&table, octaves, x, y, tau);
                    assert_eq!(
                        out[c].to_bits(),
                        want.to_bits(),
                        "{backend:?} {fbm:?} {x:?} {y:?} {tau:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn coord_normalises_fraction() {
    let a = Coord::new(5, -0.25);
    assert_eq!((a.int, a.frac), (4, 0.75));
    let b = Coord::new(-3, 2.5);
    assert_eq!((b.int, b.frac), (-1, 0.5));
    let tiny = Coord::new(0, -1e-300);
    assert!(tiny.frac < 1.0 && tiny.frac >= 0.0);
}

#[test]
fn two_product_is_exact_against_i128() {
    // Integers times a dyadic-friendly scale: the exact product is representable
    // as p + err, which we check in i128 fixed point.
    for &(a, b) in &[(3_000_000_007.0f64, 1234567.0f64), ((1u64 << 52) as f64 - 1.0, 3.0)] {
        let (p, e) = two_product(a, b);
        let exact = a as i128 * b as i128;
        assert_eq!(p as i128 + e as i128, exact);
    }
}

#[test]
fn scaled_keeps_fraction_far_from_origin() {
    // (2^40 + 0.5) * 0.1 = 109951162777.6 + 0.05: fraction 0.65, plus 6e-6 from
    // 0.1's own rounding in f64. A plain f64 product would keep only ~1e-5.
    let far = Coord::scaled(1 << 40, 0.5, 0.1);
    assert_eq!(far.int, 109_951_162_777);
    assert!((far.frac - 0.650_006).abs() < 1e-6, "{}", far.frac);
}

#[test]
fn simplex_is_bounded_and_varies() {
    let mut min: f64 = 1.0;
    let mut max: f64 = -1.0;
    for i in 0..2000 {
        let v = simplex2(7, c(i as f64 * 0.173), c(i as f64 * 0.091));
        let w = simplex3(7, c(i as f64 * 0.173), c(i as f64 * 0.091), c(i as f64 * 0.05));
        assert!((-1.0..=1.0).contains(&v) && (-1.0..=1.0).contains(&w));
        min = min.min(v);
        max = max.max(v);
    }
    assert!(max > 0.5 && min < -0.5, "range {min}..{max}");
}

#[test]
fn simplex_is_continuous() {
    let base = Coord::new(1 << 40, 0.3);
    let a = simplex2(3, base, c(0.7));
    let b = simplex2(3, Coord::new(1 << 40, 0.3 + 1e-7), c(0.7));
    assert!((a - b).abs() < 1e-4);
    let a3 = simplex3(3, base, c(0.7), c(0.2));
    let b3 = simplex3(3, base, c(0.7 + 1e-7), c(0.2));
    assert!((a3 - b3).abs() < 1e-4);
}

#[test]
fn split_and_plain_coordinates_agree_near_origin() {
    // The same point given as (int, frac) and as a plain fraction.
    for i in 0..50 {
        let x = i as f64 * 0.37;
        let a = simplex2(11, Coord::new(0, x), Coord::new(0, 1.3));
        let b = simplex2(11, Coord::new(x.floor() as i64, x - x.floor()), Coord::new(1, 0.3));
        assert!((a - b).abs() < 1e-12, "{a} {b}");
    }
}
