//! Simplex noise (2D and 3D) and fBm on split coordinates: an `i64` lattice index
//! plus an `f64` fraction in [0, 1).
//!
//! Why our own and not a crate: `noise` hashes lattice points through a 256-entry
//! permutation table (the field repeats every 256 lattice units), and
//! fastnoise-lite floors coordinates into `i32` (it wraps past 2^31 lattice units)
//! and feeds raw world coordinates through one float, so a field 2^40 cells from
//! the origin loses its fraction. `tests/fields_precision.rs` keeps the failure
//! that made us. Here lattice points are hashed as full `i64`s and the skew of
//! the simplex grid is applied to the integer and fractional parts separately,
//! so the fraction keeps full precision at any distance.
//!
//! Gustavson, "Simplex noise demystified" (2005), for the algorithm and scaling.

/// A coordinate on the noise lattice: `int + frac`, with `frac` in [0, 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coord {
    pub int: i64,
    pub frac: f64,
}

impl Coord {
    /// `int + frac` with any finite `frac`, normalised so that `frac` is in [0, 1).
    #[inline]
    pub fn new(int: i64, frac: f64) -> Coord {
        let f = frac.floor();
        let mut c = Coord {
            int: int.wrapping_add(f as i64),
            frac: frac - f,
        };
        // `frac - floor(frac)` can round up to exactly 1.0 for tiny negative fractions.
        if c.frac >= 1.0 {
            c.int = c.int.wrapping_add(1);
            c.frac -= 1.0;
        }
        c
    }

    /// `(cell + cell_frac) * scale` as a lattice coordinate, keeping the fraction
    /// exact to a few ulps even when `cell * scale` is far beyond f64's fraction
    /// precision (|cell| up to 2^52).
    #[inline]
    pub fn scaled(cell: i64, cell_frac: f64, scale: f64) -> Coord {
        let (p, err) = two_product(cell as f64, scale);
        let fl = p.floor();
        Coord::new(fl as i64, (p - fl) + err + cell_frac * scale)
    }

    /// Adds a real offset (for example a per-octave shift).
    #[inline]
    pub fn offset(self, d: f64) -> Coord {
        let fl = d.floor();
        Coord::new(self.int.wrapping_add(fl as i64), self.frac + (d - fl))
    }
}

/// Dekker's exact product: `a * b = p + err` exactly, with `p = fl(a * b)`.
/// Pure f64 arithmetic (no FMA), so it is the same on every machine.
#[inline]
pub fn two_product(a: f64, b: f64) -> (f64, f64) {
    const SPLIT: f64 = 134217729.0; // 2^27 + 1
    let p = a * b;
    let split = |x: f64| {
        let c = SPLIT * x;
        let hi = c - (c - x);
        (hi, x - hi)
    };
    let (ah, al) = split(a);
    let (bh, bl) = split(b);
    let err = ((ah * bh - p) + ah * bl + al * bh) + al * bl;
    (p, err)
}

/// A 64-bit finaliser (splitmix64 / Stafford variant 13): every input bit
/// affects every output bit.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Hash of a seed and up to three lattice indices: the indices are spread by
/// odd multipliers into one word and finalised once (every input bit reaches
/// every output bit; no table, so no period).
#[inline]
fn hash3(seed: u64, i: i64, j: i64, k: i64) -> u64 {
    mix64(
        seed ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
            ^ (j as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f).rotate_left(21)
            ^ (k as u64).wrapping_mul(0x1656_67b1_9e37_79f9).rotate_left(42),
    )
}

// 2D gradients: 16 unit vectors evenly spaced on the circle.
const GRAD2: [[f64; 2]; 16] = {
    let mut g = [[0.0; 2]; 16];
    // cos/sin of k * 22.5°, written out so the table is exact and const.
    let c = [
        1.0,
        0.923_879_532_511_286_7,
        0.707_106_781_186_547_6,
        0.382_683_432_365_089_8,
        0.0,
        -0.382_683_432_365_089_8,
        -0.707_106_781_186_547_6,
        -0.923_879_532_511_286_7,
        -1.0,
        -0.923_879_532_511_286_7,
        -0.707_106_781_186_547_6,
        -0.382_683_432_365_089_8,
        0.0,
        0.382_683_432_365_089_8,
        0.707_106_781_186_547_6,
        0.923_879_532_511_286_7,
    ];
    let mut k = 0;
    while k < 16 {
        g[k] = [c[k], c[(k + 12) % 16]];
        k += 1;
    }
    g
};

