"""The wire format: exact round trips, and every kind of bad bytes refused with a reason."""

import math
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.messages import MESSAGE_TYPES, MessageError, PosedFrame, decode, encode, peek_header, to_jsonable
from aes_planner.messages.codec import HEADER_SIZE
from aes_planner.messages.samples import sample_messages

SAMPLES = sample_messages()
ENCODED = {name: encode(m) for name, m in SAMPLES.items()}


def assert_same(a, b):
    """Field by field; arrays exactly."""
    assert type(a) is type(b)
    for name, va in vars(a).items():
        if name == "extras":
            continue
        vb = getattr(b, name)
        if isinstance(va, np.ndarray):
            assert va.dtype == vb.dtype and np.array_equal(va, vb), name
        elif isinstance(va, list):
            assert len(va) == len(vb)
            for x, y in zip(va, vb):
                assert_same(x, y)
        elif hasattr(va, "__dataclass_fields__"):  # a nested struct (a suggestion's explore candidate)
            assert_same(va, vb)
        else:
            assert va == vb, name


def test_every_registered_type_has_a_sample():
    assert set(SAMPLES) == set(MESSAGE_TYPES)


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_round_trip_is_exact(name):
    msg = SAMPLES[name]
    data = encode(msg)
    header = peek_header(data)
    assert header.type_name == name and header.schema_version == type(msg).SCHEMA_VERSION
    assert header.payload_len == len(data) - HEADER_SIZE - len(name)
    back = decode(data, type(msg))
    assert_same(msg, back)
    assert encode(back) == data
    assert to_jsonable(back)["type"] == name


def test_png_frames_round_trip_losslessly():
    frame = SAMPLES["PosedFrame"]
    data = encode(frame, image_format="png")
    assert_same(frame, decode(data))
    with pytest.raises(MessageError, match="image_format"):
        encode(frame, image_format="jpeg")


def test_png_bomb_is_refused_before_decoding():
    frame = SAMPLES["PosedFrame"]
    data = bytearray(encode(frame, image_format="png"))
    ihdr = data.index(b"IHDR")
    data[ihdr + 4 : ihdr + 12] = struct.pack(">II", 100000, 100000)
    with pytest.raises(MessageError, match="PNG"):
        decode(bytes(data))


def test_wrong_type_version_and_trailing_bytes():
    data = ENCODED["GimbalCommand"]
    with pytest.raises(MessageError, match="expected a ViewSuggestion"):
        decode(data, MESSAGE_TYPES["ViewSuggestion"])
    bumped = bytearray(data)
    bumped[6:8] = struct.pack("<H", 99)
    with pytest.raises(MessageError, match="schema version 99"):
        decode(bytes(bumped))
    fmt = bytearray(data)
    fmt[4] = 2
    with pytest.raises(MessageError, match="wire format version 2"):
        decode(bytes(fmt))
    with pytest.raises(MessageError, match="truncated or padded"):
        decode(data + b"\0")
    with pytest.raises(MessageError, match="magic"):
        decode(b"PK\x03\x04" + data[4:])
    with pytest.raises(MessageError, match="unknown message type"):
        decode(data.replace(b"GimbalCommand", b"GimbalCommanX"))
    with pytest.raises(MessageError, match="expected bytes"):
        decode("not bytes")


def test_oversized_is_refused_by_the_cap_and_a_tighter_one():
    data = ENCODED["PosedFrame"]
    with pytest.raises(MessageError, match="exceed the cap of 100"):
        decode(data, max_bytes=100)
    huge = bytearray(ENCODED["Diagnostics"])
    huge[8:12] = struct.pack("<I", 1 << 30)
    with pytest.raises(MessageError):
        decode(bytes(huge) + bytes(70000))


def _patch_f64(data: bytes, old: float, new: float) -> bytes:
    needle = struct.pack("<d", old)
    assert data.count(needle) >= 1
    return data.replace(needle, struct.pack("<d", new), 1)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_numbers_are_refused(bad):
    cmd = _patch_f64(ENCODED["GimbalCommand"], 0.25, bad)
    with pytest.raises(MessageError, match="finite"):
        decode(cmd)
    frame = SAMPLES["PosedFrame"]
    c2w = _patch_f64(ENCODED["PosedFrame"], float(frame.cam2world[0, 3]), bad)
    with pytest.raises(MessageError, match="finite"):
        decode(c2w)


