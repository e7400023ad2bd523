//! Table-free hashing of lattice points: full `i64` indices, so the noise has no period.

/// A 64-bit finaliser (splitmix64 / Stafford variant 13): every input bit
/// affects every output bit.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(MIX_MUL[0]);
    z = (z ^ (z >> 27)).wrapping_mul(MIX_MUL[1]);
    z ^ (z >> 31)
}

/// The multipliers of [`mix64`].
pub(crate) const MIX_MUL: [u64; 2] = [0xbf58_476d_1ce4_e5b9, 0x94d0_49bb_1331_11eb];

/// The odd multipliers that spread lattice indices i, j, k in [`hash3`].
pub(super) const HASH_MUL: [u64; 3] = [0x9e37_79b9_7f4a_7c15, 0xc2b2_ae3d_27d4_eb4f, 0x1656_67b1_9e37_79f9];

/// Hash of a seed and up to three lattice indices: the indices are spread by
/// odd multipliers into one word and finalised once (every input bit reaches
/// every output bit; no table, so no period).
#[inline]
pub(super) fn hash3(seed: u64, i: i64, j: i64, k: i64) -> u64 {
    mix64(
        seed ^ (i as u64).wrapping_mul(HASH_MUL[0])
            ^ (j as u64).wrapping_mul(HASH_MUL[1]).rotate_left(21)
            ^ (k as u64).wrapping_mul(HASH_MUL[2]).rotate_left(42),
    )
}
