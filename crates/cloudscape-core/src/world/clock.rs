//! The world clock: how a world's time follows real time (`[worlds.NAME.clock]`).
//!
//! World time is `t = offset + rate · u`, with `u` the Unix time in seconds; without a
//! `[clock]` table `offset = 0` and `rate = 1`, so `t` is Unix time (world time 0 is
//! the Unix epoch, as the EDR answers say). A game whose day lasts two real hours sets
//! `rate = 12`. The simulation never reads a clock: the server does (what is "now" for
//! the play areas it keeps warm, and for discovery), and passes times as arguments.

use serde::{Deserialize, Serialize};

/// A world's clock: world seconds `offset + rate · u` at Unix second `u`.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WorldClock {
    /// World time at the Unix epoch, seconds.
    #[serde(default)]
    pub offset: f64,
    /// World seconds per real second (> 0).
    #[serde(default = "one")]
    pub rate: f64,
}

fn one() -> f64 {
    1.0
}

/// Largest `|offset|` of a world clock, seconds.
pub const MAX_CLOCK_OFFSET: f64 = 1e13;
/// Largest clock rate, world seconds per real second.
pub const MAX_CLOCK_RATE: f64 = 1e6;

impl Default for WorldClock {
    fn default() -> Self {
        WorldClock { offset: 0.0, rate: 1.0 }
    }
}

impl WorldClock {
    /// World time at Unix second `unix` (not clamped to the accepted range of `t`).
    pub fn at(&self, unix: f64) -> f64 {
        self.offset + self.rate * unix
    }

    /// The Unix second at which the clock reads `t`.
    pub fn unix_at(&self, t: f64) -> f64 {
        (t - self.offset) / self.rate
    }

    /// Whether offset and rate are usable: finite, `|offset| <= 1e13`,
    /// `0 < rate <= 1e6`. Says which is not.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        if !(self.offset.is_finite() && self.offset.abs() <= MAX_CLOCK_OFFSET) {
            return Err(("offset", format!("must be finite seconds within ±{MAX_CLOCK_OFFSET:e}")));
        }
        if !(self.rate.is_finite() && self.rate > 0.0 && self.rate <= MAX_CLOCK_RATE) {
            return Err((
                "rate",
                format!("must be within (0, {MAX_CLOCK_RATE:e}] world seconds per real second"),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_clock_is_unix_time_and_unix_at_inverts_at() {
        let c = WorldClock::default();
        assert_eq!(c.at(1.7e9), 1.7e9);
        let fast = WorldClock {
            offset: -1.0e9,
            rate: 12.0,
        };
        assert_eq!(fast.at(1.0e8), 2.0e8);
        assert_eq!(fast.unix_at(fast.at(1.7e9)), 1.7e9);
        assert!(fast.check().is_ok());
    }

    #[test]
    fn bad_clocks_name_their_field() {
        for (clock, field) in [
            (WorldClock { offset: 0.0, rate: 0.0 }, "rate"),
            (
                WorldClock {
                    offset: 0.0,
                    rate: -1.0,
                },
                "rate",
            ),
            (
                WorldClock {
                    offset: 0.0,
                    rate: f64::NAN,
                },
                "rate",
            ),
            (WorldClock { offset: 0.0, rate: 1e7 }, "rate"),
            (
                WorldClock {
                    offset: f64::INFINITY,
                    rate: 1.0,
                },
                "offset",
            ),
            (
                WorldClock {
                    offset: -2e13,
                    rate: 1.0,
                },
                "offset",
            ),
        ] {
            assert_eq!(clock.check().unwrap_err().0, field, "{clock:?}");
        }
    }
}
