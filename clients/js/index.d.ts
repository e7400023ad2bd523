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
  layers: Layer[];
  products: string[];
  tiles: string[];
  [key: string]: unknown;
}

/** A keyframe span: `t0 = index · span`, `t1 = t0 + span`, `f` where a time falls in it. */
export interface Keyframe {
  index: number;
  t0: number;
  t1: number;
  span: number;
  f: number;
}

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
  /** `billboardTile`: fetch the next keyframe past the middle of the span (default true). */
  prefetch?: boolean;
  /** `billboardTile`: fetch and decode shadow.png too (default true). */
  shadow?: boolean;
}

export interface FetchResult {
  body: ArrayBuffer;
  status: number;
  etag: string | null;
  immutable: boolean;
  /** `network`: a 200; `revalidated`: a 304 reused the kept body; `memory`: an immutable body, no request. */
  source: 'network' | 'revalidated' | 'memory';
}

export interface FetchStats {
  requests: number;
  fetched: number;
  revalidated: number;
  reused: number;
  bodyBytes: number;
  retries: number;
}

export interface ClientOptions {
  fetch?: typeof fetch;
  maxBodies?: number;
  maxRetries?: number;
  /** Default quality of shaded products. */
  quality?: string;
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
  url(path: string): string;
  fetch(path: string): Promise<FetchResult>;
  bytes(path: string): Promise<ArrayBuffer>;
  json<T = unknown>(path: string): Promise<T>;
  holds(path: string): boolean;
  worldList(): Promise<{ algorithm_version: number; worlds: { name: string; seed: number; layers: string[]; url: string }[] }>;
  world(name?: string): Promise<World>;
  splats(quality?: string): Promise<SplatManifest>;
  tilePath(world: World, tile: TileRef, product: string, at: TileTime): string;
  tile(world: World, tile: TileRef, product: string, at: TileTime): Promise<ArrayBuffer>;
  billboardTile(world: World, tile: TileRef, at: TileTime): Promise<{ billboards: BillboardTile; shadow: ShadowMap | null }>;
  prefetchNext(world: World, tile: TileRef, at: TileTime, products?: string[]): Promise<string[]>;
}

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
  version: 1 | 2;
  count: number;
  tile: { z: number; x: number; y: number };
  /** South-west corner of the tile, world metres. */
  origin: [number, number];
  sun: { azimuthDeg: number; elevationDeg: number };
  splatCount: number;
  splatSize: number;
  /** Tile side, metres. */
  size: number;
  /** Keyframe span (version 2); null for version 1. */
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

export interface BillboardTile {
  header: BillboardHeader;
  count: number;
  records: BillboardRecords;
}

export function decodeBillboards(buffer: ArrayBuffer | ArrayBufferView): BillboardTile;
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
