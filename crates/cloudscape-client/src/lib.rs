//! A thin client of the tile server: fetches billboard tiles, shadow maps and the splat
//! sheet over HTTP, revalidating with ETags, and composites them exactly as
//! `cloudscape render` does locally (same level choice, same compositor, same
//! background), so a remote render matches a local one up to the 8-bit quantisation of
//! the served shadow maps (the compositor takes each splat's optical depth from the
//! sheet's count and the record's f32 `tau_sun`, not the 8-bit texels).
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
mod store;

#[cfg(feature = "blocking")]
mod blocking;
#[cfg(feature = "async")]
mod nonblocking;

#[cfg(feature = "blocking")]
pub use blocking::TileClient;
pub use decode::{RemoteLayer, RemoteRender, RemoteWorld};
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
