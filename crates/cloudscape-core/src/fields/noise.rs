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

use std::sync::OnceLock;

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
    let p = a * b;
    let (ah, al) = split(a);
    let (bh, bl) = split(b);
    let err = ((ah * bh - p) + ah * bl + al * bh) + al * bl;
    (p, err)
}

/// Veltkamp's splitter for f64: 2^27 + 1.
const SPLIT: f64 = 134_217_729.0;

/// Veltkamp's split of `x` into a 26-bit high part and the rest (`hi + lo == x`),
/// the halves of [`two_product`].
#[inline]
fn split(x: f64) -> (f64, f64) {
    let c = SPLIT * x;
    let hi = c - (c - x);
    (hi, x - hi)
}

/// A 64-bit finaliser (splitmix64 / Stafford variant 13): every input bit
/// affects every output bit.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(MIX_MUL[0]);
    z = (z ^ (z >> 27)).wrapping_mul(MIX_MUL[1]);
    z ^ (z >> 31)
}

/// The multipliers of [`mix64`].
pub(crate) const MIX_MUL: [u64; 2] = [0xbf58_476d_1ce4_e5b9, 0x94d0_49bb_1331_11eb];

/// The odd multipliers that spread lattice indices i, j, k in [`hash3`].
const HASH_MUL: [u64; 3] = [0x9e37_79b9_7f4a_7c15, 0xc2b2_ae3d_27d4_eb4f, 0x1656_67b1_9e37_79f9];

/// Hash of a seed and up to three lattice indices: the indices are spread by
/// odd multipliers into one word and finalised once (every input bit reaches
/// every output bit; no table, so no period).
#[inline]
fn hash3(seed: u64, i: i64, j: i64, k: i64) -> u64 {
    mix64(
        seed ^ (i as u64).wrapping_mul(HASH_MUL[0])
            ^ (j as u64).wrapping_mul(HASH_MUL[1]).rotate_left(21)
            ^ (k as u64).wrapping_mul(HASH_MUL[2]).rotate_left(42),
    )
}

// 2D gradients: 16 unit vectors evenly spaced on the circle.
const GRAD2: [[f64; 2]; 16] = {
    let mut g = [[0.0; 2]; 16];
    // cos/sin of k * 22.5°, written out so the table is exact and const (the
    // std constants such as FRAC_1_SQRT_2 are the same f64 values).
    #[allow(clippy::approx_constant)]
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

// Skew and unskew factors of the simplex grids (Gustavson 2005).
const F2: f64 = 0.366_025_403_784_438_6; // (√3 − 1) / 2
const G2: f64 = 0.211_324_865_405_187_1; // (3 − √3) / 6
const F3: f64 = 1.0 / 3.0;
const G3: f64 = 1.0 / 6.0;

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

/// An implementation of [`FbmGrid::row`]. Every backend gives the same bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// [`simplex3`] and [`simplex2`], one sample at a time.
    Scalar,
    /// AVX-512 (F, DQ): eight samples at a time.
    Avx512,
}

impl Backend {
    /// The fastest backend this CPU runs.
    pub fn detect() -> Backend {
        *Backend::available().last().expect("the scalar backend is always there")
    }

    /// Every backend this CPU runs, slowest first (detected once).
    pub fn available() -> &'static [Backend] {
        static AVAILABLE: OnceLock<Vec<Backend>> = OnceLock::new();
        AVAILABLE.get_or_init(|| {
            let mut out = vec![Backend::Scalar];
            #[cfg(target_arch = "x86_64")]
            if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512dq") {
                out.push(Backend::Avx512);
            }
            out
        })
    }
}

/// fBm of one octave table over a grid of sample positions, a row at a time, with
/// the same bits as [`sample_table`] at every sample. A column's lattice x per
/// octave is the same on every row (and a row's y on every column), so each is
/// worked out once rather than once per sample.
pub struct FbmGrid<'a> {
    /// The octaves in use (the first `octaves` of the table).
    octaves: &'a [Octave],
    /// Per octave, the columns' lattice x as indices and fractions in separate
    /// arrays (so eight lanes load as one vector), zero-padded to whole vectors.
    ints: Vec<Vec<i64>>,
    fracs: Vec<Vec<f64>>,
    cols: usize,
    /// Σ amp over the octaves in use, summed in the order [`sample_table`] sums it.
    norm: f64,
    backend: Backend,
}

