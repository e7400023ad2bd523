//! The x86 SIMD features the kernels choose between, detected once per process.
//!
//! Every vector kernel in core gives the same bits as its portable form, so the
//! choice is only about speed; what each kernel needs is named where it is
//! chosen ([`crate::fields::noise::NoiseBackend`],
//! [`crate::automaton::random::DrawBackend`]).

use std::sync::OnceLock;

/// Which of the instruction-set extensions the kernels use this CPU has.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Features {
    /// AVX-512 Foundation: 512-bit vectors and mask registers.
    pub avx512f: bool,
    /// AVX-512 Byte and Word: 8- and 16-bit lanes (the draws' 16-bit compares).
    pub avx512bw: bool,
    /// AVX-512 Doubleword and Quadword: 64-bit multiplies and f64 ↔ i64 conversions.
    pub avx512dq: bool,
    /// Vector AES: one AES round on four 128-bit blocks per instruction.
    pub vaes: bool,
}

impl Features {
    /// This CPU's features, detected on the first call.
    pub fn get() -> Features {
        static FEATURES: OnceLock<Features> = OnceLock::new();
        *FEATURES.get_or_init(Features::detect)
    }

    #[cfg(target_arch = "x86_64")]
    fn detect() -> Features {
        Features {
            avx512f: std::is_x86_feature_detected!("avx512f"),
            avx512bw: std::is_x86_feature_detected!("avx512bw"),
            avx512dq: std::is_x86_feature_detected!("avx512dq"),
            vaes: std::is_x86_feature_detected!("vaes"),
        }
    }

    #[cfg(not(target_arch = "x86_64"))]
    fn detect() -> Features {
        Features::default()
    }

    /// AVX-512 F and DQ: the f64/i64 kernels (noise, switch hashes, drive conversion).
    pub fn avx512_dq(self) -> bool {
        self.avx512f && self.avx512dq
    }

    /// AVX-512 F and BW with VAES: the AES draws of the automaton.
    pub fn avx512_vaes(self) -> bool {
        self.avx512f && self.avx512bw && self.vaes
    }
}

/// A choice between a kernel's portable form and vector forms of it that give the
/// same bits ([`crate::fields::noise::NoiseBackend`],
/// [`crate::automaton::random::DrawBackend`]).
pub trait Backend: Copy + PartialEq + 'static {
    /// Every backend this CPU runs, slowest (the portable one, always there) first.
    fn available() -> &'static [Self];

    /// The fastest backend this CPU runs.
    fn detect() -> Self {
        *Self::available().last().expect("the portable backend is always there")
    }

    /// Whether this CPU runs `self` (a vector kernel is only sound where it does).
    fn runs_here(self) -> bool {
        Self::available().contains(&self)
    }
}
