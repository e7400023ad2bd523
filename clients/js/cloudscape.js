// cloudscape JS client: an ES module for browsers, Node (18+), Deno and bundlers.
//
// It fetches tiles from a cloudscape server with ETag revalidation and immutable
// caching (in memory, and in a browser's Cache Storage when given one), computes
// keyframe URLs from the world's discovery document and follows its world clock,
// holds billboard keyframes decoded and fetches each tile's later keyframes as deltas
// on the one before, decodes every binary product (billboards.bin versions 3, 2 and
// 1, PNG, density .u8/.f32/.npy/.ktx2), applies the keyframe animation rule, derives
// the ground shadow from the billboards, and builds typed arrays ready for three.js
// (y up). Types: index.d.ts. Formats and rules: docs/formats.md, and the doc comments
// of crates/cloudscape-core/src/products/keyframe_bin.rs, products/billboards.rs and
// view/held.rs, which this file matches.
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
// Fetching: ETags, immutable bodies, 503 retries; keyframes held decoded.
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
 * Decoded keyframes by tile variant (world, layer, tile, quality, sun) and start
 * time: what a client draws, and what the next keyframe's delta form is decoded
 * against (crates/cloudscape-client/src/keyframes.rs). At most `maxVariants`
 * variants (the least recently stored forgotten first), `perVariant` keyframes each
 * (the one drawn, the next one prefetched, one spare; the earliest go first).
 */
export class HeldKeyframes {
  constructor({ maxVariants = 1024, perVariant = 3 } = {}) {
    this.maxVariants = maxVariants;
    this.perVariant = perVariant;
    /** @type {Map<string, {t0: number, keyframe: object}[]>} */
    this.byVariant = new Map();
  }

  /** The keyframe of `variant` that starts at `t0`, if held. */
  get(variant, t0) {
    const held = this.byVariant.get(variant);
    const k = held && held.find((h) => h.t0 === t0);
    return k ? k.keyframe : null;
  }

  /** The keyframe of `variant` that ends at `t0` (the one a delta starting at `t0` is coded on), if held. */
  endingAt(variant, t0) {
    const held = this.byVariant.get(variant) || [];
    const k = held.find((h) => h.keyframe.header.t1 !== null && Math.abs(h.keyframe.header.t1 - t0) <= 1e-9 * Math.max(Math.abs(t0), 1));
    return k ? k.keyframe : null;
  }

  /** Holds `keyframe` of `variant` starting at `t0`. */
  insert(variant, t0, keyframe) {
    let held = this.byVariant.get(variant);
    if (!held) {
      if (this.byVariant.size >= this.maxVariants) this.byVariant.delete(this.byVariant.keys().next().value);
      held = [];
      this.byVariant.set(variant, held);
    }
    const i = held.findIndex((h) => h.t0 === t0);
    if (i >= 0) held.splice(i, 1);
    held.push({ t0, keyframe });
    held.sort((a, b) => a.t0 - b.t0);
    while (held.length > this.perVariant) held.shift();
  }

  /** Keyframes held, over all variants. */
  get size() {
    let n = 0;
    for (const h of this.byVariant.values()) n += h.length;
    return n;
  }
}

/**
 * A client of one cloudscape server.
 *
 * Bodies are kept by URL (at most `maxBodies`, oldest forgotten first), and in a
 * Cache Storage `cache` when one is given (a browser's `caches.open(…)`; kept across
 * reloads). An immutable one (`Cache-Control: immutable`, as keyframe URLs are) is
 * returned again without a request; any other is revalidated with `If-None-Match`,
 * and a 304 returns the kept body. A 503 is retried after its `Retry-After`, a
 * connection that failed after a short wait.
 *
 * Billboard keyframes are held decoded (`keyframes`, a HeldKeyframes): a tile's first
 * keyframe is fetched self-contained (`billboards.bin`), every later one as a delta
 * on the one before (`billboards.delta.bin`), as docs/formats.md says a client does.
 */
export class CloudscapeClient {
  /**
   * @param {string} baseUrl the server's origin: scheme, host and port (a trailing `/` is ignored; '' for the page's own origin)
   * @param {{fetch?: typeof fetch, maxBodies?: number, maxRetries?: number, quality?: string, cache?: Cache | Promise<Cache | null> | null, maxVariants?: number, keyframesPerVariant?: number}} [options]
   */
  constructor(baseUrl, options = {}) {
    this.base = String(baseUrl || '').replace(/\/+$/, '');
    this.fetchImpl = options.fetch || globalThis.fetch.bind(globalThis);
    this.maxBodies = options.maxBodies ?? 1024;
    this.maxRetries = options.maxRetries ?? 8;
    this.quality = options.quality || 'fast';
    this.cache = Promise.resolve(options.cache || null).catch(() => null);
    /** @type {Map<string, {body: ArrayBuffer, etag: string | null, immutable: boolean}>} */
    this.bodies = new Map();
    this.worlds = new Map();
    this.keyframes = new HeldKeyframes({ maxVariants: options.maxVariants, perVariant: options.keyframesPerVariant });
    /** Keyframes being fetched, by variant and t0: one request for concurrent asks. */
    this.pending = new Map();
    this.stats = { requests: 0, fetched: 0, revalidated: 0, reused: 0, bodyBytes: 0, retries: 0, deltas: 0, prefetched: 0 };
  }

  /** The absolute URL of a path. */
  url(path) {
    return /^https?:/.test(path) ? path : `${this.base}${path}`;
  }

  /** Keeps an immutable or ETagged body in memory. */
  keep(url, entry) {
    this.bodies.delete(url);
    this.bodies.set(url, entry);
    while (this.bodies.size > this.maxBodies) this.bodies.delete(this.bodies.keys().next().value);
  }

