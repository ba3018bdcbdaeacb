"""Boards (spec, pattern, detection order, printable files) and camera intrinsics from images."""

import json
import struct
import subprocess
import sys

import cv2
import numpy as np
import pytest

from aes_planner.calibrate.board import BoardError, detect, parse_board, pattern, write_board
from aes_planner.calibrate.intrinsics import CalibrationFailed, View, calibrate_views, camera_info_yaml
from aes_planner.drivers.camera import load_calibration
from tests.calibrate.synth import board_image

K = np.array([[600.0, 0, 322.0], [0, 600.0, 236.0], [0, 0, 1]])


def test_parse_board_specs_and_errors():
    b = parse_board("chessboard:9x6:0.025")
    assert (b.cols, b.rows, b.squares, b.n_corners) == (9, 6, (10, 7), 54)
    assert b.size_m(1) == pytest.approx((0.3, 0.225))
    assert b.orientation_unique and not parse_board("chessboard:7x7:0.03").orientation_unique
    c = parse_board("charuco:7x5:0.04:0.03:DICT_5X5_100")
    assert (c.kind, c.corners_grid) == ("charuco", (6, 4))
    for bad, words in [
        ("chessboard:9x6", "not a board spec"),
        ("chessboard:9x6:25", "metres"),
        ("chessboard:2x6:0.02", "inner corners"),
        ("charuco:7x5:0.04:0.05:DICT_5X5_100", "MARKER_M must be smaller"),
        ("charuco:7x5:0.04:0.03:DICT_9X9_1", "no ArUco dictionary"),
    ]:
        with pytest.raises(BoardError, match=words):
            parse_board(bad)


def test_pattern_layout_top_left_black_with_white_margin():
    img = pattern(parse_board("chessboard:9x6:0.025"), 10, 1)
    assert img.shape == (90, 120)
    assert img[:10].min() == 255 and img[:, :10].min() == 255  # margin
    assert img[10:20, 10:20].max() == 0 and img[10:20, 20:30].min() == 255  # top-left black, then white


def test_detection_labels_corners_alike_when_the_board_is_turned_half_round():
    spec = parse_board("chessboard:9x6:0.025")
    obj = spec.object_points()
    for rvec in ([0.1, 0.2, 0.0], [0.1, 0.2, np.pi]):  # upright, and rotated 180 deg in its plane
        tvec = [-0.1, -0.06, 0.6] if rvec[2] == 0 else [0.1, 0.06, 0.6]
        img = board_image(spec, K, rvec, tvec)
        d = detect(img, spec)
        truth, _ = cv2.projectPoints(obj, np.array(rvec), np.array(tvec, float), K, None)
        err = np.linalg.norm(d.image_points - truth.reshape(-1, 2), axis=1)
        assert err.max() < 0.3, (rvec, err.max())  # every corner where its label says


def test_printable_png_states_its_print_resolution_and_svg_its_size(tmp_path):
    spec = parse_board("chessboard:9x6:0.025")
    info = write_board(spec, tmp_path / "b.png", px_per_square=100)
    data = (tmp_path / "b.png").read_bytes()
    i = data.index(b"pHYs")
    ppm = struct.unpack(">I", data[i + 4 : i + 8])[0]
    assert ppm == 4000 and info["dpi"] == pytest.approx(101.6)
    assert (info["width_mm"], info["height_mm"]) == (300.0, 225.0)
    assert cv2.imread(str(tmp_path / "b.png"), 0).shape == (900, 1200)
    write_board(spec, tmp_path / "b.svg")
    assert 'width="300.0000mm"' in (tmp_path / "b.svg").read_text()


def _views(spec, n=12, seed=0):
    rng = np.random.default_rng(seed)
    views = []
    for i in range(n):
        rvec = rng.uniform(-0.5, 0.5, 3) * [1, 1, 0.3]
        tvec = [rng.uniform(-0.18, 0.02), rng.uniform(-0.12, 0.0), rng.uniform(0.45, 0.7)]
        views.append(View(f"v{i}", img := board_image(spec, K, rvec, tvec), detect(img, spec)))
    return views


def test_intrinsics_recovered_from_synthetic_views_with_reasons_for_rejects():
    spec = parse_board("chessboard:9x6:0.025")
    views = _views(spec)
    blank = np.full((480, 640), 128, np.uint8)
    views += [View("blank", blank, None), View("again", views[0].gray, views[0].detection)]
    result = calibrate_views(views, spec)
    assert result.rms_px < 0.3
    assert result.K[0, 0] == pytest.approx(600.0, rel=0.005) and result.K[1, 1] == pytest.approx(600.0, rel=0.005)
    assert abs(result.K[0, 2] - 322.0) < 2 and abs(result.K[1, 2] - 236.0) < 2
    reasons = {r["image"]: r["reason"] for r in result.rejected}
    assert reasons["blank"].startswith("board not found") and reasons["again"] == "duplicate pose of v0"
    assert len(result.used) == 12 and 0 < result.coverage <= 1


