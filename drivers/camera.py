"""``OpenCVCamera``: a camera read through OpenCV's ``VideoCapture``, behind the
:class:`~aes_planner.devices.Camera` seam (``type: opencv_camera``), and its calibration files.

The calibration is an OpenCV ``FileStorage`` YAML with ``camera_matrix`` /
``distortion_coefficients`` / ``image_width`` / ``image_height``, or a ROS ``camera_info`` YAML
with ``camera_matrix: {rows, cols, data}`` and ``distortion_coefficients`` (read with
``yaml.safe_load``). Each image is checked against the calibration's size, undistorted with its
coefficients, and turned from OpenCV's BGR into RGB. With ``undistort: false`` (what
``aes-planner calibrate`` asks for, :func:`aes_planner.devices.make_camera`) frames are given raw,
as the sensor took them, and the calibration file is optional (the one being made needs none).
``cv2`` is imported on :meth:`connect`, which asks the camera for the calibration's size.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aes_planner.config import ConfigError, require, short_repr
from aes_planner.devices import Camera, CameraError, CameraImage, DeviceError
from aes_planner.geometry.camera import Intrinsics, IntrinsicsError

log = logging.getLogger(__name__)

__all__ = [
    "MAX_CAMERA_INDEX",
    "Calibration",
    "OpenCVCamera",
    "OpenCVCameraConfig",
    "check_capture_source",
    "load_calibration",
]


@dataclass(frozen=True)
class Calibration:
    intrinsics: Intrinsics  # the package's convention: pixel centres at +0.5 (the file's cx, cy + 0.5)
    distortion: np.ndarray  # [k] OpenCV coefficients (k1, k2, p1, p2[, k3...])

    @property
    def K_opencv(self) -> np.ndarray:
        """The camera matrix as the file and OpenCV have it (pixel centres at integers)."""
        return self.intrinsics.K - np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]])


def _numbers(values: Any, key: str) -> np.ndarray:
    """``values`` as float64 when it is a flat list of at most 64 numbers (not strings, booleans, nested lists)."""
    ok = isinstance(values, list) and len(values) <= 64
    ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    if not ok:
        raise ConfigError(key, f"expected a list of at most 64 numbers, got {short_repr(values)}")
    try:
        return np.asarray(values, dtype=np.float64)
    except OverflowError:  # an integer of thousands of digits
        raise ConfigError(key, f"a number is too large for a float, got {short_repr(values)}") from None


def _matrix(node: Any, key: str, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    if isinstance(node, Mapping) and "data" in node:
        data = _numbers(node["data"], f"{key}.data")
        r, c = node.get("rows", rows or 1), node.get("cols", cols or data.size)
        if not all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 64 for v in (r, c)):
            raise ConfigError(key, f"rows and cols must be integers 1-64, got {short_repr(r)} and {short_repr(c)}")
        if data.size != r * c:
            raise ConfigError(key, f"{r}x{c} matrix needs {r * c} numbers, got {data.size}")
        return data.reshape(r, c)
    if isinstance(node, list):
        return _numbers(node, key)
    raise ConfigError(key, f"expected a matrix ({{rows, cols, data}} or a list), got {short_repr(node)}")


def load_calibration(path: str | Path) -> Calibration:
    """Intrinsics and distortion from an OpenCV or ROS camera-info YAML (read as every YAML file is:
    :func:`aes_planner.config.load_yaml_text`, with its limits)."""
    from aes_planner.config import load_yaml_text, read_yaml_text

    if not Path(path).exists():
        raise ConfigError("calibration", f"{path}: file not found; give the camera's calibration YAML")
    text = read_yaml_text(path)
    if text.startswith("%YAML"):  # OpenCV FileStorage: a directive line and !!opencv-matrix tags
        text = "\n".join(ln for ln in text.splitlines() if not ln.startswith("%YAML")).replace("!!opencv-matrix", "")
        text = text.lstrip("-\n")
    data = load_yaml_text(text, str(path))
    if not isinstance(data, Mapping) or "camera_matrix" not in data:
        raise ConfigError("calibration", f"{path}: expected camera_matrix (and image_width, image_height)")
    for k in ("image_width", "image_height"):
        if not isinstance(data.get(k), int) or data[k] < 1:
            raise ConfigError(f"calibration.{k}", f"{path}: must be a positive integer, got {data.get(k)!r}")
    K = _matrix(data["camera_matrix"], "calibration.camera_matrix", 3, 3).reshape(3, 3)
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ConfigError("calibration.camera_matrix", f"{path}: focal lengths must be positive and finite")
    dist_node = data.get("distortion_coefficients", [])
    dist = _matrix(dist_node, "calibration.distortion_coefficients").reshape(-1) if dist_node else np.zeros(0)
    if not np.all(np.isfinite(dist)):
        raise ConfigError("calibration.distortion_coefficients", f"{path}: must be finite")
    if dist.size and dist.size not in (4, 5, 8, 12, 14):  # what cv2.undistort takes
        raise ConfigError(
            "calibration.distortion_coefficients",
            f"{path}: OpenCV takes 4, 5, 8, 12 or 14 coefficients (k1 k2 p1 p2 [k3 ...]), got {dist.size}",
        )
    # OpenCV and ROS put pixel centres at integers, the package at +0.5 (aes_planner.geometry)
    cx, cy = float(K[0, 2]) + 0.5, float(K[1, 2]) + 0.5
    try:  # Intrinsics hold the plausibility bounds themselves: every frame would be refused
        k = Intrinsics(float(K[0, 0]), float(K[1, 1]), cx, cy, data["image_width"], data["image_height"])
    except IntrinsicsError as exc:
        raise ConfigError("calibration.camera_matrix", f"{path}: {exc}") from None
    return Calibration(k, dist)


#: Largest camera index accepted (``/dev/video0`` ... ``/dev/video1023``).
MAX_CAMERA_INDEX = 1023


def check_capture_source(device: Any) -> None:
    """Refuse a capture source before OpenCV sees it: ``cv2.VideoCapture(-1)`` dies of a segmentation
    fault (the process, not an exception), and an index past 2**31 is a ``TypeError``."""
    if isinstance(device, bool) or not isinstance(device, (int, str)):
        raise ConfigError("device", f"expected a camera index or a path/URL, got {short_repr(device)}")
    if isinstance(device, int):
        require(
            0 <= device <= MAX_CAMERA_INDEX,
            "device",
            f"a camera index is 0-{MAX_CAMERA_INDEX} (/dev/videoN), got {device}",
        )
    else:
        require(
            1 <= len(device) <= 4096 and device.isprintable(),
            "device",
            f"a camera path or URL is 1-4096 printable characters, got {short_repr(device)}",
        )


@dataclass
class OpenCVCameraConfig:
    """* ``device``: the ``cv2.VideoCapture`` source, an index (``/dev/videoN``) or a path/URL.
    * ``calibration``: the camera-info YAML (OpenCV or ROS); required to read undistorted images.
    * ``undistort``: undistort each frame with the calibration (a node's frames); false: raw
      frames, as the sensor took them (a calibration's; the calibration file then optional)."""

    device: int | str = 0
    calibration: str = ""
    undistort: bool = True

    def __post_init__(self):
        check_capture_source(self.device)
        require(isinstance(self.calibration, str), "calibration", f"expected a file path, got {self.calibration!r}")
        require(isinstance(self.undistort, bool), "undistort", f"expected true or false, got {self.undistort!r}")


class OpenCVCamera(Camera):
    """See the module docstring. ``capture`` replaces ``cv2.VideoCapture`` (anything with
    ``read() -> (ok, bgr [H, W, 3] uint8)`` and ``release()``: tests); ``calibration`` the file."""

    config_class = OpenCVCameraConfig

    def __init__(self, config: OpenCVCameraConfig, capture=None, calibration: Calibration | None = None):
        self.config = config
        if calibration is None and (config.calibration or config.undistort):
            if not config.calibration:
                raise ConfigError(
                    "calibration",
                    "give the camera's calibration YAML (OpenCV or ROS camera_info), or undistort: false for raw frames",
                )
            calibration = load_calibration(config.calibration)
        self.calibration = calibration  # None: raw frames of any size (a camera being calibrated)
        self.intrinsics = calibration.intrinsics if calibration is not None else None
        self._capture = capture

    @property
    def connected(self) -> bool:
        return self._capture is not None

    def connect(self) -> None:
        if self._capture is None:
            import cv2

            capture = cv2.VideoCapture(self.config.device)
            if not capture.isOpened():
                raise DeviceError(f"cannot open camera {self.config.device!r}; check the index or path")
            if self.intrinsics is not None:  # ask for the calibration's size (a camera may start at another)
                capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.intrinsics.width)
                capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.intrinsics.height)
            self._capture = capture

    def disconnect(self) -> None:
        if self._capture is not None:
            try:
                self._capture.release()
            finally:
                self._capture = None

    def read(self, stamp_s: float) -> CameraImage | None:
        if self._capture is None:
            return None
        ok, bgr = self._capture.read()
        if not ok or bgr is None:
            return None
        k = self.intrinsics
        if bgr.ndim != 3 or bgr.shape[2] != 3:
            raise CameraError(f"frame {bgr.shape} is not a colour image [H, W, 3]; check the camera's pixel format")
        if k is not None and bgr.shape[:2] != (k.height, k.width):
            raise CameraError(
                f"the camera delivers {bgr.shape[1]}x{bgr.shape[0]} frames but its calibration is for "
                f"{k.width}x{k.height}; calibrate the camera at this resolution"
            )
        undistort = self.config.undistort and self.calibration is not None
        if undistort and self.calibration.distortion.size and np.any(self.calibration.distortion):
            import cv2

            bgr = cv2.undistort(bgr, self.calibration.K_opencv, self.calibration.distortion)
        rgb = np.ascontiguousarray(bgr[..., ::-1]).astype(np.uint8, copy=False)
        return CameraImage(rgb, float(stamp_s))
