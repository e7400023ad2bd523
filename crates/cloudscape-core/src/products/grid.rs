//! Density grid encodings: `.npy` (numpy format 1.0), raw little-endian `f32`, and `u8`.
//!
//! All three hold the grid in C order with shape `(depth, rows, cols)`, row = y,
//! col = x. `u8` maps [0, 1] to 0..=255 by rounding.

use crate::density::Grid;

/// How a grid is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridFormat {
    /// numpy `.npy`, dtype `<f4` (density) or `|u1` (cld).
    Npy,
    /// Raw little-endian f32, no header.
    F32,
    /// Raw u8, density × 255 rounded.
    U8,
}

impl GridFormat {
    /// `npy`, `f32` or `u8`.
    pub fn parse(s: &str) -> Option<GridFormat> {
        match s {
            "npy" => Some(GridFormat::Npy),
            "f32" => Some(GridFormat::F32),
            "u8" => Some(GridFormat::U8),
            _ => None,
        }
    }
}

/// Quantises a density in [0, 1] to a byte.
#[inline]
pub fn density_to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Encodes a density grid.
pub fn encode_density(grid: &Grid<f32>, format: GridFormat) -> Vec<u8> {
    match format {
        GridFormat::Npy => {
            let mut out = npy_header("<f4", grid);
            out.reserve(grid.data.len() * 4);
            for v in &grid.data {
                out.extend_from_slice(&v.to_le_bytes());
            }
            out
        }
        GridFormat::F32 => grid.data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        GridFormat::U8 => grid.data.iter().map(|&v| density_to_u8(v)).collect(),
    }
}

/// Encodes a grid of cloud bits (0/1). `f32` writes 0.0/1.0; `u8` writes 0/1.
pub fn encode_cells(grid: &Grid<u8>, format: GridFormat) -> Vec<u8> {
    match format {
        GridFormat::Npy => {
            let mut out = npy_header("|u1", grid);
            out.extend_from_slice(&grid.data);
            out
        }
        GridFormat::F32 => grid.data.iter().flat_map(|&v| (v as f32).to_le_bytes()).collect(),
        GridFormat::U8 => grid.data.clone(),
    }
}

/// The NPY 1.0 header: magic, version, little-endian header length, then a Python
/// dict literal padded with spaces and a newline so data starts at a multiple of 64.
fn npy_header<T>(descr: &str, grid: &Grid<T>) -> Vec<u8> {
    let dict = format!(
        "{{'descr': '{descr}', 'fortran_order': False, 'shape': ({}, {}, {}), }}",
        grid.depth, grid.rows, grid.cols
    );
    let unpadded = 10 + dict.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    let header_len = dict.len() + pad + 1;
    let mut out = Vec::with_capacity(10 + header_len);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header_len as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out.extend(std::iter::repeat_n(b' ', pad));
    out.push(b'\n');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_header_is_aligned_and_describes_shape() {
        let g = Grid::filled(2, 3, 4, 0.5f32);
        let b = encode_density(&g, GridFormat::Npy);
        let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + hl) % 64, 0);
        let header = std::str::from_utf8(&b[10..10 + hl]).unwrap();
        assert!(header.contains("'shape': (2, 3, 4)"));
        assert!(header.ends_with('\n'));
        assert_eq!(b.len(), 10 + hl + 24 * 4);
        assert_eq!(&b[10 + hl..10 + hl + 4], &0.5f32.to_le_bytes());
    }

    #[test]
    fn u8_rounds_and_clamps() {
        assert_eq!(density_to_u8(0.0), 0);
        assert_eq!(density_to_u8(1.0), 255);
        assert_eq!(density_to_u8(0.5), 128);
        assert_eq!(density_to_u8(2.0), 255);
    }
}
