// Types of cloudscape.js, the cloudscape JS client (an ES module).

/** Levels past which the keyframe span stops doubling. */
export const MAX_KEYFRAME_DOUBLINGS: 4;

/** One layer of a world's discovery document (`/v1/worlds/{world}`). */
export interface Layer {
  name: string;
  preset: string;
  mode: string;
  /** Altitude of the layer's bottom and top, metres. */
  base: number;
  top: number;
  /** Level-0 cell size, metres (horizontal, vertical). */
  cell_size: number;
  cell_height: number;
  /** Depth in cells: the first axis of density grids. */
  depth: number;
  /** Seconds per automaton step. */
  dt: number;
  frame_seconds: number;
  /** Keyframe span of tiles of level 0, 1, …; level z uses entry min(z, len − 1). */
  keyframe_spans?: number[];
  /** Whether the layer can rain or snow (`precipitation.png` is worth asking for). */
  precipitates?: boolean;
  /** Whether `/lightning` lists strikes in the layer. */
  lightning?: boolean;
  /** Wind at the base (m/s, x east, y north) and its change with height ((m/s)/m). */
  wind: [number, number];
  shear: [number, number];
}

/** A world's discovery document (`/v1/worlds/{world}`). */
export interface World {
  name: string;
  seed: number;
  algorithm_version: number;
  tile_size: number;
  minzoom: number;
  maxzoom: number;
  max_time: number;
  frames_per_step: number;
  keyframes?: string;
  /** The world clock: `t = offset + rate · Unix seconds`; `now` the world time the document was answered at. */
  clock?: WorldClock;
  layers: Layer[];
  products: string[];
  tiles: string[];
  [key: string]: unknown;
}

/** A world's clock, from discovery. */
export interface WorldClock {
  offset: number;
  /** World seconds per real second. */
  rate: number;
  /** World time of the answer, whole seconds. */
  now: number;
}

/** A keyframe span: `t0 = index · span`, `t1 = t0 + span`, `f` where a time falls in it. */
export interface Keyframe {
  index: number;
  t0: number;
  t1: number;
  span: number;
  f: number;
}

/** The linear colour of billboards.bin colour code value q in [0, 1] for a header's ALGORITHM_VERSION (display steps at exposure 3 since 13, (c / 2)^(1/2.2) before). */
export function colourOfCode(q: number, algorithmVersion: number): number;
export function keyframeSpan(layer: Pick<Layer, 'dt' | 'keyframe_spans'>, z: number): number;
/** The fraction of its span (in [0.5, 0.8)) past which tile (z, x, y)'s next keyframe is fetched. */
export function prefetchAt(z: number, x: number, y: number): number;
export function keyframeOf(layer: Pick<Layer, 'dt' | 'keyframe_spans'>, z: number, t: number, maxTime?: number): Keyframe;
export function fraction(t0: number, t1: number, t: number): number;
export function isImmutable(cacheControl: string | null | undefined): boolean;

/** A tile of a layer: level z (0 is the finest), x east, y north. */
export interface TileRef {
  layer: string;
  z: number;
  x: number;
  y: number;
}

/** When and how a tile is asked for. */
export interface TileTime {
  /** World-clock seconds; the URL uses the keyframe that holds it. */
  t: number;
  quality?: 'fast' | 'balanced' | 'accurate' | string;
  /** Sun azimuth and elevation, degrees; omitted: the world clock's sun. */
  sun?: [number, number];
  /** The next keyframe's URL instead (what to prefetch). */
  next?: boolean;
  /** `billboardTile`: fetch the next keyframe past the tile's prefetch point (default true). */
  prefetch?: boolean;
}

export interface FetchResult {
  body: ArrayBuffer;
  status: number;
  etag: string | null;
  immutable: boolean;
  /**
   * `network`: a 200; `revalidated`: a 304 reused the kept body; `memory`: an immutable
   * body kept in memory, `cache`: one kept in the Cache Storage (no request either).
   */
  source: 'network' | 'revalidated' | 'memory' | 'cache';
}

export interface FetchStats {
  requests: number;
  fetched: number;
  revalidated: number;
  reused: number;
  bodyBytes: number;
  retries: number;
  /** Delta keyframes (`billboards.delta.bin`) fetched over the network. */
  deltas: number;
  /** Next-keyframe products fetched ahead of need. */
  prefetched: number;
}

