//! ARS-5 over the draw counters: the step keys, the counter layout and the
//! portable one-lane draw the naive kernel uses.

use aes::Block;
use aes::hazmat::cipher_round;

use crate::fields::noise::mix64;
use crate::world::Event;

/// AES rounds per block (ARS-5).
pub const ROUNDS: usize = 5;

/// The round keys of one (layer stream, level, step): `k[0]` is XOR-ed into the
/// counter, `k[1..]` are the rounds' keys, each the previous plus ARS's Weyl
/// constants (per 64-bit half).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepKeys {
    /// `k[0]` whitens the counter; `k[1..]` are the five rounds' keys.
    pub k: [[u64; 2]; ROUNDS + 1],
}

impl StepKeys {
    /// The keys of `step` of level `level` in the layer stream `stream`.
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

pub(super) fn block(v: [u64; 2]) -> Block {
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
pub fn draw(keys: &StepKeys, y: i64, wx: i64, e: Event, bit: u32) -> u16 {
    let b = ars5(keys, counter(y, wx, e as usize, bit as usize / 8));
    let j = 2 * (bit as usize % 8);
    u16::from_le_bytes([b[j], b[j + 1]])
}

/// Whether one cell's event with threshold `q` (0..=65536) fires.
pub fn fires(keys: &StepKeys, y: i64, wx: i64, e: Event, bit: u32, q: u32) -> bool {
    q >= 65536 || u32::from(draw(keys, y, wx, e, bit)) < q
}
