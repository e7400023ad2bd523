//! Counter-based randomness: every draw is a hash of (seed, layer, level, step,
//! row, word, event, lane); there is no generator state, so any machine can
//! compute any cell at any step.
//!
//! A Bernoulli event with probability `q / 65536` fires for a cell when its
//! 16-bit draw `r` is below `q`. The draw is read a byte at a time: the high
//! byte `r_hi` comes from one 32-bit hash per 4 lanes (16 hashes per 64-cell
//! word, made 8 at a time with AVX2), and only where `r_hi` equals the high
//! byte of `q` (1 lane in 256) is the low byte `r_lo` hashed for that lane. So
//! `r < q` ⇔ `r_hi < q_hi`, or `r_hi = q_hi` and `r_lo < q_lo`: the same event
//! as comparing all 16 bits, with a fixed amount of work per word and almost
//! no branches. The naive kernel computes the same bytes one lane at a time
//! ([`fires`]); the unit tests hold the two forms equal.
//!
//! The hash of the high bytes is lowbias32 (Chris Wellons' integer hash, a
//! bijection with good avalanche) applied to the word key's two halves, each
//! XOR-ed with 8 lane constants; the word key itself comes from wyhash's mix
//! of the row key and the word index. We write this instead of using a crate
//! because the bytes are part of the output contract (ALGORITHM_VERSION): they
//! must not change with a dependency's release, and the AVX2 and scalar forms
//! must agree bit for bit.

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

/// Chris Wellons' lowbias32: a 32-bit bijection with low avalanche bias.
#[inline(always)]
fn lowbias32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^ (x >> 16)
}

/// Per-lane-group constants: hash `i` (lanes 4i..4i+3) uses the low key half
/// for i < 8 and the high half for i ≥ 8, XOR-ed with `LANE[i]`.
const LANE: [u32; 16] = [
    0x9e37_79b9,
    0x7f4a_7c15,
    0xf39c_c060,
    0x5ced_c834,
    0x1082_276b,
    0xf58b_4ab1,
    0x6a09_e667,
    0xbb67_ae85,
    0x3c6e_f372,
    0xa54f_f53a,
    0x510e_527f,
    0x9b05_688c,
    0x1f83_d9ab,
    0x5be0_cd19,
    0xcbbb_9d5d,
    0x629a_292a,
];

/// Key of one (layer stream, level, step): made once per level and step.
#[inline]
pub fn step_key(stream: u64, level: u32, step: i64) -> u64 {
    let a = mix64(stream ^ ((level as u64) << 48));
    mix64(a ^ (step as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f))
}

/// Key of one frame row under a [`step_key`].
#[inline]
pub fn row_key(step_key: u64, row: i64) -> u64 {
    mix64(step_key ^ (row as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15))
}

/// Key of one 64-cell word (frame word index `wx` = frame x / 64) in a row.
#[inline(always)]
pub fn word_key(row_key: u64, wx: i64) -> u64 {
    wymix(row_key ^ (wx as u64), 0xe703_7ed1_a0b4_28db)
}

/// Per-event salts of a word key. The three events' hash inputs differ from each
/// other and from every other lane group's (a unit test checks all 48 per key
/// half are distinct), so no two lanes of a word share a draw.
const SALT: [u64; 3] = [0x2d35_8dcc_aa6c_78a5, 0x8bb8_4b93_962e_acc9, 0x4b33_a62e_d433_d4a3];

/// Key of one event (hum, act, ext) of a word: the word key with the event's salt.
#[inline(always)]
pub fn event_key(word_key: u64, draw: Draw) -> u64 {
    word_key ^ SALT[draw as usize - 1]
}

/// The high byte of lane `bit`'s draw.
#[inline]
pub fn high_byte(word_key: u64, bit: u32) -> u8 {
    let i = (bit / 4) as usize;
    let half = if i < 8 {
        word_key as u32
    } else {
        (word_key >> 32) as u32
    };
    (lowbias32(half ^ LANE[i]) >> (8 * (bit % 4))) as u8
}

