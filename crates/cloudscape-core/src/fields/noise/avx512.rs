//! [`super::simplex3`] for eight samples at a time in AVX-512: the same IEEE operations
//! in the same order per lane (no FMA, no reassociation), so the same bits.
//! Branches become masks: the simplex ordering selects corner offsets by mask, and
//! a corner outside its radius is replaced by +0.0 after being computed.

use std::arch::x86_64::*;

use super::coord::{Coord, SPLIT, split};
use super::hash::{HASH_MUL, MIX_MUL};
use super::simplex::{F2, F3, G2, G3, GRAD2, GRAD3};

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

/// `mix64(seed ^ a ^ b.rotate_left(21) ^ c.rotate_left(42))`: [`super::hash::hash3`]
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
pub unsafe fn fbm_row(seed: u64, amp: f64, ints: &[i64], fracs: &[f64], y: Coord, z: Option<Coord>, out: &mut [f64]) {
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
