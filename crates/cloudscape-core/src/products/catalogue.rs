//! The tile products: one table that names each product, gives its content type, says
//! what it is encoded from and holds its encoder. The server routes, documents, keys
//! and computes tiles through it; the soak generator and the client name products
//! through it. Adding a product is its encoder's file, one arm of [`Product::spec`]
//! and its place in [`Product::ALL`].

use crate::density::Grid;
use crate::render::ShadedTile;
use crate::world::Layer;

use super::atlas::{self, Atlas};
use super::grid::{GridFormat, encode_density};
use super::keyframe_bin::{self, Form, Quantisation};
use super::{billboards, coverage, ktx2, precipitation, shadow};

/// What a tile URL can ask for (`/tiles/{z}/{x}/{y}/{product}`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Product {
    /// `density.npy`: the density grid as a NumPy array (f32, `(depth, 256, 256)`).
    DensityNpy,
    /// `density.f32`: the same grid, raw little-endian f32.
    DensityF32,
    /// `density.u8`: the same grid, density × 255 rounded.
    DensityU8,
    /// `density.ktx2`: the `density.u8` bytes as a KTX 2.0 R8 3D texture.
    DensityKtx2,
    /// `coverage.png`: cloud cover, base and top per column.
    CoveragePng,
    /// `billboards.json`: the shaded billboards as JSON.
    BillboardsJson,
    /// `billboards.bin`: one keyframe of the shaded billboards, quantised and coded
    /// (version 3, self-contained: what a client's first view of a tile fetches).
    BillboardsBin,
    /// `billboards.delta.bin`: the same keyframe coded on the tile's previous one
    /// (version 3, delta form): what a client holding the previous keyframe fetches.
    BillboardsDelta,
    /// `billboards.v2.bin`: the same billboards in version 2's 56-byte records, both
    /// ends at full precision (kept for clients of version 2 until the next version).
    BillboardsV2,
    /// `atlas.png`: the billboards' impostors.
    AtlasPng,
    /// `atlas.json`: the atlas manifest.
    AtlasJson,
    /// `shadow.png`: ground shadow transmittance.
    ShadowPng,
    /// `precipitation.png`: rate, kind and streak top per column.
    PrecipitationPng,
}

/// How a product's bytes are made from a computed tile.
#[derive(Clone, Copy)]
pub enum Encoder {
    /// From the tile's density grid (`(depth, 256, 256)` at the tile's level) and its layer.
    Grid(fn(&Layer, &Grid<f32>) -> Vec<u8>),
    /// From the shaded tile, which depends on a quality and a sun bucket. Shading is the
    /// expensive part, so a shaded tile is encoded into every product that is cheap
    /// once it is shaded, besides the one asked for ([`encode_shaded`]).
    Shaded(fn(&mut ShadedProducts<'_>) -> Vec<u8>),
}

/// When a shaded product is encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Whenever its tile is shaded: a few milliseconds or less (`billboards.bin` and its
    /// delta form), so a client's first view and its next keyframes cause one shading.
    Eager,
    /// Only when asked for: as long as the shading or longer (`billboards.json`, the
    /// atlas, whose two halves come from one build).
    OnRequest,
    /// Not a shaded product.
    Grid,
}

/// One row of the catalogue.
#[derive(Clone, Copy)]
pub struct Spec {
    /// The URL name, `{stem}.{extension}`.
    pub name: &'static str,
    /// The `Content-Type` it is served with.
    pub content_type: &'static str,
    /// The family whose work and metrics the product is counted under.
    pub family: &'static str,
    /// How its bytes are made.
    pub encoder: Encoder,
}

const OCTETS: &str = "application/octet-stream";
const PNG: &str = "image/png";
const JSON: &str = "application/json";
/// KTX 2.0's registered media type (Khronos, IANA `image/ktx2`).
const KTX2: &str = "image/ktx2";

impl Product {
    /// Every tile product, in the order the API lists them.
    pub const ALL: [Product; 13] = [
        Product::DensityNpy,
        Product::DensityF32,
        Product::DensityU8,
        Product::DensityKtx2,
        Product::CoveragePng,
        Product::BillboardsJson,
        Product::BillboardsBin,
        Product::BillboardsDelta,
        Product::BillboardsV2,
        Product::AtlasPng,
        Product::AtlasJson,
        Product::ShadowPng,
        Product::PrecipitationPng,
    ];

