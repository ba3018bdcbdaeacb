"""The pure-torch fallback backend: tile-binned, autograd only.

Used where numba is unavailable (or on a non-CPU device). Gaussians are projected with
:func:`~aes_planner.gaussians.projection.project`, sorted by depth per camera and binned into
TILE x TILE tiles (a Gaussian goes to every tile its ``alpha >= 1/255`` box touches); each tile
then composites its own ``[tile pixels, Gaussians of the tile]`` block. Memory grows with the
number of (tile, Gaussian) pairs times the tile area, never with N x H x W. Much slower than
the numba backend on a CPU (figures: docs/benchmarks.md, "Figures behind code comments").
"""

from __future__ import annotations

import torch
from torch import Tensor

from aes_planner.gaussians.numerics import ALPHA_MAX, ALPHA_MIN, SIGMA_CLAMP, T_STOP, TILE
from aes_planner.gaussians.projection import project

__all__ = ["render"]


def _tile_lists(proj, b: int, width: int, height: int, tiles_x: int, tiles_y: int):
    """Visible Gaussians of camera b sorted by depth, and for every tile the slice of its list."""
    vis = proj.visible[b].nonzero().squeeze(1)
    order = vis[torch.sort(proj.depths[b, vis].detach(), stable=True).indices]  # front to back
    uv = proj.means2d[b, order].detach()
    ext = proj.extents[b, order]
    # Pixel boxes (pixel i has its centre at i + 0.5), then tile boxes.
    x0 = torch.ceil(uv[:, 0] - ext[:, 0] - 0.5).clamp(0, width - 1).long() // TILE
    x1 = torch.floor(uv[:, 0] + ext[:, 0] - 0.5).clamp(0, width - 1).long() // TILE
    y0 = torch.ceil(uv[:, 1] - ext[:, 1] - 0.5).clamp(0, height - 1).long() // TILE
    y1 = torch.floor(uv[:, 1] + ext[:, 1] - 0.5).clamp(0, height - 1).long() // TILE
    nx, ny = x1 - x0 + 1, y1 - y0 + 1
    counts = nx * ny
    rank = torch.repeat_interleave(torch.arange(order.shape[0]), counts)  # depth rank per pair
    local = torch.arange(rank.shape[0]) - torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts)
    tile = (y0[rank] + local // nx[rank]) * tiles_x + x0[rank] + local % nx[rank]
    pairs = torch.sort(tile * max(order.shape[0], 1) + rank).indices  # by tile, then by depth
    per_tile = torch.bincount(tile, minlength=tiles_x * tiles_y)
    ends = torch.cumsum(per_tile, 0)
    return order[rank[pairs]], (ends - per_tile).tolist(), ends.tolist()


def render(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    log_scales: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    values: Tensor,  # [N, Cv] colours then features
    world2cam: Tensor,  # [B, 4, 4]
    K: Tensor,  # [B, 3, 3]
    width: int,
    height: int,
) -> tuple[Tensor, Tensor]:
    """(out [B, Cv + 1, H, W]: values then un-normalised depth, t_final [B, H, W])."""
    dtype = values.dtype
    n_cam, cv = world2cam.shape[0], values.shape[1]
    proj = project(means, quats, log_scales, opacities, world2cam, K, width, height)
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    ty, tx = torch.meshgrid(torch.arange(TILE), torch.arange(TILE), indexing="ij")
    tile_pix = torch.stack([tx.reshape(-1), ty.reshape(-1)], -1).to(dtype)  # [P, 2]
    outs, finals = [], []
    for b in range(n_cam):
        ids, starts, ends = _tile_lists(proj, b, width, height, tiles_x, tiles_y)
        mean2d = proj.means2d[b].to(dtype)
        conic = proj.conics[b].to(dtype)
        depth = proj.depths[b].to(dtype)
        rows = []
        for t in range(tiles_x * tiles_y):
            g = ids[starts[t] : ends[t]]
            origin = torch.tensor([(t % tiles_x) * TILE + 0.5, (t // tiles_x) * TILE + 0.5], dtype=dtype)
            d = (tile_pix + origin)[:, None, :] - mean2d[g][None]  # [P, M, 2]
            dx, dy = d[..., 0], d[..., 1]
            cg = conic[g]
            sigma = 0.5 * (cg[:, 0] * dx * dx + cg[:, 2] * dy * dy) + cg[:, 1] * dx * dy
            alpha = (opacities[g] * torch.exp(-sigma.clamp(max=SIGMA_CLAMP))).clamp(max=ALPHA_MAX)
            alpha = torch.where((sigma >= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))
            one_minus = 1 - alpha
            included = torch.cumprod(one_minus.detach(), -1) > T_STOP  # compositing axis last
            one_minus = torch.where(included, one_minus, torch.ones_like(one_minus))
            t_incl = torch.cumprod(one_minus, -1)
            t_before = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], -1)
            w = alpha * included * t_before  # [P, M]
            acc = w @ torch.cat([values[g], depth[g, None]], 1)  # [P, Cv + 1]
            t_fin = t_incl[:, -1:] if g.numel() else torch.ones(TILE * TILE, 1, dtype=dtype)
            rows.append(torch.cat([acc, t_fin], 1).reshape(TILE, TILE, cv + 2))
        img = torch.stack(rows).reshape(tiles_y, tiles_x, TILE, TILE, cv + 2)
        img = img.permute(4, 0, 2, 1, 3).reshape(cv + 2, tiles_y * TILE, tiles_x * TILE)[:, :height, :width]
        outs.append(img[:-1])
        finals.append(img[-1])
    return torch.stack(outs), torch.stack(finals)
