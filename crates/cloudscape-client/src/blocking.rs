//! The blocking fetcher (feature `blocking`): the async one driven by a runtime of its
//! own, as reqwest's blocking client is built, so both share one fetch loop. Not to be
//! called from inside an async runtime (use `AsyncTileClient` there).

use cloudscape_core::render::splats::SplatSheet;
use cloudscape_core::render::{Quality, RenderRequest, Rendered};

use crate::decode::RemoteWorld;
use crate::{AsyncTileClient, ClientError, FetchStats};

/// A blocking HTTP client of one server that keeps every body it fetched: an immutable
/// one (a keyframe) is reused without asking again, any other is revalidated with its
/// ETag (`If-None-Match`) instead of downloaded again.
pub struct TileClient {
    inner: AsyncTileClient,
    runtime: tokio::runtime::Runtime,
}

impl TileClient {
    /// A client of the server at `base` (`http://host:port`, no path).
    pub fn new(base: &str) -> Result<TileClient, ClientError> {
        let inner = AsyncTileClient::new(base)?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| ClientError::Transport {
                url: base.to_string(),
                message: format!("cannot start the client's runtime: {e}"),
            })?;
        Ok(TileClient { inner, runtime })
    }

    /// Requests, bodies and revalidations so far.
    pub fn stats(&self) -> FetchStats {
        self.inner.stats()
    }

    /// GETs `path` (with its query), revalidating a stored copy; retries 503s after
    /// their `Retry-After`.
    pub fn get(&mut self, path: &str) -> Result<Vec<u8>, ClientError> {
        self.runtime.block_on(self.inner.get(path))
    }

    /// The discovery document of `world`.
    pub fn world(&mut self, world: &str) -> Result<RemoteWorld, ClientError> {
        self.runtime.block_on(self.inner.world(world))
    }

    /// The splat sheet of `quality`, from `/v1/splats.png` and `/v1/splats.json`.
    pub fn splat_sheet(&mut self, quality: Quality) -> Result<SplatSheet, ClientError> {
        self.runtime.block_on(self.inner.splat_sheet(quality))
    }

    /// Renders `req` from the tiles the server at this client's base serves for
    /// `world`: the same level choice, compositor and background as a local
    /// `cloudscape render`. Billboard presets only.
    pub fn render(&mut self, world: &str, req: &RenderRequest) -> Result<Rendered, ClientError> {
        self.runtime.block_on(self.inner.render(world, req))
    }

    /// Whether [`render`](Self::render) also fetches the next keyframe of every tile
    /// past the middle of its span (on by default).
    pub fn set_prefetch(&mut self, on: bool) {
        self.inner.set_prefetch(on);
    }
}
