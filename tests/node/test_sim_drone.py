"""SimDrone: speed and acceleration limits, the flight box, convergence; SimDroneNode frames."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.node.sim_drone import SimDrone, SimDroneConfig
from aes_planner.platform import DroneBox

BOX = DroneBox((-2.0, -2.0, 0.5), (2.0, 2.0, 2.5))


def test_converges_within_limits():
    cfg = SimDroneConfig(max_speed_m_s=1.0, max_accel_m_s2=2.0)
    d = SimDrone(BOX, cfg, [0, 0, 1, 0, 0])
    d.set_target([1.5, -1.0, 2.0, math.radians(120), math.radians(-20)])
    dt, prev_v = 0.02, np.zeros(3)
    for _ in range(1000):
        d.advance(dt)
        v = d.velocity_m_s
        assert np.linalg.norm(v) <= cfg.max_speed_m_s + 1e-9
        assert np.linalg.norm(v - prev_v) <= cfg.max_accel_m_s2 * dt + 1e-6
        prev_v = v.copy()
    assert d.view == pytest.approx([1.5, -1.0, 2.0, math.radians(120), math.radians(-20)], abs=1e-3)


@given(st.lists(st.floats(-1e6, 1e6), min_size=5, max_size=5), st.floats(1e-4, 1.0))
def test_stays_in_its_box_whatever_the_target(target, dt):
    d = SimDrone(BOX)
    d.set_target(target)
    for _ in range(50):
        d.advance(dt)
        assert BOX.contains(d.position_m)
        assert np.all(np.isfinite(d.view))
        assert math.radians(-80) - 1e-9 <= d.pitch_rad <= math.radians(60) + 1e-9


def test_nonfinite_target_refused():
    d = SimDrone(BOX)
    with pytest.raises(Exception, match="finite"):
        d.set_target([0, 0, float("nan"), 0, 0])


def test_sim_drone_node_flies_the_top_candidate():
    from aes_planner.graph.base import LaunchContext
    from aes_planner.messages import Candidate, ViewSuggestion
    from aes_planner.node.sim_drone import SimDroneNode, SimDroneNodeConfig

    node = SimDroneNode(
        SimDroneNodeConfig(rate_hz=5.0, camera={"width": 32, "height": 24}), context=LaunchContext("indoor:3")
    )
    start = node.drone.view.copy()
    goal = node.drone.cam2world()
    goal[:3, 3] += [0.3, 0.2, 0.0]
    sugg = ViewSuggestion(0.0, [Candidate(goal, 1.0)], mode="free")
    out = node.step({"planner/suggestion": [sugg]}, 0.0)
    for i in range(1, 40):
        out = node.step({}, 0.1 * i)
    assert node.drone.position_m == pytest.approx(goal[:3, 3], abs=1e-3)
    assert not np.allclose(node.drone.view, start)
    assert out["camera/frame"] == [] or out["camera/frame"][0].image.shape == (24, 32, 3)