impl<'a> FbmGrid<'a> {
    /// The grid whose columns are at `xs` (cell + fraction), with the first
    /// `octaves` of `table`, evaluated by `backend` (one of [`Backend::available`]).
    pub fn new(table: &'a [Octave], octaves: u32, xs: &[(i64, f64)], backend: Backend) -> FbmGrid<'a> {
        // The AVX-512 path is only sound on a CPU that has it.
        assert!(Backend::available().contains(&backend), "{backend:?} is not available");
        let octaves = &table[..table.len().min(octaves as usize)];
        let padded = xs.len().div_ceil(8) * 8;
        let mut ints = Vec::with_capacity(octaves.len());
        let mut fracs = Vec::with_capacity(octaves.len());
        let mut norm = 0.0;
        for oct in octaves {
            let mut i = vec![0i64; padded];
            let mut f = vec![0.0f64; padded];
            for (c, x) in xs.iter().enumerate() {
                let cx = Coord::scaled(x.0, x.1, oct.scale).offset(oct.shift[0]);
                i[c] = cx.int;
                f[c] = cx.frac;
            }
            ints.push(i);
            fracs.push(f);
            norm += oct.amp;
        }
        FbmGrid {
            octaves,
            ints,
            fracs,
            cols: xs.len(),
            norm,
            backend,
        }
    }

    /// fBm at every column of the row at `y`, with noise time `tau` (as in
    /// [`sample_table`]), into `out` (one value per column).
    pub fn row(&self, y: (i64, f64), tau: Option<Coord>, out: &mut [f64]) {
        assert_eq!(out.len(), self.cols, "one output per column");
        // Each sample sums its octaves in table order from 0.0, as `sample_table` does.
        out.fill(0.0);
        for (o, oct) in self.octaves.iter().enumerate() {
            let cy = Coord::scaled(y.0, y.1, oct.scale).offset(oct.shift[1]);
            let (ints, fracs) = (&self.ints[o], &self.fracs[o]);
            match (tau, self.backend) {
                #[cfg(target_arch = "x86_64")]
                (tau, Backend::Avx512) => {
                    let cz = tau.map(|t| t.offset(oct.shift[2]));
                    // SAFETY: `new` admits only available backends, so the CPU has
                    // AVX-512 F and DQ.
                    unsafe { avx512::fbm_row(oct.seed, oct.amp, ints, fracs, cy, cz, out) };
                }
                (Some(t), _) => {
                    let cz = t.offset(oct.shift[2]);
                    for (c, v) in out.iter_mut().enumerate() {
                        let cx = Coord {
                            int: ints[c],
                            frac: fracs[c],
                        };
                        *v += oct.amp * simplex3(oct.seed, cx, cy, cz);
                    }
                }
                (None, _) => {
                    for (c, v) in out.iter_mut().enumerate() {
                        let cx = Coord {
                            int: ints[c],
                            frac: fracs[c],
                        };
                        *v += oct.amp * simplex2(oct.seed, cx, cy);
                    }
                }
            }
        }
        for v in out.iter_mut() {
            *v /= self.norm;
        }
    }
}

/// [`simplex3`] for eight samples at a time in AVX-512: the same IEEE operations
/// in the same order per lane (no FMA, no reassociation), so the same bits.
/// Branches become masks: the simplex ordering selects corner offsets by mask, and
/// a corner outside its radius is replaced by +0.0 after being computed.
#[cfg(target_arch = "x86_64")]
mod avx512 {
    use std::arch::x86_64::*;

    use super::{Coord, F2, F3, G2, G3, GRAD2, GRAD3, HASH_MUL, MIX_MUL, SPLIT, split};

    /// `x.floor()`.
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn floor(x: __m512d) -> __m512d {
        _mm512_roundscale_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(x)
    }

    /// `x as i64` for whole numbers `x`, with Rust's saturation: the conversion gives
    /// i64::MIN for NaN and for anything out of range, where `as` gives 0 for NaN
    /// and i64::MAX above the range (and also i64::MIN below it).
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn to_i64(x: __m512d) -> __m512i {
        let r = _mm512_cvttpd_epi64(x);
        let above = _mm512_cmp_pd_mask::<_CMP_GE_OQ>(x, _mm512_set1_pd(9_223_372_036_854_775_808.0));
        let r = _mm512_mask_mov_epi64(r, above, _mm512_set1_epi64(i64::MAX));
        let nan = _mm512_cmp_pd_mask::<_CMP_UNORD_Q>(x, x);
        _mm512_maskz_mov_epi64(!nan, r)
    }

