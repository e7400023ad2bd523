//! What the memory allocator holds, and what an allocation really takes.
//!
//! The `cloudscape` binary runs on jemalloc (`src/main.rs`). The caches weigh their
//! entries by the size class jemalloc gives an allocation of that length
//! ([`allocation`]), not by the length, and `/metrics` reports jemalloc's own figures
//! ([`Stats`]): `allocated` (what the program holds), `resident` (the pages jemalloc
//! has in memory, its free ones included), so that `resident − allocated` is the
//! allocator's overhead, measured rather than guessed. In a process on another
//! allocator (a test linking the library) the statistics describe jemalloc's own
//! empty arenas and are left out.

/// Bytes an allocation of `len` bytes takes: jemalloc's size class for it (small sizes
/// round up to 8–25 %, large ones to a quarter of their power of two at most).
pub fn allocation(len: usize) -> usize {
    if len == 0 {
        return 0;
    }
    // SAFETY: `nallocx` only computes a size class; a non-zero size and no flags are
    // valid arguments. It returns 0 for sizes it cannot allocate.
    let real = unsafe { tikv_jemalloc_sys::nallocx(len, 0) };
    real.max(len)
}

/// jemalloc's statistics, bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stats {
    /// Held by the program.
    pub allocated: u64,
    /// In pages that hold at least one allocation.
    pub active: u64,
    /// Physically resident in pages jemalloc mapped (its free pages included).
    pub resident: u64,
    /// Mapped and not yet given back to the system.
    pub retained: u64,
}

impl Stats {
    /// The current figures, or `None` when jemalloc is not this process's allocator
    /// (it then holds next to nothing).
    pub fn read() -> Option<Stats> {
        use tikv_jemalloc_ctl::{epoch, stats};
        // The statistics are a snapshot taken when the epoch advances.
        epoch::advance().ok()?;
        let s = Stats {
            allocated: stats::allocated::read().ok()? as u64,
            active: stats::active::read().ok()? as u64,
            resident: stats::resident::read().ok()? as u64,
            retained: stats::retained::read().ok()? as u64,
        };
        (s.allocated >= 1 << 20).then_some(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_allocation_takes_its_size_class() {
        assert_eq!(allocation(0), 0);
        assert_eq!(allocation(1), 8);
        assert!(allocation(4097) >= 4097 && allocation(4097) <= 5120);
        // A large allocation: within a quarter of its power of two above.
        let n = (5 << 20) + 1;
        assert!(allocation(n) >= n && allocation(n) <= 6 << 20, "{}", allocation(n));
    }
}
