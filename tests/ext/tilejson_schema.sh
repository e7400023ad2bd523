#!/usr/bin/env bash
# TileJSON conformance: every world's /tilejson.json, for every layer and tile product,
# validated against the official TileJSON 3.0.0 JSON schema
# (tests/data/tilejson-3.0.0.schema.json, from github.com/mapbox/tilejson-spec
# 3.0.0/schema.json) with the Python `jsonschema` package, plus what the schema cannot
# say: absolute URLs with {z}/{x}/{y}, minzoom <= maxzoom, four bounds. Runs against
# `cloudscape serve` on the tests' small world. Installs nothing: fails with a message
# when jsonschema is missing (./scripts/test puts it in target/test-venv).
set -euo pipefail
cd "$(dirname "$0")/../.."

PY=python3
if ! "$PY" -c 'import jsonschema' 2>/dev/null; then
  echo "error: the Python package jsonschema is not installed (./scripts/test puts it in target/test-venv)" >&2
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

port=$("$PY" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
base="http://127.0.0.1:$port"
RUST_LOG=warn "$bin" serve --config tests/data/small.toml --listen "127.0.0.1:$port" 2>"$work/server.log" &
server_pid=$!

ready=0
for _ in $(seq 1 300); do
  if "$PY" -c "import urllib.request; urllib.request.urlopen('$base/readyz', timeout=2)" 2>/dev/null; then
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

status=0
"$PY" - "$base" tests/data/tilejson-3.0.0.schema.json <<'EOF' || status=$?
import json, sys, urllib.request
import jsonschema

base, schema_path = sys.argv[1], sys.argv[2]
schema = json.load(open(schema_path))
validator_class = jsonschema.validators.validator_for(schema)
validator_class.check_schema(schema)
validator = validator_class(schema)

def get(path):
    with urllib.request.urlopen(base + path, timeout=30) as r:
        return json.load(r)

# The validator is not vacuous: a document without `tilejson` fails it.
if validator.is_valid({"tiles": [], "vector_layers": []}):
    sys.exit("error: the schema accepted a document with no `tilejson`")

checked, failures = 0, []
for summary in get("/v1/worlds")["worlds"]:
    world = get(summary["url"])
    for layer in world["layers"]:
        for product in world["products"]:
            path = f"{summary['url']}/tilejson.json?layer={layer['name']}&product={product}&t=0"
            doc = get(path)
            errors = [e.message for e in validator.iter_errors(doc)]
            t = doc["tiles"][0]
            if not t.startswith(base + "/") or not all(p in t for p in ("{z}", "{x}", "{y}")):
                errors.append(f"tile template {t} is not absolute with {{z}}/{{x}}/{{y}}")
            if doc["tilejson"] != "3.0.0" or not doc["minzoom"] <= doc["maxzoom"] or len(doc["bounds"]) != 4:
                errors.append("tilejson, zoom range or bounds")
            # The template serves the tile.
            url = t.replace("{z}", str(doc["maxzoom"])).replace("{x}", "0").replace("{y}", "0")
            with urllib.request.urlopen(url, timeout=60) as r:
                if r.status != 200:
                    errors.append(f"{url}: {r.status}")
            if errors:
                failures.append((path, errors))
            checked += 1
for path, errors in failures:
    print(f"FAILED {path}: {errors}")
print(f"{checked} TileJSON documents checked against the TileJSON 3.0.0 schema, {len(failures)} failed")
sys.exit(1 if failures or checked == 0 else 0)
EOF
if grep -q "panicked" "$work/server.log"; then
  echo "error: the server panicked" >&2
  cat "$work/server.log" >&2
  exit 1
fi
exit $status
