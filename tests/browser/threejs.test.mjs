// The three.js example (examples/threejs) in real headless Chromium:
//
//   node tests/browser/threejs.test.mjs EXAMPLE_URL CLOUDSCAPE_URL OUT_DIR
//
// EXAMPLE_URL is examples/threejs/serve.mjs (the page, three.js from npm, /v1 passed
// through to the tile server); CLOUDSCAPE_URL the tile server itself, another origin.
// Checks, looking straight down on the overcast world's stratocumulus deck between
// two keyframes: the billboard mode (InstancedMesh) and the volume mode (density.u8 as
// a Data3DTexture, ray-marched) both draw clouds where coverage.png says cloud; the
// KTX2 mode loads density.ktx2 through three.js's KTX2Loader as a 3D texture and
// draws the same; animating across a keyframe, the billboard mode reads the next
// keyframe as a delta (billboards.delta.bin) on the one it holds, through the JS
// client; and the page fetches the tiles from the tile server's own origin (CORS)
// when the server sends CORS headers. The billboard mode draws what `cloudscape
// render` draws: the viewer's default view against the server's render.png, as the
// viewer's own test holds it (render_match.mjs). Screenshots go to OUT_DIR.

import { mkdirSync, writeFileSync } from 'node:fs';
import { join } from 'node:path';
import { checks, launchChromium, mean, separated } from './harness.mjs';
import { difference, luma } from './render_match.mjs';

const [example, tiles, outDir = 'target/browser'] = process.argv.slice(2);
if (!example || !tiles) {
  console.error('usage: node threejs.test.mjs EXAMPLE_URL CLOUDSCAPE_URL [OUT_DIR]');
  process.exit(2);
}
mkdirSync(outDir, { recursive: true });

/** Small: SwiftShader ray-marches every pixel on the CPU. */
const VIEWPORT = { width: 480, height: 270 };
const LOAD_TIMEOUT_MS = 600_000;

const { check, skip, finish } = checks('threejs');

const browser = await launchChromium();

// Between keyframes (level 0 spans 20 s): 60 % of the way from 43200 to 43220.
const T = 43212;
const SCENE = `world=overcast&layer=stratocumulus&t=${T}&camera=12800,12800,9000,0,-90,60&sun=180,90&quality=fast`;

/** Opens the example with `query`, waits for its picture; returns the page, its log and its status. */
async function open(context, query) {
  const page = await context.newPage();
  const log = { errors: [], requests: [] };
  page.on('console', (m) => {
    if (m.type() === 'error') log.errors.push(m.text());
  });
  page.on('pageerror', (e) => log.errors.push(String(e)));
  page.on('request', (r) => log.requests.push(r.url()));
  await page.goto(`${example}/?${query}`);
  // Until the picture is drawn, the page reports an error, or a module fails to load
  // (then the page never reports anything).
  const deadline = Date.now() + LOAD_TIMEOUT_MS;
  let status = null;
  while (Date.now() < deadline) {
    status = await page.evaluate(() => (window.example ? window.example.status : null));
    if ((status && (status.ready || status.error)) || log.errors.length) break;
    await new Promise((r) => setTimeout(r, 250));
  }
  if (!status || !status.ready) status = { ...status, error: (status && status.error) || log.errors.join(' | ') || 'timed out' };
  return { page, log, status };
}

/**
 * Luminance of the canvas at every column of the tile's coverage map (projected at the
 * layer's middle altitude), split into cloudy (coverage ≥ 0.5) and clear (0) columns.
 */
