//! Products: one type per product, and the encoders that turn them into bytes. The
//! tile products are listed once, in [`catalogue`].

pub mod atlas;
pub mod billboards;
pub mod catalogue;
pub mod coverage;
pub mod grid;
pub mod keyframe_bin;
pub mod ktx2;
pub mod precipitation;
pub mod shadow;
pub mod sky;
pub mod splats;

pub use catalogue::Product;

/// A value at f32 precision that JSON prints in the fewest digits: the f64 nearest the
/// f32's shortest round-trip decimal, so `serde_json` writes `0.9` for `0.9f32`, not
/// `0.8999999761581421` (the f32's exact value, which the f64 writer would print). A
/// finite value beyond f32's range keeps its f64 value (as an f32 it would be ±∞, which
/// JSON writes as `null`); NaN and ±∞ are 0.
pub(crate) fn json_f32(v: f64) -> f64 {
    let short = v as f32;
    if short.is_finite() {
        // Display prints an f32's shortest decimal that reads back to the same f32.
        short.to_string().parse().unwrap_or(short as f64)
    } else if v.is_finite() {
        v
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::json_f32;

    #[test]
    fn json_numbers_are_the_shortest_f32_decimals() {
        let text = |v: f64| serde_json::to_string(&json_f32(v)).unwrap();
        assert_eq!(text(0.9f32 as f64), "0.9");
        assert_eq!(text(0.9), "0.9");
        assert_eq!(text(1.0 / 3.0), "0.33333334");
        assert_eq!(text(-1234.5), "-1234.5");
        assert_eq!(text(1e-7), "1e-7");
        assert_eq!(text(3e38), "3e+38");
        assert_eq!(text(1e300), "1e+300", "beyond f32: kept");
        assert_eq!(text(f64::NAN), "0.0");
        assert_eq!(text(f64::INFINITY), "0.0");
        // Every printed value reads back to the same f32.
        for i in 0..20_000u32 {
            let x = f32::from_bits(i.wrapping_mul(2_654_435_761) & 0x7f7f_ffff);
            let back: f64 = serde_json::from_str(&text(x as f64)).unwrap();
            assert_eq!(back as f32, x, "{x:e}");
        }
    }
}
