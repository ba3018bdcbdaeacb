"""Bad-input sweep, third round (issue 33): every case ends in one ``error:`` line with exit 2 (or an
``AesPlannerError`` from the API), a documented safe result, or a rejection a running node counts.
Each case here crashed the interpreter, allocated gigabytes, hung, printed a traceback or was
silently accepted before it was fixed.
"""

from pathlib import Path

import pytest

from aes_planner.cli import main  # noqa: F401  (the fixtures call it)

RIG = "{base_xyz_m: [0, 0, 1.3], pan_limits_deg: [-150, 150], tilt_limits_deg: [-60, 60]}"


def write(folder: Path, name: str, text: str) -> Path:
    (folder / name).write_text(text)
    return folder / name


# ----------------------------------------------------------------- 3. no input crashes the process
@pytest.mark.parametrize("device", ["-1", "-2", "-2147483648", "2147483648", "1e3", "[0]", "''", '"a\\0b"'])
def test_camera_device_is_checked_before_opencv_sees_it(tmp_path, cli_error, device):
    # cv2.VideoCapture(-1) dies of a segmentation fault: the config must refuse it first.
    launch = write(
        tmp_path,
        "cam.yaml",
        f"nodes:\n  - id: camera\n    type: camera\n    config: {{device: {device}, calibration: c.yaml, rig: {RIG}}}\n",
    )
    cli_error(["launch", launch, "--timeout", "5"], "device", seconds=30)


@pytest.mark.parametrize(
    "coefficients", ["[0.1, 0.0, 0.0]", "[0.1, 0, 0, 0, 0, 0]", "[" + ", ".join(["0.01"] * 15) + "]"]
)
def test_calibration_distortion_count_is_what_opencv_takes(tmp_path, clean_error, coefficients):
    from aes_planner.node.camera import load_calibration

    cal = write(
        tmp_path,
        "cal.yaml",
        "image_width: 64\nimage_height: 48\ncamera_matrix: {rows: 3, cols: 3, data: [50, 0, 32, 0, 50, 24, 0, 0, 1]}\n"
        f"distortion_coefficients: {coefficients}\n",
    )
    clean_error(load_calibration, cal, match="distortion_coefficients")