async function cloudyVersusClear(page) {
  return page.evaluate(async (t) => {
    const url = `/v1/worlds/overcast/tiles/0/0/0/coverage.png?t=${t}&layer=stratocumulus`;
    const img = await createImageBitmap(await (await fetch(url)).blob(), { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
    const read = (source, w, h) => {
      const c = document.createElement('canvas');
      c.width = w;
      c.height = h;
      const ctx = c.getContext('2d');
      ctx.drawImage(source, 0, 0, w, h);
      return ctx.getImageData(0, 0, w, h).data;
    };
    const cov = read(img, img.width, img.height);
    const canvas = document.querySelector('canvas');
    const [w, h] = [innerWidth, innerHeight];
    const pix = read(canvas, w, h);
    const info = await (await fetch('/v1/worlds/overcast')).json();
    const layer = info.layers.find((l) => l.name === 'stratocumulus');
    const mid = (layer.base + layer.top) / 2;
    const cloudy = [];
    const clear = [];
    for (let row = 0; row < img.height; row++) {
      for (let col = 0; col < img.width; col++) {
        const x = (col + 0.5) * layer.cell_size;
        const y = (img.height - 1 - row + 0.5) * layer.cell_size; // row 0 is north
        const p = window.example.project([x, y, mid]);
        if (!p || p[0] < 0 || p[1] < 0 || p[0] >= w || p[1] >= h) continue;
        const i = (Math.floor(p[1]) * w + Math.floor(p[0])) * 4;
        const lum = (0.2126 * pix[i] + 0.7152 * pix[i + 1] + 0.0722 * pix[i + 2]) / 255;
        const c = cov[(row * img.width + col) * 4] / 255;
        if (c >= 0.5) cloudy.push(lum);
        else if (c === 0) clear.push(lum);
      }
    }
    return { cloudy, clear };
  }, T);
}

async function drawsWhereCoverageSays(context, mode, name) {
  const { page, log, status } = await open(context, `${SCENE}&mode=${mode}`);
  check(`${name}: the page loads`, !status.error, status.error || '');
  if (status.error) {
    await page.close();
    return;
  }
  await page.screenshot({ path: join(outDir, `threejs-${mode}.png`) });
  const { cloudy, clear } = await cloudyVersusClear(page);
  check(
    `${name}: brighter where coverage.png says cloud`,
    cloudy.length >= 50 && clear.length >= 50 && separated(cloudy, clear),
    `${cloudy.length} cloudy columns at luminance ${mean(cloudy).toFixed(3)}, ${clear.length} clear at ${mean(clear).toFixed(3)}`,
  );
  check(`${name}: draws the keyframe that holds t`, status.keyframes.length === 1 && status.keyframes[0][0] === 43200, JSON.stringify(status.keyframes));
  check(`${name}: logs no console errors`, log.errors.length === 0, log.errors.slice(0, 3).join(' | '));
  await page.close();
  return status;
}

try {
  const context = await browser.newContext({ viewport: VIEWPORT });

  const b = await drawsWhereCoverageSays(context, 'billboards', 'three.js billboards (InstancedMesh)');
  check('three.js billboards: draws instances', b && b.instances > 100, `${b && b.instances} instances`);

  // Animating (4 world seconds a second) from 43212 across the keyframe at 43220.
  {
    const { page, log, status } = await open(context, `${SCENE}&mode=billboards&animate=1&rate=4`);
    check('three.js billboards animating: the page loads', !status.error, status.error || '');
    if (!status.error) {
      await page.waitForFunction(() => window.example.status.keyframes[0]?.[0] === 43220, null, { timeout: LOAD_TIMEOUT_MS, polling: 250 });
      await page.screenshot({ path: join(outDir, 'threejs-billboards-next.png') });
      const forms = await page.evaluate(() => window.example.status.forms);
      const billboards = log.requests
        .map((u) => new URL(u))
        .filter((u) => /\/billboards(\.delta)?\.bin$/.test(u.pathname))
        .map((u) => `${u.pathname.split('/').pop()}@${u.searchParams.get('t')}`);
      check(
        'three.js billboards animating: the first keyframe whole, the next a delta on it (JS client)',
        billboards.includes('billboards.bin@43200') && billboards.includes('billboards.delta.bin@43220') &&
          !billboards.includes('billboards.bin@43220') && forms[0] === 'delta',
        `${JSON.stringify(billboards)}; drawn ${JSON.stringify(forms)}`,
      );
      check('three.js billboards animating: logs no console errors', log.errors.length === 0, log.errors.slice(0, 3).join(' | '));
    }
    await page.close();
  }
  // What `cloudscape render` draws: the viewer's default view (camera, noon, the
  // clock's sun at noon) against render.png at the same size and quality. Measured:
  // mean |Δ luma| 0.0004, worst tenth of the rows 0.0018, SSIM 0.9996; before (one
  // tile of one layer, splats from the sheet blended in display values over a slate
  // background): 0.21, 0.32, 0.76. The viewer's bounds (viewer.test.mjs).
  {
    const view = 'world=default&t=43200&camera=12800,-6000,900,0,6,75&sun=180,68&quality=fast';
    const { page, log, status } = await open(context, view);
    check('three.js billboards, the default view: the page loads', !status.error, status.error || '');
    if (!status.error) {
      await page.screenshot({ path: join(outDir, 'threejs-default-view.png') });
      const size = `${VIEWPORT.width}x${VIEWPORT.height}`;
      const png = Buffer.from(await (await fetch(`${tiles}/v1/worlds/default/render.png?camera=12800,-6000,900,0,6,75&t=43200&size=${size}&quality=fast&sun=180,68`)).arrayBuffer());
      writeFileSync(join(outDir, 'threejs-default-view-render.png'), png);
      const both = await page.evaluate(async (data) => {
        const read = (src, w, h) => {
          const c = document.createElement('canvas');
          c.width = w;
          c.height = h;
          const ctx = c.getContext('2d');
          ctx.drawImage(src, 0, 0, w, h);
          return Array.from(ctx.getImageData(0, 0, w, h).data);
        };
        const canvas = document.querySelector('canvas');
        const img = await createImageBitmap(await (await fetch(data)).blob(), { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
        if (img.width !== canvas.width || img.height !== canvas.height) return { error: `render.png ${img.width}×${img.height}, canvas ${canvas.width}×${canvas.height}` };
        return { width: canvas.width, height: canvas.height, example: read(canvas, canvas.width, canvas.height), render: read(img, img.width, img.height) };
      }, `data:image/png;base64,${png.toString('base64')}`);
      if (both.error) {
        check('three.js billboards draw what cloudscape render draws', false, both.error);
      } else {
        const m = difference(luma(both.example), luma(both.render), both.width, both.height);
        check(
          'three.js billboards draw what cloudscape render draws (mean |Δ luma| ≤ 0.006, every tenth of the rows ≤ 0.012, SSIM ≥ 0.99)',
          m.mae <= 0.006 && m.worstBand <= 0.012 && m.ssim >= 0.99,
          `mean ${m.mae.toFixed(4)}, bands ${m.bands.map((v) => v.toFixed(3)).join(' ')}, SSIM ${m.ssim.toFixed(4)}`,
        );
      }
    }
    check('three.js billboards, the default view: logs no console errors', log.errors.length === 0, log.errors.slice(0, 3).join(' | '));
    await page.close();
  }

  await drawsWhereCoverageSays(context, 'volume', 'three.js volume (density.u8 as Data3DTexture)');

  // density.ktx2 through KTX2Loader, when the server has the product.
  const world = await (await fetch(`${tiles}/v1/worlds/overcast`)).json();
  if (world.products.includes('density.ktx2')) {
    const k = await drawsWhereCoverageSays(context, 'ktx2', 'three.js KTX2 (density.ktx2 through KTX2Loader)');
    check(
      'KTX2Loader gives a 256×256×depth R8 Data3DTexture',
      k && k.ktx2 && k.ktx2.isData3DTexture && k.ktx2.width === 256 && k.ktx2.height === 256 &&
        k.ktx2.depth === world.layers.find((l) => l.name === 'stratocumulus').depth,
      JSON.stringify(k && k.ktx2),
    );
  } else {
    skip('three.js KTX2 mode', 'this server serves no density.ktx2');
  }

  // --- Another origin: the page at EXAMPLE_URL, the tiles from CLOUDSCAPE_URL. -------
  // Needs the server's CORS layer (issue 23, item 1), built on another branch. Until it
  // is merged the server sends no Access-Control-Allow-Origin and this check is
  // skipped; once it does, the check runs and must pass. CLOUDSCAPE_REQUIRE_CORS=1
  // makes a missing CORS layer a failure.
  const probe = await fetch(`${tiles}/v1/worlds/overcast`, { headers: { Origin: example } });
  const allowed = probe.headers.get('access-control-allow-origin');
  await probe.arrayBuffer();
  if (!allowed && process.env.CLOUDSCAPE_REQUIRE_CORS !== '1') {
    skip('the JS client fetches tiles from another origin', 'the server sends no Access-Control-Allow-Origin (CORS not merged on this branch)');
  } else {
    const { page, log, status } = await open(context, `${SCENE}&mode=billboards&server=${encodeURIComponent(tiles)}`);
    const crossOrigin = log.requests.filter((u) => u.startsWith(`${tiles}/v1/`));
    const sameOrigin = log.requests.filter((u) => u.startsWith(`${example}/v1/`));
    check(
      'the JS client fetches tiles from another origin (CORS)',
      !status.error && status.instances > 100 && crossOrigin.some((u) => u.includes('/tiles/')) && sameOrigin.length === 0,
      status.error || `${crossOrigin.length} requests to ${tiles}, ${sameOrigin.length} to the page's origin; ACAO ${allowed}`,
    );
    check('the cross-origin page logs no console errors', log.errors.length === 0, log.errors.slice(0, 3).join(' | '));
    await page.close();
  }
} catch (e) {
  check('the three.js test ran to the end', false, e.stack || String(e));
} finally {
  await browser.close();
}

finish();
