#!/usr/bin/env bash
# The OpenAPI document through Redocly's linter (@redocly/cli, pinned in
# tests/openapi/package-lock.json, installed there by `npm ci`): `redocly lint` with
# the recommended ruleset and tests/openapi/redocly.yaml (which turns off only the
# rules it gives a reason for) must report no error and no warning. Runs against
# `cloudscape serve` on the tests' small world, whose /openapi.json it lints.
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

npm_ci tests/openapi
work=target/redocly
start_server "$work" --config tests/data/small.toml
"$PY" -c "import sys, urllib.request; sys.stdout.buffer.write(urllib.request.urlopen('$base/openapi.json', timeout=30).read())" \
  >"$work/openapi.json"
check_server

# No telemetry and no update check: the suite talks to nothing but the server.
status=0
REDOCLY_TELEMETRY=off REDOCLY_SUPPRESS_UPDATE_NOTICE=true \
  tests/openapi/node_modules/.bin/redocly lint --config tests/openapi/redocly.yaml \
  --max-problems 1000 --format stylish "$work/openapi.json" >"$work/lint.log" 2>&1 || status=$?
cat "$work/lint.log"
# `lint` exits 0 with warnings: a warning fails this suite too.
if [ "$status" -eq 0 ] && grep -qiE '[1-9][0-9]* warnings?' "$work/lint.log"; then
  echo "FAILED: redocly lint reported warnings"
  status=1
fi
exit $status
