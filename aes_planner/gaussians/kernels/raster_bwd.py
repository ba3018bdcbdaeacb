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

# Many channels (pixel-major): the values of the Gaussians behind a pixel enter d loss / d alpha
# only through their dot product with the pixel's output gradient v: the value part of
#   d loss / d alpha_i  is  T_i (c_i . v) - ((sum over j behind i of w_j c_j) . v) / (1 - alpha_i),
# so one scalar per pixel ("behind . v") replaces a buffer of every channel (gsplat keeps the
# channels; equal up to rounding). A tile's pixel state sits in one array of NPX sections and the
# current Gaussian's per-pixel terms in another, at offsets known when compiling, so the run loops
# need no run-time alias checks between a dozen arrays. Each Gaussian is walked as the one run of
# tile pixels its box rows cover (tiles.py), its gradient terms reduced over the run.
S_TRANS, S_TFIN, S_VTF, S_BD = range(4)  # pixel sections: T, T_final, d/d T_final, behind . v
S_CH = 3  # few channels: v of channel c at section S_CH + 2c, its sum behind at S_CH + 2c + 1
O_TRANS, O_TFIN, O_VTF, O_BD = (np.uint64(s * NPX) for s in range(4))
# the current Gaussian's per-pixel terms (and the tile's pixel centres): its weight alpha T, T,
# 1 / (1 - alpha), d/d alpha, the d/d sigma and d/d opacity factors
L_X, L_Y, L_BDY, L_CROW, L_FAC, L_T, L_RA, L_VA, L_VS, L_VO = (np.uint64(s * NPX) for s in range(10))
N_L_SECTIONS = 10


@njit(inline="always", **_fast)
def _bwd_run_alpha(pix, sc, last_k, p0, p1, u, ha, o, k32, consts):
    """The run of a Gaussian, walked back: undo its alpha in each pixel's transmittance and set
    the pixels' terms (its weight alpha T, 1 / (1 - alpha), T, d/d alpha from T_final, and the
    d/d sigma, d/d opacity factors when alpha was not clamped). Returns how many pixels it hit."""
    zero, one = consts[C_ZERO], consts[C_ONE]
    a_max, a_min, s_clamp = consts[C_ALPHA_MAX], consts[C_ALPHA_MIN], consts[C_EXP_CLAMP]
    one_m = consts[C_ONE_MINUS_ALPHA_MIN]
    n_hit = zero
    for j in range(p1 - p0):
        p = p0 + np.uint64(j)
        dx = sc[L_X + p] - u
        sigma = dx * (ha * dx + sc[L_BDY + p]) + sc[L_CROW + p]
        vis = exp_neg(min(max(sigma, zero), s_clamp))
        ov = o * vis
        alpha = min(ov, a_max)
        m = (k32 < last_k[p]) & (sigma >= zero) & (alpha >= a_min)
        ra = one / max(one_m, one - alpha)
        tr = pix[O_TRANS + p]
        t = tr * ra
        pix[O_TRANS + p] = t if m else tr
        sc[L_FAC + p] = alpha * t if m else zero
        sc[L_RA + p] = ra
        sc[L_T + p] = t
        sc[L_VA + p] = -(pix[O_TFIN + p] * ra * pix[O_VTF + p])
        free = m & (ov <= a_max)  # alpha not clamped: it depends on opacity and sigma
        sc[L_VS + p] = -alpha if free else zero
        sc[L_VO + p] = vis if free else zero
        n_hit += one if m else zero
    return n_hit


