#!/usr/bin/env bash
# TileJSON conformance: every world's /tilejson.json, for every layer and tile product,
# validated against the official TileJSON 3.0.0 JSON schema
# (tests/data/tilejson-3.0.0.schema.json, from github.com/mapbox/tilejson-spec
# 3.0.0/schema.json) with the Python `jsonschema` package, plus what the schema cannot
# say: absolute URLs with {z}/{x}/{y}, minzoom <= maxzoom, four bounds, and templates
# that serve tiles as a generic client uses them. A document asked with `t` names that
# time; one asked without `t` must serve a tile when only {z}, {x} and {y} are filled
# (the world clock's current keyframe, cacheable until the next keyframe, never
# immutable), and its `cloudscape.keyframe_tiles` must serve each keyframe by its {t}.
# Runs against `cloudscape serve` on the tests' small world. Installs nothing: fails
# with a message when jsonschema is missing (./scripts/test puts it in
# target/test-venv).
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

need_python jsonschema
start_server target/tilejson --config tests/data/small.toml

status=0
"$PY" - "$base" tests/data/tilejson-3.0.0.schema.json <<'EOF' || status=$?
import json, sys, urllib.error, urllib.request
sys.path.insert(0, "tests/ext/lib")
import schema_check

base, schema_path = sys.argv[1], sys.argv[2]

def get(path):
    with urllib.request.urlopen(base + path, timeout=30) as r:
        return json.load(r)

validator = schema_check.validator(
    schema_path, {"tiles": [], "vector_layers": []}, "a document with no `tilejson`"
)

def fill(template, z, t=None):
    url = template.replace("{z}", str(z)).replace("{x}", "0").replace("{y}", "0")
    return url if t is None else url.replace("{t}", str(t))

def tile(url):
    """Status and headers of a GET; an HTTP error is an answer too."""
    try:
        with urllib.request.urlopen(url, timeout=60) as r:
            r.read()
            return r.status, r.headers
    except urllib.error.HTTPError as e:
        return e.code, e.headers

report = schema_check.Report()
for summary in get("/v1/worlds")["worlds"]:
    world = get(summary["url"])
    for layer in world["layers"]:
        for product in world["products"]:
            for time in ("&t=0", ""):
                path = f"{summary['url']}/tilejson.json?layer={layer['name']}&product={product}{time}"
                doc = get(path)
                errors = [e.message for e in validator.iter_errors(doc)]
                t = doc["tiles"][0]
                if not t.startswith(base + "/") or not all(p in t for p in ("{z}", "{x}", "{y}")):
                    errors.append(f"tile template {t} is not absolute with {{z}}/{{x}}/{{y}}")
                if doc["tilejson"] != "3.0.0" or not doc["minzoom"] <= doc["maxzoom"] or len(doc["bounds"]) != 4:
                    errors.append("tilejson, zoom range or bounds")
                # The template serves the tile with only {z}/{x}/{y} filled.
                url = fill(t, doc["maxzoom"])
                status, headers = tile(url)
                if status != 200:
                    errors.append(f"{url}: {status}")
                elif not time:
                    # The current keyframe: kept until the next one, never for ever.
                    cc = headers.get("Cache-Control", "")
                    if "immutable" in cc or "max-age=" not in cc or not headers.get("Content-Location"):
                        errors.append(f"{url}: Cache-Control `{cc}`, Content-Location "
                                      f"`{headers.get('Content-Location')}`")
                    # An animating client's template names each keyframe.
                    keyframed = fill(doc["cloudscape"]["keyframe_tiles"], doc["maxzoom"], 20)
                    status, headers = tile(keyframed)
                    if status != 200 or headers.get("X-Cloudscape-T") != "20":
                        errors.append(f"{keyframed}: {status}, X-Cloudscape-T {headers.get('X-Cloudscape-T')}")
                report.add(path, errors)
report.close("TileJSON documents checked against the TileJSON 3.0.0 schema")
EOF
check_server
exit $status
