"""Plain torch twins of the numba backend's stages, one per kernel, for the per-stage tests.

Each twin takes the inputs of its kernel in :mod:`aes_planner.gaussians.kernels` (as tensors,
same order, same layouts) and returns what the kernel writes into its output arrays, computed the
obvious way: dense per tile, loops over cameras and tiles, autograd for the backward passes.
``tests/gaussians/test_stages.py`` compares every kernel with its twin (values and gradients), so
a wrong change in one stage fails that stage's test. Slow; never used for rendering.

| kernel | twin |
|---|---|
| ``project_fwd`` | :func:`project_fwd` |
| ``project_bwd`` | :func:`project_bwd` (autograd through :func:`project_fwd`) |
| ``bin_cameras`` + ``fill_lists`` | :func:`bin_and_fill` |
| ``raster_fwd`` | :func:`raster_fwd` |
| ``raster_bwd`` | :func:`raster_bwd` (autograd through :func:`raster_fwd`) |

Packed layouts (shared with the kernels): ``proj [B, N, 7]`` = (u, v, conic A, B, C, opacity,
z); ``box [B, N, 4]`` = (x0, x1, y0, y1) inclusive pixel bounds, ``x0 > x1`` when culled; ``cams
[B, 20]`` = rotation (9, row-major), translation (3), fx, fy, cx, cy and the limits of x/z
(+, -) and y/z (+, -); gradients ``g2d [B, N, 7]`` in the order of ``proj``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from aes_planner.gaussians.numerics import (
    ALPHA_MAX,
    ALPHA_MIN,
    BLUR_PX2,
    BOX_MARGIN_PX,
    DET_MIN,
    FAR_M,
    LOG_INV_ALPHA_MIN,
    NEAR_M,
    SIGMA_CLAMP,
    T_STOP,
    TILE,
)
from aes_planner.gaussians.projection import covariance_3d

__all__ = ["bin_and_fill", "project_bwd", "project_fwd", "raster_bwd", "raster_fwd"]

_COV_ROWS, _COV_COLS = [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]  # (xx, xy, xz, yy, yz, zz)


def project_fwd(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    log_scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    cams: Tensor,  # [B, 20] float64
    width: int,
    height: int,
) -> tuple[Tensor, Tensor, Tensor]:
    """(cov [N, 6], proj [B, N, 7], box [B, N, 4] int32), all float64 but box; differentiable."""
    f64 = torch.float64
    means, opac = means.to(f64), opacities.to(f64)
    n_cam = cams.shape[0]
    cov3 = covariance_3d(quats.to(f64), log_scales.to(f64))  # [N, 3, 3]
    rot = cams[:, :9].reshape(n_cam, 3, 3)  # [B, 3, 3]
    fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn = (c[:, None] for c in cams[:, 12:20].unbind(1))  # [B, 1]
    p = torch.einsum("bij,nj->bni", rot, means) + cams[:, None, 9:12]  # [B, N, 3]
    x, y, z = p.unbind(-1)
    in_depth = (z > NEAR_M) & (z < FAR_M)
    zs = torch.where(in_depth, z, torch.ones_like(z))
    u = fx * x / zs + cx
    v = fy * y / zs + cy
    rx = torch.minimum(torch.maximum(x / zs, -lim_xn), lim_xp)
    ry = torch.minimum(torch.maximum(y / zs, -lim_yn), lim_yp)
    zero = torch.zeros_like(zs)
    jac = torch.stack(
        [torch.stack([fx / zs, zero, -fx * rx / zs], -1), torch.stack([zero, fy / zs, -fy * ry / zs], -1)], -2
    )  # [B, N, 2, 3]
    cov_cam = rot[:, None] @ cov3[None] @ rot[:, None].transpose(-1, -2)  # [B, N, 3, 3]
    cov2d = jac @ cov_cam @ jac.transpose(-1, -2)  # [B, N, 2, 2]
    a = cov2d[..., 0, 0] + BLUR_PX2
    b = cov2d[..., 0, 1]
    c = cov2d[..., 1, 1] + BLUR_PX2
    det = (a * c - b * b).clamp_min(DET_MIN)
    o = opac.expand_as(z)
    proj = torch.stack([u, v, c / det, -b / det, a / det, o, z], -1)  # [B, N, 7]
    # The pixel box of the alpha >= 1/255 ellipse, as the kernel computes it.
    with torch.no_grad():
        level = torch.log(opac.clamp_min(1e-30)) + LOG_INV_ALPHA_MIN  # [N]
        ext_x = (2 * level * a).clamp_min(0).sqrt()
        ext_y = (2 * level * c).clamp_min(0).sqrt()
        fx0 = (u - ext_x - 0.5 - BOX_MARGIN_PX).clamp(-1.0, width + 1.0)
        fx1 = (u + ext_x - 0.5 + BOX_MARGIN_PX).clamp(-1.0, width + 1.0)
        fy0 = (v - ext_y - 0.5 - BOX_MARGIN_PX).clamp(-1.0, height + 1.0)
        fy1 = (v + ext_y - 0.5 + BOX_MARGIN_PX).clamp(-1.0, height + 1.0)
        ix0 = fx0.ceil().clamp_min(0).long()
        ix1 = fx1.floor().clamp_max(width - 1).long()
        iy0 = fy0.ceil().clamp_min(0).long()
        iy1 = fy1.floor().clamp_max(height - 1).long()
        finite = torch.isfinite(a) & torch.isfinite(b) & torch.isfinite(c)
        keep = (opac >= ALPHA_MIN) & in_depth & finite & (ix0 <= ix1) & (iy0 <= iy1)
        box = torch.stack([ix0, ix1, iy0, iy1], -1)
        box[..., 0] = torch.where(keep, box[..., 0], 1)
        box[..., 1] = torch.where(keep, box[..., 1], 0)
    cov = cov3[:, _COV_ROWS, _COV_COLS]  # [N, 6]
    return cov, proj, box.to(torch.int32)


def project_bwd(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    log_scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    cams: Tensor,  # [B, 20] float64
    width: int,
    height: int,
    g2d: Tensor,  # [B, N, 7] d loss / d proj (zero where culled)
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """(g_means [N, 3], g_quats [N, 4], g_log_scales [N, 3], g_opacities [N], g_cam [B, 12]):
    the vector-Jacobian product of :func:`project_fwd`'s ``proj``; ``g_cam`` holds rows 0..2 of
    world2cam row-major (rotation and translation interleaved as in a 3x4 matrix)."""
    inputs = [t.detach().to(torch.float64).requires_grad_() for t in (means, quats, log_scales, opacities, cams)]
    _, proj, box = project_fwd(*inputs, width, height)
    culled = (box[..., 0] > box[..., 1])[..., None]
    proj = torch.where(culled, torch.zeros_like(proj), proj)  # the kernel skips culled Gaussians
    grads = torch.autograd.grad(proj, inputs, g2d.to(torch.float64), allow_unused=True)
    g_means, g_quats, g_log_scales, g_opac, g_cams = (
        torch.zeros_like(t) if g is None else g for g, t in zip(grads, inputs, strict=True)
    )
    n_cam = cams.shape[0]
    g_cam = torch.cat([g_cams[:, :9].reshape(n_cam, 3, 3), g_cams[:, 9:12, None]], 2).reshape(n_cam, 12)
    return g_means, g_quats, g_log_scales, g_opac, g_cam


def bin_and_fill(
    proj: Tensor,  # [B, N, 7]
    box: Tensor,  # [B, N, 4] int32
    tiles_x: int,
    tiles_y: int,
) -> tuple[Tensor, Tensor]:
    """(offsets [B * tiles + 1] int64, lists int32): per camera and tile, the Gaussians whose box
    touches the tile, front to back (float32 depth, ties by index); tiles of camera b are the
    slices ``offsets[b * tiles + t] : offsets[b * tiles + t + 1]`` of ``lists``."""
    per_tile: list[list[int]] = []
    for b in range(proj.shape[0]):
        visible = (box[b, :, 0] <= box[b, :, 1]).nonzero().squeeze(1)
        depth32 = proj[b, visible, 6].to(torch.float32)
        order = visible[torch.sort(depth32, stable=True).indices].tolist()
        tiles: list[list[int]] = [[] for _ in range(tiles_x * tiles_y)]
        for g in order:
            x0, x1, y0, y1 = (int(v) for v in box[b, g])
            for ty in range(y0 // TILE, y1 // TILE + 1):
                for tx in range(x0 // TILE, x1 // TILE + 1):
                    tiles[ty * tiles_x + tx].append(g)
        per_tile.extend(tiles)
    counts = torch.tensor([len(t) for t in per_tile], dtype=torch.int64)
    offsets = torch.cat([torch.zeros(1, dtype=torch.int64), torch.cumsum(counts, 0)])
    lists = torch.tensor([g for t in per_tile for g in t], dtype=torch.int32)
    return offsets, lists


def raster_fwd(
    proj: Tensor,  # [B, N, 7] in the pixel dtype
    box: Tensor,  # [B, N, 4] int32
    vals: Tensor,  # [N, Cv] colours then features
    offsets: Tensor,  # [B * tiles + 1]
    lists: Tensor,  # [pairs]
    tiles_x: int,
    width: int,
    height: int,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """(rgb [B, 3, H, W], feat [B, C, H, W], dep [B, H, W] (un-normalised), t_final [B, H, W],
    last [B, H, W] int32 = list position after each pixel's last contributor, 0 if none).
    Differentiable w.r.t. ``proj`` and ``vals``; a Gaussian is tested only at pixels of its box."""
    n_cam, cv = proj.shape[0], vals.shape[1]
    dtype = vals.dtype
    n_tiles = (offsets.shape[0] - 1) // n_cam
    out = torch.zeros(n_cam, cv + 1, height, width, dtype=dtype)
    t_final = torch.ones(n_cam, height, width, dtype=dtype)
    last = torch.zeros(n_cam, height, width, dtype=torch.int32)
    for b in range(n_cam):
        for tile in range(n_tiles):
            start, end = int(offsets[b * n_tiles + tile]), int(offsets[b * n_tiles + tile + 1])
            if start == end:
                continue
            tx0, ty0 = (tile % tiles_x) * TILE, (tile // tiles_x) * TILE
            x1, y1 = min(tx0 + TILE, width), min(ty0 + TILE, height)
            py, px = torch.meshgrid(torch.arange(ty0, y1), torch.arange(tx0, x1), indexing="ij")
            px, py = px.reshape(-1, 1), py.reshape(-1, 1)  # [P, 1]
            g = lists[start:end].long()  # [M]
            bx = box[b, g].long()  # [M, 4]
            inside = (px >= bx[:, 0]) & (px <= bx[:, 1]) & (py >= bx[:, 2]) & (py <= bx[:, 3])  # [P, M]
            p = proj[b, g]  # [M, 7]
            dx = px.to(dtype) + 0.5 - p[:, 0]
            dy = py.to(dtype) + 0.5 - p[:, 1]
            sigma = 0.5 * (p[:, 2] * dx * dx + p[:, 4] * dy * dy) + p[:, 3] * dx * dy  # [P, M]
            alpha = (p[:, 5] * torch.exp(-sigma.clamp(0, SIGMA_CLAMP))).clamp(max=ALPHA_MAX)
            ok = inside & (sigma >= 0) & (alpha >= ALPHA_MIN)
            alpha = torch.where(ok, alpha, torch.zeros_like(alpha))
            included = ok & (torch.cumprod(1 - alpha.detach(), -1) > T_STOP)  # the stop rule
            alpha = torch.where(included, alpha, torch.zeros_like(alpha))
            t_incl = torch.cumprod(1 - alpha, -1)
            t_before = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], -1)
            w = alpha * t_before  # [P, M]
            acc = w @ torch.cat([vals[g], p[:, 6:7]], 1)  # [P, Cv + 1]
            out[b, :, ty0:y1, tx0:x1] = acc.T.reshape(cv + 1, y1 - ty0, x1 - tx0)
            t_final[b, ty0:y1, tx0:x1] = t_incl[:, -1].reshape(y1 - ty0, x1 - tx0)
            pos = torch.arange(start + 1, end + 1, dtype=torch.int32)
            last[b, ty0:y1, tx0:x1] = torch.where(included, pos, 0).amax(1).reshape(y1 - ty0, x1 - tx0)
    return out[:, :3], out[:, 3:cv], out[:, cv], t_final, last


def raster_bwd(
    proj: Tensor,  # [B, N, 7]
    box: Tensor,  # [B, N, 4] int32
    vals: Tensor,  # [N, Cv]
    offsets: Tensor,
    lists: Tensor,
    tiles_x: int,
    width: int,
    height: int,
    v_rgb: Tensor,  # [B, 3, H, W] d loss / d rgb
    v_feat: Tensor,  # [B, C, H, W]
    v_dep: Tensor,  # [B, H, W] d loss / d un-normalised depth
    v_t: Tensor,  # [B, H, W] d loss / d t_final
) -> tuple[Tensor, Tensor]:
    """(g2d [B, N, 7] d loss / d proj, gvals [N, Cv]): autograd through :func:`raster_fwd`."""
    proj = proj.detach().clone().requires_grad_()
    vals = vals.detach().clone().requires_grad_()
    rgb, feat, dep, t_final, _ = raster_fwd(proj, box, vals, offsets, lists, tiles_x, width, height)
    loss = (rgb * v_rgb).sum() + (feat * v_feat).sum() + (dep * v_dep).sum() + (t_final * v_t).sum()
    if not loss.requires_grad:  # nothing drawn
        return torch.zeros_like(proj), torch.zeros_like(vals)
    g_proj, g_vals = torch.autograd.grad(loss, [proj, vals], allow_unused=True)
    g_proj = torch.zeros_like(proj) if g_proj is None else g_proj
    g_vals = torch.zeros_like(vals) if g_vals is None else g_vals
    return g_proj, g_vals