export interface ClientOptions {
  fetch?: typeof fetch;
  maxBodies?: number;
  maxRetries?: number;
  /** Default quality of shaded products. */
  quality?: string;
  /** A Cache Storage cache (`caches.open(…)`, in a browser) that keeps bodies across reloads. */
  cache?: Cache | Promise<Cache | null> | null;
  /** Tile variants whose keyframes are held decoded (default 1024). */
  maxVariants?: number;
  /** Keyframes held per variant (default 3: the one drawn, the next, a spare). */
  keyframesPerVariant?: number;
}

/** Decoded keyframes by tile variant and start time, bounded. */
export class HeldKeyframes {
  constructor(options?: { maxVariants?: number; perVariant?: number });
  readonly maxVariants: number;
  readonly perVariant: number;
  get(variant: string, t0: number): BillboardTile | null;
  /** The keyframe of `variant` whose span ends at `t0`. */
  endingAt(variant: string, t0: number): BillboardTile | null;
  insert(variant: string, t0: number, keyframe: BillboardTile): void;
  readonly size: number;
}

export class CloudscapeError extends Error {
  url: string;
  status: number;
  code: string;
}

export class CloudscapeClient {
  constructor(baseUrl: string, options?: ClientOptions);
  readonly base: string;
  quality: string;
  stats: FetchStats;
  /** The billboard keyframes held decoded. */
  keyframes: HeldKeyframes;
  url(path: string): string;
  /** `keep: false`: not kept in memory; `fresh: true`: no stored copy used or kept. */
  fetch(path: string, options?: { keep?: boolean; fresh?: boolean }): Promise<FetchResult>;
  bytes(path: string): Promise<ArrayBuffer>;
  json<T = unknown>(path: string): Promise<T>;
  holds(path: string): boolean;
  worldList(): Promise<{ algorithm_version: number; worlds: { name: string; seed: number; layers: string[]; url: string }[] }>;
  world(name?: string): Promise<World>;
  splats(quality?: string): Promise<SplatManifest>;
  tilePath(world: World, tile: TileRef, product: string, at: TileTime): string;
  tile(world: World, tile: TileRef, product: string, at: TileTime): Promise<ArrayBuffer>;
  /** What names a tile variant's keyframes (world, layer, tile, quality, sun). */
  variant(world: World, tile: TileRef, at: TileTime): string;
  /** The decoded keyframe holding `at.t` (`at.next`: the next one): held, a delta on the held one before, or self-contained. */
  keyframe(world: World, tile: TileRef, at: TileTime): Promise<BillboardTile>;
  billboardTile(world: World, tile: TileRef, at: TileTime): Promise<{ billboards: BillboardTile }>;
  /** `billboards.bin` in `products` (the default) stands for the decoded keyframe. */
  prefetchNext(world: World, tile: TileRef, at: TileTime, products?: string[]): Promise<string[]>;
}

/** The world time of a discovery document's clock, as a function of wall-clock ms (default now). */
export function worldClock(world: Pick<World, 'clock' | 'max_time'>, options?: { rate?: number | null; readAt?: number }): (ms?: number) => number;

/** `/v1/splats.json`. */
export interface SplatManifest {
  count: number;
  size: number;
  columns: number;
  rows: number;
  tau_max: number;
  tau: number[];
  [key: string]: unknown;
}

export const BILLBOARD_FORMATS: { 1: { header: 64; record: 36 }; 2: { header: 160; record: 56 } };

export interface Lighting {
  /** Unit vector toward the sun (x east, y north, z up). */
  sunDirection: [number, number, number];
  /** Linear RGB. */
  sunRgb: [number, number, number];
  ambientRgb: [number, number, number];
  albedo: number;
  extinctionPerM: number;
  phase: { g1: number; g2: number; mix: number };
  octaves: { count: number; a: number; b: number; c: number };
}

export interface BillboardHeader {
  version: 1 | 2 | 3;
  /** Version 3: `self-contained` (form 0) or `delta` (form 1, decoded on the previous keyframe); null before. */
  form: 'self-contained' | 'delta' | null;
  count: number;
  tile: { z: number; x: number; y: number };
  /** South-west corner of the tile, world metres. */
  origin: [number, number];
  sun: { azimuthDeg: number; elevationDeg: number };
  splatCount: number;
  splatSize: number;
  /** Tile side, metres. */
  size: number;
  /** Keyframe span (versions 2 and 3); null for version 1. */
  t0: number | null;
  t1: number | null;
  lighting: Lighting | null;
  algorithmVersion: number | null;
}

