//! Counter-based randomness: every draw is a function of (seed, layer, level,
//! step, row, word, event, lane); there is no generator state, so any machine
//! can compute any cell at any step.
//!
//! A Bernoulli event with probability `q / 65536` fires for a cell when its
//! 16-bit draw is below `q`. The draws are ARS-5 (Salmon et al. 2011, "Parallel
//! random numbers: as easy as 1, 2, 3"; Intel MKL ships it as its ARS5
//! generator): five AES rounds over a 128-bit counter, with round keys stepped by
//! Weyl constants from a key of (layer stream, level, step). The counter is
//! (word index, row, event, block): one 128-bit block gives 8 lanes' 16-bit
//! draws, so a 64-cell word takes 8 blocks per event. With AVX-512 and VAES one
//! instruction runs a round on 4 blocks, so the three events of a word are 6
//! vectors × 5 rounds, and the 64 lanes' comparisons are two mask compares per
//! event. There are no branches and no ties: every threshold is compared in
//! full.
//!
//! One difference from ARS-5 as published: the last round is a full AES round
//! (AESENC) where ARS-5 leaves out MixColumns (AESENCLAST). MixColumns is an
//! invertible linear map of each 32-bit column, so it changes no distribution,
//! and the full round is what `aes::hazmat::cipher_round` offers.
//!
//! Two implementations give the same bits: AVX-512 + VAES (detected at run
//! time) and the portable form through `aes::hazmat` (AES-NI where the CPU has
//! it, the crate's software AES otherwise). The unit tests hold them equal, and
//! the naive kernel draws one lane at a time through [`draw`]. We build on AES
//! rather than a generator crate because the bits are part of the output
//! contract (ALGORITHM_VERSION): AES is fixed by FIPS-197, a generator crate's
//! stream is not.

use std::sync::OnceLock;

use aes::Block;
use aes::hazmat::{cipher_round, cipher_round_par};

use crate::fields::noise::mix64;

/// AES rounds per block (ARS-5).
pub const ROUNDS: usize = 5;

/// Which random event; the value is the event's index in a [`WordDrive`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Draw {
    Humidity = 0,
    Activation = 1,
    Extinction = 2,
}

/// The round keys of one (layer stream, level, step): `k[0]` is XOR-ed into the
/// counter, `k[1..]` are the rounds' keys, each the previous plus ARS's Weyl
/// constants (per 64-bit half).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepKeys {
    pub k: [[u64; 2]; ROUNDS + 1],
}

impl StepKeys {
    pub fn new(stream: u64, level: u32, step: i64) -> StepKeys {
        let a = mix64(stream ^ ((level as u64) << 48));
        let lo = mix64(a ^ (step as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f));
        let hi = mix64(lo ^ 0x6a09_e667_f3bc_c909);
        let mut k = [[lo, hi]; ROUNDS + 1];
        for i in 1..=ROUNDS {
            k[i] = [
                k[i - 1][0].wrapping_add(0x9e37_79b9_7f4a_7c15),
                k[i - 1][1].wrapping_add(0xbb67_ae85_84ca_a73b),
            ];
        }
        StepKeys { k }
    }

    /// A counter XOR-ed with the first key: the state the rounds start from.
    #[inline]
    pub fn whiten(&self, ctr: [u64; 2]) -> [u64; 2] {
        [ctr[0] ^ self.k[0][0], ctr[1] ^ self.k[0][1]]
    }
}

/// The counter of block `g` (lanes 8g..8g+7) of event `e` for word `wx` of frame
/// row `y`: the word index in the low half, the row above the event and block
/// indices in the high half. Distinct for every (y, wx, e, g) with |y| < 2^58.
#[inline]
pub fn counter(y: i64, wx: i64, e: usize, g: usize) -> [u64; 2] {
    [wx as u64, ((y as u64) << 5) | ((e as u64) << 3) | g as u64]
}

fn block(v: [u64; 2]) -> Block {
    let mut b = Block::default();
    b[..8].copy_from_slice(&v[0].to_le_bytes());
    b[8..].copy_from_slice(&v[1].to_le_bytes());
    b
}

/// ARS-5 of one counter, through the portable round function.
pub fn ars5(keys: &StepKeys, ctr: [u64; 2]) -> [u8; 16] {
    let mut b = block(keys.whiten(ctr));
    for k in &keys.k[1..] {
        cipher_round(&mut b, &block(*k));
    }
    b.into()
}

