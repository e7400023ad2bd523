//! Images: linear radiance with coverage, the PNG encoder, and the error metrics
//! (RMSE, SSIM) the quality presets are measured with.

use super::light::tone_map;
use super::pathtrace::Noise;

/// tEXt keywords of a path-traced PNG's stated noise ([`Image::to_png_with_noise`]).
const NOISE_KEYS: [&str; 3] = ["cloudscape:samples", "cloudscape:noise", "cloudscape:mean-luminance"];

/// A linear-RGB image with coverage alpha, premultiplied: `rgb` already includes alpha.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Row-major, row 0 at the top.
    pub rgb: Vec<[f32; 3]>,
    /// Coverage per pixel in [0, 1], row-major.
    pub alpha: Vec<f32>,
}

impl Image {
    /// A transparent black image.
    pub fn new(width: usize, height: usize) -> Image {
        Image {
            width,
            height,
            rgb: vec![[0.0; 3]; width * height],
            alpha: vec![0.0; width * height],
        }
    }

    /// Display values in [0, 1]: tone-mapped, gamma-encoded RGB (alpha ignored).
    pub fn display(&self) -> Vec<[f32; 3]> {
        self.rgb.iter().map(|c| c.map(|v| tone_map(v as f64) as f32)).collect()
    }

    /// An opaque 8-bit PNG of the display values, marked sRGB.
    pub fn to_png(&self) -> Vec<u8> {
        self.to_png_with_text(&[])
    }

    /// As [`Image::to_png`], with the path tracer's stated noise in tEXt chunks
    /// (`cloudscape:samples`, `cloudscape:noise`, `cloudscape:mean-luminance`), so the
    /// file says how converged it is; [`png_noise`] reads them back.
    pub fn to_png_with_noise(&self, noise: &Noise) -> Vec<u8> {
        let values = [
            noise.samples.to_string(),
            format!("{:e}", noise.std_error),
            format!("{:e}", noise.mean_luminance),
        ];
        let text: Vec<(&str, String)> = NOISE_KEYS.into_iter().zip(values).collect();
        self.to_png_with_text(&text)
    }

    /// The opaque 8-bit sRGB PNG of the display values with `text` in tEXt chunks.
    fn to_png_with_text(&self, text: &[(&str, String)]) -> Vec<u8> {
        let bytes: Vec<u8> = self.display().iter().flat_map(|c| c.map(to_u8)).collect();
        encode_png_with_text(
            self.width,
            self.height,
            png::ColorType::Rgb,
            PngSpace::Srgb,
            &bytes,
            text,
        )
    }

    /// An RGBA PNG with straight (not premultiplied) alpha: colour = display(rgb / alpha).
    pub fn to_png_straight_alpha(&self) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(self.width * self.height * 4);
        for (c, &a) in self.rgb.iter().zip(&self.alpha) {
            let a = a.clamp(0.0, 1.0);
            let straight = if a > 1e-6 { c.map(|v| v / a) } else { [0.0; 3] };
            bytes.extend(straight.map(|v| to_u8(tone_map(v as f64) as f32)));
            bytes.push(to_u8(a));
        }
        encode_png(self.width, self.height, png::ColorType::Rgba, PngSpace::Srgb, &bytes)
    }
}

/// Quantises [0, 1] to a byte by rounding (NaN → 0).
pub fn to_u8(v: f32) -> u8 {
    if v.is_nan() {
        0
    } else {
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    }
}

/// The stated noise of a PNG written by [`Image::to_png_with_noise`]; `None` for any
/// other PNG or bytes that are not one.
pub fn png_noise(png_bytes: &[u8]) -> Option<Noise> {
    let reader = png::Decoder::new(std::io::Cursor::new(png_bytes)).read_info().ok()?;
    let text = &reader.info().uncompressed_latin1_text;
    let value = |key: &str| text.iter().find(|c| c.keyword == key).map(|c| c.text.as_str());
    Some(Noise {
        samples: value(NOISE_KEYS[0])?.parse().ok()?,
        std_error: value(NOISE_KEYS[1])?.parse().ok()?,
        mean_luminance: value(NOISE_KEYS[2])?.parse().ok()?,
    })
}