/**
 * How each billboard looks, as columns. In a tile's records the two-ended ones
 * hold end 0 (t0) at 2i and end 1 (t1) at 2i + 1 (colour 6 per record); in a
 * frame every column holds one value per billboard (colour 3). `radius` is one per
 * billboard in both.
 */
export interface BillboardLooks {
  radius: Float32Array;
  splatTau: Float32Array;
  splat: Uint16Array;
  /** Linear RGB (in records: at t0, then at t1). */
  colour: Float32Array;
  tauSun: Float32Array;
  opacity: Float32Array;
  sunTransmittance: Float32Array;
}

/** Records as columns: where each billboard is and how it moves, and its looks at both ends. */
export interface BillboardRecords extends BillboardLooks {
  /** x, y from the tile origin at t0 and altitude, metres (3 per record). */
  offset: Float32Array;
  /** m/s, x east, y north (2 per record). */
  velocity: Float32Array;
}

/** One lattice level of a version-3 keyframe: where its sites are and how it moves. */
export interface LatticeLevel {
  /** The level's drift at t0, metres. */
  offset: [number, number];
  /** Wind at the level's altitude, m/s. */
  velocity: [number, number];
  /** Index shift (i, j) from the t0 lattice to the t1 lattice. */
  shift: [number, number];
  /** First row in the tile, and rows. */
  j0: number;
  rows: number;
  /** First column and count of rows with (j + k) even, then odd. */
  runs: [[number, number], [number, number]];
  /** First column and width of the level's box. */
  first: number;
  width: number;
}

/** A version-3 keyframe's lattice: what the next keyframe's delta is decoded against. */
export interface Lattice {
  geometry: { spacing: number; verticalSpacing: number; base: number; radius: number; levels: LatticeLevel[] };
  quantisation: { colourBits: number; tauSunSteps: number; tauFloor: number };
  /** Index of each level's first site. */
  bases: number[];
  /** Each site's state at t1, 5 codes a site: splat (0 none, else index + 1), green, red, blue, τ_sun. */
  end: Uint16Array;
  /** How much wider than a ball its derived ground shadow is, in radii (the server's light-buffer texel). */
  shadowWidening: number;
}

export interface BillboardTile {
  header: BillboardHeader;
  count: number;
  records: BillboardRecords;
  /** Version 3; null before. */
  lattice: Lattice | null;
}

/** Decodes billboards.bin of version 3, 2 or 1; a version-3 delta needs `previous`, its tile's keyframe before. Throws an Error on malformed bytes. */
export function decodeBillboards(buffer: ArrayBuffer | ArrayBufferView, previous?: BillboardTile | null): BillboardTile;
export function halfToFloat(h: number): number;
export const SPLAT_TAU_MAX: number;
export function splatTauOf(k: number, count: number, tauMax?: number): number;
export function splatForTau(tau: number, count: number, tauMax?: number): number;

/** A tile's billboards at one time (the animation rule applied). */
export interface BillboardFrame extends BillboardLooks {
  count: number;
  t: number;
  f: number;
  /** World metres, x east, y north, z up (3 per billboard). */
  position: Float64Array;
  /** 1 where the billboard exists at this time (τ > 0). */
  present: Uint8Array;
}

export function billboardsAt(tile: BillboardTile, t: number, sheet?: Pick<SplatManifest, 'count' | 'tau_max'> | null): BillboardFrame;

/** Side of a tile's shadow map, columns. */
export const TILE_COLUMNS: 256;

/** A held tile as the ground shadow sees it: its decoded keyframe, its layer and the layer's base altitude (m). */
export interface HeldTile {
  layer: string | number;
  base: number;
  keyframe: BillboardTile;
}

/** Sunlight transmittance on the layer's base at t0 and t1, 256×256 each, row 0 the southern edge. */
export interface DerivedShadow {
  t0: Float32Array;
  t1: Float32Array;
}

