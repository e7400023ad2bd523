//! A thin client of the tile server: fetches billboard tiles, shadow maps and the splat
//! sheet over HTTP, revalidating with ETags, and composites them exactly as
//! `cloudscape render` does locally (same level choice, same compositor, same
//! background), so a remote render matches a local one up to the 8-bit quantisation of
//! the served shadow maps (the compositor takes each splat's optical depth from the
//! sheet's count and the record's f32 `tau_sun`, not the 8-bit texels).
//!
//! Used by `cloudscape render --server URL`. Knows HTTP only as a client (blocking
//! reqwest); nothing here depends on the server's code.

use std::collections::HashMap;
use std::io::Cursor;
use std::time::Duration;

use serde::Deserialize;

use crate::products::billboards::{BinBillboards, decode_bin};
use crate::render::camera::View;
use crate::render::composite::composite;
use crate::render::light::Lighting;
use crate::render::scene::{LayerBand, background, mean_shadow, plan_bands};
use crate::render::shade::Billboard;
use crate::render::splats::SplatSheet;
use crate::render::tile::{TILE_COLUMNS, TileId, shadow_shift};
use crate::render::{Quality, RenderError, RenderRequest, Rendered, Sun};

/// Times a request is retried after a 503 (overloaded server).
const MAX_RETRIES: u32 = 8;

/// What went wrong talking to a server.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("the server URL must look like http://HOST:PORT, got `{0}`")]
    BadUrl(String),
    #[error("cannot fetch {url}: {message}")]
    Transport { url: String, message: String },
    #[error("{url} answered {status}: {message}")]
    Status { url: String, status: u16, message: String },
    #[error("{url} sent something unreadable: {message}")]
    Decode { url: String, message: String },
    #[error(transparent)]
    Render(#[from] RenderError),
}

/// What a client has fetched so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FetchStats {
    /// Requests sent (retries included).
    pub requests: u64,
    /// Responses with a body (200).
    pub fetched: u64,
    /// 304 answers to `If-None-Match`: the stored bytes were reused.
    pub revalidated: u64,
    /// Body bytes of 200 responses.
    pub body_bytes: u64,
}

/// One layer of a remote world, as discovery (`/v1/worlds/{world}`) describes it.
#[derive(Clone, Debug, Deserialize)]
pub struct RemoteLayer {
    pub name: String,
    pub base: f64,
    pub top: f64,
    pub cell_size: f64,
}

/// The parts of a remote world's discovery document the client uses.
#[derive(Clone, Debug, Deserialize)]
pub struct RemoteWorld {
    pub name: String,
    pub maxzoom: u32,
    pub layers: Vec<RemoteLayer>,
}

#[derive(Deserialize)]
struct SplatManifest {
    count: usize,
    size: usize,
    columns: usize,
}

/// A tile's ground shadow map, decoded from `shadow.png`.
struct ShadowMap {
    origin: [f64; 2],
    column: f64,
    /// Added to a ground point before the lookup (`render::tile::shadow_shift`).
    shift: [f64; 2],
    /// Transmittance, 256×256, row 0 = south.
    values: Vec<f32>,
}

impl ShadowMap {
    /// Bilinear lookup, 1 outside the tile (as `ShadedTile::shadow_at`).
    fn at(&self, x: f64, y: f64) -> f64 {
        let n = TILE_COLUMNS;
        let (x, y) = (x + self.shift[0], y + self.shift[1]);
        let u = (x - self.origin[0]) / self.column - 0.5;
        let v = (y - self.origin[1]) / self.column - 0.5;
        if !(u > -0.5 && v > -0.5 && u < n as f64 - 0.5 && v < n as f64 - 0.5) {
            return 1.0;
        }
        let (u, v) = (u.clamp(0.0, (n - 1) as f64), v.clamp(0.0, (n - 1) as f64));
        let (u0, v0) = ((u.floor() as usize).min(n - 2), (v.floor() as usize).min(n - 2));
        let (fu, fv) = (u - u0 as f64, v - v0 as f64);
        let at = |c: usize, r: usize| self.values[r * n + c] as f64;
        let a = at(u0, v0) * (1.0 - fu) + at(u0 + 1, v0) * fu;
        let b = at(u0, v0 + 1) * (1.0 - fu) + at(u0 + 1, v0 + 1) * fu;
        a * (1.0 - fv) + b * fv
    }
}

