//! Products: one type per product, and the encoders that turn them into bytes.

pub mod atlas;
pub mod billboards;
pub mod coverage;
pub mod grid;
pub mod shadow;
pub mod sky;
pub mod splats;