/// Lane `bit`'s 16-bit draw for event `e` of word `wx` in frame row `y`: bytes
/// 2j, 2j+1 (little-endian) of block `bit / 8`, j = `bit % 8`.
pub fn draw(keys: &StepKeys, y: i64, wx: i64, e: Draw, bit: u32) -> u16 {
    let b = ars5(keys, counter(y, wx, e as usize, bit as usize / 8));
    let j = 2 * (bit as usize % 8);
    u16::from_le_bytes([b[j], b[j + 1]])
}

/// Whether one cell's event with threshold `q` (0..=65536) fires.
pub fn fires(keys: &StepKeys, y: i64, wx: i64, e: Draw, bit: u32, q: u32) -> bool {
    q >= 65536 || u32::from(draw(keys, y, wx, e, bit)) < q
}

/// The thresholds of one event for the 64 cells of a word in a per-word
/// floating form: lane b's threshold is `m[b] << (8 − shift)`, with `shift` as
/// large as the word's largest threshold allows, so an event's thresholds fill
/// one 64-byte line (drives are read on every step of a run, and their size is
/// what the kernel streams from memory). Against 16-bit fixed point a lane keeps
/// at least 8 significant bits relative to the largest threshold of its word,
/// and every threshold below 1/256 stays exact.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(64))]
pub struct Thresholds {
    pub m: [u8; 64],
}

/// The drives of one word: the three events' thresholds and masks. A lane with
/// q = 65536 is in `always` (its mantissa is 0); a lane whose mantissa is not 0
/// is in `live`. A word's draws for an event are made only if a lane that could
/// change the result is live. Levels hold their words as [`StochasticDrives`];
/// this is one word of them on its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WordDrive {
    pub t: [Thresholds; 3],
    pub always: [u64; 3],
    pub live: [u64; 3],
    pub shift: [u8; 3],
}

impl WordDrive {
    /// From the 16-bit thresholds q (0..=65536) of the three events (hum, act, ext).
    pub fn new(q: [&[u32; 64]; 3]) -> WordDrive {
        let mut d = StochasticDrives::with_capacity(1);
        d.push(q);
        d.word(0)
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

/// A word's shifts and live lanes, and where its `always` masks are: 32 bytes,
/// two words a cache line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[repr(C, align(32))]
pub struct Head {
    pub shift: [u8; 3],
    /// The word's entry in the `always` side table: 0, the shared entry of no
    /// masks, unless some lane of the word always fires.
    pub slot: u32,
    /// Each event's lanes whose mantissa is not 0.
    pub live: [u64; 3],
}

const _: () = assert!(std::mem::size_of::<Head>() == 32);

/// One level's Dobashi drives, word by word, stored as the kernel streams them:
/// the mantissas in one array (192 bytes a word, whole cache lines) and each
/// word's [`Head`] in another (32 bytes a word). The `always` masks, which only
/// probabilities that quantize to 1 make, are kept on the side for the words
/// that have them.
/// Drives are read on every step of a run, and the kernel's time depends on
/// their size and on how many instructions stand between a word's loads and its
/// branches (BENCHMARKS.md "Automaton", ninth and tenth sessions):
/// - against the earlier 256 bytes a word in one record, 200 bytes (live lanes
///   found from the mantissas, `vptestmb`; a flag before the `always` load) took
///   0.84–0.87 of the time on the Intel Xeon machine, where the stream came from
///   memory, but 1.12 on the AMD EPYC machine, where it fits in L3;
/// - on the AMD machine, 224 bytes (the live lanes stored in the head, and no
///   `always` masks read in a level that has none) bring it back to 1.01 of the
///   256-byte records (both forms alternating in one process, one and two
///   threads).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StochasticDrives {
    mantissas: Vec<[Thresholds; 3]>,
    heads: Vec<Head>,
    always: Vec<[u64; 3]>,
}

impl Default for StochasticDrives {
    fn default() -> StochasticDrives {
        StochasticDrives::with_capacity(0)
    }
}

impl StochasticDrives {
    pub fn with_capacity(words: usize) -> StochasticDrives {
        StochasticDrives {
            mantissas: Vec::with_capacity(words),
            heads: Vec::with_capacity(words),
            // Slot 0: the masks of every word with no lane that always fires, so a
            // word's masks are one load with no flag to test first.
            always: vec![[0; 3]],
        }
    }