    /// [`Coord::new`].
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn coord_new(int: __m512i, frac: __m512d) -> (__m512i, __m512d) {
        let one = _mm512_set1_pd(1.0);
        let f = floor(frac);
        let int = _mm512_add_epi64(int, to_i64(f));
        let frac = _mm512_sub_pd(frac, f);
        let up = _mm512_cmp_pd_mask::<_CMP_GE_OQ>(frac, one);
        (
            _mm512_mask_add_epi64(int, up, int, _mm512_set1_epi64(1)),
            _mm512_mask_sub_pd(frac, up, frac, one),
        )
    }

    /// `mix64(seed ^ a ^ b.rotate_left(21) ^ c.rotate_left(42))`: [`super::hash3`]
    /// with the indices already multiplied by [`HASH_MUL`].
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn hash3(seed: __m512i, a: __m512i, b: __m512i, c: __m512i) -> __m512i {
        let z = _mm512_xor_si512(
            _mm512_xor_si512(seed, a),
            _mm512_xor_si512(_mm512_rol_epi64::<21>(b), _mm512_rol_epi64::<42>(c)),
        );
        let z = _mm512_mullo_epi64(
            _mm512_xor_si512(z, _mm512_srli_epi64::<30>(z)),
            _mm512_set1_epi64(MIX_MUL[0] as i64),
        );
        let z = _mm512_mullo_epi64(
            _mm512_xor_si512(z, _mm512_srli_epi64::<27>(z)),
            _mm512_set1_epi64(MIX_MUL[1] as i64),
        );
        _mm512_xor_si512(z, _mm512_srli_epi64::<31>(z))
    }

    /// A table of 16 gradients by axis, each axis as its low and high eight entries.
    const fn axes<const D: usize>(g: &[[f64; D]; 16]) -> [[[f64; 8]; 2]; D] {
        let mut out = [[[0.0; 8]; 2]; D];
        let mut i = 0;
        while i < 16 {
            let mut a = 0;
            while a < D {
                out[a][i / 8][i % 8] = g[i][a];
                a += 1;
            }
            i += 1;
        }
        out
    }
    const GRAD2_AXES: [[[f64; 8]; 2]; 2] = axes(&GRAD2);
    const GRAD3_AXES: [[[f64; 8]; 2]; 3] = axes(&GRAD3);

    /// A table made by [`axes`] in vectors, for `_mm512_permutex2var_pd`.
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn gradients<const D: usize>(axes: &[[[f64; 8]; 2]; D]) -> [[__m512d; 2]; D] {
        // SAFETY: each axis's table is 16 f64s, read as two vectors of eight.
        axes.map(|a| unsafe { [_mm512_loadu_pd(a[0].as_ptr()), _mm512_loadu_pd(a[1].as_ptr())] })
    }

    /// [`super::simplex3`] (with `z`) or [`super::simplex2`] at eight x and a
    /// shared y, for the tests.
    ///
    /// # Safety
    /// The CPU must have AVX-512 F and DQ.
    #[cfg(test)]
    #[target_feature(enable = "avx512f,avx512dq")]
    pub unsafe fn noise_x8(seed: u64, x: [Coord; 8], y: Coord, z: Option<Coord>) -> [f64; 8] {
        let ints = x.map(|c| c.int);
        let fracs = x.map(|c| c.frac);
        // SAFETY: eight lanes in and out of eight-element arrays.
        let (xi, xf) = unsafe { (_mm512_loadu_epi64(ints.as_ptr()), _mm512_loadu_pd(fracs.as_ptr())) };
        let seed = _mm512_set1_epi64(seed as i64);
        let n = match z {
            Some(z) => simplex3(seed, gradients(&GRAD3_AXES), xi, xf, y, z),
            None => simplex2(seed, gradients(&GRAD2_AXES), xi, xf, y),
        };
        let mut out = [0.0; 8];
        // SAFETY: as above.
        unsafe { _mm512_storeu_pd(out.as_mut_ptr(), n) };
        out
    }

