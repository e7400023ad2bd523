//! Metaballs: a lattice of spheres that collect the smoothed density (Dobashi et al.
//! 2000 §4; Rosa 2013 §4.2.3), the representation the billboards are drawn from.
//!
//! The lattice is anchored to the world, not to a tile, so neighbouring tiles share
//! one lattice and meet without seams. Every other row is offset by half a spacing
//! (Rosa: "every odd horizontal row of metaballs are offset"), and so is every other
//! vertical level, which weakens lattice artifacts:
//!
//! ```text
//! x = (i + ½·((j + k) mod 2)) · s + o_x(k),   y = (j + ½·(k mod 2)) · s + o_y(k),
//! z = base + (k + ½) · s_v
//! ```
//!
//! with `s` the horizontal spacing and `s_v = thickness / n_v` the vertical spacing
//! (`n_v` levels fill the layer exactly).
//!
//! The lattice drifts with the air ([`Drift`]): at time `t` level `k` is moved by
//! `o(k) = v(z_k) · t` (the wind at its altitude), taken modulo the lattice's period
//! (`s` in x, `2s` in y, so the row pattern is kept) to stay small at any `t`. A ball
//! of the lattice at `t` is then, up to rounding, a ball of the lattice at `t + Δt`
//! moved by `v · Δt` ([`Lattice::successor`] names it): the balls follow the cloud
//! they hold, so the shading of one instant serves as the end of one keyframe span
//! and the start of the next (`render::tile`).
//!
//! A metaball's density is the field-weighted mean of the cell densities within its
//! radius, `d = Σ ρ_j f(r_j/R) / Σ f(r_j/R)`, where cells beyond the grid (above or
//! below the layer) count as empty air (Rosa: "out of range ... a zero is returned").
//! The continuous field the lattice stands for is `ρ̃(x) = Σ d_i f(|x − c_i|/R) / K`,
//! with `K` the lattice's mean field sum ([`Lattice::field_sum`]), so a uniform
//! density ρ is reproduced as ρ on average.

use super::Grid;

/// Wyvill's field function (Wyvill, McPheeters & Wyvill 1986, as used by Dobashi 2000):
/// `f(r) = −4/9 r⁶ + 17/9 r⁴ − 22/9 r² + 1` for `0 <= r <= 1`, 0 beyond (and for NaN).
/// f(0) = 1, f(1) = 0, f'(1) = 0: smooth where it meets zero.
#[inline]
pub fn wyvill(r: f64) -> f64 {
    if !(r.abs() < 1.0) {
        return 0.0;
    }
    let r2 = r * r;
    let r4 = r2 * r2;
    (-4.0 / 9.0) * r4 * r2 + (17.0 / 9.0) * r4 - (22.0 / 9.0) * r2 + 1.0
}

/// ∫ f(|x|) d³x over the unit ball, exactly: `4π (−4/81 + 17/63 − 22/45 + 1/3)`.
pub fn wyvill_volume_integral() -> f64 {
    4.0 * std::f64::consts::PI * (-4.0 / 81.0 + 17.0 / 63.0 - 22.0 / 45.0 + 1.0 / 3.0)
}

/// Where a density grid sits in the world: the south-west-bottom corner of its
/// first cell and the cell sizes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridPlacement {
    /// World x (metres) of the west edge of column 0.
    pub x0: f64,
    /// World y (metres) of the south edge of row 0.
    pub y0: f64,
    /// Width of a column, metres (`cell_size · 2^level`).
    pub column: f64,
    /// Altitude of the grid's bottom, metres (the layer base).
    pub base: f64,
    /// Height of a cell, metres.
    pub cell_height: f64,
}

/// The metaball lattice of one layer at one level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lattice {
    /// Horizontal spacing, metres.
    pub spacing: f64,
    /// Vertical spacing, metres (the layer thickness divided into whole levels).
    pub vertical_spacing: f64,
    /// Number of vertical levels.
    pub levels: u32,
    /// Metaball radius, metres.
    pub radius: f64,
    /// Altitude of the layer base, metres.
    pub base: f64,
    /// How the lattice moves with the wind (none: anchored to the world).
    pub drift: Drift,
}

