"""Merging overlapping frames, pruning and the Gaussian budget, on :class:`SplatSet` records.

**Cells.** Space is hashed into cubic cells on a ladder of sizes ``BASE_CELL_M * 2^L``; a splat
lives at the level whose cell is just larger than ``factor x`` its footprint, so near and far
surfaces each get cells matched to how finely they were seen. The key also holds the splat's
normal quantised to one of six directions, so the front and back of a thin board never compete.

**Deduplication** (:func:`dedupe`). When a frame's splats arrive, each cell (at the coarser of the
two levels that meet) that holds splats of both the map and the newcomer is decided as a whole:
the newcomer wins when its best score (``confidence / footprint``: closer, more frontal, more
confident) beats the incumbent's by ``margin``; otherwise the incumbent does. A loser then goes
only where the winner really covers it — a winning splat in the loser's own fine cell
(``COVER_FACTOR`` footprints), well inside the winner's frame — because the winner may see only
part of a shared cell (an occlusion boundary, the edge of its view), and a hole costs more than a
duplicate. A frame never deduplicates against itself, so a cell larger than a splat costs no
resolution.

**Budget** (:func:`coarsen`). Each frame's splats form a quadtree over its stride blocks; the
splats of one frame in one 2 x 2 block of the next level merge into one splat whose colour is
their weighted mean and whose covariance matches their spread (moment matching, inflated so that
the merged splat nearly tiles like one built at twice the stride). Cheapest first: the cost is
the colour variance the merge hides, how far the members leave a common plane, their normal
spread, and how far the merged splat's tails would spill over a depth edge or hole — so flat,
uniform surfaces coarsen long before texture, edges and curved shapes: the stride adapts to
content. Merges never cross frames, so a merged splat never bridges what one view saw apart.

**Pruning**: :func:`prune_hidden` drops splats that the views which see them give almost no
blending weight (hidden behind better ones); low opacity is a plain mask.
:func:`refit_colors` corrects merged splats' colours against their frames.
"""

from __future__ import annotations

import logging

import numpy as np
import torch

from aes_planner.gaussians.projection import covariance_3d
from aes_planner.geometry.camera import Intrinsics
from aes_planner.reconstruct.splats import SplatSet, rotations_to_quats

__all__ = ["BASE_CELL_M", "coarsen", "contributions", "dedupe", "levels", "prune_hidden", "refit_colors"]

log = logging.getLogger(__name__)

BASE_CELL_M = 1e-3  # cell ladder: BASE_CELL_M * 2^L
COVER_FACTOR = 1.5  # a loser must have a winner within its own cell this many footprints wide
COVER_BORDER_BLOCKS = 3.0  # ... that is this many blocks inside its frame (> the cell's diagonal)
_GEO_WEIGHT = 0.05  # colour units per (plane offset / footprint)^2
_NORMAL_WEIGHT = 0.05  # colour units per (1 - cos) of normal spread
# Merged splats are drawn narrower than the moment-matched spread of their members: they render
# closer to the views (figures: docs/benchmarks.md, "Figures behind code comments").
_SPREAD_GAIN = 0.75
_MAX_LEVEL = 20  # quadtree levels: far beyond any image (2^20 blocks)
_SPILL_WEIGHT = 0.03  # colour units per block whose merged tails would reach over a depth edge


def levels(footprint_m: np.ndarray, factor: float) -> np.ndarray:  # [M] -> [M] int64
    """Level ``L`` (int64 ``[M]``) whose cell ``BASE_CELL_M * 2^L`` is >= ``factor * footprint``."""
    size = np.maximum(factor * np.asarray(footprint_m, np.float64), 1e-9)
    return np.ceil(np.log2(size / BASE_CELL_M)).astype(np.int64)


def _normal_bin(normals: np.ndarray) -> np.ndarray:  # [M, 3] -> [M] in 0..5
    axis = np.abs(normals).argmax(1)
    sign = np.take_along_axis(normals, axis[:, None], 1)[:, 0] < 0
    return axis * 2 + sign