/** S(p): the line integral of Wyvill's field function through a unit ball at impact parameter p. */
export function lineIntegral(p: number): number;
/** S(√q) / S(0), tabulated as the server does. */
export function splatProfile(q: number): number;
/** Unit vector toward the sun a keyframe was shaded for (x east, y north, z up). */
export function keyframeSun(tile: BillboardTile): [number, number, number];
/** Shift of a ground point toward the sun before reading a tile's shadow map, metres. */
export function shadowShift(tile: BillboardTile, base: number): [number, number];
/** The shadow maps of a held tile, cast by the billboards added to it, in as many steps as the caller likes. */
export class ShadowDerivation {
  constructor(target: HeldTile);
  /** Adds the balls of records `[from, to)` of `source` (a held tile of the target's layer). */
  add(source: Pick<HeldTile, 'keyframe'>, from?: number, to?: number): void;
  finish(): DerivedShadow;
}
/** The shadow maps of `target` cast by the billboards of `sources` (its layer's held tiles, itself among them). */
export function deriveShadow(target: HeldTile, sources: Iterable<Pick<HeldTile, 'keyframe'>>): DerivedShadow;
/** The shadow maps of every held tile, each cast by the held tiles of its layer. */
export function shadowMaps(tiles: HeldTile[]): DerivedShadow[];
/** The share of the optical depth of the layers above a billboard that its light takes: the sun ray's, the vertical's. */
export const LAYERS_ABOVE_SUN_DEPTH: number;
export const LAYERS_ABOVE_SKY_DEPTH: number;
/** A billboard end's colour and sun optical depth under layers of optical depth `tauAbove` (sun ray) and `tauVertical` above it. */
export function beneathLayers(
  lighting: Lighting,
  rgb: ArrayLike<number>,
  tauSun: number,
  tauAbove: number,
  tauVertical: number,
): { rgb: number[] | ArrayLike<number>; tauSun: number };
/** The sun term of a pre-shaded billboard colour for a header's lighting: τ_sun → albedo · SUN_SCATTER · sunRgb · Σ bⁱ e^{−aⁱ τ_sun}, red, green, blue. */
export function sunTerm(lighting: Pick<Lighting, 'albedo' | 'octaves' | 'sunRgb'>): (tauSun: number) => number[];
/** The first ALGORITHM_VERSION whose billboards.bin colour codes carry the ambient part, the decoder adding the sun term back. */
export const AMBIENT_CODES_SINCE: 15;
/** The colours (6 per record) and sun optical depths (2 per record) of a held tile's billboards lit through the other layers' held tiles above them. */
export function lightBeneathLayers(
  target: Pick<HeldTile, 'layer' | 'keyframe'>,
  others: Array<Pick<HeldTile, 'layer' | 'base' | 'keyframe'> & { maps?: DerivedShadow | null }>,
): { colour: Float32Array; tauSun: Float32Array };
/** The transmittance a ground point (x, y) reads from a tile's maps a fraction `f` through its span. */
export function shadowAtPoint(maps: DerivedShadow, tile: BillboardTile, base: number, x: number, y: number, f: number): number;

/** How far (horizontally, metres) `cloudscape render` draws clouds. */
export const VIEW_DISTANCE: 30000;
/** Where the ground's cloud shadow starts to fade into the mean shadow, a fraction of the view distance (render::scene::SHADOW_FADE_START). */
export const SHADOW_FADE_START: 0.4;
/** A tile splits while one of its columns would span more pixels than this, by quality. */
export const LOD_PIXELS: { fast: 8; balanced: 4; accurate: 2 };
/** A camera: position in metres (x east, y north, z up); yaw clockwise from north, pitch above the horizon, horizontal FOV, degrees. */
export interface Camera {
  x: number;
  y: number;
  z: number;
  yaw: number;
  pitch: number;
  fov: number;
}
/** A camera's unit vectors (render::camera::Camera::basis). */
export function cameraBasis(camera: Pick<Camera, 'yaw' | 'pitch'>): {
  forward: [number, number, number];
  right: [number, number, number];
  up: [number, number, number];
};
/** A tile of a plan: its layer by name and index in discovery's list. */
export interface PlannedTile extends PlacedTile {
  layerIndex: number;
}
/**
 * The tiles a camera sees, as `cloudscape render` plans them (scene.rs plan_bands):
 * clouds or their shadow (for `sun`, a unit vector toward it) in the view; null once
 * more than 64 × maxTiles tiles are under way.
 */
export function planTiles(
  world: World,
  camera: Camera,
  width: number,
  height: number,
  options?: {
    quality?: 'fast' | 'balanced' | 'accurate';
    lodPixels?: number;
    viewDistance?: number;
    sun?: [number, number, number] | null;
    layers?: string[];
    maxTiles?: number;
  },
): PlannedTile[] | null;