// 3D gradients: the 12 cube-edge midpoints (Gustavson 2005), padded to 16.
const GRAD3: [[f64; 3]; 16] = [
    [1.0, 1.0, 0.0],
    [-1.0, 1.0, 0.0],
    [1.0, -1.0, 0.0],
    [-1.0, -1.0, 0.0],
    [1.0, 0.0, 1.0],
    [-1.0, 0.0, 1.0],
    [1.0, 0.0, -1.0],
    [-1.0, 0.0, -1.0],
    [0.0, 1.0, 1.0],
    [0.0, -1.0, 1.0],
    [0.0, 1.0, -1.0],
    [0.0, -1.0, -1.0],
    [1.0, 1.0, 0.0],
    [-1.0, 1.0, 0.0],
    [0.0, -1.0, 1.0],
    [0.0, -1.0, -1.0],
];

/// Skews split coordinates into the simplex grid: returns the skewed cell
/// indices and the fractions within the skewed cell.
#[inline]
fn skew<const N: usize>(c: [Coord; N], f: f64) -> ([i64; N], [f64; N]) {
    let mut isum: i64 = 0;
    let mut fsum = 0.0;
    for x in &c {
        isum = isum.wrapping_add(x.int);
        fsum += x.frac;
    }
    // s = (Σ int + Σ frac) * F, split into integer and fraction.
    let s = Coord::scaled(isum, fsum, f);
    let mut cell = [0i64; N];
    let mut frac = [0.0; N];
    for d in 0..N {
        let v = Coord::new(c[d].int.wrapping_add(s.int), c[d].frac + s.frac);
        cell[d] = v.int;
        frac[d] = v.frac;
    }
    (cell, frac)
}

/// 2D simplex noise in [-1, 1].
pub fn simplex2(seed: u64, x: Coord, y: Coord) -> f64 {
    const F2: f64 = 0.366_025_403_784_438_6; // (√3 − 1) / 2
    const G2: f64 = 0.211_324_865_405_187_1; // (3 − √3) / 6
    let ([i, j], [xs, ys]) = skew([x, y], F2);
    // Unskewed offset from the cell origin: x0 = xs − (xs + ys)·G2 (see module docs).
    let t = (xs + ys) * G2;
    let (x0, y0) = (xs - t, ys - t);
    let (i1, j1) = if x0 > y0 { (1, 0) } else { (0, 1) };
    let x1 = x0 - i1 as f64 + G2;
    let y1 = y0 - j1 as f64 + G2;
    let x2 = x0 - 1.0 + 2.0 * G2;
    let y2 = y0 - 1.0 + 2.0 * G2;
    let corner = |dx: f64, dy: f64, ci: i64, cj: i64| {
        let t = 0.5 - dx * dx - dy * dy;
        if t <= 0.0 {
            0.0
        } else {
            let g = GRAD2[(hash3(seed, ci, cj, 0) >> 60) as usize];
            let t2 = t * t;
            t2 * t2 * (g[0] * dx + g[1] * dy)
        }
    };
    let n = corner(x0, y0, i, j)
        + corner(x1, y1, i.wrapping_add(i1), j.wrapping_add(j1))
        + corner(x2, y2, i.wrapping_add(1), j.wrapping_add(1));
    // 99.2 maps the extreme of t^4·(g·d) sums with unit gradients to ~±1.
    (99.204_334 * n).clamp(-1.0, 1.0)
}

/// 3D simplex noise in [-1, 1].
pub fn simplex3(seed: u64, x: Coord, y: Coord, z: Coord) -> f64 {
    const F3: f64 = 1.0 / 3.0;
    const G3: f64 = 1.0 / 6.0;
    let ([i, j, k], [xs, ys, zs]) = skew([x, y, z], F3);
    let t = (xs + ys + zs) * G3;
    let (x0, y0, z0) = (xs - t, ys - t, zs - t);
    let (o1, o2) = if x0 >= y0 {
        if y0 >= z0 {
            ([1, 0, 0], [1, 1, 0])
        } else if x0 >= z0 {
            ([1, 0, 0], [1, 0, 1])
        } else {
            ([0, 0, 1], [1, 0, 1])
        }
    } else if y0 < z0 {
        ([0, 0, 1], [0, 1, 1])
    } else if x0 < z0 {
        ([0, 1, 0], [0, 1, 1])
    } else {
        ([0, 1, 0], [1, 1, 0])
    };
    let corner = |o: [i64; 3], g_off: f64| {
        let dx = x0 - o[0] as f64 + g_off;
        let dy = y0 - o[1] as f64 + g_off;
        let dz = z0 - o[2] as f64 + g_off;
        let t = 0.6 - dx * dx - dy * dy - dz * dz;
        if t <= 0.0 {
            0.0
        } else {
            let h = hash3(seed, i.wrapping_add(o[0]), j.wrapping_add(o[1]), k.wrapping_add(o[2]));
            let g = GRAD3[(h >> 60) as usize];
            let t2 = t * t;
            t2 * t2 * (g[0] * dx + g[1] * dy + g[2] * dz)
        }
    };
    let n = corner([0, 0, 0], 0.0) + corner(o1, G3) + corner(o2, 2.0 * G3) + corner([1, 1, 1], 3.0 * G3);
    (32.0 * n).clamp(-1.0, 1.0)
}

