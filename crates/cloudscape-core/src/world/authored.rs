//! Authored weather: storms and fronts a designer places and times
//! (`[[worlds.NAME.events]]`), and regional climate overrides
//! (`[[worlds.NAME.regions]]`).
//!
//! Each one pushes the humidity and activation brightness of the layers that place
//! its preset: a push `s` in [-1, 1] moves a brightness `b` toward 1 (`b + (1 − b)s`
//! for `s > 0`, more cloud) or toward 0 (`b(1 + s)` for `s < 0`, clear air), before
//! the height shaping and Dobashi ellipsoids. So the noise still draws the cloud's
//! texture and the automaton its life; the designer says where and when.
//!
//! Every push is a smooth function of world position and time: storms fall off
//! from their centre, fronts across their band, regions across their `blend`
//! margin, and all of them fade in and out over `ramp` seconds. The automaton
//! evaluates pushes once per run (at the middle of the epoch the run serves, in
//! the wind frame, see `automaton::run`), so between runs a storm moves with the
//! wind and the epoch's fade carries it on; nothing pops.

use rayon::prelude::*;
use serde::Serialize;

/// A storm: a moving Dobashi ellipsoid of more (or, with negative intensity, less) cloud.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Storm {
    /// Centre at `start` (or, with a path, its altitude only): world metres x, y, altitude.
    pub centre: [f64; 3],
    /// Semi-axes in metres.
    pub radii: [f64; 3],
    /// Drift of the centre, m/s (ignored with a path).
    pub velocity: [f64; 2],
    /// Waypoints `[t, x, y]` (ascending t): the centre moves linearly between them
    /// and rests at the first before it and at the last after it.
    pub path: Vec<[f64; 3]>,
}

/// A front: a straight line moving along `velocity`, perpendicular to it, with a
/// band of cloud of half-width `width` and, optionally, another climate behind it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Front {
    /// A point on the line at `start`, world metres.
    pub origin: [f64; 2],
    /// The line's motion, m/s (nonzero); the line is perpendicular to it.
    pub velocity: [f64; 2],
    /// Half-width of the band, metres.
    pub width: f64,
    /// Push in the air the front has passed (0: the climate returns behind it).
    pub behind: f64,
    /// Length of the line along itself, centred on the origin's track (None: endless).
    pub length: Option<f64>,
}

/// Where a regional override applies.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum Area {
    /// `[x0, y0, x1, y1]`, world metres.
    Box([f64; 4]),
    /// A simple polygon, world metres (even-odd rule).
    Polygon(Polygon),
}

/// A simple polygon's vertices, world metres, and their bounding box: a point outside
/// the box is outside the polygon, so its push is known without measuring every edge
/// (up to 1024 of them, for every cell of every run).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(transparent)]
pub struct Polygon {
    vertices: Vec<[f64; 2]>,
    /// `[x0, y0, x1, y1]`; derived from the vertices, so not serialised (a layer's
    /// fingerprint is that of the vertices alone).
    #[serde(skip)]
    bounds: [f64; 4],
}

impl Polygon {
    /// The polygon through `vertices` (implicitly closed).
    pub fn new(vertices: Vec<[f64; 2]>) -> Polygon {
        let mut bounds = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        for &[x, y] in &vertices {
            bounds = [bounds[0].min(x), bounds[1].min(y), bounds[2].max(x), bounds[3].max(y)];
        }
        Polygon { vertices, bounds }
    }

    /// The vertices, world metres.
    pub fn vertices(&self) -> &[[f64; 2]] {
        &self.vertices
    }

    /// The bounding box `[x0, y0, x1, y1]`, world metres.
    pub fn bounds(&self) -> [f64; 4] {
        self.bounds
    }
}

/// What an authored influence is.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum Shape {
    /// A moving ellipsoid.
    Storm(Storm),
    /// A moving line.
    Front(Front),
    /// A fixed area (regional override), full strength `blend` metres inside its edge.
    Region {
        /// The area.
        area: Area,
        /// Width of the margin over which the push ramps up inside the edge, metres.
        blend: f64,
    },
}

