from __future__ import annotations

import numpy as np
from numba import njit, prange

from aes_planner.gaussians.kernels.common import (
    BWD_PIXEL_MAJOR_MIN_CHANNELS,
    C_ALPHA_MAX,
    C_ALPHA_MIN,
    C_EXP_CLAMP,
    C_HALF,
    C_ONE,
    C_ONE_MINUS_ALPHA_MIN,
    C_ZERO,
    G_A,
    G_B,
    G_C,
    G_O,
    G_U,
    G_V,
    G_Z,
    _fast,
    _opts,
    exp_neg,
)
from aes_planner.gaussians.kernels.tiles import _interleaved, _row_terms, _row_window, _splat, _tile_origin, _tile_rows
from aes_planner.gaussians.numerics import TILE

# Many channels (pixel-major): the values of the Gaussians behind a pixel enter d loss / d alpha
# only through their dot product with the pixel's output gradient v: the value part of
#   d loss / d alpha_i  is  T_i (c_i . v) - ((sum over j behind i of w_j c_j) . v) / (1 - alpha_i),
# so one scalar per pixel ("behind . v") replaces a buffer of every channel (gsplat keeps the
# channels; equal up to rounding). In both backward kernels the per-tile pixel state sits in one
# array of TILE*TILE sections and the per-lane state in one array of LANE_STRIDE sections, at
# offsets known when compiling, so the lane loops need no run-time alias checks between a dozen
# arrays; rows are the forward's 8-lane windows when the box fits (16 lanes otherwise).
S_TRANS, S_TFIN, S_VTF, S_BD = range(4)  # pixel sections: T, T_final, d/d T_final, behind . v
S_CH = 3  # few channels: v of channel c at section S_CH + 2c, its sum behind at S_CH + 2c + 1
LANE_STRIDE = 2 * TILE
L_FAC, L_T, L_RA, L_VA, L_VS, L_VO = range(6)  # lane sections
A_O, A_A, A_B, A_C, A_U, A_V = range(6, 12)  # lane accumulators of d/d(opacity, A, B, C, u, v)
N_LANE_SECTIONS = 12


@njit(**_fast)
def _lane_sum_at(buf, start):
    """Sum of the TILE lanes buf[start : start + TILE]."""
    s = buf[start]
    for j in range(1, TILE):
        s += buf[start + np.uint64(j)]
    return s


@njit(inline="always", **_fast)
def _bwd_init_trans(pix, npx, one):
    """Transmittances (running and final) start at one."""
    o_trans, o_tfin = np.uint64(S_TRANS * npx), np.uint64(S_TFIN * npx)
    for p in range(npx):
        pix[o_trans + np.uint64(p)] = one
        pix[o_tfin + np.uint64(p)] = one


@njit(inline="always", **_fast)
def _bwd_start_pixel(pix, last_k, p, t_fin, v_tfin, last_p, k_end):
    """A pixel's backward state from its forward: T = T_final, d/d T_final, the list end. Returns the tile's list end so far."""
    npx = TILE * TILE
    pp = np.uint64(p)
    pix[np.uint64(S_TRANS * npx) + pp] = t_fin
    pix[np.uint64(S_TFIN * npx) + pp] = t_fin
    pix[np.uint64(S_VTF * npx) + pp] = v_tfin
    last_k[p] = last_p
    return max(k_end, last_p)


