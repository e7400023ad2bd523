//! Products: one type per product, and the encoders that turn them into bytes. The
//! tile products are listed once, in [`catalogue`].

pub mod atlas;
pub mod billboards;
pub mod catalogue;
pub mod coverage;
pub mod grid;
pub mod ktx2;
pub mod precipitation;
pub mod shadow;
pub mod sky;
pub mod splats;

pub use catalogue::Product;