    /// Adds `amp · simplex3(seed, x[c], y, z)` (or `simplex2(seed, x[c], y)`
    /// without `z`) to `out[c]` for every column `c`, `x[c]` being `ints[c] + fracs[c]`.
    ///
    /// # Safety
    /// The CPU must have AVX-512 F and DQ.
    #[target_feature(enable = "avx512f,avx512dq")]
    pub unsafe fn fbm_row(
        seed: u64,
        amp: f64,
        ints: &[i64],
        fracs: &[f64],
        y: Coord,
        z: Option<Coord>,
        out: &mut [f64],
    ) {
        let padded = out.len().div_ceil(8) * 8;
        assert!(
            ints.len() >= padded && fracs.len() >= padded,
            "whole vectors of columns"
        );
        let (grad2, grad3) = (gradients(&GRAD2_AXES), gradients(&GRAD3_AXES));
        let seed = _mm512_set1_epi64(seed as i64);
        let amp = _mm512_set1_pd(amp);
        for start in (0..out.len()).step_by(8) {
            let lanes = (out.len() - start).min(8);
            let keep: __mmask8 = if lanes == 8 { 0xff } else { (1u8 << lanes) - 1 };
            // SAFETY: `start + 8 <= padded`, within `ints` and `fracs` (asserted above).
            let (xi, xf) = unsafe {
                (
                    _mm512_loadu_epi64(ints.as_ptr().add(start)),
                    _mm512_loadu_pd(fracs.as_ptr().add(start)),
                )
            };
            let n = match z {
                Some(z) => simplex3(seed, grad3, xi, xf, y, z),
                None => simplex2(seed, grad2, xi, xf, y),
            };
            // SAFETY: the mask keeps the lanes `start..start + lanes`, all within `out`.
            unsafe {
                let p = out.as_mut_ptr().add(start);
                let sum = _mm512_mask_loadu_pd(_mm512_setzero_pd(), keep, p);
                _mm512_mask_storeu_pd(p, keep, _mm512_add_pd(sum, _mm512_mul_pd(amp, n)));
            }
        }
    }

    /// [`Coord::scaled`]`(isum, fsum, f)` for the skew, `|f| < 1`.
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn skew_offset(isum: __m512i, fsum: __m512d, f: f64) -> (__m512i, __m512d) {
        // two_product(isum as f64, f).
        let a = _mm512_cvtepi64_pd(isum);
        let fv = _mm512_set1_pd(f);
        let p = _mm512_mul_pd(a, fv);
        let c = _mm512_mul_pd(_mm512_set1_pd(SPLIT), a);
        let ah = _mm512_sub_pd(c, _mm512_sub_pd(c, a));
        let al = _mm512_sub_pd(a, ah);
        let (bh, bl) = split(f);
        let (bh, bl) = (_mm512_set1_pd(bh), _mm512_set1_pd(bl));
        let err = _mm512_add_pd(
            _mm512_add_pd(
                _mm512_add_pd(_mm512_sub_pd(_mm512_mul_pd(ah, bh), p), _mm512_mul_pd(ah, bl)),
                _mm512_mul_pd(al, bh),
            ),
            _mm512_mul_pd(al, bl),
        );
        let fl = floor(p);
        // |p| < 2^63 · |f| and never NaN, so the plain conversion is exact.
        coord_new(
            _mm512_cvttpd_epi64(fl),
            _mm512_add_pd(_mm512_add_pd(_mm512_sub_pd(p, fl), err), _mm512_mul_pd(fsum, fv)),
        )
    }

    /// `if t <= 0.0 { 0.0 } else { v }` (false for NaN `t`, like the scalar test).
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn inside(t: __m512d, v: __m512d) -> __m512d {
        let zero = _mm512_setzero_pd();
        _mm512_mask_mov_pd(v, _mm512_cmp_pd_mask::<_CMP_LE_OQ>(t, zero), zero)
    }

    /// `v.clamp(-1.0, 1.0)`, whose comparisons leave NaN alone.
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn clamp1(v: __m512d) -> __m512d {
        let (lo, hi) = (_mm512_set1_pd(-1.0), _mm512_set1_pd(1.0));
        let v = _mm512_mask_mov_pd(v, _mm512_cmp_pd_mask::<_CMP_LT_OQ>(v, lo), lo);
        _mm512_mask_mov_pd(v, _mm512_cmp_pd_mask::<_CMP_GT_OQ>(v, hi), hi)
    }

