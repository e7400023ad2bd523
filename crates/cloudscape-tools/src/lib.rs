//! cloudscape-tools: the measuring and attacking tools behind `cloudscape bench`,
//! `cloudscape loadtest` and `cloudscape fuzz`, with the charts they draw.
//!
//! - [`bench`]: the measurements behind BENCHMARKS.md;
//! - [`loadtest`]: simulated MMO players and game servers against a running server;
//! - [`soak`]: the hostile-input soak and connection attacks;
//! - [`chart`]: the PNG line charts they plot.

pub mod bench;
pub mod chart;
pub mod loadtest;
pub mod soak;
