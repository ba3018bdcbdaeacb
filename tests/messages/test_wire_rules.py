"""What docs/wire.md allows, the package's reader accepts; what it says a reader refuses, it refuses.

The messages are written by an encoder made from the page alone (below: struct and numpy, driven
by each type's JSON description, no aes_planner encoding), then fed to the package's ``decode``:
strings at their cap and one byte over it, the whole-message cap counting the header, arrays of
another element type or shape, text that is not printable, counters past 2^63 - 1, map keys out of
their alphabet.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

from aes_planner.messages import MESSAGE_TYPES, MessageError, decode, describe, encode
from aes_planner.messages.samples import sample_messages
from tests.transport.test_wire_doc import decode_with

SCALARS = {"u8": "<B", "u16": "<H", "u32": "<I", "u64": "<Q", "i64": "<q", "f64": "<d"}
DTYPE_CODES = {"u1": 1, "f4": 2, "f8": 3}


# ---------------------------------------------------------------- the independent encoder
def write_value(t: dict, v) -> bytes:
    kind = t["type"]
    if kind in SCALARS:
        return struct.pack(SCALARS[kind], v)
    if kind == "bool":
        return bytes([1 if v else 0])
    if kind == "str":
        b = v.encode("utf-8")
        return struct.pack("<H", len(b)) + b
    if kind == "bytes":
        return struct.pack("<I", len(v)) + bytes(v)
    if kind == "enum":
        return bytes([t["values"].index(v)])
    if kind == "optional":
        return b"\0" if v is None else b"\1" + write_value(t["value"], v)
    if kind == "array":  # the array's own dtype and shape: a test may write what the field does not declare
        a = np.ascontiguousarray(v)
        code = {np.dtype("<u1"): 1, np.dtype("<f4"): 2, np.dtype("<f8"): 3}[a.dtype.newbyteorder("<")]
        return (
            bytes([code, a.ndim])
            + b"".join(struct.pack("<I", d) for d in a.shape)
            + a.astype(a.dtype.newbyteorder("<")).tobytes()
        )
    if kind == "list":
        return struct.pack(SCALARS[t["count"]], len(v)) + b"".join(write_value(t["items"], x) for x in v)
    if kind == "fixed":
        return b"".join(write_value(t["items"], x) for x in v)
    if kind == "map":
        return struct.pack("<I", len(v)) + b"".join(
            write_value(t["key"], k) + write_value(t["value"], x) for k, x in v.items()
        )
    if kind == "struct":
        return write_fields(t["fields"], v)
    if kind == "union":
        tag, variant = next((int(k), var) for k, var in t["variants"].items() if var["name"] == v["variant"])
        return bytes([tag]) + write_fields(variant["fields"], v)
    raise AssertionError(kind)


def write_fields(fields: list[dict], values: dict) -> bytes:
    return b"".join(write_value(f, values[f["name"]]) for f in fields)


def encode_with(desc: dict, values: dict) -> bytes:
    """The header of docs/wire.md, then the fields in the order of the description."""
    name = desc["type"].encode("ascii")
    payload = write_fields(desc["fields"], values)
    return struct.pack("<4sBBHI", b"AESM", 1, len(name), desc["schema_version"], len(payload)) + name + payload


SAMPLES = sample_messages()


def values_of(type_name: str) -> tuple[dict, dict]:
    """(description, decoded field values) of the sample of ``type_name``, by the page's decoder."""
    desc = describe(MESSAGE_TYPES[type_name])
    values = decode_with(desc, encode(SAMPLES[type_name]))
    return desc, {k: v for k, v in values.items() if k not in ("type", "version")}


def _text_fields(desc: dict):
    """(field name, max_bytes, item) of every text field at the top of a table (a list of text too)."""
    for f in desc["fields"]:
        if f["type"] == "str":
            yield f["name"], f["max_bytes"], False
        if f["type"] == "list" and f["items"]["type"] == "str":
            yield f["name"], f["items"]["max_bytes"], True


# DroneState.link is text on the wire but one of two words ("ok", "lost"): its own rule, tested there.
TEXT = [
    (t, *field)
    for t in sorted(MESSAGE_TYPES)
    for field in _text_fields(describe(MESSAGE_TYPES[t]))
    if (t, field[0]) != ("DroneState", "link")
]


# ------------------------------------------------------------------------------ the tests
@pytest.mark.parametrize("type_name", sorted(MESSAGE_TYPES))
def test_the_independent_encoder_writes_what_the_package_writes(type_name):
    desc, values = values_of(type_name)
    assert encode_with(desc, values) == encode(SAMPLES[type_name])


