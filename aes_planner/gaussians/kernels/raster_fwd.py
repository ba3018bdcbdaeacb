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
from aes_planner.gaussians.kernels.tiles import (
    NPX,
    _fill_centres,
    _interleaved,
    _run_row_terms,
    _splat,
    _tile_run,
    _tile_xy,
)
from aes_planner.gaussians.numerics import TILE

# The tile's state: sections of NPX values in one array, at offsets fixed when compiling (no
# run-time overlap checks between them): pixel centres x and y, transmittance (> 0 while
# compositing, -T once done), the current Gaussian's weights alpha T, its row terms.
F_X, F_Y, F_T, F_W, F_BDY, F_CROW = (np.uint64(s * NPX) for s in range(6))
N_F_SECTIONS = 6


@njit(**_fast)
def _tile_active(st, consts):
    """Number of tile pixels still compositing (transmittance > 0)."""
    n = consts[C_ZERO]
    for j in range(NPX):
        n += consts[C_ONE] if st[F_T + np.uint64(j)] > consts[C_ZERO] else consts[C_ZERO]
    return n


@njit(**_fast)
def _add_pixel_major(acc, st, p0, p1, vals, g, z, zero):
    """acc[pixel, :] += w * (values of g, z) for the contributing pixels of the run [p0, p1)."""
    cv = vals.shape[1]
    for j in range(p1 - p0):
        p = p0 + np.uint64(j)
        w = st[F_W + p]
        if w != zero:
            base = p * np.uint64(cv + 1)
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
    tx0, ty0 = _tile_xy(tile, tiles_x)
    st = np.empty(N_F_SECTIONS * NPX, consts.dtype)
    # [channel, pixel] (pixels vectorised) for few channels; [pixel, channel] (channels vectorised,
    # only contributing pixels visited) for many
    pixel_major = cv + 1 >= FWD_PIXEL_MAJOR_MIN_CHANNELS
    acc = np.zeros((cv + 1) * NPX, consts.dtype)
    last_k = np.zeros(NPX, np.int32)
    _fill_centres(st, F_X, F_Y, tx0, ty0, consts)
    for py in range(TILE):
        for px in range(TILE):
            inside = ty0 + py < height and tx0 + px < width
            st[F_T + np.uint64(py * TILE + px)] = one if inside else -one
    start = offsets[b * n_tiles + tile]
    end = offsets[b * n_tiles + tile + 1]
    for k in range(start, end):
        if (k - start) % DONE_CHECK_EVERY == DONE_CHECK_EVERY - 1 and _tile_active(st, consts) == zero:
            break
        g = lists[k]
        u, v, ca, cb, cc, o, z = _splat(proj, b, g)
        ha, hc = half * ca, half * cc
        k_next = np.int32(k + 1)
        p0, p1 = _tile_run(box, b, g, ty0)
        _run_row_terms(st, F_Y, F_BDY, F_CROW, p0, p1, v, cb, hc)
        w_sum = zero  # a float reduction: an int64 one would halve the vector width
        for j in range(p1 - p0):
            p = p0 + np.uint64(j)
            dx = st[F_X + p] - u
            sigma = dx * (ha * dx + st[F_BDY + p]) + st[F_CROW + p]
            alpha = min(o * exp_neg(min(max(sigma, zero), s_clamp)), a_max)
            t = st[F_T + p]
            ok = (sigma >= zero) & (alpha >= a_min) & (t > zero)
            t_next = t * (one - alpha)
            stop = ok & (t_next <= t_stop)
            contrib = ok & (t_next > t_stop)
            w = alpha * t if contrib else zero
            st[F_W + p] = w
            st[F_T + p] = -t if stop else (t_next if contrib else t)
            last_k[p] = k_next if contrib else last_k[p]
            w_sum += w
        if w_sum > zero:
            if pixel_major:
                _add_pixel_major(acc, st, p0, p1, vals, g, z, zero)
            else:
                for c in range(cv + 1):
                    val = vals[g, c] if c < cv else z
                    base = np.uint64(c * NPX)
                    for j in range(p1 - p0):
                        p = p0 + np.uint64(j)
                        acc[base + p] += st[F_W + p] * val
    _write_tile(b, tx0, ty0, width, height, cv, pixel_major, acc, st, last_k, rgb, feat, dep, t_final, last)


@njit(inline="always", **_fast)
def _write_tile(b, tx0, ty0, width, height, cv, pixel_major, acc, st, last_k, rgb, feat, dep, t_final, last):
    """The tile's accumulated maps into the outputs: channels outermost, each output row a
    contiguous run at unsigned flat indices (signed ones carry numba's negative-index wraparound
    and were not vectorised: ~3 us of every tile)."""
    rows, cols = min(TILE, height - ty0), min(TILE, width - tx0)
    hw = height * width
    for c in range(cv + 1):
        if c < 3:
            out, base = rgb.reshape(-1), (b * 3 + c) * hw
        elif c < cv:
            out, base = feat.reshape(-1), (b * (cv - 3) + c - 3) * hw
        else:
            out, base = dep.reshape(-1), b * hw
        for py in range(rows):
            dst = np.uint64(base + (ty0 + py) * width + tx0)
            if pixel_major:
                for px in range(cols):
                    out[dst + np.uint64(px)] = acc[(py * TILE + px) * (cv + 1) + c]
            else:
                src = np.uint64(c * NPX + py * TILE)
                for px in range(cols):
                    out[dst + np.uint64(px)] = acc[src + np.uint64(px)]
    t_out, l_out = t_final.reshape(-1), last.reshape(-1)
    for py in range(rows):
        dst = np.uint64(b * hw + (ty0 + py) * width + tx0)
        src = np.uint64(py * TILE)
        for px in range(cols):
            t_out[dst + np.uint64(px)] = abs(st[F_T + src + np.uint64(px)])
            l_out[dst + np.uint64(px)] = last_k[src + np.uint64(px)]


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