/// A blocking HTTP client of one server that keeps every body it fetched with its
/// ETag and revalidates it (`If-None-Match`) instead of downloading it again.
pub struct TileClient {
    base: String,
    http: reqwest::blocking::Client,
    /// Bodies by path and query, with the ETag they came with.
    store: HashMap<String, (String, Vec<u8>)>,
    stats: FetchStats,
}

/// Percent-encodes a path segment or query value (RFC 3986 unreserved kept).
fn encode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// Decodes an 8-bit PNG into (width, height, channels, samples).
fn decode_png(bytes: &[u8]) -> Result<(usize, usize, usize, Vec<u8>), String> {
    let mut reader = png::Decoder::new(Cursor::new(bytes))
        .read_info()
        .map_err(|e| e.to_string())?;
    let mut buf = vec![0; reader.output_buffer_size().ok_or("PNG too large")?];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    if info.bit_depth != png::BitDepth::Eight {
        return Err(format!("expected an 8-bit PNG, got {:?}", info.bit_depth));
    }
    buf.truncate(info.buffer_size());
    Ok((
        info.width as usize,
        info.height as usize,
        info.color_type.samples(),
        buf,
    ))
}

impl TileClient {
    /// A client of the server at `base` (`http://host:port`, no path).
    pub fn new(base: &str) -> Result<TileClient, ClientError> {
        let base = base.trim_end_matches('/');
        let rest = base
            .strip_prefix("http://")
            .ok_or_else(|| ClientError::BadUrl(base.to_string()))?;
        if rest.is_empty() || rest.contains('/') {
            return Err(ClientError::BadUrl(base.to_string()));
        }
        let http = reqwest::blocking::Client::builder()
            .no_proxy()
            .timeout(Duration::from_secs(600))
            .build()
            .map_err(|e| ClientError::Transport {
                url: base.to_string(),
                message: e.to_string(),
            })?;
        Ok(TileClient {
            base: base.to_string(),
            http,
            store: HashMap::new(),
            stats: FetchStats::default(),
        })
    }

    pub fn stats(&self) -> FetchStats {
        self.stats
    }

    /// GETs `path` (with its query), revalidating a stored copy; retries 503s after
    /// their `Retry-After`.
    pub fn get(&mut self, path: &str) -> Result<Vec<u8>, ClientError> {
        let url = format!("{}{path}", self.base);
        let transport = |e: reqwest::Error| ClientError::Transport {
            url: url.clone(),
            message: e.to_string(),
        };
        for attempt in 0.. {
            let mut request = self.http.get(&url);
            if let Some((etag, _)) = self.store.get(path) {
                request = request.header(reqwest::header::IF_NONE_MATCH, etag.as_str());
            }
            self.stats.requests += 1;
            let response = request.send().map_err(transport)?;
            let status = response.status().as_u16();
            if status == 304
                && let Some((_, body)) = self.store.get(path)
            {
                self.stats.revalidated += 1;
                return Ok(body.clone());
            }
            if status == 503 && attempt < MAX_RETRIES {
                let after = response
                    .headers()
                    .get(reqwest::header::RETRY_AFTER)
                    .and_then(|v| v.to_str().ok())
                    .and_then(|v| v.parse::<u64>().ok())
                    .unwrap_or(1);
                std::thread::sleep(Duration::from_secs(after.clamp(1, 30)));
                continue;
            }
            let etag = response
                .headers()
                .get(reqwest::header::ETAG)
                .and_then(|v| v.to_str().ok())
                .map(str::to_string);
            let body = response.bytes().map_err(transport)?.to_vec();
            if status != 200 {
                let message = serde_json::from_slice::<serde_json::Value>(&body)
                    .ok()
                    .and_then(|v| v["message"].as_str().map(str::to_string))
                    .unwrap_or_else(|| String::from_utf8_lossy(&body).chars().take(200).collect());
                return Err(ClientError::Status { url, status, message });
            }
            self.stats.fetched += 1;
            self.stats.body_bytes += body.len() as u64;
            if let Some(etag) = etag {
                self.store.insert(path.to_string(), (etag, body.clone()));
            }
            return Ok(body);
        }
        unreachable!("the retry loop returns")
    }

