//! From density to light: splats, sun shading, billboards, and the renderers: the
//! billboard compositor a client would use, the reference path tracer, and the
//! single-scattering ray marcher.
//!
//! # API summary (what the HTTP service calls)
//!
//! ```text
//! Quality::parse("fast" | "balanced" | "accurate" | "reference" | "reference-single") -> Option<Quality>;  q.as_str()
//! Sun::parse("AZ,EL") -> Result<Sun, ParseError>;  Sun::from_clock(t, &config.sun) -> Sun
//! sun.bucket() -> SunBucket;  bucket.id() -> String          (cache-key part, ~8° buckets, 1° near the horizon)
//! TileId { z, x, y }
//!
//! // Density + metaballs + shading of one tile, once; every tile product encodes it.
//! tile::shade_tile(&world, layer, TileId, t, quality, sun, &ShadingParams::default(), &config.limits)
//!     -> Result<ShadedTile, RenderError>
//! products::billboards::encode_json(&ShadedTile) -> Vec<u8>          // billboards.json
//! products::billboards::encode_bin(&ShadedTile) -> Vec<u8>           // billboards.bin
//! products::billboards::decode_bin(&[u8]) -> Result<BinBillboards, String>
//! products::shadow::encode_png_map(&ShadedTile) -> Vec<u8>           // shadow.png
//! products::atlas::build(&ShadedTile) -> Atlas { png, manifest, impostors }  // atlas.png / atlas.json
//! products::coverage::encode_png_for_tile(&world, layer, TileId, t, &config.limits)
//!     -> Result<Vec<u8>, RenderError>                               // coverage.png (no sun, no quality)
//! products::splats::encode_png_sheet(quality) / encode_json_sheet(quality) -> Vec<u8>  // /v1/splats.*
//!
//! // `cloudscape render` and GET /render.png:
//! scene::parse_size("WxH") -> Result<(usize, usize), ParseError>;  Camera::parse("X,Y,Z,YAW,PITCH,FOV")
//! scene::render(&world, &config, &RenderRequest { camera, width, height, t, quality, sun: Option<Sun>,
//!     params: ShadingParams::default(), samples: u32 }) -> Result<Rendered, RenderError>;
//! rendered.image.to_png();  rendered.noise: Option<pathtrace::Noise>   // `reference` only
//! ```
//!
//! Errors: [`ParseError`] is a camera, size or sun the parsers refuse (its message names
//! the syntax and repeats the input, for a 400 or a CLI flag's error);
//! [`RenderError::BadRequest`] and [`RenderError::Sim`] are the caller's input
//! (400, or 422 for `SimError` limits such as `RegionTooWide`), [`RenderError::TooMuchWork`]
//! is over the render limits (413/422).
//!
//! Every product for a sun is shaded with the centre of the sun's bucket, so all suns
//! in one bucket give identical bytes: the bucket belongs in the cache key, the exact
//! sun does not.

pub mod camera;
pub mod composite;
pub mod detail;
pub mod image;
pub mod light;
pub mod march;
pub mod pathtrace;
pub mod scene;
pub mod shade;
pub mod sky;
pub mod splats;
pub mod sun;
pub mod tile;

pub use camera::Camera;
pub use light::{Phase, ShadingParams};
pub use scene::{RenderRequest, Rendered, render};
pub use sun::{Sun, SunBucket};
pub use tile::{ShadedTile, TileId, shade_tile};

use crate::density::SimError;

/// A request the renderer refuses.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RenderError {
    /// The simulation refused the region or time.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// Malformed input (camera, size, layer, ...).
    #[error("{0}")]
    BadRequest(String),
    /// Well-formed but over the configured limits.
    #[error("{0}")]
    TooMuchWork(String),
}

/// A camera, image size or sun that [`Camera::parse`], [`Camera::new`],
/// [`scene::parse_size`] or [`Sun::parse`] refuses. The messages go to users as they
/// are (HTTP 400 messages, CLI errors), so each names the expected form or range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParseError {
    /// Not six comma-separated finite numbers.
    #[error("camera must be six finite numbers X,Y,Z,YAW,PITCH,FOV, got `{0}`")]
    CameraSyntax(String),
    /// A coordinate beyond ±[`camera::MAX_CAMERA_COORD`] (or not finite).
    #[error("camera position must be finite and within ±1e12 metres")]
    CameraPosition,
    /// Pitch outside [-90, 90] degrees.
    #[error("camera pitch must be within [-90, 90] degrees, got {0}")]
    CameraPitch(f64),
    /// Field of view outside [1, 170] degrees.
    #[error("camera field of view must be within [1, 170] degrees, got {0}")]
    CameraFov(f64),
    /// A yaw that is not finite.
    #[error("camera yaw must be finite")]
    CameraYaw,
    /// Not `WxH` with two positive integers.
    #[error("size must be WxH with positive integers, got `{0}`")]
    Size(String),
    /// Not two comma-separated numbers.
    #[error("sun must be AZ,EL in degrees, got `{0}`")]
    SunSyntax(String),
    /// An azimuth that is not finite or an elevation outside [-90, 90] degrees.
    #[error("sun must have a finite azimuth and an elevation within [-90, 90], got `{0}`")]
    SunRange(String),
}