@njit(inline="always", **_fast)
def _bwd_row_alpha(pix, lane, last_k, xs, row, w0, lanes, u, ha, bdy, crow, o, k32, consts):
    """One tile row of the backward, walked back over one Gaussian (inlined into both tile kernels):
    undo its alpha in each pixel's transmittance and set the lanes' terms (its weight alpha T,
    1 / (1 - alpha), T, d/d alpha from T_final, and the d/d sigma, d/d opacity factors when alpha
    was not clamped). Returns how many pixels it hit."""
    zero, one = consts[C_ZERO], consts[C_ONE]
    a_max, a_min, s_clamp = consts[C_ALPHA_MAX], consts[C_ALPHA_MIN], consts[C_EXP_CLAMP]
    one_m = consts[C_ONE_MINUS_ALPHA_MIN]
    npx = TILE * TILE
    o_trans, o_tfin, o_vtf = np.uint64(S_TRANS * npx), np.uint64(S_TFIN * npx), np.uint64(S_VTF * npx)
    ls = np.uint64(LANE_STRIDE)
    o_fac, o_t, o_ra, o_va, o_vs, o_vo = L_FAC * ls, L_T * ls, L_RA * ls, L_VA * ls, L_VS * ls, L_VO * ls
    n_hit = zero
    for j in range(lanes):
        i = np.uint64(j)
        p = row + i
        dx = xs[w0 + i] - u
        sigma = dx * (ha * dx + bdy) + crow
        vis = exp_neg(min(max(sigma, zero), s_clamp))
        ov = o * vis
        alpha = min(ov, a_max)
        m = (k32 < last_k[p]) & (sigma >= zero) & (alpha >= a_min)
        ra = one / max(one_m, one - alpha)
        tr = pix[o_trans + p]
        t = tr * ra
        pix[o_trans + p] = t if m else tr
        lane[o_fac + i] = alpha * t if m else zero
        lane[o_ra + i] = ra
        lane[o_t + i] = t
        lane[o_va + i] = -(pix[o_tfin + p] * ra * pix[o_vtf + p])
        free = m & (ov <= a_max)  # alpha not clamped: it depends on opacity and sigma
        lane[o_vs + i] = -alpha if free else zero
        lane[o_vo + i] = vis if free else zero
        n_hit += one if m else zero
    return n_hit


@njit(inline="always", **_fast)
def _bwd_row_geometry(lane, xs, w0, lanes, u, dy, ca, cb, cc):
    """Accumulate a row's d/d(opacity, conic A, B, C, u, v) lane-wise from the lanes' d/d alpha."""
    ls = np.uint64(LANE_STRIDE)
    o_va, o_vs, o_vo = L_VA * ls, L_VS * ls, L_VO * ls
    o_ao, o_aa, o_ab, o_ac, o_au, o_av = A_O * ls, A_A * ls, A_B * ls, A_C * ls, A_U * ls, A_V * ls
    for j in range(lanes):
        i = np.uint64(j)
        dx = xs[w0 + i] - u
        va = lane[o_va + i]
        vs = lane[o_vs + i] * va
        lane[o_ao + i] += lane[o_vo + i] * va
        lane[o_aa + i] += dx * dx * vs
        lane[o_ab + i] += dx * dy * vs
        lane[o_ac + i] += dy * dy * vs
        lane[o_au + i] -= (ca * dx + cb * dy) * vs
        lane[o_av + i] -= (cb * dx + cc * dy) * vs


@njit(**_fast)
def _bwd_add_geometry(g2d, b, g, lane, half):
    """Reduce the lanes' geometry accumulators of Gaussian g once into g2d[b, g]."""
    ls = np.uint64(LANE_STRIDE)
    g2d[b, g, G_O] += _lane_sum_at(lane, A_O * ls)
    g2d[b, g, G_A] += half * _lane_sum_at(lane, A_A * ls)
    g2d[b, g, G_B] += _lane_sum_at(lane, A_B * ls)
    g2d[b, g, G_C] += half * _lane_sum_at(lane, A_C * ls)
    g2d[b, g, G_U] += _lane_sum_at(lane, A_U * ls)
    g2d[b, g, G_V] += _lane_sum_at(lane, A_V * ls)


@njit(**_fast)
def _bwd_values_pixel_major(v_pix, pix, lane, row, lanes, vals, g, z, g_val, zero, need_values):
    """The value/depth part of a tile row's backward with channels innermost, hit pixels only:
    ``lanes`` pixels from tile pixel ``row``: q = (values, z) . v per pixel, then the lane's d/d alpha term and the pixel's behind . v;
    value gradients into g_val only when ``need_values`` (the depth's always)."""
    cv = vals.shape[1]
    ls = np.uint64(LANE_STRIDE)
    o_bd = np.uint64(S_BD * TILE * TILE)
    for j in range(lanes):
        i = np.uint64(j)
        fac = lane[L_FAC * ls + i]
        if fac == zero:
            continue
        base = (row + i) * np.uint64(cv + 1)
        q = zero
        if need_values:
            for c in range(cv):
                vp = v_pix[base + np.uint64(c)]
                g_val[c] += fac * vp
                q += vals[g, c] * vp
        else:
            for c in range(cv):
                q += vals[g, c] * v_pix[base + np.uint64(c)]
        vz = v_pix[base + np.uint64(cv)]
        g_val[cv] += fac * vz
        q += z * vz
        bd = pix[o_bd + row + i]
        lane[L_VA * ls + i] += q * lane[L_T * ls + i] - bd * lane[L_RA * ls + i]
        pix[o_bd + row + i] = bd + q * fac


