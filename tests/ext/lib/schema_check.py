"""Shared by the external suites that validate answers against a published JSON
schema (tilejson_schema.sh, coveragejson_schema.sh): the validator, and the closing
report. Imported with tests/ext/lib on sys.path."""
import json
import sys

import jsonschema


def validator(schema_path, refused, what):
    """A validator of the schema at `schema_path`, itself checked, and shown not to
    be vacuous: it must refuse the document `refused` (`what` names its flaw)."""
    schema = json.load(open(schema_path))
    validator_class = jsonschema.validators.validator_for(schema)
    validator_class.check_schema(schema)
    v = validator_class(schema)
    if v.is_valid(refused):
        sys.exit(f"error: the schema accepted {what}")
    return v


def report(checked, failures, what):
    """Prints each failure and the count; exits 1 when any failed or none was checked."""
    for path, errors in failures:
        print(f"FAILED {path}: {errors}")
    print(f"{checked} {what}, {len(failures)} failed")
    sys.exit(1 if failures or checked == 0 else 0)