    pub fn len(&self) -> usize {
        self.heads.len()
    }

    pub fn is_empty(&self) -> bool {
        self.heads.is_empty()
    }

    /// Keeps the first `words` words (and only their `always` masks).
    pub fn truncate(&mut self, words: usize) {
        self.mantissas.truncate(words);
        self.heads.truncate(words);
        // Slots are handed out in word order, so the kept words' masks come first.
        let kept = self.heads.iter().map(|h| h.slot as usize).max().unwrap_or(0);
        self.always.truncate(kept + 1);
    }

    /// Every word's three events' mantissas.
    #[inline]
    pub fn mantissas(&self) -> &[[Thresholds; 3]] {
        &self.mantissas
    }

    /// Every word's head.
    #[inline]
    pub fn heads(&self) -> &[Head] {
        &self.heads
    }

    /// Whether some word has lanes that always fire.
    pub fn has_always(&self) -> bool {
        self.always.len() > 1
    }

    /// The `always` masks of the word with `head`.
    #[inline]
    pub fn always(&self, head: Head) -> [u64; 3] {
        self.always[head.slot as usize]
    }

    /// Word `i` on its own.
    pub fn word(&self, i: usize) -> WordDrive {
        let (t, head) = (self.mantissas[i], self.heads[i]);
        WordDrive {
            t,
            always: self.always(head),
            live: head.live,
            shift: head.shift,
        }
    }

    /// Appends a word from the 16-bit thresholds q (0..=65536) of the three events
    /// (hum, act, ext).
    #[inline]
    pub fn push(&mut self, q: [&[u32; 64]; 3]) {
        match crate::fields::noise::Backend::detect() {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `detect` found AVX-512 F (and DQ) on this CPU.
            crate::fields::noise::Backend::Avx512 => unsafe { self.push_avx512(q) },
            _ => self.push_baseline(q),
        }
    }

    /// [`StochasticDrives::push`] in the baseline build's form (AVX2 on x86-64-v3).
    #[inline]
    pub fn push_baseline(&mut self, q: [&[u32; 64]; 3]) {
        self.push_with(q, event_thresholds);
    }

    /// [`StochasticDrives::push`] with AVX-512: inlined into callers compiled
    /// with AVX-512 (`run`'s drive conversion), where the three events'
    /// dependency chains (load, maximum, shift, narrowing) overlap.
    ///
    /// # Safety
    /// The CPU must have AVX-512 F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[inline]
    pub unsafe fn push_avx512(&mut self, q: [&[u32; 64]; 3]) {
        // SAFETY: the caller's CPU has AVX-512 F.
        self.push_with(q, |q, m| unsafe { event_thresholds_avx512(q, m) });
    }

