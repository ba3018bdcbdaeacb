from __future__ import annotations

import numpy as np
from numba import njit, prange

from aes_planner.gaussians.kernels.common import P_Z, _opts
from aes_planner.gaussians.numerics import TILE

RADIX_BITS = 12
# One camera's binning on several threads is two tasks: its sort beside its count, then its
# tile lists in two bands of tile rows (a constant: numba cannot cache a kernel that asks for
# the thread count).
ONE_CAMERA_TASKS = 2


@njit(**_opts)
def _radix_argsort(keys, idx, tmp_keys, tmp_idx):
    """Stable LSD radix sort of non-negative int64 keys, carrying idx. Keys are shifted to start
    at 0 first, so the passes cover only the spread of the keys (two passes of 12 bits for
    float32 depths within a factor of 4 of each other)."""
    n = keys.shape[0]
    if n < 2:
        return
    lo = keys.min()
    span = keys.max() - lo
    for i in range(n):
        keys[i] -= lo
    hist = np.empty(1 << RADIX_BITS, np.int64)
    mask = (1 << RADIX_BITS) - 1
    shift = 0
    while (span >> shift) > 0:
        hist[:] = 0
        for i in range(n):
            hist[(keys[i] >> shift) & mask] += 1
        total = 0
        for d in range(1 << RADIX_BITS):
            c = hist[d]
            hist[d] = total
            total += c
        for i in range(n):
            d = (keys[i] >> shift) & mask
            pos = hist[d]
            hist[d] = pos + 1
            tmp_keys[pos] = keys[i]
            tmp_idx[pos] = idx[i]
        keys[:n] = tmp_keys[:n]
        idx[:n] = tmp_idx[:n]
        shift += RADIX_BITS


@njit(**_opts)
def _sort_camera(proj, box, b, order, n_visible):
    """Visible Gaussians of camera b, sorted by depth, into order[b, :n_visible[b]]."""
    n = box.shape[1]
    depth32 = np.empty(n, np.float32)
    bits = depth32.view(np.uint32)
    keys = np.empty(n, np.int64)
    idx = np.empty(n, np.int32)
    m = 0
    for g in range(n):
        if box[b, g, 0] <= box[b, g, 1]:
            depth32[m] = proj[b, g, P_Z]
            idx[m] = g
            m += 1
    for i in range(m):
        keys[i] = np.int64(bits[i])
    _radix_argsort(keys[:m], idx[:m], np.empty(m, np.int64), np.empty(m, np.int32))
    n_visible[b] = m
    order[b, :m] = idx[:m]


