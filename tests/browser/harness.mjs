// Shared by the browser suites (viewer.test.mjs, threejs.test.mjs): the headless
// Chromium they drive, the `ok` / `not ok` lines they print, and small statistics.

import { chromium } from 'playwright-core';

/** WebGL through SwiftShader in a headless browser run as root, without background traffic. */
const FLAGS = [
  '--no-sandbox',
  '--disable-gpu',
  '--no-first-run',
  '--disable-background-networking',
  '--disable-component-update',
  '--enable-unsafe-swiftshader',
  '--use-angle=swiftshader',
  '--ignore-gpu-blocklist',
  // A software-GL frame of a dense view can outlast the GPU watchdog's timeout, which
  // then kills the GPU process and closes the page mid-screenshot.
  '--disable-gpu-watchdog',
];

/** Headless Chromium (CHROMIUM, default Debian's /usr/bin/chromium) with FLAGS and `extraFlags`. */
export function launchChromium(extraFlags = []) {
  return chromium.launch({
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: [...FLAGS, ...extraFlags],
  });
}

/**
 * The checks of the suite `suite`: `check` and `skip` print one line each; `finish`
 * prints the counts and exits, 1 when any check failed.
 */
export function checks(suite) {
  let passed = 0;
  let failed = 0;
  let skipped = 0;
  return {
    check(name, ok, detail = '') {
      if (ok) {
        passed++;
        console.log(`ok - ${name}${detail ? ` (${detail})` : ''}`);
      } else {
        failed++;
        console.log(`not ok - ${name}${detail ? `: ${detail}` : ''}`);
      }
    },
    skip(name, why) {
      skipped++;
      console.log(`ok - ${name} # SKIP ${why}`);
    },
    finish() {
      console.log(`${suite}: ${passed} passed, ${failed} failed${skipped ? `, ${skipped} skipped` : ''}`);
      process.exit(failed === 0 ? 0 : 1);
    },
  };
}

export const mean = (a) => a.reduce((s, v) => s + v, 0) / Math.max(a.length, 1);

/** Standard deviation of the samples `a`. */
export const std = (a) => {
  const m = mean(a);
  return Math.sqrt(mean(a.map((v) => (v - m) ** 2)));
};

/**
 * Whether the samples `hi` are brighter than `lo` beyond doubt: by at least 0.02 (five
 * display steps) and by more than four standard errors of the difference of the means.
 * (Under one sun a thin deck seen from above reads about what the sunlit ground does,
 * in the path tracer too: "brighter" is a small difference, not a fixed margin.)
 */
export const separated = (hi, lo) => {
  const d = mean(hi) - mean(lo);
  const se = Math.sqrt(std(hi) ** 2 / hi.length + std(lo) ** 2 / lo.length);
  return d > Math.max(0.02, 4 * se);
};
