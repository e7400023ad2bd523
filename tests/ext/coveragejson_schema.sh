#!/usr/bin/env bash
# CoverageJSON conformance of the OGC API – EDR routes: position (Point and
# PointSeries), area and cube (Grid, with and without z levels) answers of
# `cloudscape serve` on the tests' small world, each validated against the published
# OGC CoverageJSON 1.0 JSON schema (tests/data/coveragejson-1.0.schema.json: the
# bundle standard/schema/coveragejson.json of github.com/opengeospatial/CoverageJSON
# at commit bcfe98fe45014c093022077c9cf22dd05511cb1c, $id
# https://schemas.opengis.net/covjson/1.0/coveragejson.json) with the Python
# `jsonschema` package, plus what the schema cannot say: the media type, each range's
# shape against its axes, values counts, ordered unique times. Installs nothing:
# fails with a message when jsonschema is missing (./scripts/test puts it in
# target/test-venv).
set -euo pipefail
cd "$(dirname "$0")/../.."

source tests/ext/lib/server.sh
need_python jsonschema
start_server target/coveragejson --config tests/data/small.toml

"$PY" - "$base" tests/data/coveragejson-1.0.schema.json <<'EOF'
import json, sys, urllib.parse, urllib.request
sys.path.insert(0, "tests/ext/lib")
import schema_check

base, schema_path = sys.argv[1], sys.argv[2]

validator = schema_check.validator(
    schema_path, {"type": "Coverage", "parameters": {}, "ranges": {}}, "a Coverage with no domain"
)

collection = "/v1/edr/collections/default"
queries = [
    "position?coords=POINT(150 250)&z=1050&datetime=1970-01-01T00:00:20Z",
    "position?coords=POINT(150 250)&datetime=0/40",
    "position?coords=POINT(150 250)&z=5100&datetime=0&layer=high&parameter-name=density",
    "area?coords=POLYGON((0 0, 3000 0, 0 2000, 0 0))&datetime=0/20",
    "area?coords=POLYGON((0 0, 6400 0, 6400 6400, 0 6400), (1000 1000, 2000 1000, 2000 2000, 1000 2000))&datetime=10&level=1",
    "cube?bbox=0,0,3000,2000&datetime=1970-01-01T00:00:00Z/1970-01-01T00:00:30Z",
    "cube?bbox=0,0,3000,2000&datetime=0&z=1000/1200",
    "cube?bbox=-2000,-2000,2000,2000&datetime=0/40&layer=high&parameter-name=cloud_cover,precipitation_rate",
]

def axis_length(axis):
    return axis["num"] if "num" in axis else len(axis["values"])

report = schema_check.Report()
for q in queries:
    path = f"{collection}/{q}"
    url = base + urllib.parse.quote(path, safe="/?&=,:")
    with urllib.request.urlopen(url, timeout=60) as r:
        media = r.headers.get("Content-Type")
        doc = json.load(r)
    errors = [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(doc)]
    if media != "application/prs.coverage+json":
        errors.append(f"media type {media}")
    axes = doc["domain"]["axes"]
    times = axes["t"]["values"]
    if times != sorted(set(times)):
        errors.append(f"times not increasing and unique: {times}")
    for name, nd in doc["ranges"].items():
        shape = nd.get("shape", [])
        size = 1
        for n in shape:
            size *= n
        if len(nd["values"]) != size:
            errors.append(f"{name}: {len(nd['values'])} values for shape {shape}")
        for axis, n in zip(nd.get("axisNames", []), shape):
            if axis not in axes or axis_length(axes[axis]) != n:
                errors.append(f"{name}: axis {axis} of length {n} does not match the domain")
        if set(doc["parameters"]) != set(doc["ranges"]):
            errors.append("parameters and ranges differ")
    report.add(path, errors)
report.close("EDR answers checked against the CoverageJSON 1.0 schema")
EOF
check_server