    /// Appends a word, each event set from its thresholds through `form` (one of
    /// the forms of [`event_thresholds`]). The mantissas are written where the
    /// kernel will read them: built on the stack, their narrow stores would be
    /// read back at once by the wide loads of the copy, which the CPU cannot
    /// forward (perf: that load took over half of the conversion's samples).
    #[inline(always)]
    fn push_with(&mut self, q: [&[u32; 64]; 3], form: impl Fn(&[u32; 64], &mut [u8; 64]) -> (u8, u64, u64)) {
        self.mantissas.push([Thresholds { m: [0; 64] }; 3]);
        let t = self.mantissas.last_mut().expect("just pushed");
        let mut head = Head::default();
        let mut always = [0u64; 3];
        for (e, q) in q.iter().enumerate() {
            (head.shift[e], always[e], head.live[e]) = form(q, &mut t[e].m);
        }
        if always != [0; 3] {
            head.slot = u32::try_from(self.always.len()).expect("fewer than 2^32 words");
            self.always.push(always);
        }
        self.heads.push(head);
    }
}

/// One event's mantissas (into `m`) and (shift, always, live) from 16-bit
/// thresholds, in the baseline build's form ([`StochasticDrives::push`] takes the
/// AVX-512 form where the CPU has it). The live lanes are the non-zero mantissas.
#[inline]
fn event_thresholds(q: &[u32; 64], m: &mut [u8; 64]) -> (u8, u64, u64) {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    {
        // SAFETY: the crate is built for x86-64-v3 (.cargo/config.toml), so AVX2 is present.
        unsafe { event_thresholds_avx2(q, m) }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
    {
        event_thresholds_scalar(q, m)
    }
}

/// The plain form of [`event_thresholds`]: one lane at a time.
pub fn event_thresholds_scalar(q: &[u32; 64], m: &mut [u8; 64]) -> (u8, u64, u64) {
    let max = q.iter().map(|&v| if v < 65536 { v } else { 0 }).fold(0, u32::max);
    // The largest shift (most low bits kept) whose mantissas still fit in a byte.
    let shift = 16u32.saturating_sub(32 - max.leading_zeros()).min(8);
    let step = 8 - shift;
    let (mut always, mut live) = (0u64, 0u64);
    for (b, &v) in q.iter().enumerate() {
        if v >= 65536 {
            always |= 1 << b;
            m[b] = 0;
        } else {
            m[b] = ((v + ((1 << step) >> 1)) >> step).min(255) as u8;
            live |= u64::from(m[b] > 0) << b;
        }
    }
    (shift as u8, always, live)
}

/// [`event_thresholds`] with AVX2, 8 lanes per vector. Drives are built for every
/// word of every run, so this conversion is on the path of every cold tile.
#[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
#[target_feature(enable = "avx2")]
unsafe fn event_thresholds_avx2(q: &[u32; 64], m: &mut [u8; 64]) -> (u8, u64, u64) {
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
    (shift as u8, always, !(z0 | (z1 << 32)))
}

/// [`event_thresholds`] with AVX-512, 16 lanes per vector: the lanes' maximum in
/// one reduction and the mantissas narrowed to bytes in lane order (`vpmovdb`).
/// Drive conversion is about a sixth of a cold tile.
///
/// # Safety
/// The CPU must have AVX-512 F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn event_thresholds_avx512(q: &[u32; 64], m: &mut [u8; 64]) -> (u8, u64, u64) {
    use std::arch::x86_64::*;
    // SAFETY: `q` is 64 lanes, four vectors of 16.
    let v: [__m512i; 4] = std::array::from_fn(|i| unsafe { _mm512_loadu_si512(q.as_ptr().add(16 * i).cast()) });
    // Lanes at q = 65536 (or above): always fire, mantissa 0.
    let over: [__mmask16; 4] = v.map(|x| _mm512_cmpge_epu32_mask(x, _mm512_set1_epi32(65536)));
    let kept: [__m512i; 4] = std::array::from_fn(|i| _mm512_maskz_mov_epi32(!over[i], v[i]));
    let max = _mm512_reduce_max_epu32(_mm512_max_epu32(
        _mm512_max_epu32(kept[0], kept[1]),
        _mm512_max_epu32(kept[2], kept[3]),
    ));
    let shift = 16u32.saturating_sub(32 - max.leading_zeros()).min(8);
    let step = 8 - shift;
    let count = _mm_cvtsi32_si128(step as i32);
    let half = _mm512_set1_epi32(((1u32 << step) >> 1) as i32);
    let cap = _mm512_set1_epi32(255);
    let (mut always, mut live) = (0u64, 0u64);
    for (i, k) in kept.iter().enumerate() {
        let mant = _mm512_min_epu32(_mm512_srl_epi32(_mm512_add_epi32(*k, half), count), cap);
        // SAFETY: 16 bytes at 16 i, within `m`.
        unsafe { _mm_storeu_si128(m.as_mut_ptr().add(16 * i).cast(), _mm512_cvtepi32_epi8(mant)) };
        always |= (over[i] as u64) << (16 * i);
        live |= (_mm512_test_epi32_mask(mant, mant) as u64) << (16 * i);
    }
    (shift as u8, always, live)
}

/// An implementation of the per-word draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// AVX-512 (F, BW) with VAES: four AES blocks per instruction.
    Avx512,
    /// `aes::hazmat`, eight blocks per call.
    Portable,
}

impl Backend {
    /// The fastest backend this CPU runs.
    pub fn detect() -> Backend {
        *Backend::available()
            .last()
            .expect("the portable backend is always there")
    }

