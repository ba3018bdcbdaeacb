"""Camera intrinsics from images of a board: OpenCV's standard pipeline, ROS camera_info out.

``findChessboardCorners`` (``findChessboardCornersSB`` where it fails) and ``cornerSubPix``
(:func:`aes_planner.calibrate.board.detect`), then ``calibrateCamera`` with its default model
(plumb_bob: k1, k2, p1, p2, k3). A view is left out only for a reason it names: the board is not
(wholly) found, the image is blurred (OpenCV's ``estimateChessboardSharpness``: edges wider than
:data:`MAX_EDGE_WIDTH_PX` and twice the set's median), it repeats another view's pose (corners
within :data:`DUPLICATE_PX` on average), or its size differs from the first image's.

The camera_info YAML is camera_calibration_parsers' format (what ROS ``camera_calibration`` and
``camera_info_manager`` write and read), in OpenCV's pixel convention (centres at integers):
``aes_planner.drivers.camera.load_calibration`` reads it back.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from aes_planner.calibrate.board import BoardSpec, Detection, detect
from aes_planner.errors import AesPlannerError
from aes_planner.images import imread_bounded

log = logging.getLogger(__name__)

__all__ = ["CalibrationFailed", "IntrinsicsResult", "calibrate_views", "camera_info_yaml", "load_views"]

MAX_EDGE_WIDTH_PX = 5.0
DUPLICATE_PX = 2.0
MIN_VIEWS = 3


class CalibrationFailed(AesPlannerError, ValueError):
    """Images that cannot calibrate a camera (too few usable views...)."""


@dataclass
class View:
    name: str
    gray: np.ndarray | None
    detection: Detection | None = None


@dataclass
class IntrinsicsResult:
    K: np.ndarray  # [3, 3] OpenCV convention
    distortion: np.ndarray  # [5] k1, k2, p1, p2, k3
    width: int
    height: int
    rms_px: float
    used: list[dict] = field(default_factory=list)
    rejected: list[dict] = field(default_factory=list)
    coverage: float = 0.0

    def report(self) -> dict:
        return {
            "fx": float(self.K[0, 0]),
            "fy": float(self.K[1, 1]),
            "cx": float(self.K[0, 2]),
            "cy": float(self.K[1, 2]),
            "distortion_model": "plumb_bob",
            "distortion": [float(v) for v in self.distortion],
            "image_width": self.width,
            "image_height": self.height,
            "rms_px": self.rms_px,
            "views_used": self.used,
            "views_rejected": self.rejected,
            "coverage": self.coverage,
            "pixel_convention": "OpenCV/ROS: pixel centres at integer coordinates",
        }


def load_views(paths: list[str | Path], board: BoardSpec) -> list[View]:
    """Read and detect each image (grayscale)."""
    views = []
    for path in paths:
        gray = imread_bounded(path, cv2.IMREAD_GRAYSCALE, f"image {path}", CalibrationFailed)
        views.append(View(str(path), gray, detect(gray, board)))
    return views


def _sharpness(view: View, board: BoardSpec) -> float | None:
    if board.kind != "chessboard" or view.detection is None:
        return None
    cols, rows = board.corners_grid
    corners = view.detection.image_points.reshape(-1, 1, 2).astype(np.float32)
    try:
        return float(cv2.estimateChessboardSharpness(view.gray, (cols, rows), corners)[0][0])
    except cv2.error:
        return None


def _coverage(points: list[np.ndarray], width: int, height: int, cells: int = 10) -> float:
    """Fraction of a ``cells x cells`` grid over the image holding at least one corner."""
    hit = np.zeros((cells, cells), bool)
    for p in points:
        i = np.clip((p[:, 0] / width * cells).astype(int), 0, cells - 1)
        j = np.clip((p[:, 1] / height * cells).astype(int), 0, cells - 1)
        hit[j, i] = True
    return float(hit.mean())


def calibrate_views(views: list[View], board: BoardSpec) -> IntrinsicsResult:
    """``calibrateCamera`` on the views that pass the checks of the module docstring."""
    if not views:
        raise CalibrationFailed("no images given; pass the board images (e.g. views/*.png)")
    rejected: list[dict] = []
    size = views[0].gray.shape[::-1]
    candidates: list[View] = []
    for v in views:
        if v.gray.shape[::-1] != size:
            rejected.append(
                {
                    "image": v.name,
                    "reason": f"size {v.gray.shape[1]}x{v.gray.shape[0]} differs from {size[0]}x{size[1]}",
                }
            )
        elif v.detection is None:
            rejected.append(
                {"image": v.name, "reason": f"board not found (whole {board} with {board.n_corners} corners)"}
            )
        else:
            candidates.append(v)
    sharp = {v.name: _sharpness(v, board) for v in candidates}
    known = [s for s in sharp.values() if s is not None]
    limit = max(MAX_EDGE_WIDTH_PX, 2.0 * float(np.median(known))) if known else math.inf
    accepted: list[View] = []
    for v in candidates:
        s = sharp[v.name]
        if s is not None and s > limit:
            rejected.append({"image": v.name, "reason": f"blurred (edges {s:.1f} px wide, limit {limit:.1f})"})
            continue
        twin = next(
            (
                a
                for a in accepted
                if len(a.detection.image_points) == len(v.detection.image_points)
                and np.array_equal(a.detection.object_points, v.detection.object_points)
                and float(np.linalg.norm(a.detection.image_points - v.detection.image_points, axis=1).mean())
                < DUPLICATE_PX
            ),
            None,
        )
        if twin is not None:
            rejected.append({"image": v.name, "reason": f"duplicate pose of {twin.name}"})
            continue
        accepted.append(v)
    if len(accepted) < MIN_VIEWS:
        reasons = "; ".join(f"{r['image']}: {r['reason']}" for r in rejected[:5])
        raise CalibrationFailed(
            f"only {len(accepted)} usable views of {len(views)} (need {MIN_VIEWS}, 10-20 is good): {reasons or 'none rejected'}. "
            "Check that --board matches the printed board (inner corners COLSxROWS, not squares), and take sharp views "
            "with the board tilted and placed all over the image"
        )
    obj = [v.detection.object_points.astype(np.float32) for v in accepted]
    img = [v.detection.image_points.astype(np.float32).reshape(-1, 1, 2) for v in accepted]
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, None, None)
    used = []
    for v, o, i, r, t in zip(accepted, obj, img, rvecs, tvecs):
        proj, _ = cv2.projectPoints(o, r, t, K, dist)
        err = float(np.sqrt(((proj.reshape(-1, 2) - i.reshape(-1, 2)) ** 2).sum(-1).mean()))
        used.append({"image": v.name, "rms_px": err})
    points = [v.detection.image_points for v in accepted]
    return IntrinsicsResult(
        K=K,
        distortion=dist.reshape(-1)[:5],
        width=int(size[0]),
        height=int(size[1]),
        rms_px=float(rms),
        used=used,
        rejected=rejected,
        coverage=_coverage(points, size[0], size[1]),
    )


def _row(values) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def check_camera_name(name: str) -> str:
    """``name`` when it is a camera name (1-128 printable characters; camera_calibration_parsers'
    ``camera_name``); :class:`CalibrationFailed` naming ``--camera-name`` otherwise."""
    if not (isinstance(name, str) and 1 <= len(name) <= 128 and name.isprintable()):
        raise CalibrationFailed(
            f"--camera-name must be 1-128 printable characters (no newlines or control characters), got {name[:64]!r}"
        )
    return name


def camera_info_yaml(
    K: np.ndarray, distortion: np.ndarray, width: int, height: int, camera_name: str = "camera"
) -> str:
    """camera_calibration_parsers' YAML (OpenCV pixel convention); ``projection_matrix`` is ``[K | 0]``
    and ``rectification_matrix`` the identity, as for any monocular camera."""
    P = np.hstack([K, np.zeros((3, 1))])
    d = list(np.asarray(distortion, dtype=np.float64).reshape(-1)) + [0.0] * (
        5 - len(np.asarray(distortion).reshape(-1))
    )
    return (
        f"image_width: {int(width)}\n"
        f"image_height: {int(height)}\n"
        f"camera_name: {json.dumps(check_camera_name(camera_name))}\n"  # a quoted YAML scalar
        "camera_matrix:\n  rows: 3\n  cols: 3\n"
        f"  data: {_row(K.reshape(-1))}\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n"
        f"  data: {_row(d[:5])}\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n"
        f"  data: {_row(np.eye(3).reshape(-1))}\n"
        "projection_matrix:\n  rows: 3\n  cols: 4\n"
        f"  data: {_row(P.reshape(-1))}\n"
    )
