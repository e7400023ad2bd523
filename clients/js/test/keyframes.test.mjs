// billboards.bin version 3 in the JS client against a real `cloudscape serve` (started
// by tests/ext/js_client.sh, which passes its address in CLOUDSCAPE_URL): the
// self-contained form against the server's billboards.json, the delta form against
// the next keyframe's self-contained form, the fetch policy (a tile's first keyframe
// self-contained, every later one a delta), and malformed bytes refused with an Error.

import assert from 'node:assert/strict';
import { before, test } from 'node:test';

import { CloudscapeClient, HeldKeyframes, decodeBillboards, keyframeOf, worldClock } from '../cloudscape.js';

const base = process.env.CLOUDSCAPE_URL;
if (!base) throw new Error('set CLOUDSCAPE_URL to a running cloudscape server');

// Level 0 of the overcast world's stratocumulus (20 s spans): a deck over most columns.
const WORLD = 'overcast';
const TILE = { layer: 'stratocumulus', z: 0, x: 0, y: 0 };
const T0 = 43200;
const AT = { t: T0, quality: 'fast', sun: [180, 60] };

let client;
let world;
/** Raw bytes of a tile product at keyframe t0 (`AT` otherwise). */
const bytes = (product, t0, tile = TILE, at = AT) => client.tile(world, tile, product, { ...at, t: t0 });

before(async () => {
  client = new CloudscapeClient(base, { quality: 'fast' });
  world = await client.world(WORLD);
});

/** Asserts that two decoded keyframes hold the same records and the same end states, value for value. */
function assertSameKeyframe(a, b, what) {
  assert.equal(a.count, b.count, `${what}: count`);
  for (const key of Object.keys(a.records)) {
    assert.deepEqual(a.records[key], b.records[key], `${what}: records.${key}`);
  }
  assert.deepEqual(a.lattice.end, b.lattice.end, `${what}: lattice end states`);
  for (const key of ['t0', 't1', 'origin', 'sun', 'splatCount', 'lighting', 'algorithmVersion']) {
    assert.deepEqual(a.header[key], b.header[key], `${what}: header.${key}`);
  }
}

test('billboards.bin version 3 decodes to what billboards.json says, within the quantisation steps', async () => {
  const bin = decodeBillboards(await bytes('billboards.bin', T0));
  const json = await client.json(client.tilePath(world, TILE, 'billboards.json', AT));
  const h = bin.header;
  assert.equal(h.version, 3);
  assert.equal(h.form, 'self-contained');
  assert.ok(bin.count > 1000, `${bin.count} billboards`);
  assert.equal(bin.count, json.count);
  assert.deepEqual([h.t0, h.t1], [json.keyframe.t0, json.keyframe.t1]);
  assert.deepEqual(h.origin, json.origin);
  assert.equal(h.algorithmVersion, json.algorithm_version);
  assert.equal(h.splatCount, json.splats.count);
  const q = bin.lattice.quantisation;
  // Colour: steps of (c / 2)^(1/2.2) of 1 / (2^bits − 1); τ_sun: steps of 1/m e-folds.
  const levels = 2 ** q.colourBits - 1;
  // Since ALGORITHM_VERSION 13 the codes are even steps of the displayed value at the
  // tone map's exposure 3 (docs/formats.md "Codes"), so the decoded colour is within
  // half a step of the shaded one on that scale.
  assert.ok(h.algorithmVersion >= 13, `algorithm version ${h.algorithmVersion}`);
  const gamma = (c) => (1 - Math.exp(-3 * Math.min(Math.max(c, 0), 2))) ** (1 / 2.2);
  // Since ALGORITHM_VERSION 15 the codes carry the ambient part (the colour less its
  // sun term albedo · sunRgb / 4 · Σ bⁱ e^{−aⁱ τ_sun}, docs/formats.md "Codes"): that
  // part is within half a step of the shaded colour's. The sun term, written out from
  // the header:
  assert.ok(h.algorithmVersion >= 15, `algorithm version ${h.algorithmVersion}`);
  const L = h.lighting;
  const sunOf = (tau, c) => {
    let sum = 0;
    for (let i = 0; i < L.octaves.count; i++) sum += L.octaves.b ** i * Math.exp(-(L.octaves.a ** i) * tau);
    return (L.albedo * L.sunRgb[c] / 4) * sum;
  };
  const r = bin.records;
  let worstColour = 0;
  let worstTau = 0;
  for (let i = 0; i < bin.count; i++) {
    const j = json.billboards[i];
    // Positions: the lattice's, to f32 precision (offsets from the origin are f32).
    for (let c = 0; c < 2; c++) {
      const at = h.origin[c] + r.offset[3 * i + c];
      assert.ok(Math.abs(at - j.position[c]) <= 4e-7 * Math.abs(j.position[c] - h.origin[c]) + 1e-6, `position ${c} of ${i}: ${at} vs ${j.position[c]}`);
    }
    assert.equal(r.offset[3 * i + 2], Math.fround(j.position[2]), `altitude of ${i}`);
    assert.equal(r.radius[i], Math.fround(j.radius));
    assert.equal(r.velocity[2 * i], Math.fround(j.velocity[0]));
    ['start', 'end'].forEach((e, k) => {
      const m = 2 * i + k;
      assert.equal(r.splat[m], j[e].splat, `${e} splat of ${i}`);
      assert.equal(r.splatTau[m], Math.fround(j[e].splat_tau), `${e} splat_tau of ${i}`);
      assert.ok(Math.abs(r.opacity[m] - j[e].opacity) <= 0.5 / 255 + 1e-6, `${e} opacity of ${i}`);
      for (let c = 0; c < 3; c++) {
        const got = r.colour[6 * i + 3 * k + c];
        if (got >= 2) continue;
        const [sun, sunQ] = [sunOf(j[e].tau_sun, c), sunOf(r.tauSun[m], c)];
        const ambient = Math.max(j[e].colour[c] - sun, 0);
        worstColour = Math.max(worstColour, Math.abs(gamma(got - sunQ) - gamma(ambient)) - 1e-5);
      }
      const tau = Math.max(j[e].tau_sun, q.tauFloor);
      worstTau = Math.max(worstTau, Math.abs(Math.log(r.tauSun[m] / tau)));
    });
  }
  assert.ok(worstColour <= 0.5 / levels + 1e-6, `ambient off by ${worstColour} in display steps of ${1 / levels}`);
  assert.ok(worstTau <= 0.5 / q.tauSunSteps + 1e-6, `tau_sun off by ${worstTau} e-folds, steps of ${1 / q.tauSunSteps}`);
});