@pytest.mark.parametrize(("type_name", "field", "cap", "is_list"), TEXT, ids=[f"{t[0]}.{t[1]}" for t in TEXT])
def test_text_up_to_its_cap_in_bytes_is_read_and_one_byte_more_is_refused(type_name, field, cap, is_list):
    desc, values = values_of(type_name)
    at_cap = "é" * (cap // 2) + "x" * (cap % 2)  # two bytes a character: the cap counts bytes
    assert len(at_cap.encode()) == cap
    values[field] = [at_cap] if is_list else at_cap
    data = encode_with(desc, values)
    if len(data) <= desc["max_bytes"]:
        msg = decode(data)
        got = getattr(msg, field)
        assert (got[0] if is_list else got) == at_cap
        assert encode(msg) == data  # and the package writes it back the same
    values[field] = [at_cap + "x"] if is_list else at_cap + "x"
    with pytest.raises(MessageError, match="cap"):
        decode(encode_with(desc, values))


@pytest.mark.parametrize("bad", ["tab\there", "line\nbreak", "nbsp\u00a0x", "bell\x07"])
def test_text_that_is_not_printable_is_refused(bad):
    desc, values = values_of("Diagnostics")
    values["state"] = bad
    with pytest.raises(MessageError, match="control"):
        decode(encode_with(desc, values))


def test_the_size_cap_counts_the_header():
    """A GimbalState of exactly 16,384 bytes in all is read; one of 16,385 is refused."""
    desc, values = values_of("GimbalState")
    values["hardware_error"] = []
    base = len(encode_with(desc, values))
    room = desc["max_bytes"] - base  # for the faults' bytes, each with its 2-byte length
    faults = []
    while room > 0:
        n = min(1024, room - 2)
        faults.append("f" * n)
        room -= n + 2
    values["hardware_error"] = faults
    data = encode_with(desc, values)
    assert len(data) == desc["max_bytes"] == 16384
    assert decode(data).hardware_error == tuple(faults)
    values["hardware_error"] = [*faults[:-1], faults[-1] + "f"]
    with pytest.raises(MessageError, match="exceed the cap of 16384"):
        decode(encode_with(desc, values))


@pytest.mark.parametrize(
    ("type_name", "field", "value", "match"),
    [
        ("PosedFrame", "cam2world", np.eye(4, dtype=np.float32), "dtype"),  # f4 where f8 is declared: no conversion
        ("PosedFrame", "cam2world", np.eye(4)[:3], r"expected \[4, 4\]"),  # [3, 4]: exactly [4, 4] on the wire
        ("PosedFrame", "cam2world", np.eye(4)[None], "dimensions"),
        ("DroneState", "position_m", np.zeros(2), r"expected \[3\]"),
        ("DroneState", "attitude_wxyz", np.array([1.0, 0, 0, 0, 0]), "cap"),
        ("Candidate", "cam2world", np.eye(4)[:3], r"expected \[4, 4\]"),
    ],
)
def test_arrays_of_another_element_type_or_shape_are_refused(type_name, field, value, match):
    if type_name == "Candidate":
        desc, values = values_of("ViewSuggestion")
        values["candidates"][0][field] = value
    else:
        desc, values = values_of(type_name)
        values[field] = value
    with pytest.raises(MessageError, match=match):
        decode(encode_with(desc, values))


def test_image_arrays_follow_their_declared_shape():
    desc, values = values_of("PosedFrame")
    pixels = values["image"]["pixels"]
    values["image"] = {"variant": "raw", "pixels": np.ascontiguousarray(pixels[..., :2])}  # 2 channels, not 3
    with pytest.raises(MessageError, match=r"expected \[<= 8192, <= 8192, 3\]"):
        decode(encode_with(desc, values))
    values["image"] = {"variant": "raw", "pixels": np.zeros((1, 8193, 3), np.uint8)}  # past max_shape
    with pytest.raises(MessageError, match="cap"):
        decode(encode_with(desc, values))
    values["image"] = {"variant": "raw", "pixels": pixels}
    values["depth_m"] = np.ones((3, 3), np.float32)  # another size than the image
    with pytest.raises(MessageError, match="depth_m"):
        decode(encode_with(desc, values))


@pytest.mark.parametrize(("link", "ok"), [("ok", True), ("lost", True), ("gone", False), ("", False)])
def test_a_drone_link_is_ok_or_lost(link, ok):
    desc, values = values_of("DroneState")
    values["link"] = link
    if ok:
        assert decode(encode_with(desc, values)).link == link
    else:
        with pytest.raises(MessageError, match="link"):
            decode(encode_with(desc, values))


def test_counters_stop_at_2_to_the_63_minus_1():
    desc, values = values_of("Diagnostics")
    values["sequence"] = (1 << 63) - 1
    assert decode(encode_with(desc, values)).sequence == (1 << 63) - 1
    values["sequence"] = 1 << 63
    with pytest.raises(MessageError, match="sequence"):
        decode(encode_with(desc, values))


@pytest.mark.parametrize("key", ["", "a b", "ü", "k" * 65])
def test_map_keys_outside_their_alphabet_are_refused(key):
    desc, values = values_of("Diagnostics")
    values["counters"] = {key: 1}
    with pytest.raises(MessageError):
        decode(encode_with(desc, values))
    values["counters"] = {"ok_key.1:a/b-c": 1}
    assert decode(encode_with(desc, values)).counters == {"ok_key.1:a/b-c": 1}
