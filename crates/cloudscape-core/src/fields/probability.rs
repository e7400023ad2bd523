//! Per-layer probability fields p_hum, p_act, p_ext.
//!
//! Each field is Rosa's Noise Maker (2013, §3.3 and §4.1): fBm of simplex noise
//! mapped to a brightness in [0, 1], then move (offset), feather (at the edges of
//! the layer's optional extent) and cutoff. Humidity and activation are then
//! shaped by height (bases wider than tops) and by optional Dobashi ellipsoids,
//! and each brightness is mapped linearly onto the field's probability range.
//!
//! Fields are evaluated in the layer's wind frame (cells that drift with the base
//! wind), so the pattern moves with the wind; see `automaton::frame`.

use rayon::prelude::*;

use super::noise::{Coord, Fbm, FbmGrid, NoiseBackend, Octave, mix64, sample_table};
use crate::cpu::Backend;
use crate::world::{Event, FieldSpec, Layer, Mode, World};

/// The noise fields of one layer of one world.
#[derive(Clone, Debug)]
pub struct LayerFields {
    /// The layer the fields belong to.
    pub layer: Layer,
    fbm: [Fbm; 3],
    tables: [Vec<Octave>; 3],
    specs: [FieldSpec; 3],
}

/// Probabilities at one cell (or Rosa textures, for mode `rosa`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probabilities {
    /// Humidity probability p_hum, in [0, 1].
    pub hum: f32,
    /// Activation probability p_act, in [0, 1].
    pub act: f32,
    /// Extinction probability p_ext, in [0, 1].
    pub ext: f32,
}

/// Brightness (after move, feather and cutoff; before height shaping) of the
/// three fields over a window of wind-frame cells. Row-major, `w × h`.
#[derive(Clone, Debug)]
pub struct FieldWindow {
    /// Wind-frame x of column 0.
    pub x0: i64,
    /// Wind-frame y of row 0.
    pub y0: i64,
    /// Columns.
    pub w: usize,
    /// Rows.
    pub h: usize,
    /// Each field's brightness in [0, 1], indexed by [`Event`].
    pub b: [Vec<f32>; 3],
}

impl FieldWindow {
    /// Field `which`'s brightness at wind-frame cell (`x`, `y`); 0 outside the window.
    #[inline]
    pub fn get(&self, which: Event, x: i64, y: i64) -> f32 {
        let (dx, dy) = (x - self.x0, y - self.y0);
        if dx < 0 || dy < 0 || dx >= self.w as i64 || dy >= self.h as i64 {
            return 0.0;
        }
        self.b[which as usize][dy as usize * self.w + dx as usize]
    }
}

/// Probability as a 16.16 fixed-point threshold: a draw `r` in 0..65536 fires when
/// `r < q`; `q = 65536` always fires, `q = 0` never does.
///
/// Rounds half away from zero like `f32::round`, written with `floor` so that a
/// row of drives compiles to vector instructions (`round` is a scalar call on
/// x86-64); a unit test compares the two on every f32 in [0, 1]. NaN gives 0.
#[inline]
pub fn quantize(p: f32) -> u32 {
    // `max` returns the other operand for NaN, so x is a number in [0, 65536]
    // (`clamp` would keep the NaN, which the unchecked conversion below must not see).
    #[allow(clippy::manual_clamp)]
    let x = p.max(0.0).min(1.0) * 65536.0;
    let r = (x + 0.5).floor();
    // `x + 0.5` can round up across an integer when x is just below n − 0.5.
    let r = if x < r - 0.5 { r - 1.0 } else { r };
    // SAFETY: r is a whole number in [0, 65536], never NaN, so it fits an i32. The
    // unchecked form lets x86 convert eight lanes at once (`as` adds a scalar NaN check).
    unsafe { r.to_int_unchecked::<i32>() as u32 }
}

