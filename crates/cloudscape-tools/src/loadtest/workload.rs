//! Who sends what: MMO players that fetch the tiles their view needs, and game servers
//! that ask region questions. Every agent's position comes from its group's place in
//! the [`Geometry`], a pure function of the time since the run started, so the closed
//! and open loops replay the same world.
//!
//! Players are kept cheap: a view's tiles are compared with what the player holds as
//! plain keys, and a URL is written only for a request that is sent.

use std::collections::{HashMap, HashSet};

use cloudscape_client::RemoteWorld;
use cloudscape_core::render::scene::{LayerBand, plan_bands};
use cloudscape_core::render::tile::TILE_COLUMNS;
use cloudscape_core::render::{Camera, Quality, RenderRequest, ShadingParams};
use cloudscape_core::world::{Keyframe, PREFETCH_FROM, PREFETCH_SPREAD, keyframe_span, prefetch_at};

use super::geometry::{Geometry, GeometryKind, unit};
use super::sharing::KeyframeKey;

/// Players per group: players of one group share an area (and so most of their tiles),
/// as a party or a town does in an MMO.
pub const GROUP_SIZE: usize = 8;
/// Seconds between two re-plans of a player's view (and between two game-server queries).
pub const TICK_SECONDS: f64 = 1.0;
/// The viewer's default screen, pixels (web/viewer.js).
const SCREEN: (usize, usize) = (800, 450);
/// The preset MMO clients fetch unless told (`--quality`; the viewer's default).
pub const DEFAULT_QUALITY: Quality = Quality::Fast;
/// Past a fraction of a keyframe span a player fetches the next keyframe: each tile's
/// own, between these (`cloudscape_core::world::prefetch_at`, as the viewer does).
pub const PREFETCH_AT: (f64, f64) = (PREFETCH_FROM, PREFETCH_FROM + PREFETCH_SPREAD);
/// Side of a game server's /region box, metres.
const REGION_SIDE: f64 = 10_000.0;
/// A game server asks for a /series (the last minute) every this many queries.
const SERIES_EVERY: u64 = 4;
/// What a player fetches of a tile's keyframe (the viewer's, `web/viewer.js`): its
/// billboards, self-contained when it holds nothing of the tile, as a delta on the
/// keyframe before when it holds that one. The ground shadow is derived from them.
const FIRST_KEYFRAME: &str = "billboards.bin";
const NEXT_KEYFRAME: &str = "billboards.delta.bin";
/// What a client of `billboards.bin` version 2 fetched per tile keyframe (`--wire v2`):
/// both ends in full precision and the served shadow map, whatever it held.
const V2_PRODUCTS: [&str; 2] = ["billboards.v2.bin", "shadow.png"];
/// What a player fetches besides the billboards of a layer that can rain or snow (the
/// viewer's rain at the eye and haze), every keyframe in either wire.
const PRECIPITATION: &str = "precipitation.png";

/// The tile format players fetch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Wire {
    /// `billboards.bin` version 3: self-contained for a tile's first keyframe, a delta
    /// on the held keyframe for the next ones; ground shadows derived (the viewer).
    V3,
    /// As clients did before version 3: `billboards.v2.bin` and `shadow.png` for every
    /// keyframe (the baseline of the bytes-per-player figures).
    V2,
}

impl Wire {
    pub fn parse(s: &str) -> Option<Wire> {
        match s {
            "v3" => Some(Wire::V3),
            "v2" => Some(Wire::V2),
            _ => None,
        }
    }
}
/// Most a player stands from its group's centre, metres, each way.
pub const PARTY_SPREAD: f64 = 300.0;

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
    /// and the next keyframe once past the tile's prefetch point ([`PREFETCH_AT`]).
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
    /// What the agent's store calls the resource when it revalidates it: the path
    /// without the time, so a new frame of the same tile revalidates against the old
    /// ETag. `None` for what is never revalidated (keyframe URLs, the splat sheet):
    /// its ETag is not kept.
    pub resource: Option<String>,
    /// The ETag the agent holds for `resource`, sent as `If-None-Match`.
    pub etag: Option<String>,
    /// Part of a player's first view (its first tick): counted apart from the steady
    /// state in the per-player bytes.
    pub first_view: bool,
    /// The group of the agent that sends it (for the sharing figures).
    pub group: u32,
    /// The tile keyframe and product a tile request asks for.
    pub tile: Option<TileProduct>,
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
    /// Whether each layer can rain or snow: players fetch its `precipitation.png` with
    /// every keyframe, as the viewer does.
    pub precipitates: Vec<bool>,
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
            precipitates: world.layers.iter().map(|l| l.precipitates).collect(),
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

    /// Side of a level-0 tile of the world's finest layer, metres: the size of a
    /// "distinct place".
    pub fn finest_tile_side(&self) -> f64 {
        let cell = self.bands.iter().map(|b| b.cell_size).fold(f64::INFINITY, f64::min);
        TILE_COLUMNS as f64 * if cell.is_finite() { cell } else { 100.0 }
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

/// One tile keyframe: what a player asks for and holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TileProduct {
    pub keyframe: KeyframeKey,
    /// 1 when fetched as a delta on the keyframe before (`billboards.delta.bin`), 2 for
    /// the precipitation map; with [`Wire::V2`] the product's place in (billboards,
    /// shadow, precipitation).
    pub product: u8,
}

