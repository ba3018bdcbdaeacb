"""from_dict keeps the precise error of a value inside an optional section."""

from dataclasses import dataclass
from typing import Literal

import pytest

from aes_planner.config import ConfigError, from_dict, require_numbers


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


@dataclass
class _Knobs:
    rate_hz: object = 1.0
    delay_s: object = 0.0


@pytest.mark.parametrize(
    "rate, delay, strict, bad",
    [
        (1.0, 0.0, False, None),
        (1.0, 0.0, True, "delay_s"),  # 0 is not > 0
        (float("nan"), 0.0, False, "rate_hz"),
        (float("inf"), 0.0, False, "rate_hz"),
        (True, 0.0, False, "rate_hz"),  # a bool is no number
        ("1", 0.0, False, "rate_hz"),
        (1.0, -1e-9, False, "delay_s"),
    ],
)
def test_require_numbers_names_the_first_bad_field(rate, delay, strict, bad):
    knobs = _Knobs(rate, delay)
    if bad is None:
        require_numbers(knobs, ("rate_hz", "delay_s"), strict=strict)
        return
    with pytest.raises(ConfigError, match=rf"^{bad}: must be a finite number >=? 0") as info:
        require_numbers(knobs, ("rate_hz", "delay_s"), strict=strict)
    assert info.value.key == bad