/// Fractal Brownian motion over simplex noise.
#[derive(Clone, Debug, PartialEq)]
pub struct Fbm {
    pub seed: u64,
    /// Lattice units per cell at the first octave (cycles per cell).
    pub scale: f64,
    pub octaves: u32,
    pub lacunarity: f64,
    pub gain: f64,
    /// Rosa's "move", in lattice units of the first octave.
    pub offset: [f64; 2],
}

impl Fbm {
    /// The number of octaves whose wavelength is at least two output samples
    /// `sample` cells apart (finer octaves would only alias).
    pub fn octaves_for(&self, sample: f64) -> u32 {
        let mut n = 0;
        let mut f = self.scale * sample;
        while n < self.octaves && f <= 0.5 {
            n += 1;
            f *= self.lacunarity;
        }
        n.max(1)
    }

    /// A per-octave shift, so octaves do not share lattice points and the
    /// field is not pinned to zero at the origin.
    fn octave_shift(&self, o: u32, axis: u64) -> f64 {
        (mix64(self.seed ^ ((o as u64) << 8 | axis).wrapping_mul(0x2545_f491_4f6c_dd1d)) >> 11) as f64
            * (1.0 / (1u64 << 53) as f64)
            * 1024.0
    }

    /// The per-octave constants, computed once per field rather than per sample.
    pub fn table(&self) -> Vec<Octave> {
        let mut out = Vec::with_capacity(self.octaves as usize);
        let mut amp = 1.0;
        let mut scale = self.scale;
        for o in 0..self.octaves {
            out.push(Octave {
                seed: mix64(self.seed.wrapping_add(o as u64)),
                scale,
                amp,
                shift: [
                    self.offset[0] * (scale / self.scale) + self.octave_shift(o, 0),
                    self.offset[1] * (scale / self.scale) + self.octave_shift(o, 1),
                    self.octave_shift(o, 2),
                ],
            });
            amp *= self.gain;
            scale *= self.lacunarity;
        }
        out
    }

    /// Normalised fBm in [-1, 1] at cell `(x, y)` + fractions, with noise time `tau`
    /// (in lattice units; 3D noise when the field evolves, 2D otherwise).
    pub fn sample(&self, octaves: u32, x: (i64, f64), y: (i64, f64), tau: Option<Coord>) -> f64 {
        sample_table(&self.table(), octaves, x, y, tau)
    }
}

/// One octave of an fBm: its hash seed, lattice units per cell, amplitude and shift.
#[derive(Clone, Debug, PartialEq)]
pub struct Octave {
    pub seed: u64,
    pub scale: f64,
    pub amp: f64,
    pub shift: [f64; 3],
}

/// fBm from a precomputed octave table (see [`Fbm::table`]); the first `octaves` are used.
pub fn sample_table(table: &[Octave], octaves: u32, x: (i64, f64), y: (i64, f64), tau: Option<Coord>) -> f64 {
    let mut sum = 0.0;
    let mut norm = 0.0;
    for oct in table.iter().take(octaves as usize) {
        let cx = Coord::scaled(x.0, x.1, oct.scale).offset(oct.shift[0]);
        let cy = Coord::scaled(y.0, y.1, oct.scale).offset(oct.shift[1]);
        let n = match tau {
            Some(t) => simplex3(oct.seed, cx, cy, t.offset(oct.shift[2])),
            None => simplex2(oct.seed, cx, cy),
        };
        sum += oct.amp * n;
        norm += oct.amp;
    }
    sum / norm
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(v: f64) -> Coord {
        Coord::new(0, v)
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
}
