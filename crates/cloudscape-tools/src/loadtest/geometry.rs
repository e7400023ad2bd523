//! Where the groups of players are: the world they move through and each group's
//! itinerary. A group's position is a pure function of the seconds since the run
//! started (each itinerary is laid out once, before the first request), so the closed
//! and open loops replay the same world and request *i* of a seed is always the same.
//!
//! Two geometries:
//! - **towns** (default): a world of play areas (the server's warm areas when its
//!   discovery lists them, else [`generated_towns`]) joined by roads. Every group starts
//!   in a town. Walking groups stay near their town (strolls in it, walks out along a
//!   road and back); riding groups ride the roads from town to town; flying groups fly
//!   straight to any town at altitude. Riders and flyers stop in each town for
//!   [`DWELL`] seconds, so most players are in or near a town at any moment, as in an
//!   MMO.
//! - **spread** (before issue 34): groups start [`SPREAD_SPACING`] apart and each
//!   walks its own path of straight legs at 12 m/s: every group is a place of its own.

use serde::Serialize;

/// A deterministic pseudo-random number in [0, 1) from a key (SplitMix64).
pub(crate) fn unit(key: u64) -> f64 {
    let mut z = key.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// A value in `range` from a key.
fn within((lo, hi): (f64, f64), key: u64) -> f64 {
    lo + (hi - lo) * unit(key)
}

/// Which world the groups move through.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum GeometryKind {
    /// Towns and the roads between them (the default).
    Towns,
    /// Groups [`SPREAD_SPACING`] apart, each on its own path (before issue 34).
    Spread,
}

impl GeometryKind {
    pub fn parse(s: &str) -> Option<GeometryKind> {
        match s {
            "towns" => Some(GeometryKind::Towns),
            "spread" => Some(GeometryKind::Spread),
            _ => None,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            GeometryKind::Towns => "towns",
            GeometryKind::Spread => "spread",
        }
    }
}

/// How a group travels, with its speed range (horizontal, m/s).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TravelMode {
    Walking,
    Riding,
    Flying,
}

impl TravelMode {
    /// Horizontal speed range, m/s: a person on foot, a mount, a flying mount.
    pub fn speeds(self) -> (f64, f64) {
        match self {
            TravelMode::Walking => (1.2, 1.6),
            TravelMode::Riding => (8.0, 12.0),
            TravelMode::Flying => (30.0, 60.0),
        }
    }

    /// The mode of the group keyed `key`: 40 % walking, 40 % riding, 20 % flying.
    fn pick(key: u64) -> TravelMode {
        match unit(key) {
            u if u < 0.4 => TravelMode::Walking,
            u if u < 0.8 => TravelMode::Riding,
            _ => TravelMode::Flying,
        }
    }
}

/// Seconds riders and flyers stop in each town they reach.
pub const DWELL: (f64, f64) = (300.0, 1800.0);
/// Seconds walkers pause at each end of a stroll.
const PAUSE: (f64, f64) = (30.0, 180.0);
/// How far walkers walk out along a road before turning back, metres.
const WALK_OUT: (f64, f64) = (1_000.0, 3_000.0);
/// Flyers' cruising height above the ground, metres.
const FLIGHT_HEIGHT: (f64, f64) = (1_000.0, 3_000.0);
/// Horizontal distance over which a flyer climbs to its cruising height (and descends).
const CLIMB_METRES: f64 = 2_000.0;
/// Distance between the generated towns' grid points, metres, and the most each is moved off it.
const TOWN_SPACING: f64 = 24_000.0;
const TOWN_JITTER: f64 = 4_000.0;
/// Radius of a generated town: where its groups stand and stroll, metres.
const TOWN_RADIUS: f64 = 800.0;
/// Where the generated towns' middle one is: the middle of level-0 tile (0, 0) of a
/// 100 m layer, where the spread geometry's first group starts too.
const WORLD_MIDDLE: [f64; 2] = [12_800.0, 12_800.0];
/// The key of the generated layout's jitter: a constant, not the run's seed.
const TOWN_LAYOUT_KEY: u64 = 0x0770_76e5;
/// Each town has roads to this many of its nearest towns (besides a spanning tree).
const ROADS_PER_TOWN: usize = 2;