def test_too_few_views_say_what_to_do():
    spec = parse_board("chessboard:9x6:0.025")
    with pytest.raises(CalibrationFailed, match="inner corners COLSxROWS"):
        calibrate_views(_views(spec, 2), spec)


def test_camera_info_yaml_is_ros_format_and_the_camera_node_reads_it(tmp_path):
    import yaml

    d = np.array([0.1, -0.2, 0.001, 0.002, 0.05])
    text = camera_info_yaml(K, d, 640, 480, "cam0")
    doc = yaml.safe_load(text)
    assert list(doc) == [
        "image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
        "distortion_coefficients", "rectification_matrix", "projection_matrix",
    ]  # fmt: skip
    assert doc["camera_matrix"] == {"rows": 3, "cols": 3, "data": K.reshape(-1).tolist()}
    assert doc["distortion_coefficients"]["cols"] == 5 and doc["distortion_model"] == "plumb_bob"
    assert (doc["projection_matrix"]["rows"], doc["projection_matrix"]["cols"]) == (3, 4)
    (tmp_path / "c.yaml").write_text(text)
    cal = load_calibration(tmp_path / "c.yaml")
    assert cal.intrinsics.cx == 322.5 and np.allclose(cal.K_opencv, K) and np.allclose(cal.distortion, d)


def test_cli_camera_on_images_writes_yaml_and_report(tmp_path):
    spec = parse_board("chessboard:9x6:0.025")
    paths = []
    for v in _views(spec, 10, seed=3):
        paths.append(str(tmp_path / f"{v.name}.png"))
        cv2.imwrite(paths[-1], v.gray)
    cv2.imwrite(str(tmp_path / "empty.png"), np.full((480, 640), 90, np.uint8))
    out = subprocess.run(
        [sys.executable, "-m", "aes_planner", "calibrate", "camera", *paths, str(tmp_path / "empty.png"),
         "--board", "chessboard:9x6:0.025", "--out", str(tmp_path / "cam.yaml"), "--json", str(tmp_path / "cam.json")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    report = json.loads((tmp_path / "cam.json").read_text())
    assert report["fx"] == pytest.approx(600, rel=0.01) and report["rms_px"] < 0.3
    assert [r["image"] for r in report["views_rejected"]] == [str(tmp_path / "empty.png")]
    assert load_calibration(tmp_path / "cam.yaml").intrinsics.width == 640
    wrong = subprocess.run(
        [sys.executable, "-m", "aes_planner", "calibrate", "camera", *paths[:4], "--board", "chessboard:8x6:0.025",
         "--out", str(tmp_path / "x.yaml")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert wrong.returncode == 2 and "board not found" in wrong.stderr and "--board matches" in wrong.stderr


def test_charuco_board_detected_with_its_ids_and_calibrates():
    spec = parse_board("charuco:7x5:0.04:0.03:DICT_5X5_100")
    rng = np.random.default_rng(1)
    views = []
    for i in range(8):
        rvec = rng.uniform(-0.4, 0.4, 3) * [1, 1, 0.3]
        tvec = [rng.uniform(-0.16, -0.06), rng.uniform(-0.12, -0.04), rng.uniform(0.5, 0.65)]
        img = board_image(spec, K, rvec, tvec, px=60)
        d = detect(img, spec)
        assert d is not None and len(d.object_points) >= 20
        proj, _ = cv2.projectPoints(d.object_points, np.array(rvec), np.array(tvec, float), K, None)
        assert np.abs(proj.reshape(-1, 2) - d.image_points).max() < 0.5  # each id where its corner is
        views.append(View(f"c{i}", img, d))
    result = calibrate_views(views, spec)
    assert result.K[0, 0] == pytest.approx(600.0, rel=0.01) and result.rms_px < 0.3


def test_cli_board_states_size_and_scale(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "aes_planner", "calibrate", "board", "--board", "chessboard:9x6:0.06",
         "--out", str(tmp_path / "b.png")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert "720.0 x 540.0 mm" in out.stdout and "print at 100 %" in out.stdout and "dpi" in out.stdout
    assert detect(cv2.imread(str(tmp_path / "b.png"), 0), parse_board("chessboard:9x6:0.06")) is not None
    bad = subprocess.run(
        [sys.executable, "-m", "aes_planner", "calibrate", "board", "--board", "chess:9x6", "--out", str(tmp_path / "c.png")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert bad.returncode == 2 and "chessboard:COLSxROWS:SQUARE_M" in bad.stderr
