// The level choice of a view (planTiles, crates/cloudscape-core/src/render/scene.rs
// plan_bands) on the default world of a real `cloudscape serve` (CLOUDSCAPE_URL, as
// tests/ext/js_client.sh sets it): the cases scene.rs's own test holds the Rust plan
// to, so the two plans answer alike.

import assert from 'node:assert/strict';
import { before, test } from 'node:test';

import { CloudscapeClient, planTiles, VIEW_DISTANCE } from '../cloudscape.js';

const base = process.env.CLOUDSCAPE_URL;
if (!base) throw new Error('set CLOUDSCAPE_URL to a running cloudscape server');

let world;
before(async () => {
  world = await new CloudscapeClient(base).world('default');
});

/** The unit vector toward a sun at azimuth `az`, elevation `el` (degrees). */
const toward = (az, el) => {
  const [a, e] = [(az * Math.PI) / 180, (el * Math.PI) / 180];
  return [Math.sin(a) * Math.cos(e), Math.cos(a) * Math.cos(e), Math.sin(e)];
};
const camera = (s) => {
  const [x, y, z, yaw, pitch, fov] = s.split(',').map(Number);
  return { x, y, z, yaw, pitch, fov };
};
const names = (tiles) => tiles.map((t) => `${t.layer}/${t.z}/${t.x}/${t.y}`);

test('the plan takes the tiles whose shadows fall in view', async () => {
  // The viewer's default view with a western sun at 28° (scene.rs
  // plan_takes_the_tiles_whose_shadows_fall_in_view): the cirrus tile south-west of
  // the eye is out of view, its shadow ahead. 275° 28° is its bucket's centre.
  const cam = camera('12800,-6000,900,0,6,75');
  const withSun = names(planTiles(world, cam, 1280, 720, { quality: 'fast', sun: toward(275, 28) }));
  const straightDown = names(planTiles(world, cam, 1280, 720, { quality: 'fast' }));
  assert.ok(withSun.includes('cirrus/0/-1/-1'), withSun.join(' '));
  assert.ok(!straightDown.includes('cirrus/0/-1/-1'), straightDown.join(' '));
  assert.ok(straightDown.every((t) => withSun.includes(t)), 'knowing the sun only adds tiles');
  // A sun at the horizon throws shadows at most the view distance far.
  const sunset = planTiles(world, camera('12800,12800,300,270,6,75'), 640, 360, { quality: 'balanced', sun: toward(270, 2) });
  assert.ok(sunset.length <= 24, `${sunset.length} tiles`);
});

test('the plan is sorted by layer, level, row and column, and bounded', async () => {
  const tiles = planTiles(world, camera('1000,1000,500,0,20,60'), 256, 128, { quality: 'balanced' });
  assert.ok(tiles.length > 0);
  const key = (t) => [t.layerIndex, t.z, t.y, t.x];
  for (let i = 1; i < tiles.length; i++) {
    const [a, b] = [key(tiles[i - 1]), key(tiles[i])];
    const j = a.findIndex((v, k) => v !== b[k]);
    assert.ok(j >= 0 && a[j] < b[j], `${a} before ${b}`);
  }
  // Looking north: no tile lies wholly south of the camera (scene.rs plan_sees_tiles_in_front_and_bounds_work).
  assert.ok(tiles.every((t) => t.origin[1] + t.size > 1000));
  // Past 64 × maxTiles tiles under way (here a budget smaller than one split): null,
  // as `cloudscape render` refuses such a view.
  assert.equal(planTiles(world, camera('1000,1000,500,0,20,60'), 256, 128, { quality: 'balanced', maxTiles: 0.05 }), null);
  assert.equal(VIEW_DISTANCE, 30000);
});
