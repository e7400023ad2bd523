//! The cellular automaton: bit-packed grids, the Dobashi/Rosa rules, wind
//! frames, counter-based randomness, dependency cones and the epoch plan that
//! bounds history.

pub mod epoch;
pub mod frame;
pub mod kernel;
pub mod live;
pub mod naive;
pub mod random;
pub mod run;

pub use epoch::{StepPlan, plan_step, served_steps};
pub use kernel::{Level, Rect};
pub use live::LiveRuns;
pub use run::{LayerSim, RunSpec, Snapshot};

#[cfg(test)]
mod tests;