/// What the samples of a PNG mean, stated in its colour-space chunks so that a
/// decoder (or an engine's importer) knows whether to linearise them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PngSpace {
    /// Colour for display (renders, impostor atlases, charts): an `sRGB` chunk
    /// (perceptual intent) with the `gAMA` 1/2.2 and `cHRM` fallbacks PNG 3 §11.3.2.5
    /// asks for. Decode to linear before blending or lighting.
    Srgb,
    /// Data, linear in what it measures (densities, opacities, transmittances,
    /// heights): `gAMA` 1.0 and no `sRGB` chunk. Read the bytes as they are (no colour
    /// conversion: three.js `NoColorSpace`, `createImageBitmap(…, {colorSpaceConversion:
    /// 'none'})`, Unity/Godot/Unreal "linear"/"non-colour" import).
    Linear,
}

/// Encodes 8-bit samples as a PNG. The encoder writes to memory, so it cannot fail
/// for consistent dimensions; a mismatch is a programming error.
pub fn encode_png(width: usize, height: usize, colour: png::ColorType, space: PngSpace, data: &[u8]) -> Vec<u8> {
    encode_png_with_text(width, height, colour, space, data, &[])
}

/// [`encode_png`] with tEXt chunks (Latin-1 keyword, text) before the image data.
fn encode_png_with_text(
    width: usize,
    height: usize,
    colour: png::ColorType,
    space: PngSpace,
    data: &[u8],
    text: &[(&str, String)],
) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
        enc.set_color(colour);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        match space {
            PngSpace::Srgb => {
                enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
                // The fallbacks are written when they are exactly PNG's sRGB values.
                let s = png::ScaledFloat::from_scaled;
                enc.set_source_gamma(s(45_455));
                enc.set_source_chromaticities(png::SourceChromaticities {
                    white: (s(31_270), s(32_900)),
                    red: (s(64_000), s(33_000)),
                    green: (s(30_000), s(60_000)),
                    blue: (s(15_000), s(6_000)),
                });
            }
            PngSpace::Linear => enc.set_source_gamma(png::ScaledFloat::new(1.0)),
        }
        for (keyword, value) in text {
            enc.add_text_chunk(keyword.to_string(), value.clone())
                .expect("a Latin-1 keyword of 1-79 bytes");
        }
        let mut w = enc.write_header().expect("in-memory PNG header");
        w.write_image_data(data).expect("PNG data matches its dimensions");
    }
    out
}

/// Root-mean-square error over all channels of two display images (values in [0, 1]).
pub fn rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    assert_eq!(a.len(), b.len());
    if a.is_empty() {
        return 0.0;
    }
    let s: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(x, y)| (0..3).map(move |i| (x[i] as f64 - y[i] as f64).powi(2)))
        .sum();
    (s / (3 * a.len()) as f64).sqrt()
}

/// Mean SSIM (Wang, Bovik, Sheikh & Simoncelli 2004) of the luma (Rec. 601) of two
/// display images in [0, 1]: 11×11 Gaussian window, σ = 1.5, C1 = 0.01², C2 = 0.03².
pub fn ssim(a: &[[f32; 3]], b: &[[f32; 3]], width: usize, height: usize) -> f64 {
    assert_eq!(a.len(), width * height);
    assert_eq!(b.len(), width * height);
    let luma = |img: &[[f32; 3]]| -> Vec<f64> {
        img.iter()
            .map(|c| 0.299 * c[0] as f64 + 0.587 * c[1] as f64 + 0.114 * c[2] as f64)
            .collect()
    };
    let (x, y) = (luma(a), luma(b));
    let blur = |v: &[f64]| gaussian_blur(v, width, height);
    let mx = blur(&x);
    let my = blur(&y);
    let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
    let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
    let xy: Vec<f64> = x.iter().zip(&y).map(|(p, q)| p * q).collect();
    let (sxx, syy, sxy) = (blur(&xx), blur(&yy), blur(&xy));
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut total = 0.0;
    for i in 0..x.len() {
        let (mu_x, mu_y) = (mx[i], my[i]);
        let vx = (sxx[i] - mu_x * mu_x).max(0.0);
        let vy = (syy[i] - mu_y * mu_y).max(0.0);
        let cov = sxy[i] - mu_x * mu_y;
        total += ((2.0 * mu_x * mu_y + c1) * (2.0 * cov + c2)) / ((mu_x * mu_x + mu_y * mu_y + c1) * (vx + vy + c2));
    }
    total / x.len() as f64
}