impl LayerFields {
    /// The fields of layer `layer_index` of `world`, seeded from the world seed.
    pub fn new(world: &World, layer_index: usize) -> LayerFields {
        let layer = world.layers[layer_index].clone();
        let base_seed = mix64(world.seed ^ mix64(0x6c61_7965_7200_0000 ^ layer_index as u64));
        let specs = [
            layer.preset.humidity.clone(),
            layer.preset.activation.clone(),
            layer.preset.extinction.clone(),
        ];
        let fbm = std::array::from_fn(|i| {
            let s = &specs[i];
            Fbm {
                seed: mix64(base_seed ^ (i as u64 + 1)),
                // frequency is cycles per km; scale is cycles per cell.
                scale: s.frequency * layer.cell_size / 1000.0,
                octaves: s.octaves,
                lacunarity: s.lacunarity,
                gain: s.gain,
                offset: s.offset,
            }
        });
        let tables = std::array::from_fn(|i| fbm[i].table());
        LayerFields {
            layer,
            fbm,
            tables,
            specs,
        }
    }

    /// Noise time for a reference time in seconds (None when the fields are frozen).
    pub fn tau(&self, t_ref: f64) -> Option<Coord> {
        let e = self.layer.preset.evolve;
        if e > 0.0 { Some(Coord::new(0, t_ref / e)) } else { None }
    }

    /// Octaves of field `which` worth evaluating when samples are `sample` cells apart.
    pub fn octaves(&self, which: Event, sample: f64) -> u32 {
        self.fbm[which as usize].octaves_for(sample)
    }

    /// Brightness in [0, 1] of one field at a wind-frame position (cell + fraction),
    /// `world_shift` cells being the wind frame's offset from the world grid (for
    /// the feather at the extent's edges).
    pub fn brightness(
        &self,
        which: Event,
        x: (i64, f64),
        y: (i64, f64),
        octaves: u32,
        tau: Option<Coord>,
        world_shift: (i64, i64),
    ) -> f32 {
        let n = sample_table(&self.tables[which as usize], octaves, x, y, tau);
        self.brightness_of(which, n, x, y, world_shift)
    }

    /// [`LayerFields::brightness`] from the field's fBm value `n` at that position.
    #[inline]
    fn brightness_of(&self, which: Event, n: f64, x: (i64, f64), y: (i64, f64), world_shift: (i64, i64)) -> f32 {
        let spec = &self.specs[which as usize];
        let mut v = (n + 1.0) * 0.5;
        if let (Some(f), Some(ext)) = (&spec.feather, &self.layer.extent) {
            let cs = self.layer.cell_size;
            let wx = ((x.0 + world_shift.0) as f64 + x.1) * cs;
            let wy = ((y.0 + world_shift.1) as f64 + y.1) * cs;
            let d = (wx - ext[0]).min(ext[2] - wx).min(wy - ext[1]).min(ext[3] - wy);
            v *= feather_factor(d, f.start, f.depth, f.falloff);
        }
        let [lo, hi] = spec.cutoff;
        ((v - lo) / (hi - lo)).clamp(0.0, 1.0) as f32
    }

    /// [`LayerFields::brightness`] at every (x, y) of a grid whose columns are at
    /// `xs` and rows at `ys` (row-major into `out`): the fBm row by row with each
    /// column's lattice x worked out once ([`FbmGrid`]), the same bits as one
    /// sample at a time.
    #[allow(clippy::too_many_arguments)]
    pub fn brightness_grid(
        &self,
        which: Event,
        octaves: u32,
        xs: &[(i64, f64)],
        ys: &[(i64, f64)],
        tau: Option<Coord>,
        world_shift: (i64, i64),
        out: &mut [f32],
    ) {
        assert_eq!(out.len(), xs.len() * ys.len(), "one output per grid point");
        let grid = FbmGrid::new(&self.tables[which as usize], octaves, xs, NoiseBackend::detect());
        out.par_chunks_mut(xs.len().max(1)).zip(ys).for_each_init(
            || vec![0.0; xs.len()],
            |n, (row, &y)| {
                grid.row(y, tau, n);
                for ((v, &n), &x) in row.iter_mut().zip(n.iter()).zip(xs) {
                    *v = self.brightness_of(which, n, x, y, world_shift);
                }
            },
        );
    }

