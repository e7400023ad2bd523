//! Keyframes: the times tile products are computed at, and the spans clients animate
//! over by themselves.
//!
//! Dobashi et al. 2000 simulate at coarse steps and interpolate density between them;
//! game engines animate between keyframes on the client. A tile of level `z` of a
//! layer is computed at the keyframes `t_k = k · span(z)`, with
//!
//! ```text
//! span(z) = dt · 2^min(z, MAX_KEYFRAME_DOUBLINGS)
//! ```
//!
//! so a level-0 keyframe is one automaton step, and each coarser level (whose columns
//! are twice as wide, so the wind crosses a column in twice the time) doubles it, up
//! to 16 steps (one epoch of the default layers) from level 4 on. The wind moves a
//! cloud by about the same fraction of a column per span at every level; how far the
//! interpolation rule strays from the model between keyframes is measured per level
//! in BENCHMARKS.md ("Keyframes").
//!
//! A keyframe product covers the span `[t0, t1)` and carries what a client needs to
//! draw any time inside it (`products::billboards` states the animation rule).
//! Keyframe times are exact multiples of the span in `f64`, so clients compute the
//! next keyframe's URL themselves: `t0 = floor(t / span) · span`.

use super::{Layer, MAX_TIME};

/// The earliest fraction of a span at which a client fetches a tile's next keyframe.
pub const PREFETCH_FROM: f64 = 0.5;
/// How far past [`PREFETCH_FROM`] the tiles' prefetch points spread.
pub const PREFETCH_SPREAD: f64 = 0.3;

/// The fraction of its span past which a client fetches tile (z, x, y)'s next
/// keyframe: in `[0.5, 0.8)`, by a hash of the tile. Every player of a town shares the
/// world clock, so with one fraction for all (the middle) every tile of every view
/// would be asked for in the same second; spread by tile, the next keyframes of a
/// view arrive over the second half of the span, and each tile's still at one moment
/// for all players (one computation, one cache fill). A fifth of the span is left for
/// the last ones. The same integer arithmetic as the JS client's `prefetchAt`
/// (32-bit wrapping multiplies of the low 32 bits of x and y), so both agree.
pub fn prefetch_at(z: u32, x: i64, y: i64) -> f64 {
    let mut h = (x as u32).wrapping_mul(0x9E37_79B1)
        ^ (y as u32).wrapping_mul(0x85EB_CA77)
        ^ z.wrapping_add(1).wrapping_mul(0xC2B2_AE3D);
    h ^= h >> 16;
    h = h.wrapping_mul(0x7FEB_352D);
    h ^= h >> 15;
    PREFETCH_FROM + PREFETCH_SPREAD * (f64::from(h) / 4_294_967_296.0)
}

/// Levels past which the keyframe span stops doubling.
pub const MAX_KEYFRAME_DOUBLINGS: u32 = 4;

/// The span of keyframes of a tile of level `z` of a layer whose automaton steps
/// `dt` seconds: `dt · 2^min(z, MAX_KEYFRAME_DOUBLINGS)`.
pub fn keyframe_span(dt: f64, z: u32) -> f64 {
    dt * f64::from(1u32 << z.min(MAX_KEYFRAME_DOUBLINGS))
}

/// One keyframe span of a tile level: the time its products are computed at and the
/// time the next keyframe starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keyframe {
    /// Keyframe index: `t0 = index · span`.
    pub index: u64,
    /// Start of the span: the time the product's first end is computed for.
    pub t0: f64,
    /// End of the span (the next keyframe's `t0`), at most [`MAX_TIME`]; equal to
    /// `t0` for an instant (no animation).
    pub t1: f64,
}

impl Keyframe {
    /// The keyframe span of level `z` of `layer` that contains a checked `t` (finite,
    /// 0..=[`MAX_TIME`]): `index = floor(t / span)`. The last span is cut at
    /// [`MAX_TIME`].
    pub fn containing(t: f64, layer: &Layer, z: u32) -> Keyframe {
        Keyframe::on_grid(t, keyframe_span(layer.dt, z))
    }

    /// The span of a grid of `span` seconds that contains `t`.
    pub fn on_grid(t: f64, span: f64) -> Keyframe {
        let t = if t.is_finite() { t.clamp(0.0, MAX_TIME) } else { 0.0 };
        let index = (t / span).floor() as u64;
        let mut t0 = index as f64 * span;
        // `t / span` rounds: make sure t0 <= t < t1 holds in f64.
        let index = if t0 > t {
            t0 = (index - 1) as f64 * span;
            index - 1
        } else {
            index
        };
        Keyframe {
            index,
            t0,
            t1: (t0 + span).min(MAX_TIME),
        }
    }

    /// The degenerate span `[t, t]`: products for exactly `t`, nothing to animate.
    pub fn instant(t: f64) -> Keyframe {
        Keyframe { index: 0, t0: t, t1: t }
    }