test('a delta decoded on the previous keyframe is the next keyframe\'s self-contained form, keyframe after keyframe', async () => {
  let held = decodeBillboards(await bytes('billboards.bin', T0));
  for (let k = 1; k <= 3; k++) {
    const t0 = T0 + 20 * k;
    const delta = await bytes('billboards.delta.bin', t0);
    const whole = await bytes('billboards.bin', t0);
    const fromDelta = decodeBillboards(delta, held);
    const alone = decodeBillboards(whole);
    assert.equal(fromDelta.header.form, 'delta');
    assert.equal(alone.header.form, 'self-contained');
    assertSameKeyframe(fromDelta, alone, `keyframe ${t0}`);
    assert.ok(delta.byteLength < whole.byteLength, `the delta (${delta.byteLength} bytes) codes less than the whole keyframe (${whole.byteLength})`);
    held = fromDelta;
  }
});

test('a delta without its previous keyframe, or on another, is refused', async () => {
  const delta = await bytes('billboards.delta.bin', T0 + 20);
  const next = decodeBillboards(await bytes('billboards.bin', T0 + 20));
  const neighbour = decodeBillboards(await bytes('billboards.bin', T0, { ...TILE, x: 1 }));
  const otherSun = decodeBillboards(await bytes('billboards.bin', T0, TILE, { ...AT, sun: [90, 30] }));
  const v2 = decodeBillboards(await bytes('billboards.v2.bin', T0));
  assert.throws(() => decodeBillboards(delta), /needs the previous keyframe/);
  for (const [other, what] of [[next, 'the keyframe itself'], [neighbour, 'the next tile'], [otherSun, 'another sun'], [v2, 'version 2'], [{}, 'not a keyframe']]) {
    assert.throws(() => decodeBillboards(delta, other), /follows keyframe/, what);
  }
  // A self-contained keyframe needs nothing and ignores what it is given.
  assertSameKeyframe(decodeBillboards(await bytes('billboards.bin', T0 + 20), neighbour), next, 'self-contained');
});

/** Asserts that decoding throws a plain Error naming billboards.bin (not a TypeError, RangeError, …). */
function refused(buffer, previous, what) {
  let result;
  try {
    result = decodeBillboards(buffer, previous);
  } catch (e) {
    assert.equal(e.constructor, Error, `${what}: ${e.constructor.name}: ${e.message}`);
    assert.match(e.message, /^billboards\.bin/, what);
    return e;
  }
  assert.fail(`${what}: decoded ${result.count} billboards`);
}