/// The motion of a lattice with the air: the wind at the layer's base, its change
/// with height, and the time the lattice is placed for.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Drift {
    /// Wind at the layer's base, m/s (x east, y north).
    pub wind: [f64; 2],
    /// Change of the wind with height, (m/s) per metre.
    pub shear: [f64; 2],
    /// World-clock seconds: level `k` is moved by `v(z_k) · t` modulo the period.
    pub t: f64,
}

/// One metaball: a sphere of the lattice with the density it collected.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Metaball {
    /// Lattice indices (i, j, k): unique in the world for one lattice.
    pub index: [i64; 3],
    /// Centre, world metres (x east, y north, altitude).
    pub centre: [f64; 3],
    /// Collected density in [0, 1].
    pub density: f32,
}

/// Field weights around a ball for one sub-cell offset: (dk, dr, dc, f) from the
/// anchor cell, and their sum (cells beyond the grid still count, as empty air).
struct Stencil {
    key: [i64; 3],
    /// The grid level of the stencil's first level (taps off the grid are left out).
    first_k: i64,
    taps: Vec<(i32, i32, i32, f32)>,
    weight: f64,
}

impl Lattice {
    /// A lattice for a layer of `thickness` metres at altitude `base`, with horizontal
    /// `spacing` and radius `radius` (metres). The vertical spacing is the thickness
    /// split into `max(1, round(thickness / spacing))` levels.
    pub fn new(spacing: f64, radius: f64, base: f64, thickness: f64) -> Lattice {
        let levels = ((thickness / spacing).round() as u32).max(1);
        Lattice {
            spacing,
            vertical_spacing: thickness / levels as f64,
            levels,
            radius,
            base,
            drift: Drift::default(),
        }
    }

    /// The same lattice drifting with `wind` (m/s at the base) and `shear` ((m/s) per
    /// metre), placed for time `t`.
    pub fn drifting(self, wind: [f64; 2], shear: [f64; 2], t: f64) -> Lattice {
        Lattice {
            drift: Drift { wind, shear, t },
            ..self
        }
    }

    /// The same lattice placed for time `t` (same drift).
    pub fn at(self, t: f64) -> Lattice {
        Lattice {
            drift: Drift { t, ..self.drift },
            ..self
        }
    }

    /// Wind at level `k` (m/s): the base wind plus the shear over its height.
    fn velocity(&self, k: i64) -> [f64; 2] {
        let h = (k as f64 + 0.5) * self.vertical_spacing;
        let d = &self.drift;
        [d.wind[0] + d.shear[0] * h, d.wind[1] + d.shear[1] * h]
    }

    /// How far level `k` has drifted at the lattice's time, modulo the period
    /// (`s` in x, `2s` in y), metres. Written out rather than kept as a running sum so
    /// that any machine places the lattice of any time alike: `v · t` rounds once.
    pub fn offset(&self, k: i64) -> [f64; 2] {
        let v = self.velocity(k);
        let t = self.drift.t;
        let s = self.spacing;
        let wrap = |d: f64, period: f64| {
            let o = d.rem_euclid(period);
            // NaN/∞ only from a degenerate spacing; 0 keeps the lattice where it was.
            if o.is_finite() && o < period { o } else { 0.0 }
        };
        [wrap(v[0] * t, s), wrap(v[1] * t, 2.0 * s)]
    }

    /// Centre of lattice point (i, j, k), world metres.
    pub fn centre(&self, i: i64, j: i64, k: i64) -> [f64; 3] {
        let ox = 0.5 * ((j + k).rem_euclid(2)) as f64;
        let oy = 0.5 * (k.rem_euclid(2)) as f64;
        let o = self.offset(k);
        [
            (i as f64 + ox) * self.spacing + o[0],
            (j as f64 + oy) * self.spacing + o[1],
            self.base + (k as f64 + 0.5) * self.vertical_spacing,
        ]
    }

