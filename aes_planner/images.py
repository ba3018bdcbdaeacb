"""Image files in and out, outside the dataset format: images to score, contact sheets to look at."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from aes_planner.errors import AesPlannerError
from aes_planner.messages import PosedFrame

__all__ = ["read_image", "write_contact_sheet"]


def read_image(path: str | Path):  # -> Tensor [3, H, W] float in [0, 1]
    """An image file as RGB float in [0, 1]; grey is repeated, alpha dropped, 16 bit kept."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise AesPlannerError(f"{path}: no such image file")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.size == 0:
        raise AesPlannerError(f"{path}: not an image OpenCV can read (PNG, JPEG, TIFF, BMP, ...)")
    if raw.dtype == np.uint8:
        arr = raw.astype(np.float32) / 255.0
    elif raw.dtype == np.uint16:
        arr = raw.astype(np.float32) / 65535.0
    elif raw.dtype in (np.float32, np.float64):
        arr = np.clip(np.nan_to_num(raw.astype(np.float32)), 0.0, 1.0)
    else:
        raise AesPlannerError(f"{path}: unsupported pixel type {raw.dtype}; save it as 8- or 16-bit PNG")
    if arr.ndim == 2:
        arr = np.repeat(arr[..., None], 3, axis=2)
    elif arr.shape[2] == 4:
        arr = arr[..., [2, 1, 0]]  # BGRA -> RGB, alpha dropped
    elif arr.shape[2] == 3:
        arr = arr[..., ::-1]
    else:
        raise AesPlannerError(f"{path}: {arr.shape[2]} channels; expected grey, RGB or RGBA")
    return torch.from_numpy(np.ascontiguousarray(arr)).permute(2, 0, 1).contiguous()


def write_contact_sheet(frames: Sequence[PosedFrame], path: str | Path) -> Path:
    """RGB on top, colour-mapped depth below, one column per frame; returns ``path``."""
    path = Path(path)
    cols = []
    for f in frames:
        rgb = cv2.cvtColor(f.image, cv2.COLOR_RGB2BGR)
        d = f.depth_m if f.depth_m is not None else np.zeros(f.image.shape[:2], np.float32)
        valid = d > 0
        scale = np.percentile(d[valid], 98) if valid.any() else 1.0
        d8 = np.where(valid, 255 - np.clip(d / scale * 255, 0, 255), 0).astype(np.uint8)
        cols.append(np.vstack([rgb, cv2.applyColorMap(d8, cv2.COLORMAP_VIRIDIS)]))
    sheet = np.hstack([np.pad(c, ((2, 2), (2, 2), (0, 0)), constant_values=255) for c in cols])
    cv2.imwrite(str(path), sheet)
    return path
