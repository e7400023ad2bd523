// The ground shadow the JS client derives from billboards (deriveShadow, shadowMaps,
// the rule of docs/formats.md "Ground shadow" and crates/cloudscape-core/src/view/held.rs)
// against a real `cloudscape serve` (CLOUDSCAPE_URL, as tests/ext/js_client.sh sets it):
// a single ball worked out by hand, the tiles of a real deck against the server's own
// coverage.png and shadow.png, and the sun below the horizon.

import assert from 'node:assert/strict';
import { before, test } from 'node:test';

import {
  CloudscapeClient,
  LAYERS_ABOVE_SKY_DEPTH,
  LAYERS_ABOVE_SUN_DEPTH,
  TILE_COLUMNS,
  beneathLayers,
  decodeBillboards,
  decodeCoverage,
  decodeShadow,
  deriveShadow,
  lightBeneathLayers,
  lineIntegral,
  shadowAtPoint,
  shadowMaps,
  splatProfile,
} from '../cloudscape.js';

const base = process.env.CLOUDSCAPE_URL;
if (!base) throw new Error('set CLOUDSCAPE_URL to a running cloudscape server');

const WORLD = 'overcast';
const LAYER = 'stratocumulus';
const T0 = 43200;
const n = TILE_COLUMNS;
const mean = (a) => a.reduce((s, v) => s + v, 0) / a.length;

let client;
let world;
let layer;
before(async () => {
  client = new CloudscapeClient(base, { quality: 'fast' });
  world = await client.world(WORLD);
  layer = world.layers.find((l) => l.name === LAYER);
});

/** The held tiles (x, y) of level 0 around (0, 0), as a client drawing them holds them. */
async function heldAround(sun, radius = 1) {
  const held = [];
  for (let y = -radius; y <= radius; y++) {
    for (let x = -radius; x <= radius; x++) {
      const tile = { layer: LAYER, z: 0, x, y };
      const keyframe = decodeBillboards(await client.tile(world, tile, 'billboards.bin', { t: T0, quality: 'fast', sun }));
      held.push({ layer: LAYER, base: layer.base, keyframe, x, y });
    }
  }
  return held;
}

/** Wyvill's field function, f(r) = −4/9 r⁶ + 17/9 r⁴ − 22/9 r² + 1 for r ≤ 1. */
const wyvill = (r) => (r >= 1 ? 0 : 1 - (22 / 9) * r ** 2 + (17 / 9) * r ** 4 - (4 / 9) * r ** 6);

/** S(p) by Simpson's rule along the chord: independent of the closed form the client uses. */
function chordIntegral(p) {
  const half = Math.sqrt(Math.max(1 - p * p, 0));
  const steps = 2000;
  const h = (2 * half) / steps;
  let sum = 0;
  for (let i = 0; i <= steps; i++) {
    const v = -half + i * h;
    sum += (i === 0 || i === steps ? 1 : i % 2 ? 4 : 2) * wyvill(Math.hypot(p, v));
  }
  return (sum * h) / 3;
}

/** A decoded keyframe of one ball, built by hand (the columns decodeBillboards gives). */
function oneBall({ x, y, z, radius, tau, sun, span = 20, velocity = [0, 0] }) {
  const column = 100;
  return {
    header: { version: 3, form: 'self-contained', origin: [0, 0], size: n * column, sun: { azimuthDeg: sun[0], elevationDeg: sun[1] }, t0: 0, t1: span, splatCount: 64 },
    count: 1,
    records: {
      offset: Float32Array.of(x, y, z),
      radius: Float32Array.of(radius),
      velocity: Float32Array.of(...velocity),
      splatTau: Float32Array.of(tau, tau),
      splat: Uint16Array.of(0, 0),
      colour: new Float32Array(6),
      tauSun: new Float32Array(2),
      opacity: new Float32Array(2),
      sunTransmittance: new Float32Array(2),
    },
    lattice: null,
  };
}

test('the splat profile is the line integral of Wyvill\'s function, normalised', () => {
  const s0 = chordIntegral(0);
  for (const p of [0, 0.25, 0.5, 0.8, 0.99]) {
    assert.ok(Math.abs(lineIntegral(p) - chordIntegral(p)) < 1e-9, `S(${p})`);
    assert.ok(Math.abs(splatProfile(p * p) - chordIntegral(p) / s0) < 1e-6, `P(${p}²)`);
  }
  assert.equal(splatProfile(1), 0);
  assert.equal(splatProfile(4), 0);
});

