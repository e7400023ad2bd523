//! Typed path extractors, rejected with [`ApiError`] so that a malformed path gets
//! our error shape rather than the framework's, and the world and layer lookups that
//! every handler shares.

use std::sync::Arc;

use axum::extract::rejection::PathRejection;
use axum::extract::{FromRequestParts, Path};
use axum::http::HeaderMap;
use axum::http::request::Parts;
use utoipa::openapi::RefOr;
use utoipa::openapi::schema::{ObjectBuilder, Schema, Type};

use cloudscape_core::products::Product;
use cloudscape_core::render::TileId;
use cloudscape_core::world::{Layer, World};

use crate::error::ApiError;
use crate::key::ResolvedWorld;
use crate::params::{Params, parse_level, parse_tile_coordinate};
use crate::state::AppState;

/// A rejected path (bad percent-encoding) in our error shape.
pub fn path_error(e: PathRejection) -> ApiError {
    ApiError::InvalidParameter {
        name: "path".to_string(),
        message: e.body_text(),
    }
}

/// The layer named `name`, or the world's first layer.
pub fn layer<'w>(world: &'w World, name: Option<&str>) -> Result<(usize, &'w Layer), ApiError> {
    world.layer(name).ok_or_else(|| ApiError::UnknownLayer {
        world: world.name.clone(),
        layer: name.unwrap_or("").chars().take(64).collect(),
    })
}

/// The layers a query at a point reads (`/sample`, EDR `position`).
pub struct PointLayers {
    /// The layer the point lies in: the one named, else the one whose altitude band
    /// holds z (none between or above the bands).
    pub holding: Option<usize>,
    /// The layers whose precipitation reaches the point, in configuration order: the
    /// one named, else every layer whose top is above z (what falls from a layer
    /// crosses all of it).
    pub above: Vec<usize>,
}

impl PointLayers {
    /// The layers of the point at altitude `z`, given the request's `layer=`.
    pub fn at(world: &World, name: Option<&str>, z: f64) -> Result<PointLayers, ApiError> {
        Ok(match name {
            Some(name) => {
                let (i, _) = layer(world, Some(name))?;
                PointLayers {
                    holding: Some(i),
                    above: vec![i],
                }
            }
            None => PointLayers {
                holding: world.layers.iter().position(|l| l.base <= z && z < l.top()),
                above: (0..world.layers.len()).filter(|&i| world.layers[i].top() > z).collect(),
            },
        })
    }

    /// The layer whose frame grid the answer follows: the one holding the point, else
    /// the first above it; `None` above every layer.
    pub fn primary(&self) -> Option<usize> {
        self.holding.or(self.above.first().copied())
    }
}

/// `/v1/worlds/{world}…`: the world, resolved.
pub struct WorldPath(pub ResolvedWorld);

impl FromRequestParts<Arc<AppState>> for WorldPath {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, s: &Arc<AppState>) -> Result<Self, ApiError> {
        let Path(name) = Path::<String>::from_request_parts(parts, s).await.map_err(path_error)?;
        Ok(WorldPath(s.worlds.resolve(&name)?))
    }
}

/// What a query on one world arrives with: the state, its query parameters, the world
/// of its path and its headers. Extracted in that order, so a malformed query is
/// refused before the world is looked up.
pub struct WorldQuery {
    pub s: Arc<AppState>,
    pub params: Params,
    pub resolved: ResolvedWorld,
    pub headers: HeaderMap,
}

impl FromRequestParts<Arc<AppState>> for WorldQuery {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, s: &Arc<AppState>) -> Result<Self, ApiError> {
        let params = Params::from_request_parts(parts, s).await?;
        let WorldPath(resolved) = WorldPath::from_request_parts(parts, s).await?;
        let (s, headers) = (Arc::clone(s), parts.headers.clone());
        Ok(WorldQuery {
            s,
            params,
            resolved,
            headers,
        })
    }
}

/// `/v1/worlds/{world}/tiles/{z}/{x}/{y}/{product}`, checked in that order. The
/// segments are taken as text and parsed here, so a malformed one gets its own error
/// code: a level beyond `limits.max_level` or a coordinate beyond 64 bits is out of
/// range (422), anything else not a number is malformed (400).
pub struct TilePath {
    pub world: ResolvedWorld,
    pub tile: TileId,
    pub product: Product,
}

impl FromRequestParts<Arc<AppState>> for TilePath {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, s: &Arc<AppState>) -> Result<Self, ApiError> {
        TilePath::parse(parts, s, parse_level).await
    }
}

impl TilePath {
    /// The path's segments `{world}/…/{z}/{x}/{y}/{product}`, checked in that order;
    /// `level` reads the level segment given `limits.max_level` (a level, or a zoom).
    pub async fn parse(
        parts: &mut Parts,
        s: &Arc<AppState>,
        level: impl FnOnce(&str, u32) -> Result<u32, ApiError>,
    ) -> Result<TilePath, ApiError> {
        let Path((world, z, x, y, product)) =
            Path::<(String, String, String, String, String)>::from_request_parts(parts, s)
                .await
                .map_err(path_error)?;
        let world = s.worlds.resolve(&world)?;
        let product = parse_product(&product)?;
        let z = level(&z, s.worlds.config().limits.max_level)?;
        let x = parse_tile_coordinate("x", &x)?;
        let y = parse_tile_coordinate("y", &y)?;
        Ok(TilePath {
            world,
            tile: TileId { z, x, y },
            product,
        })
    }
}

/// A tile product by URL name.
pub fn parse_product(name: &str) -> Result<Product, ApiError> {
    Product::parse(name).ok_or_else(|| ApiError::UnknownProduct(name.chars().take(64).collect()))
}

/// The tile products, as the OpenAPI document lists them: the URL names of
/// [`Product::ALL`].
pub struct TileProduct;

impl utoipa::PartialSchema for TileProduct {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .description(Some(
                "The tile products: the URL names of the product catalogue (cloudscape-core's `Product::ALL`).",
            ))
            .enum_values(Some(Product::ALL.map(Product::name)))
            .into()
    }
}

impl utoipa::ToSchema for TileProduct {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_products_are_refused_by_name() {
        for p in Product::ALL {
            assert_eq!(parse_product(p.name()).unwrap(), p);
        }
        assert!(matches!(parse_product("density.png"), Err(ApiError::UnknownProduct(_))));
    }
}
