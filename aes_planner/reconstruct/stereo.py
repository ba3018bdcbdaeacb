"""Multi-view plane-sweep stereo: depth for a reference frame from posed RGB neighbours.

For each of ``D`` fronto-parallel planes (uniform in inverse depth between ``min_depth_m`` and
``max_depth_m``), every neighbour image is warped into the reference view through the plane, and
the photometric agreement is measured by zero-mean normalised cross-correlation (ZNCC) over a
small window — robust to exposure differences between frames. Costs (``1 - ZNCC``) are averaged
over the neighbours that see the point; the winner takes all, refined to sub-plane precision by
a parabola through the three costs around the minimum.

Confidence in [0, 1] combines how well the best plane matches (its ZNCC), how far its cost
sits below the median plane's (a flat cost curve means a textureless region) and how far below
the best rival plane outside its own dip (a second minimum means a repeated pattern, or stripes
running along the baseline, where any of several depths fits).
Pixels without texture, without a valid neighbour, or below ``min_confidence`` get depth 0
(the package's "no measurement").

It needs translation between frames: for a camera that only rotates (a pan-tilt rig without
depth) every plane warps alike and the depth is unobservable — :func:`expected_disparity_px`
measures that from the poses alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from aes_planner.config import require
from aes_planner.messages import PosedFrame

__all__ = ["StereoConfig", "StereoResult", "consistent_depth", "plane_sweep_depth", "expected_disparity_px"]


@dataclass
class StereoConfig:
    """Plane-sweep settings. More planes and a larger window cost time linearly."""

    num_planes: int = 64
    min_depth_m: float = 0.3
    max_depth_m: float = 50.0
    window_px: int = 7  # ZNCC window side, odd
    min_texture: float = 2e-4  # minimum variance of the reference window (gray in [0, 1])
    min_confidence: float = 0.15
    subplane: bool = True
    uniqueness_margin: float = 0.1  # cost gap to the best rival plane that gives full confidence; 0 = off

    def __post_init__(self):
        require(self.num_planes >= 3, "num_planes", f"need at least 3 planes, got {self.num_planes}")
        require(
            0 < self.min_depth_m < self.max_depth_m,
            "min_depth_m",
            f"need 0 < min_depth_m < max_depth_m, got {self.min_depth_m}, {self.max_depth_m}",
        )
        require(
            self.window_px >= 1 and self.window_px % 2 == 1,
            "window_px",
            f"must be a positive odd number, got {self.window_px}",
        )
        require(self.min_texture >= 0, "min_texture", "must be >= 0")
        require(0 <= self.min_confidence <= 1, "min_confidence", "must be in [0, 1]")
        require(self.uniqueness_margin >= 0, "uniqueness_margin", f"must be >= 0, got {self.uniqueness_margin}")


@dataclass
class StereoResult:
    depth_m: np.ndarray  # [H, W] float32, 0 where unknown
    confidence: np.ndarray  # [H, W] float32 in [0, 1]


def _gray(image: np.ndarray) -> Tensor:
    """uint8 RGB ``[H, W, 3]`` -> gray ``[1, 1, H, W]`` float32 in [0, 1]."""
    rgb = torch.from_numpy(image).float() / 255.0
    g = rgb @ torch.tensor([0.299, 0.587, 0.114], dtype=torch.float32)
    return g[None, None]


def _box(x: Tensor, k: int) -> Tensor:
    """Mean over a ``k x k`` window, same size out (edges average what exists)."""
    return F.avg_pool2d(x, k, stride=1, padding=k // 2, count_include_pad=False)


def _rival_cost(cost: Tensor, best: Tensor) -> Tensor:  # cost [D, H, W], best [H, W] -> [H, W]
    """Lowest cost outside the dip around ``best`` (the run of planes over which the cost rises
    strictly away from it); 2 (the maximum) when the dip spans every plane."""
    d = cost.shape[0]
    planes = torch.arange(d)[:, None, None]
    rises_right = torch.zeros_like(cost, dtype=torch.long)  # 1 where cost[k] <= cost[k-1]: a break
    rises_right[1:] = (cost[1:] <= cost[:-1]).long()
    breaks_r = rises_right.cumsum(0)
    rises_left = torch.zeros_like(cost, dtype=torch.long)  # 1 where cost[k] <= cost[k+1]
    rises_left[:-1] = (cost[:-1] <= cost[1:]).long()
    breaks_l = rises_left.flip(0).cumsum(0).flip(0)  # breaks at k..D-1
    at_best_r = breaks_r.gather(0, best[None])
    at_best_l = breaks_l.gather(0, best[None])
    dip = ((planes > best) & (breaks_r == at_best_r)) | ((planes < best) & (breaks_l == at_best_l)) | (planes == best)
    return torch.where(dip, torch.full_like(cost, 2.0), cost).min(dim=0).values


def expected_disparity_px(frames: list[PosedFrame], depth_m: float) -> float:
    """Largest disparity (pixels) a point at ``depth_m`` can show between any two frames.

    ``focal * baseline / depth`` over all pairs; below ~2 px, plane-sweep stereo cannot tell depths
    apart at that distance.
    """
    if len(frames) < 2:
        return 0.0
    centres = np.stack([f.cam2world[:3, 3] for f in frames])
    baseline = max(float(np.linalg.norm(a - b)) for i, a in enumerate(centres) for b in centres[i + 1 :])
    focal = max(max(f.intrinsics.fx, f.intrinsics.fy) for f in frames)
    return focal * baseline / depth_m


def plane_sweep_depth(
    ref: PosedFrame, neighbours: list[PosedFrame], config: StereoConfig | None = None
) -> StereoResult:
    """Depth and confidence for ``ref`` from posed ``neighbours`` (see the module docstring)."""
    cfg = config or StereoConfig()
    h, w = ref.height, ref.width
    if not neighbours:
        zeros = np.zeros((h, w), np.float32)
        return StereoResult(zeros, zeros.copy())
    k = cfg.window_px
    ref_g = _gray(ref.image)  # [1, 1, H, W]
    mu_r = _box(ref_g, k)
    var_r = (_box(ref_g * ref_g, k) - mu_r * mu_r).clamp_min(0)
    inv_depths = torch.linspace(1.0 / cfg.max_depth_m, 1.0 / cfg.min_depth_m, cfg.num_planes, dtype=torch.float64)
    depths = 1.0 / inv_depths  # [D]

    kr = ref.intrinsics
    u = torch.arange(w, dtype=torch.float64) + 0.5
    v = torch.arange(h, dtype=torch.float64) + 0.5
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    rays = torch.stack([(uu - kr.cx) / kr.fx, (vv - kr.cy) / kr.fy, torch.ones_like(uu)], -1)  # [H, W, 3]
    c2w_ref = torch.from_numpy(ref.cam2world)

    cost_sum = torch.zeros(cfg.num_planes, h, w, dtype=torch.float32)
    count = torch.zeros(cfg.num_planes, h, w, dtype=torch.float32)
    for nb in neighbours:
        rel = torch.from_numpy(np.linalg.inv(nb.cam2world)) @ c2w_ref  # ref camera -> neighbour camera
        a = rays @ rel[:3, :3].T  # [H, W, 3]: the ray direction in the neighbour frame
        p = depths[:, None, None, None] * a + rel[:3, 3]  # [D, H, W, 3]
        z = p[..., 2]
        kn = nb.intrinsics
        z_safe = torch.where(z > 1e-6, z, torch.ones_like(z))
        un = kn.fx * p[..., 0] / z_safe + kn.cx
        vn = kn.fy * p[..., 1] / z_safe + kn.cy
        valid = (z > 1e-6) & (un >= 0) & (un <= kn.width) & (vn >= 0) & (vn <= kn.height)  # [D, H, W]
        grid = torch.stack([un / kn.width * 2 - 1, vn / kn.height * 2 - 1], -1).float()  # [D, H, W, 2]
        nb_g = _gray(nb.image).expand(cfg.num_planes, 1, nb.height, nb.width)
        warped = F.grid_sample(nb_g, grid, mode="bilinear", padding_mode="border", align_corners=False)  # [D, 1, H, W]
        mu_n = _box(warped, k)
        var_n = (_box(warped * warped, k) - mu_n * mu_n).clamp_min(0)
        cov = _box(warped * ref_g, k) - mu_n * mu_r
        zncc = (cov / torch.sqrt(var_n * var_r + 1e-12)).clamp(-1, 1)[:, 0]  # [D, H, W]
        vf = valid.float()
        cost_sum += (1.0 - zncc) * vf
        count += vf

    seen = count > 0
    cost = torch.where(seen, cost_sum / count.clamp_min(1), torch.full_like(cost_sum, 2.0))  # [D, H, W]
    best_cost, best = cost.min(dim=0)  # [H, W]
    idx = best.clamp(1, cfg.num_planes - 2)
    c_m = cost.gather(0, (idx - 1)[None])[0]
    c_0 = cost.gather(0, idx[None])[0]
    c_p = cost.gather(0, (idx + 1)[None])[0]
    offset = torch.zeros_like(c_0)
    if cfg.subplane:
        denom = c_m - 2 * c_0 + c_p
        offset = torch.where(denom > 1e-9, 0.5 * (c_m - c_p) / denom, torch.zeros_like(denom)).clamp(-0.5, 0.5)
        offset = torch.where(best == idx, offset, torch.zeros_like(offset))  # no refinement at the ends
    step = (inv_depths[1] - inv_depths[0]).item()
    inv_d = inv_depths[best].float() + offset * step
    depth = 1.0 / inv_d.clamp_min(1.0 / cfg.max_depth_m)

    # distinctiveness: how far the minimum sits below the typical (median) plane's cost
    typical = cost.median(dim=0).values
    match = (1.0 - best_cost).clamp(0, 1)
    distinct = ((typical - best_cost) / 0.5).clamp(0, 1)
    # uniqueness: the best plane must beat every plane outside its own dip (the planes around it
    # over which the cost rises strictly); a rival there — another valley, or a flat curve — means
    # a repeated pattern or stripes along the epipolar lines, where several depths fit
    rival = _rival_cost(cost, best)
    unique = (
        ((rival - best_cost) / cfg.uniqueness_margin).clamp(0, 1)
        if cfg.uniqueness_margin > 0
        else torch.ones_like(best_cost)
    )
    conf = match * distinct * unique
    ok = seen.any(0) & (var_r[0, 0] > cfg.min_texture) & (conf >= cfg.min_confidence)
    depth = torch.where(ok, depth, torch.zeros_like(depth))
    conf = torch.where(ok, conf, torch.zeros_like(conf))
    return StereoResult(depth.numpy().astype(np.float32), conf.numpy().astype(np.float32))


def consistent_depth(
    ref: PosedFrame,
    depth_m: np.ndarray,  # [H, W] the reference's stereo depth, 0 = unknown
    others: list[tuple[PosedFrame, np.ndarray]],  # neighbours with their own stereo depth [h, w]
    rel_tol: float = 0.05,
) -> np.ndarray:
    """``depth_m`` with 0 where no neighbour agrees: a pixel is kept when, moved into some
    neighbour's camera, it lands on a pixel whose own depth is within ``rel_tol`` of its z there
    (the multi-view geometric consistency check of MVS pipelines: a wrong match is rarely wrong
    the same way from two reference views)."""
    d = np.asarray(depth_m, np.float64)
    known = d > 0
    if not known.any() or not others:
        return np.where(known, d, 0.0).astype(np.float32)
    p_cam = ref.intrinsics.pixel_directions() * d[..., None]  # [H, W, 3]
    p_world = p_cam @ ref.cam2world[:3, :3].T + ref.cam2world[:3, 3]
    agree = np.zeros(d.shape, bool)
    for nb, nb_depth in others:
        q = (p_world - nb.cam2world[:3, 3]) @ nb.cam2world[:3, :3]  # neighbour camera frame
        z = q[..., 2]
        k = nb.intrinsics
        with np.errstate(divide="ignore", invalid="ignore"):
            col = np.floor(k.fx * q[..., 0] / z + k.cx)
            row = np.floor(k.fy * q[..., 1] / z + k.cy)
        inside = known & (z > 0) & (col >= 0) & (col < k.width) & (row >= 0) & (row < k.height)
        ci = np.where(inside, col, 0).astype(np.int64)
        ri = np.where(inside, row, 0).astype(np.int64)
        seen = np.asarray(nb_depth, np.float64)[ri, ci]
        agree |= inside & (seen > 0) & (np.abs(seen - z) <= rel_tol * seen)
    return np.where(agree, d, 0.0).astype(np.float32)
