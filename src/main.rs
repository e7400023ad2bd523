//! The `cloudscape` command line. The library code lives in the workspace's crates:
//! `cloudscape-core` (simulation and products), `cloudscape-server` (HTTP),
//! `cloudscape-client` (tile client) and `cloudscape-tools` (bench, load test, soak).

// Arguments, environment and config files may hold any characters: never slice a
// `str` by byte positions (it panics inside a multibyte character).
#![deny(clippy::string_slice)]

mod cli;

/// jemalloc, whose memory the server accounts for (`cloudscape_server::allocator`):
/// it gives freed pages back to the system on a decay timer and reports what it holds.
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

/// jemalloc's options, read when it starts: a background thread purges freed pages
/// (dirty, then muzzy) after a second unused, so what a burst freed leaves the
/// resident set within seconds instead of after the default ten, and an idle server
/// holds what it uses; `narenas:8` bounds the per-thread-group arenas whose free
/// pages add up. (`_RJEM_MALLOC_CONF` in the environment overrides them.) A C string:
/// a thin, nullable pointer is what jemalloc reads.
#[allow(non_upper_case_globals)]
#[unsafe(export_name = "_rjem_malloc_conf")]
pub static malloc_conf: Option<&'static [u8; 70]> =
    Some(b"background_thread:true,dirty_decay_ms:1000,muzzy_decay_ms:0,narenas:8\0");

fn main() -> std::process::ExitCode {
    cli::main()
}