    /// Evaluates the three brightness fields over a window of wind-frame cells,
    /// at cell centres. `spacing` > 1 evaluates noise on a coarser lattice aligned
    /// to multiples of `spacing` in frame coordinates and interpolates bilinearly
    /// (the lattice is global, so any window gives the same values).
    #[allow(clippy::too_many_arguments)] // x0, y0, w, h: a rectangle type would only wrap them
    pub fn window(
        &self,
        x0: i64,
        y0: i64,
        w: usize,
        h: usize,
        spacing: [u32; 3],
        tau: Option<Coord>,
        world_shift: (i64, i64),
    ) -> FieldWindow {
        let octs = [0, 1, 2].map(|i| self.fbm[i].octaves_for(1.0));
        let which = Event::ALL;
        let mut b: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; w * h]);
        for (f, out) in b.iter_mut().enumerate() {
            if spacing[f] <= 1 {
                let xs: Vec<(i64, f64)> = (0..w).map(|c| (x0 + c as i64, 0.5)).collect();
                let ys: Vec<(i64, f64)> = (0..h).map(|r| (y0 + r as i64, 0.5)).collect();
                self.brightness_grid(which[f], octs[f], &xs, &ys, tau, world_shift, out);
                continue;
            }
            // Coarse lattice points are the centres of cells at multiples of `s`.
            let s = spacing[f] as i64;
            let gx0 = x0.div_euclid(s);
            let gy0 = y0.div_euclid(s);
            let gw = ((x0 + w as i64 - 1).div_euclid(s) + 2 - gx0) as usize;
            let gh = ((y0 + h as i64 - 1).div_euclid(s) + 2 - gy0) as usize;
            let mut g = vec![0f32; gw * gh];
            let xs: Vec<(i64, f64)> = (0..gw).map(|gc| ((gx0 + gc as i64) * s, 0.5)).collect();
            let ys: Vec<(i64, f64)> = (0..gh).map(|gr| ((gy0 + gr as i64) * s, 0.5)).collect();
            self.brightness_grid(which[f], octs[f], &xs, &ys, tau, world_shift, &mut g);
            let inv = 1.0 / s as f32;
            // Each column's coarse cell and weight are the same on every row, and
            // each coarse row's interpolation along x serves the `s` rows above it:
            // both are worked out once (the same arithmetic, so the same bits).
            let cols: Vec<(usize, f32)> = (0..w as i64)
                .map(|c| {
                    let x = x0 + c;
                    ((x.div_euclid(s) - gx0) as usize, x.rem_euclid(s) as f32 * inv)
                })
                .collect();
            let mut along = vec![0f32; gh * w];
            along.par_chunks_mut(w.max(1)).enumerate().for_each(|(gr, row)| {
                let g = &g[gr * gw..(gr + 1) * gw];
                for (v, &(i, fx)) in row.iter_mut().zip(&cols) {
                    *v = g[i] + (g[i + 1] - g[i]) * fx;
                }
            });
            out.par_chunks_mut(w.max(1)).enumerate().for_each(|(r, row)| {
                let y = y0 + r as i64;
                let fy = y.rem_euclid(s) as f32 * inv;
                let top = (y.div_euclid(s) - gy0) as usize * w;
                let (top, bot) = (&along[top..top + w], &along[top + w..top + 2 * w]);
                for ((v, &top), &bot) in row.iter_mut().zip(top).zip(bot) {
                    *v = top + (bot - top) * fy;
                }
            });
        }
        FieldWindow { x0, y0, w, h, b }
    }

    /// The coarse-lattice spacing of each field (cells, a power of two, at most 16)
    /// at which the bilinear interpolation error stays below about 0.1 of the
    /// field's value after cutoff: linear interpolation of a sinusoid of frequency f
    /// with spacing s errs by at most (π f s)² / 2 of its amplitude; summed over
    /// octaves weighted by amplitude, halved for the (n+1)/2 brightness map, and
    /// multiplied by the cutoff's stretch 1/(high − low).
    pub fn coarse_spacing(&self) -> [u32; 3] {
        std::array::from_fn(|i| {
            let f = &self.fbm[i];
            let stretch = 1.0 / (self.specs[i].cutoff[1] - self.specs[i].cutoff[0]);
            let bound = |s: f64| {
                let (mut amp, mut norm, mut sum, mut freq) = (1.0, 0.0, 0.0, f.scale);
                for _ in 0..f.octaves_for(1.0) {
                    let e = (std::f64::consts::PI * freq * s).powi(2) / 2.0;
                    sum += amp * e.min(1.0);
                    norm += amp;
                    amp *= f.gain;
                    freq *= f.lacunarity;
                }
                // Simplex features are sharper than a sinusoid of the octave's frequency;
                // the factor 2 is measured (see the test below).
                2.0 * 0.5 * sum / norm * stretch
            };
            let mut s = 1u32;
            while s < 16 && bound((2 * s) as f64) <= 0.08 {
                s *= 2;
            }
            s
        })
    }

    /// Height shaping: at height fraction `h` the brightness needed rises by
    /// `top_narrowing * h²`, so the footprint shrinks toward the top (less so where
    /// an anvil spreads: see [`LayerFields::anvil_weight`]).
    #[inline]
    pub fn shape(&self, v: f32, k: u32) -> f32 {
        let n = self.narrowing(k);
        ((v - n) / (1.0 - n)).clamp(0.0, 1.0)
    }

    /// `top_narrowing · h²` at level `k`, faded out by the anvil's weight there.
    fn narrowing(&self, k: u32) -> f32 {
        let h = (k as f32 + 0.5) / self.layer.depth as f32;
        self.layer.preset.top_narrowing as f32 * h * h * (1.0 - self.anvil_weight(k))
    }

    /// How far level `k`'s humidity and activation brightness move toward their
    /// anvil spread (the largest value within the anvil's radius): 0 without an anvil.
    pub fn anvil_weight(&self, k: u32) -> f32 {
        self.layer
            .preset
            .anvil
            .as_ref()
            .map_or(0.0, |a| a.weight(k, self.layer.depth))
    }

    /// The anvil's half-width in cells (0 without an anvil).
    pub fn anvil_cells(&self) -> usize {
        self.layer
            .preset
            .anvil
            .as_ref()
            .map_or(0, |a| a.cells(self.layer.cell_size))
    }

    /// Dobashi ellipsoid weight at a wind-frame position (metres) and level; 1 with none.
    pub fn ellipsoid_weight(&self, x_m: f64, y_m: f64, k: u32) -> f32 {
        if self.layer.ellipsoids.is_empty() {
            return 1.0;
        }
        let z = self.layer.level_altitude(k);
        let mut best: f64 = 0.0;
        for e in &self.layer.ellipsoids {
            let dx = (x_m - e.centre[0]) / e.radii[0];
            let dy = (y_m - e.centre[1]) / e.radii[1];
            let dz = (z - e.centre[2]) / e.radii[2];
            best = best.max(1.0 - (dx * dx + dy * dy + dz * dz));
        }
        best.clamp(0.0, 1.0) as f32
    }

    /// The per-level constants of [`LayerFields::level_values`], for 64 lanes at a time.
    pub fn level_mapping(&self, k: u32) -> LevelMapping {
        LevelMapping {
            mode: self.layer.preset.mode,
            narrowing: self.narrowing(k),
            ranges: std::array::from_fn(|i| {
                let r = self.specs[i].range;
                [r[0] as f32, (r[1] - r[0]) as f32]
            }),
        }
    }

    /// Probabilities (Dobashi) or textures (Rosa) at level `k` from the three brightness values.
    #[inline]
    pub fn level_values(&self, k: u32, b: [f32; 3], ellipsoid: f32) -> Probabilities {
        let hum_v = self.shape(b[0], k) * ellipsoid;
        let act_v = self.shape(b[1], k) * ellipsoid;
        match self.layer.preset.mode {
            Mode::Dobashi => {
                let map = |spec: &FieldSpec, v: f32| {
                    (spec.range[0] as f32 + (spec.range[1] - spec.range[0]) as f32 * v).clamp(0.0, 1.0)
                };
                Probabilities {
                    hum: map(&self.specs[0], hum_v),
                    act: map(&self.specs[1], act_v),
                    ext: map(&self.specs[2], b[2]),
                }
            }
            // Rosa eq. 3.5: tex_cld = (tex_hum + tex_act) / 2 stands in the extinction slot.
            Mode::Rosa => Probabilities {
                hum: hum_v,
                act: act_v,
                ext: (hum_v + act_v) * 0.5,
            },
        }
    }
}