    /// Every backend this CPU runs, slowest first (detected once).
    pub fn available() -> &'static [Backend] {
        static AVAILABLE: OnceLock<Vec<Backend>> = OnceLock::new();
        AVAILABLE.get_or_init(|| {
            let mut out = vec![Backend::Portable];
            #[cfg(target_arch = "x86_64")]
            if std::is_x86_feature_detected!("avx512f")
                && std::is_x86_feature_detected!("avx512bw")
                && std::is_x86_feature_detected!("vaes")
            {
                out.push(Backend::Avx512);
            }
            out
        })
    }
}

/// The lanes of one word whose draw for event `e` is below its threshold in
/// `t` (with `shift`; lanes in `always` are not included), one event at a time
/// through the portable round function.
pub fn below_portable(keys: &StepKeys, y: i64, wx: i64, e: usize, t: &Thresholds, shift: u8) -> u64 {
    let mut blocks: aes::Block8 = Default::default();
    for (g, b) in blocks.iter_mut().enumerate() {
        *b = block(keys.whiten(counter(y, wx, e, g)));
    }
    for k in &keys.k[1..] {
        let k = block(*k);
        cipher_round_par(&mut blocks, &[k; 8].into());
    }
    let step = 8 - shift as u32;
    let mut below = 0u64;
    for (b, &m) in t.m.iter().enumerate() {
        let blk = &blocks[b / 8];
        let r = u16::from_le_bytes([blk[2 * (b % 8)], blk[2 * (b % 8) + 1]]);
        below |= u64::from(u32::from(r) < (m as u32) << step) << b;
    }
    below
}

/// The AVX-512 + VAES form of the draws: per step, the round keys and the
/// events' counter bases in vectors; per word, 2 vectors of 4 blocks per event.
#[cfg(target_arch = "x86_64")]
pub mod avx512 {
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
    /// The CPU must have AVX-512 F and BW and VAES ([`super::Backend::Avx512`]).
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn ars5_is_aes_rounds_over_the_counter() {
        // An independent AES round (FIPS-197 steps written out here) against the crate's.
        fn xtime(b: u8) -> u8 {
            (b << 1) ^ if b & 0x80 != 0 { 0x1b } else { 0 }
        }
        fn sbox(x: u8) -> u8 {
            // Multiplicative inverse in GF(2^8) (x^254), then the affine map.
            let mul = |mut a: u8, mut b: u8| {
                let mut p = 0u8;
                while b != 0 {
                    if b & 1 != 0 {
                        p ^= a;
                    }
                    a = xtime(a);
                    b >>= 1;
                }
                p
            };
            let mut inv = 1u8;
            for _ in 0..254 {
                inv = mul(inv, x);
            }
            let inv = if x == 0 { 0 } else { inv };
            inv ^ inv.rotate_left(1) ^ inv.rotate_left(2) ^ inv.rotate_left(3) ^ inv.rotate_left(4) ^ 0x63
        }
        fn round(s: [u8; 16], k: [u8; 16]) -> [u8; 16] {
            // State byte (row r, column c) is s[r + 4c].
            let sub: Vec<u8> = s.iter().map(|&b| sbox(b)).collect();
            let mut sh = [0u8; 16];
            for c in 0..4 {
                for r in 0..4 {
                    sh[r + 4 * c] = sub[r + 4 * ((c + r) % 4)];
                }
            }
            let mut out = [0u8; 16];
            for c in 0..4 {
                let a = &sh[4 * c..4 * c + 4];
                for r in 0..4 {
                    let (a0, a1, a2, a3) = (a[r], a[(r + 1) % 4], a[(r + 2) % 4], a[(r + 3) % 4]);
                    out[r + 4 * c] = xtime(a0) ^ (xtime(a1) ^ a1) ^ a2 ^ a3 ^ k[r + 4 * c];
                }
            }
            out
        }
        assert_eq!(sbox(0x00), 0x63);
        assert_eq!(sbox(0x53), 0xed);
        let bytes = |v: [u64; 2]| -> [u8; 16] { block(v).into() };
        let mut s = 3u64;
        for _ in 0..50 {
            s = mix64(s);
            let keys = StepKeys::new(s, (s % 7) as u32, (s >> 8) as i64);
            let ctr = [mix64(s ^ 1), mix64(s ^ 2)];
            let mut st = bytes([ctr[0] ^ keys.k[0][0], ctr[1] ^ keys.k[0][1]]);
            for k in &keys.k[1..] {
                st = round(st, bytes(*k));
            }
            assert_eq!(ars5(&keys, ctr), st);
        }
    }