/** Lengths of the sky.json tables. */
export const SUN_TABLE_LEN: 41;
export const MULTIPLE_SCATTERING_LEN: 12;
/** The detail noise's most octaves, and the footprint (pixels) an octave must span. */
export const MAX_DETAIL_OCTAVES: 4;
export const MIN_WAVELENGTH_PIXELS: 2;
/** The share of the sun's radiance that cloud scatters (render::light::SUN_SCATTER). */
export const SUN_SCATTER: 0.25;
/** The server's light as GLSL ES 3.00 chunks (each declares the uniforms it reads). */
export const GLSL: {
  /** tone(x), display(x); uniforms exposure, toneOut. */
  tone: string;
  /** skyRadiance(d), aerial(v, z0, z1, vis, out T, out L); uniforms of skyUniforms. */
  atmosphere: string;
  /** ground(v, eyeZ, t); uniforms sunGround, above, groundAlbedo; needs atmosphere. */
  ground: string;
  /** phaseCorrection(tauSun, d); reads albedo, phase, octaves, sunRgb, sunDir. */
  octaves: string;
  /** chord(q, v0) and S0: the splat profile. */
  splat: string;
  /** detailNoise(p, octaves). */
  detailNoise: string;
};
/** The uniform values of GLSL.atmosphere, GLSL.ground and GLSL.tone for a parsed /v1/sky.json. */
export function skyUniforms(sky: object): {
  table: { data: Float32Array; columns: number; rows: number };
  values: {
    skySize: [number, number];
    sunDir: [number, number, number];
    night: [number, number, number];
    betaR: [number, number, number];
    mie: [number, number, number, number];
    air: [number, number, number, number];
    sunT: number[];
    multi: number[];
    sunGround: [number, number, number];
    above: [number, number, number];
    groundAlbedo: [number, number, number];
    exposure: number;
  };
};

export function zUpToYUp(p: ArrayLike<number>): [number, number, number];

/** Typed arrays for a three.js InstancedMesh (y up). */
export interface ThreeArrays {
  count: number;
  positions: Float32Array;
  colours: Float32Array;
  opacities: Float32Array;
  radii: Float32Array;
  splatTaus: Float32Array;
  tauSuns: Float32Array;
  splats: Uint16Array;
}

export function threeArrays(
  frames: BillboardFrame | BillboardFrame[],
  options?: { origin?: [number, number, number]; eye?: [number, number, number] | null },
): ThreeArrays;

export interface Png {
  width: number;
  height: number;
  channels: 1 | 2 | 3 | 4;
  data: Uint8Array;
}

export function decodePng(buffer: ArrayBuffer | ArrayBufferView): Promise<Png>;

export interface ShadowMap {
  width: number;
  height: number;
  t0: Float32Array;
  t1: Float32Array;
}

export function decodeShadow(buffer: ArrayBuffer | ArrayBufferView): Promise<ShadowMap>;
export function shadowAt(shadow: ShadowMap, f: number): Float32Array;

export interface CoverageMap {
  width: number;
  height: number;
  coverage: Float32Array;
  opacity: Float32Array;
  top: Float32Array;
}

export function decodeCoverage(buffer: ArrayBuffer | ArrayBufferView): Promise<CoverageMap>;

export interface DensityGrid<T extends Float32Array | Uint8Array> {
  /** (depth, rows, cols), row = y (row 0 south), col = x. */
  shape: [number, number, number];
  data: T;
}

export function decodeDensityU8(buffer: ArrayBuffer | ArrayBufferView, depth: number, side?: number): DensityGrid<Uint8Array>;
export function decodeDensityF32(buffer: ArrayBuffer | ArrayBufferView, depth: number, side?: number): DensityGrid<Float32Array>;
/** density.ktx2 (KTX 2.0, no supercompression): level 0 and its size. */
export function decodeKtx2(buffer: ArrayBuffer | ArrayBufferView): { vkFormat: number; width: number; height: number; depth: number; data: Uint8Array };
export function decodeNpy(buffer: ArrayBuffer | ArrayBufferView): { shape: number[]; dtype: '<f4' | '|u1'; data: Float32Array | Uint8Array };

export function blendDensityAt(
  d0: (x: number, y: number) => number,
  d1: (x: number, y: number) => number,
  x: [number, number],
  velocity: [number, number],
  t0: number,
  t1: number,
  t: number,
): number;
export function layerVelocity(layer: Pick<Layer, 'base' | 'wind' | 'shear'>, z: number): [number, number];

export interface PlacedTile extends TileRef {
  origin: [number, number];
  size: number;
}

export function tilesAround(world: World, layer: string, z: number, x: number, y: number, radius: number): PlacedTile[];
