// The JS client against a real `cloudscape serve` (started by tests/ext/js_client.sh,
// which passes its address in CLOUDSCAPE_URL):
//
//   CLOUDSCAPE_URL=http://127.0.0.1:8080 node --test clients/js/test/
//
// The server's own JSON (billboards.json, density.npy) is the independent reference
// the binary decoders are checked against. Version 3 of billboards.bin, its deltas and
// the ground shadow derived from it: keyframes.test.mjs and shadow.test.mjs.

import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { before, test } from 'node:test';

import {
  CloudscapeClient,
  CloudscapeError,
  billboardsAt,
  decodeBillboards,
  decodeCoverage,
  decodeDensityF32,
  decodeDensityU8,
  decodeNpy,
  decodePng,
  decodeShadow,
  halfToFloat,
  keyframeOf,
  keyframeSpan,
  prefetchAt,
  layerVelocity,
  shadowAt,
  splatForTau,
  splatTauOf,
  threeArrays,
  tilesAround,
  zUpToYUp,
} from '../cloudscape.js';

const base = process.env.CLOUDSCAPE_URL;
if (!base) throw new Error('set CLOUDSCAPE_URL to a running cloudscape server');

// Level 0 of the overcast world's stratocumulus (20 s steps): a span of 20 s.
const WORLD = 'overcast';
const TILE = { layer: 'stratocumulus', z: 0, x: 0, y: 0 };
const T0 = 43200;
const AT = { t: T0 + 12, quality: 'fast', sun: [180, 60] };

let client;
let world;
before(async () => {
  client = new CloudscapeClient(base, { quality: 'fast' });
  world = await client.world(WORLD);
});

test('prefetch points spread over [0.5, 0.8) by tile, as the server\'s rule does', () => {
  const points = [];
  for (let z = 0; z < 4; z++) for (let x = -20; x < 20; x++) for (let y = -20; y < 20; y++) points.push(prefetchAt(z, x, y));
  assert.ok(points.every((f) => f >= 0.5 && f < 0.8));
  const mean = points.reduce((a, b) => a + b, 0) / points.length;
  assert.ok(Math.abs(mean - 0.65) < 0.01, String(mean));
  // Negative coordinates wrap as the Rust rule's `x as u32` does.
  assert.equal(prefetchAt(1, -1, 2), prefetchAt(1, 0xffffffff, 2));
});

test('keyframes come from discovery', () => {
  const layer = world.layers.find((l) => l.name === TILE.layer);
  assert.deepEqual(layer.keyframe_spans, [0, 1, 2, 3, 4].map((z) => layer.dt * 2 ** z));
  assert.equal(keyframeSpan(layer, 7), layer.dt * 16, 'the span stops doubling at level 4');
  assert.deepEqual(keyframeOf(layer, 0, T0 + 12), { index: 2160, t0: T0, t1: T0 + 20, span: 20, f: 0.6 });
  assert.equal(keyframeOf(layer, 0, T0).t0, T0, 'a keyframe time is its own keyframe');
  assert.equal(keyframeOf(layer, 2, T0 + 90).t0, T0 + 80);
  assert.equal(keyframeOf(layer, 0, 1e12).t1, 1e12, 'the last span ends at max_time');
  assert.equal(keyframeOf({ dt: 20 }, 1, 50).t0, 40, 'without keyframe_spans: dt · 2^min(z, 4)');
});

test('tile URLs are keyframe URLs, immutable and never asked for twice', async () => {
  const path = client.tilePath(world, TILE, 'billboards.bin', AT);
  assert.equal(path, `/v1/worlds/${WORLD}/tiles/0/0/0/billboards.bin?t=${T0}&quality=fast&sun=180,60&layer=stratocumulus`);
  const first = await client.fetch(path);
  assert.equal(first.source, 'network');
  assert.ok(first.immutable, 'a keyframe URL is immutable');
  assert.ok(first.etag);
  const requests = client.stats.requests;
  const again = await client.fetch(path);
  assert.equal(again.source, 'memory');
  assert.equal(client.stats.requests, requests, 'no request for an immutable body held');
  assert.equal(again.body, first.body);
});

