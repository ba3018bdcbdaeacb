"""PosedFrame validates every field and names it."""

import numpy as np
import pytest

from aes_planner.geometry import Intrinsics, view_to_cam2world
from aes_planner.messages import MessageError, PosedFrame


def frame(**overrides):
    kw = dict(
        image=np.zeros((4, 6, 3), np.uint8),
        intrinsics=Intrinsics.from_fov(6, 4, 60.0),
        cam2world=view_to_cam2world(np.array([0, 0, 1.0, 0.2, 0.1])),
        stamp_s=1.5,
        depth_m=np.ones((4, 6), np.float32),
    )
    kw.update(overrides)
    return PosedFrame(**kw)


def test_valid_frame():
    f = frame(cam2world=view_to_cam2world(np.array([0, 0, 1.0, 0.2, 0.1]))[:3])
    assert f.cam2world.shape == (4, 4) and f.width == 6 and f.height == 4


@pytest.mark.parametrize(
    "overrides, match",
    [
        (dict(image=np.zeros((4, 6), np.uint8)), "image"),
        (dict(image=np.zeros((4, 6, 3), np.float32)), "uint8"),
        (dict(intrinsics=Intrinsics.from_fov(8, 4, 60.0)), "Intrinsics.scaled"),
        (dict(cam2world=np.diag([1.0, 2.0, 1.0, 1.0])), "cam2world.*orthonormal"),
        (dict(stamp_s=float("nan")), "stamp_s"),
        (dict(depth_m=np.ones((4, 5), np.float32)), "depth_m"),
        (dict(depth_m=np.full((4, 6), np.inf, np.float32)), "depth_m.*finite"),
        (dict(depth_m=-np.ones((4, 6), np.float32)), "depth_m"),
    ],
)
def test_bad_fields_are_named(overrides, match):
    with pytest.raises(MessageError, match=match):
        frame(**overrides)
