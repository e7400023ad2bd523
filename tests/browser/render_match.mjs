// The viewer against `cloudscape render`: one camera, time and sun drawn by the viewer
// (the page already open and settled) and by the server's `render.png` at the same
// size and quality, compared in display values; and the ground's shadow seams.
// Called by viewer.test.mjs with its page and check().
//
// Figures, both pictures as displayed (8-bit sRGB-like values in [0, 1]):
// - the mean absolute difference of luma (Rec. 601) over all pixels;
// - the largest mean absolute difference of luma over a tenth of the rows (a band
//   where the two disagree cannot hide in the average);
// - the mean SSIM of luma (render::image::ssim: 11×11 Gaussian window, σ = 1.5).
// Seams: for every edge of every drawn tile's shadow quad on the ground (the tile
// shifted away from its sun, where its shadow map ends), the mean jump in luma across
// the edge's projection on screen, against the jumps across lines parallel to it a
// few pixels either side: a straight seam is a jump that its neighbours do not have.

/** Rec. 601 luma of RGBA bytes, as render::image::ssim reads display images. */
export function luma(rgba) {
  const out = new Float64Array(rgba.length / 4);
  for (let i = 0; i < out.length; i++) out[i] = (0.299 * rgba[4 * i] + 0.587 * rgba[4 * i + 1] + 0.114 * rgba[4 * i + 2]) / 255;
  return out;
}

/** Separable normalised Gaussian, 11 taps, σ = 1.5, edges renormalised (render::image::gaussian_blur). */
function gaussianBlur(v, width, height) {
  const k = [];
  for (let i = -5; i <= 5; i++) k.push(Math.exp(-(i * i) / (2 * 1.5 * 1.5)));
  const pass = (src, horizontal) => {
    const out = new Float64Array(src.length);
    for (let y = 0; y < height; y++) {
      for (let x = 0; x < width; x++) {
        let s = 0;
        let w = 0;
        for (let t = 0; t < 11; t++) {
          const xx = horizontal ? x + t - 5 : x;
          const yy = horizontal ? y : y + t - 5;
          if (xx >= 0 && yy >= 0 && xx < width && yy < height) {
            s += k[t] * src[yy * width + xx];
            w += k[t];
          }
        }
        out[y * width + x] = s / w;
      }
    }
    return out;
  };
  return pass(pass(v, true), false);
}

/** Mean SSIM of two luma images (render::image::ssim: C1 = 0.01², C2 = 0.03²). */
export function ssim(x, y, width, height) {
  const blur = (v) => gaussianBlur(v, width, height);
  const [mx, my] = [blur(x), blur(y)];
  const sxx = blur(x.map((v) => v * v));
  const syy = blur(y.map((v) => v * v));
  const sxy = blur(x.map((v, i) => v * y[i]));
  const [c1, c2] = [0.01 ** 2, 0.03 ** 2];
  let total = 0;
  for (let i = 0; i < x.length; i++) {
    const vx = Math.max(sxx[i] - mx[i] * mx[i], 0);
    const vy = Math.max(syy[i] - my[i] * my[i], 0);
    const cov = sxy[i] - mx[i] * my[i];
    total += ((2 * mx[i] * my[i] + c1) * (2 * cov + c2)) / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
  }
  return total / x.length;
}

/** The figures of the module docs for luma images `a` (viewer) and `b` (render). */
export function difference(a, b, width, height) {
  let sum = 0;
  for (let i = 0; i < a.length; i++) sum += Math.abs(a[i] - b[i]);
  const bands = [];
  const rows = Math.ceil(height / 10);
  for (let y0 = 0; y0 < height; y0 += rows) {
    let s = 0;
    const y1 = Math.min(y0 + rows, height);
    for (let i = y0 * width; i < y1 * width; i++) s += Math.abs(a[i] - b[i]);
    bands.push(s / ((y1 - y0) * width));
  }
  return { mae: sum / a.length, worstBand: Math.max(...bands), bands, ssim: ssim(a, b, width, height) };
}

/**
 * The displayed pixels of the viewer's canvas and of `renderUrl` (a PNG of the same
 * size), read in the page: { width, height, viewer, render } with RGBA bytes.
 */
export async function readBoth(page, renderUrl) {
  return page.evaluate(async (url) => {
    const read = (source, w, h) => {
      const c = document.createElement('canvas');
      c.width = w;
      c.height = h;
      const ctx = c.getContext('2d');
      ctx.drawImage(source, 0, 0, w, h);
      return Array.from(ctx.getImageData(0, 0, w, h).data);
    };
    const view = document.getElementById('view');
    const res = await fetch(url);
    if (!res.ok) return { error: `${url}: ${res.status} ${await res.text()}` };
    const img = await createImageBitmap(await res.blob(), { premultiplyAlpha: 'none', colorSpaceConversion: 'none' });
    const [w, h] = [view.width, view.height];
    if (img.width !== w || img.height !== h) return { error: `render.png is ${img.width}×${img.height}, the canvas ${w}×${h}` };
    return { width: w, height: h, viewer: read(view, w, h), render: read(img, w, h) };
  }, renderUrl);
}

