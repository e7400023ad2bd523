#!/usr/bin/env bash
# OWSLib's OGC API – EDR client (`owslib.ogcapi.edr.EnvironmentalDataRetrieval`,
# version pinned in scripts/test, named in README), unmodified, end to end against
# `/v1/edr` on the tests' small world, as it forms its URLs: the landing page with and
# without the trailing slash, api() (the service-desc link it looks for), conformance(),
# collections(), collection(), data() (a collection link whose rel holds `data`), the
# position, area, cube and radius queries through query_data() with its
# `parameter_names` filter, and the items query through query_data() and
# collection_items(). A parameter the server does not know is refused with a 400 that
# names it, which OWSLib raises. Installs nothing: fails with a message when OWSLib is
# missing (./scripts/test puts it in target/test-venv).
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/ext/lib/server.sh

need_python owslib
start_server target/owslib --config tests/data/small.toml

status=0
"$PY" - "$base" <<'EOF' || status=$?
import json, sys
sys.path.insert(0, "tests/ext/lib")
import schema_check
from owslib.ogcapi.edr import EnvironmentalDataRetrieval

base = sys.argv[1]
report = schema_check.Report()

def case(name, check):
    """Runs `check`, which returns a list of what is wrong (or raises)."""
    try:
        errors = check()
    except Exception as e:
        errors = [f"{type(e).__name__}: {str(e)[:300]}"]
    report.add(name, errors)

def expect(cond, what):
    return [] if cond else [what]

for url in (f"{base}/v1/edr", f"{base}/v1/edr/"):
    edr = EnvironmentalDataRetrieval(url)
    case(f"landing page {url}", lambda: expect(
        {"self", "conformance", "data", "service-desc"} <= {l["rel"] for l in edr.links},
        f"links {edr.links} or the response {str(edr.response)[:200]}"))

edr = EnvironmentalDataRetrieval(f"{base}/v1/edr")
case("api()", lambda: expect(str(edr.api().get("openapi", "")).startswith("3."), "no OpenAPI document"))
case("conformance()", lambda: expect(
    "http://www.opengis.net/spec/ogcapi-edr-1/1.0/conf/core" in edr.conformance()["conformsTo"],
    "EDR core not declared"))
case("collections()", lambda: expect(
    [c["id"] for c in edr.collections()["collections"]] == ["default"], "the collection ids"))
case("collection()", lambda: expect(edr.collection("default")["id"] == "default", "the collection"))
case("data()", lambda: expect(edr.data() == ["default"], f"data() = {edr.data()}"))

def coverage(query_type, names, **kwargs):
    """A query through query_data: a Coverage holding exactly the parameters asked."""
    def check():
        c = edr.query_data("default", query_type, parameter_names=names, **kwargs)
        errors = expect(c.get("type") == "Coverage", f"not a Coverage: {str(c)[:200]}")
        errors += expect(sorted(c.get("ranges", {})) == sorted(names),
                         f"asked {names}, answered {sorted(c.get('ranges', {}))}")
        return errors
    case(f"query_data {query_type} {kwargs}", check)

coverage("position", ["density", "cloud_cover"], coords="POINT(150 250)", z=1050,
         datetime_="1970-01-01T00:00:20Z")
coverage("position", ["precipitation_rate"], coords="POINT(150 250)", datetime_="0/40")
coverage("area", ["cloud_cover"], coords="POLYGON((0 0, 3000 0, 0 2000, 0 0))", datetime_="0/20")
coverage("cube", ["cloud_top", "density"], bbox=[0, 0, 3000, 2000],
         datetime_="1970-01-01T00:00:00Z/1970-01-01T00:00:30Z")
coverage("cube", ["density"], bbox=[0, 0, 3000, 2000], z="1000/1200", datetime_="0")
# OWSLib sends no within-units (its query_data does not pass one): metres.
coverage("radius", ["density"], coords="POINT(1500 1500)", within=800, datetime_="10")

def radius_is_a_disc():
    c = edr.query_data("default", "radius", parameter_names=["cloud_cover"], coords="POINT(1500 1500)",
                       within=800, datetime_="10")
    x, y = c["domain"]["axes"]["x"], c["domain"]["axes"]["y"]
    values = c["ranges"]["cloud_cover"]["values"]
    errors = []
    for i, v in enumerate(values):
        col, row = i % x["num"], i // x["num"]
        px = x["start"] + col * (x["stop"] - x["start"]) / max(x["num"] - 1, 1)
        py = y["start"] + row * (y["stop"] - y["start"]) / max(y["num"] - 1, 1)
        inside = (px - 1500) ** 2 + (py - 1500) ** 2 <= 800 ** 2
        if inside != (v is not None):
            errors.append(f"column ({px}, {py}) is {'inside' if inside else 'outside'} but has {v}")
    return errors[:5]
case("radius: values inside the disc, null outside", radius_is_a_disc)

def features(fc):
    errors = expect(fc.get("type") == "FeatureCollection", f"not a FeatureCollection: {str(fc)[:200]}")
    return errors + expect(isinstance(fc.get("features"), list), "no features")
case("query_data items", lambda: features(
    edr.query_data("default", "items", bbox=[0, 0, 20000, 20000], datetime_="0/600")))
case("collection_items", lambda: features(
    edr.collection_items("default", bbox=[0, 0, 20000, 20000], datetime_="0/600", limit=5)))

def refused_by_name():
    try:
        edr.collection_items("default", bbox=[0, 0, 1000, 1000], datetime_="0/60", colour="blue")
    except RuntimeError as e:
        body = json.loads(str(e))
        return expect(body.get("error") == "unknown_parameter" and "colour" in body.get("message", ""),
                      f"the refusal does not name the parameter: {body}")
    return ["an unknown parameter was accepted"]
case("an unknown parameter is a 400 naming it", refused_by_name)

report.close("OWSLib EDR calls")
EOF
check_server
exit $status
