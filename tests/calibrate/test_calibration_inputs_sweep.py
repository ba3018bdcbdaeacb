"""Sweep: calibration inputs as a careless or hostile user gives them (a third sweep's cases and
their kin). Every case ends in one ``error:`` line and status 2, quickly and before any work (the
flags and the output paths are checked first: the scene below does not even exist), never a Python
error, an OpenCV assertion or a silent acceptance; the camera_info YAML is written by a YAML
writer's rules, so no name injects a key."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest
import yaml

from aes_planner.calibrate.intrinsics import camera_info_yaml
from aes_planner.cli import main

BOARD = "chessboard:9x6:0.03"


def _error(capsys, argv) -> str:
    rc = main(argv)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert rc == 2 and len(lines) == 1, err
    assert "unexpected" not in err and "Traceback" not in err and "cv2.error" not in err, err
    return lines[0]


@pytest.fixture
def rig_yaml(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text("base_xyz_m: [0.0, 0.0, 1.3]\n")
    return path


SIM_FLAGS = [
    (["--supersample", "0"], "--supersample"),
    (["--supersample", "-3"], "--supersample"),
    (["--pixel-noise", "1e9"], "--pixel-noise"),
    (["--pixel-noise", "nan"], "--pixel-noise"),
    (["--pixel-noise", "-1"], "--pixel-noise"),
    (["--joint-noise-deg", "nan"], "--joint-noise-deg"),
    (["--joint-noise-deg", "-0.1"], "--joint-noise-deg"),
    (["--joint-noise-deg", "1e300"], "--joint-noise-deg"),
    (["--sim-latency", "-0.1"], "--sim-latency"),
    (["--sim-latency", "nan"], "--sim-latency"),
    (["--sim-latency", "1e9"], "--sim-latency"),
    (["--settle-s", "inf"], "--settle-s"),
    (["--seed", "-1"], "--seed"),
    (["--seed", str(2**70)], "--seed"),
]


@pytest.mark.parametrize("step", ["rig", "verify"])
@pytest.mark.parametrize(("flags", "named"), SIM_FLAGS, ids=[" ".join(f) for f, _ in SIM_FLAGS])
def test_numeric_flags_are_refused_before_any_work(tmp_path, capsys, rig_yaml, step, flags, named):
    argv = ["calibrate", step, "--board", BOARD, "--rig", str(rig_yaml), "--scene", str(tmp_path / "none.yaml")]
    argv += ["--out", str(tmp_path / "out.yaml")] if step == "rig" else []
    assert named in _error(capsys, argv + flags)


@pytest.mark.parametrize(
    "board",
    ["chessboard:９x６:0.03", "chessboard:9x6:０.03", "charuco:５x7:0.04:0.03:DICT_5X5_100", "chessboard:9x6:0.03\x1b"],
)
def test_board_specs_with_other_digits_or_control_characters_are_refused(tmp_path, capsys, board):
    assert "--board" in _error(capsys, ["calibrate", "board", "--board", board, "--out", str(tmp_path / "b.png")])


def _symlinked(tmp_path, kind: str):
    target = tmp_path / "outside" / "victim.txt"
    target.parent.mkdir()
    if kind == "live":
        target.write_text("keep me")
    link = tmp_path / "out" / "link.yaml"
    link.parent.mkdir()
    os.symlink(target, link)
    return link, target


@pytest.mark.parametrize("kind", ["live", "dangling"])
@pytest.mark.parametrize("step", ["board", "camera", "rig", "rig-json", "verify-json"])
def test_an_output_path_that_is_a_symlink_is_refused_first(tmp_path, capsys, rig_yaml, kind, step):
    link, target = _symlinked(tmp_path, kind)
    image = tmp_path / "board.png"
    cv2.imwrite(str(image), np.full((64, 64), 255, np.uint8))
    scene = str(tmp_path / "none.yaml")  # never read: the outputs are checked first
    argv = {
        "board": ["calibrate", "board", "--board", BOARD, "--out", str(link)],
        "camera": ["calibrate", "camera", str(image), "--board", BOARD, "--out", str(link)],
        "rig": ["calibrate", "rig", "--board", BOARD, "--rig", str(rig_yaml), "--scene", scene, "--out", str(link)],
        "rig-json": ["calibrate", "rig", "--board", BOARD, "--rig", str(rig_yaml), "--scene", scene]
        + ["--out", str(tmp_path / "rig_out.yaml"), "--json", str(link)],
        "verify-json": ["calibrate", "verify", "--board", BOARD, "--rig", str(rig_yaml), "--scene", scene]
        + ["--json", str(link)],
    }[step]
    assert "symlink" in _error(capsys, argv)
    assert (target.read_text() == "keep me") if kind == "live" else not target.exists()


@pytest.mark.parametrize("size", [(1, 1), (2, 2), (3, 15), (15, 3)])
def test_tiny_images_are_a_calibration_error_not_an_opencv_assertion(tmp_path, capsys, size):
    paths = []
    for i in range(3):
        p = tmp_path / f"tiny{i}.png"
        cv2.imwrite(str(p), np.full(size, 128 + i, np.uint8))
        paths.append(str(p))
    _error(capsys, ["calibrate", "camera", *paths, "--board", BOARD, "--out", str(tmp_path / "c.yaml")])


@pytest.mark.parametrize("name", ["x\nimage_width: 1", "x\r\nimage_width: 1", "a\x1b[31m", "", "n" * 200, "tab\there"])
def test_camera_names_that_would_inject_yaml_are_refused(tmp_path, capsys, name):
    image = tmp_path / "board.png"
    cv2.imwrite(str(image), np.full((64, 64), 255, np.uint8))
    argv = ["calibrate", "camera", str(image), "--board", BOARD, "--out", str(tmp_path / "c.yaml")]
    _error(capsys, argv + ["--camera-name", name])
    assert not (tmp_path / "c.yaml").exists()


@pytest.mark.parametrize("name", ["camera", "a: b", "# not a comment", "'quoted'", "{x: 1}", "ÿ-camera"])
def test_every_printable_camera_name_round_trips_as_one_key(name):
    doc = yaml.safe_load(camera_info_yaml(np.eye(3) * 100, np.zeros(5), 64, 48, name))
    assert doc["camera_name"] == name and doc["image_width"] == 64 and len(doc) == 8


CAMERA_INFO = (
    "image_width: 64\nimage_height: 48\ncamera_name: c\n"
    "camera_matrix: {{rows: 3, cols: 3, data: {k}}}\n"
    "distortion_model: plumb_bob\ndistortion_coefficients: {{rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}}\n"
)


@pytest.mark.parametrize(
    "k",
    [
        "[a, b, c, d, e, f, g, h, i]",  # strings
        "['60', 0, 32, 0, 60, 24, 0, 0, 1]",
        "[true, 0, 32, 0, 60, 24, 0, 0, 1]",
        "[[60, 0, 32], [0, 60, 24], [0, 0, 1]]",  # nested
        "[" + "9" * 4000 + ", 0, 32, 0, 60, 24, 0, 0, 1]",  # an integer past a float
        "[" + "9" * 10000 + ", 0, 32, 0, 60, 24, 0, 0, 1]",  # past Python's int parsing limit
        "[1" + "0" * 400 + ".0, 0, 32, 0, 60, 24, 0, 0, 1]",  # a float past float64: inf
        "[1e30, 0, 32, 0, 1e30, 24, 0, 0, 1]",  # a camera no camera is
    ],
    ids=["strings", "a-string", "a-bool", "nested", "4000-digits", "10000-digits", "400-digit-float", "fx-1e30"],
)
def test_camera_info_files_no_camera_has_are_one_line_errors(tmp_path, capsys, rig_yaml, k):
    info = tmp_path / "camera_info.yaml"
    info.write_text(CAMERA_INFO.format(k=k))
    launch = tmp_path / "launch.yaml"
    launch.write_text(
        "nodes:\n  - id: gimbal\n    type: gimbal\n    config: {device: {type: dynamixel_pan_tilt, port: /dev/null}}\n"
        f"  - id: camera\n    type: camera\n    config: {{device: 0, calibration: {info}}}\n"
    )
    argv = ["calibrate", "verify", "--board", BOARD, "--rig", str(rig_yaml), "--launch", str(launch)]
    line = _error(capsys, argv)
    assert "calibration" in line or "camera_info.yaml" in line


@pytest.mark.parametrize("digits", [400, 4000, 10000])
def test_huge_numbers_in_a_rig_yaml_are_one_line_errors(tmp_path, capsys, digits):
    rig = tmp_path / "rig.yaml"
    rig.write_text(f"base_xyz_m: [{'9' * digits}, 0, 1]\n")
    argv = ["calibrate", "verify", "--board", BOARD, "--rig", str(rig), "--scene", str(tmp_path / "none.yaml")]
    _error(capsys, argv)
