"""Inbound conversions never fail other than with Ros2InputError, and never yield NaN or a wrong size."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")

from aes_planner.ros2 import convert, idl
from aes_planner.ros2.convert import Ros2InputError

dims = st.integers(min_value=0, max_value=40)


@given(
    width=dims,
    height=dims,
    step=st.integers(min_value=0, max_value=200),
    encoding=st.sampled_from(["rgb8", "bgr8", "mono8", "yuv422", "16UC1", ""]),
    extra=st.integers(min_value=-5, max_value=5),
)
def test_image_decoding_accepts_exactly_consistent_images(width, height, step, encoding, extra):
    n = max(0, step * height + extra)
    msg = idl.Image(idl.Header(), height, width, encoding, 0, step, bytes(n))
    try:
        rgb = convert.decode_image(msg)
    except Ros2InputError:
        return
    ch = convert.IMAGE_ENCODINGS[encoding]
    assert extra == 0 and step >= width * ch and rgb.shape == (height, width, 3) and rgb.dtype == np.uint8


@given(data=st.binary(max_size=64), fmt=st.sampled_from(["jpeg", "png", "rgb8; jpeg compressed bgr8", "tiff"]))
def test_compressed_garbage_is_refused(data, fmt):
    with pytest.raises(Ros2InputError):
        convert.decode_compressed_image(idl.CompressedImage(idl.Header(), fmt, data))


finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.just(math.nan))


@given(
    names=st.lists(st.sampled_from(["pan", "tilt", "wrist", "elbow"]), max_size=4, unique=True),
    position=st.lists(finite_or_not, max_size=5),
    velocity=st.lists(st.floats(allow_nan=True), max_size=5),
)
def test_joint_states_give_finite_pairs_or_a_named_error(names, position, velocity):
    msg = idl.JointState(idl.Header(), names, position, velocity, [])
    try:
        joints = convert.joint_positions(msg, ("pan", "tilt"))
    except Ros2InputError as exc:
        assert str(exc).startswith("JointState")
        return
    if joints is not None:
        assert len(position) == len(names) and all(math.isfinite(v) for v in joints)


@given(k=st.lists(finite_or_not, min_size=9, max_size=9), d=st.lists(finite_or_not, max_size=16), w=dims, h=dims)
def test_camera_info_gives_valid_intrinsics_or_a_named_error(k, d, w, h):
    msg = idl.CameraInfo(idl.Header(), h, w, "plumb_bob", d, k)
    try:
        intr, dist = convert.decode_camera_info(msg)
    except Ros2InputError as exc:
        assert str(exc).startswith("CameraInfo")
        return
    assert intr.fx > 0 and intr.fy > 0 and np.all(np.isfinite(dist)) and (intr.width, intr.height) == (w, h)
