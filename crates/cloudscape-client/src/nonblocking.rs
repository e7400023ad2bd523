//! The async fetcher (feature `async`), for a tokio runtime the caller brings; the
//! blocking one drives it.

use std::sync::Arc;
use std::time::Duration;

use cloudscape_core::products::billboards::{BinBillboards, decode_bin_after};
use cloudscape_core::render::splats::SplatSheet;
use cloudscape_core::render::{Quality, RenderRequest, Rendered};
use serde::Deserialize;

use crate::decode::{
    PlannedTile, RemoteRender, RemoteWorld, check_remote, decode_splat_sheet, splat_paths, world_path,
};
use crate::keyframes::HeldKeyframes;
use crate::store::{Head, Store, check_base};
use crate::{ClientError, FetchStats};

/// An async HTTP client of one server that keeps what it fetched: the keyframes of
/// tiles decoded (the next keyframe of a held one is fetched as a delta on it), any
/// other immutable body as it is (reused without asking again), the rest with its ETag
/// (revalidated with `If-None-Match` instead of downloaded again).
pub struct AsyncTileClient {
    base: String,
    http: reqwest::Client,
    store: Store,
    keyframes: HeldKeyframes,
    /// Fetch the next keyframes ahead of need (see [`AsyncTileClient::set_prefetch`]).
    prefetch: bool,
}

impl AsyncTileClient {
    /// A client of the server at `base` (`http://host:port`, no path).
    pub fn new(base: &str) -> Result<AsyncTileClient, ClientError> {
        let base = check_base(base)?;
        let http = reqwest::Client::builder()
            .no_proxy()
            .timeout(Duration::from_secs(600))
            // The server closes a connection idle for 5 s (`server.idle_timeout_ms`):
            // a pooled connection kept longer may be closing as a request goes out on it.
            .pool_idle_timeout(Duration::from_secs(4))
            .build()
            .map_err(|e| ClientError::Transport {
                url: base.clone(),
                message: e.to_string(),
            })?;
        Ok(AsyncTileClient {
            base,
            http,
            store: Store::default(),
            keyframes: HeldKeyframes::default(),
            prefetch: true,
        })
    }

    /// Requests, bodies and revalidations so far.
    pub fn stats(&self) -> FetchStats {
        self.store.stats
    }

    /// GETs `path` (with its query), revalidating a stored copy; retries 503s after
    /// their `Retry-After`.
    pub async fn get(&mut self, path: &str) -> Result<Vec<u8>, ClientError> {
        if let Some(body) = self.store.held(path) {
            return Ok(body);
        }
        let url = format!("{}{path}", self.base);
        let transport = |e: reqwest::Error| ClientError::Transport {
            url: url.clone(),
            message: e.to_string(),
        };
        let mut attempt = 0;
        loop {
            let mut request = self.http.get(&url);
            if let Some(etag) = self.store.begin(path) {
                request = request.header(reqwest::header::IF_NONE_MATCH, etag);
            }
            let response = request.send().await.map_err(transport)?;
            let status = response.status().as_u16();
            let header = |name| response.headers().get(name).and_then(|v| v.to_str().ok());
            match self
                .store
                .head(path, status, header(reqwest::header::RETRY_AFTER), attempt)
            {
                Head::Stored(body) => return Ok(body),
                Head::Retry(after) => {
                    tokio::time::sleep(after).await;
                    attempt += 1;
                }
                Head::ReadBody => {
                    let etag = header(reqwest::header::ETAG).map(str::to_string);
                    let cache_control = header(reqwest::header::CACHE_CONTROL).map(str::to_string);
                    let body = response.bytes().await.map_err(transport)?.to_vec();
                    return self
                        .store
                        .finish(url, path, status, etag, cache_control.as_deref(), body);
                }
            }
        }
    }

    async fn get_json<T: for<'de> Deserialize<'de>>(&mut self, path: &str) -> Result<T, ClientError> {
        let body = self.get(path).await?;
        serde_json::from_slice(&body).map_err(|e| ClientError::Decode {
            url: format!("{}{path}", self.base),
            message: e.to_string(),
        })
    }

    /// The discovery document of `world`.
    pub async fn world(&mut self, world: &str) -> Result<RemoteWorld, ClientError> {
        self.get_json(&world_path(world)).await
    }

    /// The splat sheet of `quality`, from `/v1/splats.png` and `/v1/splats.json`.
    pub async fn splat_sheet(&mut self, quality: Quality) -> Result<SplatSheet, ClientError> {
        let [manifest, png] = splat_paths(quality);
        let (m, p) = (self.get(&manifest).await?, self.get(&png).await?);
        decode_splat_sheet(&m, &p).map_err(|message| ClientError::Decode {
            url: format!("{}{png}", self.base),
            message,
        })
    }

    /// Renders `req` from the tiles the server at this client's base serves for
    /// `world`: the same level choice and drawing as a local `cloudscape render`.
    /// Billboard presets only.
    pub async fn render(&mut self, world: &str, req: &RenderRequest) -> Result<Rendered, ClientError> {
        check_remote(req)?;
        let plan = RemoteRender::plan(world, self.world(world).await?, req)?;
        let mut fetched = Vec::new();
        for p in plan.tiles() {
            fetched.push((p, self.keyframe(&plan, &p).await?));
        }
        // The clock's sun, learnt from the tiles, throws shadows of more tiles into view.
        let plan = plan.for_served_sun(fetched.first().map(|(_, k)| &**k))?.unwrap_or(plan);
        let mut keyframes = Vec::new();
        for p in plan.tiles() {
            let k = match fetched.iter().find(|(q, _)| q == &p) {
                Some((_, k)) => Arc::clone(k),
                None => self.keyframe(&plan, &p).await?,
            };
            keyframes.push(BinBillboards::clone(&k));
        }
        if self.prefetch {
            for p in plan.prefetch() {
                if self.keyframes.get(&plan.variant(&p), p.keyframe.t0).is_some() {
                    continue;
                }
                self.store.stats.prefetched += 1;
                self.keyframe(&plan, &p).await?;
            }
        }
        plan.draw(&self.base, keyframes)
    }

    /// A tile's keyframe, decoded: held already, or fetched as a delta on the keyframe
    /// before it when that is held, else self-contained.
    async fn keyframe(&mut self, plan: &RemoteRender, p: &PlannedTile) -> Result<Arc<BinBillboards>, ClientError> {
        let variant = plan.variant(p);
        if let Some(k) = self.keyframes.get(&variant, p.keyframe.t0) {
            self.store.stats.reused += 1;
            return Ok(k);
        }
        let previous = self.keyframes.ending_at(&variant, p.keyframe.t0);
        let path = plan.keyframe_path(p, previous.is_some());
        let bytes = self.get(&path).await?;
        let decoded = decode_bin_after(&bytes, previous.as_deref()).map_err(|message| ClientError::Decode {
            url: format!("{}{path}", self.base),
            message,
        })?;
        let decoded = Arc::new(decoded);
        self.keyframes.insert(&variant, p.keyframe.t0, Arc::clone(&decoded));
        Ok(decoded)
    }

    /// Whether [`render`](Self::render) also fetches the next keyframe of every tile
    /// past the middle of its span (on by default), as an animating client does so the
    /// boundary finds the next keyframe in memory.
    pub fn set_prefetch(&mut self, on: bool) {
        self.prefetch = on;
    }
}
