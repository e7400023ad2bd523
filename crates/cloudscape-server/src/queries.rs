//! REST queries by region and time: `/sample`, `/region`, `/series` (with the
//! precipitation of `cloudscape_core::weather` beside the cloud statistics).
//!
//! They read the same density the tiles serve (same function, same canonical frames),
//! so a region's answer equals what is computed from the tiles it spans.

use axum::body::Bytes;
use axum::response::Response;
use rayon::prelude::*;
use serde::Serialize;

use cloudscape_core::cancel::Cancel;
use cloudscape_core::cost::{self, Work};
use cloudscape_core::density::{self, Cell, Region, RegionStats, region_stats};
use cloudscape_core::weather::{PrecipitationKind, PrecipitationStats, column_rate, kind_at, precipitation_stats};
use cloudscape_core::world::SnappedTime;

use crate::annotations::{ColumnLevel, ColumnsBbox, ComputedResponses, LayerName, WorldName};
use crate::error::ApiError;
use crate::extract::{PointLayers, WorldQuery, layer};
use crate::key::{CacheKey, stable_hash_hex};
use crate::respond::{Cached, Freshness, Representation, cache_control};

pub(crate) fn json_bytes(value: &impl Serialize) -> Result<Bytes, ApiError> {
    serde_json::to_vec(value)
        .map(Bytes::from)
        .map_err(|e| ApiError::Internal(e.to_string()))
}

/// The columns of a region, in the region's level.
#[derive(Clone, Debug, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Columns {
    /// First column (east index) at the level.
    pub x0: i64,
    /// First row (north index) at the level.
    pub y0: i64,
    pub cols: usize,
    pub rows: usize,
}

impl From<Region> for Columns {
    fn from(r: Region) -> Columns {
        Columns {
            x0: r.x0,
            y0: r.y0,
            cols: r.cols,
            rows: r.rows,
        }
    }
}

/// `/sample`: the density and cloud flag at a point.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct SampleAnswer {
    pub world: String,
    /// The layer the point lies in; `null` when no layer spans the altitude `z`.
    pub layer: Option<String>,
    /// The canonical frame time the answer was computed for, seconds.
    pub t: f64,
    pub frame: u64,
    /// Level-0 cell holding the point: [column, row, vertical level]; `null` outside every layer.
    pub cell: Option<[i64; 3]>,
    /// Density in [0, 1] of that cell (0 outside every layer).
    pub density: f32,
    /// The automaton's cloud bit of that cell.
    pub cloud: bool,
    /// Precipitation rate at the point, mm/h: the sum of the column rates
    /// (`weather::precipitation`) of the layers above it (of `layer` alone when the
    /// request names one), each at its level-0 column holding (x, y).
    pub precipitation_mm_h: f64,
    /// What falls at altitude z: `none` when the rate is 0, `snow` at or above the
    /// snow level (the world's freezing level − 300 m), else `rain`.
    #[schema(value_type = String, example = "rain")]
    pub precipitation_kind: PrecipitationKind,
}

/// `/region`: statistics of a region at one time.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct RegionAnswer {
    pub world: String,
    pub layer: String,
    pub level: u32,
    /// The canonical frame time the answer was computed for, seconds.
    pub t: f64,
    pub frame: u64,
    /// The columns whose centres lie inside the bbox.
    pub columns: Columns,
    #[serde(flatten)]
    pub stats: RegionStats,
    /// Precipitating fraction, mean and max rate of the region's columns.
    #[serde(flatten)]
    pub precipitation: PrecipitationStats,
}

/// One time point of a `/series`.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct SeriesPoint {
    /// The requested time.
    pub t: f64,
    /// The canonical frame time computed for it.
    pub frame_t: f64,
    pub frame: u64,
    #[serde(flatten)]
    pub stats: RegionStats,
    #[serde(flatten)]
    pub precipitation: PrecipitationStats,
}

/// `/series`: region statistics over time.
#[derive(Clone, Debug, Serialize, utoipa::ToSchema)]
pub struct SeriesAnswer {
    pub world: String,
    pub layer: String,
    pub level: u32,
    pub columns: Columns,
    pub points: Vec<SeriesPoint>,
}