/// Quality presets: how finely clouds are sampled and shaded. `Reference` renders with
/// the path tracer (every order of scattering, [`pathtrace`]), `ReferenceSingle` with
/// the single-scattering ray marcher ([`march`]); the billboard products of both are
/// those of `Accurate`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Quality {
    Fast,
    Balanced,
    Accurate,
    Reference,
    ReferenceSingle,
}

/// What a preset selects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QualitySettings {
    /// Metaball spacing, in columns of the tile's level.
    pub spacing_columns: f64,
    /// Metaball radius as a multiple of the spacing.
    pub radius_factor: f64,
    /// Number of splats in the sheet and their side in texels.
    pub splat_count: usize,
    pub splat_size: usize,
    /// Light-buffer texel, in metaball radii (finer = sharper self-shadowing).
    pub light_texel: f64,
    /// Level choice: a tile is split into finer tiles while one of its columns would
    /// cover more than this many pixels on screen.
    pub lod_pixels: f64,
    /// Ray-marcher view step, in cell heights (used by `ReferenceSingle`).
    pub march_step_cells: f64,
}

impl Quality {
    pub const ALL: [Quality; 5] = [
        Quality::Fast,
        Quality::Balanced,
        Quality::Accurate,
        Quality::Reference,
        Quality::ReferenceSingle,
    ];

    /// Whether this preset renders the density volume (path tracer or marcher) rather
    /// than billboards.
    pub fn is_volumetric(&self) -> bool {
        matches!(self, Quality::Reference | Quality::ReferenceSingle)
    }

    pub fn parse(s: &str) -> Option<Quality> {
        match s {
            "fast" => Some(Quality::Fast),
            "balanced" => Some(Quality::Balanced),
            "accurate" => Some(Quality::Accurate),
            "reference" => Some(Quality::Reference),
            "reference-single" => Some(Quality::ReferenceSingle),
            _ => None,
        }
    }

    pub fn as_str(&self) -> &'static str {
        match self {
            Quality::Fast => "fast",
            Quality::Balanced => "balanced",
            Quality::Accurate => "accurate",
            Quality::Reference => "reference",
            Quality::ReferenceSingle => "reference-single",
        }
    }

    pub fn settings(&self) -> QualitySettings {
        match self {
            Quality::Fast => QualitySettings {
                spacing_columns: 4.0,
                radius_factor: 1.25,
                splat_count: 64,
                splat_size: 17,
                light_texel: 0.5,
                lod_pixels: 8.0,
                march_step_cells: 0.5,
            },
            Quality::Balanced => QualitySettings {
                spacing_columns: 2.0,
                radius_factor: 1.25,
                splat_count: 128,
                splat_size: 33,
                light_texel: 0.4,
                lod_pixels: 4.0,
                march_step_cells: 0.5,
            },
            Quality::Accurate | Quality::Reference | Quality::ReferenceSingle => QualitySettings {
                spacing_columns: 1.0,
                radius_factor: 1.5,
                splat_count: 256,
                splat_size: 65,
                light_texel: 0.33,
                lod_pixels: 2.0,
                march_step_cells: 0.25,
            },
        }
    }

    /// The splat sheet of this preset.
    pub fn splat_sheet(&self) -> splats::SplatSheet {
        let s = self.settings();
        splats::SplatSheet::new(s.splat_count, s.splat_size)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quality_round_trips() {
        for q in Quality::ALL {
            assert_eq!(Quality::parse(q.as_str()), Some(q));
        }
        assert_eq!(Quality::parse("ultra"), None);
        // Finer presets sample more finely.
        let (f, b, a) = (
            Quality::Fast.settings(),
            Quality::Balanced.settings(),
            Quality::Accurate.settings(),
        );
        assert!(f.spacing_columns > b.spacing_columns && b.spacing_columns > a.spacing_columns);
        assert!(f.splat_size < b.splat_size && b.splat_size < a.splat_size);
    }
}
