// density.ktx2 read by an independent KTX 2.0 reader (ktx-parse, Don McCurdy's, which
// three.js's KTX2Loader also uses) and by the client: the spec's fields and the bytes
// of density.u8. Needs CLOUDSCAPE_URL (tests/ext/js_client.sh).

import assert from 'node:assert/strict';
import { test } from 'node:test';

import { KHR_DF_MODEL_RGBSDA, KHR_DF_TRANSFER_LINEAR, KHR_SUPERCOMPRESSION_NONE, VK_FORMAT_R8_UNORM, read } from 'ktx-parse';

import { CloudscapeClient, decodeKtx2 } from '../cloudscape.js';

const base = process.env.CLOUDSCAPE_URL;
if (!base) throw new Error('set CLOUDSCAPE_URL to a running cloudscape server');

test('density.ktx2 is a KTX 2.0 R8 3D texture holding density.u8', async () => {
  const client = new CloudscapeClient(base);
  const world = await client.world('overcast');
  const layer = world.layers.find((l) => l.name === 'stratocumulus');
  const tile = { layer: layer.name, z: 0, x: 0, y: 0 };
  const at = { t: 43212 };
  const res = await fetch(client.url(client.tilePath(world, tile, 'density.ktx2', at)));
  assert.equal(res.status, 200);
  assert.equal(res.headers.get('Content-Type'), 'image/ktx2');
  assert.match(res.headers.get('Cache-Control'), /immutable/);
  const bytes = new Uint8Array(await res.arrayBuffer());
  const u8 = new Uint8Array(await client.tile(world, tile, 'density.u8', at));

  const c = read(bytes);
  assert.equal(c.vkFormat, VK_FORMAT_R8_UNORM);
  assert.equal(c.typeSize, 1);
  assert.deepEqual([c.pixelWidth, c.pixelHeight, c.pixelDepth], [256, 256, layer.depth]);
  assert.deepEqual([c.layerCount, c.faceCount, c.levels.length], [0, 1, 1]);
  assert.equal(c.supercompressionScheme, KHR_SUPERCOMPRESSION_NONE);
  const dfd = c.dataFormatDescriptor[0];
  assert.equal(dfd.colorModel, KHR_DF_MODEL_RGBSDA);
  assert.equal(dfd.transferFunction, KHR_DF_TRANSFER_LINEAR, 'data, not sRGB');
  assert.equal(dfd.samples.length, 1);
  assert.equal(dfd.samples[0].bitLength, 7, 'one 8-bit channel');
  assert.equal(dfd.samples[0].sampleUpper, 255);
  assert.match(String(c.keyValue.KTXwriter), /^cloudscape \d+/);
  assert.equal(c.levels[0].uncompressedByteLength, u8.length);
  assert.deepEqual(c.levels[0].levelData, u8, 'level 0 is the bytes of density.u8');

  const own = decodeKtx2(bytes);
  assert.deepEqual([own.vkFormat, own.width, own.height, own.depth], [VK_FORMAT_R8_UNORM, 256, 256, layer.depth]);
  assert.deepEqual(own.data, u8);
});
