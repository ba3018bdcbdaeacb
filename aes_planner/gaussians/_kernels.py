"""Compiled CPU kernels of the rasterizer (numba, ``cache=True``). Imported only when used.

Pipeline per call (B cameras, N Gaussians, Cv = 3 + C value channels, tiles of TILE x TILE px):

1. ``covariance_fwd``: per Gaussian, the world covariance (float64, shared by all cameras).
2. ``project_fwd``: per (camera, Gaussian), EWA projection in float64 -> packed image-space
   parameters and the pixel box of the ``alpha >= 1/255`` ellipse (empty box = culled).
3. ``bin_count`` / ``bin_fill``: per camera, a stable radix sort of the visible Gaussians by depth,
   then per-tile lists in that order (counting pass, prefix sum, fill): no per-tile sorts.
4. ``raster_fwd``: parallel over (camera, tile). Each Gaussian of the tile's list visits only the
   pixels of its ellipse, row by row (exact span per row), compositing front to back into tile
   buffers; a tile stops when all its pixels are saturated. Stores the final transmittance and
   the list position after each pixel's last contributor.
5. ``raster_bwd``: the same traversal in reverse from the stored final transmittance (gsplat's
   backward), accumulating per (camera, Gaussian) image-space gradients and per-Gaussian value
   gradients. Parallel over cameras when there are enough of them (no write conflicts), else over
   tiles with per-thread buffers.
6. ``project_bwd``: per Gaussian, the chain rule through projection and covariance for every
   camera; camera-pose gradients go to per-thread buffers.

Everything geometric is float64; image-space parameters and outputs are in the Gaussians' dtype.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from aes_planner.gaussians.numerics import (
    ALPHA_MAX,
    ALPHA_MIN,
    BLUR_PX2,
    DET_MIN,
    FAR_M,
    FRUSTUM_SLACK,
    LOG_INV_ALPHA_MIN,
    NEAR_M,
    ONE_MINUS_ALPHA_MIN,
    T_STOP,
)

TILE = 16
# Packed image-space parameters per (camera, Gaussian).
P_U, P_V, P_A, P_B, P_C, P_O, P_Z, P_LEVEL, P_HALF_INV_SYY, P_TWO_OVER_A = range(10)
NPROJ = 10
# Image-space gradients per (camera, Gaussian): mean2d, conic, opacity, depth.
G_U, G_V, G_A, G_B, G_C, G_O, G_Z = range(7)
NGRAD = 7
SPAN_MARGIN_PX = 1e-2  # widen the exact row span; the per-pixel alpha test decides

_opts = dict(cache=True, error_model="numpy")


# ---------------------------------------------------------------------------- small algebra
@njit(**_opts)
def _quat_rotation(qw, qx, qy, qz):
    """Normalised rotation (9-tuple, row-major) and 1/|q| (0 for a zero quaternion = identity)."""
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    if n2 < 1e-24:
        return (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), 0.0, 1.0, 0.0, 0.0, 0.0
    inv = 1.0 / math.sqrt(n2)
    w, x, y, z = qw * inv, qx * inv, qy * inv, qz * inv
    r = (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )
    return r, inv, w, x, y, z


@njit(**_opts)
def _mm(a, b):
    """3x3 @ 3x3 for row-major 9-tuples."""
    return (
        a[0] * b[0] + a[1] * b[3] + a[2] * b[6], a[0] * b[1] + a[1] * b[4] + a[2] * b[7], a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
        a[3] * b[0] + a[4] * b[3] + a[5] * b[6], a[3] * b[1] + a[4] * b[4] + a[5] * b[7], a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
        a[6] * b[0] + a[7] * b[3] + a[8] * b[6], a[6] * b[1] + a[7] * b[4] + a[8] * b[7], a[6] * b[2] + a[7] * b[5] + a[8] * b[8],
    )


@njit(**_opts)
def _t(a):
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


@njit(**_opts)
def _sym(c):
    """Symmetric 9-tuple from (xx, xy, xz, yy, yz, zz)."""
    return (c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5])


# ---------------------------------------------------------------------------- 1. covariance
@njit(parallel=True, **_opts)
def covariance_fwd(quats, log_scales, cov):  # [N, 4], [N, 3] -> cov [N, 6] float64
    for n in prange(quats.shape[0]):
        r, _, _, _, _, _ = _quat_rotation(
            np.float64(quats[n, 0]), np.float64(quats[n, 1]), np.float64(quats[n, 2]), np.float64(quats[n, 3])
        )
        s0 = math.exp(np.float64(log_scales[n, 0]))
        s1 = math.exp(np.float64(log_scales[n, 1]))
        s2 = math.exp(np.float64(log_scales[n, 2]))
        m = (r[0] * s0, r[1] * s1, r[2] * s2, r[3] * s0, r[4] * s1, r[5] * s2, r[6] * s0, r[7] * s1, r[8] * s2)
        cov[n, 0] = m[0] * m[0] + m[1] * m[1] + m[2] * m[2]
        cov[n, 1] = m[0] * m[3] + m[1] * m[4] + m[2] * m[5]
        cov[n, 2] = m[0] * m[6] + m[1] * m[7] + m[2] * m[8]
        cov[n, 3] = m[3] * m[3] + m[4] * m[4] + m[5] * m[5]
        cov[n, 4] = m[3] * m[6] + m[4] * m[7] + m[5] * m[8]
        cov[n, 5] = m[6] * m[6] + m[7] * m[7] + m[8] * m[8]


# ---------------------------------------------------------------------------- 2. projection
@njit(**_opts)
def _camera(world2cam, K, b, width, height):
    w = (
        world2cam[b, 0, 0], world2cam[b, 0, 1], world2cam[b, 0, 2],
        world2cam[b, 1, 0], world2cam[b, 1, 1], world2cam[b, 1, 2],
        world2cam[b, 2, 0], world2cam[b, 2, 1], world2cam[b, 2, 2],
    )
    t = (world2cam[b, 0, 3], world2cam[b, 1, 3], world2cam[b, 2, 3])
    fx, fy, cx, cy = K[b, 0, 0], K[b, 1, 1], K[b, 0, 2], K[b, 1, 2]
    lim_xp = (width - cx) / fx + FRUSTUM_SLACK * 0.5 * width / fx
    lim_xn = cx / fx + FRUSTUM_SLACK * 0.5 * width / fx
    lim_yp = (height - cy) / fy + FRUSTUM_SLACK * 0.5 * height / fy
    lim_yn = cy / fy + FRUSTUM_SLACK * 0.5 * height / fy
    return w, t, fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn


@njit(**_opts)
def _clamp_ratio(r, lo, hi):
    """(clamped ratio, 0 if inside the limits else 1)."""
    if r < lo:
        return lo, 1
    if r > hi:
        return hi, 1
    return r, 0


@njit(**_opts)
def _cov2d(j00, j02, j11, j12, s):
    """J S J^T for J = [[j00, 0, j02], [0, j11, j12]], S a symmetric 9-tuple: (a, b, c)."""
    a = j00 * j00 * s[0] + 2 * j00 * j02 * s[2] + j02 * j02 * s[8]
    b = j00 * j11 * s[1] + j00 * j12 * s[2] + j02 * j11 * s[5] + j02 * j12 * s[8]
    c = j11 * j11 * s[4] + 2 * j11 * j12 * s[5] + j12 * j12 * s[8]
    return a, b, c


@njit(parallel=True, **_opts)
def project_fwd(means, cov, opacities, world2cam, K, width, height, proj, box):
    """proj [B, N, NPROJ] (Gaussians' dtype), box [B, N, 4] int32 (x0, x1, y0, y1; x0 > x1 = culled)."""
    n_cam = world2cam.shape[0]
    for n in prange(means.shape[0]):
        m0, m1, m2 = np.float64(means[n, 0]), np.float64(means[n, 1]), np.float64(means[n, 2])
        sig = _sym((cov[n, 0], cov[n, 1], cov[n, 2], cov[n, 3], cov[n, 4], cov[n, 5]))
        o = np.float64(opacities[n])
        level = math.log(max(o, 1e-30)) + LOG_INV_ALPHA_MIN
        for b in range(n_cam):
            box[b, n, 0] = 1
            box[b, n, 1] = 0
            if not (o >= ALPHA_MIN):
                continue
            w, t, fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn = _camera(world2cam, K, b, width, height)
            x = w[0] * m0 + w[1] * m1 + w[2] * m2 + t[0]
            y = w[3] * m0 + w[4] * m1 + w[5] * m2 + t[1]
            z = w[6] * m0 + w[7] * m1 + w[8] * m2 + t[2]
            if not (z > NEAR_M and z < FAR_M):
                continue
            u = fx * x / z + cx
            v = fy * y / z + cy
            rx, _ = _clamp_ratio(x / z, -lim_xn, lim_xp)
            ry, _ = _clamp_ratio(y / z, -lim_yn, lim_yp)
            j00, j11 = fx / z, fy / z
            j02, j12 = -fx * rx / z, -fy * ry / z
            s = _mm(_mm(w, sig), _t(w))
            a, bb, c = _cov2d(j00, j02, j11, j12, s)
            a += BLUR_PX2
            c += BLUR_PX2
            det = max(a * c - bb * bb, DET_MIN)
            ext_x = math.sqrt(2.0 * level * a)
            ext_y = math.sqrt(2.0 * level * c)
            # Pixel i (centre i + 0.5) is touched if |i + 0.5 - u| <= ext: i in [u - ext - 0.5, u + ext - 0.5].
            fx0 = min(max(u - ext_x - 0.5 - SPAN_MARGIN_PX, -1.0), width + 1.0)
            fx1 = min(max(u + ext_x - 0.5 + SPAN_MARGIN_PX, -1.0), width + 1.0)
            fy0 = min(max(v - ext_y - 0.5 - SPAN_MARGIN_PX, -1.0), height + 1.0)
            fy1 = min(max(v + ext_y - 0.5 + SPAN_MARGIN_PX, -1.0), height + 1.0)
            if not (fx0 <= fx1 and fy0 <= fy1 and math.isfinite(a) and math.isfinite(c) and math.isfinite(bb)):
                continue
            ix0 = max(int(math.ceil(fx0)), 0)
            ix1 = min(int(math.floor(fx1)), width - 1)
            iy0 = max(int(math.ceil(fy0)), 0)
            iy1 = min(int(math.floor(fy1)), height - 1)
            if ix0 > ix1 or iy0 > iy1:
                continue
            box[b, n, 0] = ix0
            box[b, n, 1] = ix1
            box[b, n, 2] = iy0
            box[b, n, 3] = iy1
            ca = c / det
            proj[b, n, P_U] = u
            proj[b, n, P_V] = v
            proj[b, n, P_A] = ca
            proj[b, n, P_B] = -bb / det
            proj[b, n, P_C] = a / det
            proj[b, n, P_O] = o
            proj[b, n, P_Z] = z
            proj[b, n, P_LEVEL] = level
            proj[b, n, P_HALF_INV_SYY] = 0.5 / c
            proj[b, n, P_TWO_OVER_A] = 2.0 / ca


# ---------------------------------------------------------------------------- 3. binning
@njit(**_opts)
def _radix_argsort(keys, idx, tmp_keys, tmp_idx):
    """Stable LSD radix sort of int64 keys < 2**33 (float32 bit patterns), carrying idx."""
    n = keys.shape[0]
    hist = np.empty(2048, np.int64)
    for shift in (0, 11, 22):
        hist[:] = 0
        for i in range(n):
            hist[(keys[i] >> shift) & 2047] += 1
        if n == 0 or hist[(keys[0] >> shift) & 2047] == n:
            continue  # every key shares this digit
        total = 0
        for d in range(2048):
            c = hist[d]
            hist[d] = total
            total += c
        for i in range(n):
            d = (keys[i] >> shift) & 2047
            pos = hist[d]
            hist[d] = pos + 1
            tmp_keys[pos] = keys[i]
            tmp_idx[pos] = idx[i]
        keys[:n] = tmp_keys[:n]
        idx[:n] = tmp_idx[:n]


@njit(parallel=True, **_opts)
def bin_count(proj, box, tiles_x, order, n_visible, tile_counts):
    """Per camera: visible Gaussians sorted by depth into order[b, :n_visible[b]]; tile counts."""
    n_cam, n = box.shape[0], box.shape[1]
    for b in prange(n_cam):
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
        for i in range(m):
            g = idx[i]
            order[b, i] = g
            for ty in range(box[b, g, 2] // TILE, box[b, g, 3] // TILE + 1):
                for tx in range(box[b, g, 0] // TILE, box[b, g, 1] // TILE + 1):
                    tile_counts[b, ty * tiles_x + tx] += 1


@njit(parallel=True, **_opts)
def bin_fill(box, tiles_x, order, n_visible, offsets, lists):
    """Fill the per-tile lists (global offsets [B * tiles + 1]) in depth order."""
    n_cam = box.shape[0]
    n_tiles = (offsets.shape[0] - 1) // n_cam
    for b in prange(n_cam):
        cursor = offsets[b * n_tiles:(b + 1) * n_tiles].copy()
        for i in range(n_visible[b]):
            g = order[b, i]
            for ty in range(box[b, g, 2] // TILE, box[b, g, 3] // TILE + 1):
                for tx in range(box[b, g, 0] // TILE, box[b, g, 1] // TILE + 1):
                    t = ty * tiles_x + tx
                    lists[cursor[t]] = g
                    cursor[t] += 1


# ---------------------------------------------------------------------------- 4. forward raster
@njit(**_opts)
def _row_span(pr, py, dy, x_lo, x_hi):
    """Pixel columns [x0, x1] of row py inside the Gaussian's alpha >= 1/255 ellipse, clipped."""
    rem = pr[P_LEVEL] - dy * dy * pr[P_HALF_INV_SYY]
    if rem < 0:
        return 1, 0
    h = math.sqrt(rem * pr[P_TWO_OVER_A]) + SPAN_MARGIN_PX
    centre = pr[P_U] - 0.5 - pr[P_B] * dy * pr[P_TWO_OVER_A] * 0.5
    lo = min(max(centre - h, x_lo - 1.0), x_hi + 1.0)
    hi = min(max(centre + h, x_lo - 1.0), x_hi + 1.0)
    return max(int(math.ceil(lo)), x_lo), min(int(math.floor(hi)), x_hi)


@njit(**_opts)
def _raster_tile_fwd(b, tile, proj, box, vals, offsets, lists, tiles_x, width, height, out, t_final, last):
    n_tiles = (offsets.shape[0] - 1) // proj.shape[0]
    cv = vals.shape[1]
    tx0 = (tile % tiles_x) * TILE
    ty0 = (tile // tiles_x) * TILE
    tw = min(TILE, width - tx0)
    th = min(TILE, height - ty0)
    npx = tw * th
    acc = np.zeros((npx, cv + 1))
    trans = np.ones(npx)  # > 0 while compositing; -T once the pixel is done
    last_k = np.zeros(npx, np.int32)
    active = npx
    start = offsets[b * n_tiles + tile]
    end = offsets[b * n_tiles + tile + 1]
    for k in range(start, end):
        g = lists[k]
        pr = proj[b, g]
        u, v = np.float64(pr[P_U]), np.float64(pr[P_V])
        ca, cb, cc = np.float64(pr[P_A]), np.float64(pr[P_B]), np.float64(pr[P_C])
        o, z = np.float64(pr[P_O]), np.float64(pr[P_Z])
        for py in range(max(box[b, g, 2], ty0), min(box[b, g, 3], ty0 + th - 1) + 1):
            dy = py + 0.5 - v
            x0, x1 = _row_span(pr, py, dy, tx0, tx0 + tw - 1)
            row = (py - ty0) * tw - tx0
            for px in range(x0, x1 + 1):
                p = row + px
                t = trans[p]
                if t <= 0.0:
                    continue
                dx = px + 0.5 - u
                sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                if sigma < 0.0:
                    continue
                alpha = min(ALPHA_MAX, o * math.exp(-sigma))
                if alpha < ALPHA_MIN:
                    continue
                t_next = t * (1.0 - alpha)
                if t_next <= T_STOP:
                    trans[p] = -t
                    active -= 1
                    continue
                w = alpha * t
                for c in range(cv):
                    acc[p, c] += w * vals[g, c]
                acc[p, cv] += w * z
                trans[p] = t_next
                last_k[p] = k + 1
        if active == 0:
            break
    for py in range(th):
        for px in range(tw):
            p = py * tw + px
            for c in range(cv + 1):
                out[b, c, ty0 + py, tx0 + px] = acc[p, c]
            t_final[b, ty0 + py, tx0 + px] = abs(trans[p])
            last[b, ty0 + py, tx0 + px] = last_k[p]


@njit(parallel=True, **_opts)
def raster_fwd(proj, box, vals, offsets, lists, tiles_x, width, height, out, t_final, last):
    """out [B, Cv + 1, H, W] (values then un-normalised depth), t_final [B, H, W], last [B, H, W]."""
    n_cam = proj.shape[0]
    n_tiles = (offsets.shape[0] - 1) // n_cam
    for item in prange(n_cam * n_tiles):
        _raster_tile_fwd(item // n_tiles, item % n_tiles, proj, box, vals, offsets, lists, tiles_x, width, height, out, t_final, last)


# ---------------------------------------------------------------------------- 5. backward raster
@njit(**_opts)
def _raster_tile_bwd(b, tile, proj, box, vals, offsets, lists, tiles_x, width, height,
                     t_final, last, v_out, v_t, g2d, gvals):
    """Reverse traversal of one tile; adds into g2d [B, N, NGRAD] and gvals [N, Cv]."""
    n_tiles = (offsets.shape[0] - 1) // proj.shape[0]
    cv = vals.shape[1]
    tx0 = (tile % tiles_x) * TILE
    ty0 = (tile // tiles_x) * TILE
    tw = min(TILE, width - tx0)
    th = min(TILE, height - ty0)
    npx = tw * th
    v_pix = np.empty((npx, cv + 1))
    behind = np.zeros((npx, cv + 1))  # sum of w * value of the Gaussians behind
    trans = np.empty(npx)
    t_fin = np.empty(npx)
    v_tf = np.empty(npx)
    last_k = np.empty(npx, np.int32)
    k_end = 0
    for py in range(th):
        for px in range(tw):
            p = py * tw + px
            for c in range(cv + 1):
                v_pix[p, c] = v_out[b, c, ty0 + py, tx0 + px]
            trans[p] = t_final[b, ty0 + py, tx0 + px]
            t_fin[p] = trans[p]
            v_tf[p] = v_t[b, ty0 + py, tx0 + px]
            last_k[p] = last[b, ty0 + py, tx0 + px]
            k_end = max(k_end, last_k[p])
    g_val = np.empty(cv)
    start = offsets[b * n_tiles + tile]
    for k in range(k_end - 1, start - 1, -1):
        g = lists[k]
        pr = proj[b, g]
        u, v = np.float64(pr[P_U]), np.float64(pr[P_V])
        ca, cb, cc = np.float64(pr[P_A]), np.float64(pr[P_B]), np.float64(pr[P_C])
        o, z = np.float64(pr[P_O]), np.float64(pr[P_Z])
        gu = gv = ga = gb = gc = go = gz = 0.0
        g_val[:] = 0.0
        hit = False
        for py in range(max(box[b, g, 2], ty0), min(box[b, g, 3], ty0 + th - 1) + 1):
            dy = py + 0.5 - v
            x0, x1 = _row_span(pr, py, dy, tx0, tx0 + tw - 1)
            row = (py - ty0) * tw - tx0
            for px in range(x0, x1 + 1):
                p = row + px
                if k >= last_k[p]:
                    continue
                dx = px + 0.5 - u
                sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                if sigma < 0.0:
                    continue
                vis = math.exp(-sigma)
                ov = o * vis
                alpha = min(ALPHA_MAX, ov)
                if alpha < ALPHA_MIN:
                    continue
                ra = 1.0 / max(ONE_MINUS_ALPHA_MIN, 1.0 - alpha)
                t = trans[p] * ra
                trans[p] = t
                fac = alpha * t
                v_alpha = 0.0
                for c in range(cv):
                    vp = v_pix[p, c]
                    g_val[c] += fac * vp
                    v_alpha += (vals[g, c] * t - behind[p, c] * ra) * vp
                    behind[p, c] += vals[g, c] * fac
                vp = v_pix[p, cv]
                gz += fac * vp
                v_alpha += (z * t - behind[p, cv] * ra) * vp
                behind[p, cv] += z * fac
                v_alpha -= t_fin[p] * ra * v_tf[p]
                if ov <= ALPHA_MAX:
                    go += vis * v_alpha
                    v_sigma = -alpha * v_alpha
                    ga += 0.5 * dx * dx * v_sigma
                    gb += dx * dy * v_sigma
                    gc += 0.5 * dy * dy * v_sigma
                    gu -= (ca * dx + cb * dy) * v_sigma
                    gv -= (cb * dx + cc * dy) * v_sigma
                hit = True
        if hit:
            g2d[b, g, G_U] += gu
            g2d[b, g, G_V] += gv
            g2d[b, g, G_A] += ga
            g2d[b, g, G_B] += gb
            g2d[b, g, G_C] += gc
            g2d[b, g, G_O] += go
            g2d[b, g, G_Z] += gz
            for c in range(cv):
                gvals[g, c] += g_val[c]


@njit(parallel=True, **_opts)
def raster_bwd(proj, box, vals, offsets, lists, tiles_x, width, height, t_final, last, v_out, v_t,
               by_camera, g2d, gvals):
    """g2d [nbuf, B, N, NGRAD] (nbuf = 1 when by_camera else threads), gvals [threads, N, Cv]."""
    n_cam = proj.shape[0]
    n_tiles = (offsets.shape[0] - 1) // n_cam
    n_items = n_cam if by_camera else n_cam * n_tiles
    for item in prange(n_items):
        tid = numba.get_thread_id()
        if by_camera:
            for tile in range(n_tiles):
                _raster_tile_bwd(item, tile, proj, box, vals, offsets, lists, tiles_x, width, height,
                                 t_final, last, v_out, v_t, g2d[0], gvals[tid])
        else:
            _raster_tile_bwd(item // n_tiles, item % n_tiles, proj, box, vals, offsets, lists, tiles_x, width,
                             height, t_final, last, v_out, v_t, g2d[tid], gvals[tid])


# ---------------------------------------------------------------------------- 6. backward projection
@njit(parallel=True, **_opts)
def project_bwd(means, quats, log_scales, cov, world2cam, K, width, height, box, g2d,
                g_means, g_quats, g_log_scales, g_opacities, g_cam):
    """Chain rule from g2d [nbuf, B, N, NGRAD] to the Gaussians and to g_cam [threads, B, 12]
    (rows 0..2 of world2cam, row-major)."""
    n_cam = world2cam.shape[0]
    nbuf = g2d.shape[0]
    for n in prange(means.shape[0]):
        tid = numba.get_thread_id()
        m0, m1, m2 = np.float64(means[n, 0]), np.float64(means[n, 1]), np.float64(means[n, 2])
        sig = _sym((cov[n, 0], cov[n, 1], cov[n, 2], cov[n, 3], cov[n, 4], cov[n, 5]))
        gm0 = gm1 = gm2 = 0.0
        gs = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # d loss / d world covariance (full)
        g_o = 0.0
        for b in range(n_cam):
            if box[b, n, 0] > box[b, n, 1]:
                continue
            gu = gv = ga = gb = gc = go = gz = 0.0
            for i in range(nbuf):
                gu += g2d[i, b, n, G_U]
                gv += g2d[i, b, n, G_V]
                ga += g2d[i, b, n, G_A]
                gb += g2d[i, b, n, G_B]
                gc += g2d[i, b, n, G_C]
                go += g2d[i, b, n, G_O]
                gz += g2d[i, b, n, G_Z]
            g_o += go
            w, t, fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn = _camera(world2cam, K, b, width, height)
            x = w[0] * m0 + w[1] * m1 + w[2] * m2 + t[0]
            y = w[3] * m0 + w[4] * m1 + w[5] * m2 + t[1]
            z = w[6] * m0 + w[7] * m1 + w[8] * m2 + t[2]
            rx, clamped_x = _clamp_ratio(x / z, -lim_xn, lim_xp)
            ry, clamped_y = _clamp_ratio(y / z, -lim_yn, lim_yp)
            j00, j11 = fx / z, fy / z
            j02, j12 = -fx * rx / z, -fy * ry / z
            ws = _mm(w, sig)
            s = _mm(ws, _t(w))
            a, bb, c = _cov2d(j00, j02, j11, j12, s)
            a += BLUR_PX2
            c += BLUR_PX2
            det_raw = a * c - bb * bb
            det = max(det_raw, DET_MIN)
            # conic (A, B, C) = (c, -b, a) / det
            g_a = gc / det
            g_c = ga / det
            g_b = -gb / det
            if det_raw > DET_MIN:
                g_det = -(ga * c - gb * bb + gc * a) / (det * det)
                g_a += g_det * c
                g_c += g_det * a
                g_b -= 2.0 * g_det * bb
            # cov2d = J S J^T: G2 = [[g_a, g_b/2], [g_b/2, g_c]] (b is one parameter used twice)
            hb = 0.5 * g_b
            gS = (
                j00 * j00 * g_a, j00 * j11 * hb, j00 * (g_a * j02 + hb * j12),
                j00 * j11 * hb, j11 * j11 * g_c, j11 * (hb * j02 + g_c * j12),
                j00 * (g_a * j02 + hb * j12), j11 * (hb * j02 + g_c * j12),
                j02 * j02 * g_a + 2.0 * j02 * j12 * hb + j12 * j12 * g_c,
            )
            # dJ = 2 G2 J S; J S rows:
            r0 = (j00 * s[0] + j02 * s[6], j00 * s[1] + j02 * s[7], j00 * s[2] + j02 * s[8])
            r1 = (j11 * s[3] + j12 * s[6], j11 * s[4] + j12 * s[7], j11 * s[5] + j12 * s[8])
            gj00 = 2.0 * (g_a * r0[0] + hb * r1[0])
            gj02 = 2.0 * (g_a * r0[2] + hb * r1[2])
            gj11 = 2.0 * (hb * r0[1] + g_c * r1[1])
            gj12 = 2.0 * (hb * r0[2] + g_c * r1[2])
            # S = W Sigma W^T: dSigma = W^T gS W, dW += 2 gS W Sigma
            gsig = _mm(_mm(_t(w), gS), w)
            gs = (
                gs[0] + gsig[0], gs[1] + gsig[1], gs[2] + gsig[2], gs[3] + gsig[3], gs[4] + gsig[4],
                gs[5] + gsig[5], gs[6] + gsig[6], gs[7] + gsig[7], gs[8] + gsig[8],
            )
            gw = _mm(gS, ws)  # times 2 below
            # J(z, rx, ry) and the projected mean
            iz = 1.0 / z
            gx = fx * iz * gu
            gy = fy * iz * gv
            gzz = gz - fx * x * iz * iz * gu - fy * y * iz * iz * gv
            gzz += -fx * iz * iz * gj00 - fy * iz * iz * gj11 + fx * rx * iz * iz * gj02 + fy * ry * iz * iz * gj12
            g_rx = -fx * iz * gj02
            g_ry = -fy * iz * gj12
            if clamped_x:
                pass  # rx is a constant
            else:  # rx = x / z
                gx += g_rx * iz
                gzz -= g_rx * x * iz * iz
            if not clamped_y:
                gy += g_ry * iz
                gzz -= g_ry * y * iz * iz
            gm0 += w[0] * gx + w[3] * gy + w[6] * gzz
            gm1 += w[1] * gx + w[4] * gy + w[7] * gzz
            gm2 += w[2] * gx + w[5] * gy + w[8] * gzz
            gp = (gx, gy, gzz)
            mm = (m0, m1, m2)
            for i in range(3):
                for j in range(3):
                    g_cam[tid, b, 4 * i + j] += 2.0 * gw[3 * i + j] + gp[i] * mm[j]
                g_cam[tid, b, 4 * i + 3] += gp[i]
        g_means[n, 0] = gm0
        g_means[n, 1] = gm1
        g_means[n, 2] = gm2
        g_opacities[n] = g_o
        # Sigma = M M^T, M = R diag(s): dM = 2 gs M
        r, inv, qw, qx, qy, qz = _quat_rotation(
            np.float64(quats[n, 0]), np.float64(quats[n, 1]), np.float64(quats[n, 2]), np.float64(quats[n, 3])
        )
        sc = (math.exp(np.float64(log_scales[n, 0])), math.exp(np.float64(log_scales[n, 1])),
              math.exp(np.float64(log_scales[n, 2])))
        s0, s1, s2 = sc
        gm = _mm(gs, (r[0] * s0, r[1] * s1, r[2] * s2, r[3] * s0, r[4] * s1, r[5] * s2, r[6] * s0, r[7] * s1, r[8] * s2))
        # M_ij = R_ij s_j, dM = 2 gs M  ->  dR_ij = 2 gm_ij s_j, ds_j = sum_i 2 gm_ij R_ij
        gr = (
            2 * gm[0] * s0, 2 * gm[1] * s1, 2 * gm[2] * s2,
            2 * gm[3] * s0, 2 * gm[4] * s1, 2 * gm[5] * s2,
            2 * gm[6] * s0, 2 * gm[7] * s1, 2 * gm[8] * s2,
        )
        g_log_scales[n, 0] = 2 * (gm[0] * r[0] + gm[3] * r[3] + gm[6] * r[6]) * s0
        g_log_scales[n, 1] = 2 * (gm[1] * r[1] + gm[4] * r[4] + gm[7] * r[7]) * s1
        g_log_scales[n, 2] = 2 * (gm[2] * r[2] + gm[5] * r[5] + gm[8] * r[8]) * s2
        if inv == 0.0:
            g_quats[n, 0] = g_quats[n, 1] = g_quats[n, 2] = g_quats[n, 3] = 0.0
            continue
        gw_ = 2.0 * (-qz * gr[1] + qy * gr[2] + qz * gr[3] - qx * gr[5] - qy * gr[6] + qx * gr[7])
        gx_ = 2.0 * (qy * gr[1] + qz * gr[2] + qy * gr[3] - 2 * qx * gr[4] - qw * gr[5] + qz * gr[6] + qw * gr[7] - 2 * qx * gr[8])
        gy_ = 2.0 * (-2 * qy * gr[0] + qx * gr[1] + qw * gr[2] + qx * gr[3] + qz * gr[5] - qw * gr[6] + qz * gr[7] - 2 * qy * gr[8])
        gz_ = 2.0 * (-2 * qz * gr[0] - qw * gr[1] + qx * gr[2] + qw * gr[3] - 2 * qz * gr[4] + qy * gr[5] + qx * gr[6] + qy * gr[7])
        dot = qw * gw_ + qx * gx_ + qy * gy_ + qz * gz_
        g_quats[n, 0] = (gw_ - qw * dot) * inv
        g_quats[n, 1] = (gx_ - qx * dot) * inv
        g_quats[n, 2] = (gy_ - qy * dot) * inv
        g_quats[n, 3] = (gz_ - qz * dot) * inv