test('a URL by plain t revalidates with its ETag and gets a 304', async () => {
  const perT = `/v1/worlds/${WORLD}/tiles/0/0/0/billboards.bin?t=${T0 + 12}&quality=fast&sun=180,60&layer=stratocumulus`;
  const res = await fetch(`${base}${perT}`);
  assert.equal(res.status, 200);
  assert.match(res.headers.get('Cache-Control'), /max-age=\d+/);
  assert.doesNotMatch(res.headers.get('Cache-Control'), /immutable/);
  assert.match(res.headers.get('Content-Location') || '', new RegExp(`t=${T0}\\b`));
  await res.arrayBuffer();
  const c = new CloudscapeClient(base);
  const a = await c.fetch(perT);
  assert.equal(a.source, 'network');
  assert.equal(a.immutable, false);
  const b = await c.fetch(perT);
  assert.equal(b.source, 'revalidated');
  assert.equal(c.stats.revalidated, 1);
  assert.deepEqual(new Uint8Array(b.body), new Uint8Array(a.body));
});

test('billboards.v2.bin (version 2) decodes to what billboards.json says', async () => {
  const bin = decodeBillboards(await client.tile(world, TILE, 'billboards.v2.bin', AT));
  const json = await client.json(client.tilePath(world, TILE, 'billboards.json', AT));
  const h = bin.header;
  assert.equal(h.version, 2);
  assert.ok(bin.count > 100, `${bin.count} billboards`);
  assert.equal(bin.count, json.count);
  assert.deepEqual([h.t0, h.t1], [json.keyframe.t0, json.keyframe.t1]);
  assert.deepEqual([h.t0, h.t1], [T0, T0 + 20]);
  assert.deepEqual(h.tile, { z: 0, x: 0, y: 0 });
  assert.deepEqual(h.origin, json.origin);
  assert.equal(h.algorithmVersion, json.algorithm_version);
  const l = h.lighting;
  const near = (a, b, tol, what) => assert.ok(Math.abs(a - b) <= tol, `${what}: ${a} vs ${b}`);
  near(l.albedo, json.lighting.albedo, 1e-6, 'albedo');
  near(l.phase.g1, json.lighting.phase.g1, 1e-6, 'g1');
  assert.equal(l.octaves.count, json.lighting.octaves.count);
  l.sunRgb.forEach((v, i) => near(v, json.lighting.sun_rgb[i], 1e-5 * Math.max(1, v), 'sun_rgb'));
  near(Math.hypot(...l.sunDirection), 1, 1e-5, 'sun direction is a unit vector');
  const r = bin.records;
  for (let i = 0; i < bin.count; i += 97) {
    const j = json.billboards[i];
    near(h.origin[0] + r.offset[3 * i], j.position[0], 1e-2, `x of ${i}`);
    near(h.origin[1] + r.offset[3 * i + 1], j.position[1], 1e-2, `y of ${i}`);
    near(r.offset[3 * i + 2], j.position[2], 1e-2, `z of ${i}`);
    near(r.radius[i], j.radius, 1e-3, `radius of ${i}`);
    near(r.velocity[2 * i], j.velocity[0], 1e-5, `vx of ${i}`);
    ['start', 'end'].forEach((e, k) => {
      near(r.splatTau[2 * i + k], j[e].splat_tau, 1e-5, `${e} splat_tau of ${i}`);
      assert.equal(r.splat[2 * i + k], j[e].splat);
      // f16 colours: 11 significant bits.
      for (let c = 0; c < 3; c++) near(r.colour[6 * i + 3 * k + c], j[e].colour[c], 2e-3 * Math.max(1, j[e].colour[c]), `${e} colour of ${i}`);
      near(r.tauSun[2 * i + k], j[e].tau_sun, 2e-3 * Math.max(1, j[e].tau_sun), `${e} tau_sun of ${i}`);
      near(r.opacity[2 * i + k], j[e].opacity, 0.5 / 255 + 1e-6, `${e} opacity of ${i}`);
    });
  }
});