def _group(columns: list[np.ndarray]) -> tuple[np.ndarray, int]:  # k x [M] int64 -> ([M], n)
    """Group rows of int64 ``columns`` (each ``[M]``): returns ``(group id [M], n_groups)``."""
    m = columns[0].shape[0]
    if m == 0:
        return np.zeros(0, np.int64), 0
    lo = [c.min() for c in columns]
    span = [int(c.max() - l) + 1 for c, l in zip(columns, lo)]
    if float(np.prod([float(s) for s in span])) < 2.0**62:
        key = np.zeros(m, np.int64)
        for c, l, s in zip(columns, lo, span):
            key = key * s + (c - l)
        _, inverse = np.unique(key, return_inverse=True)
    else:  # astronomically spread cells: exact but slower
        _, inverse = np.unique(np.stack(columns, 1), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    return inverse, int(inverse.max()) + 1


def _cells(means: np.ndarray, level: np.ndarray, normals: np.ndarray) -> list[np.ndarray]:  # [M, 3], [M], [M, 3]
    cell = BASE_CELL_M * np.exp2(level.astype(np.float64))
    ijk = np.floor(means.astype(np.float64) / cell[:, None]).astype(np.int64)
    return [level, _normal_bin(normals).astype(np.int64), ijk[:, 0], ijk[:, 1], ijk[:, 2]]


def _group_mean(x: np.ndarray, w: np.ndarray, group: np.ndarray, n: int) -> np.ndarray:  # [M, C], [M], [M] -> [n, C]
    """Weighted mean of the rows of ``x [M, C]`` per group (weights ``w [M]``): ``[n, C]``."""
    wsum = np.maximum(np.bincount(group, weights=w, minlength=n), 1e-30)
    return (
        np.stack([np.bincount(group, weights=w * x[:, j], minlength=n) for j in range(x.shape[1])], 1) / wsum[:, None]
    )


def _group_min(values: np.ndarray, group: np.ndarray, n: int) -> np.ndarray:  # [M], [M] -> [n]
    out = np.full(n, np.inf)
    np.minimum.at(out, group, values)
    return out


def _group_max(values: np.ndarray, group: np.ndarray, n: int) -> np.ndarray:  # [M], [M] -> [n]
    out = np.full(n, -np.inf)
    np.maximum.at(out, group, values)
    return out


def dedupe(old: SplatSet, new: SplatSet, cell_factor: float, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Which splats of the map (``old``) and of a new frame (``new``) to keep: boolean masks
    ``([len(old)], [len(new)])`` (rules in the module docstring)."""
    keep_old = np.ones(len(old), bool)
    keep_new = np.ones(len(new), bool)
    if not len(old) or not len(new):
        return keep_old, keep_new
    lv_old = levels(old.footprint_m, cell_factor)
    lv_new = levels(new.footprint_m, cell_factor)
    # only map splats near the newcomer can meet it
    reach = BASE_CELL_M * 2.0 ** float(lv_new.max())
    lo, hi = new.means.min(0) - reach, new.means.max(0) + reach
    near = np.all((old.means >= lo) & (old.means <= hi), axis=1)
    lose_old = np.zeros(len(old), bool)  # in a cell the newcomer won
    lose_new = np.zeros(len(new), bool)  # in a cell the map kept
    for level in sorted(set(lv_old[near].tolist()) | set(lv_new.tolist()), reverse=True):
        so = np.flatnonzero(~lose_old & near & (lv_old <= level))
        sn = np.flatnonzero(~lose_new & (lv_new <= level))
        if not so.size or not sn.size:
            continue
        means = np.concatenate([old.means[so], new.means[sn]])
        normals = np.concatenate([old.normals[so], new.normals[sn]])
        group, n = _group(_cells(means, np.full(len(means), level, np.int64), normals))
        g_old, g_new = group[: so.size], group[so.size :]
        exact = np.bincount(group, weights=np.concatenate([lv_old[so] == level, lv_new[sn] == level]), minlength=n)
        both = (np.bincount(g_old, minlength=n) > 0) & (np.bincount(g_new, minlength=n) > 0) & (exact > 0)
        if not both.any():
            continue
        best_old = _group_max(old.score[so].astype(np.float64), g_old, n)
        best_new = _group_max(new.score[sn].astype(np.float64), g_new, n)
        new_wins = best_new > (1.0 + margin) * best_old
        lose_old[so[both[g_old] & new_wins[g_old]]] = True
        lose_new[sn[both[g_new] & ~new_wins[g_new]]] = True
    # a loser goes only where the winning side has a splat in its own fine cell: the winner may
    # cover just part of a shared cell (an occlusion boundary), and a hole is worse than a duplicate
    keep_old[lose_old] = ~_covered(old.select(lose_old), new.select(~lose_new))
    keep_new[lose_new] = ~_covered(new.select(lose_new), old.select(~lose_old & near))
    return keep_old, keep_new


def _covered(losers: SplatSet, winners: SplatSet) -> np.ndarray:
    """Per loser, whether a winner lies in the loser's cell ``COVER_FACTOR`` footprints wide and
    at least ``COVER_BORDER_BLOCKS`` inside its own frame (or as far inside as the loser is in
    its frame): a winner at the very edge of its view may stop short of the loser."""
    out = np.zeros(len(losers), bool)
    if not len(losers) or not len(winners):
        return out
    lv = levels(losers.footprint_m, COVER_FACTOR)
    inside = winners.border_px / (winners.stride * np.exp2(winners.level))  # in blocks
    loser_inside = losers.border_px / (losers.stride * np.exp2(losers.level))
    for level in np.unique(lv):
        sel = np.flatnonzero(lv == level)
        means = np.concatenate([losers.means[sel], winners.means])
        normals = np.concatenate([losers.normals[sel], winners.normals])
        group, n = _group(_cells(means, np.full(len(means), level, np.int64), normals))
        deepest = _group_max(inside.astype(np.float64), group[sel.size :], n)
        out[sel] = deepest[group[: sel.size]] >= np.minimum(COVER_BORDER_BLOCKS, loser_inside[sel])
    return out


def _merge_groups(
    sp: SplatSet, members: np.ndarray, group: np.ndarray, n: int, spread_gain: float
) -> SplatSet:  # members, group [K]
    """One splat per group of ``members`` (indices into ``sp``, group ids ``[K]`` in ``0..n-1``)."""
    w = (sp.samples[members] * np.maximum(sp.opacities[members], 1e-3)).astype(np.float64)
    wsum = np.bincount(group, weights=w, minlength=n)
    mu = _group_mean(sp.means[members].astype(np.float64), w, group, n)
    color = _group_mean(sp.colors[members].astype(np.float64), w, group, n)
    normal = _group_mean(sp.normals[members].astype(np.float64), w, group, n)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    opacity = np.bincount(group, weights=w * sp.opacities[members], minlength=n) / wsum
    d = sp.means[members].astype(np.float64) - mu[group]
    cov_i = covariance_3d(
        torch.from_numpy(sp.quats[members].astype(np.float64)),
        torch.from_numpy(sp.log_scales[members].astype(np.float64)),
    ).numpy()  # [K, 3, 3]
    cov_i += spread_gain * d[:, :, None] * d[:, None, :]
    cov = np.stack([np.bincount(group, weights=w * cov_i[:, a, b], minlength=n) for a in range(3) for b in range(3)], 1)
    cov = cov.reshape(n, 3, 3) / wsum[:, None, None]
    evals, evecs = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, 1, 2)))
    evecs[np.linalg.det(evecs) < 0, :, 0] *= -1  # a proper rotation
    scales = np.sqrt(np.maximum(evals, 1e-20))
    # provenance and score from the best-observed member
    order = np.lexsort((-sp.score[members], group))
    first = order[np.r_[True, group[order][1:] != group[order][:-1]]]
    best = members[first]
    area = np.bincount(group, weights=sp.footprint_m[members].astype(np.float64) ** 2, minlength=n)
    return SplatSet(
        means=mu.astype(np.float32),
        quats=rotations_to_quats(evecs),
        log_scales=np.log(scales).astype(np.float32),
        opacities=np.clip(opacity, 0, 1).astype(np.float32),
        colors=color.astype(np.float32),
        normals=normal.astype(np.float32),
        footprint_m=np.sqrt(area).astype(np.float32),
        score=sp.score[best],
        samples=np.bincount(group, weights=sp.samples[members], minlength=n).astype(np.float32),
        source_frame=sp.source_frame[best],
        source_pixel=sp.source_pixel[best],
        level=(sp.level[best] + 1).astype(np.int16),
        block=sp.block[best] >> 1,
        stride=sp.stride[best],
        edge_px=_group_min(sp.edge_px[members].astype(np.float64), group, n).astype(np.float32),
        border_px=_group_min(sp.border_px[members].astype(np.float64), group, n).astype(np.float32),
    )


def _quad_costs(sp: SplatSet, scale_factor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Quads: groups of a frame's same-level splats in one 2 x 2 block of the next level, and
    what merging each costs.

    Returns ``(quad id [M], cost per quad [Q], members per quad [Q], Q)``. The cost is what a
    merge hides, summed over the stride blocks it covers: the colour variance, the members'
    squared offsets from their mean plane (in footprints), their normal spread, and how far the
    merged splat's tails would reach over a depth edge or hole.
    """
    if not len(sp):
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64), 0
    cols = [
        sp.source_frame.astype(np.int64),
        sp.level.astype(np.int64),
        (sp.block[:, 0] >> 1).astype(np.int64),
        (sp.block[:, 1] >> 1).astype(np.int64),
    ]
    group, n = _group(cols)
    size = np.bincount(group, minlength=n)
    w = (sp.samples * np.maximum(sp.opacities, 1e-3)).astype(np.float64)
    wsum = np.bincount(group, weights=w, minlength=n)
    c_bar = _group_mean(sp.colors.astype(np.float64), w, group, n)
    mu = _group_mean(sp.means.astype(np.float64), w, group, n)
    n_bar = _group_mean(sp.normals.astype(np.float64), w, group, n)
    n_len = np.linalg.norm(n_bar, axis=1)
    n_unit = n_bar / np.maximum(n_len, 1e-12)[:, None]
    color_cost = np.bincount(group, weights=w * ((sp.colors - c_bar[group]) ** 2).sum(1), minlength=n)
    off = ((sp.means - mu[group]) * n_unit[group]).sum(1) / np.maximum(sp.footprint_m, 1e-9)
    geo_cost = np.bincount(group, weights=w * off**2, minlength=n)
    normal_cost = wsum * (1.0 - n_len)
    # a merged splat's tails (out to ~2 sigma) should not spill over a depth edge or a hole
    reach_px = 2.0 * scale_factor * sp.stride * np.exp2(sp.level.astype(np.float64) + 1)
    spill = _group_max(np.maximum(reach_px - sp.edge_px, 0.0) / reach_px, group, n)
    cost = color_cost + _GEO_WEIGHT * geo_cost + _NORMAL_WEIGHT * normal_cost + _SPILL_WEIGHT * wsum * spill
    return group, cost, size, n


def _merge_quads(sp: SplatSet, target: int, scale_factor: float) -> SplatSet:
    """One pass: merge the cheapest quads (cost per splat removed) until half the excess over
    ``target`` is gone (all of it when that is small), so that parents formed in this pass
    compete with the remaining quads in the next — a close approximation of merging strictly
    cheapest-first across levels, in O(log excess) passes."""
    quad, cost, size, nq = _quad_costs(sp, scale_factor)
    excess = len(sp) - target
    if excess <= 0:
        return sp
    candidates = np.flatnonzero(size >= 2)
    if candidates.size == 0:
        return sp
    per_removed = cost[candidates] / (size[candidates] - 1)
    order = candidates[np.argsort(per_removed, kind="stable")]
    goal = excess if excess <= 64 else (excess + 1) // 2
    take = order[: int(np.searchsorted(np.cumsum(size[order] - 1), goal)) + 1]
    chosen = np.zeros(nq, bool)
    chosen[take] = True
    in_merge = chosen[quad]
    members = np.flatnonzero(in_merge)
    remap = np.full(nq, -1, np.int64)
    remap[take] = np.arange(take.size)
    merged = _merge_groups(sp, members, remap[quad[members]], take.size, _SPREAD_GAIN * 12.0 * scale_factor**2)
    return SplatSet.cat([sp.select(~in_merge), merged])


def _promote_singletons(sp: SplatSet) -> tuple[SplatSet, bool]:
    """Lift splats alone in their quad one level up (same splat, coarser block), so that they can
    meet their neighbours' merged parents. Returns whether any moved."""
    quad, _, size, _ = _quad_costs(sp, 1.0)
    alone = (size[quad] == 1) & (sp.level < _MAX_LEVEL)
    if not alone.any():
        return sp, False
    level = sp.level.copy()
    block = sp.block.copy()
    level[alone] += 1
    block[alone] >>= 1
    return SplatSet(**{**sp.__dict__, "level": level, "block": block}), True


def coarsen(sp: SplatSet, target: int, scale_factor: float) -> SplatSet:
    """Merge splats until at most ``target`` remain: quads of a frame's blocks, cheapest first
    (see :func:`_quad_costs`), level after level — an adaptive stride.

    ``scale_factor``: a splat's on-screen size per block (``ReconstructConfig.scale_factor``).
    Merged covariances add ``g x 12 scale_factor^2`` times the members' spread: with ``g = 1`` a
    merged complete quad is exactly as large, relative to its block, as a splat built at twice the
    stride; ``g = _SPREAD_GAIN = 0.75`` renders closer to the simulator (overlapping opaque
    splats already fill the gaps). A partial quad stays as narrow as its members across the
    missing side. Only when nothing is left to merge (a target below one splat per frame and
    surface) are the least important splats (fewest blocks x opacity) dropped.
    """
    target = max(int(target), 1)
    while len(sp) > target:
        before = len(sp)
        sp = _merge_quads(sp, target, scale_factor)
        if len(sp) < before:
            continue
        sp, moved = _promote_singletons(sp)
        if not moved:
            importance = sp.samples * sp.opacities
            keep = np.argsort(-importance, kind="stable")[:target]
            log.warning(
                "coarsen: nothing left to merge; dropping the %d least important of %d splats",
                len(sp) - target,
                len(sp),
            )
            sp = sp.select(np.sort(keep))
    return sp


class _Upstream(torch.autograd.Function):
    """A scalar whose gradient with respect to ``maps`` is ``upstream`` (tensors like them):
    ``autograd.grad(maps, ..., grad_outputs=upstream)`` computes the same but imports torch's
    symbolic-shape machinery (sympy: ~1 s of a cold ``suggest`` under load) to check the shapes.
    Only for differentiating the scalar itself (its own gradient is 1)."""

    @staticmethod
    def forward(ctx, upstream, *maps):
        ctx.upstream = upstream
        return maps[0].new_zeros(())

    @staticmethod
    def backward(ctx, _one):
        return (None, *ctx.upstream)


def contributions(
    sp: SplatSet,
    views: list[tuple[np.ndarray, Intrinsics]],  # (cam2world [4, 4] local frame, intrinsics)
) -> tuple[np.ndarray, np.ndarray]:
    """Per splat, the largest total blending weight (pixels) over ``views`` and whether any of
    them drew it at all: ``(max_weight [M], seen [M])``.

    The weight is exact and cheap: the gradient of a rendered value channel with respect to a
    splat's value in it is the sum over pixels of its blending weight ``T alpha``. Views of one
    image size render in one batched call with one probe channel per view (channel ``b`` read
    in view ``b`` only), so that the rasterizer runs once for all of them.
    """
    from aes_planner.gaussians import autograd_on, rasterize

    best = np.zeros(len(sp))
    seen = np.zeros(len(sp), bool)
    if not len(sp):
        return best, seen
    by_size: dict[tuple[int, int], list[int]] = {}
    for i, (_, k) in enumerate(views):
        by_size.setdefault((k.width, k.height), []).append(i)
    with autograd_on():  # the weights are a gradient, also under a caller's no_grad or inference_mode
        g = sp.to_gaussians()
        for (width, height), index in by_size.items():
            n_views = len(index)
            # [M, B] probes: the colours carry views 0-2 and features the rest (few value channels
            # keep the backward on its lane-wise path)
            probe = torch.zeros(len(sp), max(n_views, 3), dtype=g.colors.dtype, requires_grad=True)
            g.colors, g.features = probe[:, :3], probe[:, 3:]
            world2cam = torch.from_numpy(np.stack([np.linalg.inv(views[i][0]) for i in index]))  # [B, 4, 4]
            K = torch.from_numpy(np.stack([views[i][1].K for i in index]))  # [B, 3, 3]
            out = rasterize(g, world2cam, K, width, height, validate=False)
            # d/d(view b's own channel) = 1, all else 0; built in numpy: large torch ops would wake
            # torch's thread pool against the rasterizer's (numba_backend._Raster says why)
            maps = (out.rgb, out.features, out.depth, out.alpha)
            upstream = [np.zeros(tuple(t.shape), np.float32) for t in maps]
            for b in range(n_views):
                (upstream[0][b, b] if b < 3 else upstream[1][b, b - 3])[:] = 1.0
            (grad,) = torch.autograd.grad(_Upstream.apply([torch.from_numpy(u) for u in upstream], *maps), probe)
            wgt = grad[:, :n_views].double().numpy()  # [M, B]
            best = np.maximum(best, wgt.max(axis=1))
            seen |= (wgt > 0).any(axis=1)
    return best, seen


def prune_hidden(sp: SplatSet, views: list[tuple[np.ndarray, Intrinsics]], min_weight: float) -> np.ndarray:
    """Keep mask ``[M]``: False for splats whose centre lies inside some view but which no view
    gives ``min_weight`` pixels of blending weight (hidden behind better-observed splats
    everywhere they could be seen). Splats outside every view are kept."""
    best, _ = contributions(sp, views)
    visible = np.zeros(len(sp), bool)
    for cam2world, k in views:
        p = (sp.means.astype(np.float64) - cam2world[:3, 3]) @ cam2world[:3, :3]
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = k.fx * p[:, 0] / z + k.cx
            v = k.fy * p[:, 1] / z + k.cy
        visible |= (z > 0) & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
    return ~visible | (best >= min_weight)


def refit_colors(
    sp: SplatSet,
    views: list[
        tuple[np.ndarray, Intrinsics, np.ndarray]
    ],  # (cam2world local, intrinsics, image [H, W, 3] uint8) by frame index
    iterations: int,
) -> SplatSet:
    """Van Cittert colour correction of merged splats against the frames they came from: each
    adds the mean residual ``image - render`` over its own block in its source frame. (Splats
    as built were already corrected against their frame by ``sharpen_colors``; correcting them
    again against the whole map over-fits the input views.)"""
    from aes_planner.gaussians import rasterize

    if iterations <= 0 or not len(sp):
        return sp
    colors = sp.colors.astype(np.float32).copy()
    for _ in range(iterations):
        g = sp.to_gaussians()
        g.colors = torch.from_numpy(colors)
        for index, (cam2world, k, image) in enumerate(views):
            own = np.flatnonzero((sp.source_frame == index) & (sp.level > 0))
            if not own.size:
                continue
            out = rasterize(
                g, torch.from_numpy(np.linalg.inv(cam2world)), torch.from_numpy(k.K), k.width, k.height, validate=False
            )
            resid = image.astype(np.float32) / 255.0 - out.rgb[0].permute(1, 2, 0).numpy()
            integral = np.zeros((k.height + 1, k.width + 1, 3), np.float64)
            integral[1:, 1:] = resid.cumsum(0).cumsum(1)
            size = sp.stride[own].astype(np.int64) << sp.level[own].astype(np.int64)
            r0 = np.clip(sp.block[own, 0].astype(np.int64) * size, 0, k.height)
            c0 = np.clip(sp.block[own, 1].astype(np.int64) * size, 0, k.width)
            r1, c1 = np.minimum(r0 + size, k.height), np.minimum(c0 + size, k.width)
            area = np.maximum((r1 - r0) * (c1 - c0), 1)[:, None]
            total = integral[r1, c1] - integral[r0, c1] - integral[r1, c0] + integral[r0, c0]
            colors[own] += (total / area).astype(np.float32)
    return SplatSet(**{**sp.__dict__, "colors": colors})
