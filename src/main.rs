//! The `cloudscape` command line. The library code lives in the workspace's crates:
//! `cloudscape-core` (simulation and products), `cloudscape-server` (HTTP),
//! `cloudscape-client` (tile client) and `cloudscape-tools` (bench, load test, soak).

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
