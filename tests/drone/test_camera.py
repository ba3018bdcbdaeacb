"""The software-in-the-loop camera renders the pose a vehicle reports, and nothing when it is stale or lost."""

from pathlib import Path

import numpy as np

from aes_planner.drone.camera import DroneSimCameraNode, DroneSimCameraNodeConfig
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.graph.base import LaunchContext
from aes_planner.messages import DroneState

SCENE = str(Path(__file__).resolve().parents[1] / "scenes" / "garden_drone.yaml")


def test_frames_show_the_reported_pose_and_stop_when_the_link_is_lost():
    cam = DroneSimCameraNode(DroneSimCameraNodeConfig(rate_hz=10, depth=False), context=LaunchContext(scene=SCENE))
    c2w = view_to_cam2world(np.array([5000.0, -3000.0, 2.0, 0.3, -0.2]))
    assert cam.step({}, 10.0)["camera/frame"] == []  # no pose yet
    out = cam.step({"drone/state": [DroneState(10.0, c2w, mode="OFFBOARD", armed=True)]}, 10.05)["camera/frame"]
    assert len(out) == 1 and np.allclose(out[0].cam2world, c2w) and out[0].stamp_s == 10.05
    assert cam.step({}, 11.0)["camera/frame"] == []  # the newest pose is 1 s old: withheld
    lost = DroneState(11.1, c2w, link="lost")
    assert cam.step({"drone/state": [lost]}, 11.2)["camera/frame"] == []
    moved = view_to_cam2world(np.array([5001.0, -3000.0, 2.0, 0.0, 0.0]))
    out = cam.step({"drone/state": [DroneState(11.3, moved)]}, 11.35)["camera/frame"]
    assert len(out) == 1 and np.allclose(out[0].cam2world, moved)
