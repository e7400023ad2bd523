//! Where a tile's time goes: wall time per stage of the pipeline, added up by the
//! calls that do the work (`cloudscape bench`'s keyframe profile, the server's
//! `cloudscape_stage_seconds_total`). Measuring never changes what is computed.

use std::time::{Duration, Instant};

/// A stage of a tile's computation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Automaton runs from their epochs' empty grids (fields, drives and steps).
    Automaton,
    /// Steps of runs kept alive between keyframes (`automaton::live`), new runs
    /// started for them included.
    Steps,
    /// Cloud bits to density: the tent, the wind displacement, the time blend.
    Smoothing,
    /// The far-field model of levels above 0 (fields at column centres, mean field).
    FarField,
    /// Density cut out of a grid kept from an earlier keyframe.
    Reused,
    /// Density collected into metaballs on the lattice.
    Metaballs,
    /// Light sweep toward the sun, billboards and the ground shadow map.
    Shading,
}

impl Stage {
    /// Every stage, in pipeline order.
    pub const ALL: [Stage; 7] = [
        Stage::Automaton,
        Stage::Steps,
        Stage::Smoothing,
        Stage::FarField,
        Stage::Reused,
        Stage::Metaballs,
        Stage::Shading,
    ];

    /// The stage's name in tables and metric labels.
    pub fn name(self) -> &'static str {
        match self {
            Stage::Automaton => "automaton",
            Stage::Steps => "steps",
            Stage::Smoothing => "smoothing",
            Stage::FarField => "far_field",
            Stage::Reused => "reused",
            Stage::Metaballs => "metaballs",
            Stage::Shading => "shading",
        }
    }
}

/// Wall time spent in each [`Stage`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stages([Duration; Stage::ALL.len()]);

impl Stages {
    /// Runs `f` and adds its wall time to `stage`.
    pub fn time<R>(&mut self, stage: Stage, f: impl FnOnce() -> R) -> R {
        let start = Instant::now();
        let out = f();
        self.0[stage as usize] += start.elapsed();
        out
    }

    /// Adds `d` to `stage`.
    pub fn add(&mut self, stage: Stage, d: Duration) {
        self.0[stage as usize] += d;
    }

    /// The time spent in `stage`.
    pub fn get(&self, stage: Stage) -> Duration {
        self.0[stage as usize]
    }

    /// The sum over every stage.
    pub fn total(&self) -> Duration {
        self.0.iter().sum()
    }
}