/// [`LayerFields::level_values`] for one level, with its constants worked out once,
/// applied to 64 lanes at a time (the same arithmetic per lane, so the same bits).
#[derive(Clone, Copy, Debug)]
pub struct LevelMapping {
    mode: Mode,
    /// `top_narrowing · h²` at this level (see [`LayerFields::shape`]).
    narrowing: f32,
    /// Probability range `[low, high − low]` of each field (Dobashi).
    ranges: [[f32; 2]; 3],
}

impl LevelMapping {
    /// Probabilities (Dobashi) or textures (Rosa) of 64 lanes from their brightness
    /// and ellipsoid weights.
    #[inline]
    pub fn values(&self, b: [&[f32; 64]; 3], ellipsoid: &[f32; 64], out: &mut [[f32; 64]; 3]) {
        let n = self.narrowing;
        let shape = |v: f32| ((v - n) / (1.0 - n)).clamp(0.0, 1.0);
        let map = |r: [f32; 2], v: f32| (r[0] + r[1] * v).clamp(0.0, 1.0);
        // One plain loop per output (the mode decided once), so each compiles to
        // vector instructions; every lane does the arithmetic of `level_values`.
        let [hum, act, ext] = out;
        for ((o, &v), &e) in hum.iter_mut().zip(b[0]).zip(ellipsoid) {
            *o = shape(v) * e;
        }
        for ((o, &v), &e) in act.iter_mut().zip(b[1]).zip(ellipsoid) {
            *o = shape(v) * e;
        }
        match self.mode {
            Mode::Dobashi => {
                for o in hum.iter_mut() {
                    *o = map(self.ranges[0], *o);
                }
                for o in act.iter_mut() {
                    *o = map(self.ranges[1], *o);
                }
                for (o, &v) in ext.iter_mut().zip(b[2]) {
                    *o = map(self.ranges[2], v);
                }
            }
            // Rosa eq. 3.5, as in `level_values`.
            Mode::Rosa => {
                for ((o, &h), &a) in ext.iter_mut().zip(hum.iter()).zip(act.iter()) {
                    *o = (h + a) * 0.5;
                }
            }
        }
    }
}

