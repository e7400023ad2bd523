//! A thin client of the tile server: fetches the billboard keyframes of the tiles a view
//! needs over HTTP (a tile's first keyframe self-contained, the next ones as deltas on
//! the keyframe held, `billboards.delta.bin`), revalidating other bodies with ETags, and
//! draws them as `cloudscape render` does locally (`cloudscape_core::view::held`: same
//! level choice, same bytes, same derived ground shadows, same compositor), so a remote
//! render is the local one, pixel for pixel.
//!
//! Used by `cloudscape render --server URL`. Knows HTTP only as a client; nothing here
//! depends on the server's code. The parts:
//! - [`decode`]: the decoders of served products and the plan of a remote render,
//!   with no networking (always built);
//! - `AsyncTileClient` (feature `async`): a fetcher over reqwest's async client, for
//!   a tokio runtime the caller brings;
//! - `TileClient` (feature `blocking`, default): the same, blocking, on a runtime of
//!   its own.

pub mod decode;
#[cfg(feature = "async")]
mod keyframes;
#[cfg(feature = "async")]
mod store;

#[cfg(feature = "blocking")]
mod blocking;
#[cfg(feature = "async")]
mod nonblocking;

#[cfg(feature = "blocking")]
pub use blocking::TileClient;
pub use decode::{PlannedTile, RemoteLayer, RemoteRender, RemoteWorld};
#[cfg(feature = "async")]
pub use nonblocking::AsyncTileClient;

use cloudscape_core::render::RenderError;

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
    /// Bodies of immutable URLs (keyframes, splat sheets) taken from memory without
    /// asking the server at all.
    pub reused: u64,
    /// Requests for the next keyframe of a tile, sent before it was needed.
    pub prefetched: u64,
    /// Body bytes of 200 responses.
    pub body_bytes: u64,
}
