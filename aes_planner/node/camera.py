"""``CameraNode``: a real camera (OpenCV ``VideoCapture``) on a pan-tilt rig.

Each frame is undistorted with the calibration (an OpenCV ``FileStorage`` YAML with
``camera_matrix`` / ``distortion_coefficients`` / ``image_width`` / ``image_height``, or a ROS
``camera_info`` YAML with ``camera_matrix: {rows, cols, data}`` and ``distortion_coefficients``),
stamped with the host clock when it is read, and posed by the rig's kinematics at the gimbal's
joint angles **at that stamp**: ``gimbal/state`` messages are kept for ``state_history_s`` and
interpolated linearly between the two around the stamp (held at the ends). A frame older than the
history, or taken before any gimbal state, is not published (counted).
"""

from __future__ import annotations

import bisect
import logging
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aes_planner.config import ConfigError, require, require_numbers, short_repr
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.pantilt import PanTilt, PanTiltConfig
from aes_planner.graph.base import LaunchContext, Node, NodeError, Outputs
from aes_planner.messages import GimbalState, PosedFrame

log = logging.getLogger(__name__)

__all__ = ["CameraNode", "CameraNodeConfig", "Calibration", "load_calibration"]


@dataclass(frozen=True)
class Calibration:
    intrinsics: Intrinsics
    distortion: np.ndarray  # [k] OpenCV coefficients (k1, k2, p1, p2[, k3...])


def _matrix(node: Any, key: str, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    if isinstance(node, Mapping) and "data" in node:
        data = np.asarray(node["data"], dtype=np.float64)
        r, c = int(node.get("rows", rows or 1)), int(node.get("cols", cols or data.size))
        if data.size != r * c:
            raise ConfigError(key, f"{r}x{c} matrix needs {r * c} numbers, got {data.size}")
        return data.reshape(r, c)
    if isinstance(node, list):
        return np.asarray(node, dtype=np.float64)
    raise ConfigError(key, f"expected a matrix ({{rows, cols, data}} or a list), got {node!r}")


def load_calibration(path: str | Path) -> Calibration:
    """Intrinsics and distortion from an OpenCV or ROS camera-info YAML (``yaml.safe_load``)."""
    from aes_planner.config import load_yaml

    text = Path(path).read_text(encoding="utf-8") if Path(path).exists() else None
    if text is None:
        raise ConfigError("calibration", f"{path}: file not found; give the camera's calibration YAML")
    if text.startswith("%YAML"):  # OpenCV FileStorage: a directive line and !!opencv-matrix tags
        import yaml

        body = "\n".join(ln for ln in text.splitlines() if not ln.startswith("%YAML")).replace("!!opencv-matrix", "")
        data = yaml.safe_load(body.lstrip("-\n"))
    else:
        data = load_yaml(path)
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
    k = Intrinsics(
        float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), data["image_width"], data["image_height"]
    )
    return Calibration(k, dist)


#: Largest camera index accepted (``/dev/video0`` ... ``/dev/video1023``).
MAX_CAMERA_INDEX = 1023


def _check_capture_source(device: Any) -> None:
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
class CameraNodeConfig:
    """* ``device``: ``cv2.VideoCapture`` source (an index or a path/URL).
    * ``calibration``: the camera-info YAML (required for a real camera).
    * ``rate_hz``: frames read per second; ``state_history_s``: gimbal states kept for posing.
    * ``rig``: the pan-tilt kinematics the camera sits on (a sim launch takes the scene's).
    * ``frame_id``: the frames' name prefix.
    """

    device: int | str = 0
    calibration: str = ""
    rate_hz: float = 10.0
    state_history_s: float = 2.0
    rig: PanTiltConfig | None = None
    frame_id: str = "camera"

    def __post_init__(self):
        _check_capture_source(self.device)
        require(
            isinstance(self.frame_id, str) and self.frame_id.isprintable() and 1 <= len(self.frame_id) <= 200,
            "frame_id",
            f"must be 1-200 printable characters (each frame's id is FRAME_ID/NUMBER), got {short_repr(self.frame_id)}",
        )
        require_numbers(self, ("rate_hz", "state_history_s"))
        require(self.state_history_s <= 60, "state_history_s", f"must be <= 60 s (memory), got {self.state_history_s}")
        require(0.01 <= self.rate_hz <= 240, "rate_hz", f"must be in [0.01, 240] Hz, got {self.rate_hz}")