/// The largest of `src` (row-major, `w × h`) within `r` cells in x and y of each cell
/// (a square window, cut at the grid's edges): the anvil's spread. Separable, and each
/// pass the van Herk / Gil-Werman running maximum, O(1) per cell whatever `r`.
pub fn max_filter(src: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    assert_eq!(src.len(), w * h, "one value per cell");
    if r == 0 || src.is_empty() {
        return src.to_vec();
    }
    // Rows, then columns: transpose, filter the rows, transpose back.
    let along = max_rows(src, w, r);
    let t = max_rows(&transpose(&along, w, h), h, r);
    transpose(&t, h, w)
}

/// [`running_max`] over each row of `src` (row-major, rows of `w`), rows in parallel.
fn max_rows(src: &[f32], w: usize, r: usize) -> Vec<f32> {
    let mut out = vec![0f32; src.len()];
    out.par_chunks_mut(w)
        .zip(src.par_chunks(w))
        .for_each_init(Vec::new, |scratch, (out, row)| running_max(row, r, out, scratch));
    out
}

/// The transpose of `src` (row-major, `w × h`): row-major `h × w`.
fn transpose(src: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0f32; w * h];
    for (y, row) in src.chunks(w).enumerate() {
        for (x, &v) in row.iter().enumerate() {
            out[x * h + y] = v;
        }
    }
    out
}