    /// [`super::simplex2`] at `(x, y)` in eight lanes, `y` shared.
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn simplex2(seed: __m512i, grad: [[__m512d; 2]; 2], xi: __m512i, xf: __m512d, y: Coord) -> __m512d {
        let zero = _mm512_setzero_pd();
        let one = _mm512_set1_pd(1.0);
        let (yi, yf) = (_mm512_set1_epi64(y.int), _mm512_set1_pd(y.frac));
        let (si, sf) = skew_offset(_mm512_add_epi64(xi, yi), _mm512_add_pd(_mm512_add_pd(zero, xf), yf), F2);
        let (i, xs) = coord_new(_mm512_add_epi64(xi, si), _mm512_add_pd(xf, sf));
        let (j, ys) = coord_new(_mm512_add_epi64(yi, si), _mm512_add_pd(yf, sf));
        let t = _mm512_mul_pd(_mm512_add_pd(xs, ys), _mm512_set1_pd(G2));
        let (x0, y0) = (_mm512_sub_pd(xs, t), _mm512_sub_pd(ys, t));
        // `if x0 > y0 { (1, 0) } else { (0, 1) }`.
        let o1 = _mm512_cmp_pd_mask::<_CMP_GT_OQ>(x0, y0);
        let g2 = _mm512_set1_pd(G2);
        let x1 = _mm512_add_pd(_mm512_sub_pd(x0, _mm512_maskz_mov_pd(o1, one)), g2);
        let y1 = _mm512_add_pd(_mm512_sub_pd(y0, _mm512_maskz_mov_pd(!o1, one)), g2);
        let g22 = _mm512_set1_pd(2.0 * G2);
        let x2 = _mm512_add_pd(_mm512_sub_pd(x0, one), g22);
        let y2 = _mm512_add_pd(_mm512_sub_pd(y0, one), g22);
        let mul = [HASH_MUL[0], HASH_MUL[1]].map(|m| _mm512_set1_epi64(m as i64));
        let base = [_mm512_mullo_epi64(i, mul[0]), _mm512_mullo_epi64(j, mul[1])];
        let corner = |dx: __m512d, dy: __m512d, o: [__mmask8; 2]| {
            let t = _mm512_sub_pd(
                _mm512_sub_pd(_mm512_set1_pd(0.5), _mm512_mul_pd(dx, dx)),
                _mm512_mul_pd(dy, dy),
            );
            let h: [__m512i; 2] = std::array::from_fn(|a| _mm512_mask_add_epi64(base[a], o[a], base[a], mul[a]));
            // k = 0, so its term of the hash is 0.
            let idx = _mm512_srli_epi64::<60>(hash3(seed, h[0], h[1], _mm512_setzero_si512()));
            let g: [__m512d; 2] = std::array::from_fn(|a| _mm512_permutex2var_pd(grad[a][0], idx, grad[a][1]));
            let t2 = _mm512_mul_pd(t, t);
            let v = _mm512_mul_pd(
                _mm512_mul_pd(t2, t2),
                _mm512_add_pd(_mm512_mul_pd(g[0], dx), _mm512_mul_pd(g[1], dy)),
            );
            inside(t, v)
        };
        let n = _mm512_add_pd(
            _mm512_add_pd(corner(x0, y0, [0, 0]), corner(x1, y1, [o1, !o1])),
            corner(x2, y2, [0xff, 0xff]),
        );
        clamp1(_mm512_mul_pd(_mm512_set1_pd(99.204_334), n))
    }

