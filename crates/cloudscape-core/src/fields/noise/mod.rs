//! Simplex noise (2D and 3D) and fBm on split coordinates: an `i64` lattice index
//! plus an `f64` fraction in [0, 1).
//!
//! Why our own and not a crate: `noise` hashes lattice points through a 256-entry
//! permutation table (the field repeats every 256 lattice units), and
//! fastnoise-lite floors coordinates into `i32` (it wraps past 2^31 lattice units)
//! and feeds raw world coordinates through one float, so a field 2^40 cells from
//! the origin loses its fraction. `tests/fields_precision.rs` keeps the failure
//! that made us. Here lattice points are hashed as full `i64`s and the skew of
//! the simplex grid is applied to the integer and fractional parts separately,
//! so the fraction keeps full precision at any distance.
//!
//! Gustavson, "Simplex noise demystified" (2005), for the algorithm and scaling.

#[cfg(target_arch = "x86_64")]
mod avx512;
mod coord;
mod fbm;
mod hash;
mod simplex;
#[cfg(test)]
mod tests;

pub use coord::{Coord, two_product};
pub use fbm::{Fbm, FbmGrid, Octave, sample_table};
pub(crate) use hash::MIX_MUL;
pub use hash::mix64;
pub use simplex::{simplex2, simplex3};

use crate::cpu::{Backend, Features};

/// An implementation of [`FbmGrid::row`] (and of the other f64/i64 kernels that
/// need the same AVX-512 F and DQ: switch hashes, drive conversion). Every backend
/// gives the same bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoiseBackend {
    /// [`simplex3`] and [`simplex2`], one sample at a time.
    Scalar,
    /// AVX-512 (F, DQ): eight samples at a time.
    Avx512,
}

impl Backend for NoiseBackend {
    fn available() -> &'static [NoiseBackend] {
        if Features::get().avx512_dq() {
            &[NoiseBackend::Scalar, NoiseBackend::Avx512]
        } else {
            &[NoiseBackend::Scalar]
        }
    }
}