/// One authored influence on one layer: a shape, how hard it pushes, and when.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Influence {
    /// Where it acts.
    pub shape: Shape,
    /// Push at full strength, in [-1, 1].
    pub intensity: f64,
    /// World time it begins to fade in, seconds (None: it has always been there).
    pub start: Option<f64>,
    /// World time it has faded out, seconds (None: never).
    pub end: Option<f64>,
    /// Seconds over which it fades in after `start` and out before `end` (0: at once).
    pub ramp: f64,
}

/// `3w² − 2w³` on w clamped to [0, 1]: 0 and 1 with zero slope at both ends.
fn smooth(w: f64) -> f64 {
    let w = w.clamp(0.0, 1.0);
    w * w * (3.0 - 2.0 * w)
}

impl Influence {
    /// Strength in [0, 1] at time `t` from the start/end ramps.
    pub fn envelope(&self, t: f64) -> f64 {
        let edge = |d: f64| {
            if self.ramp > 0.0 {
                smooth(d / self.ramp)
            } else {
                f64::from(d >= 0.0)
            }
        };
        let rise = self.start.map_or(1.0, |start| edge(t - start));
        match self.end {
            Some(end) => rise.min(edge(end - t)),
            None => rise,
        }
    }

    /// Signed push at world position (x, y, altitude z), metres, and time t.
    pub fn push(&self, x: f64, y: f64, z: f64, t: f64) -> f64 {
        let e = self.envelope(t);
        if e == 0.0 {
            return 0.0;
        }
        let w = match &self.shape {
            Shape::Storm(s) => {
                let [cx, cy] = s.centre_at(self.start.unwrap_or(0.0), t);
                let d = |v: f64, c: f64, r: f64| (v - c) / r;
                let r2 =
                    d(x, cx, s.radii[0]).powi(2) + d(y, cy, s.radii[1]).powi(2) + d(z, s.centre[2], s.radii[2]).powi(2);
                self.intensity * smooth(1.0 - r2)
            }
            Shape::Front(f) => {
                let speed = f.velocity[0].hypot(f.velocity[1]);
                let n = [f.velocity[0] / speed, f.velocity[1] / speed];
                let moved = t - self.start.unwrap_or(0.0);
                let (px, py) = (
                    x - f.origin[0] - f.velocity[0] * moved,
                    y - f.origin[1] - f.velocity[1] * moved,
                );
                // Signed distance ahead of the line, and along it.
                let ahead = px * n[0] + py * n[1];
                let along = -px * n[1] + py * n[0];
                let band = smooth(1.0 - (ahead / f.width).powi(2));
                let passed = smooth(0.5 - ahead / (2.0 * f.width));
                let ends = f.length.map_or(1.0, |l| smooth((0.5 * l - along.abs()) / f.width));
                (self.intensity * band + f.behind * passed) * ends
            }
            Shape::Region { area, blend } => {
                // Outside the bounds the depth is negative, where both ramps give 0.
                let strength = if !area.bounds_hold(x, y) {
                    0.0
                } else if *blend > 0.0 {
                    smooth(area.depth(x, y) / blend)
                } else {
                    f64::from(area.depth(x, y) >= 0.0)
                };
                self.intensity * strength
            }
        };
        w * e
    }
}

impl Storm {
    /// The centre's (x, y) at time `t` for a storm that starts at `start` (its
    /// `centre` is where it is then; 0 for a storm without a start).
    pub fn centre_at(&self, start: f64, t: f64) -> [f64; 2] {
        let Some(first) = self.path.first() else {
            let dt = t - start;
            return [
                self.centre[0] + self.velocity[0] * dt,
                self.centre[1] + self.velocity[1] * dt,
            ];
        };
        if t <= first[0] {
            return [first[1], first[2]];
        }
        for w in self.path.windows(2) {
            let (a, b) = (w[0], w[1]);
            if t <= b[0] {
                let f = (t - a[0]) / (b[0] - a[0]);
                return [a[1] + (b[1] - a[1]) * f, a[2] + (b[2] - a[2]) * f];
            }
        }
        let last = self.path[self.path.len() - 1];
        [last[1], last[2]]
    }
}

