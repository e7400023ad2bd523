//! `GET /v1/worlds/{world}/lightning?bbox=&t0=&t1=`: the strikes of
//! `cloudscape_core::weather::lightning` in a box and span ([`StrikeQuery`], which the
//! EDR items query answers too).

use axum::response::Response;
use serde::Serialize;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::{self, Work};
use cloudscape_core::weather::lightning::{self, LightningLimits, LightningPlan, Strike};
use cloudscape_core::world::World;

use crate::annotations::ComputedResponses;
use crate::error::ApiError;
use crate::extract::{WorldQuery, layer};
use crate::key::{CacheKey, ResolvedWorld};
use crate::queries::json_bytes;
use crate::respond::Cached;

/// The strikes of some layers of a world in a box and span, checked and laid out
/// before any work.
pub struct StrikeQuery {
    /// The layers and their flash cells.
    plans: Vec<(usize, LightningPlan)>,
    /// Metres, half-open: x0 <= x < x1, y0 <= y < y1.
    pub bbox: [f64; 4],
    /// Seconds, half-open: t0 <= t < t1.
    pub t0: f64,
    pub t1: f64,
}

impl StrikeQuery {
    /// The strikes of the layer named, else of every layer whose preset has lightning.
    /// Every check (span, box, coordinates) before any work; a world without lightning
    /// still has its query checked.
    pub fn new(world: &World, name: Option<&str>, bbox: [f64; 4], t0: f64, t1: f64) -> Result<Self, ApiError> {
        let layers: Vec<usize> = match name {
            Some(name) => vec![layer(world, Some(name))?.0],
            None => (0..world.layers.len())
                .filter(|&i| world.layers[i].preset.makes_lightning())
                .collect(),
        };
        let limits = LightningLimits::default();
        let plans = layers
            .iter()
            .map(|&i| LightningPlan::new(world, i, bbox, t0, t1, &limits).map(|p| (i, p)))
            .collect::<Result<Vec<_>, _>>()?;
        if plans.is_empty() {
            LightningPlan::new(world, 0, bbox, t0, t1, &limits)?;
        }
        Ok(StrikeQuery { plans, bbox, t0, t1 })
    }

    /// The cache key of an answer of `kind` listing these strikes.
    pub fn key(&self, kind: &str, resolved: &ResolvedWorld) -> CacheKey {
        let b = self.bbox;
        CacheKey::naming(kind, resolved, 0)
            .with("b", format!("{},{},{},{}", b[0], b[1], b[2], b[3]))
            .with("t", format!("{},{}", self.t0, self.t1))
            .with(
                "l",
                self.plans
                    .iter()
                    .map(|(i, _)| i.to_string())
                    .collect::<Vec<_>>()
                    .join(","),
            )
    }

    /// The layers whose strikes are listed, by name.
    pub fn layer_names(&self, world: &World) -> Vec<String> {
        self.plans.iter().map(|(i, _)| world.layers[*i].name.clone()).collect()
    }

    /// The estimated work: the flash-cell density of every bucket.
    pub fn work(&self, world: &World) -> Result<Work, ApiError> {
        let mut work = Work::default();
        for (i, p) in &self.plans {
            for b in 0..p.buckets {
                let w = cost::density(world, *i, lightning::FLASH_LEVEL, p.region, p.bucket_time(b))?;
                work.cpu_s += w.cpu_s;
                work.bytes = work.bytes.max(w.bytes);
            }
        }
        Ok(work)
    }

    /// The strikes with their layer's index, by time (then x, then y).
    pub fn strikes(&self, world: &World, cancel: &Cancel) -> Result<Vec<(usize, Strike)>, ApiError> {
        let mut strikes = Vec::new();
        for (i, p) in &self.plans {
            cancel.check().map_err(|_| ApiError::Cancelled)?;
            let found = lightning::strikes(world, *i, self.bbox, self.t0, self.t1, p)?;
            strikes.extend(found.into_iter().map(|s| (*i, s)));
        }
        strikes.sort_by(|(_, a), (_, b)| a.t.total_cmp(&b.t).then(a.x.total_cmp(&b.x)).then(a.y.total_cmp(&b.y)));
        Ok(strikes)
    }
}

/// `/lightning`: the strikes in a box and span.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct LightningAnswer {
    pub world: String,
    /// The bbox asked for, metres (half-open: x0 <= x < x1, y0 <= y < y1).
    pub bbox: [f64; 4],
    /// The span asked for, seconds (half-open: t0 <= t < t1).
    pub t0: f64,
    pub t1: f64,
    /// The layers whose strikes are listed (those whose preset has lightning, or the
    /// one asked for).
    pub layers: Vec<String>,
    /// The strikes, by time.
    pub strikes: Vec<Strike>,
}

/// The lightning strikes in a box and span.
///
/// 400: Malformed parameter, inverted bbox or t1 <= t0. 413: Span over 3600 s or bbox
/// side over 50 km (checked before any work). 422: Times or coordinates out of range.
#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/lightning",
    tag = "queries",
    params(
        ("world" = String, Path, description = "Configured world name, or a decimal u64 seed", example = "storm-front"),
        ("bbox" = String, Query, description = "X0,Y0,X1,Y1 in metres, X0 < X1, Y0 < Y1, each side at most 50 km; strikes with x0 <= x < x1, y0 <= y < y1", example = "-10000,20000,10000,40000"),
        ("t0" = f64, Query, description = "Start of the span, seconds (inclusive)", example = 0),
        ("t1" = f64, Query, description = "End of the span, seconds (exclusive), t0 < t1 <= t0 + 3600", example = 600),
        ("layer" = Option<String>, Query, description = "Layer name (default: every layer whose preset has lightning)"),
    ),
    responses(
        (status = 200, body = LightningAnswer, description = "Strikes (t, x, y, z, kind cg|ic) by time. A deterministic counter-based point process: the strikes of a box are the union of those of its halves; cloud-to-ground strikes have z = 0 (the ground contact), intra-cloud ones z inside the cloud"),
        ComputedResponses,
    )
)]
pub async fn lightning(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    let bbox = params.bbox()?;
    let (t0, t1) = (params.time("t0")?, params.time("t1")?);
    let query = StrikeQuery::new(&resolved.world, params.get("layer"), bbox, t0, t1)?;
    let cached = Cached::timeless("lightning", query.key("lightning", &resolved), "application/json");
    let world = resolved.world;
    cached
        .respond(&s, &headers, move || {
            Ok((query.work(&world)?, move |cancel: &Cancel| {
                let answer = LightningAnswer {
                    world: world.name.clone(),
                    bbox,
                    t0,
                    t1,
                    layers: query.layer_names(&world),
                    strikes: query.strikes(&world, cancel)?.into_iter().map(|(_, s)| s).collect(),
                };
                json_bytes(&answer)
            }))
        })
        .await
}