/// The density, cloud flag and precipitation at a point.
///
/// 400: Malformed parameter. 413: Over the configured limits. 422: t or coordinates out
/// of range.
#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/sample",
    tag = "queries",
    params(
        WorldName,
        ("x" = f64, Query, description = "East, metres", example = 150),
        ("y" = f64, Query, description = "North, metres", example = 150),
        ("z" = f64, Query, description = "Altitude above sea level, metres", example = 1050),
        ("t" = f64, Query, description = "World time, seconds, 0 <= t <= 1e12 (snapped to the layer's frame grid)", example = 0),
        ("layer" = Option<String>, Query, description = "Layer name (default: the layer whose altitude band holds z)"),
    ),
    responses(
        (status = 200, body = SampleAnswer, description = "Density and cloud flag of the level-0 cell holding the point; precipitation rate (mm/h) and kind at the point"),
        ComputedResponses,
    )
)]
pub async fn sample(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    let (x, y, z) = (
        params.required_f64("x")?,
        params.required_f64("y")?,
        params.required_f64("z")?,
    );
    let t = params.time("t")?;
    let world = &resolved.world;
    let layers = PointLayers::at(world, params.get("layer"), z)?;
    let Some(primary) = layers.primary() else {
        // Above every layer: clear sky, nothing falls, nothing to compute.
        let frame = SnappedTime::snap(t, &world.layers[0], s.settings.frames_per_step);
        let answer = SampleAnswer {
            world: world.name.clone(),
            layer: None,
            t: frame.t,
            frame: frame.index,
            cell: None,
            density: 0.0,
            cloud: false,
            precipitation_mm_h: 0.0,
            precipitation_kind: PrecipitationKind::None,
        };
        let repr = Representation {
            etag: format!(
                "\"{}\"",
                stable_hash_hex(&serde_json::to_vec(&answer).unwrap_or_default())
            ),
            cache_control: cache_control(&s, Freshness::of_frames(frame.is_exact(t))),
            time: Some(frame.into()),
            content_location: None,
        };
        return Ok(repr
            .not_modified(&headers)
            .unwrap_or_else(|| repr.ok_small("application/json", json_bytes(&answer).unwrap_or_default())));
    };
    let limits = &s.worlds.config().limits;
    let fps = s.settings.frames_per_step;
    // Each falling layer's column at its own frame (layers differ in cell size and dt).
    let mut columns = Vec::with_capacity(layers.above.len());
    for &i in &layers.above {
        let l = &world.layers[i];
        let column = Cell::at(l, x, y, z)?;
        column.region().check(0, l.depth, limits)?;
        columns.push((i, column, SnappedTime::snap(t, l, fps)));
    }
    let layer = &world.layers[primary];
    let cell = Cell::at(layer, x, y, z)?;
    let region = cell.region();
    region.check(0, layer.depth, limits)?;
    let frame = SnappedTime::snap(t, layer, fps);
    let snow = kind_at(1.0, layer.freezing_level, z) == PrecipitationKind::Snow;
    let mut key = CacheKey::naming("sample", &resolved, primary)
        .with("c", cell.col)
        .with("r", cell.row)
        .with("k", cell.k)
        .with("f", frame.index)
        .with("in", layers.holding.is_some())
        .with("snow", snow);
    for (i, c, f) in &columns {
        key = key.with(&format!("p{i}"), format_args!("{},{},{}", c.col, c.row, f.index));
    }
    let mut cached = Cached::at("sample", key, "application/json", frame, t);
    if columns.iter().any(|(_, _, f)| !f.is_exact(t)) {
        cached.freshness = Freshness::Snapped;
    }
    let inside = layers.holding.is_some();
    let world = resolved.world;
    cached
        .respond(&s, &headers, move || {
            let mut work = cost::density(&world, primary, 0, region, frame.t)?;
            for (i, c, f) in &columns {
                let w = cost::density(&world, *i, 0, c.region(), f.t)?;
                work.cpu_s += w.cpu_s;
                work.bytes = work.bytes.saturating_add(w.bytes);
            }
            Ok((work, move |cancel: &Cancel| {
                let (mut density, mut cloud) = (0.0, false);
                if inside {
                    let d = density::density_cancellable(&world, primary, 0, region, frame.t, cancel)?;
                    let c = density::cloud_cells(&world, primary, region, frame.t)?;
                    density = d.get(cell.k, 0, 0);
                    cloud = c.get(cell.k, 0, 0) != 0;
                }
                // Layer by layer in configuration order, so the sum is reproducible.
                let mut rate = 0.0;
                for (i, c, f) in &columns {
                    let grid = density::density_cancellable(&world, *i, 0, c.region(), f.t, cancel)?;
                    rate += column_rate(&world.layers[*i], &grid, 0, 0);
                }
                let layer = &world.layers[primary];
                json_bytes(&SampleAnswer {
                    layer: inside.then(|| layer.name.clone()),
                    world: world.name.clone(),
                    t: frame.t,
                    frame: frame.index,
                    cell: inside.then_some([cell.col, cell.row, cell.k as i64]),
                    density,
                    cloud,
                    precipitation_mm_h: rate,
                    precipitation_kind: kind_at(rate, layer.freezing_level, z),
                })
            }))
        })
        .await
}

