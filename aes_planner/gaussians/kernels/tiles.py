"""Tile traversal shared by the forward and backward rasters: a tile's pixel centres, a Gaussian's
image-space parameters, the run of tile pixels its box rows cover and the row terms of that run,
and the interleaving of (camera, tile) items across threads.

A tile's per-pixel state lives in sections of ``NPX = TILE * TILE`` values, row-major, so the
rows ``[py0, py1)`` of a Gaussian's box are one contiguous run of pixels ``[py0 * TILE, py1 *
TILE)``: the tile kernels walk that run as one loop (whole tile rows, the box's columns and the
rest), which LLVM vectorises and pipelines across rows. Per-row loops over a window of the row
(8 or 16 lanes) spent most of their time in per-row overhead and in each row's dependency chain
(docs/journal/rasterizer.md, "One run per Gaussian")."""

from __future__ import annotations

import numpy as np
from numba import njit

from aes_planner.gaussians.kernels.common import C_HALF, P_A, P_B, P_C, P_O, P_U, P_V, P_Z, _fast, _opts
from aes_planner.gaussians.numerics import TILE

NPX = TILE * TILE  # pixels of a tile: the length of one state section


@njit(inline="always", **_fast)
def _tile_xy(tile, tiles_x):
    """The tile's first pixel (tx0, ty0)."""
    return (tile % tiles_x) * TILE, (tile // tiles_x) * TILE


@njit(inline="always", **_fast)
def _fill_centres(st, o_x, o_y, tx0, ty0, consts):
    """Pixel centres of the tile into the sections at o_x (x) and o_y (y) of st."""
    half = consts[C_HALF]
    for py in range(TILE):
        for px in range(TILE):
            p = np.uint64(py * TILE + px)
            st[o_x + p] = tx0 + px
            st[o_x + p] += half
            st[o_y + p] = ty0 + py
            st[o_y + p] += half


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
def _tile_run(box, b, g, ty0):
    """The tile pixels [p0, p1) of the rows that Gaussian g's box covers (uint64)."""
    py0 = max(box[b, g, 2], ty0) - ty0
    py1 = min(box[b, g, 3], ty0 + TILE - 1) - ty0 + 1
    return np.uint64(py0 * TILE), np.uint64(max(py1, py0) * TILE)


@njit(inline="always", **_fast)
def _run_row_terms(st, o_y, o_bdy, o_crow, p0, p1, v, cb, hc):
    """Each pixel's b dy and c dy^2 / 2 (dy from the Gaussian's centre row) into the sections at
    o_bdy, o_crow. Stored and loaded, not recomputed where sigma is: the rounding of these two
    products is then fixed (no fused multiply-add can absorb them), the same in the forward and
    the backward, and the same as when they were computed once per row."""
    for j in range(p1 - p0):
        p = p0 + np.uint64(j)
        dy = st[o_y + p] - v
        st[o_bdy + p] = cb * dy
        st[o_crow + p] = hc * dy * dy


@njit(**_opts)
def _interleaved(item, n_items, threads):
    """Map prange's contiguous per-thread chunks to interleaved work items (-1 = none), so that
    each thread gets tiles from all over the image (centre tiles are the busy ones)."""
    chunk = -(-n_items // threads)
    real = (item % chunk) * threads + item // chunk
    return real if real < n_items else -1