/// The low byte of lane `bit`'s draw (needed only when the high byte ties).
#[inline]
pub fn low_byte(word_key: u64, bit: u32) -> u8 {
    let k = wymix(word_key ^ 0x8ebc_6af0_9c88_c6e3, 0x5899_65cc_7537_4cc3);
    (lowbias32((k as u32) ^ bit.wrapping_mul(0x9e37_79b9) ^ (k >> 32) as u32) >> 24) as u8
}

/// Whether a single cell's event with threshold `q` (0..=65536) fires.
#[inline]
pub fn fires(word_key: u64, bit: u32, q: u32) -> bool {
    if q >= 65536 {
        return true;
    }
    let (hi, lo) = ((q >> 8) as u8, q as u8);
    let r = high_byte(word_key, bit);
    r < hi || (r == hi && low_byte(word_key, bit) < lo)
}

/// The thresholds of one event for the 64 cells of a word in a per-word
/// floating form: lane b's threshold is `m[b] << (8 − shift)` (so the high byte
/// is `m[b] >> shift` and the low byte `m[b] << (8 − shift)`), with `shift` as
/// large as the word's largest threshold allows. Everything a draw reads is in
/// these 64 bytes, so a tie never waits for memory. Against 16-bit fixed point
/// a lane keeps at least 8 significant bits relative to the largest threshold
/// of its word, and every threshold below 1/256 stays exact.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(64))]
pub struct Thresholds {
    pub m: [u8; 64],
}

/// The drives of one word: the three events' thresholds and masks. A lane with
/// q = 65536 is in `always`; a lane whose threshold is 0 is not in `live`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(64))]
pub struct WordDrive {
    pub t: [Thresholds; 3],
    pub always: [u64; 3],
    pub live: [u64; 3],
    pub shift: [u8; 3],
}

impl WordDrive {
    /// From the 16-bit thresholds q (0..=65536) of the three events (hum, act, ext).
    pub fn new(q: [&[u32; 64]; 3]) -> WordDrive {
        let mut d = WordDrive {
            t: [Thresholds { m: [0; 64] }; 3],
            always: [0; 3],
            live: [0; 3],
            shift: [0; 3],
        };
        for (e, q) in q.iter().enumerate() {
            let (m, shift, always, live) = event_thresholds(q);
            d.t[e].m = m;
            d.shift[e] = shift;
            d.always[e] = always;
            d.live[e] = live;
        }
        d
    }

    /// The 16-bit threshold lane `bit` of event `e` is drawn against (0..=65536).
    pub fn q(&self, e: usize, bit: u32) -> u32 {
        if (self.always[e] >> bit) & 1 == 1 {
            65536
        } else {
            (self.t[e].m[bit as usize] as u32) << (8 - self.shift[e])
        }
    }
}

