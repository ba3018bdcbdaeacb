"""Garbage a node must not swallow: frames whose intrinsics, pose or joint angles
no real camera has are refused by the message's own validation, the same bounds the dataset
importers apply, so a subscription rejects and counts them; the planner rejects a frame that is not
the scene it models and counts it. None of them reaches the field."""

import math

import numpy as np
import pytest

from aes_planner.dataset.folder import DatasetError, check_intrinsics
from aes_planner.geometry.camera import Intrinsics, IntrinsicsError
from aes_planner.geometry.plausible import MAX_JOINT_RAD, MAX_LOCAL_DISTANCE_M, camera_problem
from aes_planner.messages import GimbalState, MessageError, PosedFrame, decode
from aes_planner.transport import InProcessBus
from tests.helpers import raw_intrinsics

H, W = 8, 12


def good_frame(**kw) -> PosedFrame:
    return PosedFrame(np.zeros((H, W, 3), np.uint8), Intrinsics(10.0, 10.0, 6.0, 4.0, W, H), np.eye(4), 1.0, **kw)


def forged(**changes) -> bytes:
    """The wire bytes of a frame with ``changes`` made after validation (what a careless or hostile
    sender puts on the bus)."""
    frame = good_frame(pan_rad=0.1, tilt_rad=0.2)
    for name, value in changes.items():
        setattr(frame, name, value)
    return frame.encode()


def far_pose(distance_m: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = [distance_m, 0.0, 0.0]
    return pose


BAD = {
    "fx_tiny": dict(intrinsics=raw_intrinsics(1e-300, 10.0, 6.0, 4.0, W, H)),
    "fy_tiny": dict(intrinsics=raw_intrinsics(10.0, 1e-300, 6.0, 4.0, W, H)),
    "all_huge": dict(intrinsics=raw_intrinsics(1e300, 1e300, 1e300, 1e300, W, H)),
    "fx_huge": dict(intrinsics=raw_intrinsics(1e300, 10.0, 6.0, 4.0, W, H)),
    "cx_far": dict(intrinsics=raw_intrinsics(10.0, 10.0, 1e6, 4.0, W, H)),
    "cy_negative": dict(intrinsics=raw_intrinsics(10.0, 10.0, 6.0, -50.0, W, H)),
    "pan_huge": dict(pan_rad=1e300),
    "tilt_huge": dict(tilt_rad=-1e300),
    "pan_three_turns": dict(pan_rad=3 * 2 * math.pi),
    "pose_far": dict(cam2world=far_pose(1e11)),
    "pose_far_negative": dict(cam2world=far_pose(-5e9)),
}


@pytest.mark.parametrize(
    "name", sorted(k for k in BAD if "intrinsics" in BAD[k] and camera_problem(BAD[k]["intrinsics"]))
)
def test_intrinsics_refuse_what_no_camera_has_where_they_are_built(name):
    k = BAD[name]["intrinsics"]
    with pytest.raises(IntrinsicsError, match="intrinsics"):
        Intrinsics(k.fx, k.fy, k.cx, k.cy, k.width, k.height)


@pytest.mark.parametrize("name", sorted(BAD))
def test_an_implausible_frame_does_not_decode(name):
    data = forged(**BAD[name])
    with pytest.raises(MessageError, match="PosedFrame"):
        decode(data, PosedFrame)


@pytest.mark.parametrize("name", sorted(BAD))
def test_a_subscription_rejects_and_counts_implausible_frames(name):
    bus = InProcessBus()
    sub = bus.subscribe("camera/frame", PosedFrame, depth=64)
    pub = bus.publisher("camera/frame", PosedFrame)
    for _ in range(10):
        pub.publish_raw(forged(**BAD[name]))
    pub.publish(good_frame())
    assert (sub.rejected, sub.received) == (10, 1), sub.stats()
    assert sub.latest().intrinsics.fx == 10.0  # nothing it had accepted is lost


@pytest.mark.parametrize("name", ["fx_tiny", "all_huge", "cx_far"])
def test_the_dataset_importers_apply_the_same_bounds(name):
    with pytest.raises(DatasetError, match="frames\\[0\\]"):
        check_intrinsics(BAD[name]["intrinsics"], "frames[0]")


def test_gimbal_states_with_implausible_joints_are_refused():
    with pytest.raises(MessageError, match="pan_rad"):
        GimbalState(1e300, 0.0, 0.0, 0.0, False, (30.0, 30.0), ())
    with pytest.raises(MessageError, match="goal_tilt_rad"):
        GimbalState(0.0, 0.0, 0.0, MAX_JOINT_RAD * 1.01, False, (30.0, 30.0), ())


def test_the_planner_rejects_and_counts_a_frame_that_is_not_its_scene():
    from aes_planner.node.planner import PlannerConfig, PlannerNode
    from aes_planner.platform import RigPlatformConfig
    from tests.node.nodekit import RIG, FakeTeacher, ScriptedProposer, frame_at

    node = PlannerNode(
        PlannerConfig(platform=RigPlatformConfig(RIG), active=False), proposer=ScriptedProposer(), teacher=FakeTeacher()
    )
    rig = ScriptedProposer().rig
    first = frame_at(rig, 0.0, 0.0, 1.0)
    node.step({"camera/frame": [first]}, 1.0)
    assert node.counters["frames_rejected"] == 0
    jump = frame_at(rig, 0.0, 0.0, 2.0)
    jump.cam2world = jump.cam2world.copy()
    jump.cam2world[0, 3] += 2 * MAX_LOCAL_DISTANCE_M
    node.step({"camera/frame": [jump]}, 2.0)
    assert node.counters["frames_rejected"] == 1
    assert node.diagnostics(2.0).counters["frames_rejected"] == 1  # in the node's diagnostics
    near = frame_at(rig, 0.1, 0.0, 3.0)
    node.step({"camera/frame": [near]}, 3.0)
    assert node.counters["frames_rejected"] == 1  # the next good frame is taken


@pytest.mark.parametrize(
    "matrix", ["[1e-300, 0, 32, 0, 50, 24, 0, 0, 1]", "[1e300, 0, 1e300, 0, 1e300, 1e300, 0, 0, 1]"]
)
def test_a_camera_calibration_no_camera_has_is_refused_at_start(tmp_path, clean_error, matrix):
    from aes_planner.drivers.camera import load_calibration

    (tmp_path / "cal.yaml").write_text(
        f"image_width: 64\nimage_height: 48\ncamera_matrix: {{rows: 3, cols: 3, data: {matrix}}}\n"
    )
    clean_error(load_calibration, tmp_path / "cal.yaml", match="calibration.camera_matrix")


def test_a_scene_camera_too_wide_for_a_real_one_is_refused(clean_error):
    from aes_planner.sim.spec import CameraSpec

    clean_error(CameraSpec, 64, 48, 179.9, match="field of view")
