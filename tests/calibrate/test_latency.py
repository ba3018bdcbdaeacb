"""The camera's delay behind the joint states: estimated from a sim sweep, compensated by the nodes."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from aes_planner.calibrate.board import parse_board
from aes_planner.calibrate.capture import SimStream, SimViewSource, board_in_world, find_board
from aes_planner.calibrate.pipeline import estimate_latency, latency_sweep_centre
from aes_planner.calibrate.simscene import board_scene, perturbed_rig
from aes_planner.cli.calibrate import sim_calibration_camera
from aes_planner.geometry import PanTilt, PanTiltConfig
from aes_planner.node.camera import CameraNode, CameraNodeConfig
from aes_planner.sim import load_scene
from tests.node.nodekit import RIG, state

from .nodefake import FakeCapture, ros_yaml

BOARD = parse_board("chessboard:9x6:0.06")


@pytest.mark.parametrize("latency_s", [0.0, 0.12])
def test_latency_of_the_sim_camera_recovered_within_10_ms(tmp_path, latency_s):
    nominal = PanTiltConfig(base_xyz_m=(0.0, 0.0, 1.2), tilt_offset_m=(0.0, 0.0, 0.05), lever_arm_m=(0.03, 0.0, 0.02))
    truth = perturbed_rig(nominal, np.random.default_rng(2))
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(board_scene(truth, BOARD, distance_m=1.6, camera=(320, 240, 60.0))))
    scene = load_scene(path)
    source = SimViewSource(sim_calibration_camera(scene, 1, 0, min_width=320))
    pan, tilt, found = find_board(source, truth, BOARD)
    b2w = board_in_world(source.camera, truth, pan, tilt, found)
    centre, amplitude = latency_sweep_centre(source.camera, truth, BOARD, b2w)
    stream = SimStream(sim_calibration_camera(scene, 1, 0, latency_s=latency_s, min_width=320))
    out = estimate_latency(stream, source.camera, truth, BOARD, b2w, centre, amplitude, duration_s=2.0)
    assert abs(out["camera_latency_s"] - latency_s) < 0.010, out
    assert out["frames_used"] >= 20


def test_camera_node_poses_frames_at_the_exposure(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(ros_yaml())
    rig = replace(RIG, camera_latency_s=0.25)
    node = CameraNode(CameraNodeConfig(calibration=str(p), rig=rig, rate_hz=10.0), capture=FakeCapture())
    states = [state(0.0, 0.0, stamp=10.0), state(0.4, 0.2, stamp=11.0)]
    (frame,) = node.step({"gimbal/state": states}, 10.75)["camera/frame"]
    assert (frame.pan_rad, frame.tilt_rad) == pytest.approx((0.2, 0.1))  # the joints at 10.75 - 0.25
    assert frame.cam2world == pytest.approx(PanTilt(rig).forward(0.2, 0.1))
