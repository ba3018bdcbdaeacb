"""The camera nodes' one frame path: calibration files, any Camera device, pose interpolated at the
stamp, best-effort frames, the sim camera behind the same seam."""

import dataclasses

import numpy as np
import pytest

from aes_planner.config import ConfigError
from aes_planner.devices import Camera, CameraError, CameraImage
from aes_planner.drivers.camera import load_calibration
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.graph.runner import NodeRunner
from aes_planner.node.camera import CameraNode, CameraNodeConfig
from aes_planner.transport import InProcessBus

from .nodekit import RIG, K, state

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


# ------------------------------------------------------------------------------ the Camera seam
class ToyCamera(Camera):
    """A camera that is not OpenCV: any Camera device drives the node."""

    def __init__(self, size=(24, 32)):
        self.intrinsics = K
        self.size = size
        self.opened = False
        self.reads = 0

    @property
    def connected(self):
        return self.opened

    def connect(self):
        self.opened = True

    def disconnect(self):
        self.opened = False

    def read(self, stamp_s):
        self.reads += 1
        h, w = self.size
        if (h, w) != (K.height, K.width):
            raise CameraError(f"frame {h}x{w} does not match the calibration {K.width}x{K.height}")
        return CameraImage(np.full((h, w, 3), 7, np.uint8), stamp_s)


def test_any_camera_device_drives_the_camera_node():
    cam = ToyCamera()
    node = CameraNode(CameraNodeConfig(rig=RIG, rate_hz=10.0, frame_id="toy"), camera=cam)
    assert node.step({"gimbal/state": [state(0.1, 0.0, stamp=0.0)]}, 0.5) == {"camera/frame": []}
    assert cam.reads == 0  # not connected: not read
    node.start()
    (frame,) = node.step({}, 1.0)["camera/frame"]
    assert frame.frame_id == "toy/000001" and frame.sequence == 1 and frame.intrinsics == K
    assert frame.cam2world == pytest.approx(PanTilt(RIG).forward(0.1, 0.0))
    assert node.step({}, 1.01)["camera/frame"] == [] and cam.reads == 1  # the node's rate, not the loop's
    node.stop()
    assert not cam.opened


def test_a_mismatched_image_is_counted_and_the_node_keeps_going():
    cam = ToyCamera(size=(10, 10))
    node = CameraNode(CameraNodeConfig(rig=RIG), camera=cam)
    node.start()
    node.step({"gimbal/state": [state(0.0, 0.0, stamp=1.0)]}, 1.0)
    assert node.counters["size_mismatch"] == 1 and node.counters["frames"] == 0
    cam.size = (K.height, K.width)
    assert len(node.step({}, 2.0)["camera/frame"]) == 1 and node.counters["frames"] == 1


def test_camera_frames_are_declared_best_effort_and_everything_else_reliable():
    from aes_planner.graph import NODE_TYPES, node_class
    from aes_planner.graph.base import output_specs

    for word in sorted(set(NODE_TYPES)):
        for topic, out in output_specs(node_class(word)).items():
            assert out.reliable == (topic != "camera/frame"), (word, topic)
    bus = InProcessBus()
    runner = NodeRunner(CameraNode(CameraNodeConfig(rig=RIG), camera=ToyCamera()), bus)
    runner.open()
    assert runner.pubs["camera/frame"].reliable is False
    runner.close()


def test_a_device_of_the_wrong_kind_is_refused_naming_the_key():
    from aes_planner.node.gimbal import GimbalNode, GimbalNodeConfig

    with pytest.raises(ConfigError, match=r"device\.type.*not a Gimbal"):
        GimbalNode(GimbalNodeConfig(device={"type": "opencv_camera", "device": 0}))


def test_sim_camera_node_publishes_through_the_device_without_extras():
    from aes_planner.node.sim_camera import SimCameraNode, SimCameraNodeConfig
    from aes_planner.sim import load_scene

    node = SimCameraNode(
        SimCameraNodeConfig(rate_hz=5.0, camera={"width": 16, "height": 12}), scene=load_scene("tabletop:1")
    )
    assert node.step({}, 0.0) == {"camera/frame": []} and not node.camera.ready  # not placed yet: nothing
    (frame,) = node.step({"gimbal/state": [state(0.2, -0.1, stamp=0.0)]}, 0.5)["camera/frame"]
    assert (frame.pan_rad, frame.tilt_rad) == pytest.approx((0.2, -0.1)) and frame.depth_m is not None
    assert frame.cam2world == pytest.approx(node.camera.kinematics.forward(0.2, -0.1))
    assert not frame.extras  # the simulator's ground truth is not part of a published frame
    assert frame.frame_id == "sim_camera/000001" and node.counters["frames"] == 1


@dataclasses.dataclass
class ToyCameraConfig:
    level: int = 7


class RegisteredToyCamera(ToyCamera):
    config_class = ToyCameraConfig

    def __init__(self, config: ToyCameraConfig):
        super().__init__()
        self.config = config


def test_a_camera_is_picked_by_its_type_word_like_a_gimbal(monkeypatch, tmp_path):
    """``camera: {type: WORD, ...}`` builds the registered device (a user adds a camera the way
    they add a servo); ``device``/``calibration`` stay the short form of ``opencv_camera``."""
    from aes_planner import devices

    monkeypatch.setitem(devices.DEVICE_TYPES, "toy_camera", RegisteredToyCamera)
    node = CameraNode(CameraNodeConfig(camera={"type": "toy_camera", "level": 3}, rig=RIG, frame_id="toy"))
    assert isinstance(node.camera, RegisteredToyCamera) and node.camera.config.level == 3
    node.start()
    (frame,) = node.step({"gimbal/state": [state(0.1, 0.0, stamp=0.0)]}, 0.5)["camera/frame"]
    assert frame.frame_id == "toy/000001" and frame.image[0, 0, 0] == 7  # the registered device's image
    node.stop()
    p = tmp_path / "cam.yaml"
    p.write_text(ROS)
    short = CameraNode(CameraNodeConfig(device=2, calibration=str(p), rig=RIG))
    assert type(short.camera).__name__ == "OpenCVCamera" and short.camera.config.device == 2
    with pytest.raises(ConfigError, match="camera.level"):
        CameraNodeConfig(camera={"type": "toy_camera", "level": "x"}, rig=RIG)
    with pytest.raises(ConfigError, match="camera.type"):
        CameraNodeConfig(camera={"type": "no_such_camera"}, rig=RIG)
    with pytest.raises(ConfigError, match="not a camera"):
        CameraNodeConfig(camera={"type": "sim_pan_tilt"}, rig=RIG)
    with pytest.raises(ConfigError, match="not both"):
        CameraNodeConfig(camera={"type": "toy_camera"}, device=1, rig=RIG)
