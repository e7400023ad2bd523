// cloudscape JS client: an ES module for browsers, Node (18+), Deno and bundlers.
//
// It fetches tiles from a cloudscape server with ETag revalidation and immutable
// caching, computes keyframe URLs from the world's discovery document, decodes every
// binary product (billboards.bin versions 1 and 2, PNG, density .u8/.f32/.npy),
// applies the keyframe animation rule, and builds typed arrays ready for three.js
// (y up). Types: index.d.ts. Formats and the rule: docs/formats.md and the doc comment
// of crates/cloudscape-core/src/products/billboards.rs.
//
// No dependencies. The server serves this file at `/client/cloudscape.js`.

// ---------------------------------------------------------------------------------
// Keyframes (crates/cloudscape-core/src/world/keyframe.rs).
// ---------------------------------------------------------------------------------

/** Levels past which the keyframe span stops doubling. */
export const MAX_KEYFRAME_DOUBLINGS = 4;

/**
 * The keyframe span (seconds) of level `z` of a discovery layer: its
 * `keyframe_spans[min(z, len − 1)]`, or `dt · 2^min(z, 4)` when discovery lists none.
 */
export function keyframeSpan(layer, z) {
  const spans = layer.keyframe_spans;
  if (spans && spans.length) return spans[Math.min(z, spans.length - 1)];
  return layer.dt * 2 ** Math.min(z, MAX_KEYFRAME_DOUBLINGS);
}

/**
 * The keyframe span of level `z` of `layer` that holds `t`: `t0 = floor(t / span) ·
 * span`, `t1 = t0 + span` (at most `maxTime`), and `f`, where `t` falls in it (0..1).
 */
export function keyframeOf(layer, z, t, maxTime = 1e12) {
  const span = keyframeSpan(layer, z);
  const tc = Math.min(Math.max(Number.isFinite(t) ? t : 0, 0), maxTime);
  let index = Math.floor(tc / span);
  let t0 = index * span;
  if (t0 > tc) {
    index -= 1;
    t0 = index * span;
  }
  const t1 = Math.min(t0 + span, maxTime);
  return { index, t0, t1, span: t1 - t0, f: fraction(t0, t1, tc) };
}

/**
 * The fraction of its span past which tile (z, x, y)'s next keyframe is fetched: in
 * [0.5, 0.8), by a hash of the tile (cloudscape_core::world::prefetch_at, the same
 * 32-bit arithmetic), so the tiles of a view, and of every player sharing the world
 * clock, are not all asked for in the same second.
 */
export function prefetchAt(z, x, y) {
  let h = (Math.imul(x | 0, 0x9e3779b1) ^ Math.imul(y | 0, 0x85ebca77) ^ Math.imul((z + 1) | 0, 0xc2b2ae3d)) >>> 0;
  h = (h ^ (h >>> 16)) >>> 0;
  h = Math.imul(h, 0x7feb352d) >>> 0;
  h = (h ^ (h >>> 15)) >>> 0;
  return 0.5 + 0.3 * (h / 4294967296);
}

/** Where `t` falls in `[t0, t1]`, clamped to 0..1 (0 for an instant). */
export function fraction(t0, t1, t) {
  const span = t1 - t0;
  return span > 0 ? Math.min(Math.max((t - t0) / span, 0), 1) : 0;
}

// ---------------------------------------------------------------------------------
// Fetching: ETags, immutable bodies, 503 retries.
// ---------------------------------------------------------------------------------

