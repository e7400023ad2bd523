//! `density.ktx2`: the density grid as a KTX 2.0 3D texture, for GPUs and engines that
//! load textures from KTX2 (three.js's `KTX2Loader`, Godot, Bevy, Unity and Unreal
//! plugins).
//!
//! Khronos KTX 2.0 (`VK_FORMAT_R8_UNORM`, one level, no supercompression), little-endian:
//! the texture is `cols × rows × depth` texels (x east, y north with row 0 the
//! southern edge, z up from the layer base), x fastest then y then z: the same bytes
//! as `density.u8` (density × 255 rounded), behind a header that says so.
//!
//! | offset | field | value |
//! |---|---|---|
//! | 0 | identifier | `«KTX 20»\r\n\x1A\n` |
//! | 12 | vkFormat | 9 (`VK_FORMAT_R8_UNORM`) |
//! | 16 | typeSize | 1 |
//! | 20 | pixelWidth, pixelHeight, pixelDepth | cols, rows, depth |
//! | 32 | layerCount, faceCount, levelCount | 0, 1, 1 |
//! | 44 | supercompressionScheme | 0 (none) |
//! | 48 | dfdByteOffset, dfdByteLength | 104, 44 |
//! | 56 | kvdByteOffset, kvdByteLength | 148, see below |
//! | 64 | sgdByteOffset, sgdByteLength (u64) | 0, 0 |
//! | 80 | level 0: byteOffset, byteLength, uncompressedByteLength (u64) | data offset, n, n |
//! | 104 | data format descriptor | one basic block: RGBSDA model, BT.709 primaries, linear transfer, one 8-bit red sample 0..255 |
//! | 148 | key/value data | `KTXwriter` = `cloudscape <ALGORITHM_VERSION>` |
//! | 4-aligned | level 0 | the texels |
//!
//! The values are data, not colour: linear, never sRGB-decoded. Served as
//! `image/ktx2`, KTX 2.0's registered media type.

use crate::density::Grid;
use crate::world::ALGORITHM_VERSION;

use super::grid::density_to_u8;

/// The file identifier of KTX 2.0.
pub const IDENTIFIER: [u8; 12] = [
    0xAB, b'K', b'T', b'X', b' ', b'2', b'0', 0xBB, b'\r', b'\n', 0x1A, b'\n',
];
/// `VK_FORMAT_R8_UNORM`.
pub const VK_FORMAT_R8_UNORM: u32 = 9;
/// Bytes before the data format descriptor: header (48), index (32), one level (24).
const DFD_OFFSET: usize = 104;

/// The data format descriptor of one unsigned-normalised 8-bit red channel
/// (Khronos Data Format Specification 1.3, basic descriptor block).
fn data_format_descriptor() -> Vec<u8> {
    let mut block = Vec::with_capacity(44);
    block.extend_from_slice(&44u32.to_le_bytes()); // dfdTotalSize
    block.extend_from_slice(&0u32.to_le_bytes()); // vendorId 0 (Khronos), descriptorType 0 (basic)
    block.extend_from_slice(&2u16.to_le_bytes()); // versionNumber (KDF 1.3)
    block.extend_from_slice(&40u16.to_le_bytes()); // descriptorBlockSize: 24 + 16 per sample
    // colorModel RGBSDA, primaries BT.709, transfer linear, flags: straight alpha.
    block.extend_from_slice(&[1, 1, 1, 0]);
    block.extend_from_slice(&[0, 0, 0, 0]); // texelBlockDimension 1×1×1×1 (stored minus one)
    block.extend_from_slice(&[1, 0, 0, 0, 0, 0, 0, 0]); // bytesPlane0 = 1
    // The sample: bits 0..8, channel red (0), no qualifiers, position 0, range 0..255.
    block.extend_from_slice(&0u16.to_le_bytes()); // bitOffset
    block.push(7); // bitLength − 1
    block.push(0); // channelType RED, qualifiers none
    block.extend_from_slice(&[0, 0, 0, 0]); // samplePosition
    block.extend_from_slice(&0u32.to_le_bytes()); // sampleLower
    block.extend_from_slice(&255u32.to_le_bytes()); // sampleUpper
    block
}