/// Cloud and precipitation statistics of a region at one time.
///
/// 400: Malformed parameter or inverted bbox. 413: bbox over the configured limits (use a
/// higher level). 422: t, level or coordinates out of range; empty region.
#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/region",
    tag = "queries",
    params(
        WorldName,
        ColumnsBbox,
        ("t" = f64, Query, description = "World time, seconds, 0 <= t <= 1e12 (snapped to the layer's frame grid)", example = 0),
        LayerName,
        ColumnLevel,
    ),
    responses(
        (status = 200, body = RegionAnswer, description = "Coverage fraction, mean/max density, cloud base/top, cluster count; precipitating fraction, mean and max precipitation rate (mm/h)"),
        ComputedResponses,
    )
)]
pub async fn region(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    let (layer_index, layer) = layer(&resolved.world, params.get("layer"))?;
    let limits = &s.worlds.config().limits;
    let bbox = params.bbox()?;
    let t = params.time("t")?;
    let level = params.level(limits.max_level)?;
    let region = Region::from_bbox(layer, level, bbox, limits)?;
    let frame = SnappedTime::snap(t, layer, s.settings.frames_per_step);
    let key = CacheKey::naming("region", &resolved, layer_index)
        .with_region(level, region)
        .with("f", frame.index);
    let world = resolved.world;
    let cached = Cached::at("region", key, "application/json", frame, t);
    cached
        .respond(&s, &headers, move || {
            let work = cost::density(&world, layer_index, level, region, frame.t)?;
            Ok((work, move |cancel: &Cancel| {
                let grid = density::density_cancellable(&world, layer_index, level, region, frame.t, cancel)?;
                let layer = &world.layers[layer_index];
                json_bytes(&RegionAnswer {
                    world: world.name.clone(),
                    layer: layer.name.clone(),
                    level,
                    t: frame.t,
                    frame: frame.index,
                    columns: region.into(),
                    stats: region_stats(&grid, layer),
                    precipitation: precipitation_stats(&grid, layer),
                })
            }))
        })
        .await
}

