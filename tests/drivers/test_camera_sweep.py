"""Bad-input sweep of the camera driver (aes_planner.drivers.camera): a device number OpenCV would
crash on is refused by the config (in a launch file and in ``calibrate rig``), and a calibration
file is read like every YAML file, with the distortion counts OpenCV takes.
"""

import pytest

from tests.helpers import write_file

RIG = "{base_xyz_m: [0, 0, 1.3], pan_limits_deg: [-150, 150], tilt_limits_deg: [-60, 60]}"


@pytest.mark.parametrize("device", ["-1", "-2", "-2147483648", "2147483648", "1e3", "[0]", "''", '"a\\0b"'])
def test_camera_device_is_checked_before_opencv_sees_it(tmp_path, cli_error, device):
    # cv2.VideoCapture(-1) dies of a segmentation fault: the config must refuse it first.
    launch = write_file(
        tmp_path,
        "cam.yaml",
        f"nodes:\n  - id: camera\n    type: camera\n    config: {{device: {device}, calibration: c.yaml, rig: {RIG}}}\n",
    )
    cli_error(["launch", launch, "--timeout", "5"], "device", seconds=30)


def test_calibrate_rig_checks_the_launch_files_camera_device_before_opencv(tmp_path, cli_error):
    launch = write_file(
        tmp_path,
        "l.yaml",
        "nodes:\n  - {id: gimbal, type: gimbal, config: {device: {type: emulated_pan_tilt}}}\n"
        f"  - {{id: camera, type: camera, config: {{device: 0, calibration: c.yaml, rig: {RIG}}}}}\n",
    )
    rig = write_file(tmp_path, "rig.yaml", "base_xyz_m: [0, 0, 1.3]\n")
    argv = ["calibrate", "rig", "--board", "chessboard:9x6:0.025", "--rig", rig, "--launch", launch]
    cli_error([*argv, "--set", "camera.device=-1", "--out", tmp_path / "o.yaml"], "device", seconds=30)
    launch = write_file(  # the camera picked by type:, as a gimbal's device
        tmp_path,
        "l2.yaml",
        "nodes:\n  - {id: gimbal, type: gimbal, config: {device: {type: emulated_pan_tilt}}}\n"
        f"  - {{id: camera, type: camera, config: {{camera: {{type: opencv_camera, device: 0, calibration: c.yaml}}, rig: {RIG}}}}}\n",
    )
    argv = ["calibrate", "rig", "--board", "chessboard:9x6:0.025", "--rig", rig, "--launch", launch]
    cli_error([*argv, "--set", "camera.camera.device=-1", "--out", tmp_path / "o.yaml"], "camera.device", seconds=30)


@pytest.mark.parametrize(
    "coefficients", ["[0.1, 0.0, 0.0]", "[0.1, 0, 0, 0, 0, 0]", "[" + ", ".join(["0.01"] * 15) + "]"]
)
def test_calibration_distortion_count_is_what_opencv_takes(tmp_path, clean_error, coefficients):
    from aes_planner.drivers.camera import load_calibration

    cal = write_file(
        tmp_path,
        "cal.yaml",
        "image_width: 64\nimage_height: 48\ncamera_matrix: {rows: 3, cols: 3, data: [50, 0, 32, 0, 50, 24, 0, 0, 1]}\n"
        f"distortion_coefficients: {coefficients}\n",
    )
    clean_error(load_calibration, cal, match="distortion_coefficients")


LAUGHS = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [{', '.join(['*' + p] * 10)}]\n" for p, c in zip("abcdefgh", "bcdefghi")
)


@pytest.mark.parametrize(
    "content, match",
    [
        (b"%YAML:1.0\n---\n" + LAUGHS.encode(), "expands to more than"),
        (LAUGHS.encode(), "expands to more than"),
        (b"%YAML:1.0\n---\ncamera_matrix: [1, 2\n", "not valid YAML"),
        (b"\xff\xfe\x00 not text", "not UTF-8"),
        (b"%YAML:1.0\n---\nimage_width: 1\nimage_width: 2\n", "duplicate key"),
    ],
)
def test_a_calibration_file_is_read_like_every_yaml_file(tmp_path, clean_error, content, match):
    from aes_planner.drivers.camera import load_calibration

    (tmp_path / "cal.yaml").write_bytes(content)
    clean_error(load_calibration, tmp_path / "cal.yaml", match=match)
    (tmp_path / "folder.yaml").mkdir()
    clean_error(load_calibration, tmp_path / "folder.yaml", match="folder")