/// Key/value data: one `KTXwriter` entry, padded to 4 bytes.
fn key_values() -> Vec<u8> {
    let mut pair = b"KTXwriter\0".to_vec();
    pair.extend_from_slice(format!("cloudscape {ALGORITHM_VERSION}").as_bytes());
    pair.push(0);
    let mut out = (pair.len() as u32).to_le_bytes().to_vec();
    out.extend_from_slice(&pair);
    out.resize(out.len().next_multiple_of(4), 0);
    out
}

/// Encodes a density grid as a KTX 2.0 R8 3D texture (layout in the module docs).
pub fn encode_density_ktx2(grid: &Grid<f32>) -> Vec<u8> {
    let dfd = data_format_descriptor();
    let kvd = key_values();
    let kvd_offset = DFD_OFFSET + dfd.len();
    // Level data is aligned to lcm(texel block size, 4) = 4.
    let data_offset = (kvd_offset + kvd.len()).next_multiple_of(4);
    let n = grid.data.len();
    let mut out = Vec::with_capacity(data_offset + n);
    out.extend_from_slice(&IDENTIFIER);
    for v in [
        VK_FORMAT_R8_UNORM,
        1, // typeSize
        grid.cols as u32,
        grid.rows as u32,
        grid.depth as u32,
        0, // layerCount: not an array
        1, // faceCount
        1, // levelCount
        0, // supercompressionScheme: none
        DFD_OFFSET as u32,
        dfd.len() as u32,
        kvd_offset as u32,
        kvd.len() as u32,
    ] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in [0u64, 0, data_offset as u64, n as u64, n as u64] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    debug_assert_eq!(out.len(), DFD_OFFSET);
    out.extend_from_slice(&dfd);
    out.extend_from_slice(&kvd);
    out.resize(data_offset, 0);
    out.extend(grid.data.iter().map(|&v| density_to_u8(v)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn u32_at(b: &[u8], o: usize) -> u32 {
        u32::from_le_bytes(b[o..o + 4].try_into().unwrap())
    }

    fn u64_at(b: &[u8], o: usize) -> u64 {
        u64::from_le_bytes(b[o..o + 8].try_into().unwrap())
    }

    #[test]
    fn the_layout_is_the_spec_s() {
        let grid = Grid {
            depth: 3,
            rows: 4,
            cols: 5,
            data: (0..60).map(|i| i as f32 / 59.0).collect(),
        };
        let b = encode_density_ktx2(&grid);
        assert_eq!(&b[..12], &IDENTIFIER);
        let header: Vec<u32> = (0..9).map(|i| u32_at(&b, 12 + 4 * i)).collect();
        assert_eq!(header, [9, 1, 5, 4, 3, 0, 1, 1, 0]);
        let (dfd_at, dfd_len) = (u32_at(&b, 48) as usize, u32_at(&b, 52) as usize);
        let (kvd_at, kvd_len) = (u32_at(&b, 56) as usize, u32_at(&b, 60) as usize);
        assert_eq!((u64_at(&b, 64), u64_at(&b, 72)), (0, 0), "no supercompression data");
        let (at, len, raw) = (
            u64_at(&b, 80) as usize,
            u64_at(&b, 88) as usize,
            u64_at(&b, 96) as usize,
        );
        assert_eq!((dfd_at, dfd_len), (104, 44));
        assert_eq!(u32_at(&b, dfd_at) as usize, dfd_len, "dfdTotalSize");
        assert_eq!(&b[dfd_at + 12..dfd_at + 16], &[1, 1, 1, 0], "RGBSDA, BT.709, linear");
        assert_eq!(u32_at(&b, dfd_at + 40), 255, "sampleUpper");
        assert_eq!(kvd_at, dfd_at + dfd_len);
        let pair_len = u32_at(&b, kvd_at) as usize;
        assert!(b[kvd_at + 4..kvd_at + 4 + pair_len].starts_with(b"KTXwriter\0cloudscape "));
        assert!(kvd_len.is_multiple_of(4));
        assert_eq!((at % 4, len, raw), (0, 60, 60));
        assert!(at >= kvd_at + kvd_len);
        assert_eq!(b.len(), at + len);
        let texels: Vec<u8> = grid.data.iter().map(|&v| density_to_u8(v)).collect();
        assert_eq!(&b[at..], &texels[..], "the bytes of density.u8, x fastest");
    }
}
