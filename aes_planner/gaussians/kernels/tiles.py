"""Tile traversal shared by the forward and backward rasters: a tile's origin, a Gaussian's
image-space parameters, the tile rows of its box, a row's terms and 8- or 16-lane window, and
the interleaving of (camera, tile) items across threads."""

from __future__ import annotations

import numpy as np
from numba import njit

from aes_planner.gaussians.kernels.common import C_HALF, HALF_TILE, P_A, P_B, P_C, P_O, P_U, P_V, P_Z, _fast, _opts
from aes_planner.gaussians.numerics import TILE


@njit(**_opts)
def _pixel_centres(origin, n, consts):
    out = np.empty(n, consts.dtype)
    for i in range(n):
        out[i] = origin + i
        out[i] += consts[C_HALF]
    return out


@njit(inline="always", **_fast)
def _tile_origin(tile, tiles_x, consts):
    """The tile's first pixel (tx0, ty0) and its pixel centres ys [TILE], xs [TILE]."""
    tx0 = (tile % tiles_x) * TILE
    ty0 = (tile // tiles_x) * TILE
    return tx0, ty0, _pixel_centres(ty0, TILE, consts), _pixel_centres(tx0, TILE, consts)


@njit(inline="always", **_fast)
def _splat(proj, b, g):
    """One projected Gaussian's centre, conic and opacity and depth: (u, v, a, b, c, o, z)."""
    return (
        proj[b, g, P_U],
        proj[b, g, P_V],
        proj[b, g, P_A],
        proj[b, g, P_B],
        proj[b, g, P_C],
        proj[b, g, P_O],
        proj[b, g, P_Z],
    )


@njit(inline="always", **_fast)
def _tile_rows(box, b, g, ty0):
    """The tile rows [first, stop) that Gaussian g's box covers."""
    return max(box[b, g, 2], ty0) - ty0, min(box[b, g, 3], ty0 + TILE - 1) - ty0 + 1


@njit(inline="always", **_fast)
def _row_terms(ys, py, v, cb, hc, w0):
    """A row's offset from the centre dy, its conic terms b dy and c dy^2 / 2, and the row's first
    window pixel."""
    dy = ys[py] - v
    return dy, cb * dy, hc * dy * dy, np.uint64(py * TILE) + w0


@njit(inline="always", **_fast)
def _row_window(box, b, g, tx0):
    """The lanes of a tile row walked for Gaussian g (forward and backward): HALF_TILE from
    min(box x0, TILE - HALF_TILE) when its columns in the tile fit in them (most Gaussians), else
    the whole row. Returns (lanes, first lane)."""
    jb0 = max(box[b, g, 0], tx0) - tx0
    jb1 = min(box[b, g, 1], tx0 + TILE - 1) - tx0
    narrow = jb1 - jb0 < HALF_TILE
    return (HALF_TILE if narrow else TILE), np.uint64(min(jb0, TILE - HALF_TILE) if narrow else 0)


@njit(**_opts)
def _interleaved(item, n_items, threads):
    """Map prange's contiguous per-thread chunks to interleaved work items (-1 = none), so that
    each thread gets tiles from all over the image (centre tiles are the busy ones)."""
    chunk = -(-n_items // threads)
    real = (item % chunk) * threads + item // chunk
    return real if real < n_items else -1