test('one ball under a high sun: exp(−τ P(q)) at each column centre, worked out by hand', () => {
  // A ball 500 m above the base, centred over column (100, 60)'s centre, the sun straight
  // overhead: its shadow on the base is the ball's own disc.
  const baseAlt = 1000;
  const tau = 2;
  const radius = 450;
  const ball = oneBall({ x: 100.5 * 100, y: 60.5 * 100, z: baseAlt + 500, radius, tau, sun: [0, 90], velocity: [10, 0] });
  const maps = deriveShadow({ layer: 0, base: baseAlt, keyframe: ball }, [{ keyframe: ball }]);
  const s0 = chordIntegral(0);
  const at = (m, col, row) => m[row * n + col];
  assert.ok(Math.abs(at(maps.t0, 100, 60) - Math.exp(-tau)) < 1e-6, 'under the centre: e^−τ');
  // Two columns east: 200 m off, p = 200 / 450.
  assert.ok(Math.abs(at(maps.t0, 102, 60) - Math.exp((-tau * chordIntegral(200 / 450)) / s0)) < 1e-5, 'p = 200/450');
  // Three columns north, one east: p = √10 · 100 / 450.
  assert.ok(Math.abs(at(maps.t0, 101, 63) - Math.exp((-tau * chordIntegral(Math.sqrt(10) * 100 / 450)) / s0)) < 1e-5);
  assert.equal(at(maps.t0, 105, 60), 1, 'beyond the radius: no shadow');
  // At t1 the ball has moved with its wind, 10 m/s for 20 s: two columns east.
  assert.ok(Math.abs(at(maps.t1, 102, 60) - Math.exp(-tau)) < 1e-6);
  assert.ok(maps.t0.every((v) => v > 0 && v <= 1) && maps.t1.every((v) => v > 0 && v <= 1));
});

test('a ball under a deck is lit through it: the sun term at τ_sun + τ_a, sky and ground light dimmed by the vertical depth given (docs/formats.md "Layers above")', () => {
  const lighting = {
    sunRgb: [1, 0.9, 0.8],
    albedo: 0.9,
    phase: { g1: 0.8, g2: -0.3, mix: 0.8 },
    octaves: { count: 3, a: 0.5, b: 0.75, c: 0.5 },
  };
  const iso = (tau) => Math.exp(-tau) + 0.75 * Math.exp(-tau / 2) + 0.5625 * Math.exp(-tau / 4);
  const meanCos = 0.8 * 0.8 + 0.2 * -0.3;
  const k = Math.sqrt(3 * 0.1 * (1 - 0.9 * meanCos));
  const ambient = [0.05, 0.06, 0.08];
  const rgb = [0, 1, 2].map((i) => 0.9 * (0.25 * lighting.sunRgb[i] * iso(1) + ambient[i]));
  // Nothing above: unchanged.
  assert.deepEqual(beneathLayers(lighting, rgb, 1, 0, 0), { rgb, tauSun: 1 });
  const lit = beneathLayers(lighting, rgb, 1, 2, 1.5);
  assert.equal(lit.tauSun, 3);
  for (let i = 0; i < 3; i++) {
    const expected = 0.9 * (0.25 * lighting.sunRgb[i] * iso(3) + ambient[i] * Math.exp(-k * 1.5));
    assert.ok(Math.abs(lit.rgb[i] - expected) < 1e-9, `channel ${i}: ${lit.rgb[i]} vs ${expected}`);
  }
  // A ball of a lower layer under a deck whose maps are uniformly e^−3 (sun overhead):
  // each end takes τ_a = 3 at the LAYERS_ABOVE_* shares; a ball above the deck's base, or of
  // the deck's own layer, is left alone.
  const low = oneBall({ x: 12800, y: 12800, z: 1500, radius: 300, tau: 1, sun: [0, 90] });
  low.header.lighting = lighting;
  low.records.colour.set([...rgb, ...rgb]);
  low.records.tauSun.set([1, 1]);
  const deck = oneBall({ x: 12800, y: 12800, z: 3300, radius: 300, tau: 1, sun: [0, 90] });
  const maps = { t0: new Float32Array(n * n).fill(Math.exp(-3)), t1: new Float32Array(n * n).fill(Math.exp(-3)) };
  const out = lightBeneathLayers({ layer: 0, keyframe: low }, [{ layer: 1, base: 3000, keyframe: deck, maps }]);
  const want = beneathLayers(lighting, rgb, 1, LAYERS_ABOVE_SUN_DEPTH * 3, LAYERS_ABOVE_SKY_DEPTH * 3);
  for (let e = 0; e < 2; e++) {
    assert.ok(Math.abs(out.tauSun[e] - want.tauSun) < 1e-5, `end ${e}: τ_sun ${out.tauSun[e]}`);
    for (let i = 0; i < 3; i++) assert.ok(Math.abs(out.colour[3 * e + i] - want.rgb[i]) < 1e-5, `end ${e} channel ${i}`);
  }
  const same = lightBeneathLayers({ layer: 1, keyframe: low }, [{ layer: 1, base: 3000, keyframe: deck, maps }]);
  assert.deepEqual([...same.tauSun], [1, 1]);
  const high = lightBeneathLayers({ layer: 0, keyframe: low }, [{ layer: 1, base: 1000, keyframe: deck, maps }]);
  assert.deepEqual([...high.tauSun], [1, 1]);
});