    /// The index, in `later` (this lattice placed for a later time), of the point that
    /// the wind carries lattice point `index` to: its centre moved by `v · Δt` lies
    /// on `later`'s point up to rounding (the drifts are the same motion).
    pub fn successor(&self, index: [i64; 3], later: &Lattice) -> [i64; 3] {
        let [i, j, k] = index;
        let v = self.velocity(k);
        let dt = later.drift.t - self.drift.t;
        let (a, b) = (self.offset(k), later.offset(k));
        let s = self.spacing;
        let di = ((a[0] + v[0] * dt - b[0]) / s).round();
        let dj = ((a[1] + v[1] * dt - b[1]) / (2.0 * s)).round() * 2.0;
        let step = |d: f64| if d.is_finite() { d.clamp(-1e15, 1e15) as i64 } else { 0 };
        [i.saturating_add(step(di)), j.saturating_add(step(dj)), k]
    }

    /// The mean of `Σ_i f(|x − c_i|/R)` over space: (balls per volume) × ∫f over the ball.
    pub fn field_sum(&self) -> f64 {
        wyvill_volume_integral() * self.radius.powi(3) / (self.spacing * self.spacing * self.vertical_spacing)
    }

    /// The metaballs whose centres lie in `owned` = [x0, y0, x1, y1) (world metres),
    /// each collecting density from `grid` placed at `place`. Balls with density below
    /// `min_density` are dropped. Ordered by (k, j, i); deterministic.
    ///
    /// A ball whose stencil covers only empty cells collects exactly 0 and is dropped
    /// without summing its taps: a table of non-empty columns ([`Occupancy`]) answers
    /// for the box under it. Clear air costs a lookup, not a stencil, and the balls
    /// kept are the same, bit for bit.
    pub fn collect(&self, grid: &Grid<f32>, place: &GridPlacement, owned: [f64; 4], min_density: f32) -> Vec<Metaball> {
        use rayon::prelude::*;
        let s = self.spacing;
        let occupied = Occupancy::of(grid);
        let mut rows = Vec::new();
        for k in 0..self.levels as i64 {
            let oy = 0.5 * (k.rem_euclid(2)) as f64;
            let o = self.offset(k);
            let j0 = ((owned[1] - o[1]) / s - oy).ceil() as i64;
            let j1 = ((owned[3] - o[1]) / s - oy).ceil() as i64;
            for j in j0..j1 {
                rows.push((k, j));
            }
        }
        // The horizontal reach of a stencil, cells: what `stencil` spans.
        let reach = (2.0 * self.radius / place.column).ceil() as i64 + 1;
        let per_row: Vec<Vec<Metaball>> = rows
            .par_iter()
            .map(|&(k, j)| {
                let ox = 0.5 * ((j + k).rem_euclid(2)) as f64;
                let o = self.offset(k);
                let i0 = ((owned[0] - o[0]) / s - ox).ceil() as i64;
                let i1 = ((owned[2] - o[0]) / s - ox).ceil() as i64;
                let mut stencils: Vec<Stencil> = Vec::new();
                let mut out = Vec::new();
                for i in i0..i1 {
                    let c = self.centre(i, j, k);
                    let (first, _) = self.stencil_anchor(place, c);
                    if !occupied.any(first[1], first[0], reach) {
                        continue;
                    }
                    let d = self.collect_cached(grid, place, c, &mut stencils);
                    if d >= min_density && d > 0.0 {
                        out.push(Metaball {
                            index: [i, j, k],
                            centre: c,
                            density: d,
                        });
                    }
                }
                out
            })
            .collect();
        per_row.into_iter().flatten().collect()
    }

    /// The first cell index in each axis whose centre may lie within the radius of `c`,
    /// and the offset of `c` from that cell's centre (in cells).
    fn stencil_anchor(&self, place: &GridPlacement, c: [f64; 3]) -> ([i64; 3], [f64; 3]) {
        let r = self.radius;
        let (w, h) = (place.column, place.cell_height);
        let axes = [(c[0], place.x0, w), (c[1], place.y0, w), (c[2], place.base, h)];
        let first = axes.map(|(centre, origin, size)| ((centre - r - origin) / size - 0.5).ceil() as i64);
        let offset = [0, 1, 2].map(|a| {
            let (centre, origin, size) = axes[a];
            (centre - origin) / size - 0.5 - first[a] as f64
        });
        (first, offset)
    }

