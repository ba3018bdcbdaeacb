"""Exporters: a posed-frame folder's frames -> nerfstudio ``transforms.json``.

The file is what nerfstudio's ``ns-process-data`` writes for pinhole images: per frame
``file_path`` (relative to the JSON file), ``transform_matrix`` (cam2world with **OpenGL camera
axes**: x right, y up, z backward, so the package's OpenCV pose times ``OPENGL_TO_OPENCV``, its own
inverse) and the intrinsics ``fl_x fl_y cx cy w h`` with ``camera_model: OPENCV`` and zero
distortion (the images are undistorted already). Shared intrinsics go to the top level, as
nerfstudio writes them for one camera. :func:`aes_planner.dataset.import_nerfstudio` with
``up="keep"`` reads the file back into the same frames.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aes_planner.dataset.folder import DatasetError, _jsonable, _writable
from aes_planner.dataset.importers import OPENGL_TO_OPENCV
from aes_planner.messages import PosedFrame

__all__ = ["write_nerfstudio"]


def _camera(f: PosedFrame) -> dict[str, Any]:
    k = f.intrinsics
    return {"fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height}


def write_nerfstudio(
    root: str | Path,
    frames: Sequence[PosedFrame],
    image_paths: Sequence[str] | None = None,
    meta: dict[str, Any] | None = None,
) -> Path:
    """Write ``root/transforms.json`` for ``frames`` whose images are ``image_paths`` (relative to
    ``root``; default ``images/00000.png``..., the names :func:`~aes_planner.dataset.save_dataset`
    gives them). ``meta`` is stored under ``aes_planner`` (nerfstudio ignores unknown keys)."""
    root = Path(root)
    if not frames:
        raise DatasetError("write_nerfstudio: no frames to write")
    paths = list(image_paths) if image_paths is not None else [f"images/{i:05d}.png" for i in range(len(frames))]
    if len(paths) != len(frames):
        raise DatasetError(f"write_nerfstudio: {len(paths)} image paths for {len(frames)} frames")
    cams = [_camera(f) for f in frames]
    shared = all(c == cams[0] for c in cams)
    entries = []
    for f, path, cam in zip(frames, paths, cams):
        entry: dict[str, Any] = {
            "file_path": path,
            "transform_matrix": (np.asarray(f.cam2world, np.float64) @ OPENGL_TO_OPENCV).tolist(),
        }
        if not shared:
            entry.update(cam)
        entries.append(entry)
    doc: dict[str, Any] = {**(cams[0] if shared else {}), "camera_model": "OPENCV",
                           "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": entries}  # fmt: skip
    if meta:
        doc["aes_planner"] = _jsonable(meta, "meta")
    path = _writable(root, "transforms.json")
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return path