    /// The product's row of the catalogue.
    pub fn spec(self) -> Spec {
        let (name, content_type, family, encoder) = match self {
            Product::DensityNpy => (
                "density.npy",
                OCTETS,
                "tile_density",
                Encoder::Grid(|_, g| encode_density(g, GridFormat::Npy)),
            ),
            Product::DensityF32 => (
                "density.f32",
                OCTETS,
                "tile_density",
                Encoder::Grid(|_, g| encode_density(g, GridFormat::F32)),
            ),
            Product::DensityU8 => (
                "density.u8",
                OCTETS,
                "tile_density",
                Encoder::Grid(|_, g| encode_density(g, GridFormat::U8)),
            ),
            Product::DensityKtx2 => (
                "density.ktx2",
                KTX2,
                "tile_density",
                Encoder::Grid(|_, g| ktx2::encode_density_ktx2(g)),
            ),
            Product::CoveragePng => (
                "coverage.png",
                PNG,
                "tile_coverage",
                Encoder::Grid(|l, g| coverage::encode_png_from_grid(l, g, 0)),
            ),
            Product::BillboardsJson => (
                "billboards.json",
                JSON,
                "tile_shaded",
                Encoder::Shaded(|s| billboards::encode_json_within(s.tile, s.max_json_bytes)),
            ),
            Product::BillboardsBin => (
                "billboards.bin",
                OCTETS,
                "tile_shaded",
                Encoder::Shaded(|s| keyframe_bin::encode(s.tile, Form::SelfContained, Quantisation::DEFAULT)),
            ),
            Product::BillboardsDelta => (
                "billboards.delta.bin",
                OCTETS,
                "tile_shaded",
                Encoder::Shaded(|s| {
                    let form = if s.previous_lit_alike {
                        Form::Delta
                    } else {
                        Form::SelfContained
                    };
                    keyframe_bin::encode(s.tile, form, Quantisation::DEFAULT)
                }),
            ),
            Product::BillboardsV2 => (
                "billboards.v2.bin",
                OCTETS,
                "tile_shaded",
                Encoder::Shaded(|s| billboards::encode_bin(s.tile)),
            ),
            Product::AtlasPng => (
                "atlas.png",
                PNG,
                "tile_shaded",
                Encoder::Shaded(|s| std::mem::take(&mut s.atlas().png)),
            ),
            Product::AtlasJson => (
                "atlas.json",
                JSON,
                "tile_shaded",
                Encoder::Shaded(|s| std::mem::take(&mut s.atlas().manifest)),
            ),
            Product::ShadowPng => (
                "shadow.png",
                PNG,
                "tile_shaded",
                Encoder::Shaded(|s| shadow::encode_png_map(s.tile)),
            ),
            Product::PrecipitationPng => (
                "precipitation.png",
                PNG,
                "tile_precipitation",
                Encoder::Grid(precipitation::encode_png),
            ),
        };
        Spec {
            name,
            content_type,
            family,
            encoder,
        }
    }

    /// The URL name (`density.npy`, …).
    pub fn name(self) -> &'static str {
        self.spec().name
    }

    /// The `Content-Type` it is served with.
    pub fn content_type(self) -> &'static str {
        self.spec().content_type
    }

    /// The family its work and metrics are counted under.
    pub fn family(self) -> &'static str {
        self.spec().family
    }

    /// True when the product is encoded from the shaded tile (so depends on a
    /// quality and a sun bucket).
    pub fn needs_shading(self) -> bool {
        matches!(self.spec().encoder, Encoder::Shaded(_))
    }

    /// The product whose URL name is `name`.
    pub fn parse(name: &str) -> Option<Product> {
        Product::ALL.into_iter().find(|p| p.name() == name)
    }

    /// The bytes of a product encoded from the density grid, or `None` for a shaded one.
    pub fn encode_grid(self, layer: &Layer, grid: &Grid<f32>) -> Option<Vec<u8>> {
        match self.spec().encoder {
            Encoder::Grid(encode) => Some(encode(layer, grid)),
            Encoder::Shaded(_) => None,
        }
    }
}

/// A shaded tile being encoded into its products.
pub struct ShadedProducts<'a> {
    /// The shaded tile.
    pub tile: &'a ShadedTile,
    /// `billboards.json` over this many bytes is encoded as no bytes
    /// ([`billboards::encode_json_within`]).
    pub max_json_bytes: u64,
    /// Whether the tile's previous keyframe was shaded with the same light (quality and
    /// sun bucket): only then does `billboards.delta.bin` code this one on it (else it
    /// is the self-contained form).
    pub previous_lit_alike: bool,
    /// Built on first use: `atlas.png` and `atlas.json` share it, each taking its part.
    atlas: Option<Atlas>,
}

