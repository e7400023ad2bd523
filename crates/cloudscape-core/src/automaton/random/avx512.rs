//! The AVX-512 + VAES form of the draws: per step, the round keys and the
//! events' counter bases in vectors; per word, 2 vectors of 4 blocks per event.

use std::arch::x86_64::*;

use super::{ROUNDS, StepKeys, Thresholds, counter};

/// One step's keys in vectors: the rounds' keys, and per event the counters
/// of its 8 blocks with word 0 and row 0, XOR-ed with the first key.
#[derive(Clone, Copy)]
pub struct Keys {
    k: [__m512i; ROUNDS],
    base: [[__m512i; 2]; 3],
}

/// # Safety
/// The CPU must have AVX-512 F and BW and VAES ([`super::DrawBackend::Avx512`]).
#[target_feature(enable = "avx512f,avx512bw,vaes")]
pub unsafe fn keys(keys: &StepKeys) -> Keys {
    let four = |v: [[u64; 2]; 4]| {
        _mm512_set_epi64(
            v[3][1] as i64,
            v[3][0] as i64,
            v[2][1] as i64,
            v[2][0] as i64,
            v[1][1] as i64,
            v[1][0] as i64,
            v[0][1] as i64,
            v[0][0] as i64,
        )
    };
    let k = std::array::from_fn(|i| four([keys.k[i + 1]; 4]));
    let base = std::array::from_fn(|e| {
        std::array::from_fn(|h| four(std::array::from_fn(|g| keys.whiten(counter(0, 0, e, 4 * h + g)))))
    });
    Keys { k, base }
}

/// The (word, row) part of the counters of a row's words: the row in every
/// block's high half, ready for [`word`] to put the word in the low halves.
/// (The row's bits and the event and block bits of [`counter`] do not
/// overlap, so OR is XOR.)
///
/// # Safety
/// As [`keys`].
#[target_feature(enable = "avx512f,avx512bw,vaes")]
#[inline]
pub unsafe fn row(y: i64) -> __m512i {
    _mm512_set1_epi64(counter(y, 0, 0, 0)[1] as i64)
}

/// The counters of word `wx` in the row made by [`row`]: the word index in the
/// low half of every block.
///
/// # Safety
/// As [`keys`].
#[target_feature(enable = "avx512f,avx512bw,vaes")]
#[inline]
pub unsafe fn word(row: __m512i, wx: i64) -> __m512i {
    _mm512_mask_set1_epi64(row, 0x55, wx)
}

/// [`super::below_portable`] for the word whose counters [`word`] made.
///
/// # Safety
/// As [`keys`].
#[target_feature(enable = "avx512f,avx512bw,vaes")]
#[inline]
pub unsafe fn below(keys: &Keys, word: __m512i, e: usize, t: &Thresholds, shift: u8) -> u64 {
    let mut x0 = _mm512_xor_si512(keys.base[e][0], word);
    let mut x1 = _mm512_xor_si512(keys.base[e][1], word);
    for k in &keys.k {
        x0 = _mm512_aesenc_epi128(x0, *k);
        x1 = _mm512_aesenc_epi128(x1, *k);
    }
    // SAFETY: `Thresholds` is 64 bytes.
    let m = unsafe { _mm512_loadu_si512(t.m.as_ptr().cast()) };
    let count = _mm_cvtsi32_si128(8 - shift as i32);
    let q0 = _mm512_sll_epi16(_mm512_cvtepu8_epi16(_mm512_castsi512_si256(m)), count);
    let q1 = _mm512_sll_epi16(_mm512_cvtepu8_epi16(_mm512_extracti64x4_epi64::<1>(m)), count);
    let b0 = _mm512_cmplt_epu16_mask(x0, q0) as u64;
    let b1 = _mm512_cmplt_epu16_mask(x1, q1) as u64;
    b0 | (b1 << 32)
}
