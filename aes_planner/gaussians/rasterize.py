"""``rasterize``: the public entry point of the Gaussian rasterizer, and backend selection.

Backends
--------
* ``"numba"``: compiled CPU kernels (projection, binning, raster and their backward), parallel over
  tiles or cameras. Needs numba (the ``fast`` extra) and CPU tensors. The first call in a fresh
  environment compiles each dtype once and caches it to disk, so later processes only load it
  (figures: docs/benchmarks.md, "Figures behind code comments").
* ``"torch"``: pure-torch, tile-binned, autograd; any device; far slower than ``numba`` on a CPU
  (same table): the fallback where numba is missing or the tensors are on another device.
* ``"auto"`` (default): ``numba`` when it imports and the tensors are on the CPU, else ``torch``.

The environment variable ``AES_PLANNER_RASTER_BACKEND`` (``auto``/``numba``/``torch``) overrides
``"auto"``; an explicit ``backend=`` argument wins over it.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from aes_planner.gaussians.container import GaussianError, Gaussians
from aes_planner.gaussians.numerics import DEPTH_ALPHA_MIN

__all__ = [
    "BACKENDS",
    "BACKEND_ENV",
    "RasterOutput",
    "rasterize",
    "resolve_backend",
]

log = logging.getLogger(__name__)

BACKENDS = ("auto", "numba", "torch")
BACKEND_ENV = "AES_PLANNER_RASTER_BACKEND"
# max |R R^T - I| accepted in world2cam: float32 poses and poses read from files with 6-7
# significant digits are off by ~1e-6; a scale or shear of 1e-4 is a wrong pose, not rounding.
RIGID_TOL = 1e-4
# Pixels (cameras x height x width) per call: the outputs alone take 4 * (5 + C) bytes per pixel.
MAX_PIXELS = 1 << 28


@dataclass
class RasterOutput:
    """Rendered maps, batch first, channel-first.

    * ``rgb``: ``[B, 3, H, W]`` colour composited over ``background`` (``bg * (1 - alpha)``).
    * ``features``: ``[B, C, H, W]`` feature maps over a zero background.
    * ``depth``: ``[B, H, W]`` expected camera z-depth in metres **normalised by alpha**
      (``sum w_i z_i / alpha``), 0 where nothing was drawn. Multiply by ``alpha`` for the
      un-normalised sum.
    * ``alpha``: ``[B, H, W]`` accumulated opacity ``1 - T_final``.
    * ``backend``: the backend that ran.
    """

    rgb: Tensor  # [B, 3, H, W]
    features: Tensor  # [B, C, H, W]
    depth: Tensor  # [B, H, W]
    alpha: Tensor  # [B, H, W]
    backend: str


def resolve_backend(backend: str = "auto", device: torch.device | str = "cpu") -> str:
    """The backend ``rasterize(..., backend=backend)`` would run for tensors on ``device``."""
    if backend not in BACKENDS:
        raise GaussianError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        backend = os.environ.get(BACKEND_ENV, "auto").strip().lower() or "auto"
        if backend not in BACKENDS:
            raise GaussianError(f"{BACKEND_ENV}={backend!r}: expected one of {BACKENDS}")
    on_cpu = torch.device(device).type == "cpu"
    if backend == "auto":
        from aes_planner.gaussians import numba_backend

        return "numba" if on_cpu and numba_backend.available() else "torch"
    if backend == "numba":
        from aes_planner.gaussians import numba_backend

        if not on_cpu:
            raise GaussianError(f"the numba backend runs on the CPU; tensors are on {device}. Use backend='torch'")
        if not numba_backend.available():
            raise GaussianError(
                "numba is not importable; install the 'fast' extra (pip install 'aes-planner[fast]') "
                "or use backend='torch'"
            )
    return backend


# The checks below run in numpy on float64 copies of the few pose numbers: torch's small ops cost
# ~5-10 us each, which made the checks ~0.14 ms of every call (docs/journal/rasterizer.md, "Alias
# checks, the 8-lane backward").
def _f64(t: Tensor) -> np.ndarray:
    return t.detach().to(torch.float64).cpu().numpy()


def _batched(t: Tensor | Sequence, name: str, shape: tuple[int, int], device) -> tuple[Tensor, np.ndarray]:
    """(t as [B, *shape] on ``device``, its float64 numpy copy)."""
    if isinstance(t, np.ndarray) and not t.flags.c_contiguous:  # torch refuses negative strides (poses[::-1])
        t = np.ascontiguousarray(t)
    t = torch.as_tensor(t, device=device)
    if t.dim() == 2:
        t = t.unsqueeze(0)
    if t.dim() != 3 or tuple(t.shape[1:]) != shape:
        raise GaussianError(
            f"{name} must have shape [B, {shape[0]}, {shape[1]}] (or [{shape[0]}, {shape[1]}]), got {tuple(t.shape)}"
        )
    if not t.dtype.is_floating_point:
        raise GaussianError(f"{name} must be floating point (float64 recommended), got {t.dtype}")
    a = _f64(t)
    if not np.isfinite(a).all():
        raise GaussianError(f"{name} has NaN or Inf entries; check the pose source")
    return t, a


def _check_inputs(gaussians, world2cam, K, width, height, background):
    if not isinstance(gaussians, Gaussians):
        raise GaussianError(f"rasterize takes a Gaussians, got {type(gaussians).__name__}")
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise GaussianError(f"{name} must be a positive int (pixels), got {v!r}")
    device = gaussians.device
    world2cam, w2c = _batched(world2cam, "world2cam", (4, 4), device)
    if world2cam.shape[0] == 0:
        raise GaussianError("world2cam holds 0 cameras: pass one pose [4, 4] or a batch [B, 4, 4] with B >= 1")
    K, kd = _batched(K, "K", (3, 3), device)
    if K.shape[0] == 1 and world2cam.shape[0] > 1:
        K = K.expand(world2cam.shape[0], 3, 3)
    if K.shape[0] != world2cam.shape[0]:
        raise GaussianError(
            f"K has {K.shape[0]} cameras but world2cam {world2cam.shape[0]}; pass one K or one per camera"
        )
    if (kd[:, 0, 0] <= 0).any() or (kd[:, 1, 1] <= 0).any():
        raise GaussianError("K: focal lengths fx = K[..., 0, 0] and fy = K[..., 1, 1] must be positive pixels")
    off = np.stack([kd[:, 0, 1], kd[:, 1, 0], kd[:, 2, 0], kd[:, 2, 1], kd[:, 2, 2] - 1])
    if (off != 0).any():
        raise GaussianError("K must read [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew); use Intrinsics.K_tensor()")
    _check_rigid(w2c)
    if height * width * world2cam.shape[0] > MAX_PIXELS:
        raise GaussianError(
            f"{world2cam.shape[0]} cameras of {width}x{height} px are more than {MAX_PIXELS:.0e} pixels in one call; "
            "render fewer cameras per call or a smaller image"
        )
    if background is not None:
        background = torch.as_tensor(background, dtype=gaussians.dtype, device=device)
        if background.shape not in ((3,), (1, 3), (world2cam.shape[0], 3)):
            raise GaussianError(f"background must have shape [3] or [B, 3], got {tuple(background.shape)}")
        if not np.isfinite(_f64(background)).all():
            raise GaussianError("background has NaN or Inf entries; pass finite colours (e.g. [0, 0, 0])")
        background = background.reshape(-1, 3)
    return world2cam, K, background


def _check_rigid(world2cam: np.ndarray) -> None:  # [B, 4, 4] float64
    """Bottom row [0, 0, 0, 1] and a proper rotation (R R^T = I, det R = +1) within RIGID_TOL."""
    if (world2cam[:, 3] != np.array([0.0, 0.0, 0.0, 1.0])).any():
        raise GaussianError("world2cam must be rigid 4x4 matrices with bottom row [0, 0, 0, 1]")
    rot = world2cam[:, :3, :3]  # [B, 3, 3]
    err = np.abs(rot @ rot.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))  # [B]
    det = np.linalg.det(rot)  # [B]
    bad = (err > RIGID_TOL) | (det <= 0)
    if bad.any():
        b = int(np.flatnonzero(bad)[0])
        what = (
            "is a reflection (det < 0)" if float(det[b]) <= 0 and float(err[b]) <= RIGID_TOL else "is not orthonormal"
        )
        raise GaussianError(
            f"world2cam[{b}] must be rigid: its rotation block {what} (max |R R^T - I| = {float(err[b]):.2e}, "
            f"det = {float(det[b]):.3g}); build poses with aes_planner.geometry (e.g. rigid_inverse(cam2world))"
        )


def rasterize(
    gaussians: Gaussians,
    world2cam: Tensor,  # [B, 4, 4] (or [4, 4]); float64 recommended for large coordinates
    K: Tensor,  # [B, 3, 3] (or [3, 3], shared): [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    width: int,
    height: int,
    background: Tensor | Sequence[float] | None = None,  # [3] or [B, 3]; None = black
    backend: str = "auto",
    validate: bool = True,
) -> RasterOutput:
    """Render ``gaussians`` from B cameras; differentiable w.r.t. ``world2cam``, ``background`` and
    every float field of ``gaussians`` (not ``K``).

    Numerics: :mod:`aes_planner.gaussians.numerics`. Pixel ``(i, j)`` has its centre at
    ``(i + 0.5, j + 0.5)``; cameras use the OpenCV axes of :mod:`aes_planner.geometry`.
    ``validate=False`` skips the O(N) finiteness/opacity checks of the Gaussians (inputs' shapes
    are always checked).
    """
    world2cam, K, background = _check_inputs(gaussians, world2cam, K, width, height, background)
    if validate:
        gaussians.validate()
    name = resolve_backend(backend, gaussians.device)
    g = gaussians
    if name == "numba":
        from aes_planner.gaussians import numba_backend

        rgb, features, depth, alpha = numba_backend.render(
            g.means, g.quats, g.log_scales, g.opacities, g.colors, g.features, background, world2cam, K, width, height
        )
        return RasterOutput(rgb=rgb, features=features, depth=depth, alpha=alpha, backend=name)
    from aes_planner.gaussians import torch_backend

    values = torch.cat([g.colors, g.features], dim=1)  # [N, 3 + C]; also when C = 0 (grads stay defined)
    out, t_final = torch_backend.render(
        g.means, g.quats, g.log_scales, g.opacities, values, world2cam, K, width, height
    )
    c = g.num_channels
    alpha = 1 - t_final
    rgb = out[:, :3]
    if background is not None:
        rgb = rgb + background[:, :, None, None] * t_final[:, None]
    depth = out[:, 3 + c] / alpha.clamp_min(DEPTH_ALPHA_MIN)
    return RasterOutput(rgb=rgb, features=out[:, 3 : 3 + c], depth=depth, alpha=alpha, backend=name)
