#!/usr/bin/env bash
# OpenAPI conformance: schemathesis (PyPI package `schemathesis`) generates requests
# from /openapi.json and checks every response against the document: no 5xx, only
# documented status codes and content types, bodies that match their schemas, and
# invalid input rejected. Runs against `cloudscape serve` on the tests' small world so each
# request is cheap, bounded in examples and in time. Installs nothing: fails with a
# message when schemathesis is missing (./scripts/test provisions it).
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

if command -v st >/dev/null 2>&1; then
  ST=(st)
elif command -v schemathesis >/dev/null 2>&1; then
  ST=(schemathesis)
else
  echo "error: schemathesis is not installed (./scripts/test puts it in target/test-venv)" >&2
  exit 1
fi

work=target/schemathesis
# A fresh directory: schemathesis keeps its examples database in its working directory.
rm -rf "$work"
# The tests' one world (tests/data/small.toml), with tighter limits so every generated
# request stays cheap.
CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS=20000 CLOUDSCAPE_SERVER_MAX_SERIES=4 \
  CLOUDSCAPE_LIMITS_MAX_COLUMNS=300 CLOUDSCAPE_LIMITS_MAX_CELLS=200000 \
  start_server "$work" --config tests/data/small.toml

# positive_data_acceptance is left out: a schema-valid world name or layer that is not
# configured is rightly a 404. Everything else schemathesis checks is on.
status=0
(cd "$work" && timeout 900 "${ST[@]}" run "$base/openapi.json" \
  --checks all \
  --exclude-checks positive_data_acceptance \
  --max-examples "${SCHEMATHESIS_MAX_EXAMPLES:-40}" \
  --max-time "${SCHEMATHESIS_MAX_TIME:-120}" \
  --request-timeout 30 \
  --workers 2 \
  --seed 1 \
  --no-color) >"$work/st.log" 2>&1 || status=$?
# The failures section in full (each with its curl line), then the summary.
if [ "$status" -ne 0 ]; then sed -n "/^=* FAILURES/,/^=* WARNINGS/p" "$work/st.log"; fi
tail -n 30 "$work/st.log"
check_server
exit $status