/// An MMO client: looks around from near its group's position and fetches the
/// billboard keyframes of every tile its view needs (the viewer's), at the levels the
/// renderer's level choice gives ([`plan_bands`]) for its quality.
#[derive(Clone, Debug)]
pub struct Player {
    index: usize,
    group: usize,
    /// Offset from the group centre, metres, and a draw in [0, 1) for its height above
    /// the group's (the geometry says what range it spans).
    offset: [f64; 2],
    height: f64,
    /// Starting yaw and how fast the player turns, degrees and degrees per second.
    yaw0: f64,
    turn: f64,
    fetched_splats: bool,
    mode: FetchMode,
    /// The preset it fetches.
    quality: Quality,
    /// The tile format it fetches.
    wire: Wire,
    /// Keyframes held (their answers never change): never asked again, and the next
    /// keyframe of a held one is fetched as a delta on it.
    held: HashSet<KeyframeKey>,
    /// What the current view needs (kept to reuse its memory from tick to tick).
    wanted: HashSet<KeyframeKey>,
}

impl Player {
    pub fn new(index: usize, seed: u64, mode: FetchMode, quality: Quality, wire: Wire) -> Player {
        let k = seed ^ (index as u64).wrapping_mul(0x1_0000_0001);
        Player {
            index,
            group: index / GROUP_SIZE,
            offset: [
                (unit(k) - 0.5) * 2.0 * PARTY_SPREAD,
                (unit(k + 1) - 0.5) * 2.0 * PARTY_SPREAD,
            ],
            height: unit(k + 2),
            yaw0: unit(k + 3) * 360.0,
            turn: (unit(k + 4) - 0.5) * 12.0,
            fetched_splats: false,
            mode,
            quality,
            wire,
            held: HashSet::new(),
            wanted: HashSet::new(),
        }
    }

    /// The player's camera `s` seconds into the run: its group's position, its offset,
    /// and its eye height: 30 to 430 m in the spread geometry (as before), 2 to 50 m
    /// above its group's height in the towns (on the ground, or a flyer's altitude).
    pub fn camera(&self, geometry: &Geometry, s: f64) -> Camera {
        let c = geometry.position(self.group, s);
        let eye = match geometry.kind {
            GeometryKind::Spread => 30.0 + self.height * 400.0,
            GeometryKind::Towns => c[2] + 2.0 + self.height * 48.0,
        };
        let yaw = (self.yaw0 + self.turn * s).rem_euclid(360.0);
        Camera::new([c[0] + self.offset[0], c[1] + self.offset[1], eye], yaw, 6.0, 75.0).expect("a finite camera")
    }