  /**
   * GETs a path (or URL) and returns `{ body, status, etag, immutable, source }`;
   * `source` is `network` (a 200), `revalidated` (a 304), `memory` (an immutable body
   * kept, no request made) or `cache` (an immutable body from the Cache Storage).
   * `keep: false` does not keep the body in memory (what is held decoded instead);
   * `fresh: true` neither uses nor keeps a stored copy (a document that changes
   * under a weak ETag, such as discovery's clock).
   */
  async fetch(path, { keep = true, fresh = false } = {}) {
    const url = this.url(path);
    const kept = fresh ? undefined : this.bodies.get(url);
    if (kept && kept.immutable) {
      this.stats.reused++;
      this.keep(url, kept);
      return { body: kept.body, status: 200, etag: kept.etag, immutable: true, source: 'memory' };
    }
    const cache = fresh ? null : await this.cache;
    let stored = kept || null;
    if (!stored && cache) {
      const res = await cache.match(url).catch(() => undefined);
      if (res) stored = { body: await res.arrayBuffer(), etag: res.headers.get('ETag'), immutable: isImmutable(res.headers.get('Cache-Control')) };
      if (stored && stored.immutable) {
        this.stats.reused++;
        if (keep) this.keep(url, stored);
        return { body: stored.body, status: 200, etag: stored.etag, immutable: true, source: 'cache' };
      }
    }
    const headers = stored && stored.etag ? { 'If-None-Match': stored.etag } : {};
    for (let attempt = 0; ; attempt++) {
      this.stats.requests++;
      let res;
      try {
        res = await this.fetchImpl(url, { headers, cache: 'no-store' });
      } catch (e) {
        // A connection that failed (one the server had closed as it was reused): a GET
        // is asked again, as often as a 503 is.
        if (attempt >= this.maxRetries) throw e;
        this.stats.retries++;
        await sleep(100 * 2 ** Math.min(attempt, 4));
        continue;
      }
      if (res.status === 304 && stored) {
        this.stats.revalidated++;
        return { body: stored.body, status: 304, etag: stored.etag, immutable: stored.immutable, source: 'revalidated' };
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
      const cacheControl = res.headers.get('Cache-Control');
      const immutable = isImmutable(cacheControl);
      this.stats.fetched++;
      this.stats.bodyBytes += body.byteLength;
      if (keep && !fresh && (etag || immutable)) this.keep(url, { body, etag, immutable });
      if (cache && etag) {
        const h = { ETag: etag, 'Cache-Control': cacheControl || '', 'Content-Type': res.headers.get('Content-Type') || 'application/octet-stream' };
        // A full or refusing Cache Storage costs the next visit a request, nothing more.
        await cache.put(url, new Response(body.slice(0), { headers: h })).catch(() => {});
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

  /** Whether an immutable body of a path is kept in memory (no request would be made). */
  holds(path) {
    const kept = this.bodies.get(this.url(path));
    return Boolean(kept && kept.immutable);
  }

  /** The world list (`/v1/worlds`). */
  async worldList() {
    return this.json('/v1/worlds');
  }

  /**
   * A world's discovery document (`/v1/worlds/{world}`), fetched once per client. Its
   * `clock` (`offset`, `rate`, `now`) is as the server read it then; `worldClock`
   * follows it.
   */
  async world(name = 'default') {
    if (!this.worlds.has(name)) {
      const path = `/v1/worlds/${encodeURIComponent(name)}`;
      const doc = JSON.parse(new TextDecoder().decode((await this.fetch(path, { fresh: true })).body));
      discoveryReadAt.set(doc, Date.now());
      this.worlds.set(name, doc);
    }
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
   * What names a tile variant's keyframes: world, layer, tile, quality and sun (the
   * server's clock sun when `at.sun` is not given).
   */
  variant(world, tile, at) {
    const sun = at.sun ? `${at.sun[0]},${at.sun[1]}` : 'clock';
    return `${world.name}|${tile.layer}|${tile.z}/${tile.x}/${tile.y}|${at.quality || this.quality}|${sun}`;
  }

  /**
   * A tile's billboards (decoded billboards.bin) at the keyframe that holds `at.t`
   * (the next one with `at.next`): held already, or fetched as a delta
   * (`billboards.delta.bin`) on the keyframe before it when that is held (or on its
   * way: it is waited for), else self-contained (`billboards.bin`). The result is held
   * for the next delta.
   */
  async keyframe(world, tile, at) {
    const layer = findLayer(world, tile.layer);
    const k = keyframeOf(layer, tile.z, at.t, world.max_time);
    const t0 = at.next ? k.t1 : k.t0;
    const variant = this.variant(world, tile, at);
    const held = this.keyframes.get(variant, t0);
    if (held) {
      this.stats.reused++;
      return held;
    }
    const key = `${variant}@${t0}`;
    if (!this.pending.has(key)) {
      // The keyframe before, if it is on its way, is waited for: this one is then a delta on it.
      const before = this.pending.get(`${variant}@${at.next ? k.t0 : k.t0 - k.span}`);
      const job = (async () => {
        if (before) await before.catch(() => null);
        const previous = this.keyframes.endingAt(variant, t0);
        const product = previous ? 'billboards.delta.bin' : 'billboards.bin';
        const path = this.tilePath(world, tile, product, at);
        const { body, source } = await this.fetch(path, { keep: false });
        if (previous && source === 'network') this.stats.deltas++;
        let decoded;
        try {
          decoded = decodeBillboards(body, previous);
        } catch (e) {
          throw new Error(`${this.url(path)}: ${e.message}`);
        }
        this.keyframes.insert(variant, t0, decoded);
        return decoded;
      })();
      this.pending.set(key, job);
      job.then(
        () => this.pending.delete(key),
        () => this.pending.delete(key),
      );
    }
    return this.pending.get(key);
  }

  /**
   * A tile's billboards at the keyframe that holds `at.t` (`keyframe`): `{ billboards }`.
   * Past the tile's prefetch point (`prefetchAt`, in the second half of the span) the
   * next keyframe is fetched in the background (`prefetch: false` turns that off), so
   * the boundary costs no wait. The ground shadow is derived from the billboards of
   * the held tiles (`shadowMaps`), not fetched.
   */
  async billboardTile(world, tile, at) {
    const billboards = await this.keyframe(world, tile, at);
    if (at.prefetch !== false) this.prefetchNext(world, tile, at);
    return { billboards };
  }

  /**
   * Fetches the next keyframe of a tile when `at.t` is past the tile's prefetch point in
   * its span (`prefetchAt`, between 0.5 and 0.8): `billboards.bin` in `products` stands
   * for its billboards, held decoded (a delta on the current keyframe when that is
   * held); any other product's body is kept. Resolves to the paths fetched (none
   * before the point, or when all are held). Errors are swallowed: the tile is asked
   * for again when its keyframe comes.
   */
  async prefetchNext(world, tile, at, products = ['billboards.bin']) {
    const k = keyframeOf(findLayer(world, tile.layer), tile.z, at.t, world.max_time);
    if (!(k.span > 0 && k.f >= prefetchAt(tile.z, tile.x, tile.y))) return [];
    const next = { ...at, next: true };
    const variant = this.variant(world, tile, at);
    const jobs = [];
    const paths = [];
    for (const p of products) {
      if (p === 'billboards.bin') {
        if (this.keyframes.get(variant, k.t1) || this.pending.has(`${variant}@${k.t1}`)) continue;
        const delta = this.keyframes.endingAt(variant, k.t1) !== null || this.pending.has(`${variant}@${k.t0}`);
        paths.push(this.tilePath(world, tile, delta ? 'billboards.delta.bin' : 'billboards.bin', next));
        this.stats.prefetched++;
        jobs.push(this.keyframe(world, tile, next));
      } else {
        const path = this.tilePath(world, tile, p, next);
        if (this.holds(path)) continue;
        paths.push(path);
        this.stats.prefetched++;
        jobs.push(this.fetch(path));
      }
    }
    await Promise.all(jobs.map((j) => j.catch(() => null)));
    return paths;
  }
}

/** When each discovery document was read (wall-clock ms), for worldClock. */
const discoveryReadAt = new WeakMap();

/**
 * The world time of a discovery document's clock (`clock: {offset, rate, now}`),
 * followed from when the document was read (by `CloudscapeClient.world`; else from now): `now + rate · (seconds since)`, as every
 * player's client reads the shared world clock. `rate` overrides the clock's (a
 * faster clock for a test or a time-lapse); the result is within [0, max_time].
 * Returns a function of the wall-clock milliseconds (`Date.now()` by default).
 */
export function worldClock(world, { rate = null, readAt = discoveryReadAt.get(world) ?? Date.now() } = {}) {
  const clock = world.clock || { offset: 0, rate: 1, now: readAt / 1000 };
  const r = rate ?? clock.rate;
  const max = world.max_time ?? 1e12;
  return (ms = Date.now()) => Math.min(Math.max(clock.now + (r * (ms - readAt)) / 1000, 0), max);
}

function findLayer(world, name) {
  const layer = world.layers.find((l) => l.name === name);
  if (!layer) throw new Error(`world ${world.name} has no layer ${name}`);
  return layer;
}
// ---------------------------------------------------------------------------------
// billboards.bin: version 3 (crates/cloudscape-core/src/products/keyframe_bin.rs),
// versions 1 and 2 (crates/cloudscape-core/src/products/billboards.rs).
// ---------------------------------------------------------------------------------

/** Header and record bytes of the record formats, by version (version 3 has no records: see decodeBillboards). */
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

/** Version 3's fixed header, level records and planes (keyframe_bin.rs). */
const V3 = {
  fixed: 200,
  level: 88,
  planes: 12,
  /** Bounds a decoder holds a header to before it allocates anything. */
  maxLevels: 256,
  maxSide: 4096,
  maxSites: 1 << 23,
  /** Largest |i64| of a level's indices (beyond it a lattice cannot lie in a tile). */
  far: 2n ** 52n,
};
/** Planes of one end: splat (low, high bytes), green, red, blue, τ_sun; the end's six follow the start's. */
const PLANE_SPLAT = 0;
const PLANE_GREEN = 2;
const PLANE_END = 6;
/** A site's state: 5 values at `5 · site`: splat code (0 none, else index + 1), green, red, blue codes, τ_sun code. */
const STATE = 5;

/**
 * Decodes billboards.bin: version 3 (the current `billboards.bin` and
 * `billboards.delta.bin`; a delta needs `previous`, the decoded keyframe of the same
 * tile variant that ends where this one starts), version 2 (`billboards.v2.bin`: a
 * keyframe with both ends of each record) or version 1 (one time). Records come as
 * columns of typed arrays; index `2i` / `2i + 1` of a two-ended column is billboard
 * i's end at t0 / t1 (a version-1 tile has the same value at both ends and a zero
 * velocity). Offsets are metres from the tile origin (x east, y north), altitude
 * absolute. A version-3 tile also carries `lattice`, what its successor's delta is
 * decoded against.
 *
 * Bytes that are not a well-formed keyframe (truncated, damaged, a delta without its
 * previous keyframe or with another) throw an `Error` that says what is wrong; sizes
 * are checked before anything is allocated.
 */
export function decodeBillboards(buffer, previous = null) {
  const bytes = byteView(buffer);
  const v = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (bytes.length < 64) throw new Error(`billboards.bin: ${bytes.length} bytes, shorter than a header`);
  const magic = String.fromCharCode(v.getUint8(0), v.getUint8(1), v.getUint8(2), v.getUint8(3));
  if (magic !== 'CSBB') throw new Error('billboards.bin: bad magic');
  const version = v.getUint16(4, true);
  if (version === 3) return decodeKeyframe(bytes, v, previous);
  const format = BILLBOARD_FORMATS[version];
  if (!format) throw new Error(`billboards.bin: unknown version ${version}`);
  if (v.getUint16(6, true) !== format.record) throw new Error(`billboards.bin: record size ${v.getUint16(6, true)} for version ${version}`);
  const count = v.getUint32(8, true);
  if (bytes.length !== format.header + count * format.record) {
    throw new Error(`billboards.bin: ${bytes.length} bytes for ${count} records`);
  }
  const f32 = (o) => v.getFloat32(o, true);
  const header = commonHeader(v, version, count);
  if (version >= 2) Object.assign(header, keyframeHeader(v));
  const r = recordColumns(count);
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
  return { header, count, records: r, lattice: null };
}

/** Offsets 0–63, the same in every version. */
function commonHeader(v, version, count) {
  const f32 = (o) => v.getFloat32(o, true);
  return {
    version,
    form: version === 3 ? 'self-contained' : null,
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
}

/** Offsets 64–155 of versions 2 and 3: the span and the lighting. */
function keyframeHeader(v) {
  const f32 = (o) => v.getFloat32(o, true);
  const vec3 = (o) => [f32(o), f32(o + 4), f32(o + 8)];
  return {
    t0: v.getFloat64(64, true),
    t1: v.getFloat64(72, true),
    lighting: {
      sunDirection: vec3(80),
      sunRgb: vec3(92),
      ambientRgb: vec3(104),
      albedo: f32(116),
      extinctionPerM: f32(120),
      phase: { g1: f32(124), g2: f32(128), mix: f32(132) },
      octaves: { count: v.getUint32(136, true), a: f32(140), b: f32(144), c: f32(148) },
    },
    algorithmVersion: v.getUint32(152, true),
  };
}

function recordColumns(count) {
  return {
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
}

/** First column and width of a level's box: from the smaller first column of its two row kinds to the larger end. */
function boxColumns(level) {
  const live = level.runs.filter((r) => r[1] > 0);
  if (!live.length) return [0, 0];
  const first = Math.min(...live.map((r) => r[0]));
  const end = Math.max(...live.map((r) => r[0] + r[1]));
  return [first, Math.max(end - first, 0)];
}

/** Whether site (i, j) of level `k` lies in the tile (its row's run). */
function levelContains(level, k, i, j) {
  if (j < level.j0 || j >= level.j0 + level.rows) return false;
  const [first, n] = level.runs[(((j + k) % 2) + 2) % 2];
  return i >= first && i < first + n;
}

/** LOCO-I's median edge detector (JPEG-LS): left `a`, up `b`, up-left `c`, each -1 when missing at the box's edge. */
function med(a, b, c) {
  const a2 = a >= 0 ? a : b >= 0 ? b : 0;
  const b2 = b >= 0 ? b : a2;
  const c2 = c >= 0 ? c : a2;
  const lo = Math.min(a2, b2);
  const hi = Math.max(a2, b2);
  if (c2 >= hi) return lo;
  if (c2 <= lo) return hi;
  return a2 + b2 - c2;
}

/**
 * The linear colour of colour code value q in [0, 1] for a header's ALGORITHM_VERSION
 * (products::keyframe_bin::ColourCurve): since version 13 steps of the displayed value
 * at exposure 3, (1 − e^(−3c))^(1/2.2), the top code standing for 2; before, steps of
 * (c / 2)^(1/2.2).
 */
export function colourOfCode(q, algorithmVersion) {
  if (!(algorithmVersion >= 13)) return 2 * q ** 2.2;
  if (q >= 1) return 2;
  return Math.min(-Math.log(1 - q ** 2.2) / 3, 2);
}

/**
 * The first ALGORITHM_VERSION whose colour codes carry a billboard's ambient part (sky
 * and ground light), the decoder adding the sun term of the dequantised τ_sun back
 * (products::keyframe_bin::AMBIENT_CODES_SINCE).
 */
export const AMBIENT_CODES_SINCE = 15;

/** Dequantised colour channel and τ_sun of each code (256 codes; values are one byte). */
function codeTables(colourBits, tauSunSteps, tauFloor, algorithmVersion) {
  const levels = 2 ** colourBits - 1;
  const colour = new Float32Array(256);
  const tauSun = new Float32Array(256);
  for (let c = 0; c < 256; c++) {
    colour[c] = colourOfCode(Math.min(c, levels) / levels, algorithmVersion);
    tauSun[c] = tauFloor * Math.exp((Math.min(Math.max(c, 1), 255) - 1) / tauSunSteps);
  }
  return { colour, tauSun };
}

/** Peak opacity (or transmittance) × 255 rounded, as the server stores it (render::image::to_u8), back to 0..1. */
const byteFraction = (x) => (Number.isNaN(x) ? 0 : Math.round(Math.fround(Math.min(Math.max(x, 0), 1) * 255)) / 255);

/**
 * The residual planes of a version-3 keyframe, each read from its own cursor: one
 * traversal of the sites asks them in the order the encoder wrote them.
 */
class PlaneReader {
  constructor(bytes, at, lengths) {
    this.bytes = bytes;
    this.lengths = lengths;
    this.starts = [];
    for (const len of lengths) {
      this.starts.push(at);
      at += len;
    }
    this.used = new Array(lengths.length).fill(0);
  }

  /** The next byte of plane `p`; an Error when the plane is spent. */
  take(p) {
    if (this.used[p] >= this.lengths[p]) throw new Error(`billboards.bin: plane ${p} ends early (truncated or malformed)`);
    return this.bytes[this.starts[p] + this.used[p]++];
  }

  /**
   * The value at the next site of `plane`, predicted `pred`: pred + residual, modulo
   * 2^8 (2^16 for a wide splat code, whose high byte is in the next plane).
   */
  code(plane, pred, wide) {
    const lo = this.take(plane);
    return wide ? (pred + (lo | (this.take(plane + 1) << 8))) & 0xffff : (pred + lo) & 0xff;
  }
}

/** The median prediction of field `f` of a site from the states at its left, up and up-left box positions (-1: none). */
function spatial(states, left, up, upleft, f) {
  return med(left >= 0 ? states[left + f] : -1, up >= 0 ? states[up + f] : -1, upleft >= 0 ? states[upleft + f] : -1);
}

function decodeKeyframe(bytes, v, previous) {
  if (bytes.length < V3.fixed) throw new Error(`billboards.bin: ${bytes.length} bytes, shorter than a version-3 header (${V3.fixed})`);
  const formCode = v.getUint16(6, true);
  if (formCode > 1) throw new Error(`billboards.bin: unknown form ${formCode}`);
  const nLevels = v.getUint16(190, true);
  const planes = v.getUint16(196, true);
  if (nLevels > V3.maxLevels || planes !== V3.planes) {
    throw new Error(`billboards.bin: ${nLevels} levels and ${planes} planes (at most ${V3.maxLevels} levels, ${V3.planes} planes)`);
  }
  const headerBytes = V3.fixed + V3.level * nLevels + 4 * V3.planes;
  if (v.getUint32(8, true) !== headerBytes) throw new Error(`billboards.bin: the header says ${v.getUint32(8, true)} bytes, its tables ${headerBytes}`);
  if (bytes.length < headerBytes) throw new Error(`billboards.bin: ${bytes.length} bytes, shorter than its header (${headerBytes}; truncated)`);
  const index = (o) => {
    const x = v.getBigInt64(o, true);
    return x > V3.far || x < -V3.far ? null : Number(x);
  };
  const levels = [];
  let sites = 0;
  let inside = 0;
  for (let k = 0; k < nLevels; k++) {
    const o = V3.fixed + k * V3.level;
    const l = {
      offset: [v.getFloat64(o, true), v.getFloat64(o + 8, true)],
      velocity: [v.getFloat64(o + 16, true), v.getFloat64(o + 24, true)],
      shift: [index(o + 32), index(o + 40)],
      j0: index(o + 48),
      rows: v.getUint32(o + 56, true),
      runs: [
        [index(o + 60), v.getUint32(o + 68, true)],
        [index(o + 72), v.getUint32(o + 80, true)],
      ],
    };
    if (
      l.rows > V3.maxSide ||
      l.runs.some((r) => r[1] > V3.maxSide || r[0] === null) ||
      l.j0 === null ||
      l.shift.some((s) => s === null)
    ) {
      throw new Error(`billboards.bin: level ${k} has an impossible extent`);
    }
    [l.first, l.width] = boxColumns(l);
    sites += l.rows * l.width;
    if (sites > V3.maxSites) throw new Error(`billboards.bin: more than ${V3.maxSites} sites`);
    // Rows of each kind alternate from j0.
    const kind0 = (((l.j0 + k) % 2) + 2) % 2;
    const rowsOf = (kind) => (kind === kind0 ? Math.ceil(l.rows / 2) : Math.floor(l.rows / 2));
    inside += rowsOf(0) * l.runs[0][1] + rowsOf(1) * l.runs[1][1];
    levels.push(l);
  }
  const lengths = [];
  let body = 0;
  for (let p = 0; p < V3.planes; p++) {
    lengths.push(v.getUint32(V3.fixed + nLevels * V3.level + 4 * p, true));
    body += lengths[p];
  }
  if (bytes.length !== headerBytes + body) throw new Error(`billboards.bin: ${bytes.length} bytes, its header says ${headerBytes + body}`);
  // Every site in the tile has an end splat code: the plane's length is known before
  // the arrays are made (the traversal would find the same).
  if (lengths[PLANE_END + PLANE_SPLAT] !== inside) {
    throw new Error(`billboards.bin: plane ${PLANE_END + PLANE_SPLAT} holds ${lengths[PLANE_END + PLANE_SPLAT]} bytes for ${inside} sites`);
  }
  const colourBits = v.getUint8(188);
  const tauSunSteps = v.getUint8(189);
  if (!(colourBits >= 1 && colourBits <= 8) || tauSunSteps === 0) throw new Error('billboards.bin: impossible quantisation');
  const header = Object.assign(commonHeader(v, 3, v.getUint32(156, true)), keyframeHeader(v));
  header.form = formCode === 0 ? 'self-contained' : 'delta';
  const geometry = {
    spacing: v.getFloat64(160, true),
    verticalSpacing: v.getFloat64(168, true),
    base: v.getFloat64(176, true),
    radius: v.getFloat32(184, true),
    levels,
  };
  const quantisation = { colourBits, tauSunSteps, tauFloor: v.getFloat32(192, true) };
  const { z, x, y } = header.tile;

  // A delta's sites held from the previous keyframe: its end states.
  let prev = null;
  if (formCode === 1) {
    if (!previous) throw new Error(`billboards.bin: a delta keyframe (tile ${z}/${x}/${y}, t0 = ${header.t0}) needs the previous keyframe of its tile`);
    const p = previous.header || {};
    const pl = previous.lattice;
    const same =
      Boolean(pl && pl.geometry && pl.quantisation && pl.end && p.tile && p.sun) &&
      p.tile.z === z &&
      p.tile.x === x &&
      p.tile.y === y &&
      typeof p.t1 === 'number' &&
      Math.abs(p.t1 - header.t0) <= 1e-9 * Math.max(Math.abs(header.t0), 1) &&
      p.splatCount === header.splatCount &&
      p.sun.azimuthDeg === header.sun.azimuthDeg &&
      p.sun.elevationDeg === header.sun.elevationDeg &&
      pl.quantisation.colourBits === colourBits &&
      pl.quantisation.tauSunSteps === tauSunSteps &&
      pl.geometry.levels.length === nLevels;
    if (!same) {
      const tile = p.tile ? `${p.tile.z}/${p.tile.x}/${p.tile.y}` : '?';
      throw new Error(`billboards.bin: this delta follows keyframe t1 = ${header.t0} of tile ${z}/${x}/${y}, not the keyframe given (t1 = ${p.t1}, tile ${tile})`);
    }
    prev = pl;
  }

  const start = new Uint16Array(STATE * sites);
  const end = new Uint16Array(STATE * sites);
  const reader = new PlaneReader(bytes, headerBytes, lengths);
  const wide = header.splatCount > 255;
  const prevEnd = prev ? prev.end : null;
  const bases = [];
  let level = 0;
  for (let k = 0; k < nLevels; k++) {
    const l = levels[k];
    bases.push(level);
    const w = l.width;
    const pl = prev ? prev.geometry.levels[k] : null;
    for (let r = 0; r < l.rows; r++) {
      const j = l.j0 + r;
      const [runFirst, runCount] = l.runs[(((j + k) % 2) + 2) % 2];
      for (let c = 0; c < w; c++) {
        const s = level + r * w + c;
        const i = l.first + c;
        const o = STATE * s;
        const left = c > 0 ? o - STATE : -1;
        const up = r > 0 ? o - STATE * w : -1;
        const upleft = c > 0 && r > 0 ? o - STATE * (w + 1) : -1;
        const isInside = i >= runFirst && i < runFirst + runCount;
        // The predecessor of a site the client holds: the previous keyframe's site
        // (i, j) − shift(k) inside its runs; its end state is this site's start.
        let kept = -1;
        if (isInside && pl) {
          const pi = i - pl.shift[0];
          const pj = j - pl.shift[1];
          if (levelContains(pl, k, pi, pj)) kept = STATE * (prev.bases[k] + (pj - pl.j0) * pl.width + (pi - pl.first));
        }
        // The start: held, or in space.
        let pred = spatial(start, left, up, upleft, 0);
        const splat = !isInside ? 0 : kept >= 0 ? prevEnd[kept] : reader.code(PLANE_SPLAT, pred, wide);
        start[o] = splat;
        let drift = 0;
        for (let f = 1; f < STATE; f++) {
          pred = spatial(start, left, up, upleft, f);
          let value;
          if (splat === 0) value = pred;
          else if (kept >= 0) value = prevEnd[kept + f];
          else value = reader.code(PLANE_GREEN + f - 1, f === 2 || f === 3 ? pred + drift : pred, false);
          if (f === 1) drift = value - pred;
          start[o + f] = value;
        }
        // The end, from the start of the same site.
        const was = start[o];
        const esplat = isInside ? reader.code(PLANE_END + PLANE_SPLAT, was, wide) : 0;
        end[o] = esplat;
        drift = 0;
        for (let f = 1; f < STATE; f++) {
          pred = was !== 0 ? start[o + f] : spatial(end, left, up, upleft, f);
          const value = esplat === 0 ? pred : reader.code(PLANE_END + PLANE_GREEN + f - 1, f === 2 || f === 3 ? pred + drift : pred, false);
          if (f === 1) drift = value - pred;
          end[o + f] = value;
        }
      }
    }
    level += l.rows * w;
  }
  const used = reader.used;
  for (let p = 0; p < V3.planes; p++) {
    if (used[p] !== lengths[p]) throw new Error(`billboards.bin: plane ${p} holds ${lengths[p]} bytes, the keyframe uses ${used[p]}`);
  }

  // The billboards: every site with a ball at either end, in site order.
  let count = 0;
  for (let s = 0; s < sites; s++) if (start[STATE * s] !== 0 || end[STATE * s] !== 0) count++;
  if (count !== header.count) throw new Error(`billboards.bin: ${count} billboards decoded, the header says ${header.count}`);
  const rec = recordColumns(count);
  const tables = codeTables(colourBits, tauSunSteps, quantisation.tauFloor, header.algorithmVersion);
  // Since AMBIENT_CODES_SINCE the colour codes leave out the sun term: one per τ_sun code, computed once.
  const sunOf = header.algorithmVersion >= AMBIENT_CODES_SINCE ? sunTerm(header.lighting) : null;
  const sunOfCode = sunOf ? Array.from(tables.tauSun, (tau) => sunOf(tau)) : null;
  const origin = header.origin;
  const splatCount = header.splatCount;
  let n = 0;
  for (let k = 0; k < nLevels; k++) {
    const l = levels[k];
    const oy = 0.5 * (k % 2);
    const zc = Math.fround(geometry.base + (k + 0.5) * geometry.verticalSpacing);
    for (let r = 0; r < l.rows; r++) {
      const j = l.j0 + r;
      const ox = 0.5 * ((((j + k) % 2) + 2) % 2);
      for (let c = 0; c < l.width; c++) {
        const s = STATE * (bases[k] + r * l.width + c);
        if (start[s] === 0 && end[s] === 0) continue;
        rec.offset[3 * n] = (l.first + c + ox) * geometry.spacing + l.offset[0] - origin[0];
        rec.offset[3 * n + 1] = (j + oy) * geometry.spacing + l.offset[1] - origin[1];
        rec.offset[3 * n + 2] = zc;
        rec.radius[n] = geometry.radius;
        rec.velocity[2 * n] = l.velocity[0];
        rec.velocity[2 * n + 1] = l.velocity[1];
        for (let e = 0; e < 2; e++) {
          const [self, other] = e === 0 ? [start, end] : [end, start];
          // An end without a ball draws nothing and keeps the other end's light.
          const light = self[s] !== 0 ? self : other;
          const m = 2 * n + e;
          if (self[s] !== 0) {
            const splat = Math.min(self[s] - 1, Math.max(splatCount - 1, 0));
            rec.splat[m] = splat;
            rec.splatTau[m] = splatTauOf(splat, splatCount);
          }
          rec.opacity[m] = byteFraction(Math.fround(1 - Math.fround(Math.exp(-rec.splatTau[m]))));
          rec.tauSun[m] = tables.tauSun[light[s + 4]];
          const rgb = [tables.colour[light[s + 2]], tables.colour[light[s + 1]], tables.colour[light[s + 3]]];
          // Since AMBIENT_CODES_SINCE the codes are the ambient part: add the sun term back.
          const sun = sunOfCode ? sunOfCode[light[s + 4]] : null;
          for (let c = 0; c < 3; c++) rec.colour[6 * n + 3 * e + c] = sun ? Math.min(rgb[c] + sun[c], 2) : rgb[c];
          rec.sunTransmittance[m] = byteFraction(Math.fround(Math.exp(-rec.tauSun[m])));
        }
        n++;
      }
    }
  }
  return { header, count, records: rec, lattice: { geometry, quantisation, bases, end, shadowWidening: Math.fround(v.getUint16(198, true) / 1000) } };
}

/** Largest centre optical depth of the splat sheet (src/render/splats.rs TAU_MAX; /v1/splats.json `tau_max`). */
export const SPLAT_TAU_MAX = 8;

/** Centre optical depth τ_k of splat `k` of a sheet of `count`: `tau_max · ((k + 1) / count)²`. */
export function splatTauOf(k, count, tauMax = SPLAT_TAU_MAX) {
  const x = (Math.min(k, Math.max(count - 1, 0)) + 1) / Math.max(count, 1);
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
// Ground shadows derived from the billboards (crates/cloudscape-core/src/view/held.rs).
// ---------------------------------------------------------------------------------

/** Columns per tile side: the side of a shadow map. */
export const TILE_COLUMNS = 256;
/** Entries of the splat profile table over q = p² (render::shade PROFILE_ENTRIES). */
const PROFILE_ENTRIES = 4096;

/**
 * S(p), the line integral of Wyvill's field function through a unit ball at impact
 * parameter p (render::splats::line_integral); 0 for |p| ≥ 1.
 */
export function lineIntegral(p) {
  if (!(Math.abs(p) < 1)) return 0;
  const q = p * p;
  const l = Math.sqrt(1 - q);
  const l2 = l * l;
  const l3 = l * l * l;
  const l5 = l3 * l2;
  const l7 = l3 * l2 * l2;
  const a3 = 2 * (q * q * q * l + q * q * l3 + (3 * q * l5) / 5 + l7 / 7);
  const a2 = 2 * (q * q * l + (2 * q * l3) / 3 + l5 / 5);
  const a1 = 2 * (q * l + l3 / 3);
  return Math.max((-4 / 9) * a3 + (17 / 9) * a2 - (22 / 9) * a1 + 2 * l, 0);
}

let profileTable = null;
/** S(√q) / S(0) tabulated over q (linear between entries), as render::shade::profile_table. */
function profile() {
  if (!profileTable) {
    const s0 = 2 * (1 - 22 / 27 + 17 / 45 - 4 / 63);
    profileTable = new Float64Array(PROFILE_ENTRIES + 1);
    for (let i = 0; i <= PROFILE_ENTRIES; i++) profileTable[i] = lineIntegral(Math.sqrt(i / PROFILE_ENTRIES)) / s0;
  }
  return profileTable;
}

/** P(q) = S(√q) / S(0), q the squared distance from a ball's centre in radii (render::shade::profile_at). */
export function splatProfile(q) {
  const table = profile();
  const x = Math.min(Math.max(q, 0), 1) * PROFILE_ENTRIES;
  const i = Math.min(Math.floor(x), PROFILE_ENTRIES - 1);
  const f = x - i;
  return table[i] * (1 - f) + table[i + 1] * f;
}

/**
 * The unit vector toward a keyframe's sun (its header's bucket centre), as
 * render::sun::Sun: azimuth clockwise from north, elevation above the horizon; an
 * elevation outside [−90, 90] stands for the zenith.
 */
export function keyframeSun(tile) {
  const s = tile.header.sun;
  let az = s.azimuthDeg;
  let el = s.elevationDeg;
  if (!(Number.isFinite(az) && Number.isFinite(el) && el >= -90 && el <= 90)) {
    az = 0;
    el = 90;
  }
  az = ((az % 360) + 360) % 360;
  if (az >= 360) az = 0;
  const a = az * (Math.PI / 180);
  const e = el * (Math.PI / 180);
  return [Math.sin(a) * Math.cos(e), Math.cos(a) * Math.cos(e), Math.sin(e)];
}

/**
 * How far to shift a ground point (x, y) toward the sun before reading a tile's
 * shadow map: `(s_x, s_y) · base / max(s_z, sin 1°)` (render::tile::shadow_shift),
 * `base` the altitude of the tile's layer's base.
 */
export function shadowShift(tile, base) {
  const s = keyframeSun(tile);
  const k = base / Math.max(s[2], Math.sin(Math.PI / 180));
  return [s[0] * k, s[1] * k];
}

/**
 * The ground shadow maps of a held tile (`target`: `{ layer, base, keyframe }`, the
 * keyframe decoded by decodeBillboards, `base` its layer's base altitude) cast by the
 * billboards added to it (`add`: the held tiles of its layer, itself among them), in
 * as many steps as the caller likes (a frame's budget at a time): `finish` gives
 * `{ t0, t1 }`, sunlight transmittance at the two ends of the target's span,
 * 256×256 each, row 0 the southern edge. At each column centre p on the base,
 * `T = exp(−Σ_b τ_b P(q_b))` over the balls b at that end, τ_b the ball's splat
 * optical depth, P the splat profile and q_b the squared distance, in radii, from the
 * ball's centre to the sun ray through p (docs/formats.md, "Ground shadow"); a ball
 * at t1 is at its t0 centre moved by its wind over its own span. All 1 with the sun
 * at or below the horizon.
 */
export class ShadowDerivation {
  constructor(target) {
    const n = TILE_COLUMNS;
    const k = target.keyframe;
    this.base = target.base;
    this.sun = keyframeSun(k);
    this.maps = [new Float64Array(n * n), new Float64Array(n * n)];
    this.column = k.header.size / n;
    this.origin = k.header.origin;
    const s = this.sun;
    // The footprint of a ball on the base is an ellipse, r / s_z along the sun's
    // horizontal direction and r across.
    const h = Math.sqrt(s[0] * s[0] + s[1] * s[1]);
    this.across = h > 1e-12 ? [s[0] / h, s[1] / h] : [1, 0];
  }

  /** Adds the balls of records `[from, to)` of `source` (`{ keyframe }`, a held tile of the target's layer). */
  add(source, from = 0, to = source.keyframe.count) {
    const s = this.sun;
    if (!(s[2] > 0)) return;
    const n = TILE_COLUMNS;
    const { column, origin, maps } = this;
    const x1 = origin[0] + n * column;
    const y1 = origin[1] + n * column;
    const [ux, uy] = this.across;
    const table = profile();
    const sk = source.keyframe;
    const r = sk.records;
    const so = sk.header.origin;
    const span = sk.header.t0 !== null && sk.header.t1 !== null ? sk.header.t1 - sk.header.t0 : 0;
    // The footprint widened by the server's light-buffer texel (the keyframe's shadow
    // widening w, in radii; the variances add), its optical depth spread to keep the
    // integral: radius r·√(1 + w²), τ / (1 + w²).
    const w = sk.lattice ? sk.lattice.shadowWidening : 0;
    const spread = 1 + w * w;
    const widen = Math.sqrt(spread);
    for (let b = from; b < to; b++) {
      const radius = r.radius[b] * widen;
      if (!(radius > 0 && Number.isFinite(radius))) continue;
      const a = radius / s[2];
      const hx = Math.sqrt(a * a * ux * ux + radius * radius * uy * uy);
      const hy = Math.sqrt(a * a * uy * uy + radius * radius * ux * ux);
      const invR2 = 1 / (radius * radius);
      for (let e = 0; e < 2; e++) {
        const tau = r.splatTau[2 * b + e] / spread;
        if (!(tau > 0)) continue;
        const moved = e === 1 ? span : 0;
        const cx = so[0] + r.offset[3 * b] + r.velocity[2 * b] * moved;
        const cy = so[1] + r.offset[3 * b + 1] + r.velocity[2 * b + 1] * moved;
        // Where the sun ray through the centre crosses the base.
        const lift = (r.offset[3 * b + 2] - this.base) / s[2];
        const px = cx - s[0] * lift;
        const py = cy - s[1] * lift;
        if (px + hx < origin[0] || px - hx > x1 || py + hy < origin[1] || py - hy > y1) continue;
        const map = maps[e];
        const c0 = Math.max(Math.ceil((px - hx - origin[0]) / column - 0.5), 0);
        const c1 = Math.min(Math.max(Math.floor((px + hx - origin[0]) / column - 0.5) + 1, 0), n);
        const r0 = Math.max(Math.ceil((py - hy - origin[1]) / column - 0.5), 0);
        const r1 = Math.min(Math.max(Math.floor((py + hy - origin[1]) / column - 0.5) + 1, 0), n);
        for (let row = r0; row < r1; row++) {
          const wy = py - (origin[1] + (row + 0.5) * column);
          for (let col = c0; col < c1; col++) {
            const wx = px - (origin[0] + (col + 0.5) * column);
            // The distance between the sun rays through the centre and through the
            // column: the offset less its part along the sun.
            const along = wx * s[0] + wy * s[1];
            const q = (wx * wx + wy * wy - along * along) * invR2;
            if (q < 1) {
              const x = Math.max(q, 0) * PROFILE_ENTRIES;
              const i = Math.min(Math.floor(x), PROFILE_ENTRIES - 1);
              const f = x - i;
              map[row * n + col] += tau * (table[i] * (1 - f) + table[i + 1] * f);
            }
          }
        }
      }
    }
  }

  /** The maps: `{ t0, t1 }`, transmittance at the span's ends. */
  finish() {
    const lit = (m) => {
      const out = new Float32Array(m.length);
      for (let i = 0; i < out.length; i++) out[i] = Math.exp(-m[i]);
      return out;
    };
    return { t0: lit(this.maps[0]), t1: lit(this.maps[1]) };
  }
}

/**
 * The ground shadow maps of a held tile cast by the billboards of `sources` (the held
 * tiles of its layer, itself among them): ShadowDerivation in one step.
 */
export function deriveShadow(target, sources) {
  const d = new ShadowDerivation(target);
  for (const s of sources) d.add(s);
  return d.finish();
}

/**
 * The ground shadow maps of every held tile (`{ layer, base, keyframe }`), each cast
 * by the held tiles of its layer (deriveShadow): what the viewer, the Rust client and
 * `cloudscape render` draw. A client holds only the tiles its view plans, so a tile's
 * shadow is cast by those; the server's shadow.png takes a halo around the tile.
 */
export function shadowMaps(tiles) {
  return tiles.map((t) => deriveShadow(t, tiles.filter((s) => s.layer === t.layer)));
}

/**
 * A tile's shadow map read where a ground point (x, y) looks toward the sun: bilinear
 * between column centres, the two ends blended by `f`, 1 outside the tile
 * (render::tile::shadow_lookup after shadow_shift). `maps` from deriveShadow, `tile`
 * the decoded keyframe, `base` its layer's base altitude.
 */
export function shadowAtPoint(maps, tile, base, x, y, f) {
  const [sx, sy] = shadowShift(tile, base);
  const n = TILE_COLUMNS;
  const column = tile.header.size / n;
  const u = (x + sx - tile.header.origin[0]) / column - 0.5;
  const v = (y + sy - tile.header.origin[1]) / column - 0.5;
  if (!(u > -0.5 && v > -0.5 && u < n - 0.5 && v < n - 0.5)) return 1;
  const uc = Math.min(Math.max(u, 0), n - 1);
  const vc = Math.min(Math.max(v, 0), n - 1);
  const u0 = Math.min(Math.floor(uc), n - 2);
  const v0 = Math.min(Math.floor(vc), n - 2);
  const fu = uc - u0;
  const fv = vc - v0;
  const at = (m) => {
    const p = (c, r) => m[r * n + c];
    const a = p(u0, v0) * (1 - fu) + p(u0 + 1, v0) * fu;
    const b = p(u0, v0 + 1) * (1 - fu) + p(u0 + 1, v0 + 1) * fu;
    return a * (1 - fv) + b * fv;
  };
  const a = at(maps.t0);
  return f === 0 ? a : (1 - f) * a + f * at(maps.t1);
}

/**
 * How much of the layers above a billboard its light sees (render::light
 * LAYERS_ABOVE_SUN_DEPTH, LAYERS_ABOVE_SKY_DEPTH): the share of the sun ray's optical
 * depth through them, and of their vertical depth, that `beneathLayers` takes.
 */
export const LAYERS_ABOVE_SUN_DEPTH = 1;
export const LAYERS_ABOVE_SKY_DEPTH = 0;

/**
 * A billboard end's pre-shaded colour `rgb` and sun optical depth `tauSun` under
 * other layers: the sun ray from the ball crosses them with optical depth `tauAbove`,
 * the vertical with `tauVertical` (Lighting::beneath_layers). The sun term
 * albedo · SUN_SCATTER · sunRgb · Σ bⁱ e^{−aⁱ τ} is re-evaluated at τ_sun + tauAbove,
 * the rest (sky and ground light) is dimmed by e^{−k · tauVertical}, k diffusion
 * theory's attenuation of the header's albedo and phase (every preset's sky-light
 * scale is 1). `lighting` is a keyframe header's. Returns `{ rgb, tauSun }`.
 */
export function beneathLayers(lighting, rgb, tauSun, tauAbove, tauVertical) {
  const ok = (t) => (Number.isFinite(t) ? Math.max(t, 0) : 0);
  tauAbove = ok(tauAbove);
  tauVertical = ok(tauVertical);
  if (tauAbove <= 0 && tauVertical <= 0) return { rgb, tauSun };
  const { albedo, phase } = lighting;
  const a = Math.min(Math.max(albedo, 0), 1);
  const fix = (v, lo, hi, nan) => (Number.isFinite(v) ? Math.min(Math.max(v, lo), hi) : nan);
  const g = (v) => fix(v, -0.99, 0.99, 0);
  const mix = fix(phase.mix, 0, 1, 0.5);
  const meanCos = mix * g(phase.g1) + (1 - mix) * g(phase.g2);
  const k = Math.min(Math.max(Math.sqrt(3 * (1 - a) * (1 - a * meanCos)), 0), 1);
  const t0 = ok(tauSun);
  const t1 = Math.min(t0 + tauAbove, 1e6);
  const sun = sunTerm(lighting);
  const before = sun(t0);
  const after = sun(t1);
  const sky = Math.exp(-k * tauVertical);
  const out = [0, 1, 2].map((i) => {
    const ambient = Math.max(rgb[i] - before[i], 0);
    return Math.min(Math.max(after[i] + ambient * sky, 0), 2);
  });
  return { rgb: out, tauSun: t1 };
}

/**
 * The sun term of a pre-shaded billboard colour for a keyframe header's `lighting`
 * (render::light::SunTerm): a function of the sun optical depth τ giving
 * albedo · SUN_SCATTER · sunRgb · Σ bⁱ e^{−aⁱ τ} per channel (red, green, blue).
 */
export function sunTerm(lighting) {
  const { albedo, octaves, sunRgb } = lighting;
  // Damaged bytes (NaN, ±∞) count as 0, as the Rust SunTerm::new.
  const a = Number.isFinite(albedo) ? Math.min(Math.max(albedo, 0), 1) : 0;
  const fix = (v, lo, hi, nan) => (Number.isFinite(v) ? Math.min(Math.max(v, lo), hi) : nan);
  const n = Math.min(Math.max(octaves.count, 1), 8);
  const oa = fix(octaves.a, 1e-3, 1, 1);
  const ob = fix(octaves.b, 0, 0.99, 0);
  const scale = [0, 1, 2].map((i) => (Number.isFinite(sunRgb[i]) ? a * SUN_SCATTER * sunRgb[i] : 0));
  return (tau) => {
    tau = tau > 0 ? tau : 0;
    let w = 1;
    let att = 1;
    let sum = 0;
    for (let i = 0; i < n; i++) {
      sum += w * Math.exp(-att * tau);
      w *= ob;
      att *= oa;
    }
    return scale.map((c) => c * sum);
  };
}

/**
 * The colours and sun optical depths of a held tile's billboards (`target`:
 * `{ layer, keyframe }`) lit through the layers above them (view/held.rs
 * beneath_layers): `others` are held tiles of the other layers with their ground
 * shadow maps (`{ layer, base, keyframe, maps }`, maps from deriveShadow); at each
 * end of each record, the sun transmittance through every layer whose base is above
 * the ball is read where the sun ray from the ball crosses that base, at the same end
 * of its span. Returns `{ colour, tauSun }` laid out as the records' (6 and 2 per
 * record).
 */
export function lightBeneathLayers(target, others) {
  const k = target.keyframe;
  const r = k.records;
  const colour = Float32Array.from(r.colour);
  const tauSun = Float32Array.from(r.tauSun);
  const lighting = k.header.lighting;
  const s = keyframeSun(k);
  const per = 1 / Math.max(s[2], Math.sin(Math.PI / 180));
  const o = k.header.origin;
  const span = k.header.t0 !== null && k.header.t1 !== null ? k.header.t1 - k.header.t0 : 0;
  // The box the balls' sun rays cross an upper tile's base in, to skip the tiles they miss.
  let zMin = Infinity;
  let zMax = -Infinity;
  let reach = 0;
  for (let i = 0; i < k.count; i++) {
    zMin = Math.min(zMin, r.offset[3 * i + 2]);
    zMax = Math.max(zMax, r.offset[3 * i + 2]);
    reach = Math.max(reach, Math.hypot(r.velocity[2 * i], r.velocity[2 * i + 1]) * span);
  }
  const size = k.header.size;
  const crosses = (u) => {
    const lo = Math.max(u.base - zMax, 0) * per;
    const hi = Math.max(u.base - zMin, 0) * per;
    const ux = u.keyframe.header.origin;
    const us = u.keyframe.header.size;
    const x0 = o[0] - reach + Math.min(s[0] * lo, s[0] * hi);
    const x1 = o[0] + size + reach + Math.max(s[0] * lo, s[0] * hi);
    const y0 = o[1] - reach + Math.min(s[1] * lo, s[1] * hi);
    const y1 = o[1] + size + reach + Math.max(s[1] * lo, s[1] * hi);
    return x0 <= ux[0] + us && ux[0] <= x1 && y0 <= ux[1] + us && ux[1] <= y1;
  };
  const above = others
    .filter((u) => u.layer !== target.layer && u.maps && u.base > zMin && crosses(u))
    .map((u) => ({ ...u, shift: shadowShift(u.keyframe, u.base) }));
  if (!lighting || !above.length || !(s[2] > 0)) return { colour, tauSun };
  for (let i = 0; i < k.count; i++) {
    const z = r.offset[3 * i + 2];
    for (let e = 0; e < 2; e++) {
      const moved = e === 1 ? span : 0;
      const x = o[0] + r.offset[3 * i] + r.velocity[2 * i] * moved;
      const y = o[1] + r.offset[3 * i + 1] + r.velocity[2 * i + 1] * moved;
      let t = 1;
      for (const u of above) {
        if (!(z < u.base)) continue;
        // shadowAtPoint reads from the ground: shift back by the climb not taken.
        const climb = u.base - z;
        const gx = x + s[0] * per * climb - u.shift[0];
        const gy = y + s[1] * per * climb - u.shift[1];
        t *= shadowAtPoint(u.maps, u.keyframe, u.base, gx, gy, e);
      }
      const tau = -Math.log(Math.min(Math.max(t, 1e-30), 1));
      if (!(tau > 0)) continue;
      const rgb = [0, 1, 2].map((c) => colour[6 * i + 3 * e + c]);
      const lit = beneathLayers(
        lighting,
        rgb,
        tauSun[2 * i + e],
        LAYERS_ABOVE_SUN_DEPTH * tau,
        LAYERS_ABOVE_SKY_DEPTH * tau * s[2],
      );
      for (let c = 0; c < 3; c++) colour[6 * i + 3 * e + c] = lit.rgb[c];
      tauSun[2 * i + e] = lit.tauSun;
    }
  }
  return { colour, tauSun };
}

// ---------------------------------------------------------------------------------
// The level choice of a view (crates/cloudscape-core/src/render/scene.rs plan_bands).
// ---------------------------------------------------------------------------------

/** How far (horizontally, metres) `cloudscape render` draws clouds (render::scene::VIEW_DISTANCE). */
export const VIEW_DISTANCE = 30000;
/** Where the ground's cloud shadow starts to fade into the mean shadow, a fraction of the view distance (render::scene::SHADOW_FADE_START). */
export const SHADOW_FADE_START = 0.4;
/** A tile splits while one of its columns would span more pixels than this (QualitySettings::lod_pixels). */
export const LOD_PIXELS = { fast: 8, balanced: 4, accurate: 2 };

/**
 * A camera's unit vectors (render::camera::Camera::basis): `camera` { yaw, pitch }
 * in degrees, yaw clockwise from north, pitch above the horizon.
 */
export function cameraBasis(camera) {
  const yaw = (camera.yaw * Math.PI) / 180;
  const pitch = (camera.pitch * Math.PI) / 180;
  const forward = [Math.sin(yaw) * Math.cos(pitch), Math.cos(yaw) * Math.cos(pitch), Math.sin(pitch)];
  const right = [Math.cos(yaw), -Math.sin(yaw), 0];
  const up = [
    right[1] * forward[2] - right[2] * forward[1],
    right[2] * forward[0] - right[0] * forward[2],
    right[0] * forward[1] - right[1] * forward[0],
  ];
  return { forward, right, up };
}

/**
 * The tiles a camera sees, as `cloudscape render` plans them (scene.rs plan_bands):
 * per layer a quadtree from the coarsest tiles covering the view distance, a tile
 * split while one of its columns, at the tile's nearest distance from the eye, would
 * span more than `lodPixels`; a tile kept when its clouds or its shadow on the ground
 * lie in the view frustum and within the view distance. The shadow of a point at
 * altitude z lies (s_x, s_y) · z / s_z away from the sun `sun` (a unit vector toward
 * it: the tiles' sun bucket's centre, sky.json's `sun.direction`), at most the view
 * distance away; with no sun, or the sun down, straight below.
 *
 * `camera` { x, y, z, yaw, pitch, fov } (metres, degrees, horizontal FOV), the image
 * `width` × `height` pixels. Options: `quality` (fast | balanced | accurate) or
 * `lodPixels`; `viewDistance` (VIEW_DISTANCE); `layers` (names, default all);
 * `maxTiles`: past 64 × maxTiles tiles under way the plan stops and gives null
 * (`cloudscape render` refuses such a view; a client may plan coarser). Returns
 * `{ layer, layerIndex, z, x, y, origin, size }` sorted by layer, level, y, x.
 */
export function planTiles(world, camera, width, height, options = {}) {
  const lodPixels = options.lodPixels ?? LOD_PIXELS[options.quality ?? 'balanced'];
  const view = options.viewDistance ?? VIEW_DISTANCE;
  const maxTiles = options.maxTiles ?? Infinity;
  const { forward, right, up } = cameraBasis(camera);
  const w = Math.max(1, width);
  const h = Math.max(1, height);
  const tanH = Math.tan((camera.fov * Math.PI) / 360);
  const tanV = (tanH * h) / w;
  const pixelAngle = (2 * tanH) / w;
  const s = options.sun;
  const k = s && s[2] > 0 ? 1 / Math.max(s[2], Math.sin(Math.PI / 180)) : 0;
  /** The move of the shadow of a point at altitude z. */
  const move = (z) => {
    const [x, y] = k ? [-s[0] * k * Math.max(z, 0), -s[1] * k * Math.max(z, 0)] : [0, 0];
    const len = Math.hypot(x, y);
    const scale = len > view ? view / len : 1;
    return [x * scale, y * scale];
  };
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const out = [];
  for (const [layerIndex, l] of world.layers.entries()) {
    if (options.layers && !options.layers.includes(l.name)) continue;
    const [zb, zt] = [l.base, l.top];
    const tileSize = (z) => (world.tile_size || TILE_COLUMNS) * l.cell_size * 2 ** z;
    let zTop = 0;
    while (tileSize(zTop) < 2 * view && zTop < world.maxzoom) zTop++;
    const side = tileSize(zTop);
    // The shadow's moves for the layer's base and top.
    const moves = [move(zb), move(zt)];
    const far = view + Math.hypot(...moves[1]);
    const stack = [];
    for (let y = Math.floor((camera.y - far) / side); y <= Math.floor((camera.y + far) / side); y++) {
      for (let x = Math.floor((camera.x - far) / side); x <= Math.floor((camera.x + far) / side); x++) stack.push([zTop, x, y]);
    }
    while (stack.length) {
      const [z, x, y] = stack.pop();
      const size = tileSize(z);
      const [x0, y0] = [x * size, y * size];
      const [x1, y1] = [x0 + size, y0 + size];
      const dx = Math.max(x0 - camera.x, 0, camera.x - x1);
      const dy = Math.max(y0 - camera.y, 0, camera.y - y1);
      const dz = Math.max(zb - camera.z, 0, camera.z - zt);
      // The shadow's bounding rectangle on the ground.
      const [mx0, mx1] = [Math.min(moves[0][0], moves[1][0]), Math.max(moves[0][0], moves[1][0])];
      const [my0, my1] = [Math.min(moves[0][1], moves[1][1]), Math.max(moves[0][1], moves[1][1])];
      const sdx = Math.max(x0 + mx0 - camera.x, 0, camera.x - x1 - mx1);
      const sdy = Math.max(y0 + my0 - camera.y, 0, camera.y - y1 - my1);
      if (Math.hypot(dx, dy) > view && Math.hypot(sdx, sdy) > view) continue;
      // Culled when all corners of its box, of the ground under it and of its shadow
      // on the ground lie outside one plane of the frustum.
      const outside = [true, true, true, true, true];
      for (const cx of [x0, x1]) {
        for (const cy of [y0, y1]) {
          const corners = [
            [cx, cy, Math.min(zb, 0)],
            [cx, cy, zt],
            [cx + moves[0][0], cy + moves[0][1], 0],
            [cx + moves[1][0], cy + moves[1][1], 0],
          ];
          for (const c of corners) {
            const r = [c[0] - camera.x, c[1] - camera.y, c[2] - camera.z];
            const [a, b, f] = [dot(r, right), dot(r, up), dot(r, forward)];
            const tests = [f < 0, a > f * tanH, a < -f * tanH, b > f * tanV, b < -f * tanV];
            for (let i = 0; i < 5; i++) outside[i] = outside[i] && tests[i];
          }
        }
      }
      if (outside.some(Boolean)) continue;
      const dist = Math.max(Math.hypot(dx, dy, dz), 1);
      if (z > 0 && (l.cell_size * 2 ** z) / (dist * pixelAngle) > lodPixels) {
        for (const [ox, oy] of [[0, 0], [1, 0], [0, 1], [1, 1]]) stack.push([z - 1, x * 2 + ox, y * 2 + oy]);
        if (out.length + stack.length > 64 * maxTiles) return null;
        continue;
      }
      out.push({ layer: l.name, layerIndex, z, x, y, origin: [x0, y0], size });
    }
  }
  return out.sort((a, b) => a.layerIndex - b.layerIndex || a.z - b.z || a.y - b.y || a.x - b.x);
}

// ---------------------------------------------------------------------------------
// Drawing in WebGL2: the server's light (crates/cloudscape-core/src/render/light.rs,
// sky.rs, splats.rs, detail.rs, composite.rs) as GLSL ES 3.00 chunks and the uniform
// values of /v1/sky.json, so a WebGL2 engine (the viewer, the three.js example) draws
// what `cloudscape render` draws. The chunks declare the uniforms they read.
// ---------------------------------------------------------------------------------

/** Lengths of the sky.json tables (src/render/sky.rs SUN_TABLE_LEN, MS_ALTITUDES). */
export const SUN_TABLE_LEN = 41;
export const MULTIPLE_SCATTERING_LEN = 12;
/** src/render/detail.rs: most detail octaves, and the footprint (pixels) an octave must span. */
export const MAX_DETAIL_OCTAVES = 4;
export const MIN_WAVELENGTH_PIXELS = 2;
/** The share of the sun's radiance (header lighting `sunRgb`) that cloud scatters (render::light::SUN_SCATTER). */
export const SUN_SCATTER = 0.25;
const MS_LEN = MULTIPLE_SCATTERING_LEN;

export const GLSL = {
  /**
   * The display mapping (light.rs `tone_map`): `tone(x)` = (1 − exp(−exposure · x))^(1/2.2),
   * `exposure` sky.json's (1 when it names none). Blend in radiance and map once, as
   * the server does; `display(x)` maps only when `toneOut` (a pass drawing straight to
   * the screen, for want of float targets).
   */
  tone: `
uniform float exposure;
uniform bool toneOut;
vec3 tone(vec3 x) { return pow(1.0 - exp(-exposure * max(x, vec3(0.0))), vec3(1.0 / 2.2)); }
vec3 display(vec3 x) { return toneOut ? tone(x) : x; }
`,
  /**
   * The atmosphere (sky.rs): `skyRadiance(d)`, the sky table lookup (Sky::radiance),
   * and `aerial(v, z0, z1, vis, T, L)`, the air between the eye at altitude z0 and a
   * point at offset v and altitude z1 (Sky::aerial_lit, Hoffman & Preetham 2002 with
   * the server's coefficients and tables): transmittance T and in-scattered light L,
   * the sun's share scaled by vis. Uniforms: skyUniforms.
   */
  atmosphere: `
const float PI = 3.14159265358979;
uniform sampler2D skyTable;
uniform vec2 skySize;          // columns, rows
uniform vec3 sunDir, night;
uniform vec3 betaR;            // Rayleigh scattering per metre
uniform vec4 mie;              // scattering, extinction, scale height, g
uniform vec4 air;              // Rayleigh scale height, scatter irradiance, top altitude, sun table step
uniform vec3 sunT[${SUN_TABLE_LEN}];
uniform vec3 multi[${MS_LEN}];
vec3 skyRadiance(vec3 d) {
  float e = asin(clamp(d.z, 0.0, 1.0));
  float hd = length(d.xy);
  float hs = length(sunDir.xy);
  float phi = 0.0;
  if (hd > 1e-6 && hs > 1e-6) phi = acos(clamp(dot(d.xy, sunDir.xy) / (hd * hs), -1.0, 1.0));
  else if (hd > 1e-6) phi = acos(clamp(d.y / hd, -1.0, 1.0));
  vec2 uv = vec2(phi / PI, sqrt(e / (0.5 * PI)));
  vec2 tc = (uv * (skySize - 1.0) + 0.5) / skySize;
  return texture(skyTable, tc).rgb + night;
}
float phaseR(float mu) { return 3.0 / (16.0 * PI) * (1.0 + mu * mu); }
float phaseM(float mu, float g) {
  float g2 = g * g;
  float d = max(1.0 + g2 - 2.0 * g * mu, 1e-12);
  return 3.0 / (8.0 * PI) * (1.0 - g2) * (1.0 + mu * mu) / ((2.0 + g2) * d * sqrt(d));
}
float meanDensity(float z0, float z1, float h) {
  float dz = z1 - z0;
  if (abs(dz) < 1e-3 * h) return exp(-0.5 * (z0 + z1) / h);
  return h * (exp(-z0 / h) - exp(-z1 / h)) / dz;
}
vec3 sunAt(float h) {
  float x = clamp(h / air.w, 0.0, float(${SUN_TABLE_LEN} - 1));
  int i = min(int(x), ${SUN_TABLE_LEN} - 2);
  return mix(sunT[i], sunT[i + 1], x - float(i));
}
vec3 multiAt(float h) {
  float x = sqrt(clamp(h / air.z, 0.0, 1.0)) * float(${MS_LEN} - 1);
  int i = min(int(x), ${MS_LEN} - 2);
  return mix(multi[i], multi[i + 1], x - float(i));
}
// The air between the eye (altitude z0) and a point at offset v (altitude z1):
// transmittance T and in-scattered light L; the sun's share scaled by vis.
void aerial(vec3 v, float z0, float z1, float vis, out vec3 T, out vec3 L) {
  float d = length(v);
  if (!(d > 0.0)) { T = vec3(1.0); L = vec3(0.0); return; }
  z0 = clamp(z0, 0.0, air.z);
  z1 = clamp(z1, 0.0, air.z);
  float mR = meanDensity(z0, z1, air.x);
  float mM = meanDensity(z0, z1, mie.z);
  float mu = dot(v / d, sunDir);
  float h = 0.5 * (z0 + z1);
  vec3 sr = betaR * mR;
  float sm = mie.x * mM;
  vec3 ext = sr + mie.y * mM;
  T = exp(-ext * d);
  vec3 src = (sr * phaseR(mu) + sm * phaseM(mu, mie.w)) * air.y * sunAt(h) * vis + (sr + sm) * multiAt(h);
  L = src / ext * (1.0 - T);
}
`,
  /**
   * The ground (Lighting::ground_radiance) seen along offset v from the eye at eyeZ:
   * albedo · (sun · t · cos + sky light, turning grey as the shadow deepens), through
   * the air (its sunlit in-scatter shadowed too); t the sun's transmittance through
   * the clouds. Needs `atmosphere` before it.
   */
  ground: `
uniform vec3 sunGround, above, groundAlbedo;
vec3 ground(vec3 v, float eyeZ, float t) {
  float grey = dot(above, vec3(0.2126, 0.7152, 0.0722));
  vec3 sky = t * above + (1.0 - t) * vec3(grey);
  vec3 g = groundAlbedo * (sunGround * t * max(sunDir.z, 0.0) + sky);
  vec3 T, L;
  aerial(v, eyeZ, 0.0, t, T, L);
  return g * T + L;
}
`,
  /**
   * The phase correction of the scattering octaves (Lighting::phase_correction,
   * Octaves::sun_sum − Octaves::isotropic_sum, of the sun's SUN_SCATTER share): what
   * view direction d adds to a billboard's pre-shaded (isotropic) colour for sun
   * optical depth tauSun. Reads the
   * uniforms albedo, phase (g1, g2, mix), octaves (N, a, b, c) and sunRgb of the
   * keyframe's header lighting, and sunDir; declare them before it.
   */
  octaves: `
  float hg(float g, float c) { float d = max(1.0 + g * g - 2.0 * g * c, 1e-12); return (1.0 - g * g) / (d * sqrt(d)); }
  vec3 phaseCorrection(float tauSun, vec3 d) {
    float cosTheta = dot(d, sunDir);
    float w = 1.0, att = 1.0, ecc = 1.0, corr = 0.0;
    for (int i = 0; i < 8; i++) {
      if (float(i) >= octaves.x) break;
      float g1 = clamp(phase.x * ecc, -0.99, 0.99), g2 = clamp(phase.y * ecc, -0.99, 0.99);
      float ph = mix(hg(g2, cosTheta), hg(g1, cosTheta), phase.z);
      corr += w * (ph - 1.0) * exp(-att * max(tauSun, 0.0));
      w *= octaves.z; att *= octaves.y; ecc *= octaves.w;
    }
    return albedo * ${SUN_SCATTER.toFixed(2)} * sunRgb * corr;
  }`,
  /**
   * The splat profile (splats.rs): `chord(q, v0)`, the integral of Wyvill's field
   * function along a line at squared impact parameter q (radii) over v ≥ v0, v the
   * signed distance from the closest approach (line_integral_beyond; v0 ≤ −√(1 − q):
   * the whole chord S), and S0 = S(0). A billboard's opacity at q is
   * 1 − exp(−τ · chord(q, −1) / S0).
   */
  splat: `  // render::splats::line_integral_beyond: the field's integral along a line at impact
  // parameter sqrt(q) (radii) over v >= v0, v the signed distance from the closest
  // approach; v0 <= -sqrt(1 - q) gives the whole chord, S.
  float chord(float q, float v0) {
    if (!(q < 1.0)) return 0.0;
    float l = sqrt(1.0 - q);
    float c0 = 1.0 - 22.0 / 9.0 * q + 17.0 / 9.0 * q * q - 4.0 / 9.0 * q * q * q;
    float c2 = -22.0 / 9.0 + 34.0 / 9.0 * q - 4.0 / 3.0 * q * q;
    float c4 = 17.0 / 9.0 - 4.0 / 3.0 * q;
    float c6 = -4.0 / 9.0;
    vec2 v = vec2(l, clamp(v0, -l, l));
    vec2 v2 = v * v;
    vec2 a = v * (c0 + v2 * (c2 / 3.0 + v2 * (c4 / 5.0 + v2 * c6 / 7.0)));
    return max(a.x - a.y, 0.0);
  }
  // S(0) = 2 (1 − 22/27 + 17/45 − 4/63).
  const float S0 = 2.0 * (1.0 - 22.0 / 27.0 + 17.0 / 45.0 - 4.0 / 63.0);
`,
  /**
   * The detail noise (detail.rs): `detailNoise(p, octaves)`, fBm in [0, 1] of a 3-D
   * gradient noise, lacunarity 2, gain ½, p in units of the first wavelength. The
   * octave rule and constants are the server's; the basis has a 32-bit integer hash
   * (WebGL has no 64-bit integers), so the pattern is not the server's bit for bit.
   */
  detailNoise: `
uint hash(ivec3 q) {
  uvec3 p = uvec3(q);
  uint h = p.x * 0x8da6b343u ^ p.y * 0xd8163841u ^ p.z * 0xcb1ab31fu;
  h ^= h >> 16; h *= 0x7feb352du; h ^= h >> 15; h *= 0x846ca68bu; h ^= h >> 16;
  return h;
}
vec3 grad(ivec3 q) {
  uint h = hash(q);
  vec3 g = vec3(float(h & 1023u), float((h >> 10) & 1023u), float((h >> 20) & 1023u)) / 511.5 - 1.0;
  return g / max(length(g), 1e-6);
}
float gnoise(vec3 x) {
  vec3 i = floor(x), f = x - i;
  ivec3 b = ivec3(i);
  vec3 u = f * f * f * (f * (f * 6.0 - 15.0) + 10.0);
  float n000 = dot(grad(b), f);
  float n100 = dot(grad(b + ivec3(1, 0, 0)), f - vec3(1, 0, 0));
  float n010 = dot(grad(b + ivec3(0, 1, 0)), f - vec3(0, 1, 0));
  float n110 = dot(grad(b + ivec3(1, 1, 0)), f - vec3(1, 1, 0));
  float n001 = dot(grad(b + ivec3(0, 0, 1)), f - vec3(0, 0, 1));
  float n101 = dot(grad(b + ivec3(1, 0, 1)), f - vec3(1, 0, 1));
  float n011 = dot(grad(b + ivec3(0, 1, 1)), f - vec3(0, 1, 1));
  float n111 = dot(grad(b + ivec3(1, 1, 1)), f - vec3(1, 1, 1));
  float n = mix(mix(mix(n000, n100, u.x), mix(n010, n110, u.x), u.y),
                mix(mix(n001, n101, u.x), mix(n011, n111, u.x), u.y), u.z);
  return clamp(n * 1.15, -1.0, 1.0);
}
float detailNoise(vec3 p, int octaves) {
  float sum = 0.0, norm = 0.0, amp = 1.0;
  for (int o = 0; o < ${MAX_DETAIL_OCTAVES}; o++) {
    if (o >= octaves) break;
    sum += amp * gnoise(p + float(o) * 17.31);
    norm += amp;
    amp *= 0.5; p *= 2.0;
  }
  return clamp(0.5 + 0.5 * sum / norm, 0.0, 1.0);
}
`,
};

/**
 * The uniform values of GLSL.atmosphere, GLSL.ground and GLSL.tone for a parsed
 * /v1/sky.json: `table` the sky radiance as RGBA float texels (`columns` × `rows`,
 * for a linear-filtered float texture bound to `skyTable`), and `values`, by uniform
 * name, numbers and arrays (sunT and multi flattened).
 */
export function skyUniforms(sky) {
  const { rows, columns, rgb } = sky.sky;
  const data = new Float32Array(rows * columns * 4);
  for (let i = 0; i < rows * columns; i++) {
    data.set(rgb.slice(i * 3, i * 3 + 3), i * 4);
    data[i * 4 + 3] = 1;
  }
  const a = sky.aerial;
  const exposure = Number.isFinite(sky.exposure) && sky.exposure > 0 ? sky.exposure : 1;
  return {
    table: { data, columns, rows },
    values: {
      skySize: [columns, rows],
      sunDir: sky.sun.direction,
      night: sky.night_rgb,
      betaR: a.rayleigh_scattering,
      mie: [a.mie_scattering, a.mie_extinction, a.mie_scale_height, a.mie_g],
      air: [a.rayleigh_scale_height, a.scatter_irradiance, a.top_altitude, a.sun_step_m],
      sunT: a.sun_transmittance,
      multi: a.multiple,
      sunGround: sky.sun_rgb_ground,
      above: sky.sky_ambient_above,
      groundAlbedo: sky.ground_albedo,
      exposure,
    },
  };
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

/** The bytes of an ArrayBuffer or a view of one, without a copy. */
function byteView(buffer) {
  if (buffer instanceof ArrayBuffer) return new Uint8Array(buffer);
  if (ArrayBuffer.isView(buffer)) return new Uint8Array(buffer.buffer, buffer.byteOffset, buffer.byteLength);
  throw new Error('billboards.bin: not an ArrayBuffer or a view of one');
}

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
