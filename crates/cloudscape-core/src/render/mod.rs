//! From density to light: splats, sun shading, billboards, and the renderers: the
//! billboard compositor a client would use, the reference path tracer, and the
//! single-scattering ray marcher.
//!
//! # What the HTTP service calls
//!
//! Presets and suns parse from their query strings. Every sun in one bucket
//! (about 8° wide, 1° near the horizon) is shaded as the bucket's centre, so the
//! bucket's id is the cache-key part:
//!
//! ```rust
//! use cloudscape_core::render::{Quality, Sun};
//!
//! let q = Quality::parse("balanced").unwrap();
//! assert_eq!(q.as_str(), "balanced");
//! assert!(Quality::parse("reference").unwrap().is_volumetric());
//!
//! let sun = Sun::parse("135,40").unwrap();
//! assert_eq!(sun.bucket(), Sun::parse("135.2,40.2").unwrap().bucket());
//! assert_eq!(sun.bucket().centre().bucket(), sun.bucket());
//! assert!(Sun::parse("135,95").is_err());
//! let _id: String = sun.bucket().id();
//!
//! // Without a sun in the request, the world clock's: solar time at the
//! // configured latitude and day.
//! let config = cloudscape_core::world::Config::embedded();
//! assert!(Sun::from_clock(12.0 * 3600.0, &config.sun).elevation_deg > 0.0);
//! assert!(Sun::from_clock(0.0, &config.sun).elevation_deg < 0.0);
//! ```
//!
//! A tile product shades a tile's density and metaballs once per keyframe span
//! ([`shade_tile`], both ends of the span); every product of that tile encodes the
//! same [`ShadedTile`], and [`keyframe`]'s rule draws it at any time in the span
//! (not run here: a tile takes seconds in a debug build):
//!
//! ```rust,no_run
//! use cloudscape_core::products::billboards;
//! use cloudscape_core::cancel::Cancel;
//! use cloudscape_core::render::{Quality, ShadingParams, Sun, TileId, shade_tile};
//! use cloudscape_core::world::{Config, Keyframe};
//!
//! let config = Config::embedded();
//! let world = config.world("default").unwrap();
//! let tile = TileId { z: 0, x: 0, y: 0 };
//! let sun = Sun::parse("135,40").unwrap();
//! let span = Keyframe::containing(1234.5, &world.layers[0], tile.z); // [1220, 1240)
//! let shaded = shade_tile(&world, 0, tile, span, Quality::Fast, sun, &ShadingParams::default(), &config.limits, &Cancel::never()).unwrap();
//! let bytes = billboards::encode_bin(&shaded); // billboards.bin
//! let decoded = billboards::decode_bin(&bytes).unwrap();
//! assert_eq!(decoded.records.len(), shaded.billboards.len());
//! let drawn = shaded.billboards_at(1234.5); // what a client draws at t = 1234.5
//! assert_eq!(drawn.len(), shaded.billboards.len());
//! ```
//!
//! `cloudscape render` and `GET /render.png` render a camera view with
//! [`crate::view::render`] (which draws the billboards as a client draws them once
//! served). From above every layer, looking up, the view holds no tile and only the
//! sky is drawn:
//!
//! ```rust
//! use cloudscape_core::render::{Camera, Quality, RenderRequest, ShadingParams, scene};
//! use cloudscape_core::view::render;
//! use cloudscape_core::world::Config;
//!
//! let config = Config::embedded();
//! let world = config.world("default").unwrap();
//! let (width, height) = scene::parse_size("32x18").unwrap();
//! let req = RenderRequest {
//!     camera: Camera::parse("0,0,30000,0,89,60").unwrap(),
//!     width,
//!     height,
//!     t: 0.0,
//!     quality: Quality::Fast,
//!     sun: None, // the world clock's sun at `t`
//!     params: ShadingParams::default(),
//!     samples: 1,
//! };
//! let rendered = render(&world, &config, &req).unwrap();
//! assert_eq!((rendered.image.width, rendered.image.height), (32, 18));
//! assert!(rendered.tiles.is_empty() && rendered.billboards == 0);
//! assert!(rendered.noise.is_none()); // only `reference` estimates its noise
//! let _png: Vec<u8> = rendered.image.to_png();
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
pub mod keyframe;
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
pub use scene::{RenderRequest, Rendered};
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
    /// Coarse metaballs and small splats: the quickest preset.
    Fast,
    /// Twice the metaball density of `fast`.
    Balanced,
    /// One metaball per column and the largest splats.
    Accurate,
    /// The path tracer (every order of scattering); billboards as `accurate`.
    Reference,
    /// The single-scattering ray marcher; billboards as `accurate`.
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
    /// Side of one splat sprite, texels.
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
    /// Every preset, fastest first.
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

    /// The preset named `s` (its query-string name), if any.
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

    /// The preset's query-string name.
    pub fn as_str(&self) -> &'static str {
        match self {
            Quality::Fast => "fast",
            Quality::Balanced => "balanced",
            Quality::Accurate => "accurate",
            Quality::Reference => "reference",
            Quality::ReferenceSingle => "reference-single",
        }
    }

    /// What the preset selects.
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

    /// The preset's billboard light, fitted to the path tracer (`--quality
    /// reference`) by `examples/calibrate_scattering.rs` on the four scenes of
    /// `bench::quality::SCENES` (figures and commands in BENCHMARKS.md, "Presets'
    /// light and edges").
    ///
    /// The form is Wrenninge's scattering octaves for the sun (Wrenninge, Kulla &
    /// Lundqvist 2013; as used by Hillaire 2016 §5.1.4 and Schneider's Nubis, see
    /// [`light::Octaves`]) plus sky and ground light attenuated at diffusion theory's
    /// rate ([`light::ShadingParams::diffusion_attenuation`], scale 1), not a table
    /// fitted to the path tracer: three constants per preset that keep an energy
    /// bound (`a ≤ b`) and a physical reading, shipped in every keyframe's header so
    /// a client applies the same phase per octave. The sky half of the sphere is lit
    /// by the upper hemisphere's own radiance (`sky_ambient_above`), which is what
    /// brings thick cloud to the path tracer's bluish grey.
    ///
    /// Per preset: `balanced` and `accurate` take the literature's a = c = ½ with
    /// b = ¾; `fast`'s balls are four columns apart and its self-shadowing coarser,
    /// so its deep cloud took too much of the higher octaves (a stratus deck from
    /// below 1.41–1.76× the reference in τ > 2): its octaves fade faster with depth,
    /// a = 0.65 (still `a ≤ b`). Detail erosion 0.3
    /// (was 0.6 everywhere): at 0.6 `accurate` ate 7–9 % of the reference's cloud
    /// pixels on cumulus and altocumulus. The splat opacity is the density's own
    /// (scale 1) in every preset: a larger scale brings `fast`'s thin altocumulus
    /// back but inflates its cumulus by as much.
    pub fn light(&self) -> light::BillboardLight {
        let preset = |attenuation: f64| light::BillboardLight {
            octaves: light::Octaves {
                count: 3,
                attenuation,
                contribution: 0.75,
                eccentricity: 0.5,
            },
            sky_extinction_scale: 1.0,
            detail_erosion: 0.3,
            opacity_scale: 1.0,
        };
        match self {
            Quality::Fast => preset(0.65),
            Quality::Balanced | Quality::Accurate | Quality::Reference | Quality::ReferenceSingle => preset(0.5),
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