    fn get_json<T: for<'de> Deserialize<'de>>(&mut self, path: &str) -> Result<T, ClientError> {
        let body = self.get(path)?;
        serde_json::from_slice(&body).map_err(|e| ClientError::Decode {
            url: format!("{}{path}", self.base),
            message: e.to_string(),
        })
    }

    /// The discovery document of `world`.
    pub fn world(&mut self, world: &str) -> Result<RemoteWorld, ClientError> {
        self.get_json(&format!("/v1/worlds/{}", encode(world)))
    }

    /// The splat sheet of `quality`, from `/v1/splats.png` and `/v1/splats.json`.
    pub fn splat_sheet(&mut self, quality: Quality) -> Result<SplatSheet, ClientError> {
        let q = quality.as_str();
        let manifest: SplatManifest = self.get_json(&format!("/v1/splats.json?quality={q}"))?;
        let path = format!("/v1/splats.png?quality={q}");
        let png = self.get(&path)?;
        let decode = |message: String| ClientError::Decode {
            url: format!("{}{path}", self.base),
            message,
        };
        let (width, height, channels, samples) = decode_png(&png).map_err(decode)?;
        let (n, s, cols) = (manifest.count, manifest.size, manifest.columns.max(1));
        if channels != 2 || width < cols * s || height < n.div_ceil(cols) * s {
            return Err(decode(format!(
                "a {width}×{height} sheet with {channels} channels cannot hold {n} splats of {s}×{s} in {cols} columns"
            )));
        }
        let mut alpha = Vec::with_capacity(n * s * s);
        for k in 0..n {
            let (gx, gy) = ((k % cols) * s, (k / cols) * s);
            for v in 0..s {
                for u in 0..s {
                    alpha.push(samples[((gy + v) * width + gx + u) * 2 + 1] as f32 / 255.0);
                }
            }
        }
        Ok(SplatSheet {
            count: n,
            size: s,
            alpha,
        })
    }

    fn tile_path(world: &str, tile: TileId, product: &str, query: &str, layer: &str) -> String {
        format!(
            "/v1/worlds/{}/tiles/{}/{}/{}/{product}?{query}&layer={}",
            encode(world),
            tile.z,
            tile.x,
            tile.y,
            encode(layer)
        )
    }

    fn shadow_map(&mut self, path: &str, tile: &BinBillboards, base: f64) -> Result<ShadowMap, ClientError> {
        let png = self.get(path)?;
        let n = TILE_COLUMNS;
        let (width, height, channels, samples) = decode_png(&png)
            .and_then(|d| {
                if d.0 == n && d.1 == n && d.2 == 1 {
                    Ok(d)
                } else {
                    Err(format!(
                        "expected a {n}×{n} greyscale shadow map, got {}×{}×{}",
                        d.0, d.1, d.2
                    ))
                }
            })
            .map_err(|message| ClientError::Decode {
                url: format!("{}{path}", self.base),
                message,
            })?;
        debug_assert_eq!((width, height, channels), (n, n, 1));
        // PNG row 0 is north; the map's row 0 is south.
        let mut values = Vec::with_capacity(n * n);
        for row in (0..n).rev() {
            values.extend(samples[row * n..(row + 1) * n].iter().map(|&v| v as f32 / 255.0));
        }
        let sun = Sun::new(tile.sun_azimuth_deg as f64, tile.sun_elevation_deg as f64).unwrap_or(Sun {
            azimuth_deg: 0.0,
            elevation_deg: 90.0,
        });
        Ok(ShadowMap {
            origin: tile.origin,
            column: tile.size as f64 / n as f64,
            shift: shadow_shift(sun, base),
            values,
        })
    }

