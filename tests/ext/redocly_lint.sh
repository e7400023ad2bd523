#!/usr/bin/env bash
# The OpenAPI document through Redocly's linter (@redocly/cli, pinned in
# tests/openapi/package-lock.json, installed there by `npm ci`): `redocly lint` with
# the recommended ruleset and tests/openapi/redocly.yaml (which turns off only the
# rules it gives a reason for) must report no error and no warning, on the document
# as OpenAPI 3.1 (/openapi.json) and as OpenAPI 3.0 (/v1/edr/api, the EDR landing
# page's service-desc). Runs against `cloudscape serve` on the tests' small world.
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

npm_ci tests/openapi
work=target/redocly
start_server "$work" --config tests/data/small.toml
fetch() {
  "$PY" -c "import sys, urllib.request; sys.stdout.buffer.write(urllib.request.urlopen('$base$1', timeout=30).read())" >"$2"
}
fetch /openapi.json "$work/openapi-3.1.json"
fetch /v1/edr/api "$work/openapi-3.0.json"
check_server

# No telemetry and no update check: the suite talks to nothing but the server.
status=0
for doc in "$work/openapi-3.1.json" "$work/openapi-3.0.json"; do
  lint=0
  REDOCLY_TELEMETRY=off REDOCLY_SUPPRESS_UPDATE_NOTICE=true \
    tests/openapi/node_modules/.bin/redocly lint --config tests/openapi/redocly.yaml \
    --max-problems 1000 --format stylish "$doc" >"$doc.lint" 2>&1 || lint=$?
  # The lines about the document, without the banner about Node.js versions.
  grep -v '[║╔╚]' "$doc.lint" | sed '/^ *$/d'
  # `lint` exits 0 with warnings: a warning fails this suite too.
  if [ "$lint" -ne 0 ] || grep -qiE '[1-9][0-9]* warnings?' "$doc.lint"; then
    echo "FAILED: redocly lint of $doc"
    status=1
  fi
done
exit $status
