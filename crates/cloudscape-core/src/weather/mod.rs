//! Weather that gameplay reads off the clouds: what falls out of them. Downstream of
//! [`crate::density`]: every quantity here is a pure function of a layer's density
//! column, so it is as deterministic and seamless as the density itself.

pub mod lightning;
pub mod precipitation;

pub use precipitation::{PrecipitationKind, PrecipitationStats, column_rate, kind_at, precipitation_stats};
