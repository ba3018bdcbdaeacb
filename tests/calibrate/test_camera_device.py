"""Calibration takes its camera through the device factory, as the camera node does
(``camera: {type: ...}``, :func:`aes_planner.devices.make_camera`), with raw frames: the
distortion is what a calibration measures, so it must not be undistorted away."""

from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from aes_planner.calibrate.board import parse_board
from aes_planner.calibrate.intrinsics import camera_info_yaml
from aes_planner.cli import main
from aes_planner.config import ConfigError
from aes_planner.devices import DEVICE_TYPES, Camera, CameraImage, make_camera

from .test_board_intrinsics import _views

RIG = {"base_xyz_m": [0, 0, 1.3], "pan_limits_deg": [-150, 150], "tilt_limits_deg": [-60, 60]}
SPEC = parse_board("chessboard:9x6:0.025")


class FakeCapture:
    """``cv2.VideoCapture`` stand-in: one BGR frame, and the sizes it was asked for."""

    def __init__(self, frame):
        self.frame, self.asked = frame, {}

    def isOpened(self):
        return True

    def set(self, prop, value):
        self.asked[prop] = value
        return True

    def read(self):
        return True, self.frame.copy()

    def release(self):
        pass


def _calibration(tmp_path, distortion):
    K = np.array([[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]])
    path = tmp_path / "cam.yaml"
    path.write_text(camera_info_yaml(K, np.asarray(distortion, float), 320, 240))
    return str(path)


def test_the_opencv_camera_gives_raw_frames_for_calibration_and_undistorted_ones_for_a_node(tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    captures = []
    monkeypatch.setattr(cv2, "VideoCapture", lambda device: captures.append(FakeCapture(bgr)) or captures[-1])
    spec = {"type": "opencv_camera", "device": 0, "calibration": _calibration(tmp_path, [-0.3, 0.1, 0, 0, 0])}
    raw, node = make_camera(spec, raw=True), make_camera(spec)
    for cam in (raw, node):
        cam.connect()
    raw_rgb, node_rgb = raw.read(1.0).image, node.read(1.0).image
    assert np.array_equal(raw_rgb, bgr[..., ::-1])  # as the sensor took it (RGB)
    assert not np.array_equal(node_rgb, raw_rgb)  # the node's is undistorted
    assert captures[0].asked == {cv2.CAP_PROP_FRAME_WIDTH: 320, cv2.CAP_PROP_FRAME_HEIGHT: 240}
    # a camera being calibrated has no calibration yet: raw frames of any size
    bare = make_camera({"type": "opencv_camera", "device": 0}, raw=True)
    bare.connect()
    assert bare.intrinsics is None and bare.read(2.0).image.shape == (240, 320, 3)
    with pytest.raises(ConfigError, match="calibration"):  # a node's camera still needs its file
        make_camera({"type": "opencv_camera", "device": 0})


@dataclass
class ReplayConfig:
    undistort: bool = True


class ReplayCamera(Camera):
    """A plugin camera type: replays synthetic board views (RGB), and says whether it was asked raw."""

    config_class = ReplayConfig
    built: list = []

    def __init__(self, config):
        self.config, self.i, self._on = config, 0, False
        self.views = [v.gray for v in _views(SPEC, 10, seed=3)]
        ReplayCamera.built.append(self)

    @property
    def connected(self):
        return self._on

    def connect(self):
        self._on = True

    def disconnect(self):
        self._on = False

    def read(self, stamp_s):
        gray = self.views[self.i % len(self.views)]
        self.i += 1
        return CameraImage(np.repeat(gray[..., None], 3, axis=2), stamp_s)


@dataclass
class NoRawConfig:
    exposure_ms: float = 10.0


class NoRawCamera(ReplayCamera):
    config_class = NoRawConfig


def _launch(tmp_path, camera):
    import yaml

    path = tmp_path / "rig.yaml"
    path.write_text(
        yaml.safe_dump({"nodes": [{"id": "camera", "type": "camera", "config": {"camera": camera, "rig": RIG}}]})
    )
    return str(path)


def test_calibrate_camera_reads_the_launch_files_camera_type_raw(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(DEVICE_TYPES, "replay_camera", ReplayCamera)
    ReplayCamera.built.clear()
    out = tmp_path / "cam.yaml"
    argv = ["calibrate", "camera", "--board", "chessboard:9x6:0.025", "--frames", "8", "--out", str(out)]
    assert main([*argv, "--launch", _launch(tmp_path, {"type": "replay_camera"})]) == 0
    (cam,) = ReplayCamera.built
    assert cam.config.undistort is False and not cam.connected  # asked for raw frames, released after
    from aes_planner.drivers.camera import load_calibration

    assert load_calibration(out).intrinsics.fx == pytest.approx(600.0, rel=0.01)  # the views' camera


def test_a_camera_type_without_raw_frames_is_refused_naming_the_key(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(DEVICE_TYPES, "noraw_camera", NoRawCamera)
    argv = ["calibrate", "camera", "--board", "chessboard:9x6:0.025", "--out", str(tmp_path / "c.yaml")]
    assert main([*argv, "--launch", _launch(tmp_path, {"type": "noraw_camera"})]) == 2
    err = capsys.readouterr().err
    assert "camera.type" in err and "raw" in err and "'noraw_camera'" in err
    with pytest.raises(ConfigError, match="camera.type"):
        make_camera({"type": "noraw_camera"}, "camera", raw=True)
