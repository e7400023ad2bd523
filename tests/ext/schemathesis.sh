#!/usr/bin/env bash
# OpenAPI conformance: schemathesis (PyPI package `schemathesis`) generates requests
# from /openapi.json and checks every response against the document: no 5xx, only
# documented status codes and content types, bodies that match their schemas, and
# invalid input rejected. Runs against `cloudscape serve` on the tests' small world so each
# request is cheap, bounded in examples and in time. Installs nothing: fails with a
# message when schemathesis is missing (./scripts/test provisions it).
set -euo pipefail
cd "$(dirname "$0")/../.."

if command -v st >/dev/null 2>&1; then
  ST=(st)
elif command -v schemathesis >/dev/null 2>&1; then
  ST=(schemathesis)
else
  echo "error: schemathesis is not installed (./scripts/test puts it in target/test-venv)" >&2
  exit 1
fi

bin=target/release/cloudscape
if [ ! -x "$bin" ]; then
  echo "error: $bin is missing; run 'cargo build --release --bins' first" >&2
  exit 1
fi

work=$(mktemp -d)
server_pid=""
cleanup() {
  if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
    kill -TERM "$server_pid" 2>/dev/null || true
    wait "$server_pid" 2>/dev/null || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT


port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
base="http://127.0.0.1:$port"
# The tests' one world (tests/data/small.toml), with tighter limits so every generated
# request stays cheap.
RUST_LOG=warn \
  CLOUDSCAPE_SERVER_REQUEST_TIMEOUT_MS=20000 CLOUDSCAPE_SERVER_MAX_SERIES=4 \
  CLOUDSCAPE_LIMITS_MAX_COLUMNS=300 CLOUDSCAPE_LIMITS_MAX_CELLS=200000 \
  "$bin" serve --config tests/data/small.toml --listen "127.0.0.1:$port" 2>"$work/server.log" &
server_pid=$!

ready=0
for _ in $(seq 1 300); do
  if python3 -c "import urllib.request, sys; urllib.request.urlopen('$base/readyz', timeout=2)" 2>/dev/null; then
    ready=1
    break
  fi
  sleep 0.2
done
if [ "$ready" != 1 ]; then
  echo "error: cloudscape serve did not become ready" >&2
  cat "$work/server.log" >&2
  exit 1
fi

# positive_data_acceptance is left out: a schema-valid world name or layer that is not
# configured is rightly a 404. Everything else schemathesis checks is on.
status=0
# Run from the scratch directory: schemathesis keeps a cache in its working directory.
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
if ! kill -0 "$server_pid" 2>/dev/null; then
  echo "error: the server died during the run" >&2
  cat "$work/server.log" >&2
  exit 1
fi
if grep -q "panicked" "$work/server.log"; then
  echo "error: the server panicked" >&2
  cat "$work/server.log" >&2
  exit 1
fi
exit $status
