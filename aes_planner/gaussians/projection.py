"""EWA projection of 3D Gaussians to image-space 2D Gaussians, in plain differentiable torch.

Used by the pure-torch backend and the dense reference; the numba backend has a compiled copy of
the same maths with a hand-written backward (tested against this one through the reference).
Computed in float64 whatever the input dtype: far-away cameras (1e5 m) and extreme focal lengths
or scales overflow or cancel in float32.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from aes_planner.gaussians.numerics import (
    ALPHA_MIN,
    BLUR_PX2,
    DET_MIN,
    FAR_M,
    FRUSTUM_SLACK,
    NEAR_M,
)
from aes_planner.geometry.poses import quat_to_matrix

__all__ = ["Projected", "covariance_3d", "project"]


class Projected(NamedTuple):
    """Per camera and Gaussian, float64. Entries of culled Gaussians are finite but meaningless."""

    means2d: Tensor  # [B, N, 2] pixel coordinates (u, v) of the centre
    conics: Tensor  # [B, N, 3] (A, B, C) of the inverse 2D covariance [[A, B], [B, C]]
    depths: Tensor  # [B, N] camera z, metres
    extents: Tensor  # [B, N, 2] half-width and half-height (px) of the alpha >= 1/255 ellipse
    visible: Tensor  # [B, N] bool: inside near/far, opacity >= 1/255 and overlapping the image


def covariance_3d(quats: Tensor, log_scales: Tensor) -> Tensor:  # quats [N, 4], log_scales [N, 3]
    """World-frame covariances ``[N, 3, 3] = R diag(s^2) R^T``."""
    rotation = quat_to_matrix(quats)  # [N, 3, 3]
    m = rotation * log_scales.exp().unsqueeze(-2)  # columns scaled by s
    return m @ m.transpose(-1, -2)


def project(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    log_scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    world2cam: Tensor,  # [B, 4, 4]
    K: Tensor,  # [B, 3, 3]
    width: int,
    height: int,
) -> Projected:
    f64 = torch.float64
    means, world2cam, K = means.to(f64), world2cam.to(f64), K.to(f64)
    rot = world2cam[:, None, :3, :3]  # [B, 1, 3, 3]
    p = (rot @ means[None, :, :, None]).squeeze(-1) + world2cam[:, None, :3, 3]  # [B, N, 3]
    x, y, z = p.unbind(-1)
    in_depth = (z > NEAR_M) & (z < FAR_M)
    zs = torch.where(in_depth, z, torch.ones_like(z))  # no inf/NaN (nor their gradients) when culled
    fx, fy = K[:, 0, 0, None], K[:, 1, 1, None]  # [B, 1]
    cx, cy = K[:, 0, 2, None], K[:, 1, 2, None]
    u = fx * x / zs + cx
    v = fy * y / zs + cy
    # gsplat's frustum clamp of the Jacobian's x/z, y/z.
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    tx = zs * torch.minimum(
        (width - cx) / fx + FRUSTUM_SLACK * tan_x, torch.maximum(-(cx / fx + FRUSTUM_SLACK * tan_x), x / zs)
    )
    ty = zs * torch.minimum(
        (height - cy) / fy + FRUSTUM_SLACK * tan_y, torch.maximum(-(cy / fy + FRUSTUM_SLACK * tan_y), y / zs)
    )
    zero = torch.zeros_like(zs)
    jac = torch.stack(
        [torch.stack([fx / zs, zero, -fx * tx / zs**2], -1), torch.stack([zero, fy / zs, -fy * ty / zs**2], -1)], -2
    )  # [B, N, 2, 3]
    cov_world = covariance_3d(quats.to(f64), log_scales.to(f64))  # [N, 3, 3]
    cov_cam = rot @ cov_world[None] @ rot.transpose(-1, -2)  # [B, N, 3, 3]
    cov2d = jac @ cov_cam @ jac.transpose(-1, -2)  # [B, N, 2, 2]
    a = cov2d[..., 0, 0] + BLUR_PX2
    b = cov2d[..., 0, 1]
    c = cov2d[..., 1, 1] + BLUR_PX2
    det = (a * c - b * b).clamp_min(DET_MIN)
    conics = torch.stack([c / det, -b / det, a / det], -1)
    # alpha = o exp(-sigma) >= 1/255  <=>  sigma <= log(255 o): an ellipse with these half-extents.
    opac = opacities.detach().to(f64)
    level = torch.log((opac / ALPHA_MIN).clamp_min(1.0))  # [N]
    extents = torch.stack([(2 * level * a.detach()).sqrt(), (2 * level * c.detach()).sqrt()], -1)
    ud, vd = u.detach(), v.detach()
    on_image = (
        (ud + extents[..., 0] > 0)
        & (ud - extents[..., 0] < width)
        & (vd + extents[..., 1] > 0)
        & (vd - extents[..., 1] < height)
    )
    visible = in_depth & (opac >= ALPHA_MIN) & on_image
    return Projected(torch.stack([u, v], -1), conics, z, extents, visible)
