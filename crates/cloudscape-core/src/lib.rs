//! cloudscape-core: noise-driven Dobashi cloud simulation for large game worlds, with
//! no networking.
//!
//! The pipeline runs one way, one module per stage:
//! world spec → probability fields → automaton → density → metaballs →
//! shading → encoding ([`products`]) → what a client draws from them ([`view`]);
//! [`weather`] reads precipitation off the density. A stage depends only on the stages before it;
//! [`region`] (the columns a computation covers) and [`world`] sit below them all.
//! The HTTP service is `cloudscape-server`; the tile client is `cloudscape-client`.

#![warn(missing_docs)]
// Slicing a `str` by byte positions panics inside a multibyte character; parsers
// split at ASCII separators (`split_once`, `strip_prefix`) or use `str::get`.
#![deny(clippy::string_slice)]

pub mod automaton;
pub mod cancel;
pub mod civil;
pub mod cost;
pub mod cpu;
pub mod density;
pub mod fields;
pub mod products;
pub mod region;
pub mod render;
pub mod stages;
pub mod view;
pub mod weather;
pub mod world;