test('the animation rule: ends at the keyframes, wind in between', async () => {
  const tile = decodeBillboards(await client.tile(world, TILE, 'billboards.bin', AT));
  const sheet = await client.splats('fast');
  const at0 = billboardsAt(tile, T0, sheet);
  const at1 = billboardsAt(tile, T0 + 20, sheet);
  const mid = billboardsAt(tile, T0 + 12, sheet);
  const before = billboardsAt(tile, T0 - 100, sheet);
  const r = tile.records;
  let formed = 0;
  let vanished = 0;
  for (let i = 0; i < tile.count; i++) {
    assert.equal(at0.splatTau[i], r.splatTau[2 * i]);
    assert.ok(Math.abs(at1.splatTau[i] - r.splatTau[2 * i + 1]) < 1e-6);
    assert.ok(Math.abs(mid.splatTau[i] - (0.4 * r.splatTau[2 * i] + 0.6 * r.splatTau[2 * i + 1])) < 1e-5);
    assert.ok(Math.abs(mid.position[3 * i] - (at0.position[3 * i] + 12 * r.velocity[2 * i])) < 1e-6);
    assert.equal(mid.position[3 * i + 2], at0.position[3 * i + 2], 'the wind is horizontal');
    assert.ok(Math.abs(at1.position[3 * i + 1] - (at0.position[3 * i + 1] + 20 * r.velocity[2 * i + 1])) < 1e-6);
    assert.equal(before.position[3 * i], at0.position[3 * i], 'a time before the span clamps to t0');
    assert.equal(mid.splat[i], splatForTau(mid.splatTau[i], sheet.count, sheet.tau_max));
    if (r.splatTau[2 * i] === 0) formed++;
    if (r.splatTau[2 * i + 1] === 0) vanished++;
    assert.ok(r.splatTau[2 * i] > 0 || r.splatTau[2 * i + 1] > 0, 'a record is present at one end at least');
  }
  assert.ok(formed > 0 && vanished > 0, `${formed} balls form and ${vanished} vanish in the span`);
  assert.equal(at0.present.reduce((a, b) => a + b, 0), tile.count - formed);
  // The splat table: τ_k = tau_max ((k + 1) / count)², as /v1/splats.json lists.
  for (const k of [0, 7, sheet.count - 1]) {
    assert.ok(Math.abs(splatTauOf(k, sheet.count, sheet.tau_max) - sheet.tau[k]) < 1e-5);
    assert.equal(splatForTau(sheet.tau[k], sheet.count, sheet.tau_max), k);
  }
  // The wind a layer's discovery gives is the records' velocity at their height.
  const layer = world.layers.find((l) => l.name === TILE.layer);
  const v = layerVelocity(layer, r.offset[2]);
  assert.ok(Math.abs(v[0] - r.velocity[0]) < 1e-3 && Math.abs(v[1] - r.velocity[1]) < 1e-3, `${v} vs ${r.velocity.slice(0, 2)}`);
});

test('three.js arrays: y up, back to front, absent billboards left out', async () => {
  const tile = decodeBillboards(await client.tile(world, TILE, 'billboards.bin', AT));
  const frame = billboardsAt(tile, AT.t);
  const origin = [12800, 12800, 0];
  const eye = [12800, 12800, 9000];
  const a = threeArrays(frame, { origin, eye });
  assert.equal(a.count, frame.present.reduce((s, p) => s + p, 0));
  assert.deepEqual(zUpToYUp([1, 2, 3]), [1, 3, -2]);
  // Back to front: the distance from the eye (y up: eye at (0, 9000, 0)) never grows.
  let last = Infinity;
  for (let j = 0; j < a.count; j++) {
    const d = Math.hypot(a.positions[3 * j], a.positions[3 * j + 1] - 9000, a.positions[3 * j + 2]);
    assert.ok(d <= last + 1e-2, `instance ${j} is nearer than the one before`);
    last = d;
    assert.ok(a.positions[3 * j + 1] > 0, 'altitude is y');
  }
  // One instance by hand.
  const i = frame.present.indexOf(1);
  const unsorted = threeArrays(frame, { origin });
  assert.ok(Math.abs(unsorted.positions[0] - (frame.position[3 * i] - origin[0])) < 1e-2);
  assert.ok(Math.abs(unsorted.positions[1] - frame.position[3 * i + 2]) < 1e-2);
  assert.ok(Math.abs(unsorted.positions[2] + (frame.position[3 * i + 1] - origin[1])) < 1e-2);
  assert.equal(unsorted.radii[0], frame.radius[i]);
});

