"""from_dict keeps the precise error of a value inside an optional section."""

from dataclasses import dataclass
from typing import Literal

import pytest

from aes_planner.config import ConfigError, from_dict


@dataclass
class _Pattern:
    kind: Literal["checker", "stripes"]


@dataclass
class _Material:
    pattern: _Pattern | None = None


def test_optional_section_keeps_the_inner_key_and_message():
    with pytest.raises(ConfigError, match=r"material\.pattern\.kind: must be one of \['checker', 'stripes'\]") as info:
        from_dict(_Material, {"pattern": {"kind": "dots"}}, "material")
    assert info.value.key == "material.pattern.kind"


def test_optional_section_may_be_absent_or_null():
    assert from_dict(_Material, {}).pattern is None
    assert from_dict(_Material, {"pattern": None}).pattern is None
    assert from_dict(_Material, {"pattern": {"kind": "stripes"}}).pattern == _Pattern("stripes")
