#!/usr/bin/env bash
# The three.js example (examples/threejs) in real headless Chromium: starts `cloudscape
# serve` and the example's static server (examples/threejs/serve.mjs, another origin)
# on free ports, runs tests/browser/threejs.test.mjs, stops both. Screenshots go to
# target/browser/. Needs the Debian package `chromium`; installs the locked npm
# packages of tests/browser (playwright-core) and examples/threejs (three) with npm ci.
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

need_chromium
out=target/browser
npm_ci examples/threejs
start_server target/threejs

example_port=$(free_port)
node examples/threejs/serve.mjs --port "$example_port" --cloudscape "$base" >target/threejs/example-server.log 2>&1 &
example_pid=$!
trap 'kill "$example_pid" 2>/dev/null || true; stop_server' EXIT
example="http://127.0.0.1:$example_port"
for _ in $(seq 1 100); do
  if node -e "fetch('$example/').then(r=>process.exit(r.ok?0:1),()=>process.exit(1))"; then break; fi
  sleep 0.1
done

CHROMIUM="$chromium" node tests/browser/threejs.test.mjs "$example" "$base" "$out"
