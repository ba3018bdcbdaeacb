"""The rig's kinematic calibration: the mount field in the kinematics, the least squares on
synthetic corners (noise, degenerate data), the tilt re-zeroing, and the simulator end to end."""

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import yaml

from aes_planner.calibrate.board import parse_board
from aes_planner.calibrate.capture import CameraModel, SimViewSource
from aes_planner.calibrate.pipeline import calibrate_rig
from aes_planner.calibrate.rig import RigCalibrationError, compare_kinematics, rezero_tilt, solve_rig
from aes_planner.calibrate.simscene import board_scene, perturbed_rig
from aes_planner.cli.calibrate import sim_calibration_camera
from aes_planner.config import from_dict
from aes_planner.geometry import PanTilt, PanTiltConfig
from aes_planner.geometry.rig import rig_dict
from aes_planner.sim import load_scene
from aes_planner.sim.spec import SceneSpec
from tests.calibrate.synth import rig_observations

BOARD = parse_board("chessboard:9x6:0.06")
CAMERA = CameraModel(np.array([[554.3, 0, 319.5], [0, 554.3, 239.5], [0, 0, 1]]), np.zeros(5), 640, 480)
NOMINAL = PanTiltConfig(base_xyz_m=(0.0, 0.0, 1.2), tilt_offset_m=(0.0, 0.0, 0.05), lever_arm_m=(0.03, 0.0, 0.02))


def _board2world(distance=2.0, height=1.25, bearing_deg=10.0):
    a = math.radians(bearing_deg)
    out = np.eye(4)
    # board x (page right) = the rig's right, y (page down) = world down, z into the board = away
    fwd = np.array([math.cos(a), math.sin(a), 0.0])
    right = np.array([math.sin(a), -math.cos(a), 0.0])
    out[:3, :3] = np.column_stack([right, [0, 0, -1.0], fwd])
    out[:3, 3] = fwd * distance + [0, 0, height] - right * 0.24 + [0, 0, 0.15]
    return out


def test_mount_rotation_turns_the_camera_and_zero_keeps_old_rigs_unchanged():
    base = PanTilt(NOMINAL).forward(0.3, -0.2)
    mounted = PanTilt(replace(NOMINAL, camera_mount_rpy_deg=(0.0, 0.0, 2.0))).forward(0.3, -0.2)
    assert np.allclose(base[:3, 3], mounted[:3, 3])  # turns, does not move
    angle = math.degrees(math.acos((np.trace(base[:3, :3].T @ mounted[:3, :3]) - 1) / 2))
    assert angle == pytest.approx(2.0, abs=1e-9)
    assert "camera_mount_rpy_deg" not in rig_dict(NOMINAL) and "camera_latency_s" not in rig_dict(NOMINAL)
    kin = PanTilt(replace(NOMINAL, camera_mount_rpy_deg=(1.0, -1.5, 2.0)))
    d = np.array([0.8, 0.3, 0.2])
    sol = kin.inverse_direction(d)
    assert sol.error_rad < 1e-9  # the inverse corrects for the mount


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_solver_recovers_a_rig_off_its_drawing_from_noisy_corners(seed):
    truth = perturbed_rig(NOMINAL, np.random.default_rng(seed))
    obs = rig_observations(truth, NOMINAL, BOARD, _board2world(), CAMERA, 30, pixel_sigma=0.2, seed=seed)
    sol = solve_rig(obs, NOMINAL)
    before, after = compare_kinematics(NOMINAL, truth), compare_kinematics(sol.config, truth)
    assert before["position_rms_mm"] > 8 or before["angle_rms_deg"] > 0.8  # the drawing is off ...
    assert after["position_rms_mm"] < 2.0 and after["angle_rms_deg"] < 0.05  # ... the calibration is not
    assert sol.rms_after_px == pytest.approx(0.2 * math.sqrt(2), rel=0.2) and sol.rms_before_px > 1.0
    assert all(0 < s < 2.0 for s in sol.std.values())  # mm and deg


def test_solver_tolerates_joint_reading_noise():
    """0.01 deg of encoder noise per view is worth ~0.35 mm of camera translation at the board's
    2 m (one planar board tells rotation from translation only by its perspective): 60 views."""
    truth = perturbed_rig(NOMINAL, np.random.default_rng(5))
    obs = rig_observations(truth, NOMINAL, BOARD, _board2world(), CAMERA, 60, 0.2, joint_sigma_deg=0.01, seed=5)
    after = compare_kinematics(solve_rig(obs, NOMINAL).config, truth)
    assert after["position_rms_mm"] < 4.0 and after["angle_rms_deg"] < 0.2


def test_degenerate_data_is_refused_saying_what_to_capture():
    truth = perturbed_rig(NOMINAL, np.random.default_rng(0))
    obs = rig_observations(truth, NOMINAL, BOARD, _board2world(), CAMERA, 30)
    one_pan = obs.subset(np.arange(30))
    one_pan.pan_rad = np.full(30, one_pan.pan_rad[0])
    with pytest.raises(RigCalibrationError, match="every view is at one pan angle"):
        solve_rig(one_pan, NOMINAL)
    with pytest.raises(RigCalibrationError, match="only 5 views"):
        solve_rig(obs.subset(np.arange(5)), NOMINAL)
    symmetric = parse_board("chessboard:7x7:0.06")
    with pytest.raises(RigCalibrationError, match="even and an odd"):
        calibrate_rig(None, NOMINAL, symmetric)