/// One event's (mantissas, shift, always, live) from 16-bit thresholds.
#[inline]
fn event_thresholds(q: &[u32; 64]) -> ([u8; 64], u8, u64, u64) {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    {
        // SAFETY: the crate is built for x86-64-v3 (.cargo/config.toml), so AVX2 is present.
        unsafe { event_thresholds_avx2(q) }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
    {
        event_thresholds_scalar(q)
    }
}

/// The plain form of [`event_thresholds`]: one lane at a time.
pub fn event_thresholds_scalar(q: &[u32; 64]) -> ([u8; 64], u8, u64, u64) {
    let max = q.iter().map(|&v| if v < 65536 { v } else { 0 }).fold(0, u32::max);
    // The largest shift (most low bits kept) whose mantissas still fit in a byte.
    let shift = 16u32.saturating_sub(32 - max.leading_zeros()).min(8);
    let step = 8 - shift;
    let mut m = [0u8; 64];
    let (mut always, mut live) = (0u64, 0u64);
    for (b, &v) in q.iter().enumerate() {
        if v >= 65536 {
            always |= 1 << b;
        } else {
            m[b] = ((v + ((1 << step) >> 1)) >> step).min(255) as u8;
            live |= u64::from(m[b] > 0) << b;
        }
    }
    (m, shift as u8, always, live)
}

/// [`event_thresholds`] with AVX2, 8 lanes per vector. Drives are built for every
/// word of every run, so this conversion is on the path of every cold tile.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
#[target_feature(enable = "avx2")]
unsafe fn event_thresholds_avx2(q: &[u32; 64]) -> ([u8; 64], u8, u64, u64) {
    use std::arch::x86_64::*;
    let v: [__m256i; 8] = std::array::from_fn(|i| unsafe { _mm256_loadu_si256(q.as_ptr().add(8 * i).cast()) });
    let limit = _mm256_set1_epi32(65535);
    // Lanes at q = 65536 (or above): always fire, mantissa 0.
    let over: [__m256i; 8] = v.map(|x| _mm256_cmpgt_epi32(_mm256_min_epu32(x, _mm256_set1_epi32(65536)), limit));
    let kept: [__m256i; 8] = std::array::from_fn(|i| _mm256_andnot_si256(over[i], v[i]));
    let mut mx = kept[0];
    for k in &kept[1..] {
        mx = _mm256_max_epu32(mx, *k);
    }
    let mut lanes = [0u32; 8];
    unsafe { _mm256_storeu_si256(lanes.as_mut_ptr().cast(), mx) };
    let max = lanes.iter().fold(0, |a, &b| a.max(b));
    let shift = 16u32.saturating_sub(32 - max.leading_zeros()).min(8);
    let step = 8 - shift;
    let count = _mm_cvtsi32_si128(step as i32);
    let half = _mm256_set1_epi32(((1u32 << step) >> 1) as i32);
    let cap = _mm256_set1_epi32(255);
    let mant: [__m256i; 8] = kept.map(|k| _mm256_min_epu32(_mm256_srl_epi32(_mm256_add_epi32(k, half), count), cap));
    // u32 → u8 in lane order: packs work within 128-bit halves, so fix the order after.
    let w01 = _mm256_packus_epi32(mant[0], mant[1]);
    let w23 = _mm256_packus_epi32(mant[2], mant[3]);
    let w45 = _mm256_packus_epi32(mant[4], mant[5]);
    let w67 = _mm256_packus_epi32(mant[6], mant[7]);
    let b0 = _mm256_packus_epi16(w01, w23);
    let b1 = _mm256_packus_epi16(w45, w67);
    // After the two packs, 32-bit group g of a 256-bit result holds lanes in the order
    // [0, 2, 4, 6, 1, 3, 5, 7] of its four source vectors' halves.
    let order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let b0 = _mm256_permutevar8x32_epi32(b0, order);
    let b1 = _mm256_permutevar8x32_epi32(b1, order);
    let mut m = [0u8; 64];
    unsafe {
        _mm256_storeu_si256(m.as_mut_ptr().cast(), b0);
        _mm256_storeu_si256(m.as_mut_ptr().add(32).cast(), b1);
    }
    let mut always = 0u64;
    for (i, o) in over.iter().enumerate() {
        always |= (_mm256_movemask_ps(_mm256_castsi256_ps(*o)) as u32 as u64) << (8 * i);
    }
    let zero = _mm256_setzero_si256();
    let z0 = _mm256_movemask_epi8(_mm256_cmpeq_epi8(b0, zero)) as u32 as u64;
    let z1 = _mm256_movemask_epi8(_mm256_cmpeq_epi8(b1, zero)) as u32 as u64;
    let live = !(z0 | (z1 << 32));
    (m, shift as u8, always, live)
}

/// Lanes of one word and event whose high bytes tied, to be decided by their low bytes.
#[derive(Clone, Copy, Debug, Default)]
pub struct Tie {
    pub lanes: u64,
    pub key: u64,
    pub e: u8,
}

impl Tie {
    /// The lanes among `self.lanes` that fire.
    #[inline]
    pub fn resolve(&self, d: &WordDrive) -> u64 {
        let (e, shift) = (self.e as usize, d.shift[self.e as usize] as u32);
        let mut lanes = self.lanes;
        let mut fired = 0;
        while lanes != 0 {
            let b = lanes.trailing_zeros();
            lanes &= lanes - 1;
            let lo = ((d.t[e].m[b as usize] as u32) << (8 - shift)) as u8;
            fired |= u64::from(low_byte(self.key, b) < lo) << b;
        }
        fired
    }
}

/// The part of a 64-lane Bernoulli draw decided by the high bytes: the lanes that fire, and
/// the lanes left to [`Tie::resolve`] (1 in 256 of the open ones). Kept apart so
/// the kernel can decide the rare ties after a row instead of branching per word.
#[inline(always)]
pub fn bernoulli_high(d: &WordDrive, e: usize, word_key: u64, care: u64) -> (u64, Tie) {
    let care = care & (d.live[e] | d.always[e]);
    let fired = d.always[e] & care;
    let open = care & !d.always[e];
    if open == 0 {
        return (fired, Tie::default());
    }
    let key = word_key ^ SALT[e];
    let (below, ties) = compare_high(&d.t[e], d.shift[e] as u32, key);
    let tie = Tie {
        lanes: ties & open,
        key,
        e: e as u8,
    };
    (fired | (below & open), tie)
}

/// For every lane: (high byte of the draw < high byte of the threshold, the two are equal).
#[inline(always)]
pub fn compare_high(t: &Thresholds, shift: u32, key: u64) -> (u64, u64) {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    {
        // SAFETY: the crate is built for x86-64-v3 (.cargo/config.toml), so AVX2 is
        // present; `Thresholds` is 64 bytes, read as two unaligned 32-byte vectors.
        unsafe { compare_high_avx2(t, shift, key) }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
    {
        compare_high_scalar(t, shift, key)
    }
}

/// The plain form of [`compare_high`]: one lane at a time.
pub fn compare_high_scalar(t: &Thresholds, shift: u32, key: u64) -> (u64, u64) {
    let (mut below, mut ties) = (0u64, 0u64);
    for b in 0..64u32 {
        let r = high_byte(key, b);
        let q = (t.m[b as usize] as u32 >> shift) as u8;
        below |= u64::from(r < q) << b;
        ties |= u64::from(r == q) << b;
    }
    (below, ties)
}

#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
#[inline(always)]
unsafe fn compare_high_avx2(t: &Thresholds, shift: u32, key: u64) -> (u64, u64) {
    use std::arch::x86_64::*;
    // SAFETY (whole body): AVX2 is enabled for the crate; loads stay inside `t` and `LANE`.
    unsafe {
        let hash = |half: u32, consts: *const u32| -> __m256i {
            let mut x = _mm256_xor_si256(_mm256_set1_epi32(half as i32), _mm256_loadu_si256(consts.cast()));
            x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 16));
            x = _mm256_mullo_epi32(x, _mm256_set1_epi32(0x7feb_352d));
            x = _mm256_xor_si256(x, _mm256_srli_epi32(x, 15));
            x = _mm256_mullo_epi32(x, _mm256_set1_epi32(0x846c_a68bu32 as i32));
            _mm256_xor_si256(x, _mm256_srli_epi32(x, 16))
        };
        let r0 = hash(key as u32, LANE.as_ptr());
        let r1 = hash((key >> 32) as u32, LANE.as_ptr().add(8));
        // High bytes m >> shift: a 16-bit shift, then the bits that crossed from the
        // neighbouring byte cleared.
        let count = _mm_cvtsi32_si128(shift as i32);
        let keep = _mm256_set1_epi8((0xffu32 >> shift) as u8 as i8);
        let high = |p: *const u8| _mm256_and_si256(_mm256_srl_epi16(_mm256_loadu_si256(p.cast()), count), keep);
        let q0 = high(t.m.as_ptr());
        let q1 = high(t.m.as_ptr().add(32));
        // r >= q ⇔ max(r, q) = r (unsigned bytes).
        let ge0 = _mm256_movemask_epi8(_mm256_cmpeq_epi8(_mm256_max_epu8(r0, q0), r0)) as u32 as u64;
        let ge1 = _mm256_movemask_epi8(_mm256_cmpeq_epi8(_mm256_max_epu8(r1, q1), r1)) as u32 as u64;
        let eq0 = _mm256_movemask_epi8(_mm256_cmpeq_epi8(r0, q0)) as u32 as u64;
        let eq1 = _mm256_movemask_epi8(_mm256_cmpeq_epi8(r1, q1)) as u32 as u64;
        (!(ge0 | (ge1 << 32)), eq0 | (eq1 << 32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 64 Bernoulli bits of event `e` at once, decided for the lanes in `care`
    /// (lanes outside it come back 0; the caller combines the result so that they
    /// do not matter). No hash is made when no lane in `care` can fire.
    fn bernoulli(d: &WordDrive, e: usize, word_key: u64, care: u64) -> u64 {
        let (fired, tie) = bernoulli_high(d, e, word_key, care);
        fired | tie.resolve(d)
    }

    fn random_q(s: &mut u64) -> [u32; 64] {
        let mut q = [0u32; 64];
        for v in q.iter_mut() {
            *s = mix64(*s);
            *v = match *s % 6 {
                0 => 0,
                1 => 65536,
                2 => (*s >> 20) as u32 % 300,
                _ => (*s >> 20) as u32 % 65537,
            };
        }
        q
    }

    #[test]
    fn packed_bernoulli_equals_per_lane_comparison() {
        let mut s = 12345u64;
        for _ in 0..2000 {
            let qs = [random_q(&mut s), random_q(&mut s), random_q(&mut s)];
            let d = WordDrive::new([&qs[0], &qs[1], &qs[2]]);
            let (rk, wx) = (mix64(s ^ 99), (s % 1000) as i64 - 500);
            let wk = word_key(rk, wx);
            let care = mix64(s ^ 7) | if s % 3 == 0 { !0 } else { 0 };
            for e in 0..3 {
                let packed = bernoulli(&d, e, wk, care);
                let key = event_key(wk, [Draw::Humidity, Draw::Activation, Draw::Extinction][e]);
                for b in 0..64 {
                    let want = (care >> b) & 1 == 1 && fires(key, b, d.q(e, b));
                    assert_eq!((packed >> b) & 1 == 1, want, "lane {b} q {}", d.q(e, b));
                }
            }
        }
    }

    #[test]
    fn compare_high_equals_its_scalar_form() {
        let mut s = 99u64;
        for _ in 0..5000 {
            s = mix64(s);
            let mut t = Thresholds { m: [0; 64] };
            for (b, v) in t.m.iter_mut().enumerate() {
                *v = (mix64(s ^ b as u64) >> (s % 50)) as u8;
            }
            let shift = (s % 9) as u32;
            assert_eq!(compare_high(&t, shift, s), compare_high_scalar(&t, shift, s));
        }
    }

    #[test]
    fn event_thresholds_equal_their_scalar_form() {
        let mut s = 77u64;
        for _ in 0..3000 {
            let mut q = random_q(&mut s);
            // Words whose largest threshold sits at every bit length.
            let top = 1 + (mix64(s) % 17) as u32;
            for v in q.iter_mut() {
                if *v < 65536 {
                    *v %= 1 << top.min(16);
                }
            }
            assert_eq!(event_thresholds(&q), event_thresholds_scalar(&q), "{q:?}");
        }
    }

    #[test]
    fn thresholds_keep_eight_bits_relative_to_the_word_maximum() {
        let mut s = 5u64;
        for _ in 0..3000 {
            let q = random_q(&mut s);
            let d = WordDrive::new([&q, &q, &q]);
            let max = q.iter().filter(|&&v| v < 65536).fold(0, |a, &v| a.max(v));
            for b in 0..64u32 {
                let (want, got) = (q[b as usize], d.q(0, b));
                if want >= 65536 || max < 256 {
                    assert_eq!(got, want, "exact below 1/256 and at 1");
                } else {
                    // Half a unit of the word's scale, the scale being at most max / 128.
                    let unit = 1u32 << (8 - d.shift[0]);
                    assert!(unit <= max.div_ceil(128).next_power_of_two(), "unit {unit} max {max}");
                    assert!(
                        got.abs_diff(want) <= unit / 2 || (got == 255 * unit && want > got),
                        "q {want} -> {got}"
                    );
                }
            }
        }
    }

    /// Runs 640k draws through `fires` for threshold q and checks the rate within
    /// 5 standard deviations.
    fn check_rate(q: u32) {
        let n = 10_000u64;
        let mut count = 0u64;
        for w in 0..n {
            let key = event_key(word_key(row_key(step_key(7, 3, 5), 11), w as i64), Draw::Activation);
            count += (0..64).filter(|&b| fires(key, b, q)).count() as u64;
        }
        let trials = (n * 64) as f64;
        let qp = q as f64 / 65536.0;
        let sd = (trials * qp * (1.0 - qp)).sqrt().max(1.0);
        assert!(
            (count as f64 - trials * qp).abs() < 5.0 * sd,
            "q={q} got {count} want {}",
            trials * qp
        );
    }

    #[test]
    fn rate_matches_probability() {
        // Large, small (ties of the high byte decide), below one high-byte step, and exact bytes.
        for q in [6554, 66, 200, 1, 256, 32768, 65535] {
            check_rate(q);
        }
    }

    #[test]
    fn no_two_lane_groups_of_a_word_share_a_hash_input() {
        for (half, lanes) in [(0u32, 0..8), (32, 8..16)] {
            let mut inputs: Vec<u32> = SALT
                .iter()
                .flat_map(|s| LANE[lanes.clone()].iter().map(move |k| k ^ (s >> half) as u32))
                .collect();
            inputs.sort_unstable();
            inputs.dedup();
            assert_eq!(inputs.len(), 24);
        }
    }

    #[test]
    fn lanes_words_and_steps_are_uncorrelated() {
        // At p = 1/2 the 64 lanes of a word, a word and its neighbour, and a step and
        // the next must agree about half the time; a shared or shifted stream would not.
        let q = 32768;
        let n = 20_000i64;
        let (mut same_lane, mut same_word, mut same_step, mut same_event, mut pairs) = (0u64, 0u64, 0u64, 0u64, 0u64);
        for w in 0..n {
            let k0 = event_key(word_key(row_key(step_key(3, 0, 100), 5), w), Draw::Humidity);
            let k1 = event_key(word_key(row_key(step_key(3, 0, 100), 5), w + 1), Draw::Humidity);
            let k2 = event_key(word_key(row_key(step_key(3, 0, 101), 5), w), Draw::Humidity);
            for b in 0..64u32 {
                let f = fires(k0, b, q);
                same_lane += u64::from(f == fires(k0, (b + 1) % 64, q));
                same_word += u64::from(f == fires(k1, b, q));
                same_step += u64::from(f == fires(k2, b, q));
                same_event += u64::from(f == fires(k0 ^ SALT[0] ^ SALT[2], b, q));
                pairs += 1;
            }
        }
        let sd = (pairs as f64 * 0.25).sqrt();
        for (name, c) in [
            ("lane", same_lane),
            ("word", same_word),
            ("step", same_step),
            ("event", same_event),
        ] {
            assert!(
                (c as f64 - pairs as f64 / 2.0).abs() < 5.0 * sd,
                "{name}: {c} of {pairs}"
            );
        }
    }
}