@njit(**_opts)
def _count_camera(box, b, tiles_x, tile_counts):
    """Tile counts of camera b's visible Gaussians (in index order: sequential loads of box)."""
    for g in range(box.shape[1]):
        if box[b, g, 0] > box[b, g, 1]:
            continue
        for ty in range(box[b, g, 2] // TILE, box[b, g, 3] // TILE + 1):
            for tx in range(box[b, g, 0] // TILE, box[b, g, 1] // TILE + 1):
                tile_counts[b, ty * tiles_x + tx] += 1


@njit(**_opts)
def _fill_camera(box, b, tiles_x, order, n_visible, offsets, lists, ty_lo, ty_hi):
    """Append camera b's visible Gaussians, in depth order, to the lists of its tiles in tile rows
    [ty_lo, ty_hi) (all rows: one thread fills the camera; a band: threads share it)."""
    n_tiles = (offsets.shape[0] - 1) // box.shape[0]
    cursor = offsets[b * n_tiles : (b + 1) * n_tiles].copy()
    for i in range(n_visible[b]):
        g = order[b, i]
        for ty in range(max(box[b, g, 2] // TILE, ty_lo), min(box[b, g, 3] // TILE + 1, ty_hi)):
            for tx in range(box[b, g, 0] // TILE, box[b, g, 1] // TILE + 1):
                t = ty * tiles_x + tx
                lists[cursor[t]] = g
                cursor[t] += 1


@njit(**_opts)
def bin_cameras(proj, box, tiles_x, parallel, order, n_visible, tile_counts):
    """Per camera: depth sort of the visible Gaussians and tile counts. ``parallel``: cameras
    spread over the threads, or with one camera its sort and its count on two threads at once;
    else the calling thread does it all."""
    if not parallel:
        for b in range(box.shape[0]):
            _sort_camera(proj, box, b, order, n_visible)
            _count_camera(box, b, tiles_x, tile_counts)
    elif box.shape[0] == 1:
        _bin_one_camera_parallel(proj, box, tiles_x, order, n_visible, tile_counts)
    else:
        _bin_cameras_parallel(proj, box, tiles_x, order, n_visible, tile_counts)


@njit(parallel=True, **_opts)
def _bin_cameras_parallel(proj, box, tiles_x, order, n_visible, tile_counts):
    for b in prange(box.shape[0]):
        _sort_camera(proj, box, b, order, n_visible)
        _count_camera(box, b, tiles_x, tile_counts)


@njit(parallel=True, **_opts)
def _bin_one_camera_parallel(proj, box, tiles_x, order, n_visible, tile_counts):
    for task in prange(ONE_CAMERA_TASKS):  # the sort and the count: same boxes read, different arrays written
        if task == 0:
            _sort_camera(proj, box, 0, order, n_visible)
        else:
            _count_camera(box, 0, tiles_x, tile_counts)


@njit(**_opts)
def fill_lists(box, tiles_x, parallel, order, n_visible, offsets, lists):
    """Fill the per-tile lists (global offsets [B * tiles + 1]) in depth order: ``parallel`` as in
    :func:`bin_cameras` (one camera: two bands of tile rows at once, each walking the whole depth
    order and writing only its own tiles)."""
    n_cam = box.shape[0]
    tiles_y = (offsets.shape[0] - 1) // n_cam // tiles_x
    if not parallel:
        for b in range(n_cam):
            _fill_camera(box, b, tiles_x, order, n_visible, offsets, lists, 0, tiles_y)
    elif n_cam == 1:
        _fill_one_camera_parallel(box, tiles_x, tiles_y, order, n_visible, offsets, lists)
    else:
        _fill_lists_parallel(box, tiles_x, tiles_y, order, n_visible, offsets, lists)


@njit(**_opts)
def bin_and_fill(proj, box, tiles_x, n_tiles, parallel):
    """The whole binning stage in one call, so no Python runs between its parallel regions (a
    region that starts after a pause of 0.1 ms or more waits ~17 us for TBB's workers to wake):
    sort and count (:func:`bin_cameras`), prefix sum, fill (:func:`fill_lists`). Returns
    (offsets [B * n_tiles + 1], lists)."""
    n_cam, n = box.shape[0], box.shape[1]
    order = np.empty((n_cam, n), np.int32)
    n_visible = np.zeros(n_cam, np.int64)
    counts = np.zeros((n_cam, n_tiles), np.int64)
    bin_cameras(proj, box, tiles_x, parallel, order, n_visible, counts)
    offsets = np.zeros(n_cam * n_tiles + 1, np.int64)
    flat = counts.reshape(-1)
    for i in range(flat.shape[0]):
        offsets[i + 1] = offsets[i] + flat[i]
    lists = np.empty(offsets[-1], np.int32)
    fill_lists(box, tiles_x, parallel, order, n_visible, offsets, lists)
    return offsets, lists


@njit(parallel=True, **_opts)
def _fill_lists_parallel(box, tiles_x, tiles_y, order, n_visible, offsets, lists):
    for b in prange(box.shape[0]):
        _fill_camera(box, b, tiles_x, order, n_visible, offsets, lists, 0, tiles_y)


@njit(parallel=True, **_opts)
def _fill_one_camera_parallel(box, tiles_x, tiles_y, order, n_visible, offsets, lists):
    bands = min(ONE_CAMERA_TASKS, tiles_y)
    for band in prange(bands):
        rows = (band * tiles_y // bands, (band + 1) * tiles_y // bands)
        _fill_camera(box, 0, tiles_x, order, n_visible, offsets, lists, rows[0], rows[1])
