"""Sweep: what a broken ROS 2 rig sends the inbound bridge (a third sweep's cases and their kin).

Far-future joint states after a silence, images stamped days ahead, CameraInfo with absurd
distortion, an unknown distortion model or a focal length of 1e30, joint angles of 1e6 rad: each is
rejected and counted in the bridge's diagnostics, and good input afterwards is posed and forwarded
again (no message poisons the bridge for good)."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the ros2 extra (cyclonedds) is not installed")
pytest.importorskip("rosbags", reason="the ros2 extra (rosbags) is not installed")

from aes_planner.ros2.bridge import Ros2BridgeConfig, Ros2BridgeNode
from aes_planner.ros2.dds import DdsConfig
from aes_planner.sim import load_scene
from tests.helpers import raw_intrinsics, wait_for
from tests.ros2.stock import domain_for_tests
from tests.ros2.test_inbound import K, _camera_info, _image, _joint_state, peer  # noqa: F401

GOOD = np.full((K.height, K.width, 3), 100, np.uint8)


class Rig:
    """The bridge (inbound) and the writers of a ROS 2 rig on a test domain."""

    def __init__(self, ros):
        rig = load_scene("tabletop:1").rig.pan_tilt
        self.node = Ros2BridgeNode(
            Ros2BridgeConfig(dds=DdsConfig(domain_id=domain_for_tests()), inbound=True, rig=rig, outbound=())
        )
        self.node.start()
        self.info = ros.writer("/camera/camera_info", "sensor_msgs/msg/CameraInfo", "sensor_data")
        self.img = ros.writer("/camera/image_raw", "sensor_msgs/msg/Image", "sensor_data")
        self.js = ros.writer("/joint_states", "sensor_msgs/msg/JointState", "reliable")
        self.out: dict = {}

    def step(self):
        for k, v in self.node.step({}, time.time()).items():
            self.out.setdefault(k, []).extend(v)

    def frames(self) -> list:
        return self.out.get("camera/frame", [])

    def good_frame_comes_through(self, timeout_s: float = 20.0) -> bool:
        n = len(self.frames())

        def more():
            self.info.write(_camera_info())
            now = time.time()
            self.js.write(_joint_state(now - 0.05, pos=(0.2, -0.1)))
            self.js.write(_joint_state(now, pos=(0.2, -0.1)))
            self.img.write(_image(now - 0.02, GOOD))
            self.step()
            return len(self.frames()) > n

        return wait_for(more, timeout_s, 0.05)

    def rejected(self, key: str) -> int:
        return self.node.diagnostics(time.time()).counters.get(f"rejected.{key}", 0)


@pytest.fixture
def rig(peer):  # noqa: F811
    r = Rig(peer)
    yield r
    r.node.stop()


@pytest.mark.parametrize("ahead_s", [1e6, 3.0], ids=["1e6s-ahead", "3s-ahead"])
def test_far_future_joint_states_after_a_silence_do_not_stop_the_frames_for_good(rig, ahead_s):
    assert rig.good_frame_comes_through(), rig.node.counters
    # a silence (no joint states), then four joint states stamped ahead of the clock
    for _ in range(4):
        rig.js.write(_joint_state(time.time() + ahead_s, pos=(0.4, 0.1)))
    before = rig.rejected("joint_states_in")
    assert wait_for(lambda: rig.step() or rig.node.counters.get("received.joint_states_in", 0) >= 4, 20.0)
    if ahead_s > 5.0:  # beyond the stamp-ahead guard: rejected where it enters
        assert wait_for(lambda: rig.step() or rig.rejected("joint_states_in") >= before + 4, 20.0)
    assert rig.good_frame_comes_through(), rig.node.counters  # and images are posed again
    if ahead_s <= 5.0:  # inside the guard: the history started again when the clock came back
        assert rig.node.counters.get("joint_history_resets", 0) >= 1


def test_an_image_stamped_days_ahead_is_not_forwarded(rig):
    assert rig.good_frame_comes_through()
    n = len(rig.frames())
    rig.img.write(_image(time.time() + 11.6 * 86400, GOOD))
    assert wait_for(lambda: rig.step() or rig.rejected("image_in") >= 1, 20.0), rig.node.counters
    assert len(rig.frames()) == n
    assert all(f.stamp_s < time.time() + 5.0 for f in rig.frames())


@pytest.mark.parametrize(
    "info",
    [
        dict(d=(1e300, 0, 0, 0, 0)),
        dict(d=(-1e9, 0, 0, 0, 0)),
        dict(model="fisheye9000", d=(0.1, 0, 0, 0, 0)),
        dict(model="fisheye9000", d=(0.0,) * 5),
        dict(model="plumb_bob", d=(0.1,) * 9),
        dict(k=raw_intrinsics(1e30, 1e30, 16.0, 12.0, 32, 24)),
        dict(k=raw_intrinsics(1e-30, 1e-30, 16.0, 12.0, 32, 24)),
        dict(k=raw_intrinsics(30.0, 30.0, 1e9, 12.0, 32, 24)),
    ],
    ids=["d-1e300", "d-minus-1e9", "fisheye9000", "fisheye9000-zero-d", "plumb-bob-9", "fx-1e30", "fx-1e-30", "cx-1e9"],
)
def test_implausible_camera_info_is_refused_counted_and_not_used(rig, info):
    msg = _camera_info(k=info.get("k", K), d=info.get("d", (0.0,) * 5))
    if "model" in info:
        msg.distortion_model = info["model"]
    assert rig.good_frame_comes_through()
    rig.info.write(msg)
    assert wait_for(lambda: rig.step() or rig.rejected("camera_info_in") >= 1, 20.0), rig.node.counters
    k, d = rig.node._inbound.calibration
    assert k.fx == pytest.approx(K.fx) and not np.any(d)  # the good one is kept
    assert rig.good_frame_comes_through()


@pytest.mark.parametrize("pos", [(1e6, 0.0), (0.0, -1e300)])
def test_joint_angles_no_joint_reaches_are_refused(rig, pos):
    rig.js.write(_joint_state(time.time(), pos=pos))
    assert wait_for(lambda: rig.step() or rig.rejected("joint_states_in") >= 1, 20.0), rig.node.counters
    assert not rig.out.get("gimbal/state")
