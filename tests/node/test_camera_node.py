"""CameraNode with a fake capture source: calibration files, pose interpolated at the stamp."""

import numpy as np
import pytest

from aes_planner.config import ConfigError
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.node.camera import CameraNode, CameraNodeConfig, load_calibration

from .nodekit import RIG, state

ROS = """image_width: 32
image_height: 24
camera_name: test
camera_matrix: {rows: 3, cols: 3, data: [30.0, 0.0, 16.0, 0.0, 30.0, 12.0, 0.0, 0.0, 1.0]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [0.0, 0.0, 0.0, 0.0, 0.0]}
"""

OPENCV = """%YAML:1.0
---
image_width: 32
image_height: 24
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 30., 0., 16., 0., 30., 12., 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ 0.01, 0., 0., 0., 0. ]
"""


class FakeCapture:
    def __init__(self, ok=True):
        self.ok = ok
        self.released = False

    def read(self):
        return self.ok, np.full((24, 32, 3), (10, 20, 30), np.uint8)

    def release(self):
        self.released = True


@pytest.mark.parametrize("text", [ROS, OPENCV])
def test_calibration_formats(tmp_path, text):
    p = tmp_path / "cam.yaml"
    p.write_text(text)
    cal = load_calibration(p)
    # the file's cx = 16 (OpenCV: pixel centres at integers) is 16.5 in the package's convention (+0.5)
    assert (cal.intrinsics.width, cal.intrinsics.height, cal.intrinsics.fx, cal.intrinsics.cx) == (32, 24, 30.0, 16.5)


def test_bad_calibration_names_the_key(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(ROS.replace("image_width: 32", "image_width: -3"))
    with pytest.raises(ConfigError, match="image_width"):
        load_calibration(p)


def test_pose_interpolated_at_the_frame_stamp(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(ROS)
    cap = FakeCapture()
    node = CameraNode(CameraNodeConfig(calibration=str(p), rig=RIG, rate_hz=10.0), capture=cap)
    out = node.step({}, 10.0)
    assert out["camera/frame"] == [] and node.counters["unposed"] == 1  # no gimbal state yet
    states = [state(0.0, 0.0, stamp=10.0), state(0.4, 0.2, stamp=11.0)]
    out = node.step({"gimbal/state": states}, 10.5)
    (frame,) = out["camera/frame"]
    assert (frame.pan_rad, frame.tilt_rad) == pytest.approx((0.2, 0.1))
    assert frame.cam2world == pytest.approx(PanTilt(RIG).forward(0.2, 0.1))
    assert frame.image[0, 0].tolist() == [30, 20, 10]  # BGR -> RGB
    node.stop()
    assert cap.released


def test_failed_reads_are_counted(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(ROS)
    node = CameraNode(CameraNodeConfig(calibration=str(p), rig=RIG), capture=FakeCapture(ok=False))
    node.step({"gimbal/state": [state(0.0, 0.0, stamp=1.0)]}, 1.0)
    assert node.counters["read_failures"] == 1
