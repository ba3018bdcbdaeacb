"""Pinhole intrinsics (pixels, pixel centres at +0.5) and ray generation."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from aes_planner.errors import AesPlannerError

if TYPE_CHECKING:  # torch is imported where a tensor is asked for: messages and the bus tools need no torch
    import torch
    from torch import Tensor

__all__ = ["MAX_CAMERA_PIXELS", "MAX_CAMERA_SIDE_PX", "Intrinsics", "IntrinsicsError"]

#: Largest camera, and largest image file read (:func:`aes_planner.images.imread_bounded`): 2^26
#: pixels, e.g. 8192 x 8192 or a 64 MP photo. A frame on the bus is smaller still
#: (:data:`aes_planner.messages.posed_frame.MAX_FRAME_PIXELS`: it is downscaled at the boundary).
#: Checked before anything of that size is allocated (a 100000 x 100000 camera would ask for 300 GB).
MAX_CAMERA_PIXELS = 1 << 26
#: Longest side of a camera or an image file, in pixels.
MAX_CAMERA_SIDE_PX = 1 << 15


class IntrinsicsError(AesPlannerError, ValueError):
    """Intrinsics that no pinhole camera has (non-positive focal length, empty image...);
    ``problem``: what is wrong, starting with the field (``fx: ...``), when a bound refused it."""

    def __init__(self, message: str, problem: str | None = None):
        super().__init__(message)
        self.problem = problem


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera intrinsics in pixels; no distortion.

    ``fx, fy``: focal lengths in pixels. ``cx, cy``: principal point in pixels, measured from
    the image's top-left corner, so pixel ``(i, j)`` has its centre at ``(i + 0.5, j + 0.5)`` and
    a centred principal point is ``(width / 2, height / 2)``.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self):
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise IntrinsicsError(f"intrinsics.{name} must be a finite number, got {v!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise IntrinsicsError(f"intrinsics focal lengths must be positive pixels, got fx={self.fx}, fy={self.fy}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise IntrinsicsError(f"intrinsics.{name} must be a positive integer, got {v!r}")
        if max(self.width, self.height) > MAX_CAMERA_SIDE_PX or self.width * self.height > MAX_CAMERA_PIXELS:
            raise IntrinsicsError(
                f"a {self.width}x{self.height} camera is too large: at most {MAX_CAMERA_SIDE_PX} pixels per side "
                f"and {MAX_CAMERA_PIXELS} in all"
            )
        # the bounds of any camera (field of view 0.01-179.5 deg over the longer side, principal point
        # within ten image sizes), here where every camera enters: a focal length of 1e30 px is a
        # broken file, and the compiled and the torch rasterizer (float32) part ways out there
        problem = camera_problem(self)
        if problem is not None:
            raise IntrinsicsError(f"intrinsics.{problem}", problem)

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> Intrinsics:
        """Square pixels, centred principal point, horizontal field of view ``hfov_deg``."""
        if not (0.0 < hfov_deg < 180.0):
            raise IntrinsicsError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
        half_tan = math.tan(math.radians(hfov_deg) / 2)  # 0 for denormal angles: radians() underflows
        f = 0.5 * width / half_tan if half_tan > 0.0 else math.inf
        if not math.isfinite(f):
            raise IntrinsicsError(
                f"hfov_deg = {hfov_deg:g} is too narrow for a finite focal length at {width} px; use a wider field of view"
            )
        try:
            return cls(f, f, width / 2.0, height / 2.0, int(width), int(height))
        except IntrinsicsError as exc:
            if exc.problem is None:
                raise
            raise IntrinsicsError(
                f"hfov_deg = {hfov_deg:g} at {width}x{height} px: {exc.problem}", exc.problem
            ) from None

    @classmethod
    def from_matrix(cls, K: np.ndarray, width: int, height: int) -> Intrinsics:
        """From a 3x3 matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` (skew must be 0)."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise IntrinsicsError(f"intrinsics matrix must be 3x3, got shape {K.shape}")
        if abs(K[0, 1]) > 1e-9 or not np.allclose(K[2], [0, 0, 1]) or abs(K[1, 0]) > 1e-9:
            raise IntrinsicsError(f"intrinsics matrix must be [[fx,0,cx],[0,fy,cy],[0,0,1]], got {K.tolist()}")
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height))

    @classmethod
    def from_normalized(cls, fx_n: float, fy_n: float, cx_n: float, cy_n: float, width: int, height: int) -> Intrinsics:
        """From intrinsics normalised by the image size (fx/W, fy/H, cx/W, cy/H)."""
        return cls(fx_n * width, fy_n * height, cx_n * width, cy_n * height, int(width), int(height))

    def to_normalized(self) -> tuple[float, float, float, float]:
        """(fx/W, fy/H, cx/W, cy/H), the DepthSplat/RealEstate10K form."""
        return (self.fx / self.width, self.fy / self.height, self.cx / self.width, self.cy / self.height)

    @property
    def K(self) -> np.ndarray:
        """The 3x3 intrinsics matrix, float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def K_tensor(self, dtype: torch.dtype | None = None, device: str | torch.device = "cpu") -> Tensor:
        """The 3x3 intrinsics matrix as a tensor ``[3, 3]`` (float32 unless ``dtype`` says)."""
        import torch

        return torch.tensor(self.K, dtype=dtype or torch.float32, device=device)

    @property
    def hfov_rad(self) -> float:
        return 2.0 * math.atan(0.5 * self.width / self.fx)

    @property
    def vfov_rad(self) -> float:
        return 2.0 * math.atan(0.5 * self.height / self.fy)

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera resampled to ``width x height`` pixels (same field of view)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, int(width), int(height))

    def pixel_directions(self, supersample: int = 1) -> np.ndarray:
        """Camera-frame ray directions ``[H*s, W*s, 3]`` with z = 1 (not unit length), float64.

        With ``supersample = s`` each pixel is split into ``s x s`` sub-pixels on a regular grid;
        for ``s = 1`` the ray goes through the pixel centre ``(i + 0.5, j + 0.5)``.
        """
        s = int(supersample)
        if s < 1:
            raise IntrinsicsError(f"supersample must be >= 1, got {supersample}")
        u = (np.arange(self.width * s, dtype=np.float64) + 0.5) / s
        v = (np.arange(self.height * s, dtype=np.float64) + 0.5) / s
        uu, vv = np.meshgrid(u, v)  # [H*s, W*s]
        return np.stack([(uu - self.cx) / self.fx, (vv - self.cy) / self.fy, np.ones_like(uu)], axis=-1)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Camera-frame points ``[..., 3]`` -> pixel coordinates ``[..., 2]`` (u, v); z must be > 0."""
        p = np.asarray(points_cam, dtype=np.float64)
        z = p[..., 2]
        return np.stack([self.fx * p[..., 0] / z + self.cx, self.fy * p[..., 1] / z + self.cy], axis=-1)

    def unproject(self, uv_px: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
        """Pixel coordinates ``[..., 2]`` and z-depth ``[...]`` -> camera-frame points ``[..., 3]``."""
        uv = np.asarray(uv_px, dtype=np.float64)
        d = np.asarray(depth_m, dtype=np.float64)
        x = (uv[..., 0] - self.cx) / self.fx * d
        y = (uv[..., 1] - self.cy) / self.fy * d
        return np.stack([x, y, d], axis=-1)


#: Fields of view any camera the package is given may have (over the image's longer side), and
#: how far its principal point may lie from the image (in image sizes): the range over which the
#: rasterizers (compiled, torch) are tested to agree. Checked by every Intrinsics when built; a
#: focal length of 1e30 px (where the two part ways in float32) is refused there.
CAMERA_FOV_RANGE_DEG = (0.01, 179.5)
MAX_PRINCIPAL_OFFSET = 10.0


def camera_problem(k: Intrinsics) -> str | None:
    """What no camera at all has about ``k`` (looser than :func:`intrinsics_problem`, which is
    what a real frame has): None when its focal lengths give 0.01-179.5 deg over the image's longer
    side and its principal point is within 10 image sizes of the image."""
    lo, hi = CAMERA_FOV_RANGE_DEG
    side = max(k.width, k.height)
    for name, f in (("fx", k.fx), ("fy", k.fy)):
        fov = math.degrees(2 * math.atan(side / (2 * f)))
        if not lo <= fov <= hi:
            return (
                f"{name}: a focal length of {f:g} px gives a {fov:.3g} deg field of view over {side} px; "
                f"expected {lo} to {hi} deg (are the intrinsics in pixels?)"
            )
    for name, c, size in (("cx", k.cx, k.width), ("cy", k.cy, k.height)):
        if not -MAX_PRINCIPAL_OFFSET * size <= c <= (1 + MAX_PRINCIPAL_OFFSET) * size:
            return f"{name}: principal point {c:g} px is far outside the {size} px image; expected about {size / 2:g}"
    return None
