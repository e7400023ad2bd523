//! Who sends what: MMO players that fetch the tiles their view needs, and game servers
//! that ask region questions. Every agent's position is a pure function of the time
//! since the run started, so the closed and open loops replay the same world.

use std::collections::{HashMap, HashSet};

use cloudscape_client::RemoteWorld;
use cloudscape_core::render::scene::{LayerBand, plan_bands};
use cloudscape_core::render::{Camera, Quality, RenderRequest, ShadingParams, TileId};
use cloudscape_core::world::{Keyframe, keyframe_span};

/// Players per group: players of one group share an area (and so most of their tiles),
/// as a party or a town does in an MMO.
pub const GROUP_SIZE: usize = 8;
/// Seconds between two re-plans of a player's view (and between two game-server queries).
pub const TICK_SECONDS: f64 = 1.0;
/// How fast a group walks along its path, m/s (a mounted player).
const GROUP_SPEED: f64 = 12.0;
/// Length of one straight leg of a group's path, metres.
const LEG_METRES: f64 = 2_000.0;
/// Distance between the starting points of neighbouring groups, metres.
pub const GROUP_SPACING: f64 = 30_000.0;
/// The viewer's default screen, pixels (web/viewer.js).
const SCREEN: (usize, usize) = (800, 450);
/// The preset MMO clients fetch (the viewer's default).
pub const CLIENT_QUALITY: Quality = Quality::Fast;
/// Past this fraction of a keyframe span a player fetches the next keyframe (as the
/// viewer does).
pub const PREFETCH_AT: f64 = 0.5;
/// Side of a game server's /region box, metres.
const REGION_SIDE: f64 = 10_000.0;
/// A game server asks for a /series (the last minute) every this many queries.
const SERIES_EVERY: u64 = 4;

/// What a request is, for the report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RequestKind {
    Tile,
    /// A tile's next keyframe, fetched before the player needs it.
    Prefetch,
    Splats,
    Region,
    Series,
}

/// How players fetch their tiles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FetchMode {
    /// As the viewer: each tile's keyframe URL once (immutable, never revalidated),
    /// and the next keyframe once past [`PREFETCH_AT`] of the span.
    Keyframes,
    /// Every tile of the view every tick at the current time, revalidating the held
    /// ETag (what clients did before keyframes; `--poll`).
    Poll,
}

/// One request an agent wants sent.
#[derive(Clone, Debug)]
pub struct Request {
    pub kind: RequestKind,
    /// Path and query, relative to the target.
    pub path: String,
    /// What the agent's store calls the resource: the path without the time, so a new
    /// frame of the same tile revalidates against the old ETag (and gets the new body).
    pub resource: String,
    /// The ETag the agent holds for `resource`, sent as `If-None-Match`.
    pub etag: Option<String>,
}

