"""The OGC API – EDR queries whose CoverageJSON answers the external suites validate
(coveragejson_schema.sh against the published JSON schema, edr_pydantic.sh with
covjson-pydantic): every query type and domain type the server answers, on the tests'
small world (tests/data/small.toml). Imported with tests/ext/lib on sys.path."""
import json
import urllib.error
import urllib.parse
import urllib.request

COLLECTION = "/v1/edr/collections/default"

# Paths under COLLECTION: position (Point, PointSeries), area and radius (Grid with
# nulls outside), cube (Grid per column, and per cell of z levels).
COVERAGE_QUERIES = [
    "position?coords=POINT(150 250)&z=1050&datetime=1970-01-01T00:00:20Z",
    "position?coords=POINT(150 250)&datetime=0/40",
    "position?coords=POINT(150 250)&z=5100&datetime=0&layer=high&parameter-name=density",
    "area?coords=POLYGON((0 0, 3000 0, 0 2000, 0 0))&datetime=0/20",
    "area?coords=POLYGON((0 0, 6400 0, 6400 6400, 0 6400), (1000 1000, 2000 1000, 2000 2000, 1000 2000))&datetime=10&level=1",
    "cube?bbox=0,0,3000,2000&datetime=1970-01-01T00:00:00Z/1970-01-01T00:00:30Z",
    "cube?bbox=0,0,3000,2000&datetime=0&z=1000/1200",
    "cube?bbox=-2000,-2000,2000,2000&datetime=0/40&layer=high&parameter-name=cloud_cover,precipitation_rate",
    "radius?coords=POINT(1500 1500)&within=800&within-units=m&datetime=0/20",
    "radius?coords=POINT(0 0)&within=2&within-units=km&datetime=20&layer=high&parameter-name=cloud_top",
]


def url(base, path):
    """The absolute URL of a path with its query's spaces and parentheses encoded."""
    return base + urllib.parse.quote(path, safe="/?&=,:")


class Answer:
    """A GET's status, media type and body (an HTTP error is an answer too)."""

    def __init__(self, base, path):
        try:
            with urllib.request.urlopen(url(base, path), timeout=60) as r:
                self.status, self.media, self.body = r.status, r.headers.get("Content-Type"), r.read()
        except urllib.error.HTTPError as e:
            self.status, self.media, self.body = e.code, e.headers.get("Content-Type"), e.read()

    def problems(self, media):
        """What is wrong with the answer before its body is read: not a 200 of `media`."""
        if self.status != 200:
            return [f"HTTP {self.status}: {self.body[:300].decode(errors='replace')}"]
        return [] if self.media == media else [f"media type {self.media}"]


def coverages(base):
    """(path, answer) of every query of COVERAGE_QUERIES."""
    for q in COVERAGE_QUERIES:
        path = f"{COLLECTION}/{q}"
        yield path, Answer(base, path)


def get_json(base, path):
    """The JSON of a GET that must answer 200."""
    answer = Answer(base, path)
    if answer.status != 200:
        raise SystemExit(f"error: {path} answered {answer.status}: {answer.body[:300]}")
    return json.loads(answer.body)