    /// The tiles (layer, tile) this player's view needs at `s`. Like the viewer, it
    /// coarsens the level choice (a narrower screen) when a view needs too many tiles.
    pub fn tiles(
        &self,
        world: &WorldView,
        geometry: &Geometry,
        s: f64,
    ) -> Vec<(usize, cloudscape_core::render::TileId)> {
        let camera = self.camera(geometry, s);
        let mut width = SCREEN.0;
        loop {
            let req = RenderRequest {
                camera,
                width,
                height: SCREEN.1 * width / SCREEN.0,
                t: world.t(s).clamp(0.0, 1e12),
                quality: self.quality,
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

    /// The requests of one view refresh at `s`: the splat sheet once, then per planned
    /// tile in [`FetchMode::Keyframes`] its keyframe (and the next one past the tile's
    /// prefetch point) when not held, each as a delta on the keyframe before when that
    /// is held or asked first in this tick; in [`FetchMode::Poll`] every tile's
    /// self-contained keyframe at the current time.
    pub fn requests(&mut self, world: &WorldView, geometry: &Geometry, s: f64) -> Vec<Request> {
        let t = world.t(s).clamp(0.0, 1e12);
        let q = self.quality.as_str();
        let group = self.group as u32;
        let first_view = !self.fetched_splats;
        let mut out = Vec::new();
        if first_view {
            self.fetched_splats = true;
            for product in ["splats.json", "splats.png"] {
                out.push(Request {
                    kind: RequestKind::Splats,
                    path: format!("/v1/{product}?quality={q}"),
                    resource: None,
                    etag: None,
                    first_view,
                    group,
                    tile: None,
                });
            }
        }
        self.wanted.clear();
        let mut asked: HashSet<KeyframeKey> = HashSet::new();
        for (layer, tile) in self.tiles(world, geometry, s) {
            let name = &world.layers[layer];
            let span = keyframe_span(world.dts[layer], tile.z);
            let k = Keyframe::on_grid(t, span);
            let key = |t0: f64| KeyframeKey {
                layer: layer as u16,
                z: tile.z,
                x: tile.x,
                y: tile.y,
                t0_bits: t0.to_bits(),
            };
            let url = |product: &str| {
                format!(
                    "/v1/worlds/{}/tiles/{}/{}/{}/{product}?quality={q}&layer={name}",
                    world.name, tile.z, tile.x, tile.y
                )
            };
            if self.mode == FetchMode::Poll {
                let resource = url(FIRST_KEYFRAME);
                out.push(Request {
                    kind: RequestKind::Tile,
                    path: format!("{resource}&t={t}"),
                    resource: Some(resource),
                    etag: None,
                    first_view,
                    group,
                    tile: Some(TileProduct {
                        keyframe: key(k.t0),
                        product: 0,
                    }),
                });
                continue;
            }
            let prefetch = k.fraction(t) >= prefetch_at(tile.z, tile.x, tile.y) && k.t1 > k.t0;
            for (kind, t0) in [(RequestKind::Tile, k.t0), (RequestKind::Prefetch, k.t1)] {
                if kind == RequestKind::Prefetch && !prefetch {
                    continue;
                }
                let this = key(t0);
                self.wanted.insert(this);
                if self.held.contains(&this) {
                    continue;
                }
                let before = key(Keyframe::on_grid(t0 - 0.5 * span, span).t0);
                let delta = t0 > 0.0 && (self.held.contains(&before) || asked.contains(&before));
                asked.insert(this);
                let products: &[&str] = match self.wire {
                    Wire::V3 if delta => &[NEXT_KEYFRAME],
                    Wire::V3 => &[FIRST_KEYFRAME],
                    Wire::V2 => &V2_PRODUCTS,
                };
                let weather = world.precipitates.get(layer).copied().unwrap_or(false);
                let weather = if weather { &[PRECIPITATION][..] } else { &[] };
                for (i, product) in products.iter().chain(weather).enumerate() {
                    out.push(Request {
                        kind,
                        path: format!("{}&t={t0}", url(product)),
                        resource: None,
                        etag: None,
                        first_view,
                        group,
                        tile: Some(TileProduct {
                            keyframe: this,
                            product: match (self.wire, i) {
                                (Wire::V3, 0) => delta as u8,
                                (Wire::V3, _) => 2,
                                (Wire::V2, i) => i as u8,
                            },
                        }),
                    });
                }
            }
        }
        // What the view no longer needs is let go (a viewer's memory is bounded too).
        if self.mode == FetchMode::Keyframes {
            let wanted = &self.wanted;
            self.held.retain(|h| wanted.contains(h));
        }
        out
    }

    /// Takes note of a 200: a keyframe product is held from now on.
    fn fetched(&mut self, req: &Request) {
        if self.mode != FetchMode::Keyframes {
            return;
        }
        if let Some(tile) = req.tile {
            self.held.insert(tile.keyframe);
        }
    }

    pub fn index(&self) -> usize {
        self.index
    }

    pub fn group(&self) -> usize {
        self.group
    }
}

/// A game server: every tick asks how cloudy the 10 km box around one of the groups
/// is now (`/region`), and every few ticks how it went over the last minute (`/series`).
#[derive(Clone, Debug)]
pub struct GameServer {
    index: usize,
    /// The groups of the run: the server watches group `index mod groups`.
    groups: usize,
    queries: u64,
}

impl GameServer {
    pub fn new(index: usize, groups: usize) -> GameServer {
        GameServer {
            index,
            groups: groups.max(1),
            queries: 0,
        }
    }

    /// The next query at `s`, about the area of group `index mod groups`.
    pub fn request(&mut self, world: &WorldView, geometry: &Geometry, s: f64) -> Request {
        let group = self.index % self.groups;
        let c = geometry.position(group, s);
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
            resource: Some(path.clone()),
            path,
            etag: None,
            first_view: false,
            group: group as u32,
            tile: None,
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
/// ETags of what it revalidates.
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
    pub fn plan(&mut self, world: &WorldView, geometry: &Geometry, s: f64) {
        let mut reqs = match &mut self.role {
            Role::Player(p) => p.requests(world, geometry, s),
            Role::GameServer(g) => vec![g.request(world, geometry, s)],
        };
        reqs.reverse();
        self.pending = reqs;
    }

    /// The next request of the current tick, with the ETag held for its resource.
    pub fn next_request(&mut self) -> Option<Request> {
        let mut r = self.pending.pop()?;
        r.etag = r.resource.as_ref().and_then(|res| self.etags.get(res).cloned());
        Some(r)
    }

    /// Whether the agent keeps the ETag of `req`'s answer (it revalidates the resource).
    pub fn keeps_etag(req: &Request) -> bool {
        req.resource.is_some()
    }

    /// Remembers what a 200 answer came with: for a player fetching keyframes, that
    /// the keyframe is held; for a resource it revalidates, the ETag.
    pub fn answered(&mut self, req: &Request, ok: bool, etag: Option<String>) {
        if !ok {
            return;
        }
        if let Role::Player(p) = &mut self.role {
            p.fetched(req);
        }
        if let (Some(res), Some(e)) = (&req.resource, etag) {
            self.etags.insert(res.clone(), e);
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
                precipitates: false,
            }],
        };
        WorldView::new(&remote, 43_200.0, 1.0)
    }

    fn towns(places: usize) -> Geometry {
        Geometry::new(GeometryKind::Towns, places, 1, Vec::new(), 600.0)
    }

    /// Player 0 of seed 1 fetching keyframes of the default quality in `wire`.
    fn player(wire: Wire) -> Agent {
        Agent::new(Role::Player(Player::new(
            0,
            1,
            FetchMode::Keyframes,
            DEFAULT_QUALITY,
            wire,
        )))
    }

    fn drain(agent: &mut Agent) -> Vec<Request> {
        let mut reqs = Vec::new();
        while let Some(r) = agent.next_request() {
            reqs.push(r);
        }
        reqs
    }

    #[test]
    fn players_fetch_each_keyframe_once_and_the_next_one_past_its_prefetch_point() {
        let w = world();
        let geo = towns(1);
        let mut agent = player(Wire::V3);
        agent.plan(&w, &geo, 0.0);
        let first = drain(&mut agent);
        let tiles: Vec<_> = first.iter().filter(|r| r.kind == RequestKind::Tile).collect();
        assert!(!tiles.is_empty());
        // t = 43 200 is every level's keyframe time: no prefetch yet.
        assert!(first.iter().all(|r| r.kind != RequestKind::Prefetch));
        assert!(tiles.iter().all(|r| r.path.ends_with("&t=43200") && r.etag.is_none()));
        // A first view: every tile self-contained, every request counted as the first view.
        assert!(tiles.iter().all(|r| r.path.contains("/billboards.bin?")), "{tiles:?}");
        assert!(first.iter().all(|r| r.first_view));
        for r in &first {
            agent.answered(r, true, Some("\"e\"".into()));
        }
        // Keyframe URLs are never revalidated: their ETags are not kept.
        assert!(agent.etags.is_empty());
        // Three seconds on (level 0 spans 20 s): everything is held, nothing is asked.
        agent.plan(&w, &geo, 3.0);
        let held: Vec<_> = drain(&mut agent);
        assert!(
            held.iter().all(|r| !r.path.ends_with("&t=43200")),
            "held keyframes are never asked again: {held:?}"
        );
        // At 0.6 of the level-0 span: the next keyframe of the tiles whose prefetch
        // point is past, and only those.
        agent.plan(&w, &geo, 12.0);
        let early = drain(&mut agent);
        for r in &early {
            let tile = r.tile.expect("a tile request");
            assert!(r.kind == RequestKind::Prefetch && r.path.ends_with("&t=43220"), "{r:?}");
            // The keyframe before is held: the next one comes as a delta on it.
            assert!(r.path.contains("/billboards.delta.bin?") && !r.first_view, "{r:?}");
            let (x, y) = (tile.keyframe.x, tile.keyframe.y);
            assert!(prefetch_at(tile.keyframe.z, x, y) <= 0.6, "{r:?}");
            agent.answered(r, true, None);
        }
        // At 0.825, past every tile's point: the rest of the next keyframes, once.
        agent.plan(&w, &geo, 16.5);
        let pre = drain(&mut agent);
        let next: Vec<_> = pre.iter().filter(|r| r.path.ends_with("&t=43220")).collect();
        assert!(!next.is_empty() && next.iter().all(|r| r.kind == RequestKind::Prefetch));
        assert!(
            next.iter().all(|r| !early.iter().any(|e| e.path == r.path)),
            "asked twice"
        );
        for r in &pre {
            agent.answered(r, true, None);
        }
        // After the boundary the prefetched keyframe is the current one: not asked again.
        agent.plan(&w, &geo, 20.5);
        let after = drain(&mut agent);
        assert!(after.iter().all(|r| !r.path.ends_with("&t=43220")), "{after:?}");
    }

    #[test]
    fn version_2_players_fetch_both_products_of_every_keyframe() {
        let w = world();
        let geo = towns(1);
        let mut agent = player(Wire::V2);
        agent.plan(&w, &geo, 0.0);
        let first: Vec<_> = drain(&mut agent).into_iter().filter(|r| r.tile.is_some()).collect();
        let count = |p: &str| first.iter().filter(|r| r.path.contains(p)).count();
        assert!(count("/billboards.v2.bin?") > 0);
        assert_eq!(count("/billboards.v2.bin?"), count("/shadow.png?"));
        assert_eq!(count("/billboards.v2.bin?") + count("/shadow.png?"), first.len());
        for r in &first {
            agent.answered(r, true, None);
        }
        // Past every prefetch point: the next keyframes, both products again, no delta.
        agent.plan(&w, &geo, 16.5);
        let next = drain(&mut agent);
        assert!(
            !next.is_empty() && next.iter().all(|r| !r.path.contains("delta")),
            "{next:?}"
        );
    }

    #[test]
    fn players_fetch_the_precipitation_map_of_every_keyframe_of_a_layer_that_can_rain() {
        let mut w = world();
        w.precipitates = vec![true];
        let geo = towns(1);
        let mut agent = player(Wire::V3);
        agent.plan(&w, &geo, 0.0);
        let first: Vec<_> = drain(&mut agent).into_iter().filter(|r| r.tile.is_some()).collect();
        let count = |reqs: &[Request], p: &str| reqs.iter().filter(|r| r.path.contains(p)).count();
        assert!(count(&first, "/billboards.bin?") > 0);
        assert_eq!(count(&first, "/billboards.bin?"), count(&first, "/precipitation.png?"));
        assert_eq!(2 * count(&first, "/precipitation.png?"), first.len());
        for r in &first {
            agent.answered(r, true, None);
        }
        // The next keyframes: a delta of the billboards, the precipitation map whole.
        agent.plan(&w, &geo, 16.5);
        let next: Vec<_> = drain(&mut agent).into_iter().filter(|r| r.tile.is_some()).collect();
        assert!(count(&next, "/billboards.delta.bin?") > 0, "{next:?}");
        assert_eq!(
            count(&next, "/billboards.delta.bin?"),
            count(&next, "/precipitation.png?")
        );
        assert_eq!(count(&next, "/billboards.bin?"), 0);
    }

    #[test]
    fn a_failed_request_is_asked_again() {
        let w = world();
        let geo = towns(1);
        let mut agent = player(Wire::V3);
        agent.plan(&w, &geo, 0.0);
        let first = drain(&mut agent);
        for r in &first {
            agent.answered(r, false, None);
        }
        agent.plan(&w, &geo, 1.0);
        let again = drain(&mut agent);
        let tiles = |rs: &[Request]| {
            rs.iter()
                .filter(|r| r.tile.is_some())
                .map(|r| r.path.clone())
                .collect::<Vec<_>>()
        };
        assert_eq!(tiles(&again), tiles(&first));
    }

    #[test]
    fn tile_requests_name_their_keyframe_and_group() {
        let w = world();
        let geo = towns(4);
        let mut agent = Agent::new(Role::Player(Player::new(
            17,
            1,
            FetchMode::Keyframes,
            DEFAULT_QUALITY,
            Wire::V3,
        )));
        agent.plan(&w, &geo, 0.0);
        for r in drain(&mut agent).iter().filter(|r| r.kind == RequestKind::Tile) {
            assert_eq!(r.group, 2);
            let k = r.tile.unwrap().keyframe;
            let want = format!("/tiles/{}/{}/{}/", k.z, k.x, k.y);
            assert!(r.path.contains(&want) && r.path.ends_with(&format!("&t={}", f64::from_bits(k.t0_bits))));
        }
    }

    #[test]
    fn the_same_seed_sends_the_same_requests() {
        let w = world();
        let run = |seed: u64| {
            let geo = Geometry::new(GeometryKind::Towns, 3, seed, Vec::new(), 600.0);
            let mut agents: Vec<Agent> = (0..24)
                .map(|i| {
                    Agent::new(Role::Player(Player::new(
                        i,
                        seed,
                        FetchMode::Keyframes,
                        DEFAULT_QUALITY,
                        Wire::V3,
                    )))
                })
                .collect();
            let mut paths = Vec::new();
            for tick in 0..30 {
                for a in &mut agents {
                    a.plan(&w, &geo, tick as f64 * 5.0);
                    for r in drain(a) {
                        a.answered(&r, true, None);
                        paths.push(r.path);
                    }
                }
            }
            paths
        };
        let a = run(5);
        assert!(a.len() > 100);
        assert_eq!(a, run(5));
        assert_ne!(a, run(6));
    }

    #[test]
    fn polling_players_fetch_their_planned_tiles_and_revalidate() {
        let w = world();
        let geo = towns(1);
        let mut agent = Agent::new(Role::Player(Player::new(
            0,
            1,
            FetchMode::Poll,
            DEFAULT_QUALITY,
            Wire::V3,
        )));
        agent.plan(&w, &geo, 0.0);
        let reqs = drain(&mut agent);
        assert_eq!(reqs[0].kind, RequestKind::Splats);
        let tiles: Vec<_> = reqs.iter().filter(|r| r.kind == RequestKind::Tile).collect();
        assert!(!tiles.is_empty());
        assert!(tiles.iter().all(|r| r.etag.is_none() && r.path.contains("&t=43200")));
        agent.answered(tiles[0], true, Some("\"abc\"".into()));
        // One second later: a new time, the same resources, the held ETag is sent.
        agent.plan(&w, &geo, 1.0);
        let first = agent.next_request().unwrap();
        assert_eq!(first.kind, RequestKind::Tile, "the splat sheet is fetched once");
        assert_eq!(first.resource, tiles[0].resource);
        assert_eq!(first.etag.as_deref(), Some("\"abc\""));
    }

    #[test]
    fn game_servers_mix_region_and_series() {
        let w = world();
        let geo = towns(1);
        let mut g = GameServer::new(0, 1);
        let kinds: Vec<_> = (0..8).map(|i| g.request(&w, &geo, i as f64).kind).collect();
        assert_eq!(kinds.iter().filter(|k| **k == RequestKind::Series).count(), 2);
        assert!(g.request(&w, &geo, 0.0).path.contains("/region?bbox="));
    }

    #[test]
    fn a_flying_player_looks_from_its_group_s_altitude() {
        let geo = Geometry::new(GeometryKind::Towns, 64, 2, Vec::new(), 7_200.0);
        let (g, s) = (0..64)
            .flat_map(|g| (0..72).map(move |i| (g, i as f64 * 100.0)))
            .find(|&(g, s)| geo.position(g, s)[2] > 500.0)
            .expect("a group in flight within 2 h");
        let p = Player::new(g * GROUP_SIZE, 2, FetchMode::Keyframes, DEFAULT_QUALITY, Wire::V3);
        let cam = p.camera(&geo, s);
        let c = geo.position(g, s);
        assert!(cam.position[2] >= c[2] + 2.0 && cam.position[2] <= c[2] + 50.0);
        assert!((cam.position[0] - c[0]).abs() <= PARTY_SPREAD && (cam.position[1] - c[1]).abs() <= PARTY_SPREAD);
    }
}
