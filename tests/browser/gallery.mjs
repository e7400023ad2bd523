// Viewer screenshots of the gallery's views (the table VIEWS in
// crates/cloudscape-tools/src/bench/gallery.rs: same cameras, suns and time, in the
// default world), saved as OUT_DIR/gallery-<view>.png beside the server-side gallery.
// Called by viewer.test.mjs with its browser and check(); a unit test in
// crates/cloudscape-tools/src/bench/gallery.rs checks that every camera and sun of the
// Rust table appears here.

import { join } from 'node:path';

export const GALLERY_VIEWS = [
  { name: 'ground-noon', camera: '12800,-5000,2,0,20,75', sun: '180,60', t: 43200 },
  { name: 'up-60', camera: '12800,12800,2,0,60,75', sun: '150,55', t: 43200 },
  { name: 'above-10km', camera: '12800,-8000,10000,0,-40,70', sun: '200,45', t: 43200 },
  { name: 'backlit', camera: '12800,12800,500,250,10,70', sun: '250,12', t: 43200 },
  { name: 'sunset', camera: '12800,12800,300,270,6,75', sun: '270,2', t: 43200 },
  { name: 'inside-layer', camera: '5550,1050,1850,0,5,70', sun: '180,60', t: 43200 },
  { name: 'horizon', camera: '12800,-20000,400,0,4,60', sun: '135,35', t: 43200 },
];

/**
 * Opens each view in the viewer, waits until its tiles are drawn, saves a screenshot
 * and checks that the page logged no error and (outside a layer) the picture is not
 * one flat colour. `helpers` = { check, figure, settle, canvasLuminance, std, openPage,
 * screenshotTimeout }.
 */
export async function galleryScreenshots(browser, base, outDir, viewport, helpers) {
  const { check, figure, settle, canvasLuminance, std, openPage, screenshotTimeout } = helpers;
  const context = await browser.newContext({ viewport });
  for (const v of GALLERY_VIEWS) {
    const { page, log } = await openPage(context);
    await page.goto(`${base}/?world=default&t=${v.t}&camera=${v.camera}&quality=balanced&sun=${v.sun}`);
    await settle(page);
    // The picture alone, for the contact sheet beside the server's renders.
    await page.addStyleTag({ content: '#panel, #hud { display: none !important; }' });
    await page.screenshot({ path: join(outDir, `gallery-${v.name}.png`), timeout: screenshotTimeout });
    const l = await canvasLuminance(page);
    figure(`gallery ${v.name}: luminance std`, std(l.lum).toFixed(3));
    if (v.name !== 'inside-layer') {
      check(`gallery view ${v.name} is not blank`, std(l.lum) > 0.01, `luminance std ${std(l.lum).toFixed(3)}`);
    }
    const bad = log.responses.filter((r) => r.status >= 400);
    check(`gallery view ${v.name}: no request failed, no console error`, bad.length === 0 && log.errors.length === 0,
      `${JSON.stringify(bad.slice(0, 3))} ${log.errors.slice(0, 3).join(' | ')}`);
    await page.close();
  }
  await context.close();
}