def test_rezero_tilt_gives_the_same_kinematics_for_the_shifted_joint():
    rig = replace(NOMINAL, lever_arm_m=(0.04, 0.01, 0.03), camera_mount_rpy_deg=(0.5, -1.7, 0.9))
    new, ticks = rezero_tilt(rig)
    e = -ticks * 2 * math.pi / 4096  # new angle = old angle + e
    assert ticks == round(math.degrees(math.radians(1.7)) / 360 * 4096) or abs(ticks) > 0
    old, shifted = PanTilt(rig), PanTilt(new)
    for p, t in [(0.0, 0.0), (0.4, -0.3), (-1.0, 0.5)]:
        assert np.allclose(old.forward(p, t), shifted.forward(p, t + e), atol=1e-12)
    level = shifted.forward(0.0, 0.0)[:3, 2]
    assert abs(math.degrees(math.asin(level[2]))) < 360 / 4096  # tilt 0 now looks level, to a tick


def _scene_file(tmp_path, truth, camera=(320, 240, 60.0), distance=1.4, board=BOARD):
    scene = board_scene(truth, board, distance_m=distance, bearing_deg=15.0, camera=camera)
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene))
    return path


def test_sim_rig_recovered_end_to_end(tmp_path):
    """A sim scene (board texture) whose rig differs from the drawing: rendered, detected, solved."""
    truth = perturbed_rig(NOMINAL, np.random.default_rng(11))
    scene = load_scene(_scene_file(tmp_path, truth))
    source = SimViewSource(sim_calibration_camera(scene, 1, 0, pixel_noise_sigma=1.0, min_width=320))
    config, report = calibrate_rig(source, NOMINAL, BOARD, n_views=16)
    after = compare_kinematics(config, truth)
    assert after["position_rms_mm"] < 4.0 and after["angle_rms_deg"] < 0.2, after
    assert report["rms_after_px"] < min(0.6, report["rms_before_px"])  # 1 level of pixel noise at 320x240
    assert {u["combination"].split(" ")[0] for u in report["unobservable"]} >= {"tilt_offset_m[2]", "pan"}


def test_board_never_found_and_wrong_spec_say_what_to_do(tmp_path):
    truth = perturbed_rig(NOMINAL, np.random.default_rng(3))
    narrow = replace(NOMINAL, pan_limits_deg=(-20.0, 20.0), tilt_limits_deg=(-10.0, 10.0))
    scene = load_scene(_scene_file(tmp_path, truth))
    source = SimViewSource(sim_calibration_camera(scene, 1, 0, min_width=320))
    with pytest.raises(RigCalibrationError, match="matches the printed board"):
        calibrate_rig(source, narrow, parse_board("chessboard:7x6:0.06"))
    away = replace(NOMINAL, pan_limits_deg=(120.0, 150.0), tilt_limits_deg=(-10.0, 10.0))
    with pytest.raises(RigCalibrationError, match="was in none of"):
        calibrate_rig(source, away, BOARD)


def test_rig_yaml_loads_where_rigs_are_loaded(tmp_path):
    """``calibrate rig`` output: PanTiltConfig fields only (suggest --rig, scene rig.pan_tilt, launch rig)."""
    from aes_planner.calibrate.pipeline import rig_yaml

    rig = replace(NOMINAL, camera_mount_rpy_deg=(0.5, -1.0, 0.25), camera_latency_s=0.0831)
    doc = yaml.safe_load(rig_yaml(rig, "a comment"))
    assert from_dict(PanTiltConfig, doc, "rig") == rig
    spec = from_dict(SceneSpec, {"rig": {"pan_tilt": doc}})
    assert spec.rig.pan_tilt.camera_mount_rpy_deg == (0.5, -1.0, 0.25)


def test_cli_rig_on_a_sim_scene(tmp_path):
    truth = perturbed_rig(NOMINAL, np.random.default_rng(4))
    scene = _scene_file(tmp_path, truth, camera=(640, 480, 60.0), distance=1.9)
    (tmp_path / "nominal.yaml").write_text(yaml.safe_dump(rig_dict(NOMINAL)))
    cmd = [sys.executable, "-m", "aes_planner", "calibrate", "rig", "--scene", str(scene), "--rig",
           str(tmp_path / "nominal.yaml"), "--board", "chessboard:9x6:0.06", "--out", str(tmp_path / "rig.yaml"),
           "--json", str(tmp_path / "rig.json"), "--views", "10", "--supersample", "1"]  # fmt: skip
    out = subprocess.run(cmd, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    rig = from_dict(PanTiltConfig, yaml.safe_load((tmp_path / "rig.yaml").read_text()), "rig")
    after = compare_kinematics(rig, truth)
    assert after["position_rms_mm"] < 4.0 and after["angle_rms_deg"] < 0.2, after
    report = json.loads((tmp_path / "rig.json").read_text())
    assert set(report["parameters"]) >= {"lever_arm_m[0]", "camera_mount_rpy_deg[2]"}
    assert all("std" in p for p in report["parameters"].values())


def test_verify_tells_a_calibrated_rig_from_its_drawing(tmp_path):
    from aes_planner.calibrate.pipeline import verify_rig

    truth = perturbed_rig(NOMINAL, np.random.default_rng(8))
    scene = load_scene(_scene_file(tmp_path, truth))
    source = SimViewSource(sim_calibration_camera(scene, 1, 0, min_width=320))
    good = verify_rig(source, truth, BOARD, n_views=8)
    bad = verify_rig(source, NOMINAL, BOARD, n_views=8)
    assert good["held_out_rms_px"] < 0.5 < bad["held_out_rms_px"], (good["held_out_rms_px"], bad["held_out_rms_px"])
