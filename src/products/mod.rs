//! Products: one type per product, and the encoders that turn them into bytes.

pub mod grid;
