//! The `cloudscape` command line. The library code lives in the workspace's crates:
//! `cloudscape-core` (simulation and products), `cloudscape-server` (HTTP),
//! `cloudscape-client` (tile client) and `cloudscape-tools` (bench, load test, soak).

// Arguments, environment and config files may hold any characters: never slice a
// `str` by byte positions (it panics inside a multibyte character).
#![deny(clippy::string_slice)]

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
