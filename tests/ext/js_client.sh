#!/usr/bin/env bash
# The JS client (clients/js) against a real server: starts `cloudscape serve` on a free
# port, runs the client's node tests (node --test) against it, and type-checks
# index.d.ts with tsc. Installs the client's locked dev dependencies (npm ci).
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

npm_ci clients/js
start_server target/js-client
(cd clients/js && npx --no-install tsc --noEmit -p .)
echo "ok - clients/js/index.d.ts type-checks (tsc --noEmit)"
CLOUDSCAPE_URL="$base" node --test clients/js/test/
