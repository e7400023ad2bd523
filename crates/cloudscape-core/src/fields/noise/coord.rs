//! Split coordinates: an `i64` lattice index plus an `f64` fraction, and the exact
//! product that scales them without losing the fraction.

/// A coordinate on the noise lattice: `int + frac`, with `frac` in [0, 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coord {
    /// The lattice index.
    pub int: i64,
    /// The fraction within the lattice cell, in [0, 1).
    pub frac: f64,
}

impl Coord {
    /// `int + frac` with any finite `frac`, normalised so that `frac` is in [0, 1).
    #[inline]
    pub fn new(int: i64, frac: f64) -> Coord {
        let f = frac.floor();
        let mut c = Coord {
            int: int.wrapping_add(f as i64),
            frac: frac - f,
        };
        // `frac - floor(frac)` can round up to exactly 1.0 for tiny negative fractions.
        if c.frac >= 1.0 {
            c.int = c.int.wrapping_add(1);
            c.frac -= 1.0;
        }
        c
    }

    /// `(cell + cell_frac) * scale` as a lattice coordinate, keeping the fraction
    /// exact to a few ulps even when `cell * scale` is far beyond f64's fraction
    /// precision (|cell| up to 2^52).
    #[inline]
    pub fn scaled(cell: i64, cell_frac: f64, scale: f64) -> Coord {
        let (p, err) = two_product(cell as f64, scale);
        let fl = p.floor();
        Coord::new(fl as i64, (p - fl) + err + cell_frac * scale)
    }

    /// Adds a real offset (for example a per-octave shift).
    #[inline]
    pub fn offset(self, d: f64) -> Coord {
        let fl = d.floor();
        Coord::new(self.int.wrapping_add(fl as i64), self.frac + (d - fl))
    }
}

/// Dekker's exact product: `a * b = p + err` exactly, with `p = fl(a * b)`.
/// Pure f64 arithmetic (no FMA), so it is the same on every machine.
#[inline]
pub fn two_product(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    let (ah, al) = split(a);
    let (bh, bl) = split(b);
    let err = ((ah * bh - p) + ah * bl + al * bh) + al * bl;
    (p, err)
}

/// Veltkamp's splitter for f64: 2^27 + 1.
pub(super) const SPLIT: f64 = 134_217_729.0;

/// Veltkamp's split of `x` into a 26-bit high part and the rest (`hi + lo == x`),
/// the halves of [`two_product`].
#[inline]
pub(super) fn split(x: f64) -> (f64, f64) {
    let c = SPLIT * x;
    let hi = c - (c - x);
    (hi, x - hi)
}
