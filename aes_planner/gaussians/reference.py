"""The plain dense reference rasterizer: every Gaussian against every pixel, autograd only.

For tests and the benchmark, never for production: it holds ``[pixels, N]`` matrices (chunked
over pixels to bound memory when no gradient is asked for). Same numerics and outputs as
:func:`aes_planner.gaussians.rasterize` (see :mod:`aes_planner.gaussians.numerics`), computed in
float64 and returned in the Gaussians' dtype.
"""

from __future__ import annotations

import torch
from torch import Tensor

from aes_planner.gaussians.container import Gaussians
from aes_planner.gaussians.numerics import ALPHA_MAX, ALPHA_MIN, DEPTH_ALPHA_MIN, FAR_M, NEAR_M, SIGMA_CLAMP, T_STOP
from aes_planner.gaussians.projection import project

__all__ = ["rasterize_dense"]


def rasterize_dense(
    gaussians: Gaussians,
    world2cam: Tensor,  # [B, 4, 4]
    K: Tensor,  # [B, 3, 3]
    width: int,
    height: int,
    background: Tensor | None = None,  # [3] or [B, 3]
    pixel_chunk: int = 4096,
    compute_dtype: torch.dtype = torch.float64,
) -> dict[str, Tensor]:
    """Dense rendering; returns ``rgb [B,3,H,W]``, ``features [B,C,H,W]``, ``depth [B,H,W]``
    (expected z-depth normalised by alpha, 0 where alpha is 0) and ``alpha [B,H,W]``.

    ``compute_dtype`` is the dtype of the per-pixel maths (float64 for tests; the benchmark
    uses float32 to compare against an equally plain float32 dense rasterizer)."""
    cdt = compute_dtype
    g = gaussians
    proj = project(g.means, g.quats, g.log_scales, g.opacities, world2cam, K, width, height)
    # The reference culls only by depth and keeps every Gaussian that could touch a pixel:
    # the fast backends' image-space culling must not change the result.
    in_depth = (proj.depths > NEAR_M) & (proj.depths < FAR_M)
    values = torch.cat([g.colors, g.features], dim=1).to(cdt)  # [N, 3 + C]
    opac = g.opacities.to(cdt)
    ys, xs = torch.meshgrid(torch.arange(height, dtype=cdt) + 0.5, torch.arange(width, dtype=cdt) + 0.5, indexing="ij")
    pix = torch.stack([xs.reshape(-1), ys.reshape(-1)], -1)  # [P, 2]
    outs = []
    for b in range(world2cam.shape[0]):
        keep = in_depth[b].nonzero().squeeze(1)
        order = keep[torch.sort(proj.depths[b, keep], stable=True).indices]  # front to back
        mean2d, conic = proj.means2d[b, order].to(cdt), proj.conics[b, order].to(cdt)  # [M, 2], [M, 3]
        z, o, vals = proj.depths[b, order].to(cdt), opac[order], values[order]
        chunks = []
        for start in range(0, pix.shape[0], pixel_chunk):
            d = pix[start : start + pixel_chunk, None, :] - mean2d[None]  # [P, M, 2]
            dx, dy = d[..., 0], d[..., 1]
            sigma = 0.5 * (conic[:, 0] * dx * dx + conic[:, 2] * dy * dy) + conic[:, 1] * dx * dy
            alpha = (o * torch.exp(-sigma.clamp(max=SIGMA_CLAMP))).clamp(max=ALPHA_MAX)
            alpha = torch.where((sigma >= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))
            one_minus = 1 - alpha
            t_incl = torch.cumprod(one_minus, dim=-1)  # compositing axis last (fast cumprod)
            included = (t_incl > T_STOP).to(cdt)  # the Gaussian that would end the pixel is left out
            one_minus = torch.where(included > 0, one_minus, torch.ones_like(one_minus))
            t_incl = torch.cumprod(one_minus, dim=-1)
            t_before = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], dim=-1)
            w = alpha * included * t_before  # [P, M]
            color = w @ vals  # [P, 3 + C]
            depth_acc = w @ z  # [P]
            t_final = t_incl[:, -1] if t_incl.shape[1] else torch.ones(w.shape[0], dtype=cdt)
            chunks.append(torch.cat([color, depth_acc[:, None], t_final[:, None]], dim=1))
        outs.append(torch.cat(chunks, dim=0))  # [P, 3 + C + 2]
    out = torch.stack(outs).reshape(world2cam.shape[0], height, width, -1).permute(0, 3, 1, 2)  # [B, 5+C, H, W]
    t_final = out[:, -1]
    alpha_map = 1 - t_final
    rgb = out[:, :3]
    if background is not None:
        bg = background.to(cdt).reshape(-1, 3)  # [1 or B, 3]
        rgb = rgb + bg[:, :, None, None] * t_final[:, None]
    depth = out[:, -2] / alpha_map.clamp_min(DEPTH_ALPHA_MIN)
    dtype = g.dtype
    return {
        "rgb": rgb.to(dtype),
        "features": out[:, 3:-2].to(dtype),
        "depth": depth.to(dtype),
        "alpha": alpha_map.to(dtype),
    }
