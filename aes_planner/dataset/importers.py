"""Importers: nerfstudio ``transforms.json`` and RealEstate10K camera files -> :class:`PosedDataset`.

* **nerfstudio** (``transforms.json``): intrinsics ``fl_x, fl_y, cx, cy, w, h`` at the top level or
  per frame (or ``camera_angle_x`` as in the original NeRF files); ``frames[i].file_path`` relative
  to the JSON file; ``transform_matrix`` is cam2world with **OpenGL camera axes** (x right, y up,
  z backward), converted here to OpenCV (x right, y down, z forward) by flipping the y and z
  camera axes. ``depth_file_path`` is read when present (16-bit PNG scaled by
  ``depth_unit_scale_factor``, default 1e-3 m, or ``.npy`` metres). The planner models a pinhole
  camera: frames with distortion coefficients are undistorted on import to the same intrinsics
  (``camera_model`` ``OPENCV``: ``k1 k2 p1 p2 k3``; ``OPENCV_FISHEYE``: ``k1``-``k4``); another model
  with non-zero coefficients is refused.
* **RealEstate10K** (one ``.txt`` per clip): first line the video URL, then one line per frame:
  ``timestamp_us fx fy cx cy 0 0`` (intrinsics normalised by the image size) followed by a 3x4
  **world-to-camera** matrix, row-major (19 numbers per line). Frame images are looked up as
  ``<frames_dir>/<timestamp>.{png,jpg,jpeg}``.

Neither format fixes which way is up; the planner's 5-DoF views need world +z up.
``up="cameras"`` rotates the world so that the mean camera up axis (-y of the OpenCV camera)
becomes +z (right for footage shot by a level camera: RealEstate10K's default); ``up="keep"``
leaves the world as it is (right for nerfstudio data processed with its default
``orientation_method="up"``, or any z-up source).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Literal

import numpy as np

from aes_planner.config import short_repr
from aes_planner.dataset.folder import (
    DatasetError,
    PosedDataset,
    _inside,
    check_depth_scale,
    check_intrinsics,
    finite_number,
    frame_from_parts,
    pixel_count,
    read_depth,
    read_json,
    read_rgb,
)
from aes_planner.geometry.camera import Intrinsics, IntrinsicsError
from aes_planner.geometry.plausible import FOV_RANGE_DEG
from aes_planner.geometry.poses import PoseError, rigid_inverse, validate_cam2world

log = logging.getLogger(__name__)

__all__ = ["import_nerfstudio", "import_re10k", "align_up_to_cameras", "rotation_to_z", "OPENGL_TO_OPENCV"]

# Right-multiplying an OpenGL-axes cam2world by this flips the camera's y and z axes.
OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])

UpMode = Literal["cameras", "keep"]
_RE10K_MAX_BYTES = 64 << 20  # a clip's camera file is about 200 bytes per frame


def align_up_to_cameras(cam2worlds: np.ndarray) -> np.ndarray:
    """World rotation ``[4, 4]`` that maps the mean camera up axis (-y, OpenCV) to +z.

    Apply as ``aligned = R @ cam2world``. The rotation is the smallest one doing that; if the mean
    up is ill-defined (cameras disagree completely) the identity is returned with a warning.
    """
    ups = -np.asarray(cam2worlds)[:, :3, 1]  # [N, 3]
    mean = ups.mean(axis=0)
    if np.linalg.norm(mean) < 1e-6:
        log.warning("camera up axes cancel out; keeping the world orientation")
        return np.eye(4)
    return rotation_to_z(mean)


def rotation_to_z(up: np.ndarray) -> np.ndarray:
    """The smallest world rotation ``[4, 4]`` taking the direction ``up [3]`` (non-zero) to +z."""
    out = np.eye(4)
    a = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(a, z)
    s, c = np.linalg.norm(v), float(np.dot(a, z))
    if s < 1e-12:
        if c < 0:  # upside down: half turn about x
            out[:3, :3] = np.diag([1.0, -1.0, -1.0])
        return out
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    out[:3, :3] = np.eye(3) + vx + vx @ vx * ((1 - c) / (s * s))
    return out


def _apply_up(frames_c2w: list[np.ndarray], up: UpMode) -> tuple[list[np.ndarray], np.ndarray]:
    if up not in ("cameras", "keep"):
        raise DatasetError(f"up must be 'cameras' or 'keep', got {up!r}")
    if up == "keep" or not frames_c2w:
        return frames_c2w, np.eye(4)
    r = align_up_to_cameras(np.stack(frames_c2w))
    return [r @ m for m in frames_c2w], r


def _undistort(
    image: np.ndarray,  # [H, W, 3] uint8
    depth: np.ndarray | None,  # [H, W] metres
    k: Intrinsics,
    merged: dict,
    key: str,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The frame undistorted to the pinhole camera ``k`` (same intrinsics), by nerfstudio's
    ``camera_model``: ``OPENCV`` (``k1 k2 p1 p2 [k3]``) or ``OPENCV_FISHEYE`` (``k1``-``k4``);
    other models with non-zero coefficients are refused. Depth is resampled nearest-neighbour;
    pixels that see outside the original image are black (depth 0: unknown)."""
    import cv2

    c = {d: finite_number(merged, d, key, 0.0) for d in ("k1", "k2", "k3", "k4", "p1", "p2")}
    if not any(c.values()):
        return image, depth
    model = merged.get("camera_model", "OPENCV")
    size = (k.width, k.height)
    if model == "OPENCV" and not c["k4"]:
        dist = np.array([c["k1"], c["k2"], c["p1"], c["p2"], c["k3"]])
        maps = cv2.initUndistortRectifyMap(k.K, dist, None, k.K, size, cv2.CV_32FC1)
    elif model == "OPENCV_FISHEYE" and not (c["p1"] or c["p2"]):
        dist = np.array([c["k1"], c["k2"], c["k3"], c["k4"]])
        maps = cv2.fisheye.initUndistortRectifyMap(k.K, dist, np.eye(3), k.K, size, cv2.CV_32FC1)
    else:
        raise DatasetError(
            f"{key}: camera_model {short_repr(model)} with distortion { ({d: v for d, v in c.items() if v}) } is not "
            "undistorted here (OPENCV takes k1 k2 p1 p2 k3, OPENCV_FISHEYE k1-k4); undistort the images first"
        )
    log.info("%s: undistorted (%s %s)", key, model, ", ".join(f"{d}={v:g}" for d, v in c.items() if v))
    out = cv2.remap(image, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if depth is not None:
        depth = cv2.remap(
            depth.astype(np.float32), *maps, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        ).astype(depth.dtype)
    return out, depth


def import_nerfstudio(
    transforms_json: str | Path, up: UpMode = "keep", load_depth: bool = True, allow_outside: bool = False
) -> PosedDataset:
    """Read a nerfstudio ``transforms.json`` (see the module docstring).

    Image and depth paths must lead inside the JSON file's folder unless ``allow_outside``."""
    path = Path(transforms_json)
    if path.is_dir():
        path = path / "transforms.json"
    doc = read_json(path, "pass nerfstudio's transforms.json or its folder")
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise DatasetError(f"{path}: expected an object with a 'frames' list (a nerfstudio transforms.json)")
    root = path.parent
    parts = []
    for i, fr in enumerate(doc["frames"]):
        key = f"frames[{i}]"
        if not isinstance(fr, dict) or not isinstance(fr.get("file_path"), str):
            raise DatasetError(f"{key}.file_path: missing")
        image = read_rgb(_inside(root, fr["file_path"], f"{key}.file_path", allow_outside), f"{key}.file_path")
        h, w = image.shape[:2]
        merged = {**doc, **fr}
        if pixel_count(merged, "w", key, w) != w or pixel_count(merged, "h", key, h) != h:
            raise DatasetError(f"{key}: w/h say {merged.get('w')}x{merged.get('h')} but {fr['file_path']} is {w}x{h}")
        fx = finite_number(merged, "fl_x", key, None)
        fy = finite_number(merged, "fl_y", key, None)
        if fx is None and "camera_angle_x" in merged:
            angle = finite_number(merged, "camera_angle_x", key)
            lo, hi = (math.radians(a) for a in FOV_RANGE_DEG)
            if not lo <= angle <= hi:
                raise DatasetError(
                    f"{key}.camera_angle_x: {angle:g} rad; it is the horizontal field of view in radians, "
                    f"expected {lo:.4f} to {hi:.4f}"
                )
            fx = 0.5 * w / math.tan(angle / 2)
        if fx is None:
            raise DatasetError(f"{key}: no focal length (fl_x, or camera_angle_x) at the top level or in the frame")
        fy = fy if fy is not None else fx
        cx = finite_number(merged, "cx", key, w / 2.0)
        cy = finite_number(merged, "cy", key, h / 2.0)
        try:
            k = check_intrinsics(Intrinsics(fx, fy, cx, cy, w, h), key)
        except IntrinsicsError as exc:
            raise DatasetError(f"{key}.{exc.problem}" if exc.problem else f"{key}: {exc}") from None
        if "transform_matrix" not in fr:
            raise DatasetError(f"{key}.transform_matrix: missing")
        try:
            m = validate_cam2world(np.asarray(fr["transform_matrix"], dtype=np.float64), f"{key}.transform_matrix")
        except (PoseError, ValueError, TypeError) as exc:
            raise DatasetError(
                str(exc) if isinstance(exc, PoseError) else f"{key}.transform_matrix: expected a 4x4 list of numbers"
            ) from None
        depth = None
        if load_depth and fr.get("depth_file_path"):
            if not isinstance(fr["depth_file_path"], str):
                raise DatasetError(f"{key}.depth_file_path: expected a path relative to {root}")
            scale = finite_number(merged, "depth_unit_scale_factor", key, 1e-3)
            check_depth_scale(scale, f"{key}.depth_unit_scale_factor")
            depth_path = _inside(root, fr["depth_file_path"], f"{key}.depth_file_path", allow_outside)
            depth = read_depth(depth_path, f"{key}.depth_file_path", scale)
        image, depth = _undistort(image, depth, k, merged, key)
        parts.append((key, image, k, m @ OPENGL_TO_OPENCV, depth, Path(fr["file_path"]).stem))
    if not parts:
        raise DatasetError(f"{path}: 'frames' is empty; there is nothing to import")
    poses, rot = _apply_up([p[3] for p in parts], up)
    frames = [
        frame_from_parts(key, image, k, c2w, float(i), depth, fid)
        for i, ((key, image, k, _, depth, fid), c2w) in enumerate(zip(parts, poses))
    ]
    meta = {"source": "nerfstudio", "path": str(path), "up": up, "world_rotation": rot.tolist()}
    return PosedDataset(frames, meta, root)


def _find_frame_image(frames_dir: Path, stamp: str, key: str, allow_outside: bool) -> Path:
    for ext in (".png", ".jpg", ".jpeg"):
        p = frames_dir / f"{stamp}{ext}"
        if p.is_file():
            return _inside(frames_dir, p.name, key, allow_outside)
    raise DatasetError(
        f"{key}: no image {stamp}.png/.jpg in {frames_dir}; extract the clip's frames named by timestamp"
    )


def import_re10k(
    camera_txt: str | Path,
    frames_dir: str | Path,
    up: UpMode = "cameras",
    every: int = 1,
    allow_outside: bool = False,
) -> PosedDataset:
    """Read a RealEstate10K clip (see the module docstring); ``every`` keeps every n-th frame.

    Frame images must be files inside ``frames_dir`` (symlinks that leave it are refused) unless
    ``allow_outside``."""
    path = Path(camera_txt)
    if not path.is_file():
        raise DatasetError(f"{path}: not found")
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise DatasetError(f"every must be an integer >= 1, got {every!r}")
    frames_dir = Path(frames_dir)
    if not frames_dir.is_dir():
        raise DatasetError(f"{frames_dir}: not a folder; --frames is the folder of the clip's frames")
    if path.stat().st_size > _RE10K_MAX_BYTES:
        raise DatasetError(f"{path}: larger than {_RE10K_MAX_BYTES} bytes; not a RealEstate10K camera file")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise DatasetError(
            f"{path}: not a text file; a RealEstate10K camera file is text, one frame per line"
        ) from None
    lines = [(no, ln.strip()) for no, ln in enumerate(text.splitlines(), start=1) if ln.strip()]
    if not lines:
        raise DatasetError(f"{path}: empty file")
    body = lines if _looks_numeric(lines[0][1]) else lines[1:]  # the first line is the video URL
    parts = []
    for line_no, ln in body[::every]:
        key = f"{path.name}:{line_no}"
        fields = ln.split()
        if len(fields) != 19:
            raise DatasetError(
                f"{key}: expected 19 numbers (timestamp, fx fy cx cy 0 0, 12 of world-to-camera), got {len(fields)}"
            )
        if not fields[0].isascii() or not fields[0].isdigit():
            raise DatasetError(f"{key}: the first field must be the timestamp in microseconds (digits only)")
        try:
            values = np.array([float(v) for v in fields[1:]])
        except ValueError:
            raise DatasetError(f"{key}: not all fields are numbers") from None
        if not np.all(np.isfinite(values)):
            raise DatasetError(f"{key}: contains NaN or Inf")
        image = read_rgb(_find_frame_image(frames_dir, fields[0], key, allow_outside), key)
        h, w = image.shape[:2]
        fx_n, fy_n, cx_n, cy_n = values[:4]
        try:
            k = check_intrinsics(Intrinsics.from_normalized(fx_n, fy_n, cx_n, cy_n, w, h), key)
        except IntrinsicsError as exc:
            raise DatasetError(f"{key}.{exc.problem}" if exc.problem else f"{key}: {exc}") from None
        w2c = np.vstack([values[6:].reshape(3, 4), [0.0, 0.0, 0.0, 1.0]])
        try:
            w2c = validate_cam2world(w2c, f"{key} world-to-camera")
        except PoseError as exc:
            raise DatasetError(str(exc)) from None
        parts.append((key, image, k, rigid_inverse(w2c), int(fields[0]) * 1e-6, fields[0]))
    if not parts:
        raise DatasetError(f"{path}: no frame lines; there is nothing to import")
    poses, rot = _apply_up([p[3] for p in parts], up)
    frames = [
        frame_from_parts(key, image, k, c2w, stamp, None, fid)
        for (key, image, k, _, stamp, fid), c2w in zip(parts, poses)
    ]
    meta = {"source": "re10k", "path": str(path), "up": up, "world_rotation": rot.tolist()}
    return PosedDataset(frames, meta, frames_dir)


def _looks_numeric(line: str) -> bool:
    try:
        float(line.split()[0])
        return True
    except (ValueError, IndexError):
        return False