def test_non_rigid_rotation_wrong_dtype_and_shape_are_refused():
    frame = SAMPLES["PosedFrame"]
    scaled = _patch_f64(ENCODED["PosedFrame"], float(frame.cam2world[0, 0]), float(frame.cam2world[0, 0]) * 2)
    with pytest.raises(MessageError, match="orthonormal"):
        decode(scaled)
    data = bytearray(ENCODED["PosedFrame"])
    # the image array: dtype code 1 (u1), 3 dims, 6 x 8 x 3
    img = data.index(bytes([1, 3]) + struct.pack("<III", 6, 8, 3))
    wrong_dtype = bytearray(data)
    wrong_dtype[img] = 2
    with pytest.raises(MessageError, match="dtype"):
        decode(bytes(wrong_dtype))
    wrong_shape = bytearray(data)
    wrong_shape[img + 2 : img + 6] = struct.pack("<I", 7)
    with pytest.raises(MessageError):
        decode(bytes(wrong_shape))
    four_channels = bytearray(data)
    four_channels[img + 10 : img + 14] = struct.pack("<I", 4)
    with pytest.raises(MessageError):
        decode(bytes(four_channels))


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_every_truncation_is_refused(name):
    data = ENCODED[name]
    step = max(1, len(data) // 97)
    for n in range(0, len(data), step):
        with pytest.raises(MessageError):
            decode(data[:n])


def _no_nan(msg) -> None:
    for v in vars(msg).values():
        if isinstance(v, np.ndarray) and v.dtype.kind == "f":
            assert np.all(np.isfinite(v))
        elif isinstance(v, float):
            assert math.isfinite(v)
        elif isinstance(v, list):
            for c in v:
                _no_nan(c)
        elif isinstance(v, dict):
            assert all(math.isfinite(x) for x in v.values())


@given(st.binary(max_size=300))
def test_random_bytes_never_crash(data):
    try:
        _no_nan(decode(data))
    except MessageError:
        pass


@given(st.sampled_from(sorted(ENCODED)), st.data())
def test_bit_flips_never_crash_or_yield_nan(name, data):
    buf = bytearray(ENCODED[name])
    flips = data.draw(st.lists(st.integers(0, len(buf) * 8 - 1), min_size=1, max_size=4))
    for bit in flips:
        buf[bit // 8] ^= 1 << (bit % 8)
    try:
        msg = decode(bytes(buf))
    except MessageError:
        return
    _no_nan(msg)


@given(st.sampled_from(sorted(ENCODED)), st.data())
def test_spliced_garbage_never_crashes(name, data):
    buf = ENCODED[name]
    at = data.draw(st.integers(HEADER_SIZE, len(buf)))
    junk = data.draw(st.binary(min_size=1, max_size=16))
    try:
        _no_nan(decode(buf[:at] + junk + buf[at + len(junk) :]))
    except MessageError:
        pass


def test_frame_size_caps():
    from aes_planner.geometry import Intrinsics

    with pytest.raises(MessageError, match="at most"):
        PosedFrame(np.zeros((1, 9000, 3), np.uint8), Intrinsics.from_fov(9000, 1, 60.0), np.eye(4))
    with pytest.raises(MessageError, match="non-empty"):
        PosedFrame(np.zeros((0, 4, 3), np.uint8), Intrinsics.from_fov(4, 1, 60.0), np.eye(4))


@pytest.mark.parametrize("value", [1e300, -1e200, 1.5])
def test_huge_rotation_entries_are_refused_without_overflow(value):
    frame = SAMPLES["PosedFrame"]
    data = _patch_f64(ENCODED["PosedFrame"], float(frame.cam2world[0, 0]), value)
    with pytest.raises(MessageError, match="orthonormal"):
        decode(data)
    far = _patch_f64(ENCODED["PosedFrame"], float(frame.cam2world[0, 3]), 1e200)
    with pytest.raises(MessageError, match="translation"):
        decode(far)


def test_a_version_2_suggestion_decodes_without_coverage_or_explore():
    """Schema 3 appended ``covered_fraction`` and ``explore``: a version-2 message (the bytes a
    version-2 writer sends: the header's version 2, the payload without the appended fields)
    decodes with both absent."""
    from aes_planner.messages import ViewSuggestion

    old = ViewSuggestion(3.0, SAMPLES["ViewSuggestion"].candidates, 4, 2, mode="rig", kind="search")
    data = bytearray(encode(old))
    data = data[: len(data) - 2]  # both optional fields absent: one flag byte each
    struct.pack_into("<H", data, 6, 2)  # header bytes 6-7: the schema version
    struct.pack_into("<I", data, 8, len(data) - HEADER_SIZE - len("ViewSuggestion"))
    back = decode(bytes(data))
    assert back.covered_fraction is None and back.explore is None
    assert back.kind == "search" and len(back.candidates) == 2


def test_a_suggestion_refuses_a_coverage_outside_0_1_naming_the_field():
    from aes_planner.messages import ViewSuggestion

    with pytest.raises(MessageError, match="covered_fraction"):
        ViewSuggestion(1.0, [], covered_fraction=1.5)
    with pytest.raises(MessageError, match="covered_fraction"):
        ViewSuggestion(1.0, [], covered_fraction=math.nan)
    with pytest.raises(MessageError, match="explore"):
        ViewSuggestion(1.0, [], explore="left")
