"""``calibrate rig --launch``'s capture path on the real Dynamixel driver and the servo emulator
(``emulated_pan_tilt``), with a stand-in camera that renders the sim scene at the joints the
gimbal reports (no real camera here: what stays untested is a USB camera's buffering and timing)."""

import sys

import cv2
import numpy as np
import pytest
import yaml

from aes_planner.calibrate.board import parse_board
from aes_planner.calibrate.capture import HardwareViewSource, SimViewSource
from aes_planner.calibrate.pipeline import calibrate_rig
from aes_planner.calibrate.rig import compare_kinematics
from aes_planner.calibrate.simscene import board_scene, perturbed_rig
from aes_planner.cli.calibrate import sim_calibration_camera
from aes_planner.devices import Camera, CameraImage, make_device
from aes_planner.geometry import PanTiltConfig
from aes_planner.sim import load_scene

pytest.importorskip("dynamixel_sdk", reason="the hardware extra (dynamixel-sdk) is not installed")

BOARD = parse_board("chessboard:9x6:0.06")


class RenderingCamera(Camera):
    """A camera device whose ``read`` renders what the sim rig sees at the gimbal's present joints
    (as a camera on it would), raw RGB."""

    def __init__(self, gimbal, sim_source):
        self.gimbal, self.sim = gimbal, sim_source

    connected = True

    def connect(self):
        pass

    def disconnect(self):
        pass

    def read(self, stamp_s):
        s = self.gimbal.state()
        gray, _, _ = self.sim.capture(s.pan_rad, s.tilt_rad)
        return CameraImage(cv2.cvtColor(gray, cv2.COLOR_GRAY2RGB), stamp_s)


@pytest.fixture
def fast_switching():
    before = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)  # the SDK busy-waits holding the GIL; let the emulator thread answer
    yield
    sys.setswitchinterval(before)


def test_rig_calibrated_through_the_dynamixel_driver_on_the_emulator(tmp_path, fast_switching):
    nominal = PanTiltConfig(
        base_xyz_m=(0.0, 0.0, 1.2),
        tilt_offset_m=(0.0, 0.0, 0.05),
        lever_arm_m=(0.03, 0.0, 0.02),
        pan_limits_deg=(-60.0, 60.0),
        tilt_limits_deg=(-30.0, 30.0),
    )
    truth = perturbed_rig(nominal, np.random.default_rng(21))
    path = tmp_path / "scene.yaml"
    path.write_text(
        yaml.safe_dump(board_scene(truth, BOARD, distance_m=1.4, bearing_deg=-10.0, camera=(320, 240, 60.0)))
    )
    sim = SimViewSource(sim_calibration_camera(load_scene(path), 1, 0, min_width=320))
    gimbal = make_device(
        {
            "type": "emulated_pan_tilt",
            "profile_velocity_deg_s": 0.0,
            "profile_acceleration_deg_s2": 0.0,
            "latency_timer_ms": 100.0,
            "pan_limits_deg": [-60.0, 60.0],
            "tilt_limits_deg": [-30.0, 30.0],
        }
    )
    gimbal.connect()
    try:
        source = HardwareViewSource(gimbal, RenderingCamera(gimbal, sim), sim.camera, settle_s=0.0, flush_frames=0)
        config, report = calibrate_rig(source, nominal, BOARD, n_views=12)
    finally:
        gimbal.disconnect()
    after = compare_kinematics(config, truth)
    assert after["position_rms_mm"] < 4.0 and after["angle_rms_deg"] < 0.2, after
    assert report["views_used"] >= 10


def test_launch_file_wiring_opens_the_gimbal_and_the_camera(tmp_path, fast_switching):
    """``--launch``: the gimbal node's device and the camera node's device and calibration, from a
    launch file (emulated servos; a video file stands in for the USB camera)."""
    import argparse

    from aes_planner.calibrate.intrinsics import camera_info_yaml
    from aes_planner.cli.calibrate import _Session

    video = tmp_path / "cam.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (320, 240))
    if not writer.isOpened():
        pytest.skip("this OpenCV build writes no MJPG video (needed as the stand-in camera)")
    for _ in range(12):
        writer.write(np.full((240, 320, 3), 120, np.uint8))
    writer.release()
    K = np.array([[277.0, 0, 159.5], [0, 277.0, 119.5], [0, 0, 1]])
    (tmp_path / "cam.yaml").write_text(camera_info_yaml(K, np.zeros(5), 320, 240))
    launch = {
        "nodes": [
            {
                "id": "gimbal",
                "type": "gimbal",
                "config": {
                    "device": {
                        "type": "emulated_pan_tilt",
                        "profile_velocity_deg_s": 0.0,
                        "profile_acceleration_deg_s2": 0.0,
                        "latency_timer_ms": 100.0,
                    }
                },
            },
            {
                "id": "camera",
                "type": "camera",
                "config": {"device": str(video), "calibration": str(tmp_path / "cam.yaml"), "rig": {}},
            },
        ]
    }
    (tmp_path / "rig_launch.yaml").write_text(yaml.safe_dump(launch))
    args = argparse.Namespace(
        scene=None, launch=str(tmp_path / "rig_launch.yaml"), set=[], camera_info=None, settle_s=0.0, seed=0
    )
    with _Session(args) as session:
        session.source.flush_frames = 1
        gray, pan, tilt = session.source.capture(0.1, -0.05)
        assert gray.shape == (240, 320)
        assert (pan, tilt) == pytest.approx((0.1, -0.05), abs=0.002)  # within a tick of the goal
        assert np.allclose(session.source.camera.K, K)
        assert type(session.camera).__name__ == "OpenCVCamera" and session.camera.config.undistort is False
    assert not session.gimbal.connected and not session.camera.connected