@njit(**_fast)
def _bwd_run_geometry(g2d, b, g, sc, p0, p1, u, v, ca, cb, cc, half, zero):
    """Reduce the run's d/d(opacity, conic A, B, C, u, v) from the pixels' d/d alpha into g2d[b, g]."""
    s_o = s_a = s_b = s_c = s_u = s_v = zero
    for j in range(p1 - p0):
        p = p0 + np.uint64(j)
        dx = sc[L_X + p] - u
        dy = sc[L_Y + p] - v
        va = sc[L_VA + p]
        vs = sc[L_VS + p] * va
        s_o += sc[L_VO + p] * va
        s_a += dx * dx * vs
        s_b += dx * dy * vs
        s_c += dy * dy * vs
        s_u -= (ca * dx + cb * dy) * vs
        s_v -= (cb * dx + cc * dy) * vs
    g2d[b, g, G_O] += s_o
    g2d[b, g, G_A] += half * s_a
    g2d[b, g, G_B] += s_b
    g2d[b, g, G_C] += half * s_c
    g2d[b, g, G_U] += s_u
    g2d[b, g, G_V] += s_v


@njit(**_fast)
def _bwd_values_pixel_major(v_pix, pix, sc, p0, p1, vals, g, z, g_val, zero, need_values):
    """The value/depth part of a run's backward with channels innermost, hit pixels only: q =
    (values, z) . v per pixel, then the pixel's d/d alpha term and its behind . v; value
    gradients into g_val only when ``need_values`` (the depth's always)."""
    cv = vals.shape[1]
    for j in range(p1 - p0):
        p = p0 + np.uint64(j)
        fac = sc[L_FAC + p]
        if fac == zero:
            continue
        base = p * np.uint64(cv + 1)
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
        bd = pix[O_BD + p]
        sc[L_VA + p] += q * sc[L_T + p] - bd * sc[L_RA + p]
        pix[O_BD + p] = bd + q * fac


@njit(inline="always", **_fast)
def _bwd_values_channel_major(pix, sc, g_val, p0, p1, vals, g, z, zero):
    """The value/depth part of a run's backward with channels outermost and pixels vectorised:
    per channel, the run's sum of d/d value into g_val[channel], the pixels' d/d alpha terms and
    their behind sums (a channel's v at section S_CH + 2c, its behind sum right after)."""
    cv = vals.shape[1]
    for c in range(cv + 1):
        val = vals[g, c] if c < cv else z
        base = np.uint64((S_CH + 2 * c) * NPX)  # v; behind at base + NPX
        s = zero
        for j in range(p1 - p0):
            p = p0 + np.uint64(j)
            vp = pix[base + p]
            fac = sc[L_FAC + p]
            s += fac * vp
            sc[L_VA + p] += (val * sc[L_T + p] - pix[base + np.uint64(NPX) + p] * sc[L_RA + p]) * vp
            pix[base + np.uint64(NPX) + p] += val * fac
        g_val[c] = s


@njit(inline="always", **_fast)
def _read_tile(b, tx0, ty0, width, height, cv, many, pix, v_pix, last_k, upstream):
    """The tile's upstream gradients and forward state into its pixel state (v channel-major in
    pix for few channels, pixel-major in v_pix for many), channels outermost, each input row a
    contiguous run at unsigned flat indices (as the forward's _write_tile). Returns the tile's
    list end (the largest last)."""
    t_final, last, v_rgb, v_feat, v_dep, v_t = upstream
    rows, cols = min(TILE, height - ty0), min(TILE, width - tx0)
    hw = height * width
    for c in range(cv + 1):
        if c < 3:
            src_arr, base = v_rgb.reshape(-1), (b * 3 + c) * hw
        elif c < cv:
            src_arr, base = v_feat.reshape(-1), (b * (cv - 3) + c - 3) * hw
        else:
            src_arr, base = v_dep.reshape(-1), b * hw
        for py in range(rows):
            src = np.uint64(base + (ty0 + py) * width + tx0)
            if many:
                for px in range(cols):
                    v_pix[np.uint64((py * TILE + px) * (cv + 1) + c)] = src_arr[src + np.uint64(px)]
            else:
                dst = np.uint64((S_CH + 2 * c) * NPX + py * TILE)
                for px in range(cols):
                    pix[dst + np.uint64(px)] = src_arr[src + np.uint64(px)]
    t_in, l_in, vt_in = t_final.reshape(-1), last.reshape(-1), v_t.reshape(-1)
    k_end = np.int32(0)
    for py in range(rows):
        src = np.uint64(b * hw + (ty0 + py) * width + tx0)
        dst = np.uint64(py * TILE)
        for px in range(cols):
            t_fin = t_in[src + np.uint64(px)]
            pix[O_TRANS + dst + np.uint64(px)] = t_fin
            pix[O_TFIN + dst + np.uint64(px)] = t_fin
            pix[O_VTF + dst + np.uint64(px)] = vt_in[src + np.uint64(px)]
            last_k[dst + np.uint64(px)] = l_in[src + np.uint64(px)]
            k_end = max(k_end, l_in[src + np.uint64(px)])
    return k_end