/// Separable normalised Gaussian (11 taps, σ = 1.5), edges renormalised.
fn gaussian_blur(v: &[f64], width: usize, height: usize) -> Vec<f64> {
    let k: Vec<f64> = (-5i32..=5)
        .map(|i| (-(i * i) as f64 / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    let pass = |src: &[f64], horizontal: bool| -> Vec<f64> {
        let mut out = vec![0.0; src.len()];
        for y in 0..height {
            for x in 0..width {
                let (mut s, mut w) = (0.0, 0.0);
                for (t, kv) in k.iter().enumerate() {
                    let o = t as i64 - 5;
                    let (xx, yy) = if horizontal {
                        (x as i64 + o, y as i64)
                    } else {
                        (x as i64, y as i64 + o)
                    };
                    if xx >= 0 && yy >= 0 && (xx as usize) < width && (yy as usize) < height {
                        s += kv * src[yy as usize * width + xx as usize];
                        w += kv;
                    }
                }
                out[y * width + x] = s / w;
            }
        }
        out
    };
    pass(&pass(v, true), false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_have_zero_error_and_unit_ssim() {
        let img: Vec<[f32; 3]> = (0..400)
            .map(|i| [(i % 20) as f32 / 20.0, 0.5, (i / 20) as f32 / 20.0])
            .collect();
        assert_eq!(rmse(&img, &img), 0.0);
        assert!((ssim(&img, &img, 20, 20) - 1.0).abs() < 1e-12);
        let shifted: Vec<[f32; 3]> = img.iter().map(|c| c.map(|v| (v + 0.1).min(1.0))).collect();
        let e = rmse(&img, &shifted);
        assert!(e > 0.05 && e <= 0.1, "{e}");
        let noisy: Vec<[f32; 3]> = img
            .iter()
            .enumerate()
            .map(|(i, c)| c.map(|v| if i % 2 == 0 { v } else { 1.0 - v }))
            .collect();
        assert!(ssim(&img, &noisy, 20, 20) < 0.5);
    }

    #[test]
    fn png_decodes_with_the_png_crate() {
        let mut img = Image::new(3, 2);
        img.rgb[0] = [1.0, 0.0, 0.0];
        img.alpha[0] = 0.5;
        for bytes in [img.to_png(), img.to_png_straight_alpha()] {
            let dec = png::Decoder::new(std::io::Cursor::new(bytes));
            let reader = dec.read_info().unwrap();
            assert_eq!((reader.info().width, reader.info().height), (3, 2));
        }
        assert_eq!(png_noise(&img.to_png()), None);
        assert_eq!(png_noise(b"not a png"), None);
        let noise = Noise {
            samples: 64,
            std_error: 0.012_345_678_9,
            mean_luminance: 0.5,
        };
        let bytes = img.to_png_with_noise(&noise);
        assert_eq!(png_noise(&bytes), Some(noise));
        // The same pixels as without the text.
        let pixels = |b: Vec<u8>| {
            let mut r = png::Decoder::new(std::io::Cursor::new(b)).read_info().unwrap();
            let mut buf = vec![0; r.output_buffer_size().unwrap()];
            r.next_frame(&mut buf).unwrap();
            buf
        };
        assert_eq!(pixels(bytes), pixels(img.to_png()));
    }
}