/// Spread geometry: distance between neighbouring groups' starting points, metres.
pub const SPREAD_SPACING: f64 = 30_000.0;
/// Spread geometry: speed along the path (a mounted player), m/s, and leg length, m.
const SPREAD_SPEED: f64 = 12.0;
const SPREAD_LEG: f64 = 2_000.0;

/// A play area groups stay in: a town of the generated layout or a warm area of the
/// server.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Town {
    pub name: String,
    /// Where groups stand and stroll: within `radius` of `centre`, metres.
    pub centre: [f64; 2],
    pub radius: f64,
}

impl Town {
    /// The town a warm area describes: centred on its polygon's centroid (its box's
    /// centre without one); groups stay within a quarter of the box's smaller side of
    /// it (so a group of players, 600 m across, stays inside an area of a few km).
    pub fn from_area(name: &str, bbox: [f64; 4], polygon: Option<&[[f64; 2]]>) -> Option<Town> {
        let [x0, y0, x1, y1] = bbox;
        if !(bbox.iter().all(|v| v.is_finite()) && x0 < x1 && y0 < y1) {
            return None;
        }
        let centre = polygon.and_then(centroid).unwrap_or([(x0 + x1) / 2.0, (y0 + y1) / 2.0]);
        Some(Town {
            name: name.to_string(),
            centre,
            radius: 0.25 * (x1 - x0).min(y1 - y0),
        })
    }

    /// A point of the town from a key: uniform over its disc.
    fn spot(&self, key: u64) -> [f64; 2] {
        let r = self.radius * unit(key).sqrt();
        let a = unit(key ^ 0x5bd1_e995) * std::f64::consts::TAU;
        [self.centre[0] + r * a.cos(), self.centre[1] + r * a.sin()]
    }

    pub fn contains(&self, p: [f64; 2]) -> bool {
        distance(p, self.centre) <= self.radius + 1e-6
    }
}