class CameraNode(Node):
    """See the module docstring. ``capture`` replaces ``cv2.VideoCapture`` (anything with
    ``read() -> (ok, bgr [H, W, 3] uint8)`` and ``release()``); ``calibration`` the file."""

    config_class = CameraNodeConfig
    inputs = {"gimbal/state": (GimbalState, 64)}
    outputs = {"camera/frame": (PosedFrame, False)}

    def __init__(
        self,
        config: CameraNodeConfig | None = None,
        node_id: str = "camera",
        context: LaunchContext | None = None,
        capture=None,
        calibration: Calibration | None = None,
    ):
        super().__init__(config or CameraNodeConfig(), node_id, context)
        c = self.config
        rig = c.rig
        if rig is None and self.context.scene is not None and self.context.load_scene().rig is not None:
            rig = self.context.load_scene().rig.pan_tilt
        if rig is None:
            raise NodeError(f"{node_id}: the camera node needs the rig's kinematics: set config.rig")
        self.kinematics = PanTilt(rig)
        if calibration is None:
            if not c.calibration:
                raise ConfigError("calibration", "give the camera's calibration YAML (OpenCV or ROS camera_info)")
            calibration = load_calibration(c.calibration)
        self.calibration = calibration
        self._capture = capture
        self._stamps: deque[float] = deque()
        self._joints: deque[tuple[float, float]] = deque()
        self.counters = {"frames": 0, "read_failures": 0, "unposed": 0, "size_mismatch": 0}
        self._last_s = -np.inf
        self._maps = None

    @property
    def period_s(self) -> float:
        return 1.0 / self.config.rate_hz

    def start(self) -> None:
        if self._capture is None:
            import cv2

            self._capture = cv2.VideoCapture(self.config.device)
            if not self._capture.isOpened():
                raise NodeError(f"{self.node_id}: cannot open camera {self.config.device!r}; check the index or path")

    def stop(self) -> None:
        if self._capture is not None:
            try:
                self._capture.release()
            finally:
                self._capture = None

    def joints_at(self, stamp_s: float) -> tuple[float, float] | None:
        """Joint angles at ``stamp_s``, linearly interpolated between gimbal states."""
        if not self._stamps or stamp_s < self._stamps[0] - self.config.state_history_s:
            return None
        stamps = list(self._stamps)
        i = bisect.bisect_right(stamps, stamp_s)
        if i == 0:
            return self._joints[0]
        if i == len(stamps):
            return self._joints[-1]
        t0, t1 = stamps[i - 1], stamps[i]
        (p0, q0), (p1, q1) = self._joints[i - 1], self._joints[i]
        w = (stamp_s - t0) / (t1 - t0) if t1 > t0 else 1.0
        return p0 + w * (p1 - p0), q0 + w * (q1 - q0)

    def step(self, inputs: Mapping[str, list], now: float) -> Outputs:
        for s in inputs.get("gimbal/state", ()):
            if self._stamps and s.stamp_s <= self._stamps[-1]:
                continue
            self._stamps.append(s.stamp_s)
            self._joints.append((s.pan_rad, s.tilt_rad))
        while self._stamps and self._stamps[0] < now - self.config.state_history_s and len(self._stamps) > 2:
            self._stamps.popleft()
            self._joints.popleft()
        if now - self._last_s < self.period_s * 0.999 or self._capture is None:
            return {"camera/frame": []}
        self._last_s = now
        ok, bgr = self._capture.read()
        stamp = time.time() if now is None else now
        if not ok or bgr is None:
            self.counters["read_failures"] += 1
            return {"camera/frame": []}
        frame = self._frame(bgr, stamp)
        return {"camera/frame": [frame] if frame is not None else []}

    def _frame(self, bgr: np.ndarray, stamp: float) -> PosedFrame | None:
        import cv2

        k = self.calibration.intrinsics
        if bgr.ndim != 3 or bgr.shape[:2] != (k.height, k.width):
            self.counters["size_mismatch"] += 1
            log.warning("%s: frame %s does not match the calibration %dx%d", self.node_id, bgr.shape, k.width, k.height)
            return None
        joints = self.joints_at(stamp)
        if joints is None:
            self.counters["unposed"] += 1
            return None
        if self.calibration.distortion.size and np.any(self.calibration.distortion):
            bgr = cv2.undistort(bgr, k.K, self.calibration.distortion)
        rgb = np.ascontiguousarray(bgr[..., ::-1])
        pan, tilt = joints
        frame = PosedFrame(
            image=rgb.astype(np.uint8, copy=False),
            intrinsics=k,
            cam2world=self.kinematics.forward(pan, tilt),
            stamp_s=stamp,
            frame_id=f"{self.config.frame_id}/{self.counters['frames']:06d}",
            sequence=self.counters["frames"],
            pan_rad=float(pan),
            tilt_rad=float(tilt),
        )
        self.counters["frames"] += 1
        return frame