test('shadow.png holds both ends; coverage.png decodes', async () => {
  const shadow = await decodeShadow(await client.tile(world, TILE, 'shadow.png', AT));
  assert.equal(shadow.width, 256);
  assert.equal(shadow.height, 256);
  const mean = (a) => a.reduce((s, v) => s + v, 0) / a.length;
  const half = shadowAt(shadow, 0.5);
  assert.ok(Math.abs(mean(half) - 0.5 * (mean(shadow.t0) + mean(shadow.t1))) < 1e-5);
  assert.ok(mean(shadow.t0) < 1, 'the overcast deck shadows the ground');
  assert.ok(shadow.t0.some((v, i) => v !== shadow.t1[i]), 'the two ends differ');
  const cov = await decodeCoverage(await client.tile(world, TILE, 'coverage.png', AT));
  assert.equal(cov.width, 256);
  assert.ok(cov.coverage.some((v) => v > 0.5) && cov.coverage.some((v) => v === 0));
  for (let i = 0; i < cov.coverage.length; i++) {
    if (cov.coverage[i] === 0) assert.equal(cov.top[i], 0, 'no top without cloud');
  }
  const png = await decodePng(await client.bytes('/v1/splats.png?quality=fast'));
  assert.equal(png.channels, 2, 'the splat sheet is grey + alpha');
});

test('density grids: .u8 is .npy × 255 rounded, .f32 is .npy', async () => {
  const layer = world.layers.find((l) => l.name === TILE.layer);
  const npy = decodeNpy(await client.tile(world, TILE, 'density.npy', AT));
  assert.deepEqual(npy.shape, [layer.depth, 256, 256]);
  assert.equal(npy.dtype, '<f4');
  const u8 = decodeDensityU8(await client.tile(world, TILE, 'density.u8', AT), layer.depth);
  const f32 = decodeDensityF32(await client.tile(world, TILE, 'density.f32', AT), layer.depth);
  let cloudy = 0;
  for (let i = 0; i < npy.data.length; i++) {
    // The server rounds in f32: (v · 255) in f32, then to the nearest byte.
    assert.equal(u8.data[i], Math.round(Math.fround(Math.min(Math.max(npy.data[i], 0), 1) * 255)));
    assert.equal(f32.data[i], npy.data[i]);
    if (npy.data[i] > 0.5) cloudy++;
  }
  assert.ok(cloudy > 0);
  assert.throws(() => decodeDensityU8(new Uint8Array(10), layer.depth), /density.u8/);
});