/// A deterministic pseudo-random number in [0, 1) from a key (SplitMix64).
fn unit(key: u64) -> f64 {
    let mut z = key.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// The path a group walks: straight legs of [`LEG_METRES`], each turning up to 60°
/// from the last, starting from the group's home.
#[derive(Clone, Debug)]
pub struct GroupPath {
    /// Leg start points; extended as the group walks on.
    waypoints: Vec<[f64; 2]>,
    heading: f64,
    seed: u64,
}

impl GroupPath {
    /// The path of group `g` of `groups` (homes on a square grid around the world origin).
    pub fn new(g: usize, groups: usize, seed: u64) -> GroupPath {
        let side = (groups as f64).sqrt().ceil().max(1.0) as usize;
        let home = [
            12_800.0 + GROUP_SPACING * (g % side) as f64,
            12_800.0 + GROUP_SPACING * (g / side) as f64,
        ];
        GroupPath {
            waypoints: vec![home],
            heading: unit(seed ^ (g as u64) << 20) * std::f64::consts::TAU,
            seed: seed ^ (g as u64) << 20,
        }
    }

    /// Where the group is `s` seconds into the run.
    pub fn at(&mut self, s: f64) -> [f64; 2] {
        let walked = (s.max(0.0) * GROUP_SPEED) / LEG_METRES;
        let leg = walked.floor() as usize;
        while self.waypoints.len() < leg + 2 {
            let k = self.waypoints.len() as u64;
            self.heading += (unit(self.seed.wrapping_add(k)) - 0.5) * 2.0 * 60f64.to_radians();
            let last = self.waypoints[self.waypoints.len() - 1];
            self.waypoints.push([
                last[0] + LEG_METRES * self.heading.sin(),
                last[1] + LEG_METRES * self.heading.cos(),
            ]);
        }
        let (a, b) = (self.waypoints[leg], self.waypoints[leg + 1]);
        let f = walked - leg as f64;
        [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f]
    }
}

/// The world as the agents see it: from discovery, plus the clock.
#[derive(Clone, Debug)]
pub struct WorldView {
    /// The world's name, as its URLs spell it.
    pub name: String,
    /// The deepest level the server serves: the players' level choice stops there.
    pub maxzoom: u32,
    /// Layer names, in the world's order.
    pub layers: Vec<String>,
    /// Each layer's height band and cell size, for the level choice ([`plan_bands`]).
    pub bands: Vec<LayerBand>,
    /// Seconds per automaton step of each layer: its keyframe spans.
    pub dts: Vec<f64>,
    /// World-clock seconds at the start of the run.
    pub t0: f64,
    /// World seconds per real second.
    pub clock: f64,
}

impl WorldView {
    pub fn new(world: &RemoteWorld, t0: f64, clock: f64) -> WorldView {
        WorldView {
            name: world.name.clone(),
            maxzoom: world.maxzoom,
            layers: world.layers.iter().map(|l| l.name.clone()).collect(),
            bands: world.bands(),
            dts: world.layers.iter().map(|l| l.dt).collect(),
            t0,
            clock,
        }
    }

    /// The world clock `s` real seconds into the run.
    pub fn t(&self, s: f64) -> f64 {
        self.t0 + self.clock * s
    }

    /// The shortest keyframe span of the world (level 0 of its fastest layer), seconds.
    pub fn shortest_span(&self) -> f64 {
        self.dts.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// Whether `s` real seconds into the run fall in the first real second after a
    /// level-0 keyframe boundary of the fastest layer (when every level-0 tile of it
    /// turns over).
    pub fn just_after_boundary(&self, s: f64) -> bool {
        let span = self.shortest_span();
        if !(self.clock > 0.0 && span.is_finite() && span > 0.0) {
            return false;
        }
        self.t(s).rem_euclid(span) < self.clock
    }
}

/// An MMO client: looks around from near its group's position and fetches
/// `billboards.bin` and `shadow.png` for every tile its view needs (the viewer's
/// products), at the levels the renderer's level choice gives ([`plan_bands`]).
#[derive(Clone, Debug)]
pub struct Player {
    index: usize,
    group: usize,
    /// Offset from the group centre, metres, and height above ground.
    offset: [f64; 3],
    /// Starting yaw and how fast the player turns, degrees and degrees per second.
    yaw0: f64,
    turn: f64,
    fetched_splats: bool,
    mode: FetchMode,
    /// Keyframe URLs held (their answers never change): never asked again.
    held: HashSet<String>,
}

impl Player {
    pub fn new(index: usize, seed: u64, mode: FetchMode) -> Player {
        let k = seed ^ (index as u64).wrapping_mul(0x1_0000_0001);
        Player {
            index,
            group: index / GROUP_SIZE,
            offset: [
                (unit(k) - 0.5) * 600.0,
                (unit(k + 1) - 0.5) * 600.0,
                30.0 + unit(k + 2) * 400.0,
            ],
            yaw0: unit(k + 3) * 360.0,
            turn: (unit(k + 4) - 0.5) * 12.0,
            fetched_splats: false,
            mode,
            held: HashSet::new(),
        }
    }

    /// The player's camera `s` seconds into the run.
    pub fn camera(&self, paths: &mut [GroupPath], s: f64) -> Camera {
        let c = paths[self.group].at(s);
        let yaw = (self.yaw0 + self.turn * s).rem_euclid(360.0);
        Camera::new(
            [c[0] + self.offset[0], c[1] + self.offset[1], self.offset[2]],
            yaw,
            6.0,
            75.0,
        )
        .expect("a finite camera")
    }

    /// The tiles (layer, tile) this player's view needs at `s`. Like the viewer, it
    /// coarsens the level choice (a narrower screen) when a view needs too many tiles.
    pub fn tiles(&self, world: &WorldView, paths: &mut [GroupPath], s: f64) -> Vec<(usize, TileId)> {
        let camera = self.camera(paths, s);
        let mut width = SCREEN.0;
        loop {
            let req = RenderRequest {
                camera,
                width,
                height: SCREEN.1 * width / SCREEN.0,
                t: world.t(s).clamp(0.0, 1e12),
                quality: CLIENT_QUALITY,
                sun: None,
                params: ShadingParams::default(),
                samples: cloudscape_core::render::pathtrace::DEFAULT_SAMPLES,
            };
            match plan_bands(&world.bands, world.maxzoom, &req) {
                Ok(tiles) => return tiles,
                Err(_) if width > 16 => width /= 2,
                Err(_) => return Vec::new(),
            }
        }
    }

    /// The requests of one view refresh at `s`: the splat sheet once, then two
    /// products per planned tile: in [`FetchMode::Keyframes`] those of its keyframe
    /// (and of the next one past [`PREFETCH_AT`]) not held yet, in [`FetchMode::Poll`]
    /// every one at the current time.
    pub fn requests(&mut self, world: &WorldView, paths: &mut [GroupPath], s: f64) -> Vec<Request> {
        let t = world.t(s);
        let q = CLIENT_QUALITY.as_str();
        let mut out = Vec::new();
        if !self.fetched_splats {
            self.fetched_splats = true;
            for product in ["splats.json", "splats.png"] {
                let path = format!("/v1/{product}?quality={q}");
                out.push(Request {
                    kind: RequestKind::Splats,
                    resource: path.clone(),
                    path,
                    etag: None,
                });
            }
        }
        let mut wanted = HashSet::new();
        for (layer, tile) in self.tiles(world, paths, s) {
            let name = &world.layers[layer];
            for product in ["billboards.bin", "shadow.png"] {
                let resource = format!(
                    "/v1/worlds/{}/tiles/{}/{}/{}/{product}?quality={q}&layer={name}",
                    world.name, tile.z, tile.x, tile.y
                );
                if self.mode == FetchMode::Poll {
                    out.push(Request {
                        kind: RequestKind::Tile,
                        path: format!("{resource}&t={t}"),
                        resource,
                        etag: None,
                    });
                    continue;
                }
                let k = Keyframe::on_grid(t.clamp(0.0, 1e12), keyframe_span(world.dts[layer], tile.z));
                let mut times = vec![(RequestKind::Tile, k.t0)];
                if k.fraction(t) >= PREFETCH_AT && k.t1 > k.t0 {
                    times.push((RequestKind::Prefetch, k.t1));
                }
                for (kind, t0) in times {
                    let path = format!("{resource}&t={t0}");
                    wanted.insert(path.clone());
                    if !self.held.contains(&path) {
                        out.push(Request {
                            kind,
                            resource: path.clone(),
                            path,
                            etag: None,
                        });
                    }
                }
            }
        }
        // What the view no longer needs is let go (a viewer's memory is bounded too).
        if self.mode == FetchMode::Keyframes {
            self.held.retain(|p| wanted.contains(p));
        }
        out
    }

    /// Takes note of a 200: a keyframe URL is held from now on.
    fn fetched(&mut self, path: &str) {
        if self.mode == FetchMode::Keyframes && path.contains("/tiles/") {
            self.held.insert(path.to_string());
        }
    }

    pub fn index(&self) -> usize {
        self.index
    }
}

/// A game server: every tick asks how cloudy the 10 km box around one of the groups
/// is now (`/region`), and every few ticks how it went over the last minute (`/series`).
#[derive(Clone, Debug)]
pub struct GameServer {
    index: usize,
    queries: u64,
}

impl GameServer {
    pub fn new(index: usize) -> GameServer {
        GameServer { index, queries: 0 }
    }

    /// The next query at `s`, about the area of group `index mod groups`.
    pub fn request(&mut self, world: &WorldView, paths: &mut [GroupPath], s: f64) -> Request {
        let c = paths[self.index % paths.len()].at(s);
        let h = REGION_SIDE / 2.0;
        let bbox = format!("{:.0},{:.0},{:.0},{:.0}", c[0] - h, c[1] - h, c[0] + h, c[1] + h);
        let t = world.t(s);
        self.queries += 1;
        let (kind, path) = if self.queries.is_multiple_of(SERIES_EVERY) {
            let t0 = (t - 60.0).max(0.0);
            (
                RequestKind::Series,
                format!("/v1/worlds/{}/series?bbox={bbox}&t0={t0}&t1={t}&dt=20", world.name),
            )
        } else {
            (
                RequestKind::Region,
                format!("/v1/worlds/{}/region?bbox={bbox}&t={t}", world.name),
            )
        };
        Request {
            kind,
            resource: path.clone(),
            path,
            etag: None,
        }
    }
}

/// One simulated client of either kind, with the ETags it holds.
#[derive(Clone, Debug)]
pub enum Role {
    Player(Player),
    GameServer(GameServer),
}

/// An agent: a role, the requests it still has to send for its current tick, and the
/// ETags of what it has fetched.
#[derive(Clone, Debug)]
pub struct Agent {
    pub role: Role,
    pending: Vec<Request>,
    etags: HashMap<String, String>,
}

impl Agent {
    pub fn new(role: Role) -> Agent {
        Agent {
            role,
            pending: Vec::new(),
            etags: HashMap::new(),
        }
    }

    /// Whether the agent has sent everything for its current tick.
    pub fn idle(&self) -> bool {
        self.pending.is_empty()
    }

    /// Plans a new tick at `s` (a player's view, a game server's query).
    pub fn plan(&mut self, world: &WorldView, paths: &mut [GroupPath], s: f64) {
        let mut reqs = match &mut self.role {
            Role::Player(p) => p.requests(world, paths, s),
            Role::GameServer(g) => vec![g.request(world, paths, s)],
        };
        reqs.reverse();
        self.pending = reqs;
    }

    /// The next request of the current tick, with the ETag held for its resource.
    pub fn next_request(&mut self) -> Option<Request> {
        let mut r = self.pending.pop()?;
        r.etag = self.etags.get(&r.resource).cloned();
        Some(r)
    }

    /// Remembers what a 200 answer came with: its ETag (to revalidate with), and for a
    /// player fetching keyframes, that the URL is held.
    pub fn answered(&mut self, req: &Request, etag: Option<String>) {
        if let Some(e) = etag {
            if let Role::Player(p) = &mut self.role {
                p.fetched(&req.path);
            }
            self.etags.insert(req.resource.clone(), e);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cloudscape_client::RemoteLayer;

    fn world() -> WorldView {
        let remote = RemoteWorld {
            name: "default".into(),
            maxzoom: 16,
            layers: vec![RemoteLayer {
                name: "stratocumulus".into(),
                base: 1000.0,
                top: 2000.0,
                cell_size: 100.0,
                dt: 20.0,
            }],
        };
        WorldView::new(&remote, 43_200.0, 1.0)
    }

    #[test]
    fn paths_are_continuous_and_deterministic() {
        let mut a = GroupPath::new(3, 10, 7);
        let mut b = GroupPath::new(3, 10, 7);
        let mut last = a.at(0.0);
        for i in 1..2000 {
            let s = i as f64 * 0.5;
            let p = a.at(s);
            let step = ((p[0] - last[0]).powi(2) + (p[1] - last[1]).powi(2)).sqrt();
            assert!(step <= GROUP_SPEED * 0.5 + 1e-6, "jump of {step} m at {s} s");
            last = p;
        }
        assert_eq!(a.at(123.0), b.at(123.0));
    }

    #[test]
    fn players_fetch_each_keyframe_once_and_the_next_one_past_the_middle() {
        let w = world();
        let mut paths = vec![GroupPath::new(0, 1, 1)];
        let mut agent = Agent::new(Role::Player(Player::new(0, 1, FetchMode::Keyframes)));
        let drain = |agent: &mut Agent| {
            let mut reqs = Vec::new();
            while let Some(r) = agent.next_request() {
                reqs.push(r);
            }
            reqs
        };
        agent.plan(&w, &mut paths, 0.0);
        let first = drain(&mut agent);
        let tiles: Vec<_> = first.iter().filter(|r| r.kind == RequestKind::Tile).collect();
        assert!(!tiles.is_empty());
        // t = 43 200 is every level's keyframe time: no prefetch yet.
        assert!(first.iter().all(|r| r.kind != RequestKind::Prefetch));
        assert!(tiles.iter().all(|r| r.path.ends_with("&t=43200") && r.etag.is_none()));
        for r in &first {
            agent.answered(r, Some("\"e\"".into()));
        }
        // Three seconds on (level 0 spans 20 s): everything is held, nothing is asked.
        agent.plan(&w, &mut paths, 3.0);
        let held: Vec<_> = drain(&mut agent);
        assert!(
            held.iter().all(|r| !r.path.ends_with("&t=43200")),
            "held keyframes are never asked again: {held:?}"
        );
        // Past the middle of the level-0 span: the next keyframe, once.
        agent.plan(&w, &mut paths, 12.0);
        let pre = drain(&mut agent);
        let next: Vec<_> = pre.iter().filter(|r| r.path.ends_with("&t=43220")).collect();
        assert!(!next.is_empty() && next.iter().all(|r| r.kind == RequestKind::Prefetch));
        for r in &pre {
            agent.answered(r, Some("\"e\"".into()));
        }
        // After the boundary the prefetched keyframe is the current one: not asked again.
        agent.plan(&w, &mut paths, 20.5);
        let after = drain(&mut agent);
        assert!(after.iter().all(|r| !r.path.ends_with("&t=43220")), "{after:?}");
    }

    #[test]
    fn polling_players_fetch_their_planned_tiles_and_revalidate() {
        let w = world();
        let mut paths = vec![GroupPath::new(0, 1, 1)];
        let mut agent = Agent::new(Role::Player(Player::new(0, 1, FetchMode::Poll)));
        agent.plan(&w, &mut paths, 0.0);
        let mut reqs = Vec::new();
        while let Some(r) = agent.next_request() {
            reqs.push(r);
        }
        assert_eq!(reqs[0].kind, RequestKind::Splats);
        let tiles: Vec<_> = reqs.iter().filter(|r| r.kind == RequestKind::Tile).collect();
        assert!(!tiles.is_empty() && tiles.len() % 2 == 0);
        assert!(tiles.iter().all(|r| r.etag.is_none() && r.path.contains("&t=43200")));
        agent.answered(tiles[0], Some("\"abc\"".into()));
        // One second later: a new time, the same resources, the held ETag is sent.
        agent.plan(&w, &mut paths, 1.0);
        let first = agent.next_request().unwrap();
        assert_eq!(first.kind, RequestKind::Tile, "the splat sheet is fetched once");
        assert_eq!(first.resource, tiles[0].resource);
        assert_eq!(first.etag.as_deref(), Some("\"abc\""));
    }

    #[test]
    fn game_servers_mix_region_and_series() {
        let w = world();
        let mut paths = vec![GroupPath::new(0, 1, 1)];
        let mut g = GameServer::new(0);
        let kinds: Vec<_> = (0..8).map(|i| g.request(&w, &mut paths, i as f64).kind).collect();
        assert_eq!(kinds.iter().filter(|k| **k == RequestKind::Series).count(), 2);
        assert!(g.request(&w, &mut paths, 0.0).path.contains("/region?bbox="));
    }
}
