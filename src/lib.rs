//! cloudscape: noise-driven Dobashi cloud simulation for large game worlds.
//!
//! The pipeline runs one way, one module per stage:
//! world spec → probability fields → automaton → density → metaballs →
//! shading → encoding → HTTP. A stage depends only on the stages before it.

pub mod automaton;
pub mod bench;
pub mod cancel;
pub mod chart;
pub mod cli;
pub mod client;
pub mod cost;
pub mod density;
pub mod fields;
pub mod fuzz;
pub mod loadtest;
pub mod products;
pub mod render;
pub mod service;
pub mod world;