@njit(inline="always", **_fast)
def _bwd_values_channel_major(pix, lane, acc_val, row, lanes, vals, g, z):
    """The value/depth part of a tile row's backward with channels outermost and lanes vectorised:
    per channel, the lane sums of d/d value into acc_val [channel, lane], the lanes' d/d alpha
    terms and the pixels' behind sums (a channel's v at S_CH + 2c, its behind sum right after)."""
    npx = np.uint64(TILE * TILE)
    o_fac, o_t = np.uint64(L_FAC * LANE_STRIDE), np.uint64(L_T * LANE_STRIDE)
    o_ra, o_va = np.uint64(L_RA * LANE_STRIDE), np.uint64(L_VA * LANE_STRIDE)
    cv = vals.shape[1]
    for c in range(cv + 1):
        val = vals[g, c] if c < cv else z
        base = np.uint64(S_CH + 2 * c) * npx + row  # v; behind at base + npx
        lane_base = np.uint64(c * TILE)
        # every channel's lane sums, also when only the depth's are used (!need_values): the loop
        # without them is small enough for LLVM to unroll fully instead of vectorising it, and ran
        # 1.4x slower
        for j in range(lanes):
            i = np.uint64(j)
            vp = pix[base + i]
            fac = lane[o_fac + i]
            acc_val[lane_base + i] += fac * vp
            lane[o_va + i] += (val * lane[o_t + i] - pix[base + npx + i] * lane[o_ra + i]) * vp
            pix[base + npx + i] += val * fac


@njit(inline="always", **_fast)
def _bwd_tile(b, tile, splats, image, upstream, g2d, gvals, need_values, many):
    """Reverse traversal of one tile; adds into g2d [B, N, NGRAD] and gvals [N, Cv] (when
    ``need_values``). ``many`` is a compile-time constant (one wrapper kernel per layout, so LLVM
    drops the other branch): with few channels the pixel state holds each channel's v and behind
    sums channel-major and the row loops run over lanes; with many (``cv + 1 >=
    BWD_PIXEL_MAJOR_MIN_CHANNELS``) v is pixel-major and only the hit pixels' channel loops run.

    Per-pixel gradient terms are accumulated lane-wise and reduced once per Gaussian, so the row
    loops have no horizontal reductions. Pixel and lane state are packed into two arrays at
    compile-time offsets, so LLVM needs no run-time overlap checks between them.
    """
    proj, box, vals, offsets, lists = splats
    tiles_x, width, height, consts = image
    t_final, last, v_rgb, v_feat, v_dep, v_t = upstream
    n_tiles = (offsets.shape[0] - 1) // proj.shape[0]
    cv = vals.shape[1]
    dt = consts.dtype
    zero, one, half = consts[C_ZERO], consts[C_ONE], consts[C_HALF]
    tx0, ty0, ys, xs = _tile_origin(tile, tiles_x, consts)
    npx = TILE * TILE
    o_ao = np.uint64(A_O * LANE_STRIDE)
    if many:
        pix = np.zeros(4 * npx, dt)
        v_pix = np.zeros((cv + 1) * npx, dt)  # [pixel, channel]
        acc = np.empty(cv + 1, dt)  # d/d(values, depth) of the current Gaussian
    else:
        pix = np.zeros((S_CH + 2 * (cv + 1)) * npx, dt)
        v_pix = np.zeros(0, dt)  # v lives in pix
        acc = np.empty((cv + 1) * TILE, dt)  # lane sums of d/d(values, depth), [channel, lane]
    lane = np.zeros(N_LANE_SECTIONS * LANE_STRIDE, dt)
    last_k = np.zeros(npx, np.int32)
    _bwd_init_trans(pix, npx, one)
    k_end = 0
    for py in range(min(TILE, height - ty0)):
        for px in range(min(TILE, width - tx0)):
            p = py * TILE + px
            y, x = ty0 + py, tx0 + px
            for c in range(cv + 1):
                if c < 3:
                    vo = v_rgb[b, c, y, x]
                elif c < cv:
                    vo = v_feat[b, c - 3, y, x]
                else:
                    vo = v_dep[b, y, x]
                if many:
                    v_pix[p * (cv + 1) + c] = vo
                else:
                    pix[(S_CH + 2 * c) * npx + p] = vo
            k_end = _bwd_start_pixel(pix, last_k, p, t_final[b, y, x], v_t[b, y, x], last[b, y, x], k_end)
    start = offsets[b * n_tiles + tile]
    for k in range(k_end - 1, start - 1, -1):
        g = lists[k]
        u, v, ca, cb, cc, o, z = _splat(proj, b, g)
        ha, hc = half * ca, half * cc
        k32 = np.int32(k)
        lanes, w0 = _row_window(box, b, g, tx0)
        lane[o_ao:] = zero
        acc[:] = zero
        hit = False
        py0, py1 = _tile_rows(box, b, g, ty0)
        for py in range(py0, py1):
            dy, bdy, crow, row = _row_terms(ys, py, v, cb, hc, w0)
            n_hit = _bwd_row_alpha(pix, lane, last_k, xs, row, w0, lanes, u, ha, bdy, crow, o, k32, consts)
            if n_hit == zero:
                continue
            hit = True
            if many:
                _bwd_values_pixel_major(v_pix, pix, lane, row, lanes, vals, g, z, acc, zero, need_values)
            else:
                _bwd_values_channel_major(pix, lane, acc, row, lanes, vals, g, z)
            _bwd_row_geometry(lane, xs, w0, lanes, u, dy, ca, cb, cc)
        if not hit:
            continue
        _bwd_add_geometry(g2d, b, g, lane, half)
        if many:
            g2d[b, g, G_Z] += acc[cv]
        else:
            g2d[b, g, G_Z] += _lane_sum_at(acc, np.uint64(cv * TILE))
        if need_values:
            for c in range(cv):
                gvals[g, c] += acc[c] if many else _lane_sum_at(acc, np.uint64(c * TILE))