    /// [`Lattice::collect_at`] with the field weights of each distinct sub-cell offset
    /// computed once: a lattice whose spacing is a multiple of the cell size has only a
    /// few offsets, so most balls reuse a stencil.
    fn collect_cached(&self, grid: &Grid<f32>, place: &GridPlacement, c: [f64; 3], cache: &mut Vec<Stencil>) -> f32 {
        let (first, offset) = self.stencil_anchor(place, c);
        let key = offset.map(|v| (v * 1e6).round() as i64);
        let idx = match cache.iter().position(|s| s.key == key && s.first_k == first[2]) {
            Some(i) => i,
            None => {
                cache.push(self.stencil(place, offset, key, (first[2], grid.depth)));
                cache.len() - 1
            }
        };
        let st = &cache[idx];
        if st.weight <= 0.0 {
            return 0.0;
        }
        let mut sum = 0.0f64;
        for &(dk, dr, dc, f) in &st.taps {
            let (kk, rr, cc) = (first[2] + dk as i64, first[1] + dr as i64, first[0] + dc as i64);
            if kk >= 0
                && rr >= 0
                && cc >= 0
                && (kk as usize) < grid.depth
                && (rr as usize) < grid.rows
                && (cc as usize) < grid.cols
            {
                sum += f as f64 * grid.get(kk as usize, rr as usize, cc as usize) as f64;
            }
        }
        (sum / st.weight).clamp(0.0, 1.0) as f32
    }

    /// The field-weighted mean density around `c` (cells outside the grid are empty):
    /// the naive reference of the cached stencils [`Lattice::collect`] uses.
    pub fn collect_at(&self, grid: &Grid<f32>, place: &GridPlacement, c: [f64; 3]) -> f32 {
        let r = self.radius;
        let (w, h) = (place.column, place.cell_height);
        let range = |centre: f64, origin: f64, size: f64| {
            let lo = ((centre - r - origin) / size - 0.5).ceil() as i64;
            let hi = ((centre + r - origin) / size - 0.5).floor() as i64;
            (lo, hi)
        };
        let (c0, c1) = range(c[0], place.x0, w);
        let (r0, r1) = range(c[1], place.y0, w);
        let (k0, k1) = range(c[2], place.base, h);
        let (mut sum, mut weight) = (0.0f64, 0.0f64);
        for kk in k0..=k1 {
            let dz = place.base + (kk as f64 + 0.5) * h - c[2];
            let kin = kk >= 0 && (kk as usize) < grid.depth;
            for rr in r0..=r1 {
                let dy = place.y0 + (rr as f64 + 0.5) * w - c[1];
                let rin = kin && rr >= 0 && (rr as usize) < grid.rows;
                for cc in c0..=c1 {
                    let dx = place.x0 + (cc as f64 + 0.5) * w - c[0];
                    let f = wyvill((dx * dx + dy * dy + dz * dz).sqrt() / r);
                    if f <= 0.0 {
                        continue;
                    }
                    weight += f;
                    if rin && cc >= 0 && (cc as usize) < grid.cols {
                        sum += f * grid.get(kk as usize, rr as usize, cc as usize) as f64;
                    }
                }
            }
        }
        if weight > 0.0 {
            (sum / weight).clamp(0.0, 1.0) as f32
        } else {
            0.0
        }
    }

