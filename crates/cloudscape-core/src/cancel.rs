//! Cooperative cancellation of a computation whose answer nobody waits for any more.
//!
//! The service gives every compute job a [`Cancel`] and fires it when the last
//! request waiting for the job has gone (its time budget ran out, or its client
//! disconnected). The heavy loops below (automaton steps, density rows, tiles of a
//! view, compositor bands, ray-marcher rows) look at the flag between units of work
//! and, once it is fired, skip the rest of their work. They need no error plumbing:
//! a fired token is final, so whoever ran the job asks [`Cancel::check`] once after
//! it returns and throws the (incomplete) result away. Output bytes never depend on
//! the token: a result is either complete and exactly what it would have been, or
//! discarded.
//!
//! The token reads no clock (the simulation never does): deadlines are the
//! service's business, which fires the token when they pass.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A shared, one-way cancellation flag. Cloning shares it; [`Cancel::never`] is a
/// token that cannot fire (the CLI, benches and tests compute to the end).
#[derive(Clone, Debug, Default)]
pub struct Cancel(Option<Arc<AtomicBool>>);

/// The computation was stopped because its token fired; its result was discarded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("the computation was stopped: nobody was waiting for it any more")]
pub struct Cancelled;

impl Cancel {
    /// A token that can fire.
    pub fn new() -> Cancel {
        Cancel(Some(Arc::new(AtomicBool::new(false))))
    }

    /// A token that never fires.
    pub const fn never() -> Cancel {
        Cancel(None)
    }

    /// Fires the token: every holder sees it from now on.
    pub fn fire(&self) {
        if let Some(flag) = &self.0 {
            flag.store(true, Ordering::Relaxed);
        }
    }

    /// True once fired. One relaxed load: cheap enough for the top of every row.
    #[inline]
    pub fn is_fired(&self) -> bool {
        self.0.as_ref().is_some_and(|f| f.load(Ordering::Relaxed))
    }

    /// `Err(Cancelled)` once fired; the check a job's owner makes after it returns.
    pub fn check(&self) -> Result<(), Cancelled> {
        if self.is_fired() { Err(Cancelled) } else { Ok(()) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fires_once_for_every_clone_and_never_never_fires() {
        let c = Cancel::new();
        let d = c.clone();
        assert!(!d.is_fired() && d.check().is_ok());
        c.fire();
        assert!(d.is_fired());
        assert_eq!(d.check(), Err(Cancelled));
        let n = Cancel::never();
        n.fire();
        assert!(!n.is_fired() && n.check().is_ok());
    }
}