impl Area {
    /// Whether (x, y) lies in the area's bounding box, edges included: outside it,
    /// [`Area::depth`] is negative.
    pub fn bounds_hold(&self, x: f64, y: f64) -> bool {
        let [x0, y0, x1, y1] = match self {
            Area::Box(b) => *b,
            Area::Polygon(p) => p.bounds,
        };
        x0 <= x && x <= x1 && y0 <= y && y <= y1
    }

    /// Signed distance from the edge, metres: positive inside, negative outside.
    pub fn depth(&self, x: f64, y: f64) -> f64 {
        match self {
            Area::Box([x0, y0, x1, y1]) => (x - x0).min(x1 - x).min(y - y0).min(y1 - y),
            Area::Polygon(p) => {
                let v = &p.vertices;
                let mut inside = false;
                let mut nearest = f64::INFINITY;
                for (i, &a) in v.iter().enumerate() {
                    let b = v[(i + 1) % v.len()];
                    if (a[1] > y) != (b[1] > y) && x < a[0] + (y - a[1]) / (b[1] - a[1]) * (b[0] - a[0]) {
                        inside = !inside;
                    }
                    let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                    let f = (((x - a[0]) * ex + (y - a[1]) * ey) / (ex * ex + ey * ey)).clamp(0.0, 1.0);
                    nearest = nearest.min((x - a[0] - f * ex).hypot(y - a[1] - f * ey));
                }
                if inside { nearest } else { -nearest }
            }
        }
    }
}

/// The summed push of `influences` at a point, clamped to [-1, 1] (0 with none).
pub fn push(influences: &[Influence], x: f64, y: f64, z: f64, t: f64) -> f32 {
    total(influences.iter().map(|i| i.push(x, y, z, t)))
}

/// The sum of pushes in their order, clamped to [-1, 1]. Every way of pushing sums
/// through here, so the same terms give the same bits.
fn total(terms: impl Iterator<Item = f64>) -> f32 {
    // -0.0 is the identity of addition (and where `Iterator::sum` of f64 starts).
    terms.fold(-0.0, |s, v| s + v).clamp(-1.0, 1.0) as f32
}

/// The push of `influences` at time `t` over a grid of columns (x along `xs`, y along
/// `ys`, world metres) at any altitude. A polygon region (up to 1024 edges) is
/// measured once per column of its bounding box, where [`push`] measures it at every
/// point of every level; the other shapes cost a few operations and are measured at
/// each point. The terms and their order are [`push`]'s, so the bits are too.
pub struct GridPushes<'a> {
    influences: &'a [Influence],
    t: f64,
    xs: Vec<f64>,
    ys: Vec<f64>,
    /// Per influence: a polygon region's push over the columns of its bounding box.
    planes: Vec<Option<Plane>>,
}

/// One influence's push over the grid's columns `c0..c1` and rows `r0..r1`.
struct Plane {
    c0: usize,
    c1: usize,
    r0: usize,
    r1: usize,
    values: Vec<f64>,
}

impl Plane {
    fn get(&self, c: usize, r: usize) -> Option<f64> {
        let inside = (self.c0..self.c1).contains(&c) && (self.r0..self.r1).contains(&r);
        inside.then(|| self.values[(r - self.r0) * (self.c1 - self.c0) + (c - self.c0)])
    }
}

impl<'a> GridPushes<'a> {
    /// How many whole grids of polygon planes one `GridPushes` may hold.
    pub const MOST_PLANES: usize = 4;