    ///
    /// `(first_k, depth)` places the stencil's first level against the grid's levels:
    /// only taps on the grid's levels are kept (cells above and below the grid are
    /// empty), but the weight counts the whole ball. Up to [`EXACT_WEIGHT_LEVELS`]
    /// levels the weight is the sum of every tap; beyond, at coarse levels where the
    /// radius spans thousands of cell heights while the grid has a few, it is the
    /// vertical integral of the field ([`column_weight`]), so a stencil costs the
    /// grid's depth and not the radius.
    fn stencil(
        &self,
        place: &GridPlacement,
        offset: [f64; 3],
        key: [i64; 3],
        (first_k, depth): (i64, usize),
    ) -> Stencil {
        let r = self.radius;
        let (w, h) = (place.column, place.cell_height);
        let n = [
            (2.0 * r / w).ceil() as i32 + 1,
            (2.0 * r / w).ceil() as i32 + 1,
            (2.0 * r / h).ceil() as i32 + 1,
        ];
        let exact = n[2] <= EXACT_WEIGHT_LEVELS;
        // The levels whose taps can land on the grid.
        let on_grid = (-first_k).max(0)..=(depth as i64 - 1 - first_k).min(n[2] as i64);
        let levels = if exact { 0..=n[2] as i64 } else { on_grid.clone() };
        let mut taps = Vec::new();
        // The weight as the f32 taps apply it, so a uniform field stays exact.
        let mut weight = 0.0f64;
        for dk in levels {
            let dz = (dk as f64 - offset[2]) * h;
            for dr in 0..=n[1] {
                let dy = (dr as f64 - offset[1]) * w;
                for dc in 0..=n[0] {
                    let dx = (dc as f64 - offset[0]) * w;
                    let f = wyvill((dx * dx + dy * dy + dz * dz).sqrt() / r);
                    if f > 0.0 {
                        if exact {
                            weight += f as f32 as f64;
                        }
                        if on_grid.contains(&dk) {
                            taps.push((dk as i32, dr, dc, f as f32));
                        }
                    }
                }
            }
        }
        if !exact {
            for dr in 0..=n[1] {
                let dy = (dr as f64 - offset[1]) * w;
                for dc in 0..=n[0] {
                    let dx = (dc as f64 - offset[0]) * w;
                    weight += column_weight((dx * dx + dy * dy) / (r * r)) * r / h;
                }
            }
        }
        Stencil {
            key,
            first_k,
            taps,
            weight,
        }
    }
}

/// Which columns of a grid hold any non-zero cell, as a summed-area table: whether a
/// box of columns is all clear air costs four lookups.
struct Occupancy {
    rows: usize,
    cols: usize,
    /// `sum[(r + 1) · (cols + 1) + c + 1]`: non-empty columns in rows `..=r`, cols `..=c`.
    sum: Vec<u32>,
}

impl Occupancy {
    fn of(grid: &Grid<f32>) -> Occupancy {
        let (rows, cols) = (grid.rows, grid.cols);
        let mut filled = vec![false; rows * cols];
        for k in 0..grid.depth {
            let level = &grid.data[grid.index(k, 0, 0)..][..rows * cols];
            for (f, &v) in filled.iter_mut().zip(level) {
                // NaN counts as filled: such a ball is summed as it always was.
                *f |= v != 0.0;
            }
        }
        let w = cols + 1;
        let mut sum = vec![0u32; (rows + 1) * w];
        for r in 0..rows {
            let mut run = 0u32;
            for c in 0..cols {
                run += u32::from(filled[r * cols + c]);
                sum[(r + 1) * w + c + 1] = sum[r * w + c + 1] + run;
            }
        }
        Occupancy { rows, cols, sum }
    }

    /// Whether any column in rows `r0..=r0 + n`, cols `c0..=c0 + n` (clipped to the
    /// grid) holds a non-zero cell.
    fn any(&self, r0: i64, c0: i64, n: i64) -> bool {
        let clip = |v: i64, len: usize| v.clamp(0, len as i64) as usize;
        let (r_lo, r_hi) = (
            clip(r0, self.rows),
            clip(r0.saturating_add(n).saturating_add(1), self.rows),
        );
        let (c_lo, c_hi) = (
            clip(c0, self.cols),
            clip(c0.saturating_add(n).saturating_add(1), self.cols),
        );
        if r_lo >= r_hi || c_lo >= c_hi {
            return false;
        }
        let w = self.cols + 1;
        let at = |r: usize, c: usize| self.sum[r * w + c];
        at(r_hi, c_hi) + at(r_lo, c_lo) > at(r_lo, c_hi) + at(r_hi, c_lo)
    }
}

