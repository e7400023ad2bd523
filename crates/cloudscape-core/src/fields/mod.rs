//! Noise and the probability fields built from it. Everything here is a pure
//! function of coordinates, seed and layer: no clocks, no globals.

pub mod noise;
pub mod probability;

pub use probability::{FieldWindow, LayerFields, Probabilities, quantize};
