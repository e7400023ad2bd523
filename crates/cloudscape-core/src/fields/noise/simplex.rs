//! Scalar simplex noise in 2D and 3D (Gustavson 2005), one sample at a time.

use super::coord::Coord;
use super::hash::hash3;

// 2D gradients: 16 unit vectors evenly spaced on the circle.
pub(super) const GRAD2: [[f64; 2]; 16] = {
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
pub(super) const GRAD3: [[f64; 3]; 16] = [
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
pub(super) const F2: f64 = 0.366_025_403_784_438_6; // (√3 − 1) / 2
pub(super) const G2: f64 = 0.211_324_865_405_187_1; // (3 − √3) / 6
pub(super) const F3: f64 = 1.0 / 3.0;
pub(super) const G3: f64 = 1.0 / 6.0;

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