    /// Seconds from `t0` to `t1`.
    pub fn span(&self) -> f64 {
        self.t1 - self.t0
    }

    /// True for an instant (`t1 == t0`).
    pub fn is_instant(&self) -> bool {
        self.t1 == self.t0
    }

    /// Where `t` falls in the span, `(t − t0) / (t1 − t0)` within [0, 1] (0 for an
    /// instant).
    pub fn fraction(&self, t: f64) -> f64 {
        if self.is_instant() {
            return 0.0;
        }
        let f = (t - self.t0) / (self.t1 - self.t0);
        if f.is_finite() { f.clamp(0.0, 1.0) } else { 0.0 }
    }

    /// True when `t` is this keyframe's own time: an answer for it is final.
    pub fn is_exact(&self, t: f64) -> bool {
        self.t0 == t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Config;

    #[test]
    fn spans_double_per_level_up_to_the_cap() {
        assert_eq!(keyframe_span(20.0, 0), 20.0);
        assert_eq!(keyframe_span(20.0, 1), 40.0);
        assert_eq!(keyframe_span(20.0, 4), 320.0);
        assert_eq!(keyframe_span(20.0, 5), 320.0);
        assert_eq!(keyframe_span(20.0, 40), 320.0);
    }

    #[test]
    fn the_span_containing_t_starts_at_or_before_it() {
        let c = Config::embedded();
        let layer = &c.worlds["default"].layers[0];
        let k = Keyframe::containing(1234.5, layer, 0);
        assert_eq!((k.index, k.t0, k.t1), (61, 1220.0, 1240.0));
        assert!((k.fraction(1234.5) - 0.725).abs() < 1e-12);
        assert!(k.is_exact(1220.0) && !k.is_exact(1234.5));
        let k2 = Keyframe::containing(1234.5, layer, 2);
        assert_eq!((k2.t0, k2.t1), (1200.0, 1280.0));
        // On the grid: the keyframe itself.
        assert_eq!(Keyframe::containing(1240.0, layer, 0).t0, 1240.0);
        assert_eq!(Keyframe::containing(0.0, layer, 9).index, 0);
        // At the end of time the span is cut, never beyond MAX_TIME.
        let last = Keyframe::containing(MAX_TIME, layer, 0);
        assert!(last.t0 <= MAX_TIME && last.t1 <= MAX_TIME && last.t0 <= last.t1);
        assert_eq!(last.fraction(MAX_TIME), 0.0);
        // Every t lies in its span, on awkward spans too.
        for span in [0.1, 1.0 / 3.0, 7.3, 20.0] {
            for t in [0.3, 1e3 + 0.7, 123_456.789, 9.99e11, 1e12] {
                let k = Keyframe::on_grid(t, span);
                assert!(k.t0 <= t && (t < k.t1 || k.t1 == MAX_TIME), "{span} {t} {k:?}");
                assert_eq!(k.t0, k.index as f64 * span);
            }
        }
        assert!(Keyframe::instant(5.0).is_instant());
        assert_eq!(Keyframe::instant(5.0).fraction(7.0), 0.0);
    }

    #[test]
    fn prefetch_points_spread_over_the_second_half() {
        let mut points = Vec::new();
        for z in 0..4u32 {
            for x in -20..20i64 {
                for y in -20..20i64 {
                    let f = prefetch_at(z, x, y);
                    assert!((0.5..0.8).contains(&f), "{z}/{x}/{y}: {f}");
                    assert_eq!(f, prefetch_at(z, x, y));
                    points.push(f);
                }
            }
        }
        // Spread: the mean is near the middle of [0.5, 0.8) and every tenth of the
        // range holds a share of the tiles.
        let mean = points.iter().sum::<f64>() / points.len() as f64;
        assert!((mean - 0.65).abs() < 0.01, "{mean}");
        for bin in 0..10 {
            let lo = 0.5 + 0.03 * bin as f64;
            let n = points.iter().filter(|&&f| f >= lo && f < lo + 0.03).count();
            assert!(n > points.len() / 20, "bin {bin}: {n}");
        }
        // Worked out from the definition in Python's big integers, masked to 32 bits:
        // tile (0, 0, 0): h = 0xC2B2AE3D; h ^= h >> 16 = 0xC2B26C8F; h *= 0x7FEB352D
        // (mod 2^32) = 0xC21BB023; h ^= h >> 15 = 0xC21A3414.
        let h = 0xC21A_3414u32;
        assert_eq!(prefetch_at(0, 0, 0), 0.5 + 0.3 * f64::from(h) / 4_294_967_296.0);
        // Negative coordinates wrap as two's complement, as `x | 0` does in JS.
        assert_eq!(prefetch_at(1, -1, 2), prefetch_at(1, 0xFFFF_FFFF, 2));
    }
}
