//! What a panic costs the server: one log line, and for a request a 500 with the JSON
//! error body.
//!
//! A panic is a bug, but a client can find one (a parser that slices a string inside a
//! character did): the server must stay up, answer, give back what the request held,
//! and not let each such request write the 49 KB of a backtrace to the log. So:
//! - [`catch`] turns a panicking handler into `500 {"error": "internal", …}` before the
//!   response leaves the router (tower-http's `CatchPanicLayer`, which also catches a
//!   panic while the service is called). The request's guards (in-flight count,
//!   admission, reply budget) are dropped by the unwinding, and its connection goes on
//!   serving; jobs on the compute pool are caught the same way by the cache.
//! - [`log_in_one_line`] replaces the process's panic hook: each panic is one `ERROR`
//!   line with its message (escaped, at most [`MAX_MESSAGE_CHARS`] characters) and
//!   where it happened, through the log subscriber; no backtrace, whatever
//!   `RUST_BACKTRACE` says, since a client could otherwise write one per request.

use std::any::Any;

use axum::response::{IntoResponse, Response};
use tower_http::catch_panic::CatchPanicLayer;

use crate::error::ApiError;

/// Longest panic message logged, characters (a message may quote request input).
pub const MAX_MESSAGE_CHARS: usize = 512;

/// The layer that answers a panicking handler with [`ApiError::Panicked`].
pub fn catch() -> CatchPanicLayer<fn(Box<dyn Any + Send + 'static>) -> Response> {
    CatchPanicLayer::custom(panicked as fn(Box<dyn Any + Send + 'static>) -> Response)
}

fn panicked(_payload: Box<dyn Any + Send + 'static>) -> Response {
    ApiError::Panicked.into_response()
}

/// The text of a panic's payload (`panic!` gives a `&str` or a `String`).
pub fn message(payload: &(dyn Any + Send)) -> &str {
    payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("(a panic without a message)")
}

/// `message` on one line: control characters escaped, cut to [`MAX_MESSAGE_CHARS`].
pub fn one_line(message: &str) -> String {
    let mut out: String = message
        .chars()
        .take(MAX_MESSAGE_CHARS)
        .flat_map(char::escape_debug)
        .collect();
    if message.chars().nth(MAX_MESSAGE_CHARS).is_some() {
        out.push('…');
    }
    out
}

/// Makes every panic of the process one log line (see the module notes). For
/// `cloudscape serve`; a library test keeps the default hook.
pub fn log_in_one_line() {
    std::panic::set_hook(Box::new(|info| {
        let location = info
            .location()
            .map_or_else(String::new, |l| format!("{}:{}", l.file(), l.line()));
        let thread = std::thread::current();
        tracing::error!(
            thread = thread.name().unwrap_or("unnamed"),
            location,
            "panic: {}",
            one_line(message(info.payload()))
        );
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_are_one_bounded_line() {
        assert_eq!(one_line("a\nb\t\"c\" é"), "a\\nb\\t\\\"c\\\" é");
        let long = "x".repeat(MAX_MESSAGE_CHARS + 10);
        let line = one_line(&long);
        assert_eq!(line.chars().count(), MAX_MESSAGE_CHARS + 1);
        assert!(line.ends_with('…'));
        let payload: Box<dyn Any + Send> = Box::new(String::from("owned"));
        assert_eq!(message(payload.as_ref()), "owned");
        let payload: Box<dyn Any + Send> = Box::new("static");
        assert_eq!(message(payload.as_ref()), "static");
        let payload: Box<dyn Any + Send> = Box::new(7u8);
        assert_eq!(message(payload.as_ref()), "(a panic without a message)");
    }
}