    #[test]
    fn word_draws_equal_lane_draws_on_every_backend() {
        let mut s = 12345u64;
        for _ in 0..300 {
            s = mix64(s);
            let keys = StepKeys::new(s, (s % 11) as u32, (s >> 3) as i64 - (1 << 40));
            let y = (mix64(s ^ 5) >> 20) as i64 - (1 << 43);
            let wx = (mix64(s ^ 6) >> 4) as i64;
            let d = WordDrive::new([&random_q(&mut s), &random_q(&mut s), &random_q(&mut s)]);
            for (e, draw_e) in [Draw::Humidity, Draw::Activation, Draw::Extinction]
                .into_iter()
                .enumerate()
            {
                let want: u64 = (0..64u32)
                    .filter(|&b| d.always[e] >> b & 1 == 0 && fires(&keys, y, wx, draw_e, b, d.q(e, b)))
                    .map(|b| 1u64 << b)
                    .sum();
                assert_eq!(below_portable(&keys, y, wx, e, &d.t[e], d.shift[e]), want);
                #[cfg(target_arch = "x86_64")]
                if Backend::available().contains(&Backend::Avx512) {
                    // SAFETY: the CPU has the features (just checked).
                    let got = unsafe {
                        avx512::below(
                            &avx512::keys(&keys),
                            avx512::word(avx512::row(y), wx),
                            e,
                            &d.t[e],
                            d.shift[e],
                        )
                    };
                    assert_eq!(got, want);
                }
            }
        }
    }

    /// One form of `event_thresholds` over a fixed q.
    type Form<'a> = &'a dyn Fn(&mut [u8; 64]) -> (u8, u64, u64);

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
            // Thresholds above 65536 (never made by `quantize`, but they must read
            // as "always", which a signed compare would get wrong at 2^31 and up).
            if mix64(s).is_multiple_of(4) {
                let b = (mix64(s ^ 1) % 64) as usize;
                q[b] = [65537, 1 << 31, u32::MAX][(mix64(s ^ 2) % 3) as usize];
            }
            // Every form writes into a buffer of garbage (so each must write all 64
            // bytes) and must give the scalar form's mantissas and masks.
            let mut want_m = [0x55; 64];
            let want = event_thresholds_scalar(&q, &mut want_m);
            // The live lanes are the non-zero mantissas.
            let non_zero = (0..64).fold(0u64, |l, b| l | (u64::from(want_m[b] != 0) << b));
            assert_eq!(want.2, non_zero, "{q:?}");
            let check = |name: &str, f: Form| {
                let mut m = [0xaa; 64];
                assert_eq!((f(&mut m), m), (want, want_m), "{name} {q:?}");
            };
            // The baseline form: AVX2 on an x86-64-v3 build.
            check("baseline", &|m| event_thresholds(&q, m));
            #[cfg(target_arch = "x86_64")]
            if crate::fields::noise::Backend::available().contains(&crate::fields::noise::Backend::Avx512) {
                // SAFETY: the CPU has AVX-512 F (just checked).
                check("AVX-512", &|m| unsafe { event_thresholds_avx512(&q, m) });
            }
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

    #[test]
    fn a_levels_words_keep_their_own_thresholds() {
        // Many words, some with lanes that always fire (kept on the side) and some
        // without: every word reads back as it does on its own, and its always
        // lanes as 65536, whichever words before it had some.
        let mut s = 9u64;
        let mut drives = StochasticDrives::default();
        let mut words = Vec::new();
        for i in 0..500 {
            let mut q = [random_q(&mut s), random_q(&mut s), random_q(&mut s)];
            if i % 3 != 0 {
                for v in q.iter_mut().flatten() {
                    *v = (*v).min(65535);
                }
            }
            drives.push(q.each_ref());
            words.push(q);
        }
        assert_eq!(drives.len(), words.len());
        for (i, q) in words.iter().enumerate() {
            let d = drives.word(i);
            assert_eq!(d, WordDrive::new(q.each_ref()), "word {i}");
            for (e, q) in q.iter().enumerate() {
                for b in 0..64u32 {
                    if q[b as usize] >= 65536 {
                        assert_eq!(d.q(e, b), 65536, "word {i} event {e} lane {b}");
                    }
                }
            }
        }
        // Cut at word 250 (its predecessor, 249, has always lanes): the side table
        // keeps the masks of the kept words only, and words pushed after the cut
        // still find theirs.
        drives.truncate(250);
        words.truncate(250);
        let with_always = words.iter().filter(|q| q.iter().flatten().any(|&v| v >= 65536)).count();
        assert_eq!(
            drives.always.len(),
            1 + with_always,
            "the shared entry and the kept words' masks"
        );
        for _ in 0..10 {
            let q = [random_q(&mut s), random_q(&mut s), random_q(&mut s)];
            drives.push(q.each_ref());
            words.push(q);
        }
        assert_eq!(drives.len(), 260);
        for (i, q) in words.iter().enumerate() {
            assert_eq!(drives.word(i), WordDrive::new(q.each_ref()), "word {i} after the cut");
        }
    }