/** Whether a Cache-Control value says `immutable`. */
export function isImmutable(cacheControl) {
  return (cacheControl || '').split(',').some((d) => d.trim().toLowerCase() === 'immutable');
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** An error answer from the server: its status and its JSON `error`/`message`. */
export class CloudscapeError extends Error {
  constructor(url, status, code, message) {
    super(`${url}: ${status} ${message}`);
    this.name = 'CloudscapeError';
    this.url = url;
    this.status = status;
    this.code = code;
  }
}

/**
 * A client of one cloudscape server.
 *
 * Bodies are kept by URL (at most `maxBodies`, oldest forgotten first). An immutable
 * one (`Cache-Control: immutable`, as keyframe URLs are) is returned again without a
 * request; any other is revalidated with `If-None-Match`, and a 304 returns the kept
 * body. A 503 is retried after its `Retry-After`.
 */
export class CloudscapeClient {
  /**
   * @param {string} baseUrl the server's origin: scheme, host and port (a trailing `/` is ignored; '' for the page's own origin)
   * @param {{fetch?: typeof fetch, maxBodies?: number, maxRetries?: number, quality?: string}} [options]
   */
  constructor(baseUrl, options = {}) {
    this.base = String(baseUrl || '').replace(/\/+$/, '');
    this.fetchImpl = options.fetch || globalThis.fetch.bind(globalThis);
    this.maxBodies = options.maxBodies ?? 1024;
    this.maxRetries = options.maxRetries ?? 8;
    this.quality = options.quality || 'fast';
    /** @type {Map<string, {body: ArrayBuffer, etag: string | null, immutable: boolean}>} */
    this.bodies = new Map();
    this.worlds = new Map();
    this.stats = { requests: 0, fetched: 0, revalidated: 0, reused: 0, bodyBytes: 0, retries: 0 };
  }

  /** The absolute URL of a path. */
  url(path) {
    return /^https?:/.test(path) ? path : `${this.base}${path}`;
  }

  /**
   * GETs a path (or URL) and returns `{ body, status, etag, immutable, source }`;
   * `source` is `network` (a 200), `revalidated` (a 304) or `memory` (an immutable
   * body kept, no request made).
   */
  async fetch(path) {
    const url = this.url(path);
    const kept = this.bodies.get(url);
    if (kept && kept.immutable) {
      this.stats.reused++;
      this.bodies.delete(url);
      this.bodies.set(url, kept);
      return { body: kept.body, status: 200, etag: kept.etag, immutable: true, source: 'memory' };
    }
    const headers = kept && kept.etag ? { 'If-None-Match': kept.etag } : {};
    for (let attempt = 0; ; attempt++) {
      this.stats.requests++;
      const res = await this.fetchImpl(url, { headers, cache: 'no-store' });
      if (res.status === 304 && kept) {
        this.stats.revalidated++;
        return { body: kept.body, status: 304, etag: kept.etag, immutable: kept.immutable, source: 'revalidated' };
      }
      if (res.status === 503 && attempt < this.maxRetries) {
        this.stats.retries++;
        const after = Number(res.headers.get('Retry-After'));
        await res.arrayBuffer().catch(() => {});
        await sleep(Number.isFinite(after) && after > 0 ? Math.min(after, 30) * 1000 : 250 * 2 ** Math.min(attempt, 4));
        continue;
      }
      if (!res.ok) {
        let code = 'http';
        let message = res.statusText;
        try {
          const e = await res.json();
          code = e.error || code;
          message = e.message || message;
        } catch {
          // not JSON
        }
        throw new CloudscapeError(url, res.status, code, message);
      }
      const body = await res.arrayBuffer();
      const etag = res.headers.get('ETag');
      const immutable = isImmutable(res.headers.get('Cache-Control'));
      this.stats.fetched++;
      this.stats.bodyBytes += body.byteLength;
      if (etag || immutable) {
        this.bodies.delete(url);
        this.bodies.set(url, { body, etag, immutable });
        while (this.bodies.size > this.maxBodies) this.bodies.delete(this.bodies.keys().next().value);
      }
      return { body, status: res.status, etag, immutable, source: 'network' };
    }
  }

  /** GETs a path and returns its body. */
  async bytes(path) {
    return (await this.fetch(path)).body;
  }

  /** GETs a path and parses its JSON body. */
  async json(path) {
    return JSON.parse(new TextDecoder().decode(await this.bytes(path)));
  }

  /** Whether an immutable body of a path is kept (no request would be made). */
  holds(path) {
    const kept = this.bodies.get(this.url(path));
    return Boolean(kept && kept.immutable);
  }

  /** The world list (`/v1/worlds`). */
  async worldList() {
    return this.json('/v1/worlds');
  }

  /** A world's discovery document (`/v1/worlds/{world}`), fetched once per client. */
  async world(name = 'default') {
    if (!this.worlds.has(name)) this.worlds.set(name, await this.json(`/v1/worlds/${encodeURIComponent(name)}`));
    return this.worlds.get(name);
  }

  /** The splat sheet's manifest (`/v1/splats.json`). */
  async splats(quality = this.quality) {
    return this.json(`/v1/splats.json?quality=${encodeURIComponent(quality)}`);
  }

  /**
   * The keyframe URL (a path) of a tile product at the keyframe that holds `t`:
   * the same for every `t` in the span, and immutable.
   *
   * @param {object} world the discovery document
   * @param {{layer: string, z: number, x: number, y: number}} tile
   * @param {string} product e.g. `billboards.bin`
   * @param {{t: number, quality?: string, sun?: [number, number], next?: boolean}} at
   *   `next`: the following keyframe's URL (what to prefetch)
   */
  tilePath(world, tile, product, at) {
    const layer = findLayer(world, tile.layer);
    const k = keyframeOf(layer, tile.z, at.t, world.max_time);
    const t = at.next ? k.t1 : k.t0;
    let q = `t=${t}`;
    // Only shaded products depend on quality and sun; the server ignores them otherwise.
    q += `&quality=${encodeURIComponent(at.quality || this.quality)}`;
    if (at.sun) q += `&sun=${at.sun[0]},${at.sun[1]}`;
    return (
      `/v1/worlds/${encodeURIComponent(world.name)}/tiles/${tile.z}/${tile.x}/${tile.y}/${product}` +
      `?${q}&layer=${encodeURIComponent(layer.name)}`
    );
  }

  /** The body of a tile product at the keyframe that holds `at.t`. */
  async tile(world, tile, product, at) {
    return this.bytes(this.tilePath(world, tile, product, at));
  }

  /**
   * A tile's billboards (decoded billboards.bin) and shadow map (decoded shadow.png)
   * at the keyframe that holds `at.t`. Past the tile's prefetch point (`prefetchAt`,
   * in the second half of the span) the next keyframe's products are fetched in the background (`prefetch: false` turns that
   * off), so the boundary costs no wait.
   */
  async billboardTile(world, tile, at) {
    const [bin, png] = await Promise.all([
      this.tile(world, tile, 'billboards.bin', at),
      at.shadow === false ? null : this.tile(world, tile, 'shadow.png', at),
    ]);
    const billboards = decodeBillboards(bin);
    const shadow = png ? await decodeShadow(png) : null;
    if (at.prefetch !== false) this.prefetchNext(world, tile, at);
    return { billboards, shadow };
  }

  /**
   * Fetches the next keyframe's `products` of a tile when `at.t` is past the tile's
   * prefetch point in its span (`prefetchAt`, between 0.5 and 0.8); resolves to the
   * paths fetched (none before it). Errors are swallowed: the tile is asked for again
   * when its keyframe comes.
   */
  async prefetchNext(world, tile, at, products = ['billboards.bin', 'shadow.png']) {
    const k = keyframeOf(findLayer(world, tile.layer), tile.z, at.t, world.max_time);
    if (!(k.span > 0 && k.f >= prefetchAt(tile.z, tile.x, tile.y))) return [];
    const paths = products.map((p) => this.tilePath(world, tile, p, { ...at, next: true })).filter((p) => !this.holds(p));
    await Promise.all(paths.map((p) => this.fetch(p).catch(() => null)));
    return paths;
  }
}

function findLayer(world, name) {
  const layer = world.layers.find((l) => l.name === name);
  if (!layer) throw new Error(`world ${world.name} has no layer ${name}`);
  return layer;
}

// ---------------------------------------------------------------------------------
// billboards.bin (crates/cloudscape-core/src/products/billboards.rs).
// ---------------------------------------------------------------------------------

/** Header and record bytes by format version. */
export const BILLBOARD_FORMATS = { 1: { header: 64, record: 36 }, 2: { header: 160, record: 56 } };

/** IEEE 754 binary16 → number. */
export function halfToFloat(h) {
  const sign = h & 0x8000 ? -1 : 1;
  const e = (h >> 10) & 0x1f;
  const m = h & 0x3ff;
  if (e === 0) return sign * m * 2 ** -24;
  if (e === 31) return m ? NaN : sign * Infinity;
  return sign * (1 + m / 1024) * 2 ** (e - 15);
}

let halfTable = null;
function half(h) {
  if (!halfTable) {
    halfTable = new Float32Array(65536);
    for (let i = 0; i < 65536; i++) halfTable[i] = halfToFloat(i);
  }
  return halfTable[h];
}

/**
 * Decodes billboards.bin (version 2, a keyframe with both ends of each billboard and
 * the lighting in its header; or version 1, one time). Records come as columns of
 * typed arrays; index `2i` / `2i + 1` of a two-ended column is billboard i's end at
 * t0 / t1 (a version-1 tile has the same value at both ends and a zero velocity).
 * Offsets are metres from the tile origin (x east, y north), altitude absolute.
 */
export function decodeBillboards(buffer) {
  const buf = buffer instanceof ArrayBuffer ? buffer : toArrayBuffer(buffer);
  const v = new DataView(buf);
  if (buf.byteLength < 64) throw new Error('billboards.bin: shorter than a header');
  const magic = String.fromCharCode(v.getUint8(0), v.getUint8(1), v.getUint8(2), v.getUint8(3));
  const version = v.getUint16(4, true);
  const format = BILLBOARD_FORMATS[version];
  if (magic !== 'CSBB') throw new Error('billboards.bin: bad magic');
  if (!format) throw new Error(`billboards.bin: unknown version ${version}`);
  if (v.getUint16(6, true) !== format.record) throw new Error(`billboards.bin: record size ${v.getUint16(6, true)} for version ${version}`);
  const count = v.getUint32(8, true);
  if (buf.byteLength !== format.header + count * format.record) {
    throw new Error(`billboards.bin: ${buf.byteLength} bytes for ${count} records`);
  }
  const f32 = (o) => v.getFloat32(o, true);
  const vec3 = (o) => [f32(o), f32(o + 4), f32(o + 8)];
  const header = {
    version,
    count,
    tile: { z: v.getUint32(12, true), x: Number(v.getBigInt64(16, true)), y: Number(v.getBigInt64(24, true)) },
    origin: [v.getFloat64(32, true), v.getFloat64(40, true)],
    sun: { azimuthDeg: f32(48), elevationDeg: f32(52) },
    splatCount: v.getUint16(56, true),
    splatSize: v.getUint16(58, true),
    size: f32(60),
    t0: null,
    t1: null,
    lighting: null,
    algorithmVersion: null,
  };
  if (version >= 2) {
    header.t0 = v.getFloat64(64, true);
    header.t1 = v.getFloat64(72, true);
    header.lighting = {
      sunDirection: vec3(80),
      sunRgb: vec3(92),
      ambientRgb: vec3(104),
      albedo: f32(116),
      extinctionPerM: f32(120),
      phase: { g1: f32(124), g2: f32(128), mix: f32(132) },
      octaves: { count: v.getUint32(136, true), a: f32(140), b: f32(144), c: f32(148) },
    };
    header.algorithmVersion = v.getUint32(152, true);
  }
  const r = {
    offset: new Float32Array(3 * count),
    radius: new Float32Array(count),
    velocity: new Float32Array(2 * count),
    splatTau: new Float32Array(2 * count),
    splat: new Uint16Array(2 * count),
    colour: new Float32Array(6 * count),
    tauSun: new Float32Array(2 * count),
    opacity: new Float32Array(2 * count),
    sunTransmittance: new Float32Array(2 * count),
  };
  for (let i = 0; i < count; i++) {
    const o = format.header + i * format.record;
    r.offset[3 * i] = f32(o);
    r.offset[3 * i + 1] = f32(o + 4);
    r.offset[3 * i + 2] = f32(o + 8);
    r.radius[i] = f32(o + 12);
    if (version >= 2) {
      r.velocity[2 * i] = f32(o + 16);
      r.velocity[2 * i + 1] = f32(o + 20);
      for (let e = 0; e < 2; e++) {
        r.splatTau[2 * i + e] = f32(o + 24 + 4 * e);
        r.splat[2 * i + e] = v.getUint16(o + 32 + 2 * e, true);
        for (let c = 0; c < 3; c++) r.colour[6 * i + 3 * e + c] = half(v.getUint16(o + 36 + 6 * e + 2 * c, true));
        r.tauSun[2 * i + e] = half(v.getUint16(o + 48 + 2 * e, true));
        r.opacity[2 * i + e] = v.getUint8(o + 52 + e) / 255;
        r.sunTransmittance[2 * i + e] = v.getUint8(o + 54 + e) / 255;
      }
    } else {
      const splat = v.getUint16(o + 16, true);
      const tau = splatTauOf(splat, header.splatCount);
      for (let e = 0; e < 2; e++) {
        r.splatTau[2 * i + e] = tau;
        r.splat[2 * i + e] = splat;
        for (let c = 0; c < 3; c++) r.colour[6 * i + 3 * e + c] = f32(o + 20 + 4 * c);
        r.tauSun[2 * i + e] = f32(o + 32);
        r.opacity[2 * i + e] = v.getUint8(o + 18) / 255;
        r.sunTransmittance[2 * i + e] = v.getUint8(o + 19) / 255;
      }
    }
  }
  return { header, count, records: r };
}

/** Largest centre optical depth of the splat sheet (src/render/splats.rs TAU_MAX; /v1/splats.json `tau_max`). */
export const SPLAT_TAU_MAX = 8;

/** Centre optical depth τ_k of splat `k` of a sheet of `count`: `tau_max · ((k + 1) / count)²`. */
export function splatTauOf(k, count, tauMax = SPLAT_TAU_MAX) {
  const x = (Math.min(k, count - 1) + 1) / count;
  return tauMax * x * x;
}

/** The splat whose τ_k is nearest `tau` (on the squared scale), as SplatSheet::index_for_tau. */
export function splatForTau(tau, count, tauMax = SPLAT_TAU_MAX) {
  if (!(tau > 0)) return 0;
  const x = Math.sqrt(Math.min(tau, tauMax) / tauMax) * count - 1;
  return Math.min(Math.max(Math.round(x), 0), count - 1);
}

/**
 * The animation rule (render::keyframe): a decoded tile's billboards at time `t`,
 * with f = (t − t0) / (t1 − t0) clamped to the span. Each billboard is moved by its
 * velocity · f · span; its centre optical depth `splatTau`, colour, `tauSun`, peak
 * `opacity` and `sunTransmittance` are linear in f; `splat` is the splat nearest its
 * τ (pass the sheet's `count` and `tau_max` in `sheet`; without it, the end nearer in
 * time, as the Rust client does). Positions are world metres (x east, y north, z up),
 * as Float64Array. A billboard with τ = 0 is absent at `t` (it forms or vanishes
 * during the span): `present` says which are drawn.
 */
export function billboardsAt(tile, t, sheet = null) {
  const { header, count, records: r } = tile;
  const t0 = header.t0 ?? t;
  const t1 = header.t1 ?? t;
  const f = fraction(t0, t1, t);
  const since = f * (t1 - t0);
  const out = {
    count,
    t,
    f,
    position: new Float64Array(3 * count),
    radius: r.radius,
    splatTau: new Float32Array(count),
    splat: new Uint16Array(count),
    colour: new Float32Array(3 * count),
    tauSun: new Float32Array(count),
    opacity: new Float32Array(count),
    sunTransmittance: new Float32Array(count),
    present: new Uint8Array(count),
  };
  const lerp = (a, b) => (1 - f) * a + f * b;
  for (let i = 0; i < count; i++) {
    out.position[3 * i] = header.origin[0] + r.offset[3 * i] + r.velocity[2 * i] * since;
    out.position[3 * i + 1] = header.origin[1] + r.offset[3 * i + 1] + r.velocity[2 * i + 1] * since;
    out.position[3 * i + 2] = r.offset[3 * i + 2];
    const tau = lerp(r.splatTau[2 * i], r.splatTau[2 * i + 1]);
    out.splatTau[i] = tau;
    out.present[i] = tau > 0 ? 1 : 0;
    out.splat[i] = sheet ? splatForTau(tau, sheet.count, sheet.tau_max ?? SPLAT_TAU_MAX) : r.splat[2 * i + (f < 0.5 ? 0 : 1)];
    for (let c = 0; c < 3; c++) out.colour[3 * i + c] = lerp(r.colour[6 * i + c], r.colour[6 * i + 3 + c]);
    out.tauSun[i] = lerp(r.tauSun[2 * i], r.tauSun[2 * i + 1]);
    out.opacity[i] = lerp(r.opacity[2 * i], r.opacity[2 * i + 1]);
    out.sunTransmittance[i] = lerp(r.sunTransmittance[2 * i], r.sunTransmittance[2 * i + 1]);
  }
  return out;
}

// ---------------------------------------------------------------------------------
// three.js: y up.
// ---------------------------------------------------------------------------------

/**
 * A z-up world point (x east, y north, z up; metres) in three.js's y-up frame (x east,
 * y up, z south): `[x, z, −y]`. A right-handed frame goes to a right-handed frame.
 */
export function zUpToYUp(p) {
  return [p[0], p[2], -p[1]];
}

/**
 * Typed arrays for a three.js InstancedMesh or Points of billboards (one frame from
 * `billboardsAt`, or several concatenated by passing an array): `positions` (xyz, y
 * up, relative to `origin`, a z-up world point, so f32 keeps centimetres far from the
 * world origin), `colours` (linear RGB, the pre-shaded isotropic colour), `opacities`
 * (peak opacity), `radii`, `splatTaus`, `tauSuns`, `splats`, and `count`. Absent
 * billboards are left out. With `eye` (a z-up world point) the instances are sorted
 * back to front from it, ready for alpha blending without depth writes.
 */
export function threeArrays(frames, { origin = [0, 0, 0], eye = null } = {}) {
  const list = Array.isArray(frames) ? frames : [frames];
  const idx = [];
  for (let k = 0; k < list.length; k++) {
    for (let i = 0; i < list[k].count; i++) if (list[k].present[i]) idx.push([k, i]);
  }
  if (eye) {
    const d = idx.map(([k, i]) => {
      const p = list[k].position;
      return (p[3 * i] - eye[0]) ** 2 + (p[3 * i + 1] - eye[1]) ** 2 + (p[3 * i + 2] - eye[2]) ** 2;
    });
    const order = idx.map((_, j) => j).sort((a, b) => d[b] - d[a]);
    const sorted = order.map((j) => idx[j]);
    idx.length = 0;
    idx.push(...sorted);
  }
  const n = idx.length;
  const out = {
    count: n,
    positions: new Float32Array(3 * n),
    colours: new Float32Array(3 * n),
    opacities: new Float32Array(n),
    radii: new Float32Array(n),
    splatTaus: new Float32Array(n),
    tauSuns: new Float32Array(n),
    splats: new Uint16Array(n),
  };
  idx.forEach(([k, i], j) => {
    const b = list[k];
    const x = b.position[3 * i] - origin[0];
    const y = b.position[3 * i + 1] - origin[1];
    const z = b.position[3 * i + 2] - origin[2];
    out.positions[3 * j] = x;
    out.positions[3 * j + 1] = z;
    out.positions[3 * j + 2] = -y;
    for (let c = 0; c < 3; c++) out.colours[3 * j + c] = b.colour[3 * i + c];
    out.opacities[j] = b.opacity[i];
    out.radii[j] = b.radius[i];
    out.splatTaus[j] = b.splatTau[i];
    out.tauSuns[j] = b.tauSun[i];
    out.splats[j] = b.splat[i];
  });
  return out;
}

// ---------------------------------------------------------------------------------
// PNG (8-bit, non-interlaced: what the server writes), density grids.
// ---------------------------------------------------------------------------------

function toArrayBuffer(bytes) {
  if (bytes instanceof ArrayBuffer) return bytes;
  return bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
}

async function inflate(bytes) {
  if (typeof DecompressionStream === 'undefined') throw new Error('PNG decoding needs DecompressionStream (Node 18+, any current browser)');
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('deflate'));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

/**
 * Decodes an 8-bit, non-interlaced PNG (grey, grey+alpha, RGB or RGBA; what the server
 * writes) into `{ width, height, channels, data }`, rows top (north) first. In a
 * browser, `createImageBitmap` does the same faster; this one needs no DOM.
 */
export async function decodePng(buffer) {
  const bytes = new Uint8Array(toArrayBuffer(buffer));
  const sig = [137, 80, 78, 71, 13, 10, 26, 10];
  if (!sig.every((b, i) => bytes[i] === b)) throw new Error('not a PNG');
  const v = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let at = 8;
  let width = 0;
  let height = 0;
  let channels = 0;
  const idat = [];
  while (at + 8 <= bytes.length) {
    const len = v.getUint32(at);
    const type = String.fromCharCode(...bytes.subarray(at + 4, at + 8));
    const data = bytes.subarray(at + 8, at + 8 + len);
    if (type === 'IHDR') {
      width = v.getUint32(at + 8);
      height = v.getUint32(at + 12);
      const depth = data[8];
      const colour = data[9];
      channels = { 0: 1, 2: 3, 4: 2, 6: 4 }[colour];
      if (depth !== 8 || !channels || data[12] !== 0) throw new Error(`PNG: only 8-bit non-interlaced grey/RGB(A) is decoded (depth ${depth}, colour type ${colour})`);
    } else if (type === 'IDAT') {
      idat.push(data);
    } else if (type === 'IEND') {
      break;
    }
    at += 12 + len;
  }
  const total = idat.reduce((n, d) => n + d.length, 0);
  const z = new Uint8Array(total);
  let o = 0;
  for (const d of idat) {
    z.set(d, o);
    o += d.length;
  }
  const raw = await inflate(z);
  const stride = width * channels;
  const out = new Uint8Array(height * stride);
  for (let y = 0; y < height; y++) {
    const filter = raw[y * (stride + 1)];
    const line = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    const row = out.subarray(y * stride, (y + 1) * stride);
    const prev = y > 0 ? out.subarray((y - 1) * stride, y * stride) : new Uint8Array(stride);
    for (let i = 0; i < stride; i++) {
      const a = i >= channels ? row[i - channels] : 0;
      const b = prev[i];
      const c = i >= channels ? prev[i - channels] : 0;
      let p;
      switch (filter) {
        case 0: p = 0; break;
        case 1: p = a; break;
        case 2: p = b; break;
        case 3: p = (a + b) >> 1; break;
        case 4: {
          const pa = Math.abs(b - c);
          const pb = Math.abs(a - c);
          const pc = Math.abs(a + b - 2 * c);
          p = pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
          break;
        }
        default: throw new Error(`PNG: bad filter ${filter}`);
      }
      row[i] = (line[i] + p) & 255;
    }
  }
  return { width, height, channels, data: out };
}

/**
 * A decoded shadow.png: transmittance (0..1) at the span's start (`t0`, from R) and
 * end (`t1`, from G), 256×256 each, rows north first.
 */
export async function decodeShadow(buffer) {
  const png = await decodePng(buffer);
  const n = png.width * png.height;
  const t0 = new Float32Array(n);
  const t1 = new Float32Array(n);
  for (let i = 0; i < n; i++) {
    t0[i] = png.data[i * png.channels] / 255;
    t1[i] = png.channels >= 3 ? png.data[i * png.channels + 1] / 255 : t0[i];
  }
  return { width: png.width, height: png.height, t0, t1 };
}

/** A shadow map a fraction `f` of the way through its span: `(1 − f) R + f G` per texel. */
export function shadowAt(shadow, f) {
  const out = new Float32Array(shadow.t0.length);
  for (let i = 0; i < out.length; i++) out[i] = (1 - f) * shadow.t0[i] + f * shadow.t1[i];
  return out;
}

/**
 * A decoded coverage.png (RGB since ALGORITHM_VERSION 8): per column (rows north
 * first) `coverage` (largest density), `opacity` (vertical opacity) and `top` (a
 * fraction of the layer's thickness; 0 where there is no cloud), each 0..1.
 */
export async function decodeCoverage(buffer) {
  const png = await decodePng(buffer);
  const n = png.width * png.height;
  const ch = (k) => {
    const a = new Float32Array(n);
    for (let i = 0; i < n; i++) a[i] = png.data[i * png.channels + k] / 255;
    return a;
  };
  return { width: png.width, height: png.height, coverage: ch(0), opacity: ch(1), top: ch(2) };
}

/**
 * density.u8: `depth × 256 × 256` bytes, C order `(depth, rows, cols)`, row = y (row 0
 * the southern edge), col = x; density × 255. `depth` is the layer's (discovery).
 * Returns `{ shape, data }` with data the bytes (a Uint8Array view, ready for a
 * three.js Data3DTexture of RedFormat / UnsignedByteType: width = cols, height = rows,
 * depth = depth).
 */
export function decodeDensityU8(buffer, depth, side = 256) {
  const data = new Uint8Array(toArrayBuffer(buffer));
  if (data.length !== depth * side * side) throw new Error(`density.u8: ${data.length} bytes for (${depth}, ${side}, ${side})`);
  return { shape: [depth, side, side], data };
}

/** density.f32: the same grid as little-endian f32. */
export function decodeDensityF32(buffer, depth, side = 256) {
  const buf = toArrayBuffer(buffer);
  if (buf.byteLength !== 4 * depth * side * side) throw new Error(`density.f32: ${buf.byteLength} bytes for (${depth}, ${side}, ${side})`);
  return { shape: [depth, side, side], data: littleEndianF32(buf, 0, depth * side * side) };
}

function littleEndianF32(buf, offset, n) {
  const v = new DataView(buf, offset);
  const out = new Float32Array(n);
  for (let i = 0; i < n; i++) out[i] = v.getFloat32(4 * i, true);
  return out;
}

/** The identifier that opens a KTX 2.0 file. */
const KTX2_IDENTIFIER = [0xab, 0x4b, 0x54, 0x58, 0x20, 0x32, 0x30, 0xbb, 0x0d, 0x0a, 0x1a, 0x0a];

/**
 * density.ktx2: a KTX 2.0 texture without supercompression, as the server writes it
 * (`VK_FORMAT_R8_UNORM`, width = cols, height = rows, depth = the layer's depth):
 * `{ vkFormat, width, height, depth, data }`, data level 0 (the bytes of density.u8).
 * three.js's KTX2Loader reads the same file into a Data3DTexture.
 */
export function decodeKtx2(buffer) {
  const buf = toArrayBuffer(buffer);
  const bytes = new Uint8Array(buf);
  if (bytes.length < 104 || !KTX2_IDENTIFIER.every((b, i) => bytes[i] === b)) throw new Error('not a KTX 2.0 file');
  const v = new DataView(buf);
  const u32 = (o) => v.getUint32(o, true);
  const u64 = (o) => Number(v.getBigUint64(o, true));
  const [vkFormat, , width, height, depth, , faces, levels, scheme] = [0, 1, 2, 3, 4, 5, 6, 7, 8].map((i) => u32(12 + 4 * i));
  if (scheme !== 0) throw new Error(`KTX2: supercompression scheme ${scheme} is not decoded`);
  if (faces !== 1 || levels < 1) throw new Error(`KTX2: ${faces} faces, ${levels} levels`);
  const offset = u64(80);
  const length = u64(88);
  if (offset + length > bytes.length) throw new Error('KTX2: truncated');
  return { vkFormat, width, height, depth, data: bytes.slice(offset, offset + length) };
}

/** A NumPy .npy (format 1.x/2.x, C order, dtype `<f4` or `|u1`): `{ shape, dtype, data }`. */
export function decodeNpy(buffer) {
  const buf = toArrayBuffer(buffer);
  const bytes = new Uint8Array(buf);
  if (bytes[0] !== 0x93 || String.fromCharCode(...bytes.subarray(1, 6)) !== 'NUMPY') throw new Error('not a .npy');
  const major = bytes[6];
  const v = new DataView(buf);
  const headerLen = major >= 2 ? v.getUint32(8, true) : v.getUint16(8, true);
  const start = major >= 2 ? 12 : 10;
  const header = new TextDecoder().decode(bytes.subarray(start, start + headerLen));
  const descr = /'descr':\s*'([^']+)'/.exec(header)?.[1];
  const fortran = /'fortran_order':\s*(True|False)/.exec(header)?.[1];
  const shapeText = /'shape':\s*\(([^)]*)\)/.exec(header)?.[1];
  if (!descr || !shapeText || fortran !== 'False') throw new Error(`.npy: unsupported header ${header.trim()}`);
  const shape = shapeText.split(',').map((s) => s.trim()).filter(Boolean).map(Number);
  const n = shape.reduce((a, b) => a * b, 1);
  const offset = start + headerLen;
  let data;
  if (descr === '<f4') data = littleEndianF32(buf, offset, n);
  else if (descr === '|u1') data = bytes.slice(offset, offset + n);
  else throw new Error(`.npy: dtype ${descr} is not decoded`);
  if (data.length !== n) throw new Error('.npy: truncated');
  return { shape, dtype: descr, data };
}