    /// [`super::simplex3`] at `(x, y, z)` in eight lanes, `y` and `z` shared.
    #[target_feature(enable = "avx512f,avx512dq")]
    #[inline]
    fn simplex3(seed: __m512i, grad: [[__m512d; 2]; 3], xi: __m512i, xf: __m512d, y: Coord, z: Coord) -> __m512d {
        let zero = _mm512_setzero_pd();
        let one = _mm512_set1_pd(1.0);
        let (yi, yf) = (_mm512_set1_epi64(y.int), _mm512_set1_pd(y.frac));
        let (zi, zf) = (_mm512_set1_epi64(z.int), _mm512_set1_pd(z.frac));
        let isum = _mm512_add_epi64(_mm512_add_epi64(xi, yi), zi);
        let fsum = _mm512_add_pd(_mm512_add_pd(_mm512_add_pd(zero, xf), yf), zf);
        let (si, sf) = skew_offset(isum, fsum, F3);
        let (i, xs) = coord_new(_mm512_add_epi64(xi, si), _mm512_add_pd(xf, sf));
        let (j, ys) = coord_new(_mm512_add_epi64(yi, si), _mm512_add_pd(yf, sf));
        let (k, zs) = coord_new(_mm512_add_epi64(zi, si), _mm512_add_pd(zf, sf));

        let g3 = _mm512_set1_pd(G3);
        let t = _mm512_mul_pd(_mm512_add_pd(_mm512_add_pd(xs, ys), zs), g3);
        let (x0, y0, z0) = (_mm512_sub_pd(xs, t), _mm512_sub_pd(ys, t), _mm512_sub_pd(zs, t));

        // The scalar ordering's `if` tree, with its own comparisons (so NaN lanes go
        // the same way): o1 and o2 per axis as masks.
        let xy = _mm512_cmp_pd_mask::<_CMP_GE_OQ>(x0, y0);
        let yz = _mm512_cmp_pd_mask::<_CMP_GE_OQ>(y0, z0);
        let xz = _mm512_cmp_pd_mask::<_CMP_GE_OQ>(x0, z0);
        let y_lt_z = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(y0, z0);
        let x_lt_z = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(x0, z0);
        let o1 = [xy & (yz | xz), !xy & !y_lt_z, (xy & !(yz | xz)) | (!xy & y_lt_z)];
        let o2 = [
            xy | (!xy & !y_lt_z & !x_lt_z),
            (xy & yz) | !xy,
            (xy & !yz) | (!xy & (y_lt_z | x_lt_z)),
        ];

        // Indices times the hash multipliers; a corner's offset adds the multiplier.
        let mul = HASH_MUL.map(|m| _mm512_set1_epi64(m as i64));
        let base = [
            _mm512_mullo_epi64(i, mul[0]),
            _mm512_mullo_epi64(j, mul[1]),
            _mm512_mullo_epi64(k, mul[2]),
        ];
        let d0 = [x0, y0, z0];
        let corner = |o: [__mmask8; 3], g_off: f64| {
            let g_off = _mm512_set1_pd(g_off);
            let d: [__m512d; 3] =
                std::array::from_fn(|a| _mm512_add_pd(_mm512_sub_pd(d0[a], _mm512_maskz_mov_pd(o[a], one)), g_off));
            let t = _mm512_sub_pd(
                _mm512_sub_pd(
                    _mm512_sub_pd(_mm512_set1_pd(0.6), _mm512_mul_pd(d[0], d[0])),
                    _mm512_mul_pd(d[1], d[1]),
                ),
                _mm512_mul_pd(d[2], d[2]),
            );
            let h: [__m512i; 3] = std::array::from_fn(|a| _mm512_mask_add_epi64(base[a], o[a], base[a], mul[a]));
            let idx = _mm512_srli_epi64::<60>(hash3(seed, h[0], h[1], h[2]));
            let g: [__m512d; 3] = std::array::from_fn(|a| _mm512_permutex2var_pd(grad[a][0], idx, grad[a][1]));
            let t2 = _mm512_mul_pd(t, t);
            let v = _mm512_mul_pd(
                _mm512_mul_pd(t2, t2),
                _mm512_add_pd(
                    _mm512_add_pd(_mm512_mul_pd(g[0], d[0]), _mm512_mul_pd(g[1], d[1])),
                    _mm512_mul_pd(g[2], d[2]),
                ),
            );
            inside(t, v)
        };
        let n = _mm512_add_pd(
            _mm512_add_pd(_mm512_add_pd(corner([0; 3], 0.0), corner(o1, G3)), corner(o2, 2.0 * G3)),
            corner([0xff; 3], 3.0 * G3),
        );
        clamp1(_mm512_mul_pd(_mm512_set1_pd(32.0), n))
    }
}

#[cfg(test)]
mod tests {
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
        if !Backend::available().contains(&Backend::Avx512) {
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
            for &backend in Backend::available() {
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
}