impl ShadedProducts<'_> {
    fn atlas(&mut self) -> &mut Atlas {
        let tile = self.tile;
        self.atlas.get_or_insert_with(|| atlas::build(tile))
    }
}

impl Product {
    /// When the product is encoded from its shaded tile.
    pub fn encoding(self) -> Encoding {
        match self {
            Product::BillboardsBin | Product::BillboardsDelta => Encoding::Eager,
            Product::BillboardsJson
            | Product::BillboardsV2
            | Product::ShadowPng
            | Product::AtlasPng
            | Product::AtlasJson => Encoding::OnRequest,
            _ => Encoding::Grid,
        }
    }

    /// True when `self` and `other` come from one piece of work (the atlas's image
    /// and manifest), so asking for one encodes both.
    pub fn shares_work_with(self, other: Product) -> bool {
        let atlas = |p| matches!(p, Product::AtlasPng | Product::AtlasJson);
        self == other || (atlas(self) && atlas(other))
    }
}

/// The shaded products of `tile` that are worth encoding when `wanted` is asked for:
/// `wanted`, what shares its work, and every [`Encoding::Eager`] product, in
/// [`Product::ALL`] order. `previous_lit_alike`: see [`ShadedProducts`].
pub fn encode_shaded(
    tile: &ShadedTile,
    max_json_bytes: u64,
    previous_lit_alike: bool,
    wanted: Product,
) -> Vec<(Product, Vec<u8>)> {
    let mut products = ShadedProducts {
        tile,
        max_json_bytes,
        previous_lit_alike,
        atlas: None,
    };
    Product::ALL
        .into_iter()
        .filter(|p| p.encoding() == Encoding::Eager || p.shares_work_with(wanted))
        .filter_map(|p| match p.spec().encoder {
            Encoder::Shaded(encode) => Some((p, encode(&mut products))),
            Encoder::Grid(_) => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn products_round_trip_their_names() {
        for p in Product::ALL {
            assert_eq!(Product::parse(p.name()), Some(p));
        }
        assert_eq!(Product::parse("density.png"), None);
        let mut names: Vec<_> = Product::ALL.iter().map(|p| p.name()).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), Product::ALL.len(), "names are unique");
    }

    #[test]
    fn shaded_products_are_those_encoded_from_the_shaded_tile() {
        let shaded: Vec<_> = Product::ALL.into_iter().filter(|p| p.needs_shading()).collect();
        assert_eq!(
            shaded,
            [
                Product::BillboardsJson,
                Product::BillboardsBin,
                Product::BillboardsDelta,
                Product::BillboardsV2,
                Product::AtlasPng,
                Product::AtlasJson,
                Product::ShadowPng
            ]
        );
        for p in Product::ALL {
            assert_eq!(p.needs_shading(), p.family() == "tile_shaded", "{}", p.name());
            assert_eq!(p.needs_shading(), p.encoding() != Encoding::Grid, "{}", p.name());
        }
    }

    #[test]
    fn a_shaded_tile_is_encoded_into_what_was_asked_and_the_cheap_products() {
        use crate::render::tile::shade_density;
        use crate::render::{Quality, ShadingParams, Sun, TileId};
        let config = crate::world::Config::embedded();
        let layer = &config.worlds["default"].layers[0];
        let mut grid = Grid::new(layer.depth as usize, 260, 260);
        grid.data
            .iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = if i % 7 == 0 { 0.6 } else { 0.0 });
        let tile = TileId { z: 0, x: 0, y: 0 };
        let sun = Sun::new(100.0, 40.0).unwrap();
        let shaded = shade_density(
            0,
            layer,
            tile,
            0.0,
            Quality::Fast,
            sun,
            &ShadingParams::default(),
            grid,
            2,
        );
        let names = |wanted| {
            encode_shaded(&shaded, u64::MAX, true, wanted)
                .into_iter()
                .map(|(p, _)| p.name())
                .collect::<Vec<_>>()
        };
        assert_eq!(
            names(Product::ShadowPng),
            ["billboards.bin", "billboards.delta.bin", "shadow.png"]
        );
        assert_eq!(
            names(Product::BillboardsJson),
            ["billboards.json", "billboards.bin", "billboards.delta.bin"]
        );
        assert_eq!(
            names(Product::AtlasJson),
            ["billboards.bin", "billboards.delta.bin", "atlas.png", "atlas.json"]
        );
    }
}
