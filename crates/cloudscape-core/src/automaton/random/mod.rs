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

mod ars;
#[cfg(target_arch = "x86_64")]
pub mod avx512;
mod drives;
mod portable;
#[cfg(test)]
mod tests;

pub use ars::{ROUNDS, StepKeys, ars5, counter, draw, fires};
pub use drives::{Head, StochasticDrives, Thresholds, WordDrive, event_thresholds_scalar};
pub use portable::below_portable;

use crate::cpu::{Backend, Features};

/// An implementation of the per-word draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DrawBackend {
    /// AVX-512 (F, BW) with VAES: four AES blocks per instruction.
    Avx512,
    /// `aes::hazmat`, eight blocks per call.
    Portable,
}

impl Backend for DrawBackend {
    fn available() -> &'static [DrawBackend] {
        if Features::get().avx512_vaes() {
            &[DrawBackend::Portable, DrawBackend::Avx512]
        } else {
            &[DrawBackend::Portable]
        }
    }
}
