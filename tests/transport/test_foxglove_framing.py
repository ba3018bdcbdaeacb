"""The Foxglove view draws the planner's lifted framing boxes (CubePrimitive) from its diagnostics."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

pytest.importorskip("foxglove", reason="the foxglove extra is not installed")

from aes_planner.messages import Diagnostics
from aes_planner.node.planner import box_values
from aes_planner.search.framing import Region, Subject
from aes_planner.transport.foxglove_view import foxglove_view, framing_boxes, view_channels


def test_planner_diagnostics_show_the_subjects_box():
    yaw = 0.4
    axes = np.array([[math.cos(yaw), math.sin(yaw), 0.0], [-math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    sub = Subject(Region("a.png", 0, 0, 4, 4), np.array([1.0, 2.0, 0.5]), axes, np.array([0.3, 0.2, 0.5]))
    values = {**box_values("framing.box0.keep", sub), "framing.box1.avoid.cx": 1.0, "latency_p50_s": 0.2}
    boxes = framing_boxes(values)  # the avoid box is incomplete: left out
    assert len(boxes) == 1 and boxes[0][0] == "keep"
    np.testing.assert_allclose(boxes[0][2], [0.6, 0.4, 1.0])
    assert boxes[0][3] == pytest.approx(yaw)
    out = foxglove_view("planner/diagnostics", Diagnostics(3.0, "planner", "idle", {}, values), 0)
    scene = [m for m in out if m.topic == "/planner/diagnostics/framing"]
    assert len(scene) == 1
    assert scene[0].schema_name == "foxglove.SceneUpdate"
    data = scene[0].data  # protobuf: a Vector3's doubles are 8 little-endian bytes each
    for v in (0.6, 0.4, 1.0, 2.0, math.sin(yaw / 2)):  # size, centre y, the yaw's quaternion
        assert struct.pack("<d", v) in data, v
    names = [c[0] for c in view_channels("planner/diagnostics", Diagnostics)]
    assert "/planner/diagnostics/framing" in names
    # no framing active: the scene is cleared (an update with no entities), other nodes get none
    out = foxglove_view("planner/diagnostics", Diagnostics(4.0, "planner", "idle"), 0)
    assert [m.topic for m in out if m.topic.endswith("/framing")] == ["/planner/diagnostics/framing"]
    out = foxglove_view("gimbal/diagnostics", Diagnostics(4.0, "gimbal", "idle"), 0)
    assert not [m for m in out if m.topic.endswith("/framing")]
