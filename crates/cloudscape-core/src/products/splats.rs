//! `splats.png` and `splats.json`: the splat sprite sheet of a quality preset.
//!
//! The PNG is 8-bit grey + alpha: every texel is white (255) with straight alpha =
//! the splat's opacity × 255. Splat `k` sits at column `k mod columns`, row
//! `k div columns` of the grid, each `size × size` texels. The JSON describes it:
//! `{"count", "size", "columns", "rows", "tau_max", "tau": [τ_k], "alpha": "straight",
//! "profile": ..., "index": ...}`.

use serde_json::json;

use super::json_f32;
use crate::render::Quality;
use crate::render::image::{PngSpace, encode_png, to_u8};
use crate::render::splats::TAU_MAX;

fn grid_columns(count: usize) -> usize {
    (count as f64).sqrt().ceil().max(1.0) as usize
}

/// The sprite sheet of `quality` as a PNG.
pub fn encode_png_sheet(quality: Quality) -> Vec<u8> {
    let sheet = quality.splat_sheet();
    let (n, s) = (sheet.count, sheet.size);
    let cols = grid_columns(n);
    let rows = n.div_ceil(cols);
    let (w, h) = (cols * s, rows * s);
    let mut bytes = vec![0u8; w * h * 2];
    for px in bytes.chunks_mut(2) {
        px[0] = 255;
    }
    for k in 0..n {
        let (gx, gy) = ((k % cols) * s, (k / cols) * s);
        for v in 0..s {
            for u in 0..s {
                let i = ((gy + v) * w + gx + u) * 2;
                bytes[i + 1] = to_u8(sheet.alpha[(k * s + v) * s + u]);
            }
        }
    }
    encode_png(w, h, png::ColorType::GrayscaleAlpha, PngSpace::Linear, &bytes)
}

/// The description of the sheet of `quality` as JSON.
pub fn encode_json_sheet(quality: Quality) -> Vec<u8> {
    let sheet = quality.splat_sheet();
    let cols = grid_columns(sheet.count);
    let taus: Vec<f64> = (0..sheet.count).map(|k| json_f32(sheet.tau(k))).collect();
    let v = json!({
        "quality": quality.as_str(),
        "count": sheet.count,
        "size": sheet.size,
        "columns": cols,
        "rows": sheet.count.div_ceil(cols),
        "tau_max": TAU_MAX,
        "tau": taus,
        "alpha": "straight",
        "profile": "alpha(p) = 1 - exp(-tau_k * S(p) / S(0)), S = line integral of Wyvill's field function through the unit ball at impact parameter p",
        "index": "tau_k = tau_max * ((k + 1) / count)^2; a metaball uses the splat nearest its centre optical depth",
    });
    serde_json::to_vec(&v).expect("a JSON value serialises")
}
