"""Seeded synthetic scenes for tests and benchmarks: Gaussians spread in front of the cameras."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from aes_planner.gaussians.container import Gaussians
from aes_planner.geometry.poses import rigid_inverse, view_to_cam2world

__all__ = ["random_scene"]

HFOV_RAD = math.radians(60.0)


def random_scene(
    n: int,
    channels: int = 0,
    width: int = 64,
    height: int = 64,
    n_cameras: int = 1,
    seed: int = 0,
    dtype: torch.dtype = torch.float32,
    sigma_px_at_64: tuple[float, float] = (0.4, 2.5),
    opacity: tuple[float, float] = (0.1, 0.9),
    depth_m: tuple[float, float] = (2.0, 6.0),
    origin_m: tuple[float, float, float] = (0.0, 0.0, 1.5),
) -> tuple[Gaussians, Tensor, Tensor]:
    """``n`` Gaussians in the view of a camera at ``origin_m`` looking along world +x.

    Centres are uniform over the image (10 % beyond each border) and over ``depth_m``; each
    Gaussian's standard deviations are log-uniform so that it spans ``sigma_px_at_64`` pixels
    at 64 px image width (twice that at 128 px), up to 2x anisotropic, randomly rotated. With
    ``n_cameras > 1`` the cameras are jittered around the first (0.3 m, 0.15 rad yaw, 0.1 rad
    pitch). Returns ``(gaussians, world2cam [B, 4, 4] float64, K [B, 3, 3] float64)``.
    """
    g = torch.Generator().manual_seed(seed)
    f64 = torch.float64
    fx = 0.5 * width / math.tan(HFOV_RAD / 2)
    fy = fx
    K = torch.tensor([[fx, 0.0, width / 2], [0.0, fy, height / 2], [0.0, 0.0, 1.0]], dtype=f64)
    base = torch.tensor([*origin_m, 0.0, 0.0], dtype=f64)
    views = base.repeat(n_cameras, 1)
    if n_cameras > 1:
        jitter = (torch.rand(n_cameras - 1, 5, generator=g, dtype=f64) * 2 - 1) * torch.tensor(
            [0.3, 0.3, 0.3, 0.15, 0.1], dtype=f64
        )
        views[1:] += jitter
    cam2world = view_to_cam2world(views)  # [B, 4, 4]
    # Unproject uniform pixels at uniform depths through the first camera.
    u = (torch.rand(n, generator=g, dtype=f64) * 1.2 - 0.1) * width
    v = (torch.rand(n, generator=g, dtype=f64) * 1.2 - 0.1) * height
    z = depth_m[0] + torch.rand(n, generator=g, dtype=f64) * (depth_m[1] - depth_m[0])
    p_cam = torch.stack([(u - width / 2) / fx * z, (v - height / 2) / fy * z, z, torch.ones_like(z)], -1)
    means = (cam2world[0] @ p_cam.T).T[:, :3].contiguous()  # [N, 3] rows, as a caller's would be
    lo, hi = (math.log(s / 64.0 * 2 * math.tan(HFOV_RAD / 2)) for s in sigma_px_at_64)  # radians per px
    log_sigma = lo + torch.rand(n, 1, generator=g, dtype=f64) * (hi - lo)
    aniso = (torch.rand(n, 3, generator=g, dtype=f64) * 2 - 1) * math.log(2.0) / 2
    log_scales = log_sigma + aniso + torch.log(z)[:, None]
    gaussians = Gaussians(
        means=means.to(dtype),
        quats=torch.randn(n, 4, generator=g, dtype=f64).to(dtype),
        log_scales=log_scales.to(dtype),
        opacities=(opacity[0] + torch.rand(n, generator=g, dtype=f64) * (opacity[1] - opacity[0])).to(dtype),
        colors=torch.rand(n, 3, generator=g, dtype=f64).to(dtype),
        features=torch.randn(n, channels, generator=g, dtype=f64).to(dtype),
    )
    return gaussians, rigid_inverse(cam2world), K.repeat(n_cameras, 1, 1)