/// `out[i]` = the largest of `src[i − r ..= i + r]` (within bounds): prefix and suffix
/// maxima of blocks of `2r + 1` over the row padded with `r` values below every input
/// on each side (brightness is never below 0, so 0 pads; NaN never wins a `max`).
fn running_max(src: &[f32], r: usize, out: &mut [f32], scratch: &mut Vec<f32>) {
    let (n, l) = (src.len(), 2 * r + 1);
    let m = n + 2 * r;
    let p = |j: usize| if j >= r && j - r < n { src[j - r] } else { 0.0 };
    scratch.clear();
    scratch.resize(2 * m, 0.0);
    let (g, hh) = scratch.split_at_mut(m);
    for j in 0..m {
        g[j] = if j % l == 0 { p(j) } else { g[j - 1].max(p(j)) };
    }
    for j in (0..m).rev() {
        hh[j] = if j + 1 == m || (j + 1) % l == 0 {
            p(j)
        } else {
            hh[j + 1].max(p(j))
        };
    }
    for (i, o) in out.iter_mut().enumerate() {
        *o = hh[i].max(g[i + 2 * r]);
    }
}

/// Rosa's feather: 0 within `start` of the edge (and outside), 1 beyond `depth`,
/// a ramp between whose steepness near the edge grows with `falloff`.
fn feather_factor(d: f64, start: f64, depth: f64, falloff: f64) -> f64 {
    if d <= start {
        0.0
    } else if d >= depth {
        1.0
    } else {
        ((d - start) / (depth - start)).powf(1.0 + 3.0 * falloff)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Config;

    fn fields() -> LayerFields {
        let w = Config::embedded().world("default").unwrap();
        LayerFields::new(&w, 0)
    }

    #[test]
    fn level_mapping_equals_level_values_in_every_lane() {
        let mut s = 21u64;
        let mut next = || {
            s = mix64(s);
            s
        };
        for mode in [Mode::Dobashi, Mode::Rosa] {
            let mut f = fields();
            f.layer.preset.mode = mode;
            for k in 0..f.layer.depth {
                let mapping = f.level_mapping(k);
                for _ in 0..50 {
                    // Brightness in [0, 1] with its ends, a little outside, and NaN.
                    let mut lane = || match next() % 8 {
                        0 => 0.0,
                        1 => 1.0,
                        2 => -0.25,
                        3 => 1.5,
                        4 => f32::NAN,
                        _ => (next() >> 40) as f32 / (1u64 << 24) as f32,
                    };
                    let b: [[f32; 64]; 3] = std::array::from_fn(|_| std::array::from_fn(|_| lane()));
                    let e: [f32; 64] = std::array::from_fn(|_| match next() % 3 {
                        0 => 1.0,
                        1 => 0.0,
                        _ => (next() >> 40) as f32 / (1u64 << 24) as f32,
                    });
                    let mut out = [[0f32; 64]; 3];
                    mapping.values(b.each_ref(), &e, &mut out);
                    for l in 0..64 {
                        let want = f.level_values(k, [b[0][l], b[1][l], b[2][l]], e[l]);
                        let got = [out[0][l], out[1][l], out[2][l]];
                        assert_eq!(
                            got.map(f32::to_bits),
                            [want.hum, want.act, want.ext].map(f32::to_bits),
                            "{mode:?} level {k} lane {l}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn quantize_equals_rounding_half_away_from_zero_on_every_probability() {
        let plain = |p: f32| {
            if p.is_nan() {
                0
            } else {
                (p.clamp(0.0, 1.0) * 65536.0).round() as u32
            }
        };
        // Every f32 bit pattern from 0 to 1.0 (about 1.07e9 values).
        let mut bits = 0u32;
        while bits <= 1.0f32.to_bits() {
            let p = f32::from_bits(bits);
            assert_eq!(quantize(p), plain(p), "p = {p:e}");
            bits += 1;
        }
        for p in [f32::NAN, -0.0, -1.0, 2.0, f32::INFINITY, f32::NEG_INFINITY] {
            assert_eq!(quantize(p), plain(p), "p = {p}");
        }
    }

    #[test]
    fn quantize_ends() {
        assert_eq!(quantize(0.0), 0);
        assert_eq!(quantize(1.0), 65536);
        assert_eq!(quantize(f32::NAN), 0);
        assert_eq!(quantize(-1.0), 0);
        assert_eq!(quantize(0.5), 32768);
    }

    #[test]
    fn coarse_window_matches_exact_on_lattice_points_and_is_close_between() {
        let f = fields();
        let sp = f.coarse_spacing();
        assert!(
            sp.iter().any(|&s| s >= 2),
            "some default field is smooth enough to interpolate: {sp:?}"
        );
        let exact = f.window(-37, 101, 64, 48, [1; 3], None, (0, 0));
        let coarse = f.window(-37, 101, 64, 48, sp, None, (0, 0));
        for (which, &s) in sp.iter().enumerate() {
            let mut max_err: f32 = 0.0;
            for i in 0..exact.b[which].len() {
                let (x, y) = (-37 + (i % 64) as i64, 101 + (i / 64) as i64);
                let e = (exact.b[which][i] - coarse.b[which][i]).abs();
                if x.rem_euclid(s as i64) == 0 && y.rem_euclid(s as i64) == 0 {
                    assert!(e < 1e-6);
                }
                max_err = max_err.max(e);
            }
            assert!(
                max_err < 0.1,
                "field {which} spacing {s}: interpolation error {max_err}"
            );
        }
    }

    #[test]
    fn window_has_the_bits_of_brightness_per_sample() {
        let f = fields();
        let (x0, y0, w, h, shift) = (-37, 101, 45, 23, (5, -3));
        let which = Event::ALL;
        for tau in [None, f.tau(1234.5)] {
            for spacing in [[1; 3], [2, 4, 16]] {
                let win = f.window(x0, y0, w, h, spacing, tau, shift);
                for (i, &s) in spacing.iter().enumerate() {
                    let octaves = f.octaves(which[i], 1.0);
                    let at = |x: i64, y: i64| f.brightness(which[i], (x, 0.5), (y, 0.5), octaves, tau, shift);
                    let s = s as i64;
                    for r in 0..h {
                        for c in 0..w {
                            let (x, y) = (x0 + c as i64, y0 + r as i64);
                            // The interpolation as written before rows and columns were hoisted.
                            let want = if s == 1 {
                                at(x, y)
                            } else {
                                let (gx, gy) = (x.div_euclid(s) * s, y.div_euclid(s) * s);
                                let inv = 1.0 / s as f32;
                                let (fx, fy) = (x.rem_euclid(s) as f32 * inv, y.rem_euclid(s) as f32 * inv);
                                let top = at(gx, gy) + (at(gx + s, gy) - at(gx, gy)) * fx;
                                let bot = at(gx, gy + s) + (at(gx + s, gy + s) - at(gx, gy + s)) * fx;
                                top + (bot - top) * fy
                            };
                            assert_eq!(
                                win.get(which[i], x, y).to_bits(),
                                want.to_bits(),
                                "{tau:?} {spacing:?} {x} {y}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn brightness_grid_has_the_bits_of_brightness_per_sample() {
        // Arbitrary fractions and far-out indices, as the far-field levels ask for.
        let f = fields();
        let xs: Vec<(i64, f64)> = (0..19).map(|c| (c * 4 - (1 << 40), 0.03 * c as f64)).collect();
        let ys: Vec<(i64, f64)> = (0..5)
            .map(|r| ((1 << 40) - r * 4, 1.0 - 0.2 * r as f64 - 1e-12))
            .collect();
        for tau in [None, f.tau(1234.5), f.tau(-3e9)] {
            for which in Event::ALL {
                let octaves = f.octaves(which, 4.0);
                let mut out = vec![0f32; xs.len() * ys.len()];
                f.brightness_grid(which, octaves, &xs, &ys, tau, (7, -9), &mut out);
                for (r, &y) in ys.iter().enumerate() {
                    for (c, &x) in xs.iter().enumerate() {
                        let want = f.brightness(which, x, y, octaves, tau, (7, -9));
                        assert_eq!(
                            out[r * xs.len() + c].to_bits(),
                            want.to_bits(),
                            "{which:?} {tau:?} {x:?} {y:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn windows_are_seamless() {
        let f = fields();
        let s = f.coarse_spacing();
        let a = f.window(0, 0, 40, 20, s, None, (0, 0));
        let b = f.window(13, 7, 20, 10, s, None, (0, 0));
        for r in 0..10 {
            for c in 0..20 {
                assert_eq!(
                    a.get(Event::Activation, 13 + c, 7 + r),
                    b.get(Event::Activation, 13 + c, 7 + r)
                );
            }
        }
    }

    #[test]
    fn max_filter_equals_the_naive_maximum() {
        let (w, h) = (37, 23);
        let mut s = 5u64;
        let src: Vec<f32> = (0..w * h)
            .map(|_| {
                s = mix64(s);
                (s >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        for r in [0usize, 1, 2, 5, 11, 40] {
            let got = max_filter(&src, w, h, r);
            for y in 0..h {
                for x in 0..w {
                    let mut want = 0f32;
                    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                        for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                            want = want.max(src[yy * w + xx]);
                        }
                    }
                    assert_eq!(got[y * w + x], want, "r {r} at ({x}, {y})");
                }
            }
        }
    }

    #[test]
    fn an_anvil_spreads_toward_the_top_and_stops_narrowing() {
        let mut f = fields();
        f.layer.depth = 10;
        f.layer.preset.top_narrowing = 0.4;
        let before: Vec<f32> = (0..10).map(|k| f.shape(0.5, k)).collect();
        f.layer.preset.anvil = Some(crate::world::Anvil {
            start: 0.6,
            radius: 1000.0,
        });
        let w: Vec<f32> = (0..10).map(|k| f.anvil_weight(k)).collect();
        assert!(w[..6].iter().all(|&w| w == 0.0), "{w:?}");
        assert_eq!(w[9], 1.0);
        assert!(w[6] > 0.0 && w[6] < w[7] && w[7] < w[8] && w[8] < 1.0, "{w:?}");
        for k in 0..6 {
            assert_eq!(f.shape(0.5, k), before[k as usize]);
        }
        assert_eq!(f.shape(0.5, 9), 0.5, "no narrowing under the cap");
        assert_eq!(f.anvil_cells(), (1000.0 / f.layer.cell_size).ceil() as usize);
    }

    #[test]
    fn tops_are_narrower_than_bases() {
        let f = fields();
        let v = 0.5;
        assert!(f.shape(v, f.layer.depth - 1) < f.shape(v, 0));
        assert_eq!(f.shape(0.0, 0), 0.0);
    }
}
