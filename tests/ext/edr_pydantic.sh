#!/usr/bin/env bash
# The OGC API – EDR documents through the Python validators users run, unmodified
# (versions pinned in scripts/test, named in README): edr-pydantic on the landing page
# (with and without the trailing slash), the conformance declaration, the collection
# list and every collection (configured worlds and a seed; the server has no
# instances: a world is one deterministic run); covjson-pydantic on every
# CoverageJSON answer of tests/ext/lib/edr_queries.py (position, area, radius,
# cube). Each model is first
# shown to refuse a document it must refuse, so a pass is not vacuous. Runs against
# `cloudscape serve` on the tests' small world. Installs nothing: fails with a message
# when a package is missing (./scripts/test puts them in target/test-venv).
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

need_python edr_pydantic covjson_pydantic
start_server target/edr-pydantic --config tests/data/small.toml

status=0
"$PY" - "$base" <<'EOF' || status=$?
import sys
sys.path.insert(0, "tests/ext/lib")
import edr_queries, schema_check
from pydantic import ValidationError
from edr_pydantic.capabilities import ConformanceModel, LandingPageModel
from edr_pydantic.collections import Collection, Collections
from covjson_pydantic.coverage import Coverage

base = sys.argv[1]

def problems(model, body):
    """What `model` finds wrong with the JSON text `body` (empty: valid)."""
    try:
        model.model_validate_json(body)
        return []
    except ValidationError as e:
        found = [f"{'/'.join(map(str, err['loc']))}: {err['msg']}" for err in e.errors()]
        return found[:8] + ([f"… {len(found)} errors in all"] if len(found) > 8 else [])

# Not vacuous: each model refuses what its standard forbids.
for model, bad, what in [
    (LandingPageModel, b'{"title": "no links"}', "a landing page without links"),
    (Collection, b'{"id": "x", "links": [], "extent": {}, "parameter_names": {}, "layers": []}',
     "a collection with an unknown member"),
    (Coverage, b'{"type": "Coverage", "domain": {"type": "Domain", "axes": {"x": {"values": [1]}},'
               b' "referencing": [{"coordinates": ["x"], "system": {"type": "EngineeringCRS"}}]},'
               b' "ranges": {}}', "a reference system of a type CoverageJSON does not define"),
]:
    if not problems(model, bad):
        sys.exit(f"error: {model.__name__} accepted {what}")

report = schema_check.Report()
def check(path, model, media="application/json"):
    answer = edr_queries.Answer(base, path)
    errors = answer.problems(media)
    report.add(path, errors or problems(model, answer.body))

check("/v1/edr", LandingPageModel)
check("/v1/edr/", LandingPageModel)
check("/v1/edr/conformance", ConformanceModel)
check("/v1/edr/collections", Collections)
listed = edr_queries.get_json(base, "/v1/edr/collections")["collections"]
for id in [c["id"] for c in listed] + ["7"]:
    check(f"/v1/edr/collections/{id}", Collection)
for q in edr_queries.COVERAGE_QUERIES:
    check(f"{edr_queries.COLLECTION}/{q}", Coverage, "application/prs.coverage+json")
report.close("EDR documents and CoverageJSON answers checked with edr-pydantic and covjson-pydantic")
EOF
check_server
exit $status