/// The `/region` statistics over a span of time.
///
/// 400: Malformed parameter, inverted bbox or t1 < t0. 413: bbox or number of points over
/// the configured limits. 422: Times, level or coordinates out of range.
#[utoipa::path(
    get,
    path = "/v1/worlds/{world}/series",
    tag = "queries",
    params(
        WorldName,
        ColumnsBbox,
        ("t0" = f64, Query, description = "First time, seconds", example = 0),
        ("t1" = f64, Query, description = "Last time (inclusive when on the step grid), seconds, t1 >= t0", example = 20),
        ("dt" = Option<f64>, Query, description = "Step between points, seconds, > 0 (default: the layer's dt)"),
        LayerName,
        ColumnLevel,
    ),
    responses(
        (status = 200, body = SeriesAnswer, description = "The /region statistics at t0, t0+dt, … <= t1"),
        ComputedResponses,
    )
)]
pub async fn series(
    WorldQuery {
        s,
        params,
        resolved,
        headers,
    }: WorldQuery,
) -> Result<Response, ApiError> {
    let (layer_index, layer) = layer(&resolved.world, params.get("layer"))?;
    let limits = &s.worlds.config().limits;
    let bbox = params.bbox()?;
    let (t0, t1) = (params.time("t0")?, params.time("t1")?);
    let step = params.f64("dt")?.unwrap_or(layer.dt);
    if t1 < t0 {
        return Err(ApiError::InvalidParameter {
            name: "t1".into(),
            message: "must be >= t0".into(),
        });
    }
    if step <= 0.0 {
        return Err(ApiError::InvalidParameter {
            name: "dt".into(),
            message: "must be > 0 seconds".into(),
        });
    }
    let points = ((t1 - t0) / step).floor() + 1.0;
    if points > s.settings.max_series as f64 {
        return Err(ApiError::SeriesTooLong {
            points: points.min(u64::MAX as f64) as u64,
            max: s.settings.max_series,
        });
    }
    let level = params.level(limits.max_level)?;
    let region = Region::from_bbox(layer, level, bbox, limits)?;
    let fps = s.settings.frames_per_step;
    let times: Vec<f64> = (0..points as u64).map(|i| (t0 + i as f64 * step).min(t1)).collect();
    let frames: Vec<SnappedTime> = times.iter().map(|&t| SnappedTime::snap(t, layer, fps)).collect();
    let frame_list = frames.iter().map(|f| f.index.to_string()).collect::<Vec<_>>().join(",");
    let key = CacheKey::naming("series", &resolved, layer_index)
        .with_region(level, region)
        .with("t", times.iter().map(f64::to_string).collect::<Vec<_>>().join(","))
        .with("f", frame_list);
    let mut cached = Cached::timeless("series", key, "application/json");
    cached.freshness = Freshness::of_frames(frames.iter().zip(&times).all(|(f, &t)| f.is_exact(t)));
    let world = resolved.world;
    cached
        .respond(&s, &headers, move || {
            // Each distinct frame once; consecutive points often share one.
            let mut distinct: Vec<SnappedTime> = frames.clone();
            distinct.dedup_by_key(|f| f.index);
            let mut work = Work::default();
            for f in &distinct {
                let w = cost::density(&world, layer_index, level, region, f.t)?;
                // CPU adds up; memory does not: a frame's grid is dropped once its
                // statistics are taken, so at most one grid per compute thread is
                // alive at once.
                work.cpu_s += w.cpu_s;
                work.bytes = work.bytes.max(w.bytes);
            }
            work.bytes = work
                .bytes
                .saturating_mul(distinct.len().min(rayon::current_num_threads().max(1)) as u64);
            Ok((work, move |cancel: &Cancel| {
                let layer = &world.layers[layer_index];
                let stats: Vec<(u64, (RegionStats, PrecipitationStats))> = distinct
                    .par_iter()
                    .map(|f| {
                        let grid = density::density_cancellable(&world, layer_index, level, region, f.t, cancel)?;
                        Ok((f.index, (region_stats(&grid, layer), precipitation_stats(&grid, layer))))
                    })
                    .collect::<Result<_, ApiError>>()?;
                let points = times
                    .iter()
                    .zip(&frames)
                    .map(|(&t, f)| {
                        let (stats, precipitation) = stats
                            .iter()
                            .find(|(i, _)| *i == f.index)
                            .map(|(_, s)| s.clone())
                            .expect("every frame computed");
                        SeriesPoint {
                            t,
                            frame_t: f.t,
                            frame: f.index,
                            stats,
                            precipitation,
                        }
                    })
                    .collect();
                json_bytes(&SeriesAnswer {
                    world: world.name.clone(),
                    layer: layer.name.clone(),
                    level,
                    columns: region.into(),
                    points,
                })
            }))
        })
        .await
}
