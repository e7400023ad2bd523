//! Encode once: the compressed variants of cached bytes, kept beside them.
//!
//! Compression costs more than everything else on a cache hit (a 512 KB
//! `billboards.bin` takes 0.8 ms to send as it is and 16–32 ms to gzip), so a cached
//! response is compressed at most once per coding: the first request that accepts
//! a coding compresses (concurrent ones join it), the variant goes into the response
//! cache under the key plus the coding, and every later request takes it from there.
//! The response then carries `Content-Encoding`, so the generic compression layer
//! leaves it alone, and its ETag gets the coding appended like any compressed
//! representation (`tag_coding`).

use axum::body::Bytes;
use axum::http::{HeaderMap, header};

/// A content coding the server compresses cached bytes with itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coding {
    Zstd,
    Gzip,
}

/// Bodies smaller than this are sent as they are.
pub const MIN_COMPRESSED_BYTES: usize = 256;

impl Coding {
    pub fn name(self) -> &'static str {
        match self {
            Coding::Zstd => "zstd",
            Coding::Gzip => "gzip",
        }
    }

    /// The coding to answer a request with: zstd when `Accept-Encoding` accepts it,
    /// else gzip, else none (q = 0 refuses a coding; `*` accepts any not named).
    pub fn negotiate(headers: &HeaderMap) -> Option<Coding> {
        let accept = headers.get(header::ACCEPT_ENCODING)?.to_str().ok()?;
        let q = |name: &str| -> Option<f64> {
            accept.split(',').find_map(|part| {
                let mut it = part.split(';');
                let coding = it.next()?.trim();
                if !coding.eq_ignore_ascii_case(name) {
                    return None;
                }
                let q = it
                    .find_map(|p| p.trim().strip_prefix("q=").and_then(|v| v.trim().parse::<f64>().ok()))
                    .unwrap_or(1.0);
                Some(q)
            })
        };
        let star = q("*");
        let accepts = |name: &str| q(name).or(star).is_some_and(|q| q > 0.0);
        [Coding::Zstd, Coding::Gzip].into_iter().find(|c| accepts(c.name()))
    }

    /// Compresses `bytes` (deterministic: same bytes, same output).
    pub fn compress(self, bytes: &[u8]) -> Result<Bytes, String> {
        use std::io::Write;
        match self {
            Coding::Zstd => zstd::bulk::compress(bytes, 3)
                .map(Bytes::from)
                .map_err(|e| e.to_string()),
            Coding::Gzip => {
                let mut w =
                    flate2::write::GzEncoder::new(Vec::with_capacity(bytes.len() / 3), flate2::Compression::default());
                w.write_all(bytes).map_err(|e| e.to_string())?;
                w.finish().map(Bytes::from).map_err(|e| e.to_string())
            }
        }
    }
}

/// Whether a body of `content_type` is worth compressing: not images, which are
/// compressed already, except KTX2, whose density texels are stored raw.
pub fn compressible(content_type: &str) -> bool {
    !content_type.starts_with("image/") || content_type == "image/ktx2"
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    fn accept(v: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::ACCEPT_ENCODING, HeaderValue::from_str(v).unwrap());
        h
    }

    #[test]
    fn negotiation_prefers_zstd_and_honours_q_zero() {
        assert_eq!(Coding::negotiate(&HeaderMap::new()), None);
        assert_eq!(Coding::negotiate(&accept("gzip, deflate, br")), Some(Coding::Gzip));
        assert_eq!(Coding::negotiate(&accept("gzip, zstd")), Some(Coding::Zstd));
        assert_eq!(Coding::negotiate(&accept("zstd;q=0, gzip;q=0.5")), Some(Coding::Gzip));
        assert_eq!(Coding::negotiate(&accept("identity")), None);
        assert_eq!(Coding::negotiate(&accept("*")), Some(Coding::Zstd));
        assert_eq!(Coding::negotiate(&accept("*, zstd;q=0")), Some(Coding::Gzip));
        assert_eq!(Coding::negotiate(&accept("GZIP")), Some(Coding::Gzip));
    }

    #[test]
    fn compressed_bytes_decompress_to_the_original() {
        use std::io::Read;
        let data: Vec<u8> = (0..100_000u32).map(|i| (i % 251) as u8 ^ (i / 1000) as u8).collect();
        let z = Coding::Zstd.compress(&data).unwrap();
        assert_eq!(zstd::bulk::decompress(&z, data.len()).unwrap(), data);
        let g = Coding::Gzip.compress(&data).unwrap();
        let mut out = Vec::new();
        flate2::read::GzDecoder::new(&g[..]).read_to_end(&mut out).unwrap();
        assert_eq!(out, data);
        assert!(z.len() < data.len() / 2 && g.len() < data.len() / 2);
        assert_eq!(Coding::Gzip.compress(&data).unwrap(), g, "deterministic");
    }
}
