#!/usr/bin/env bash
# CoverageJSON conformance of the OGC API – EDR routes: position (Point and
# PointSeries), area, radius and cube (Grid, with and without z levels) answers of
# `cloudscape serve` on the tests' small world (the queries of
# tests/ext/lib/edr_queries.py), each validated against the published
# OGC CoverageJSON 1.0 JSON schema (tests/data/coveragejson-1.0.schema.json: the
# bundle standard/schema/coveragejson.json of github.com/opengeospatial/CoverageJSON
# at commit bcfe98fe45014c093022077c9cf22dd05511cb1c, $id
# https://schemas.opengis.net/covjson/1.0/coveragejson.json) with the Python
# `jsonschema` package, plus what the schema cannot say: the media type, each range's
# shape against its axes, values counts, ordered unique times. Installs nothing:
# fails with a message when jsonschema is missing (./scripts/test puts it in
# target/test-venv). tests/ext/edr_pydantic.sh validates the same answers with
# covjson-pydantic.
set -euo pipefail
cd "$(dirname "$0")/../.."

source tests/ext/lib/server.sh
need_python jsonschema
start_server target/coveragejson --config tests/data/small.toml

"$PY" - "$base" tests/data/coveragejson-1.0.schema.json <<'EOF'
import json, sys
sys.path.insert(0, "tests/ext/lib")
import edr_queries, schema_check

base, schema_path = sys.argv[1], sys.argv[2]

validator = schema_check.validator(
    schema_path, {"type": "Coverage", "parameters": {}, "ranges": {}}, "a Coverage with no domain"
)

def axis_length(axis):
    return axis["num"] if "num" in axis else len(axis["values"])

report = schema_check.Report()
for path, answer in edr_queries.coverages(base):
    errors = answer.problems("application/prs.coverage+json")
    if answer.status != 200:
        report.add(path, errors)
        continue
    doc = json.loads(answer.body)
    errors += [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(doc)]
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