test('every truncation of a keyframe, self-contained or delta, is refused with an Error', async () => {
  const whole = new Uint8Array(await bytes('billboards.bin', T0));
  const previous = decodeBillboards(whole);
  const delta = new Uint8Array(await bytes('billboards.delta.bin', T0 + 20));
  for (const [b, prev, name] of [[whole, null, 'self-contained'], [delta, previous, 'delta']]) {
    for (let n = 0; n < b.length; n++) refused(b.subarray(0, n), prev, `${name} cut to ${n} of ${b.length} bytes`);
    // One byte too many is as wrong as one too few.
    const longer = new Uint8Array(b.length + 1);
    longer.set(b);
    refused(longer, prev, `${name} with a byte more`);
  }
});

/** A seeded generator (mulberry32): the same damage every run. */
function random(seed) {
  return () => {
    seed = (seed + 0x6d2b79f5) | 0;
    let t = Math.imul(seed ^ (seed >>> 15), 1 | seed);
    t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t;
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

test('damaged keyframes decode or are refused with an Error, never anything else', async () => {
  const whole = new Uint8Array(await bytes('billboards.bin', T0));
  const previous = decodeBillboards(whole);
  const delta = new Uint8Array(await bytes('billboards.delta.bin', T0 + 20));
  const rnd = random(38);
  let refusedCount = 0;
  let decoded = 0;
  for (const [b, prev] of [[whole, null], [delta, previous]]) {
    const header = new DataView(b.buffer, b.byteOffset).getUint32(8, true);
    for (let trial = 0; trial < 300; trial++) {
      const damaged = b.slice();
      const hits = 1 + Math.floor(rnd() * 4);
      for (let h = 0; h < hits; h++) {
        // Half the damage in the header and tables, where sizes are.
        const at = rnd() < 0.5 ? Math.floor(rnd() * header) : Math.floor(rnd() * b.length);
        damaged[at] = Math.floor(rnd() * 256);
      }
      try {
        const k = decodeBillboards(damaged, prev);
        assert.equal(k.records.splat.length, 2 * k.count);
        decoded++;
      } catch (e) {
        assert.equal(e.constructor, Error, `trial ${trial}: ${e.constructor.name}: ${e.message}`);
        assert.match(e.message, /^billboards\.bin/);
        refusedCount++;
      }
    }
  }
  assert.ok(refusedCount > 100 && decoded > 0, `${refusedCount} refused, ${decoded} decoded`);
});

test('impossible header extents are refused before anything is allocated', async () => {
  const whole = new Uint8Array(await bytes('billboards.bin', T0));
  const edit = (f) => {
    const b = whole.slice();
    f(new DataView(b.buffer));
    return b;
  };
  const level = 200; // the first level record
  const cases = [
    ['a level with 2^32 − 1 rows', (v) => v.setUint32(level + 56, 0xffffffff, true), /impossible extent/],
    ['a run of 2^32 − 1 columns', (v) => v.setUint32(level + 68, 0xffffffff, true), /impossible extent/],
    ['a first row past 2^52', (v) => v.setBigInt64(level + 48, 2n ** 60n, true), /impossible extent/],
    ['a shift past 2^52', (v) => v.setBigInt64(level + 32, -(2n ** 62n), true), /impossible extent/],
    ['4096 × 4096 sites', (v) => {
      v.setUint32(level + 56, 4096, true);
      v.setUint32(level + 68, 4096, true);
      v.setUint32(level + 80, 4096, true);
    }, /more than \d+ sites/],
    ['runs far apart (a box of sparse sites)', (v) => v.setBigInt64(level + 72, v.getBigInt64(level + 72, true) + 3000n, true), /plane|billboards decoded/],
    ['runs too far apart for the box', (v) => v.setBigInt64(level + 72, 1000000n, true), /more than \d+ sites/],
    ['300 levels', (v) => v.setUint16(190, 300, true), /levels/],
    ['13 planes', (v) => v.setUint16(196, 13, true), /planes/],
    ['a header size that is not its tables\'', (v) => v.setUint32(8, 1 << 30, true), /header says/],
    ['a plane longer than the file', (v) => v.setUint32(200 + 88 * v.getUint16(190, true), 0xffffffff, true), /header says/],
    ['0 colour bits', (v) => v.setUint8(188, 0), /quantisation/],
    ['form 7', (v) => v.setUint16(6, 7, true), /unknown form/],
    ['version 4', (v) => v.setUint16(4, 4, true), /unknown version/],
    ['more billboards than decoded', (v) => v.setUint32(156, v.getUint32(156, true) + 1, true), /header says/],
  ];
  for (const [what, f, message] of cases) {
    const e = refused(edit(f), null, what);
    assert.match(e.message, message, what);
  }
});

test('the client fetches a tile\'s first keyframe whole and every later one as a delta on the one it holds', async () => {
  const asked = [];
  const c = new CloudscapeClient(base, {
    quality: 'fast',
    fetch: (url, init) => {
      asked.push(url.slice(base.length));
      return fetch(url, init);
    },
  });
  const w = await c.world(WORLD);
  asked.length = 0;
  const path = (product, t) => `/v1/worlds/${WORLD}/tiles/0/0/0/${product}?t=${t}&quality=fast&sun=180,60&layer=stratocumulus`;
  const k0 = await c.keyframe(w, TILE, { ...AT, t: T0 + 5 });
  const k1 = await c.keyframe(w, TILE, { ...AT, t: T0 + 25 });
  const k2 = await c.keyframe(w, TILE, { ...AT, t: T0 + 45 });
  assert.deepEqual(asked, [path('billboards.bin', T0), path('billboards.delta.bin', T0 + 20), path('billboards.delta.bin', T0 + 40)]);
  assert.equal(k0.header.form, 'self-contained');
  assert.equal(k2.header.form, 'delta');
  assertSameKeyframe(k1, decodeBillboards(await bytes('billboards.bin', T0 + 20)), 'the second keyframe');
  // Held: asked again, no request; concurrent asks share one request.
  assert.equal(await c.keyframe(w, TILE, { ...AT, t: T0 + 41 }), k2);
  const [a, b] = await Promise.all([c.keyframe(w, TILE, { ...AT, t: T0 + 61 }), c.keyframe(w, TILE, { ...AT, t: T0 + 62 })]);
  assert.equal(a, b);
  assert.equal(asked.length, 4);
  // A keyframe that does not follow a held one (a jump in time) is fetched whole.
  await c.keyframe(w, TILE, { ...AT, t: T0 + 200 });
  assert.equal(asked.at(-1), path('billboards.bin', T0 + 200));
  // Bytes are not kept beside what is held decoded.
  assert.equal(c.holds(path('billboards.delta.bin', T0 + 20)), false);
});

test('held keyframes are bounded per tile variant and in variants', () => {
  const keyframe = (t0) => ({ header: { t0, t1: t0 + 20 } });
  const held = new HeldKeyframes({ maxVariants: 2, perVariant: 3 });
  for (let k = 0; k < 5; k++) held.insert('a', 20 * k, keyframe(20 * k));
  assert.equal(held.size, 3, 'the earliest of a variant go first');
  assert.equal(held.get('a', 0), null);
  assert.equal(held.get('a', 80).header.t0, 80);
  assert.equal(held.endingAt('a', 100).header.t0, 80, 'the keyframe a delta at 100 is coded on');
  assert.equal(held.endingAt('a', 110), null);
  held.insert('b', 0, keyframe(0));
  held.insert('c', 0, keyframe(0));
  assert.equal(held.get('a', 80), null, 'the least recently stored variant goes');
  assert.ok(held.get('c', 0));
});

test('the world clock is read from discovery and followed', async () => {
  assert.ok(world.clock && world.clock.rate > 0, JSON.stringify(world.clock));
  // The default clock is Unix time (offset 0, rate 1): discovery's `now` is this machine's.
  const now = worldClock(world)();
  assert.ok(Math.abs(now - (world.clock.offset + world.clock.rate * (Date.now() / 1000))) < 60, `clock ${now}`);
  const clock = worldClock({ clock: { offset: 0, rate: 12, now: 1000 }, max_time: 1e12 }, { readAt: 5000 });
  assert.equal(clock(5000), 1000);
  assert.equal(clock(15000), 1120, 'rate 12: two minutes of world time in ten seconds');
  assert.equal(worldClock({ clock: { offset: 0, rate: 1, now: 1000 }, max_time: 1e12 }, { rate: 60, readAt: 0 })(1000), 1060, 'a faster rate given');
  assert.equal(worldClock({ clock: { offset: 0, rate: 1, now: 1e12 - 1 }, max_time: 1e12 }, { readAt: 0 })(1e6), 1e12, 'clamped to max_time');
  const k = keyframeOf(world.layers[0], 0, now, world.max_time);
  assert.ok(k.t0 <= now && now < k.t1);
});

test('asked for the next keyframe while the current one is on its way, the client waits for it and fetches a delta', async () => {
  const asked = [];
  const c = new CloudscapeClient(base, {
    quality: 'fast',
    fetch: (url, init) => {
      asked.push(url.slice(base.length));
      return fetch(url, init);
    },
  });
  const w = await c.world(WORLD);
  asked.length = 0;
  const at = { ...AT, t: T0 + 100 + 16 };
  const [current, next] = await Promise.all([c.keyframe(w, TILE, at), c.keyframe(w, TILE, { ...at, next: true })]);
  assert.deepEqual(asked.map((u) => u.split('?')[0].split('/').pop()), ['billboards.bin', 'billboards.delta.bin']);
  assert.equal(next.header.t0, current.header.t1);
  assert.equal(next.header.form, 'delta');
});
