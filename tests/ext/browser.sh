#!/usr/bin/env bash
# The viewer in a real browser: starts `cloudscape serve` on a free port, drives the
# page at `/` in headless Chromium (tests/browser/viewer.test.mjs, playwright-core
# pointed at Debian's /usr/bin/chromium, WebGL through SwiftShader), stops the server.
# Screenshots and figures go to target/browser/. Needs the Debian package `chromium`;
# installs tests/browser's locked npm packages (npm ci) when they are missing.
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

need_chromium
out=target/browser
start_server "$out"
CHROMIUM="$chromium" node tests/browser/viewer.test.mjs "$base" "$out"
