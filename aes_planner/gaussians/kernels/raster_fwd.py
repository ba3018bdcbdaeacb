from __future__ import annotations

import numpy as np
from numba import njit, prange

from aes_planner.gaussians.kernels.common import (
    C_ALPHA_MAX,
    C_ALPHA_MIN,
    C_EXP_CLAMP,
    C_HALF,
    C_ONE,
    C_T_STOP,
    C_ZERO,
    DONE_CHECK_EVERY,
    FWD_PIXEL_MAJOR_MIN_CHANNELS,
    _fast,
    _opts,
    exp_neg,
)
from aes_planner.gaussians.kernels.tiles import _interleaved, _row_terms, _row_window, _splat, _tile_origin, _tile_rows
from aes_planner.gaussians.numerics import TILE


@njit(**_fast)
def _tile_active(trans, consts):
    """Number of tile pixels still compositing (trans > 0)."""
    n = consts[C_ZERO]
    for j in range(TILE * TILE):
        n += consts[C_ONE] if trans[np.uint64(j)] > consts[C_ZERO] else consts[C_ZERO]
    return n


@njit(**_fast)
def _add_pixel_major(acc, start, lanes, wbuf, vals, g, z, zero):
    """acc[pixel, :] += w * (values of g, z) for the contributing pixels of a tile row's window:
    ``lanes`` pixels from tile pixel ``start`` (wbuf holds the window)."""
    cv = vals.shape[1]
    for j in range(lanes):
        w = wbuf[j]
        if w != zero:
            base = (start + np.uint64(j)) * np.uint64(cv + 1)
            for c in range(cv):
                acc[base + np.uint64(c)] += w * vals[g, c]
            acc[base + np.uint64(cv)] += w * z


@njit(**_fast)
def _raster_tile_fwd(
    b, tile, proj, box, vals, offsets, lists, tiles_x, width, height, consts, rgb, feat, dep, t_final, last
):
    n_tiles = (offsets.shape[0] - 1) // proj.shape[0]
    cv = vals.shape[1]
    zero, one, half = consts[C_ZERO], consts[C_ONE], consts[C_HALF]
    a_max, a_min, t_stop, s_clamp = consts[C_ALPHA_MAX], consts[C_ALPHA_MIN], consts[C_T_STOP], consts[C_EXP_CLAMP]
    tx0, ty0, ys, xs = _tile_origin(tile, tiles_x, consts)
    trans = np.empty(TILE * TILE, consts.dtype)  # > 0 while compositing, -T once done
    # [channel, pixel] (lanes vectorised) for few channels; [pixel, channel] (channels vectorised,
    # only contributing pixels visited) for many
    pixel_major = cv + 1 >= FWD_PIXEL_MAJOR_MIN_CHANNELS
    acc = np.zeros((cv + 1) * TILE * TILE, consts.dtype)
    last_k = np.zeros(TILE * TILE, np.int32)
    wbuf = np.empty(TILE, consts.dtype)
    for py in range(TILE):
        for px in range(TILE):
            inside = ty0 + py < height and tx0 + px < width
            trans[py * TILE + px] = one if inside else -one
    start = offsets[b * n_tiles + tile]
    end = offsets[b * n_tiles + tile + 1]
    for k in range(start, end):
        if (k - start) % DONE_CHECK_EVERY == DONE_CHECK_EVERY - 1 and _tile_active(trans, consts) == zero:
            break
        g = lists[k]
        u, v, ca, cb, cc, o, z = _splat(proj, b, g)
        ha, hc = half * ca, half * cc
        k_next = np.int32(k + 1)
        lanes, w0 = _row_window(box, b, g, tx0)
        py0, py1 = _tile_rows(box, b, g, ty0)
        for py in range(py0, py1):
            dy, bdy, crow, row = _row_terms(ys, py, v, cb, hc, w0)
            w_sum = zero  # a float reduction: an int64 one would halve the vector width
            for j in range(lanes):
                i = np.uint64(j)
                dx = xs[w0 + i] - u
                sigma = dx * (ha * dx + bdy) + crow
                alpha = min(o * exp_neg(min(max(sigma, zero), s_clamp)), a_max)
                t = trans[row + i]
                ok = (sigma >= zero) & (alpha >= a_min) & (t > zero)
                t_next = t * (one - alpha)
                stop = ok & (t_next <= t_stop)
                contrib = ok & (t_next > t_stop)
                w = alpha * t if contrib else zero
                wbuf[i] = w
                trans[row + i] = -t if stop else (t_next if contrib else t)
                last_k[row + i] = k_next if contrib else last_k[row + i]
                w_sum += w
            if w_sum > zero:
                if pixel_major:
                    _add_pixel_major(acc, row, lanes, wbuf, vals, g, z, zero)
                else:
                    for c in range(cv + 1):
                        val = vals[g, c] if c < cv else z
                        base = np.uint64(c * TILE * TILE) + row
                        for j in range(lanes):
                            i = np.uint64(j)
                            acc[base + i] += wbuf[i] * val
    for py in range(min(TILE, height - ty0)):
        for px in range(min(TILE, width - tx0)):
            p = py * TILE + px
            for c in range(cv + 1):
                val = acc[p * (cv + 1) + c] if pixel_major else acc[c * TILE * TILE + p]
                if c < 3:
                    rgb[b, c, ty0 + py, tx0 + px] = val
                elif c < cv:
                    feat[b, c - 3, ty0 + py, tx0 + px] = val
                else:
                    dep[b, ty0 + py, tx0 + px] = val
            t_final[b, ty0 + py, tx0 + px] = abs(trans[p])
            last[b, ty0 + py, tx0 + px] = last_k[p]


@njit(parallel=True, **_opts)
def raster_fwd(proj, box, vals, offsets, lists, tiles_x, width, height, consts, threads, rgb, feat, dep, t_final, last):
    """rgb [B, 3, H, W], feat [B, C, H, W], dep [B, H, W] (un-normalised depth), t_final [B, H, W],
    last [B, H, W]."""
    n_cam = proj.shape[0]
    n_tiles = (offsets.shape[0] - 1) // n_cam
    n_items = n_cam * n_tiles
    for item in prange(threads * -(-n_items // threads)):
        real = _interleaved(item, n_items, threads)
        if real >= 0:
            _raster_tile_fwd(
                real // n_tiles,
                real % n_tiles,
                proj,
                box,
                vals,
                offsets,
                lists,
                tiles_x,
                width,
                height,
                consts,
                rgb,
                feat,
                dep,
                t_final,
                last,
            )
