"""The ros2 bench group's measurement: a subscriber process receives what the bridge sends."""

import os

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")


def test_group_is_registered_and_measures_bus_to_dds_latency():
    from aes_planner.bench import GROUPS
    from aes_planner.bench.ros2 import _measure
    from aes_planner.geometry import view_to_cam2world
    from aes_planner.messages import Candidate, ViewSuggestion

    assert GROUPS["ros2"] == "aes_planner.bench.ros2"
    c2w = view_to_cam2world(np.array([0.0, 0.0, 1.0, 0.2, 0.0]))

    def suggestion(t):
        return ViewSuggestion(t, [Candidate(c2w, 1.0)], 1, 1)

    lat = _measure(120 + os.getpid() % 30, "suggestion", suggestion, "planner/suggestion", 3, 20.0)
    assert len(lat) == 3 and all(0.0 < x < 5000.0 for x in lat)