@njit(**_fast)
def _raster_tile_bwd(b, tile, splats, image, upstream, g2d, gvals, need_values):
    """:func:`_bwd_tile` for few channels (channels outermost, lanes vectorised)."""
    _bwd_tile(b, tile, splats, image, upstream, g2d, gvals, need_values, False)


@njit(**_fast)
def _raster_tile_bwd_many(b, tile, splats, image, upstream, g2d, gvals, need_values):
    """:func:`_bwd_tile` for many channels (pixel-major v, the hit pixels' channel loops)."""
    _bwd_tile(b, tile, splats, image, upstream, g2d, gvals, need_values, True)


@njit(parallel=True, **_opts)
def raster_bwd(
    proj,
    box,
    vals,
    offsets,
    lists,
    tiles_x,
    width,
    height,
    consts,
    t_final,
    last,
    v_rgb,
    v_feat,
    v_dep,
    v_t,
    by_camera,
    threads,
    g2d,
    gvals,
    need_values,
):
    """g2d [nbuf, B, N, NGRAD] (nbuf = 1 when by_camera else threads), gvals [threads, N, Cv]
    (left at zero unless ``need_values``)."""
    n_cam = proj.shape[0]
    n_tiles = (offsets.shape[0] - 1) // n_cam
    n_items = n_cam if by_camera else n_cam * n_tiles
    many = vals.shape[1] + 1 >= BWD_PIXEL_MAJOR_MIN_CHANNELS
    splats = (proj, box, vals, offsets, lists)
    image = (tiles_x, width, height, consts)
    upstream = (t_final, last, v_rgb, v_feat, v_dep, v_t)
    # Items interleaved over the workers as in the forward (``_interleaved``: worker w's share is
    # its chunk of prange's items); worker w's value gradients, and by tile its g2d, go to buffer
    # w, not to the running thread's: which thread runs which worker's items varies from call to
    # call, and with it the order of the sums.
    per = -(-n_items // threads)
    for worker in prange(threads):
        w = np.int64(worker)  # prange's index can be unsigned: int64 keeps the mixed arithmetic integral
        for j in range(per):
            real = _interleaved(w * per + j, n_items, threads)
            if real < 0:
                break
            # by camera: one item is a whole camera (all its tiles on this worker, so one shared
            # g2d buffer is race-free); by tile: one item is one tile, into this worker's buffer
            cam = real if by_camera else real // n_tiles
            first = 0 if by_camera else real % n_tiles
            stop = n_tiles if by_camera else first + 1
            buf = 0 if by_camera else w
            for tile in range(first, stop):
                if many:
                    _raster_tile_bwd_many(cam, tile, splats, image, upstream, g2d[buf], gvals[w], need_values)
                else:
                    _raster_tile_bwd(cam, tile, splats, image, upstream, g2d[buf], gvals[w], need_values)
