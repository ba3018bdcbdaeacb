"""``PosedFrame``: one image with its intrinsics, pose, optional depth and time stamp."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import PoseError, validate_cam2world

__all__ = ["MessageError", "PosedFrame"]


class MessageError(AesPlannerError, ValueError):
    """A message field has the wrong shape, type or a non-finite value."""


@dataclass
class PosedFrame:
    """An RGB image taken from a known pose.

    * ``image``: ``[H, W, 3]`` uint8 RGB.
    * ``intrinsics``: pinhole intrinsics in pixels; its size must be the image's.
    * ``cam2world``: ``[4, 4]`` float64, OpenCV camera axes (see :mod:`aes_planner.geometry`).
    * ``depth_m``: optional ``[H, W]`` float32 z-depth in metres; ``0`` marks pixels without a
      measurement (sky, holes). Never NaN or Inf.
    * ``stamp_s``: capture time in seconds (the sensor's clock; sim time in the simulator).
    * ``frame_id``: a name for the frame (file stem, sequence number), free-form.

    Construction validates every field and raises :class:`MessageError` naming it.
    """

    image: np.ndarray
    intrinsics: Intrinsics
    cam2world: np.ndarray
    stamp_s: float = 0.0
    depth_m: np.ndarray | None = None
    frame_id: str = ""
    extras: dict = field(default_factory=dict)  # e.g. the simulator's instance ids, not serialised

    def __post_init__(self):
        img = self.image
        if not isinstance(img, np.ndarray) or img.ndim != 3 or img.shape[2] != 3:
            raise MessageError(f"PosedFrame.image must be an [H, W, 3] array, got {getattr(img, 'shape', type(img))}")
        if img.dtype != np.uint8:
            raise MessageError(
                f"PosedFrame.image must be uint8 RGB, got {img.dtype}; convert with (img * 255).round().astype(np.uint8)"
            )
        h, w = img.shape[:2]
        if not isinstance(self.intrinsics, Intrinsics):
            raise MessageError(f"PosedFrame.intrinsics must be an Intrinsics, got {type(self.intrinsics).__name__}")
        if (self.intrinsics.width, self.intrinsics.height) != (w, h):
            raise MessageError(
                f"PosedFrame.intrinsics are for {self.intrinsics.width}x{self.intrinsics.height} but the image is {w}x{h}; "
                "rescale them with Intrinsics.scaled(width, height)"
            )
        try:
            self.cam2world = validate_cam2world(self.cam2world, "PosedFrame.cam2world")
        except PoseError as exc:
            raise MessageError(str(exc)) from None
        if not isinstance(self.stamp_s, (int, float)) or not math.isfinite(self.stamp_s):
            raise MessageError(f"PosedFrame.stamp_s must be a finite number of seconds, got {self.stamp_s!r}")
        self.stamp_s = float(self.stamp_s)
        if self.depth_m is not None:
            d = np.asarray(self.depth_m)
            if d.shape != (h, w):
                raise MessageError(f"PosedFrame.depth_m must be [{h}, {w}] like the image, got {d.shape}")
            if not np.issubdtype(d.dtype, np.floating):
                raise MessageError(f"PosedFrame.depth_m must be float metres, got {d.dtype}")
            d = d.astype(np.float32, copy=False)
            if not np.all(np.isfinite(d)) or (d < 0).any():
                raise MessageError("PosedFrame.depth_m must be finite and >= 0 (0 = no measurement)")
            self.depth_m = d

    @property
    def width(self) -> int:
        return self.image.shape[1]

    @property
    def height(self) -> int:
        return self.image.shape[0]
