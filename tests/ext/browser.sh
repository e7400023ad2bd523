#!/usr/bin/env bash
# The viewer in a real browser: starts `cloudscape serve` on a free port, drives the
# page at `/` in headless Chromium (tests/browser/viewer.test.mjs, playwright-core
# pointed at Debian's /usr/bin/chromium, WebGL through SwiftShader), stops the server.
# Screenshots and figures go to target/browser/. Installs nothing: needs the Debian
# package `chromium` and `npm ci` run in tests/browser (both done by .ci/run).
set -euo pipefail
cd "$(dirname "$0")/../.."

bin=target/release/cloudscape
chromium=${CHROMIUM:-/usr/bin/chromium}
out=target/browser
if [ ! -x "$bin" ]; then
  echo "error: $bin is missing; run 'cargo build --release --bins' first" >&2
  exit 1
fi
if [ ! -x "$chromium" ]; then
  echo "error: $chromium is missing; install the Debian package 'chromium'" >&2
  exit 1
fi
if [ ! -d tests/browser/node_modules/playwright-core ]; then
  echo "error: playwright-core is missing; run 'npm ci' in tests/browser" >&2
  exit 1
fi
mkdir -p "$out"

port=$(node -e 'const s=require("net").createServer().listen(0,"127.0.0.1",()=>{console.log(s.address().port);s.close()})')
server_pid=""
cleanup() {
  if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
    kill -TERM "$server_pid" 2>/dev/null || true
    wait "$server_pid" 2>/dev/null || true
  fi
}
trap cleanup EXIT

# A cold tile may take a while on a loaded CI machine: give computations time rather
# than shedding them (the viewer retries 503s, but the browser logs them as errors).
CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS=300000 CLOUDSCAPE_SERVER_DRAIN_MS=0 \
  "$bin" serve --listen "127.0.0.1:$port" >"$out/server.log" 2>&1 &
server_pid=$!

base="http://127.0.0.1:$port"
for _ in $(seq 1 200); do
  if node -e "fetch('$base/healthz').then(r=>process.exit(r.ok?0:1),()=>process.exit(1))"; then
    break
  fi
  if ! kill -0 "$server_pid" 2>/dev/null; then
    echo "error: the server exited; see $out/server.log" >&2
    cat "$out/server.log" >&2
    exit 1
  fi
  sleep 0.1
done

CHROMIUM="$chromium" node tests/browser/viewer.test.mjs "$base" "$out"
