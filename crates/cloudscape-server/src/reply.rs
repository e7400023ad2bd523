//! Bounded reply memory: the bytes held by responses still being sent.
//!
//! A response body is the cached [`Bytes`] itself (a clone shares the buffer; no
//! copy per client). It is handed to hyper in slices of [`CHUNK`] bytes, and hyper
//! asks for the next slice only once it has written the last, so until a body is
//! dropped (sent, or its connection closed) it keeps the rest of its buffer alive.
//! Every body therefore holds a share of `server.reply_bytes` (its length, in KiB
//! permits) from before it is sent until it is dropped; when the budget is spent the
//! request is answered 503 with `Retry-After` instead. A slow or stalled reader
//! (closed by the connection layer's write timeout) keeps its share until then.

use std::convert::Infallible;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use axum::body::{Body, Bytes, HttpBody};
use http_body::{Frame, SizeHint};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

use crate::error::ApiError;

/// Bytes per slice handed to hyper.
pub const CHUNK: usize = 256 << 10;

/// Bodies at most this long are not counted (error bodies, small products): their
/// bytes are noise beside the budget and counting them would only cost time.
const UNCOUNTED: usize = 64 << 10;

/// The budget of reply bytes in flight, in KiB permits.
pub struct ReplyBudget {
    permits: Arc<Semaphore>,
    kib: u32,
    gauge: prometheus::IntGauge,
}

impl ReplyBudget {
    pub fn new(bytes: u64, gauge: prometheus::IntGauge) -> ReplyBudget {
        let kib = (bytes >> 10).clamp(1, Semaphore::MAX_PERMITS as u64 >> 1) as u32;
        ReplyBudget {
            permits: Arc::new(Semaphore::new(kib as usize)),
            kib,
            gauge,
        }
    }

    /// A body for `bytes` that holds its share of the budget until dropped, or
    /// `ReplyMemoryFull` when the share is not free (`retry_after` seconds).
    pub fn body(&self, bytes: Bytes, retry_after: u32) -> Result<Body, ApiError> {
        if bytes.len() <= UNCOUNTED {
            return Ok(Body::from(bytes));
        }
        let kib = (bytes.len() as u64).div_ceil(1 << 10).min(self.kib as u64) as u32;
        let permit = self
            .permits
            .clone()
            .try_acquire_many_owned(kib)
            .map_err(|_| ApiError::ReplyMemoryFull {
                held_mib: ((self.kib as usize - self.permits.available_permits()) >> 10) as u64,
                budget_mib: (self.kib >> 10) as u64,
                retry_after,
            })?;
        let counted = kib as i64 * 1024;
        self.gauge.add(counted);
        Ok(Body::new(ReplyBody {
            rest: bytes,
            _share: Share {
                _permit: permit,
                gauge: self.gauge.clone(),
                bytes: counted,
            },
        }))
    }
}

/// A body's share of the budget, given back when the body is dropped.
struct Share {
    _permit: OwnedSemaphorePermit,
    gauge: prometheus::IntGauge,
    bytes: i64,
}

impl Drop for Share {
    fn drop(&mut self) {
        self.gauge.sub(self.bytes);
    }
}

/// The cached bytes of one response, sent in [`CHUNK`] slices (zero-copy).
struct ReplyBody {
    rest: Bytes,
    _share: Share,
}

impl HttpBody for ReplyBody {
    type Data = Bytes;
    type Error = Infallible;

    fn poll_frame(mut self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<Option<Result<Frame<Bytes>, Infallible>>> {
        if self.rest.is_empty() {
            return Poll::Ready(None);
        }
        let n = self.rest.len().min(CHUNK);
        Poll::Ready(Some(Ok(Frame::data(self.rest.split_to(n)))))
    }

    fn is_end_stream(&self) -> bool {
        self.rest.is_empty()
    }

    fn size_hint(&self) -> SizeHint {
        SizeHint::with_exact(self.rest.len() as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn budget(bytes: u64) -> ReplyBudget {
        ReplyBudget::new(bytes, prometheus::IntGauge::new("g", "g").unwrap())
    }

    #[tokio::test]
    async fn a_body_holds_its_share_until_dropped_and_sends_every_byte_in_order() {
        let b = budget(4 << 20);
        let data: Vec<u8> = (0..3_000_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let bytes = Bytes::from(data.clone());
        let body = b.body(bytes.clone(), 1).unwrap();
        assert_eq!(b.gauge.get(), 2930 * 1024);
        // A second body of the same size does not fit in 4 MiB.
        let refused = b.body(bytes.clone(), 7).unwrap_err();
        assert!(
            matches!(refused, ApiError::ReplyMemoryFull { retry_after: 7, .. }),
            "{refused:?}"
        );
        let got = axum::body::to_bytes(body, usize::MAX).await.unwrap();
        assert_eq!(got.as_ref(), &data[..]);
        // Sent and dropped: the share is back.
        assert_eq!(b.gauge.get(), 0);
        assert!(b.body(bytes, 1).is_ok());
        // Small bodies are not counted.
        let small = b.body(Bytes::from_static(b"{}"), 1).unwrap();
        assert_eq!(axum::body::to_bytes(small, 10).await.unwrap().as_ref(), b"{}");
    }
}