@njit(inline="always", **_fast)
def _bwd_tile(b, tile, splats, image, upstream, g2d, gvals, need_values, many):
    """Reverse traversal of one tile; adds into g2d [B, N, NGRAD] and gvals [N, Cv] (when
    ``need_values``). ``many`` is a compile-time constant (one wrapper kernel per layout, so LLVM
    drops the other branch): with few channels the pixel state holds each channel's v and behind
    sums channel-major and the run loops vectorise over pixels; with many (``cv + 1 >=
    BWD_PIXEL_MAJOR_MIN_CHANNELS``) v is pixel-major and only the hit pixels' channel loops run.
    """
    proj, box, vals, offsets, lists = splats
    tiles_x, width, height, consts = image
    n_tiles = (offsets.shape[0] - 1) // proj.shape[0]
    cv = vals.shape[1]
    dt = consts.dtype
    zero, one, half = consts[C_ZERO], consts[C_ONE], consts[C_HALF]
    tx0, ty0 = _tile_xy(tile, tiles_x)
    if many:
        pix = np.zeros(4 * NPX, dt)
        v_pix = np.zeros((cv + 1) * NPX, dt)  # [pixel, channel]
    else:
        pix = np.zeros((S_CH + 2 * (cv + 1)) * NPX, dt)
        v_pix = np.zeros(0, dt)  # v lives in pix
    acc = np.empty(cv + 1, dt)  # d/d(values, depth) of the current Gaussian
    sc = np.empty(N_L_SECTIONS * NPX, dt)
    last_k = np.zeros(NPX, np.int32)
    _fill_centres(sc, L_X, L_Y, tx0, ty0, consts)
    pix[: 2 * NPX] = one  # T and T_final (sections S_TRANS, S_TFIN) outside the image
    k_end = _read_tile(b, tx0, ty0, width, height, cv, many, pix, v_pix, last_k, upstream)
    start = offsets[b * n_tiles + tile]
    for k in range(k_end - 1, start - 1, -1):
        g = lists[k]
        u, v, ca, cb, cc, o, z = _splat(proj, b, g)
        ha, hc = half * ca, half * cc
        p0, p1 = _tile_run(box, b, g, ty0)
        _run_row_terms(sc, L_Y, L_BDY, L_CROW, p0, p1, v, cb, hc)
        if _bwd_run_alpha(pix, sc, last_k, p0, p1, u, ha, o, np.int32(k), consts) == zero:
            continue
        if many:
            acc[:] = zero
            _bwd_values_pixel_major(v_pix, pix, sc, p0, p1, vals, g, z, acc, zero, need_values)
        else:
            _bwd_values_channel_major(pix, sc, acc, p0, p1, vals, g, z, zero)
        _bwd_run_geometry(g2d, b, g, sc, p0, p1, u, v, ca, cb, cc, half, zero)
        g2d[b, g, G_Z] += acc[cv]
        if need_values:
            for c in range(cv):
                gvals[g, c] += acc[c]


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