test('the next keyframe is fetched ahead past the tile\'s prefetch point, as a delta, then needs no request', async () => {
  const c = new CloudscapeClient(base, { quality: 'fast' });
  const w = await c.world(WORLD);
  // Tile (0, 0, 0)'s point: 0.7275 of the span (worked out in Python from the rule).
  const point = prefetchAt(TILE.z, TILE.x, TILE.y);
  assert.equal(point, 0.5 + (0.3 * 0xc21a3414) / 2 ** 32);
  const early = await c.prefetchNext(w, TILE, { ...AT, t: T0 + 14 });
  assert.deepEqual(early, [], 'nothing before the prefetch point (0.70 < 0.7275)');
  const { billboards } = await c.billboardTile(w, TILE, { ...AT, prefetch: false });
  assert.equal(billboards.header.t0, T0);
  const paths = await c.prefetchNext(w, TILE, { ...AT, t: T0 + 15 });
  assert.deepEqual(paths, [`/v1/worlds/${WORLD}/tiles/0/0/0/billboards.delta.bin?t=${T0 + 20}&quality=fast&sun=180,60&layer=stratocumulus`]);
  assert.equal(c.stats.deltas, 1);
  const requests = c.stats.requests;
  const next = await c.billboardTile(w, TILE, { ...AT, t: T0 + 21, prefetch: false });
  assert.equal(c.stats.requests, requests, 'the next keyframe came from what was prefetched');
  assert.equal(next.billboards.header.t0, T0 + 20);
  assert.equal(next.billboards.header.form, 'delta');
  assert.deepEqual(await c.prefetchNext(w, TILE, { ...AT, t: T0 + 15 }), [], 'a held keyframe is not fetched again');
});

test('tiles around a point; errors carry the server code', async () => {
  const layer = world.layers.find((l) => l.name === TILE.layer);
  const size = 256 * layer.cell_size;
  const around = tilesAround(world, TILE.layer, 0, 10, 10, 20);
  assert.deepEqual(around.map((t) => [t.x, t.y]), [[-1, -1], [0, -1], [-1, 0], [0, 0]]);
  assert.equal(around[3].size, size);
  await assert.rejects(client.fetch('/v1/worlds/no-such-world'), (e) => e instanceof CloudscapeError && e.status === 404 && e.code.length > 0);
});

test('billboards.bin version 1 still decodes', () => {
  // One record, built by hand from the version-1 layout.
  const buf = new ArrayBuffer(64 + 36);
  const v = new DataView(buf);
  [67, 83, 66, 66].forEach((b, i) => v.setUint8(i, b));
  v.setUint16(4, 1, true);
  v.setUint16(6, 36, true);
  v.setUint32(8, 1, true);
  v.setUint32(12, 2, true);
  v.setBigInt64(16, -3n, true);
  v.setBigInt64(24, 4n, true);
  v.setFloat64(32, 1000, true);
  v.setFloat64(40, 2000, true);
  v.setUint16(56, 64, true);
  v.setFloat32(64, 10, true);
  v.setFloat32(68, 20, true);
  v.setFloat32(72, 1500, true);
  v.setFloat32(76, 80, true);
  v.setUint16(80, 31, true);
  v.setUint8(82, 128);
  v.setUint8(83, 255);
  [0.5, 0.6, 0.7].forEach((c, i) => v.setFloat32(84 + 4 * i, c, true));
  v.setFloat32(96, 1.5, true);
  const tile = decodeBillboards(buf);
  assert.equal(tile.header.version, 1);
  assert.deepEqual(tile.header.tile, { z: 2, x: -3, y: 4 });
  assert.equal(tile.header.lighting, null);
  const f = billboardsAt(tile, 123);
  assert.deepEqual([...f.position], [1010, 2020, 1500]);
  assert.equal(f.splat[0], 31);
  assert.ok(Math.abs(f.splatTau[0] - splatTauOf(31, 64)) < 1e-6);
  assert.ok(Math.abs(f.colour[1] - 0.6) < 1e-6);
  assert.equal(f.tauSun[0], 1.5);
  assert.throws(() => decodeBillboards(buf.slice(0, 90)), /bytes for 1 records/);
  assert.equal(halfToFloat(0x3c00), 1);
  assert.equal(halfToFloat(0xc000), -2);
});

test('the server serves this module and its types', async () => {
  for (const [path, file, type] of [
    ['/client/cloudscape.js', '../cloudscape.js', /^text\/javascript/],
    ['/client/index.d.ts', '../index.d.ts', /^text\/plain/],
  ]) {
    const res = await fetch(`${base}${path}`);
    assert.equal(res.status, 200, path);
    assert.match(res.headers.get('Content-Type'), type);
    assert.equal(await res.text(), readFileSync(new URL(file, import.meta.url), 'utf8'), `${path} is ${file}`);
  }
});