/// The area centroid of a simple polygon (shoelace formula); `None` when degenerate.
fn centroid(poly: &[[f64; 2]]) -> Option<[f64; 2]> {
    let (mut a, mut cx, mut cy) = (0.0, 0.0, 0.0);
    for (i, p) in poly.iter().enumerate() {
        let q = poly[(i + 1) % poly.len()];
        let cross = p[0] * q[1] - q[0] * p[1];
        a += cross;
        cx += (p[0] + q[0]) * cross;
        cy += (p[1] + q[1]) * cross;
    }
    (a.abs() > 1e-9 && poly.len() >= 3).then(|| [cx / (3.0 * a), cy / (3.0 * a)])
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// The towns used when the server lists no warm areas: nine on a 3 × 3 grid
/// [`TOWN_SPACING`] apart around [`WORLD_MIDDLE`], each moved up to [`TOWN_JITTER`] off
/// its grid point (the same layout for every seed: the world does not change with its
/// players). The first, in the middle, is the capital.
pub fn generated_towns() -> Vec<Town> {
    let mut grid: Vec<(i64, i64)> = vec![(0, 0)];
    grid.extend(
        (-1..=1)
            .flat_map(|j| (-1..=1).map(move |i| (i, j)))
            .filter(|&g| g != (0, 0)),
    );
    grid.iter()
        .enumerate()
        .map(|(n, &(i, j))| {
            let k = TOWN_LAYOUT_KEY + 16 * n as u64;
            Town {
                name: format!("town-{n}"),
                centre: [
                    WORLD_MIDDLE[0] + i as f64 * TOWN_SPACING + (unit(k) - 0.5) * 2.0 * TOWN_JITTER,
                    WORLD_MIDDLE[1] + j as f64 * TOWN_SPACING + (unit(k + 1) - 0.5) * 2.0 * TOWN_JITTER,
                ],
                radius: TOWN_RADIUS,
            }
        })
        .collect()
}

/// Straight roads between towns: a minimum spanning tree (so every town is reachable)
/// plus each town's [`ROADS_PER_TOWN`] nearest neighbours. Pairs `(a, b)` with `a < b`,
/// sorted.
pub fn roads(towns: &[Town]) -> Vec<(usize, usize)> {
    let n = towns.len();
    let d = |a: usize, b: usize| distance(towns[a].centre, towns[b].centre);
    let mut out = Vec::new();
    // Prim's algorithm, O(n²): the towns are a handful.
    // Town 0 is linked first; `best[b]` is b's nearest linked town and its distance.
    let mut linked: Vec<bool> = (0..n).map(|b| b == 0).collect();
    let mut best: Vec<(f64, usize)> = (0..n).map(|b| (d(0, b), 0)).collect();
    for _ in 1..n {
        let next = (0..n)
            .filter(|&b| !linked[b])
            .min_by(|&a, &b| best[a].0.total_cmp(&best[b].0))
            .expect("an unlinked town");
        linked[next] = true;
        out.push((best[next].1.min(next), best[next].1.max(next)));
        for b in 0..n {
            if !linked[b] && d(next, b) < best[b].0 {
                best[b] = (d(next, b), next);
            }
        }
    }
    for a in 0..n {
        let mut others: Vec<usize> = (0..n).filter(|&b| b != a).collect();
        others.sort_by(|&x, &y| d(a, x).total_cmp(&d(a, y)));
        out.extend(others.into_iter().take(ROADS_PER_TOWN).map(|b| (a.min(b), a.max(b))));
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// One piece of an itinerary: from `from` at `start` to `to` at `end` in a straight
/// line at constant speed (a stop when they are equal). Points are x, y and height
/// above the ground, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Segment {
    start: f64,
    end: f64,
    from: [f64; 3],
    to: [f64; 3],
}

/// Where one group is over the run: contiguous segments from 0 to past the run's end.
#[derive(Clone, Debug)]
pub struct Itinerary {
    pub mode: TravelMode,
    /// Horizontal speed when moving, m/s.
    pub speed: f64,
    segments: Vec<Segment>,
}

impl Itinerary {
    fn builder(mode: TravelMode, speed: f64, at: [f64; 3]) -> ItineraryBuilder {
        ItineraryBuilder {
            it: Itinerary {
                mode,
                speed,
                segments: Vec::new(),
            },
            t: 0.0,
            at,
        }
    }

    /// Where the group is `s` seconds into the run: x, y and height above the ground
    /// (its last point past the laid-out horizon).
    pub fn at(&self, s: f64) -> [f64; 3] {
        let i = self.segments.partition_point(|g| g.end <= s);
        let Some(g) = self.segments.get(i) else {
            return self.segments.last().map_or([0.0; 3], |g| g.to);
        };
        let f = if g.end > g.start {
            ((s - g.start) / (g.end - g.start)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        std::array::from_fn(|k| g.from[k] + (g.to[k] - g.from[k]) * f)
    }

    /// The horizontal speeds of the moving segments, m/s (for the tests).
    pub fn moving_speeds(&self) -> impl Iterator<Item = f64> + '_ {
        self.segments
            .iter()
            .filter(|g| g.from[..2] != g.to[..2])
            .map(|g| distance([g.from[0], g.from[1]], [g.to[0], g.to[1]]) / (g.end - g.start))
    }
}

/// Lays an itinerary out segment by segment.
struct ItineraryBuilder {
    it: Itinerary,
    t: f64,
    at: [f64; 3],
}

impl ItineraryBuilder {
    fn stop(&mut self, seconds: f64) {
        self.push(self.at, self.t + seconds.max(0.0));
    }

    /// Moves to `to` at the itinerary's horizontal speed.
    fn go(&mut self, to: [f64; 3]) {
        let d = distance([self.at[0], self.at[1]], [to[0], to[1]]);
        if d > 0.0 {
            self.push(to, self.t + d / self.it.speed);
        }
    }

    fn push(&mut self, to: [f64; 3], end: f64) {
        self.it.segments.push(Segment {
            start: self.t,
            end,
            from: self.at,
            to,
        });
        self.t = end;
        self.at = to;
    }
}

/// The groups' world and every place's itinerary over the run.
#[derive(Clone, Debug)]
pub struct Geometry {
    pub kind: GeometryKind,
    /// The towns (empty for [`GeometryKind::Spread`]) and the roads between them.
    pub towns: Vec<Town>,
    pub roads: Vec<(usize, usize)>,
    /// Whether the towns are the server's warm areas (else generated).
    pub towns_from_server: bool,
    /// One itinerary per place; group `g` follows place `g mod places`.
    places: Vec<Itinerary>,
}

impl Geometry {
    /// Lays out `places` itineraries covering `horizon` seconds. `towns` are the
    /// server's warm areas (empty: [`generated_towns`]).
    pub fn new(kind: GeometryKind, places: usize, seed: u64, towns: Vec<Town>, horizon: f64) -> Geometry {
        let places = places.max(1);
        match kind {
            GeometryKind::Spread => Geometry {
                kind,
                towns: Vec::new(),
                roads: Vec::new(),
                towns_from_server: false,
                places: (0..places).map(|p| spread_path(p, places, seed, horizon)).collect(),
            },
            GeometryKind::Towns => {
                let towns_from_server = !towns.is_empty();
                let towns = if towns_from_server { towns } else { generated_towns() };
                let roads = roads(&towns);
                let places = (0..places)
                    .map(|p| town_itinerary(&towns, &roads, p, seed, horizon))
                    .collect();
                Geometry {
                    kind,
                    towns,
                    roads,
                    towns_from_server,
                    places,
                }
            }
        }
    }

    /// Where group `g` is `s` seconds into the run: x, y and height above the ground.
    pub fn position(&self, g: usize, s: f64) -> [f64; 3] {
        self.places[g % self.places.len()].at(s)
    }

    /// The itinerary group `g` follows.
    pub fn itinerary(&self, g: usize) -> &Itinerary {
        &self.places[g % self.places.len()]
    }

    /// Distinct places: the tiles `tile_side` metres wide (level 0 of the world's
    /// finest layer) that held at least one of the `groups` groups' centres at a whole
    /// second in `[from_s, to_s]`.
    pub fn distinct_places(&self, groups: usize, tile_side: f64, from_s: f64, to_s: f64) -> usize {
        let mut tiles = std::collections::HashSet::new();
        let used = groups.min(self.places.len());
        let mut s = from_s.ceil();
        while s <= to_s {
            for g in 0..used {
                let p = self.position(g, s);
                tiles.insert(((p[0] / tile_side).floor() as i64, (p[1] / tile_side).floor() as i64));
            }
            s += 1.0;
        }
        tiles.len()
    }
}

/// The spread geometry's path of place `p` of `places` (homes on a square grid
/// [`SPREAD_SPACING`] apart): straight legs of [`SPREAD_LEG`], each turning up to 60°
/// from the last, at [`SPREAD_SPEED`]. The same path as before issue 34.
fn spread_path(p: usize, places: usize, seed: u64, horizon: f64) -> Itinerary {
    let side = (places as f64).sqrt().ceil().max(1.0) as usize;
    let key = seed ^ (p as u64) << 20;
    let mut at = [
        12_800.0 + SPREAD_SPACING * (p % side) as f64,
        12_800.0 + SPREAD_SPACING * (p / side) as f64,
        0.0,
    ];
    let mut heading = unit(key) * std::f64::consts::TAU;
    let mut b = Itinerary::builder(TravelMode::Riding, SPREAD_SPEED, at);
    let mut k = 1u64;
    while b.t <= horizon {
        heading += (unit(key.wrapping_add(k)) - 0.5) * 2.0 * 60f64.to_radians();
        at = [
            at[0] + SPREAD_LEG * heading.sin(),
            at[1] + SPREAD_LEG * heading.cos(),
            0.0,
        ];
        b.go(at);
        k += 1;
    }
    b.it
}

/// The town a group calls home: Zipf weights (the first town twice as busy as the
/// second, three times the third, …), as an MMO's capital is.
fn home_town(towns: usize, key: u64) -> usize {
    let total: f64 = (1..=towns).map(|r| 1.0 / r as f64).sum();
    let mut u = unit(key) * total;
    for r in 0..towns {
        u -= 1.0 / (r + 1) as f64;
        if u < 0.0 {
            return r;
        }
    }
    towns - 1
}

/// The itinerary of place `p` in a world of towns: its mode and speed, its home town,
/// then stops and journeys until `horizon`. At 0 s every group is in its home town.
fn town_itinerary(towns: &[Town], roads: &[(usize, usize)], p: usize, seed: u64, horizon: f64) -> Itinerary {
    let key = seed.rotate_left(17) ^ (p as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let mode = TravelMode::pick(key);
    let speed = within(mode.speeds(), key + 1);
    let mut town = home_town(towns.len(), key + 2);
    let spot = towns[town].spot(key + 3);
    let mut b = Itinerary::builder(mode, speed, [spot[0], spot[1], 0.0]);
    let neighbours = |t: usize| -> Vec<usize> {
        roads
            .iter()
            .filter_map(|&(a, c)| (a == t).then_some(c).or((c == t).then_some(a)))
            .collect()
    };
    // The first stop is already under way: it ends anywhere within a full one.
    let first = match mode {
        TravelMode::Walking => PAUSE.1,
        TravelMode::Riding | TravelMode::Flying => DWELL.1,
    };
    b.stop(unit(key + 4) * first);
    let cruise = within(FLIGHT_HEIGHT, key + 5);
    let mut k = key.wrapping_add(64);
    while b.t <= horizon {
        k = k.wrapping_add(8);
        match mode {
            TravelMode::Walking => {
                let roads_out = neighbours(town);
                if roads_out.is_empty() || unit(k) < 0.5 {
                    // A stroll to another spot of the town.
                    let s = towns[town].spot(k + 1);
                    b.go([s[0], s[1], 0.0]);
                } else {
                    // Out along a road and back.
                    let to = towns[roads_out[(unit(k + 1) * roads_out.len() as f64) as usize]].centre;
                    let from = b.at;
                    let d = distance([from[0], from[1]], to).max(1.0);
                    let f = within(WALK_OUT, k + 2).min(d) / d;
                    b.go([from[0] + (to[0] - from[0]) * f, from[1] + (to[1] - from[1]) * f, 0.0]);
                    b.stop(within(PAUSE, k + 3));
                    b.go(from);
                }
                b.stop(within(PAUSE, k + 4));
            }
            TravelMode::Riding => {
                let roads_out = neighbours(town);
                if !roads_out.is_empty() {
                    // Along the road: to the town's centre, to the next one's, to a spot in it.
                    let next = roads_out[(unit(k) * roads_out.len() as f64) as usize];
                    let (c0, c1) = (towns[town].centre, towns[next].centre);
                    let s = towns[next].spot(k + 1);
                    b.go([c0[0], c0[1], 0.0]);
                    b.go([c1[0], c1[1], 0.0]);
                    b.go([s[0], s[1], 0.0]);
                    town = next;
                }
                b.stop(within(DWELL, k + 2));
            }
            TravelMode::Flying => {
                if towns.len() > 1 {
                    // Straight to any other town: climb, cruise, descend.
                    let next = (town + 1 + (unit(k) * (towns.len() - 1) as f64) as usize) % towns.len();
                    let s = towns[next].spot(k + 1);
                    let from = b.at;
                    let d = distance([from[0], from[1]], s);
                    let along = |m: f64, h: f64| {
                        let f = (m / d.max(1.0)).min(1.0);
                        [from[0] + (s[0] - from[0]) * f, from[1] + (s[1] - from[1]) * f, h]
                    };
                    if d > 2.0 * CLIMB_METRES {
                        b.go(along(CLIMB_METRES, cruise));
                        b.go(along(d - CLIMB_METRES, cruise));
                    }
                    b.go([s[0], s[1], 0.0]);
                    town = next;
                }
                b.stop(within(DWELL, k + 2));
            }
        }
    }
    b.it
}

#[cfg(test)]
mod tests {
    use super::*;

    const HOUR: f64 = 3_600.0;

    #[test]
    fn the_same_seed_gives_the_same_positions_and_another_seed_others() {
        let a = Geometry::new(GeometryKind::Towns, 40, 7, Vec::new(), 4.0 * HOUR);
        let b = Geometry::new(GeometryKind::Towns, 40, 7, Vec::new(), 4.0 * HOUR);
        let c = Geometry::new(GeometryKind::Towns, 40, 8, Vec::new(), 4.0 * HOUR);
        let mut differ = 0;
        for g in 0..40 {
            for s in [0.0, 1.5, 600.0, 3_333.3, 4.0 * HOUR] {
                assert_eq!(a.position(g, s), b.position(g, s));
                differ += usize::from(a.position(g, s) != c.position(g, s));
            }
        }
        assert!(differ > 150, "another seed, other itineraries: {differ} of 200 differ");
    }

    #[test]
    fn speeds_stay_within_their_mode_s_range_and_every_mode_occurs() {
        let geo = Geometry::new(GeometryKind::Towns, 200, 3, Vec::new(), 6.0 * HOUR);
        let mut modes = std::collections::HashMap::new();
        for g in 0..200 {
            let it = geo.itinerary(g);
            *modes.entry(it.mode).or_insert(0) += 1;
            let (lo, hi) = it.mode.speeds();
            assert!((lo..=hi).contains(&it.speed), "{:?} at {} m/s", it.mode, it.speed);
            let speeds: Vec<f64> = it.moving_speeds().collect();
            assert!(!speeds.is_empty(), "group {g} never moves in 6 h");
            for v in speeds {
                assert!((v - it.speed).abs() < 1e-6 * it.speed, "{:?}: {v} m/s", it.mode);
            }
            // Sampled positions never jump faster than the mode allows.
            let mut last = geo.position(g, 0.0);
            for i in 1..=2_000 {
                let p = geo.position(g, i as f64 * 7.0);
                let v = distance([p[0], p[1]], [last[0], last[1]]) / 7.0;
                assert!(v <= hi + 1e-6, "{:?} moved {v} m/s", it.mode);
                last = p;
            }
        }
        for (mode, share) in [
            (TravelMode::Walking, 0.4),
            (TravelMode::Riding, 0.4),
            (TravelMode::Flying, 0.2),
        ] {
            let n = modes.get(&mode).copied().unwrap_or(0) as f64 / 200.0;
            assert!((n - share).abs() < 0.1, "{mode:?}: {n}");
        }
    }

    #[test]
    fn groups_start_in_towns_and_most_are_in_or_near_one_later() {
        let geo = Geometry::new(GeometryKind::Towns, 300, 11, Vec::new(), 3.0 * HOUR);
        let near = |p: [f64; 3], margin: f64| {
            geo.towns
                .iter()
                .any(|t| distance([p[0], p[1]], t.centre) <= t.radius + margin)
        };
        for g in 0..300 {
            let p = geo.position(g, 0.0);
            assert!(near(p, 0.0) && p[2] == 0.0, "group {g} starts at {p:?}");
        }
        // Two hours on (a steady state), most groups are within 3 km of a town.
        let in_or_near = (0..300).filter(|&g| near(geo.position(g, 2.0 * HOUR), 3_000.0)).count();
        assert!(in_or_near > 150, "{in_or_near} of 300 in or near a town");
        // Flyers fly at altitude, everyone else stays on the ground.
        let flying_high = (0..300).any(|g| geo.position(g, 2.0 * HOUR)[2] >= FLIGHT_HEIGHT.0);
        assert!(flying_high);
        for g in (0..300).filter(|&g| geo.itinerary(g).mode != TravelMode::Flying) {
            assert!((0..100).all(|i| geo.position(g, i as f64 * 100.0)[2] == 0.0));
        }
    }

    #[test]
    fn the_generated_towns_are_tens_of_km_apart_and_all_joined_by_roads() {
        let towns = generated_towns();
        assert_eq!(towns.len(), 9);
        for (i, a) in towns.iter().enumerate() {
            for b in &towns[i + 1..] {
                let d = distance(a.centre, b.centre);
                assert!(d >= TOWN_SPACING - 2.0 * 2f64.sqrt() * TOWN_JITTER, "{d}");
            }
        }
        let roads = roads(&towns);
        // Connected: a walk from town 0 over the roads reaches every town.
        let mut reached = vec![0];
        while let Some(t) = reached.iter().find_map(|&t| {
            roads
                .iter()
                .filter_map(|&(a, b)| (a == t).then_some(b).or((b == t).then_some(a)))
                .find(|n| !reached.contains(n))
        }) {
            reached.push(t);
        }
        assert_eq!(reached.len(), 9, "{roads:?}");
        assert!(roads.iter().all(|&(a, b)| a < b));
    }

    #[test]
    fn riders_follow_the_roads_between_towns() {
        let geo = Geometry::new(GeometryKind::Towns, 100, 5, Vec::new(), 5.0 * HOUR);
        let on_road = |p: [f64; 3]| {
            geo.roads.iter().any(|&(a, b)| {
                let (u, v) = (geo.towns[a].centre, geo.towns[b].centre);
                let (dx, dy) = (v[0] - u[0], v[1] - u[1]);
                let f = (((p[0] - u[0]) * dx + (p[1] - u[1]) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
                distance([p[0], p[1]], [u[0] + f * dx, u[1] + f * dy]) < 1.0
            })
        };
        let riders: Vec<usize> = (0..100)
            .filter(|&g| geo.itinerary(g).mode == TravelMode::Riding)
            .collect();
        assert!(!riders.is_empty());
        for &g in &riders {
            for i in 0..300 {
                let p = geo.position(g, i as f64 * 60.0);
                assert!(
                    on_road(p) || geo.towns.iter().any(|t| t.contains([p[0], p[1]])),
                    "rider {g} off the roads at {p:?}"
                );
            }
        }
    }

    #[test]
    fn warm_areas_make_the_towns() {
        let a = Town::from_area("harbour", [0.0, 0.0, 4_000.0, 2_000.0], None).unwrap();
        assert_eq!((a.centre, a.radius), ([2_000.0, 1_000.0], 500.0));
        // A polygon's centroid, not its box's centre: a right triangle's is at a third.
        let tri = [[0.0, 0.0], [3_000.0, 0.0], [0.0, 3_000.0]];
        let b = Town::from_area("tri", [0.0, 0.0, 3_000.0, 3_000.0], Some(&tri)).unwrap();
        assert!((b.centre[0] - 1_000.0).abs() < 1e-9 && (b.centre[1] - 1_000.0).abs() < 1e-9);
        assert!(Town::from_area("flat", [0.0, 0.0, 0.0, 10.0], None).is_none());
        let geo = Geometry::new(GeometryKind::Towns, 16, 1, vec![a.clone(), b.clone()], HOUR);
        assert!(geo.towns_from_server && geo.towns == vec![a, b]);
        assert_eq!(geo.roads, vec![(0, 1)]);
        for g in 0..16 {
            let p = geo.position(g, 0.0);
            assert!(geo.towns.iter().any(|t| t.contains([p[0], p[1]])), "{p:?}");
        }
    }

    #[test]
    fn the_spread_geometry_keeps_its_paths() {
        // The path before issue 34: 12 m/s legs of 2 km from (12 800, 12 800).
        let geo = Geometry::new(GeometryKind::Spread, 4, 7, Vec::new(), 600.0);
        assert_eq!(geo.position(0, 0.0), [12_800.0, 12_800.0, 0.0]);
        assert_eq!(geo.position(1, 0.0), [42_800.0, 12_800.0, 0.0]);
        let heading = unit(7) * std::f64::consts::TAU + (unit(8) - 0.5) * 2.0 * 60f64.to_radians();
        let p = geo.position(0, 100.0);
        assert!((p[0] - (12_800.0 + 1_200.0 * heading.sin())).abs() < 1e-6);
        assert!((p[1] - (12_800.0 + 1_200.0 * heading.cos())).abs() < 1e-6);
        assert!(geo.itinerary(0).moving_speeds().all(|v| (v - 12.0).abs() < 1e-9));
        // Past the laid-out horizon the group stays at its last point.
        assert_eq!(geo.position(0, 1e6), geo.position(0, 1e7));
    }

    #[test]
    fn distinct_places_count_tiles_under_group_centres() {
        let geo = Geometry::new(GeometryKind::Spread, 4, 7, Vec::new(), 60.0);
        // Four groups 30 km apart: four 25.6 km tiles; one group alone: one.
        assert_eq!(geo.distinct_places(4, 25_600.0, 0.0, 10.0), 4);
        assert_eq!(geo.distinct_places(1, 25_600.0, 0.0, 10.0), 1);
        // A whole world in one tile.
        assert_eq!(geo.distinct_places(4, 1e9, 0.0, 10.0), 1);
    }
}