    /// Measures the polygon regions of `influences` over the grid `xs` × `ys`. The
    /// planes hold at most [`GridPushes::MOST_PLANES`] grids' worth of columns (8
    /// bytes each), so memory stays within a few times the field window's (12 bytes
    /// a column); polygons beyond that are measured at each point, as by [`push`].
    pub fn new(influences: &'a [Influence], t: f64, xs: Vec<f64>, ys: Vec<f64>) -> GridPushes<'a> {
        let mut room = Self::MOST_PLANES * xs.len() * ys.len();
        let planes = influences
            .iter()
            .map(|i| {
                let Shape::Region {
                    area: Area::Polygon(p), ..
                } = &i.shape
                else {
                    return None;
                };
                // The index span whose coordinates fall in the bounding box (every
                // column in it is measured, so the coordinates need no order).
                let span = |v: &[f64], lo: f64, hi: f64| {
                    let first = v.iter().position(|&x| lo <= x && x <= hi)?;
                    let last = v.iter().rposition(|&x| lo <= x && x <= hi)?;
                    Some((first, last + 1))
                };
                let [x0, y0, x1, y1] = p.bounds;
                let ((c0, c1), (r0, r1)) = (span(&xs, x0, x1)?, span(&ys, y0, y1)?);
                room = room.checked_sub((c1 - c0) * (r1 - r0))?;
                let mut values = vec![0f64; (c1 - c0) * (r1 - r0)];
                values.par_chunks_mut(c1 - c0).enumerate().for_each(|(r, row)| {
                    for (c, v) in row.iter_mut().enumerate() {
                        // A region does not depend on altitude.
                        *v = i.push(xs[c0 + c], ys[r0 + r], 0.0, t);
                    }
                });
                Some(Plane { c0, c1, r0, r1, values })
            })
            .collect();
        GridPushes {
            influences,
            t,
            xs,
            ys,
            planes,
        }
    }

    /// Whether the push is the same at every altitude (no storm).
    pub fn flat(&self) -> bool {
        !self.influences.iter().any(|i| matches!(i.shape, Shape::Storm(_)))
    }

    /// The push at column `c`, row `r` and altitude `z`: what [`push`] gives at
    /// (`xs[c]`, `ys[r]`, `z`).
    pub fn at(&self, c: usize, r: usize, z: f64) -> f32 {
        let (x, y) = (self.xs[c], self.ys[r]);
        total(self.influences.iter().zip(&self.planes).map(
            |(i, plane)| match plane.as_ref().and_then(|p| p.get(c, r)) {
                Some(v) => v,
                None => i.push(x, y, z, self.t),
            },
        ))
    }
}

/// A brightness `b` pushed by `s` in [-1, 1]: toward 1 for `s > 0`, toward 0 for `s < 0`.
#[inline]
pub fn pushed(b: f32, s: f32) -> f32 {
    if s >= 0.0 { b + (1.0 - b) * s } else { b * (1.0 + s) }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn storm() -> Influence {
        Influence {
            shape: Shape::Storm(Storm {
                centre: [0.0, 0.0, 3000.0],
                radii: [5000.0, 5000.0, 4000.0],
                velocity: [10.0, 0.0],
                path: Vec::new(),
            }),
            intensity: 1.0,
            start: Some(1000.0),
            end: Some(5000.0),
            ramp: 500.0,
        }
    }

    #[test]
    fn a_storm_moves_and_fades_in_and_out() {
        let s = storm();
        assert_eq!(s.push(0.0, 0.0, 3000.0, 900.0), 0.0, "before its start");
        assert_eq!(
            s.push(10_000.0, 0.0, 3000.0, 2000.0),
            1.0,
            "centre after 1000 s at 10 m/s"
        );
        assert_eq!(s.push(0.0, 0.0, 3000.0, 2000.0), 0.0, "its old place is 2 radii behind");
        assert!(
            (s.push(2500.0, 0.0, 3000.0, 1250.0) - 0.5).abs() < 1e-12,
            "half way up its ramp"
        );
        assert_eq!(s.push(40_000.0, 0.0, 3000.0, 5000.0), 0.0, "gone at its end");
        assert!(s.push(5000.0, 0.0, 3000.0, 1500.0) > s.push(7000.0, 0.0, 3000.0, 1500.0));
    }

    #[test]
    fn a_path_is_followed_and_held_at_its_ends() {
        let s = Storm {
            centre: [0.0, 0.0, 0.0],
            radii: [1.0; 3],
            velocity: [0.0; 2],
            path: vec![[100.0, 0.0, 0.0], [200.0, 1000.0, 0.0], [400.0, 1000.0, 2000.0]],
        };
        assert_eq!(s.centre_at(0.0, 50.0), [0.0, 0.0]);
        assert_eq!(s.centre_at(0.0, 150.0), [500.0, 0.0]);
        assert_eq!(s.centre_at(0.0, 300.0), [1000.0, 1000.0]);
        assert_eq!(s.centre_at(0.0, 1e12), [1000.0, 2000.0]);
    }

    fn front() -> Influence {
        Influence {
            shape: Shape::Front(Front {
                origin: [0.0, 0.0],
                velocity: [0.0, 5.0],
                width: 2000.0,
                behind: -0.5,
                length: Some(20_000.0),
            }),
            intensity: 1.0,
            start: None,
            end: None,
            ramp: 0.0,
        }
    }

    #[test]
    fn a_front_has_a_band_and_another_climate_behind() {
        let f = front();
        // After 1000 s the line is at y = 5000.
        assert_eq!(f.push(0.0, 5000.0, 0.0, 1000.0), 1.0 - 0.5 * 0.5);
        assert_eq!(f.push(0.0, 9000.0, 0.0, 1000.0), 0.0, "ahead of the band");
        assert_eq!(f.push(0.0, -9000.0, 0.0, 1000.0), -0.5, "behind it");
        assert_eq!(f.push(30_000.0, 5000.0, 0.0, 1000.0), 0.0, "beyond its length");
    }

    /// A concave L in the square [0, 100]²: its notch is outside.
    fn l_shape() -> Vec<[f64; 2]> {
        vec![
            [0.0, 0.0],
            [100.0, 0.0],
            [100.0, 20.0],
            [20.0, 20.0],
            [20.0, 100.0],
            [0.0, 100.0],
        ]
    }

    #[test]
    fn areas_measure_depth_inside_their_edge() {
        let b = Area::Box([0.0, 0.0, 100.0, 50.0]);
        assert_eq!(b.depth(10.0, 25.0), 10.0);
        assert_eq!(b.depth(-10.0, 25.0), -10.0);
        // The same square as a polygon, and a concave L.
        let p = Area::Polygon(Polygon::new(vec![[0.0, 0.0], [100.0, 0.0], [100.0, 50.0], [0.0, 50.0]]));
        assert_eq!(p.depth(10.0, 25.0), 10.0);
        assert_eq!(p.depth(-10.0, 25.0), -10.0);
        let l = Area::Polygon(Polygon::new(l_shape()));
        assert!(l.depth(10.0, 50.0) > 0.0);
        assert!(l.depth(50.0, 50.0) < 0.0, "the notch of the L is outside");
        assert_eq!(l.depth(50.0, 30.0), -10.0);
    }

    #[test]
    fn outside_its_bounds_an_area_is_outside_and_a_polygon_serialises_as_its_vertices() {
        let vertices = l_shape();
        let areas = [
            Area::Box([0.0, 0.0, 100.0, 100.0]),
            Area::Polygon(Polygon::new(vertices.clone())),
        ];
        for area in &areas {
            // Every point of a grid around the area: outside the bounds, the depth is
            // negative (the early-out in `push` skips only what would give 0); on the
            // bounds' edges they hold.
            for i in -20..=120 {
                for j in -20..=120 {
                    let (x, y) = (i as f64 * 1.25 - 12.5, j as f64 * 1.25 - 12.5);
                    if !area.bounds_hold(x, y) {
                        assert!(area.depth(x, y) < 0.0, "({x}, {y}) outside the bounds of {area:?}");
                    }
                }
            }
            assert!(area.bounds_hold(0.0, 0.0) && area.bounds_hold(100.0, 100.0));
        }
        // The fingerprint of a layer is that of the configured vertices alone.
        assert_eq!(
            serde_json::to_value(&areas[1]).unwrap(),
            serde_json::json!({ "Polygon": vertices })
        );
    }

    #[test]
    fn per_column_pushes_are_the_plain_sum_bit_for_bit() {
        // Regions, a front and a storm overlapping around the origin: the L scaled to
        // 20 km, a box across it, the front's band, the storm at its centre.
        let region = |area, intensity| Influence {
            shape: Shape::Region { area, blend: 1500.0 },
            intensity,
            start: None,
            end: None,
            ramp: 0.0,
        };
        let l = region(
            Area::Polygon(Polygon::new(l_shape().iter().map(|v| v.map(|c| c * 200.0)).collect())),
            0.7,
        );
        let b = region(Area::Box([-8000.0, 2000.0, 12_000.0, 9000.0]), -0.6);
        let lists = [
            vec![l.clone(), front(), storm(), b.clone()],
            vec![storm(), l.clone(), b.clone()],
            vec![l.clone(), b.clone(), front()],
            vec![l.clone(), l.clone(), storm(), storm()],
            vec![],
        ];
        // The sum as `push` always formed it: every influence at the point, in order.
        let plain = |list: &[Influence], x, y, z, t| {
            list.iter().map(|i| i.push(x, y, z, t)).sum::<f64>().clamp(-1.0, 1.0) as f32
        };
        let mut nonzero = 0;
        let coordinates = |offset: f64| (-25..=25).map(|i| i as f64 * 1000.0 + offset).collect::<Vec<f64>>();
        let (xs, ys) = (coordinates(0.25), coordinates(-0.5));
        for list in &lists {
            for t in [1500.0, 3000.0] {
                let p = GridPushes::new(list, t, xs.clone(), ys.clone());
                for (c, &x) in xs.iter().enumerate() {
                    for (r, &y) in ys.iter().enumerate() {
                        for z in [0.0, 1500.0, 3000.0, 5500.0] {
                            let want = plain(list, x, y, z, t);
                            assert_eq!(p.at(c, r, z).to_bits(), want.to_bits(), "{x} {y} {z} {t}");
                            assert_eq!(push(list, x, y, z, t).to_bits(), want.to_bits());
                            nonzero += usize::from(want != 0.0);
                        }
                    }
                }
            }
        }
        assert!(nonzero > 10_000, "the influences overlap the grid: {nonzero}");
        // Past the planes' room the last polygons are measured at each point: the
        // same bits again.
        // A triangle over the whole grid (so each plane is a whole grid), and a box
        // (never a plane) among them.
        let whole = region(
            Area::Polygon(Polygon::new(vec![[-1e5, -1e5], [1e5, -1e5], [0.0, 1e5]])),
            0.2,
        );
        let mut many = vec![whole; GridPushes::MOST_PLANES + 2];
        many.insert(2, b.clone());
        let p = GridPushes::new(&many, 0.0, xs.clone(), ys.clone());
        let planes: Vec<bool> = p.planes.iter().map(Option::is_some).collect();
        assert_eq!(planes, [true, true, false, true, true, false, false]);
        for (c, &x) in xs.iter().enumerate() {
            for (r, &y) in ys.iter().enumerate() {
                assert_eq!(p.at(c, r, 0.0).to_bits(), plain(&many, x, y, 0.0, 0.0).to_bits());
            }
        }
        let flat = |list: &[Influence]| GridPushes::new(list, 0.0, xs.clone(), ys.clone()).flat();
        assert!(flat(&lists[2]) && !flat(&lists[0]) && flat(&lists[4]));
    }

    #[test]
    fn pushes_sum_clamp_and_move_brightness_toward_their_end() {
        let s = storm();
        assert_eq!(push(&[s.clone(), s.clone()], 10_000.0, 0.0, 3000.0, 2000.0), 1.0);
        assert_eq!(push(&[], 0.0, 0.0, 0.0, 0.0), 0.0);
        assert_eq!(pushed(0.2, 1.0), 1.0);
        assert_eq!(pushed(0.2, -1.0), 0.0);
        assert_eq!(pushed(0.2, 0.0), 0.2);
        assert_eq!(pushed(0.5, 0.5), 0.75);
        assert_eq!(pushed(0.5, -0.5), 0.25);
    }
}
