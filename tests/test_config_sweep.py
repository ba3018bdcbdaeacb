"""Bad-input sweep: YAML files through aes_planner.config.load_yaml and from_dict.

Every case ends in a ConfigError whose one-line message names the problem, in bounded time and
memory, or in the documented value.
"""

import string
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.config import YAML_MAX_BYTES, ConfigError, from_dict, load_yaml, load_yaml_text, short_repr

BOMB = 'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n' + "\n".join(
    f"{c}: &{c} [" + ",".join([f"*{p}"] * 9) + "]" for p, c in zip("abcdefgh", "bcdefghi")
)

BAD_YAML = [
    (BOMB, "expands to more than"),
    ("a: 1\nb: 2\na: 3\n", "duplicate key 'a'"),
    ("outer:\n  x: 1\n  x: 2\n", "duplicate key 'x'"),
    ("[" * 100 + "]" * 100, "nested deeper than"),
    ("[" * 20000 + "]" * 20000, "nested too deeply"),
    ("a: &x [1, *x]\n", "recursive alias"),
    ("? [1, 2]\n: 3\n", "plain value"),
    ("a: b\n\x00", "special characters"),
    ("a: [1, 2\n", "not valid YAML"),
    ("a: *undefined\n", "not valid YAML"),
    ("!!python/object/apply:os.system ['true']\n", "not valid YAML"),
    ("a: !!binary 'AAAA'\nb: !!set {x}\nc: !custom 1\n", "not valid YAML"),
    ("{" + ", ".join(f"k{i}: {i}" for i in range(5)) + ", k0: 9}", "duplicate key 'k0'"),
]


@pytest.mark.parametrize("text, match", BAD_YAML, ids=range(len(BAD_YAML)))
def test_bad_yaml_is_one_clear_error(text, match, clean_error):
    err = clean_error(load_yaml_text, text, "f.yaml", match=match, seconds=20)
    assert str(err).startswith("f.yaml: ")


def test_yaml_files_that_are_not_yaml(tmp_path, clean_error):
    (tmp_path / "bin.yaml").write_bytes(bytes(range(256)) * 4)
    clean_error(load_yaml, tmp_path / "bin.yaml", match="not UTF-8")
    (tmp_path / "big.yaml").write_bytes(b"#" * (YAML_MAX_BYTES + 1))
    clean_error(load_yaml, tmp_path / "big.yaml", match="larger than")
    clean_error(load_yaml, tmp_path, match="is a folder")
    clean_error(load_yaml, tmp_path / "missing.yaml", match="file not found")
    (tmp_path / "empty.yaml").write_text("")
    assert load_yaml(tmp_path / "empty.yaml") is None


def test_yaml_1_2_numbers_and_merges_are_read():
    doc = load_yaml_text("a: 1e30\nb: -2E-5\nc: 1.5\nd: 7\ne: '1e3'\nbase: &b {x: 1}\nm: {<<: *b, y: 2}\n")
    assert doc["a"] == 1e30 and doc["b"] == -2e-5 and doc["c"] == 1.5 and doc["d"] == 7 and doc["e"] == "1e3"
    assert doc["m"] == {"x": 1, "y": 2}
    # a few aliases are fine: only their expansion is bounded
    assert load_yaml_text("m: &m {albedo: [1, 1, 1]}\nn: *m\n")["n"] == {"albedo": [1, 1, 1]}


@dataclass
class _Knobs:
    rate_hz: float = 1.0
    count: int = 1
    name: str = "x"
    flags: tuple[bool, bool] = (False, False)


@pytest.mark.parametrize(
    "data, match",
    [
        ({"rate_hz": "fast"}, "rate_hz: expected a number"),
        ({"rate_hz": float("nan")}, "finite"),
        ({"rate_hz": [1.0] * 100000}, "rate_hz: expected a number"),
        ({"count": 1.5}, "count: expected an integer"),
        ({"count": True}, "count: expected an integer"),
        ({"name": 3}, "name: expected a string"),
        ({"flags": [True]}, "expected 2 values"),
        ({"flags": "x" * 1_000_000}, "flags: expected a list"),
        ({"speed": 1}, "unknown key"),
        ([1, 2], "expected a mapping"),
    ],
)
def test_from_dict_errors_are_bounded_and_named(data, match, clean_error):
    clean_error(from_dict, _Knobs, data, match=match)


def test_short_repr_bounds_any_value():
    nested: list = []
    for _ in range(500):
        nested = [nested]
    for value in ("x" * 10**6, list(range(10**5)), {i: i for i in range(10**4)}, nested):
        assert len(short_repr(value)) <= 200


@given(st.text(alphabet=string.printable, max_size=300))
def test_any_text_loads_or_raises_config_error(text):
    try:
        load_yaml_text(text)
    except ConfigError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 1200


@pytest.mark.slow
@given(st.text(max_size=2000))
def test_any_unicode_text_loads_or_raises_config_error_slow(text):
    try:
        load_yaml_text(text)
    except ConfigError as exc:
        assert "\n" not in str(exc)


def test_a_post_init_that_breaks_on_a_value_is_a_config_error(clean_error):
    # The shared mechanism: whatever a dataclass's own check trips over is named, not a traceback.
    from dataclasses import dataclass

    from aes_planner.config import from_dict

    @dataclass
    class Odd:
        n: int = 1

        def __post_init__(self):
            float(2**self.n)  # OverflowError for a big n

    clean_error(from_dict, Odd, {"n": 5000}, "block", match="block: invalid value (OverflowError")