/// Most levels a stencil sums its weight over tap by tap; beyond, the weight is the
/// integral of the field ([`column_weight`]). Just past 1,024 levels the two differ
/// by under 1e-6 relative (tested; the field and its slope vanish at the ball's
/// edge, so the sum of samples converges fast to the integral), and 1,024 levels
/// keep a stencil under a millisecond; a level-19 tile's balls span 2.6 million.
pub const EXACT_WEIGHT_LEVELS: i32 = 1024;

/// `∫ f(√(b + t²)) dt` over the chord `b + t² < 1`, exactly: the vertical integral of
/// Wyvill's field through a ball of radius 1 at squared horizontal distance `b`. With
/// `u = b + t²`, `f = 1 − 22/9 u + 17/9 u² − 4/9 u³` is a polynomial in `t²`.
pub fn column_weight(b: f64) -> f64 {
    if !(b < 1.0) {
        return 0.0;
    }
    let b = b.max(0.0);
    let c0 = 1.0 - 22.0 / 9.0 * b + 17.0 / 9.0 * b * b - 4.0 / 9.0 * b * b * b;
    let c2 = -22.0 / 9.0 + 34.0 / 9.0 * b - 12.0 / 9.0 * b * b;
    let c4 = 17.0 / 9.0 - 12.0 / 9.0 * b;
    let c6 = -4.0 / 9.0;
    let z = (1.0 - b).sqrt();
    let (z2, z3) = (z * z, z * z * z);
    2.0 * (c0 * z + c2 * z3 / 3.0 + c4 * z3 * z2 / 5.0 + c6 * z3 * z2 * z2 / 7.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn field_function_endpoints_and_smoothness() {
        assert_eq!(wyvill(0.0), 1.0);
        assert!(wyvill(1.0).abs() < 1e-15);
        assert_eq!(wyvill(1.5), 0.0);
        assert_eq!(wyvill(f64::NAN), 0.0);
        // Derivative at 1 from the left: f'(r) = −24/9 r⁵ + 68/9 r³ − 44/9 r → 0 at r = 1.
        let h = 1e-6;
        let slope = (wyvill(1.0) - wyvill(1.0 - h)) / h;
        assert!(slope.abs() < 1e-4, "{slope}");
        // Monotone decreasing on [0, 1].
        let mut prev = 1.0;
        for i in 1..=100 {
            let v = wyvill(i as f64 / 100.0);
            assert!(v <= prev && v >= 0.0);
            prev = v;
        }
    }

    #[test]
    fn volume_integral_matches_numeric_quadrature() {
        // ∫ f dV = 4π ∫ f(r) r² dr, midpoint rule.
        let n = 100_000;
        let numeric: f64 = (0..n)
            .map(|i| {
                let r = (i as f64 + 0.5) / n as f64;
                wyvill(r) * r * r
            })
            .sum::<f64>()
            / n as f64
            * 4.0
            * std::f64::consts::PI;
        assert!((numeric - wyvill_volume_integral()).abs() < 1e-8, "{numeric}");
    }

    #[test]
    fn uniform_density_is_collected_exactly_and_offsets_alternate() {
        let grid = Grid::filled(10, 40, 40, 0.6f32);
        let place = GridPlacement {
            x0: 0.0,
            y0: 0.0,
            column: 100.0,
            base: 1000.0,
            cell_height: 100.0,
        };
        let lat = Lattice::new(200.0, 250.0, 1000.0, 1000.0);
        assert_eq!(lat.levels, 5);
        // Interior ball, away from the top/bottom: exactly the uniform value.
        let c = lat.centre(10, 10, 2);
        assert!((lat.collect_at(&grid, &place, c) - 0.6).abs() < 1e-6);
        // The bottom level sees air below: less than the uniform value, more than 0.
        let b = lat.collect_at(&grid, &place, lat.centre(10, 10, 0));
        assert!(b > 0.2 && b < 0.6, "{b}");
        // Odd rows are shifted by half a spacing in x; odd levels in y.
        assert_eq!(lat.centre(0, 1, 0)[0] - lat.centre(0, 0, 0)[0], 100.0);
        assert_eq!(lat.centre(0, 0, 1)[1] - lat.centre(0, 0, 0)[1], 100.0);
        let balls = lat.collect(&grid, &place, [0.0, 0.0, 4000.0, 4000.0], 0.001);
        assert_eq!(balls.len(), 20 * 20 * 5);
        assert!(balls.iter().all(|b| b.centre[0] >= 0.0 && b.centre[0] < 4000.0));
    }

    #[test]
    fn cached_stencils_agree_with_the_naive_sum() {
        // Pseudo-random density; lattices aligned and not aligned with the cells.
        let mut grid = Grid::<f32>::new(7, 30, 40);
        for (i, v) in grid.data.iter_mut().enumerate() {
            *v = ((i as u64).wrapping_mul(2_654_435_761) % 1000) as f32 / 1000.0;
        }
        let place = GridPlacement {
            x0: -1000.0,
            y0: 500.0,
            column: 100.0,
            base: 2000.0,
            cell_height: 90.0,
        };
        for (spacing, radius) in [(200.0, 250.0), (130.0, 210.0), (400.0, 500.0)] {
            let lat = Lattice::new(spacing, radius, 2000.0, 630.0);
            let balls = lat.collect(&grid, &place, [-1000.0, 500.0, 3000.0, 3500.0], 0.0);
            assert!(!balls.is_empty());
            for b in &balls {
                let naive = lat.collect_at(&grid, &place, b.centre);
                assert!((b.density - naive).abs() < 1e-5, "{b:?} vs {naive}");
            }
        }
    }

    #[test]
    fn column_weight_is_the_integral_of_the_field() {
        // Against a fine midpoint sum of the field along the chord.
        for b in [0.0, 0.1, 0.37, 0.8, 0.99] {
            let n = 200_000;
            let half = (1.0f64 - b).sqrt();
            let dt = 2.0 * half / n as f64;
            let sum: f64 = (0..n)
                .map(|i| wyvill((b + (-half + (i as f64 + 0.5) * dt).powi(2)).sqrt()) * dt)
                .sum();
            assert!(
                (column_weight(b) - sum).abs() < 1e-9,
                "b {b}: {} vs {sum}",
                column_weight(b)
            );
        }
        assert_eq!(column_weight(1.0), 0.0);
        assert_eq!(column_weight(f64::NAN), 0.0);
    }

    #[test]
    fn integral_weight_matches_the_tap_sum_past_the_exact_limit() {
        // A stencil just past EXACT_WEIGHT_LEVELS, weighed both ways: the integral and
        // the tap-by-tap sum (which the stencil would use below the limit).
        let (w, h) = (100.0, 1.0);
        let r = 0.5 * h * (EXACT_WEIGHT_LEVELS + 8) as f64;
        let lat = Lattice::new(2.0 * w, r, 0.0, 200.0);
        let place = GridPlacement {
            x0: 0.0,
            y0: 0.0,
            column: w,
            base: 0.0,
            cell_height: h,
        };
        // A ball's centre lies about a radius past the stencil's first tap.
        let (rw, rh) = ((r / w).floor(), (r / h).floor());
        for offset in [[rw + 0.3, rw + 0.7, rh + 0.25], [rw, rw + 0.5, rh + 0.5]] {
            let st = lat.stencil(&place, offset, [0; 3], (-600, 200));
            let n = [(2.0 * r / w).ceil() as i32 + 1, (2.0 * r / h).ceil() as i32 + 1];
            let mut naive = 0.0;
            for dk in 0..=n[1] {
                for dr in 0..=n[0] {
                    for dc in 0..=n[0] {
                        let d = [
                            (dc as f64 - offset[0]) * w,
                            (dr as f64 - offset[1]) * w,
                            (dk as f64 - offset[2]) * h,
                        ];
                        naive += wyvill((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() / r) as f32 as f64;
                    }
                }
            }
            assert!(((st.weight - naive) / naive).abs() < 1e-6, "{} vs {naive}", st.weight);
            // Only the grid's 200 levels keep taps.
            assert!(
                st.taps.iter().all(|t| (600..800).contains(&t.0)),
                "{:?}",
                st.taps.first()
            );
        }
    }

    #[test]
    fn cached_stencils_agree_with_the_naive_sum_at_a_coarse_level() {
        // A level-9 tile of a thin layer: 51 km columns, 100 m cells, two levels. The
        // radius spans about 1,300 cell heights, nearly all of them off the grid.
        let mut grid = Grid::<f32>::new(2, 12, 12);
        for (i, v) in grid.data.iter_mut().enumerate() {
            *v = ((i as u64).wrapping_mul(2_654_435_761) % 1000) as f32 / 1000.0;
        }
        let column = 100.0 * 2f64.powi(9);
        let place = GridPlacement {
            x0: 0.0,
            y0: 0.0,
            column,
            base: 1000.0,
            cell_height: 100.0,
        };
        let lat = Lattice::new(2.0 * column, 2.5 * column, 1000.0, 200.0);
        let balls = lat.collect(&grid, &place, [0.0, 0.0, 12.0 * column, 12.0 * column], 0.0);
        assert!(!balls.is_empty());
        for b in &balls {
            let naive = lat.collect_at(&grid, &place, b.centre);
            assert!((b.density - naive).abs() <= 1e-6 * naive.max(1e-3), "{b:?} vs {naive}");
        }
    }

    #[test]
    fn empty_metaballs_are_dropped() {
        let mut grid = Grid::<f32>::new(4, 20, 20);
        let i = grid.index(1, 10, 10);
        grid.data[i] = 1.0;
        let place = GridPlacement {
            x0: 0.0,
            y0: 0.0,
            column: 100.0,
            base: 0.0,
            cell_height: 100.0,
        };
        let lat = Lattice::new(100.0, 150.0, 0.0, 400.0);
        let balls = lat.collect(&grid, &place, [0.0, 0.0, 2000.0, 2000.0], 1e-4);
        assert!(!balls.is_empty() && balls.len() < 30, "{}", balls.len());
        // Every kept ball lies within its radius of the one dense cell (1050, 1050, 150).
        for b in &balls {
            let d = ((b.centre[0] - 1050.0).powi(2) + (b.centre[1] - 1050.0).powi(2) + (b.centre[2] - 150.0).powi(2))
                .sqrt();
            assert!(d < 150.0, "{b:?}");
        }
    }

    #[test]
    fn field_sum_matches_a_brute_force_lattice_average() {
        let lat = Lattice::new(200.0, 250.0, 0.0, 100_000.0);
        // Average Σ f over random-ish points deep inside an unbounded lattice.
        let mut total = 0.0;
        let n = 400;
        for p in 0..n {
            let x = 10_000.0 + (p as f64 * 37.77) % 400.0;
            let y = 10_000.0 + (p as f64 * 91.13) % 400.0;
            let z = 50_000.0 + (p as f64 * 53.9) % 400.0;
            let mut s = 0.0;
            let (i0, j0, k0) = (
                (x / 200.0) as i64,
                (y / 200.0) as i64,
                (z / lat.vertical_spacing) as i64,
            );
            for k in k0 - 3..=k0 + 3 {
                for j in j0 - 3..=j0 + 3 {
                    for i in i0 - 3..=i0 + 3 {
                        let c = lat.centre(i, j, k);
                        let d = ((x - c[0]).powi(2) + (y - c[1]).powi(2) + (z - c[2]).powi(2)).sqrt();
                        s += wyvill(d / 250.0);
                    }
                }
            }
            total += s;
        }
        let mean = total / n as f64;
        assert!(
            (mean / lat.field_sum() - 1.0).abs() < 0.05,
            "{mean} vs {}",
            lat.field_sum()
        );
    }
}
