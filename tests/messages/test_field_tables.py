"""Each message type's field table is its whole wire layout: every dataclass field is on the wire
(so a field added to the class but not to ``FIELDS`` fails here, not silently on the bus), and every
table describes itself as JSON."""

import dataclasses
import json

import pytest

from aes_planner.messages import MESSAGE_TYPES, Candidate, describe

NOT_ON_THE_WIRE = {"extras"}  # PosedFrame's in-process side data, documented as never serialised


def _wire_roots(fields) -> set[str]:
    return {f.name.split(".")[0] for f in fields}


@pytest.mark.parametrize("cls", [*MESSAGE_TYPES.values(), Candidate], ids=lambda c: c.__name__)
def test_every_dataclass_field_is_in_the_table(cls):
    declared = {f.name for f in dataclasses.fields(cls)} - NOT_ON_THE_WIRE
    assert declared == _wire_roots(cls.FIELDS)


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_descriptions_are_json_with_versions_that_only_grow(name):
    cls = MESSAGE_TYPES[name]
    d = json.loads(json.dumps(describe(cls)))
    assert d["type"] == name and d["schema_version"] == cls.SCHEMA_VERSION
    since = [f.get("since", 1) for f in d["fields"]]
    assert since == sorted(since) and max(since) <= cls.SCHEMA_VERSION  # new fields only at the end
    for f in d["fields"]:
        if "since" in f:
            assert "default" in f
