"""Framing over ROS 2: a stock sensor_msgs/RegionOfInterest on /planner/keep and /planner/avoid
becomes a PlannerRequest that sets the planner's keep/avoid regions."""

from __future__ import annotations

import pytest

pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")
pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")

from aes_planner.messages import PlannerRequest
from aes_planner.messages.codec import decode
from aes_planner.ros2.bridge import Ros2BridgeConfig, Ros2BridgeNode
from aes_planner.ros2.dds import DdsConfig
from tests.helpers import wait_for
from tests.ros2.stock import Peer, domain_for_tests, make


def _roi(x, y, w, h):
    return make("sensor_msgs/msg/RegionOfInterest", x_offset=x, y_offset=y, width=w, height=h, do_rectify=False)


@pytest.fixture
def peer():
    p = Peer(domain_for_tests())
    yield p
    p.close()


def test_region_of_interest_sets_keep_and_avoid(peer):
    node = Ros2BridgeNode(Ros2BridgeConfig(dds=DdsConfig(domain_id=domain_for_tests()), outbound=(), keep_margin=0.1))
    assert "planner/request" in node.outputs
    node.start()
    try:
        keep = peer.writer("/planner/keep", "sensor_msgs/msg/RegionOfInterest")
        avoid = peer.writer("/planner/avoid", "sensor_msgs/msg/RegionOfInterest")
        got: list[PlannerRequest] = []

        def until(n, writer, sample):
            def step():
                if len(got) < n:
                    writer.write(sample)  # again until the reader has matched the writer
                got.extend(node.step({}, 0.0)["planner/request"])
                return len(got) >= n

            assert wait_for(step, 30.0, 0.05), node.counters

        until(1, keep, _roi(21, 0, 40, 36))
        req = decode(got[-1].encode(), PlannerRequest)  # what goes over the bus
        assert req.set_framing and req.keep_margin == 0.1 and not req.avoid
        r = req.keep[0]
        assert (r.frame, r.x0, r.y0, r.x1, r.y1) == ("latest", 21.0, 0.0, 61.0, 36.0)
        n = len(got)
        until(n + 1, avoid, _roi(0, 40, 30, 20))
        assert [a.x1 for a in got[-1].avoid] == [30.0] and got[-1].keep == req.keep  # keep stays
        n = len(got)
        until(n + 1, keep, _roi(5, 5, 0, 10))  # zero size clears the kept subject
        assert got[-1].keep == [] and len(got[-1].avoid) == 1
    finally:
        node.stop()


def test_framing_in_can_be_turned_off():
    node = Ros2BridgeNode(Ros2BridgeConfig(dds=DdsConfig(domain_id=domain_for_tests()), outbound=(), framing_in=False))
    assert "planner/request" not in node.outputs