    /// Runs 640k draws through `fires` for threshold q and checks the rate within
    /// 5 standard deviations.
    fn check_rate(q: u32) {
        let n = 10_000i64;
        let keys = StepKeys::new(7, 3, 5);
        let mut count = 0u64;
        for w in 0..n {
            count += (0..64).filter(|&b| fires(&keys, 11, w, Draw::Activation, b, q)).count() as u64;
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
        for q in [6554, 66, 200, 1, 256, 32768, 65535] {
            check_rate(q);
        }
    }

    #[test]
    fn draws_are_uniform_in_every_lane() {
        // 2^16 draws per lane position, histogram of the high byte: chi-square with
        // 255 degrees of freedom stays below its 1e-6 tail (about 386).
        let keys = StepKeys::new(11, 2, 9);
        for bit in [0u32, 1, 7, 8, 33, 63] {
            let mut hist = [0u32; 256];
            for w in 0..65536i64 {
                hist[(draw(&keys, w >> 8, w & 255, Draw::Humidity, bit) >> 8) as usize] += 1;
            }
            let exp = 256.0;
            let chi2: f64 = hist.iter().map(|&c| (c as f64 - exp).powi(2) / exp).sum();
            assert!(chi2 < 386.0, "lane {bit}: chi2 {chi2}");
        }
    }

    #[test]
    fn lanes_words_rows_steps_and_events_are_uncorrelated() {
        // At p = 1/2 a lane and its neighbours in lane, word, row, step and event
        // must agree about half the time; a shared or shifted stream would not.
        let q = 32768;
        let n = 4_000i64;
        let k0 = StepKeys::new(3, 0, 100);
        let k1 = StepKeys::new(3, 0, 101);
        let kl = StepKeys::new(3, 1, 100);
        let mut same = [0u64; 6];
        let mut pairs = 0u64;
        for w in 0..n {
            for b in 0..64u32 {
                let f = fires(&k0, 5, w, Draw::Humidity, b, q);
                let others = [
                    fires(&k0, 5, w, Draw::Humidity, (b + 1) % 64, q),
                    fires(&k0, 5, w + 1, Draw::Humidity, b, q),
                    fires(&k0, 6, w, Draw::Humidity, b, q),
                    fires(&k1, 5, w, Draw::Humidity, b, q),
                    fires(&k0, 5, w, Draw::Extinction, b, q),
                    fires(&kl, 5, w, Draw::Humidity, b, q),
                ];
                for (s, o) in same.iter_mut().zip(others) {
                    *s += u64::from(f == o);
                }
                pairs += 1;
            }
        }
        let sd = (pairs as f64 * 0.25).sqrt();
        for (name, c) in ["lane", "word", "row", "step", "event", "level"].iter().zip(same) {
            assert!(
                (c as f64 - pairs as f64 / 2.0).abs() < 5.0 * sd,
                "{name}: {c} of {pairs}"
            );
        }
    }

    #[test]
    fn counters_are_distinct() {
        let mut seen = std::collections::HashSet::new();
        for y in [-(1i64 << 57), -1, 0, 1, 1 << 40] {
            for wx in [i64::MIN, -1, 0, 1, i64::MAX] {
                for e in 0..3 {
                    for g in 0..8 {
                        assert!(seen.insert(counter(y, wx, e, g)));
                    }
                }
            }
        }
    }
}