    /// Renders `req` from the tiles the server at this client's base serves for
    /// `world`: the same level choice, compositor and background as a local
    /// `cloudscape render`. Billboard presets only (`reference` marches the density
    /// volume, which the server does not serve as billboards).
    pub fn render(&mut self, world: &str, req: &RenderRequest) -> Result<Rendered, ClientError> {
        if req.quality.is_volumetric() {
            return Err(RenderError::BadRequest(format!(
                "quality `{}` renders the density locally; a remote render draws billboards (fast, balanced, accurate)",
                req.quality.as_str()
            ))
            .into());
        }
        let info = self.world(world)?;
        let bands: Vec<LayerBand> = info
            .layers
            .iter()
            .map(|l| LayerBand {
                base: l.base,
                top: l.top,
                cell_size: l.cell_size,
            })
            .collect();
        let tiles = plan_bands(&bands, info.maxzoom, req)?;
        let mut query = format!("t={}&quality={}", req.t, req.quality.as_str());
        if let Some(sun) = req.sun {
            query.push_str(&format!("&sun={},{}", sun.azimuth_deg, sun.elevation_deg));
        }
        let mut billboards = Vec::new();
        let mut shadows = Vec::new();
        let mut served_sun = None;
        for &(layer, tile) in &tiles {
            let name = &info.layers[layer].name;
            let path = Self::tile_path(world, tile, "billboards.bin", &query, name);
            let bytes = self.get(&path)?;
            let decoded = decode_bin(&bytes).map_err(|message| ClientError::Decode {
                url: format!("{}{path}", self.base),
                message,
            })?;
            served_sun.get_or_insert((decoded.sun_azimuth_deg, decoded.sun_elevation_deg));
            billboards.extend(decoded.records.iter().map(|r| Billboard {
                centre: [
                    decoded.origin[0] + r.offset[0] as f64,
                    decoded.origin[1] + r.offset[1] as f64,
                    r.offset[2] as f64,
                ],
                radius: r.radius,
                density: 0.0,
                tau: 0.0,
                splat: r.splat,
                opacity: r.opacity as f32 / 255.0,
                tau_sun: r.tau_sun,
                sun_transmittance: r.sun_transmittance as f32 / 255.0,
                colour: r.colour,
            }));
            let shadow_path = Self::tile_path(world, tile, "shadow.png", &query, name);
            shadows.push(self.shadow_map(&shadow_path, &decoded, bands[layer].base)?);
        }
        // Every tile is shaded for the centre of the request's sun bucket, which the
        // tiles report; the sky and ground use the same.
        let sun = match (served_sun, req.sun) {
            (Some((az, el)), _) => Sun::new(az as f64, el as f64).ok_or_else(|| ClientError::Decode {
                url: self.base.clone(),
                message: format!("tiles report an impossible sun {az},{el}"),
            })?,
            (None, Some(sun)) => sun,
            (None, None) => {
                return Err(RenderError::BadRequest(
                    "the view holds no cloud tiles, so the server's sun is unknown; pass --sun AZ,EL".into(),
                )
                .into());
            }
        };
        let sheet = self.splat_sheet(req.quality)?;
        let view = View::perspective(&req.camera, req.width, req.height);
        let lighting = Lighting::new(sun.bucket().centre(), req.params);
        let far = mean_shadow(tiles.iter().zip(&shadows).map(|(&(layer, _), s)| {
            (
                layer,
                s.values.iter().map(|&v| v as f64).sum::<f64>() / s.values.len().max(1) as f64,
            )
        }));
        let mut image = background(&view, &lighting, far, |x, y| {
            shadows.iter().map(|s| s.at(x, y)).product()
        });
        composite(&mut image, &billboards, &sheet, &lighting, &view);
        Ok(Rendered {
            image,
            tiles,
            billboards: billboards.len(),
            sun,
            noise: None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_are_checked_and_names_encoded() {
        assert!(TileClient::new("http://127.0.0.1:8080").is_ok());
        assert!(TileClient::new("http://127.0.0.1:8080/").is_ok());
        assert!(matches!(TileClient::new("127.0.0.1:8080"), Err(ClientError::BadUrl(_))));
        assert!(matches!(TileClient::new("https://x"), Err(ClientError::BadUrl(_))));
        assert!(matches!(TileClient::new("http://x/v1"), Err(ClientError::BadUrl(_))));
        assert_eq!(encode("a b/c"), "a%20b%2Fc");
        assert_eq!(encode("stratocumulus"), "stratocumulus");
    }

    #[test]
    fn shadow_lookup_matches_the_tile_rule() {
        let n = TILE_COLUMNS;
        let mut values = vec![1.0f32; n * n];
        values[0] = 0.0; // south-west column
        let map = ShadowMap {
            origin: [1000.0, 2000.0],
            column: 100.0,
            shift: [0.0, 0.0],
            values,
        };
        assert_eq!(map.at(1050.0, 2050.0), 0.0);
        assert_eq!(map.at(900.0, 2050.0), 1.0, "outside the tile");
        assert!(
            (map.at(1100.0, 2050.0) - 0.5).abs() < 1e-9,
            "halfway to the next column"
        );
    }
}
