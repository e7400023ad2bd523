//! Fractal Brownian motion over simplex noise: octave tables, single samples and
//! whole rows of a grid.

use super::NoiseBackend;
use super::coord::Coord;
use super::hash::mix64;
use super::simplex::{simplex2, simplex3};
use crate::cpu::Backend;

/// Fractal Brownian motion over simplex noise.
#[derive(Clone, Debug, PartialEq)]
pub struct Fbm {
    /// Seed of the first octave; each octave hashes with its own seed derived from it.
    pub seed: u64,
    /// Lattice units per cell at the first octave (cycles per cell).
    pub scale: f64,
    /// Number of octaves.
    pub octaves: u32,
    /// Frequency ratio between successive octaves.
    pub lacunarity: f64,
    /// Amplitude ratio between successive octaves.
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
    /// The octave's hash seed.
    pub seed: u64,
    /// Lattice units per cell.
    pub scale: f64,
    /// Amplitude (the first octave's is 1).
    pub amp: f64,
    /// Shift in lattice units along x, y and noise time.
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
    backend: NoiseBackend,
}

impl<'a> FbmGrid<'a> {
    /// The grid whose columns are at `xs` (cell + fraction), with the first
    /// `octaves` of `table`, evaluated by `backend` (one of [`NoiseBackend::available`]).
    pub fn new(table: &'a [Octave], octaves: u32, xs: &[(i64, f64)], backend: NoiseBackend) -> FbmGrid<'a> {
        // The AVX-512 path is only sound on a CPU that has it.
        assert!(backend.runs_here(), "{backend:?} is not available");
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
                (tau, NoiseBackend::Avx512) => {
                    let cz = tau.map(|t| t.offset(oct.shift[2]));
                    // SAFETY: `new` admits only available backends, so the CPU has
                    // AVX-512 F and DQ.
                    unsafe { super::avx512::fbm_row(oct.seed, oct.amp, ints, fracs, cy, cz, out) };
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