test('one ball under a low sun: the shadow falls away from the sun, stretched along it, where the ground reads it', () => {
  const baseAlt = 1000;
  const sun = [90, 30]; // toward the east, 30° up
  const e = (30 * Math.PI) / 180;
  const ball = oneBall({ x: 128.5 * 100, y: 128.5 * 100, z: baseAlt + 1000, radius: 400, tau: 3, sun });
  const maps = deriveShadow({ layer: 0, base: baseAlt, keyframe: ball }, [{ keyframe: ball }]);
  // The sun ray through the centre crosses the base 1000 m / tan 30° west of it.
  const westward = 1000 / Math.tan(e);
  let darkest = 0;
  for (let i = 1; i < n * n; i++) if (maps.t0[i] < maps.t0[darkest]) darkest = i;
  const [col, row] = [darkest % n, Math.floor(darkest / n)];
  assert.equal(row, 128);
  assert.ok(Math.abs((col + 0.5) * 100 - (128.5 * 100 - westward)) <= 50, `darkest column ${col}`);
  // Longer along the sun (r / sin 30°, twice) than across it (r).
  const extent = (dx, dy) => {
    let k = 1;
    while (maps.t0[(row + k * dy) * n + col + k * dx] < 1) k++;
    return k;
  };
  assert.ok(extent(1, 0) > 1.6 * extent(0, 1), `along ${extent(1, 0)} columns, across ${extent(0, 1)}`);
  // The ground point under the ball's shadow reads the darkest texel: shifted toward
  // the sun by base / tan(elevation) before the lookup.
  const groundX = 128.5 * 100 - (baseAlt + 1000) / Math.tan(e);
  const t = shadowAtPoint(maps, ball, baseAlt, groundX, 128.5 * 100, 0);
  assert.ok(Math.abs(t - maps.t0[darkest]) < 0.02, `ground reads ${t}, darkest ${maps.t0[darkest]}`);
});

test('with the sun below the horizon the ground is lit everywhere', async () => {
  const held = await heldAround([180, -10], 0);
  assert.ok(held[0].keyframe.header.sun.elevationDeg < 0, JSON.stringify(held[0].keyframe.header.sun));
  assert.ok(held[0].keyframe.count > 0);
  const [maps] = shadowMaps(held);
  assert.ok(maps.t0.every((v) => v === 1) && maps.t1.every((v) => v === 1));
});

test('a real deck: transmittance in [0, 1], darker under denser columns (coverage.png), close to the server\'s shadow.png', async () => {
  // The sun at the zenith: a column's shadow is cast by the cloud right above it.
  const held = await heldAround([180, 90]);
  const maps = shadowMaps(held);
  const centre = maps[held.findIndex((h) => h.x === 0 && h.y === 0)];
  for (const m of maps) assert.ok(m.t0.every((v) => v >= 0 && v <= 1) && m.t1.every((v) => v >= 0 && v <= 1));
  const at = { t: T0, quality: 'fast', sun: [180, 90] };
  const tile = { layer: LAYER, z: 0, x: 0, y: 0 };
  const coverage = await decodeCoverage(await client.tile(world, tile, 'coverage.png', at));
  const served = await decodeShadow(await client.tile(world, tile, 'shadow.png', at));
  const dense = [];
  const clear = [];
  let off = 0;
  for (let row = 0; row < n; row++) {
    for (let col = 0; col < n; col++) {
      // The derived maps' row 0 is south; the PNGs' row 0 is north.
      const v = centre.t0[row * n + col];
      const png = (n - 1 - row) * n + col;
      if (coverage.opacity[png] >= 0.5) dense.push(v);
      else if (coverage.opacity[png] === 0) clear.push(v);
      off += Math.abs(v - served.t0[png]);
    }
  }
  assert.ok(dense.length > 1000 && clear.length > 1000, `${dense.length} dense, ${clear.length} clear columns`);
  assert.ok(mean(dense) < 0.5 * mean(clear), `mean transmittance ${mean(dense).toFixed(3)} under dense columns, ${mean(clear).toFixed(3)} under clear ones`);
  // shadow.png is built from the full-precision balls of a halo around the tile; the
  // derived map from the quantised balls of the 3 × 3 held tiles.
  assert.ok(off / (n * n) < 0.03, `mean |derived − shadow.png| ${(off / (n * n)).toFixed(4)}`);
  // Both ends hold a shadow, and they differ (the deck moves in 20 s).
  assert.ok(centre.t0.some((v, i) => v !== centre.t1[i]));
});

test('a tile\'s shadow is cast by the held tiles of its layer: a neighbour adds to it near the edge only', async () => {
  const sun = [90, 20];
  const held = await heldAround(sun);
  const centre = held.find((h) => h.x === 0 && h.y === 0);
  const alone = deriveShadow(centre, [centre]);
  const [withAll] = shadowMaps([centre, ...held.filter((h) => h !== centre)]);
  // The sun low in the east: the eastern neighbour's balls shadow the tile's eastern edge.
  let eastern = 0;
  let western = 0;
  for (let row = 0; row < n; row++) {
    for (let col = 0; col < n; col++) {
      const d = alone.t0[row * n + col] - withAll.t0[row * n + col];
      assert.ok(d >= -1e-7, 'a neighbour never lightens');
      if (col >= n - 16) eastern += d;
      if (col < 16) western += d;
    }
  }
  assert.ok(eastern > 10 * Math.max(western, 1e-9), `darkened by ${eastern.toFixed(2)} along the eastern edge, ${western.toFixed(4)} along the western`);
});
