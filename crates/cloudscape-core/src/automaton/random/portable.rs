//! The portable form of a word's draws, through `aes::hazmat` (AES-NI where the
//! CPU has it, the crate's software AES otherwise).

use aes::hazmat::cipher_round_par;

use super::ars::{StepKeys, block, counter};
use super::drives::Thresholds;

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
