//! Counter-based randomness: every draw is a hash of (seed, layer, kind, level,
//! row, word, step, bit plane); there is no generator state, so any machine can
//! compute any cell at any step.
//!
//! A draw for a cell is a 16-bit number `r` whose bits come from 16 random words
//! (bit plane j holds bit 15−j of `r` for the 64 cells of a word). A Bernoulli
//! event with probability `q / 65536` fires when `r < q`. The packed kernel
//! compares all 64 lanes at once from the most significant plane down and stops
//! as soon as every lane is decided; the naive kernel assembles `r` per cell.
//! Both give the same bits.

use crate::fields::noise::mix64;

/// Which random event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Draw {
    Humidity = 1,
    Activation = 2,
    Extinction = 3,
}

/// wyhash's mixing step: a 64×64→128 multiply folded to 64 bits.
#[inline(always)]
fn wymix(a: u64, b: u64) -> u64 {
    let r = (a as u128).wrapping_mul(b as u128);
    (r as u64) ^ ((r >> 64) as u64)
}

const PLANE_SECRETS: [u64; 16] = [
    0xa076_1d64_78bd_642f,
    0xe703_7ed1_a0b4_28db,
    0x8ebc_6af0_9c88_c6e3,
    0x5899_65cc_7537_4cc3,
    0x1d8e_4e27_c47d_124f,
    0x9e37_79b9_7f4a_7c15,
    0xc2b2_ae3d_27d4_eb4f,
    0x1656_67b1_9e37_79f9,
    0x27d4_eb2f_1656_67c5,
    0x94d0_49bb_1331_11eb,
    0xbf58_476d_1ce4_e5b9,
    0x2545_f491_4f6c_dd1d,
    0x6a09_e667_f3bc_c909,
    0xbb67_ae85_84ca_a73b,
    0x3c6e_f372_fe94_f82b,
    0xa54f_f53a_5f1d_36f1,
];

