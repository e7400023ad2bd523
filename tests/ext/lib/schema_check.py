"""Shared by the external suites that validate answers against a published JSON
schema (tilejson_schema.sh, coveragejson_schema.sh): the validator, and the report of
what was checked. Imported with tests/ext/lib on sys.path."""
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


class Report:
    """The documents checked so far and those that failed."""

    def __init__(self):
        self.checked = 0
        self.failures = []

    def add(self, path, errors):
        """One document checked: `errors` says what is wrong with it (empty: nothing)."""
        self.checked += 1
        if errors:
            self.failures.append((path, errors))

    def close(self, what):
        """Prints each failure and the count; exits 1 when any failed or none was checked."""
        for path, errors in self.failures:
            print(f"FAILED {path}: {errors}")
        print(f"{self.checked} {what}, {len(self.failures)} failed")
        sys.exit(1 if self.failures or self.checked == 0 else 0)
