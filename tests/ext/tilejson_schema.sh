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
source tests/ext/lib/server.sh

need_python jsonschema
start_server target/tilejson --config tests/data/small.toml

status=0
"$PY" - "$base" tests/data/tilejson-3.0.0.schema.json <<'EOF' || status=$?
import json, sys, urllib.request
sys.path.insert(0, "tests/ext/lib")
import schema_check

base, schema_path = sys.argv[1], sys.argv[2]

def get(path):
    with urllib.request.urlopen(base + path, timeout=30) as r:
        return json.load(r)

validator = schema_check.validator(
    schema_path, {"tiles": [], "vector_layers": []}, "a document with no `tilejson`"
)

report = schema_check.Report()
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
            report.add(path, errors)
report.close("TileJSON documents checked against the TileJSON 3.0.0 schema")
EOF
check_server
exit $status