/// Key of one (layer stream, draw kind, level, frame row, step).
#[inline]
pub fn row_key(stream: u64, draw: Draw, level: u32, row: i64, step: i64) -> u64 {
    let a = mix64(stream ^ ((draw as u64) << 56) ^ ((level as u64) << 48));
    let b = mix64(a ^ (row as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
    mix64(b ^ (step as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f))
}

/// Key of one 64-cell word (frame word index `wx` = frame x / 64) in a row.
#[inline(always)]
pub fn word_key(row_key: u64, wx: i64) -> u64 {
    wymix(row_key ^ (wx as u64), 0xe703_7ed1_a0b4_28db)
}

/// Random bit plane `j` (0 = most significant) of a word.
#[inline(always)]
pub fn plane(word_key: u64, j: usize) -> u64 {
    wymix(word_key ^ PLANE_SECRETS[j], 0x8ebc_6af0_9c88_c6e3)
}

/// 64 Bernoulli bits at once, decided only for the lanes in `care`. `p[0]` marks
/// lanes that always fire (q = 65536); `p[1 + j]` holds bit 15−j of q for the
/// other lanes. The caller combines the result so that lanes outside `care` do not
/// matter (they are OR-ed with a 1 or AND-ed with a 0), and leaves out of `care`
/// the lanes with q = 0 (see [`live_lanes`]), which never fire; so the loop stops as
/// soon as every lane that matters is decided, and no random word is made when
/// none does. The bits that matter are the same as deciding all 64 lanes.
#[inline]
pub fn bernoulli(p: &[u64; 17], row_key: u64, wx: i64, care: u64) -> u64 {
    let mut fired = p[0] & care;
    let mut undecided = care & !p[0];
    if undecided == 0 {
        return fired;
    }
    let key = word_key(row_key, wx);
    for j in 0..16 {
        let r = plane(key, j);
        let pj = p[1 + j];
        // r bit 0 where q bit 1: r < q for this lane; r bit 1 where q bit 0: r > q.
        fired |= undecided & pj & !r;
        undecided &= !(pj ^ r);
        if undecided == 0 {
            break;
        }
    }
    fired
}

/// The lanes of a bit-plane threshold with q > 0: the only ones that can fire.
pub fn live_lanes(p: &[u64; 17]) -> u64 {
    p.iter().fold(0, |a, &w| a | w)
}

/// The 16-bit draw of lane `bit` of a word (the naive kernel's view).
#[inline]
pub fn draw16(word_key: u64, bit: u32) -> u32 {
    let mut r = 0u32;
    for j in 0..16 {
        r = (r << 1) | ((plane(word_key, j) >> bit) & 1) as u32;
    }
    r
}

/// Whether a single cell's event with threshold `q` (0..=65536) fires.
#[inline]
pub fn fires(word_key: u64, bit: u32, q: u32) -> bool {
    q >= 65536 || draw16(word_key, bit) < q
}

/// Bit-plane form of 64 thresholds. A lane with q = 65536 goes to the
/// "always" mask; its bits 0..15 are zero, so it adds nothing to the planes.
pub fn planes_of(q: &[u32; 64]) -> [u64; 17] {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    {
        // SAFETY: the crate is built for x86-64-v3 (.cargo/config.toml), so AVX2 is present.
        unsafe { planes_of_avx2(q) }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
    {
        planes_of_scalar(q)
    }
}

/// The plain form of [`planes_of`]: one lane at a time.
pub fn planes_of_scalar(q: &[u32; 64]) -> [u64; 17] {
    let mut p = [0u64; 17];
    let any = q.iter().fold(0u32, |a, &v| a | v);
    if any == 0 {
        return p;
    }
    for (b, &v) in q.iter().enumerate() {
        p[0] |= ((v >> 16) as u64 & 1) << b;
    }
    for j in 0..16 {
        let shift = 15 - j;
        if (any >> shift) & 1 == 0 {
            continue;
        }
        let mut w = 0u64;
        for (b, &v) in q.iter().enumerate() {
            w |= (((v >> shift) & 1) as u64) << b;
        }
        p[1 + j] = w;
    }
    p
}

/// [`planes_of`] with AVX2: the wanted bit of 8 lanes is shifted into their sign
/// bits and collected by one `movemask`. Building drives is a bit-matrix transpose
/// done for every word of every run, and no crate offers this 64×17 shape.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
#[target_feature(enable = "avx2")]
unsafe fn planes_of_avx2(q: &[u32; 64]) -> [u64; 17] {
    use std::arch::x86_64::*;
    let mut p = [0u64; 17];
    let any = q.iter().fold(0u32, |a, &v| a | v);
    if any == 0 {
        return p;
    }
    let v: [__m256i; 8] = std::array::from_fn(|i| unsafe { _mm256_loadu_si256(q.as_ptr().add(8 * i).cast()) });
    // Bit `bit` of every lane, as a 64-bit mask.
    let gather = |bit: i32| -> u64 {
        let count = _mm_cvtsi32_si128(31 - bit);
        let mut w = 0u64;
        for (i, x) in v.iter().enumerate() {
            let m = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_sll_epi32(*x, count)));
            w |= (m as u32 as u64) << (8 * i);
        }
        w
    };
    if any >> 16 != 0 {
        p[0] = gather(16);
    }
    for j in 0..16 {
        let shift = 15 - j as i32;
        if (any >> shift) & 1 != 0 {
            p[1 + j] = gather(shift);
        }
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_bernoulli_equals_per_lane_comparison() {
        let mut s = 12345u64;
        for _ in 0..500 {
            let mut q = [0u32; 64];
            for v in q.iter_mut() {
                s = mix64(s);
                *v = match s % 5 {
                    0 => 0,
                    1 => 65536,
                    _ => (s >> 20) as u32 % 65537,
                };
            }
            let (rk, wx) = (mix64(s ^ 99), (s % 1000) as i64 - 500);
            let key = word_key(rk, wx);
            let care = mix64(s ^ 7) | if s % 3 == 0 { !0 } else { 0 };
            let packed = bernoulli(&planes_of(&q), rk, wx, care);
            for b in 0..64 {
                if (care >> b) & 1 == 0 {
                    continue;
                }
                assert_eq!((packed >> b) & 1 == 1, fires(key, b, q[b as usize]));
            }
        }
    }

    #[test]
    fn planes_of_equals_its_scalar_form() {
        let mut s = 99u64;
        for _ in 0..2000 {
            let mut q = [0u32; 64];
            let top = 1 + (mix64(s) % 17) as u32;
            for v in q.iter_mut() {
                s = mix64(s);
                *v = match s % 7 {
                    0 => 0,
                    1 => 65536,
                    _ => (s >> 20) as u32 % (1 << top).min(65537),
                };
            }
            assert_eq!(planes_of(&q), planes_of_scalar(&q), "{q:?}");
        }
    }

    #[test]
    fn rate_matches_probability() {
        // 640k draws at p = 0.1 and p = 0.001: within 5 standard deviations.
        for &p in &[0.1f64, 0.001] {
            let q = (p * 65536.0).round() as u32;
            let pl = planes_of(&[q; 64]);
            let mut count = 0u64;
            let n = 10_000u64;
            for w in 0..n {
                count += bernoulli(&pl, row_key(7, Draw::Activation, 3, 11, 5), w as i64, !0).count_ones() as u64;
            }
            let trials = (n * 64) as f64;
            let qp = q as f64 / 65536.0;
            let sd = (trials * qp * (1.0 - qp)).sqrt();
            assert!((count as f64 - trials * qp).abs() < 5.0 * sd, "p={p} got {count}");
        }
    }
}