/**
 * The density a client draws at a world point and time inside a keyframe span from
 * the two keyframes' grids (render::keyframe::blend_density_at):
 * `(1 − f) · D0(x − v (t − t0)) + f · D1(x + v (t1 − t))`, `d0`/`d1` reading a
 * keyframe's grid at a world point of the same height, `v` the wind there
 * (`layerVelocity`).
 */
export function blendDensityAt(d0, d1, x, velocity, t0, t1, t) {
  const f = fraction(t0, t1, t);
  const back = t - t0;
  const ahead = t1 - t;
  const a = d0(x[0] - velocity[0] * back, x[1] - velocity[1] * back);
  if (f === 0) return a;
  const b = d1(x[0] + velocity[0] * ahead, x[1] + velocity[1] * ahead);
  return (1 - f) * a + f * b;
}

/** The wind of a discovery layer at altitude `z`: `wind + shear · (z − base)` (m/s, x east, y north). */
export function layerVelocity(layer, z) {
  const h = z - layer.base;
  return [layer.wind[0] + layer.shear[0] * h, layer.wind[1] + layer.shear[1] * h];
}

/**
 * The tiles of level `z` of a layer that a square of `radius` metres around a point
 * (x, y) touches: `[{layer, z, x, y, origin, size}]`. A tile is 256 columns of
 * `cell_size · 2^z` metres; tile (z, 0, 0)'s south-west corner is the world origin.
 */
export function tilesAround(world, layerName, z, x, y, radius) {
  const layer = findLayer(world, layerName);
  const size = (world.tile_size || 256) * layer.cell_size * 2 ** z;
  const out = [];
  for (let ty = Math.floor((y - radius) / size); ty <= Math.floor((y + radius) / size); ty++) {
    for (let tx = Math.floor((x - radius) / size); tx <= Math.floor((x + radius) / size); tx++) {
      out.push({ layer: layerName, z, x: tx, y: ty, origin: [tx * size, ty * size], size });
    }
  }
  return out;
}