/**
 * The seam figure of the module docs. `shifts` gives, by layer name, how far the
 * layer's shadow maps lie from its tiles on the ground ((s_x, s_y) · base / s_z,
 * render::tile::shadow_shift, subtracted); `near` the ground distance (m) within which
 * edges are measured (the shadow fades to the mean from 40 % of the view distance on,
 * SHADOW_FADE_START: half way at 70 %).
 * For each edge of a drawn tile's shadow quad on screen: the mean |Δ luma| across it
 * (one and a half pixels either side), and the mean of the same over lines parallel
 * to it at ±4, ±8 and ±12 pixels. Returns the edges, largest excess first.
 */
export async function seams(page, lum, width, height, shifts, near) {
  const edges = await page.evaluate(({ shifts, near }) => {
    const out = [];
    const cam = window.cloudscape.state.camera;
    for (const t of window.cloudscape.tiles()) {
      const [sx, sy] = shifts[t.layer];
      const [x0, y0, x1, y1] = [t.origin[0] - sx, t.origin[1] - sy, t.origin[0] + t.size - sx, t.origin[1] + t.size - sy];
      const sides = [[[x0, y0], [x1, y0]], [[x1, y0], [x1, y1]], [[x1, y1], [x0, y1]], [[x0, y1], [x0, y0]]];
      for (const [a, b] of sides) {
        // The edge sampled densely on the ground, where it lands on screen.
        const pts = [];
        for (let i = 0; i <= 2000; i++) {
          const f = i / 2000;
          const g = [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f];
          if (Math.hypot(g[0] - cam.x, g[1] - cam.y) > near) continue;
          const p = window.cloudscape.project([g[0], g[1], 0]);
          if (p && p[0] >= 0 && p[1] >= 0 && p[0] < innerWidth && p[1] < innerHeight) pts.push(p);
        }
        if (pts.length >= 2) out.push({ tile: `${t.layer}/${t.z}/${t.x}/${t.y}`, pts });
      }
    }
    return out;
  }, { shifts, near });
  const at = (x, y) => {
    const [xi, yi] = [Math.round(x), Math.round(y)];
    return xi >= 0 && yi >= 0 && xi < width && yi < height ? lum[yi * width + xi] : null;
  };
  const results = [];
  for (const e of edges) {
    // Along the edge's path on screen, a pixel at a time, across its normal at `offset`.
    const jumpAt = (offset) => {
      let sum = 0;
      let n = 0;
      for (let i = 0; i + 1 < e.pts.length; i++) {
        const [p, q] = [e.pts[i], e.pts[i + 1]];
        const len = Math.hypot(q[0] - p[0], q[1] - p[1]);
        if (!(len > 0)) continue;
        const [nx, ny] = [-(q[1] - p[1]) / len, (q[0] - p[0]) / len];
        const steps = Math.max(1, Math.round(len));
        for (let s = 0; s < steps; s++) {
          const x = p[0] + ((q[0] - p[0]) * s) / steps + nx * offset;
          const y = p[1] + ((q[1] - p[1]) * s) / steps + ny * offset;
          const [u, v] = [at(x - nx * 1.5, y - ny * 1.5), at(x + nx * 1.5, y + ny * 1.5)];
          if (u === null || v === null) continue;
          sum += Math.abs(u - v);
          n++;
        }
      }
      return n ? { jump: sum / n, n } : null;
    };
    const on = jumpAt(0);
    const beside = [-12, -8, -4, 4, 8, 12].map(jumpAt).filter(Boolean);
    if (!on || on.n < 40 || beside.length < 4) continue;
    const mean = beside.reduce((s, v) => s + v.jump, 0) / beside.length;
    results.push({ tile: e.tile, pixels: on.n, jump: on.jump, beside: mean, excess: on.jump - mean });
  }
  return results.sort((a, b) => b.excess - a.excess);
}

/**
 * How far each layer's shadow maps lie from its tiles on the ground for the sun of
 * `/v1/sky.json?sun=AZ,EL` (its bucket's centre, which the tiles are shaded for):
 * { layer name: [dx, dy] } (render::tile::shadow_shift).
 */
export async function shadowShifts(base, world, sun) {
  const sky = await (await fetch(`${base}/v1/sky.json?sun=${sun}`)).json();
  const info = await (await fetch(`${base}/v1/worlds/${world}`)).json();
  const s = sky.sun.direction;
  const k = 1 / Math.max(s[2], Math.sin(Math.PI / 180));
  return Object.fromEntries(info.layers.map((l) => [l.name, [s[0] * k * l.base, s[1] * k * l.base]]));
}
