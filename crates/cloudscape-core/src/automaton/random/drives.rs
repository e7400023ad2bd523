//! The Dobashi drives of a level: per word, the three events' thresholds in a
//! per-word floating form, laid out as the kernel streams them.

use crate::cpu::Features;

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
    /// Lane b's mantissa: its threshold is `m[b] << (8 − shift)`.
    pub m: [u8; 64],
}

/// The drives of one word: the three events' thresholds and masks. A lane with
/// q = 65536 is in `always` (its mantissa is 0); a lane whose mantissa is not 0
/// is in `live`. A word's draws for an event are made only if a lane that could
/// change the result is live. Levels hold their words as [`StochasticDrives`];
/// this is one word of them on its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WordDrive {
    /// Each event's mantissas.
    pub t: [Thresholds; 3],
    /// Each event's lanes whose threshold is 65536 (they always fire).
    pub always: [u64; 3],
    /// Each event's lanes whose mantissa is not 0.
    pub live: [u64; 3],
    /// Each event's shift (see [`Thresholds`]).
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
    /// Each event's shift (see [`Thresholds`]).
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
///
/// Drives are read on every step of a run, so the kernel's time depends on their
/// size and on how many instructions stand between a word's loads and its
/// branches: the live lanes are stored in the head (rather than found from the
/// mantissas) so a word's branch waits on one load, and a level with no `always`
/// masks reads none (BENCHMARKS.md "Automaton" has the layouts measured).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StochasticDrives {
    mantissas: Vec<[Thresholds; 3]>,
    heads: Vec<Head>,
    pub(super) always: Vec<[u64; 3]>,
}

impl Default for StochasticDrives {
    fn default() -> StochasticDrives {
        StochasticDrives::with_capacity(0)
    }
}

impl StochasticDrives {
    /// Empty drives with room for `words` words.
    pub fn with_capacity(words: usize) -> StochasticDrives {
        StochasticDrives {
            mantissas: Vec::with_capacity(words),
            heads: Vec::with_capacity(words),
            // Slot 0: the masks of every word with no lane that always fires, so a
            // word's masks are one load with no flag to test first.
            always: vec![[0; 3]],
        }
    }

    /// The number of words.
    pub fn len(&self) -> usize {
        self.heads.len()
    }

    /// Whether there is no word.
    pub fn is_empty(&self) -> bool {
        self.heads.is_empty()
    }

    /// Bytes the drives hold.
    pub fn bytes(&self) -> usize {
        use std::mem::size_of;
        self.mantissas.capacity() * size_of::<[Thresholds; 3]>()
            + self.heads.capacity() * size_of::<Head>()
            + self.always.capacity() * size_of::<[u64; 3]>()
    }

    /// Keeps the first `words` words (and only their `always` masks).
    pub fn truncate(&mut self, words: usize) {
        self.mantissas.truncate(words);
        self.heads.truncate(words);
        // Slots are handed out in word order, so the kept words' masks come first.
        let kept = self.heads.iter().map(|h| h.slot as usize).max().unwrap_or(0);
        self.always.truncate(kept + 1);
    }

    /// The words of rows `rows` and word columns `words` of drives laid out `wpr`
    /// words a row (a level cropped to a smaller window of its own grid).
    pub fn crop(&self, wpr: usize, rows: std::ops::Range<usize>, words: std::ops::Range<usize>) -> StochasticDrives {
        let mut out = StochasticDrives::with_capacity(rows.len() * words.len());
        for r in rows {
            for w in words.clone() {
                let i = r * wpr + w;
                let mut head = self.heads[i];
                if head.slot != 0 {
                    head.slot = u32::try_from(out.always.len()).expect("fewer than 2^32 words");
                    out.always.push(self.always[self.heads[i].slot as usize]);
                }
                out.mantissas.push(self.mantissas[i]);
                out.heads.push(head);
            }
        }
        out
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
        #[cfg(target_arch = "x86_64")]
        if Features::get().avx512f {
            // SAFETY: the CPU has AVX-512 F (just checked).
            return unsafe { self.push_avx512(q) };
        }
        self.push_baseline(q)
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
    /// forward (a store-forwarding stall on every word).
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
pub(super) fn event_thresholds(q: &[u32; 64], m: &mut [u8; 64]) -> (u8, u64, u64) {
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

/// The plain form of `event_thresholds`: one lane at a time.
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
pub(super) unsafe fn event_thresholds_avx512(q: &[u32; 64], m: &mut [u8; 64]) -> (u8, u64, u64) {
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
