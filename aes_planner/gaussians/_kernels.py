"""Compiled CPU kernels of the rasterizer (numba, ``cache=True``). Imported only when used.

Pipeline per call (B cameras, N Gaussians, Cv = 3 + C value channels, tiles of TILE x TILE px):

1-2. ``project_fwd``: per Gaussian the world covariance (float64, shared by all cameras), then
   per camera the EWA projection in float64 -> packed image-space parameters and the pixel box
   of the ``alpha >= 1/255`` ellipse (empty box = culled).
3. ``bin_cameras`` / ``fill_lists``: per camera, a stable radix sort of the visible Gaussians by
   depth, then per-tile lists in that order (counting pass, prefix sum, fill): no per-tile sorts.
   Cameras go to threads; a single camera splits in two (sort beside count, then two bands of fill).
4. ``raster_fwd``: parallel over (camera, tile), tiles interleaved across threads. Each Gaussian
   of the tile's depth-sorted list visits only the tile rows of its ``alpha >= 1/255`` box; a row
   is one masked 8- or 16-lane vector (sigma, exp, alpha, transmittance, stop rule), then the
   values are accumulated lane-wise (up to 63 channels) or per contributing pixel with the
   channels innermost (64 or more). A tile stops once all its pixels are saturated. Stores the
   final transmittance and, per pixel, the list position after its last contributor.
5. ``raster_bwd``: the same traversal in reverse from the stored final transmittance (gsplat's
   backward), accumulating per-lane gradient terms that are reduced once per Gaussian; channels
   lane-wise up to 7, per contributing pixel from 8 (through one dot product per pixel). Parallel
   over cameras when there are enough of them (no write conflicts), else over tiles with
   per-thread buffers.
6. ``project_bwd``: per Gaussian, the chain rule through projection and covariance for every
   camera; camera-pose gradients go to per-thread buffers.

Everything geometric is float64; image-space parameters and outputs are in the Gaussians' dtype.
"""

from __future__ import annotations

import ctypes
import math
import os
import site
import sys

import numba
import numpy as np
from numba import njit, prange, types
from numba.extending import overload

from aes_planner.gaussians.numerics import (
    ALPHA_MAX,
    ALPHA_MIN,
    BLUR_PX2,
    BOX_MARGIN_PX,
    DET_MIN,
    FAR_M,
    FRUSTUM_SLACK,
    LOG_INV_ALPHA_MIN,
    NEAR_M,
    ONE_MINUS_ALPHA_MIN,
    SIGMA_CLAMP,
    T_STOP,
    TILE,
)


def _choose_threading_layer() -> None:
    """TBB first, then numba's workqueue; OpenMP last. On these VMs workqueue's sleeping workers
    wake up to ~1.5 ms late (one thread did a single view's tiles alone), and OpenMP's spinning
    threads fight torch's and any busy neighbour (a view's forward+backward 2.7-5.6x slower); TBB
    is fast idle and does not spin against a neighbour (figures: docs/benchmarks.md, "Threading
    layer"). pip puts oneTBB's libtbb.so.12 in the environment's lib/, off the loader's path:
    loaded here by its path so that numba's TBB pool finds it. An explicit
    NUMBA_THREADING_LAYER wins."""
    if "NUMBA_THREADING_LAYER" in os.environ:
        return
    for base in dict.fromkeys((sys.prefix, site.getuserbase(), sys.base_prefix)):
        path = os.path.join(base, "lib", "libtbb.so.12")
        if os.path.exists(path):
            try:
                ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
            except OSError:
                continue
            break
    numba.config.THREADING_LAYER_PRIORITY = ["tbb", "workqueue", "omp"]
    numba.config.THREADING_LAYER = "default"


_choose_threading_layer()

HALF_TILE = TILE // 2  # lanes of a narrow row window in the forward
# Value channels + depth from which the channel loops go innermost (only contributing pixels
# visited) instead of lanes innermost. The forward's lanes-innermost loops stayed faster up to 36
# channels once rows became 8-lane windows (docs/rasterizer.md, round 4); the backward's need it
# from 8 (2.2x at 36 channels).
FWD_PIXEL_MAJOR_MIN_CHANNELS = 64
BWD_PIXEL_MAJOR_MIN_CHANNELS = 8
DONE_CHECK_EVERY = 32  # Gaussians between checks whether every pixel of a tile is saturated
# Packed image-space parameters per (camera, Gaussian).
P_U, P_V, P_A, P_B, P_C, P_O, P_Z = range(7)
NPROJ = 7
# Image-space gradients per (camera, Gaussian): mean2d, conic, opacity, depth.
G_U, G_V, G_A, G_B, G_C, G_O, G_Z = range(7)
NGRAD = 7
# Pose gradient per camera: rows 0..2 of world2cam, row-major.
NPOSE = 12
# project_bwd's per-thread pose-gradient rows: NPOSE used, then 8 float64 (one cache line) of
# padding, so that two threads never write the same line (unpadded rows made the threads'
# read-modify-writes bounce a shared line: 839 -> 696 us for 10k Gaussians on 2 threads,
# docs/rasterizer.md round 6).
G_CAM_STRIDE = NPOSE + 8

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
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )
    return r, inv, w, x, y, z


@njit(**_opts)
def _mm(a, b):
    """3x3 @ 3x3 for row-major 9-tuples."""
    return (
        a[0] * b[0] + a[1] * b[3] + a[2] * b[6],
        a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
        a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
        a[3] * b[0] + a[4] * b[3] + a[5] * b[6],
        a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
        a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
        a[6] * b[0] + a[7] * b[3] + a[8] * b[6],
        a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
        a[6] * b[2] + a[7] * b[5] + a[8] * b[8],
    )


@njit(**_opts)
def _t(a):
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


@njit(**_opts)
def _sym(c):
    """Symmetric 9-tuple from (xx, xy, xz, yy, yz, zz)."""
    return (c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5])


# ---------------------------------------------------------------------------- 1. covariance
@njit(**_opts)
def _covariance(quats, log_scales, n, cov):
    """World covariance of Gaussian n into cov[n] (xx, xy, xz, yy, yz, zz), float64. Returns its
    largest variance (largest scale squared)."""
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
    s_max = max(s0, s1, s2)
    return s_max * s_max


# ---------------------------------------------------------------------------- 2. projection
@njit(**_opts)
def camera_table(world2cam, K, width, height):
    """Per-camera constants [B, NCAM] (float64): rotation (9), translation (3), fx, fy, cx, cy and
    the clamp limits of x/z and y/z (+x, -x, +y, -y), computed once per call."""
    n_cam = world2cam.shape[0]
    cams = np.empty((n_cam, NCAM))
    for b in range(n_cam):
        for i in range(3):
            for j in range(3):
                cams[b, 3 * i + j] = world2cam[b, i, j]
            cams[b, 9 + i] = world2cam[b, i, 3]
        fx, fy, cx, cy = K[b, 0, 0], K[b, 1, 1], K[b, 0, 2], K[b, 1, 2]
        slack_x = FRUSTUM_SLACK * 0.5 * width / fx
        slack_y = FRUSTUM_SLACK * 0.5 * height / fy
        cams[b, 12], cams[b, 13], cams[b, 14], cams[b, 15] = fx, fy, cx, cy
        cams[b, 16] = (width - cx) / fx + slack_x
        cams[b, 17] = cx / fx + slack_x
        cams[b, 18] = (height - cy) / fy + slack_y
        cams[b, 19] = cy / fy + slack_y
    return cams


NCAM = 20


@njit(**_opts)
def _camera(cams, b):
    c = cams[b]
    w = (c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8])
    t = (c[9], c[10], c[11])
    return w, t, c[12], c[13], c[14], c[15], c[16], c[17], c[18], c[19]


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


CULL_SLACK = 1.01  # world2cam rotations are orthonormal to 1e-4 (rasterize checks), bounds hold with margin


@njit(parallel=True, **_opts)
def project_fwd(means, quats, log_scales, opacities, cams, width, height, cov, proj, box):
    """cov [N, 6] float64 (kept for the backward), proj [B, N, NPROJ] (Gaussians' dtype), box
    [B, N, 4] int32 (x0, x1, y0, y1; x0 > x1 = culled). One parallel region for all of it."""
    n_cam = cams.shape[0]
    for n in prange(means.shape[0]):
        s_max2 = _covariance(quats, log_scales, n, cov)  # its largest variance: for the early cull below
        m0, m1, m2 = np.float64(means[n, 0]), np.float64(means[n, 1]), np.float64(means[n, 2])
        sig = _sym((cov[n, 0], cov[n, 1], cov[n, 2], cov[n, 3], cov[n, 4], cov[n, 5]))
        o = np.float64(opacities[n])
        level = math.log(max(o, 1e-30)) + LOG_INV_ALPHA_MIN
        for b in range(n_cam):
            box[b, n, 0] = 1
            box[b, n, 1] = 0
            if not (o >= ALPHA_MIN):
                continue
            w, t, fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn = _camera(cams, b)
            x = w[0] * m0 + w[1] * m1 + w[2] * m2 + t[0]
            y = w[3] * m0 + w[4] * m1 + w[5] * m2 + t[1]
            z = w[6] * m0 + w[7] * m1 + w[8] * m2 + t[2]
            if not (z > NEAR_M and z < FAR_M):
                continue
            iz = 1.0 / z
            u = fx * x * iz + cx
            v = fy * y * iz + cy
            rx, _ = _clamp_ratio(x * iz, -lim_xn, lim_xp)
            ry, _ = _clamp_ratio(y * iz, -lim_yn, lim_yp)
            j00, j11 = fx * iz, fy * iz
            j02, j12 = -fx * rx * iz, -fy * ry * iz
            # Early cull, before the covariance: the rows of T = J W below have norms^2 j00^2 + j02^2
            # and j11^2 + j12^2 (W is a rotation), so a <= (j00^2 + j02^2) s_max^2 + blur, and so on.
            bx = math.sqrt(2.0 * level * ((j00 * j00 + j02 * j02) * s_max2 + BLUR_PX2)) * CULL_SLACK + 1.0
            by = math.sqrt(2.0 * level * ((j11 * j11 + j12 * j12) * s_max2 + BLUR_PX2)) * CULL_SLACK + 1.0
            if u + bx < 0.0 or u - bx > width or v + by < 0.0 or v - by > height:
                continue
            # cov2d = T Sigma T^T with T = J W (2 x 3)
            t0 = (j00 * w[0] + j02 * w[6], j00 * w[1] + j02 * w[7], j00 * w[2] + j02 * w[8])
            t1 = (j11 * w[3] + j12 * w[6], j11 * w[4] + j12 * w[7], j11 * w[5] + j12 * w[8])
            s0 = (
                sig[0] * t0[0] + sig[1] * t0[1] + sig[2] * t0[2],
                sig[3] * t0[0] + sig[4] * t0[1] + sig[5] * t0[2],
                sig[6] * t0[0] + sig[7] * t0[1] + sig[8] * t0[2],
            )
            s1 = (
                sig[0] * t1[0] + sig[1] * t1[1] + sig[2] * t1[2],
                sig[3] * t1[0] + sig[4] * t1[1] + sig[5] * t1[2],
                sig[6] * t1[0] + sig[7] * t1[1] + sig[8] * t1[2],
            )
            a = t0[0] * s0[0] + t0[1] * s0[1] + t0[2] * s0[2]
            bb = t1[0] * s0[0] + t1[1] * s0[1] + t1[2] * s0[2]
            c = t1[0] * s1[0] + t1[1] * s1[1] + t1[2] * s1[2]
            a += BLUR_PX2
            c += BLUR_PX2
            det = max(a * c - bb * bb, DET_MIN)
            ext_x = math.sqrt(2.0 * level * a)
            ext_y = math.sqrt(2.0 * level * c)
            # Pixel i (centre i + 0.5) is touched if |i + 0.5 - u| <= ext: i in [u - ext - 0.5, u + ext - 0.5].
            fx0 = min(max(u - ext_x - 0.5 - BOX_MARGIN_PX, -1.0), width + 1.0)
            fx1 = min(max(u + ext_x - 0.5 + BOX_MARGIN_PX, -1.0), width + 1.0)
            fy0 = min(max(v - ext_y - 0.5 - BOX_MARGIN_PX, -1.0), height + 1.0)
            fy1 = min(max(v + ext_y - 0.5 + BOX_MARGIN_PX, -1.0), height + 1.0)
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
            proj[b, n, P_U] = u
            proj[b, n, P_V] = v
            proj[b, n, P_A] = c / det
            proj[b, n, P_B] = -bb / det
            proj[b, n, P_C] = a / det
            proj[b, n, P_O] = o
            proj[b, n, P_Z] = z


# ---------------------------------------------------------------------------- 3. binning
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


# ---------------------------------------------------------------------------- 4. forward raster
# The tile loops are written lane-wise for LLVM's loop vectoriser: one tile row (TILE pixels) is
# one masked vector; branches become selects; indices into per-row slices are unsigned (numba's
# negative-index wraparound would make addresses non-affine); exp is a polynomial, not a libm call.
# Typed constants come in the `consts` array (same dtype as the image-space parameters), so the
# float32 pipeline never widens to float64 inside a loop.
C_ZERO, C_ONE, C_HALF, C_ALPHA_MAX, C_ALPHA_MIN, C_T_STOP, C_EXP_CLAMP, C_ONE_MINUS_ALPHA_MIN = range(8)
CONSTS = (0.0, 1.0, 0.5, ALPHA_MAX, ALPHA_MIN, T_STOP, SIGMA_CLAMP, ONE_MINUS_ALPHA_MIN)
_fast = dict(_opts, fastmath={"reassoc", "contract", "nsz"})


def exp_neg(s):
    """exp(-s) for 0 <= s <= SIGMA_CLAMP = 16 (numba only): range reduction by ln 2, polynomial, exact 2^-n."""
    raise NotImplementedError("exp_neg is only available inside numba-compiled code")


@overload(exp_neg, jit_options=dict(fastmath={"contract"}))
def _exp_neg_impl(s):
    if s == types.float32:
        f = np.float32

        def impl32(s):  # max relative error 1.0e-7 on [0, 16]
            n = np.int32(s * f(1.4426950408889634) + f(0.5))
            x = (f(n) * f(0.693359375) - s) + f(n) * f(-2.12194440e-4)
            p = f(1.0 / 5040.0) * x + f(1.0 / 720.0)
            p = p * x + f(1.0 / 120.0)
            p = p * x + f(1.0 / 24.0)
            p = p * x + f(1.0 / 6.0)
            p = p * x + f(0.5)
            p = p * x + f(1.0)
            p = p * x + f(1.0)
            # numba widens int32 arithmetic to int64, which halves the vector width: cast back.
            shift = np.int32(np.int32(24) - n)
            return p * (f(np.int32(np.int32(1) << shift)) * f(5.9604644775390625e-08))

        return impl32

    def impl64(s):  # max relative error 3.2e-16 on [0, 16]
        n = np.int64(s * 1.4426950408889634 + 0.5)
        x = (n * 6.93147180369123816490e-01 - s) + n * 1.90821492927058770002e-10
        p = x * (1.0 / 479001600.0) + 1.0 / 39916800.0
        p = p * x + 1.0 / 3628800.0
        p = p * x + 1.0 / 362880.0
        p = p * x + 1.0 / 40320.0
        p = p * x + 1.0 / 5040.0
        p = p * x + 1.0 / 720.0
        p = p * x + 1.0 / 120.0
        p = p * x + 1.0 / 24.0
        p = p * x + 1.0 / 6.0
        p = p * x + 0.5
        p = p * x + 1.0
        p = p * x + 1.0
        return p * ((np.int64(1) << (24 - n)) * 5.9604644775390625e-08)

    return impl64


@njit(**_opts)
def _pixel_centres(origin, n, consts):
    out = np.empty(n, consts.dtype)
    for i in range(n):
        out[i] = origin + i
        out[i] += consts[C_HALF]
    return out


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


@njit(**_opts)
def _interleaved(item, n_items, threads):
    """Map prange's contiguous per-thread chunks to interleaved work items (-1 = none), so that
    each thread gets tiles from all over the image (centre tiles are the busy ones)."""
    chunk = -(-n_items // threads)
    real = (item % chunk) * threads + item // chunk
    return real if real < n_items else -1


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


# ---------------------------------------------------------------------------- 5. backward raster
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
    for item in prange(threads * -(-n_items // threads)):
        real = _interleaved(item, n_items, threads)
        if real < 0:
            continue
        tid = numba.get_thread_id()
        # by camera: one item is a whole camera (all its tiles on this thread, so one shared g2d
        # buffer is race-free); by tile: one item is one tile, into this thread's own buffer
        cam = real if by_camera else real // n_tiles
        first = 0 if by_camera else real % n_tiles
        stop = n_tiles if by_camera else first + 1
        buf = 0 if by_camera else tid
        for tile in range(first, stop):
            if many:
                _raster_tile_bwd_many(cam, tile, splats, image, upstream, g2d[buf], gvals[tid], need_values)
            else:
                _raster_tile_bwd(cam, tile, splats, image, upstream, g2d[buf], gvals[tid], need_values)


# ---------------------------------------------------------------------------- 6. backward projection
@njit(parallel=True, **_opts)
def project_bwd(
    means, quats, log_scales, cov, cams, box, g2d, g_means, g_quats, g_log_scales, g_opacities, g_cam, need_gaussians
):
    """Chain rule from g2d [nbuf, B, N, NGRAD] to the Gaussians and to g_cam [threads, B,
    G_CAM_STRIDE] (its first NPOSE: rows 0..2 of world2cam, row-major). With ``need_gaussians``
    False (only the poses need a gradient: the search's refinement) the covariance chain is
    skipped and g_means, g_quats, g_log_scales, g_opacities are left as they are."""
    n_cam = cams.shape[0]
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
            w, t, fx, fy, cx, cy, lim_xp, lim_xn, lim_yp, lim_yn = _camera(cams, b)
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
                j00 * j00 * g_a,
                j00 * j11 * hb,
                j00 * (g_a * j02 + hb * j12),
                j00 * j11 * hb,
                j11 * j11 * g_c,
                j11 * (hb * j02 + g_c * j12),
                j00 * (g_a * j02 + hb * j12),
                j11 * (hb * j02 + g_c * j12),
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
            if need_gaussians:
                gsig = _mm(_mm(_t(w), gS), w)
            else:
                gsig = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            gs = (
                gs[0] + gsig[0],
                gs[1] + gsig[1],
                gs[2] + gsig[2],
                gs[3] + gsig[3],
                gs[4] + gsig[4],
                gs[5] + gsig[5],
                gs[6] + gsig[6],
                gs[7] + gsig[7],
                gs[8] + gsig[8],
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
        if not need_gaussians:
            continue
        g_means[n, 0] = gm0
        g_means[n, 1] = gm1
        g_means[n, 2] = gm2
        g_opacities[n] = g_o
        # Sigma = M M^T, M = R diag(s): dM = 2 gs M
        r, inv, qw, qx, qy, qz = _quat_rotation(
            np.float64(quats[n, 0]), np.float64(quats[n, 1]), np.float64(quats[n, 2]), np.float64(quats[n, 3])
        )
        sc = (
            math.exp(np.float64(log_scales[n, 0])),
            math.exp(np.float64(log_scales[n, 1])),
            math.exp(np.float64(log_scales[n, 2])),
        )
        s0, s1, s2 = sc
        gm = _mm(
            gs, (r[0] * s0, r[1] * s1, r[2] * s2, r[3] * s0, r[4] * s1, r[5] * s2, r[6] * s0, r[7] * s1, r[8] * s2)
        )
        # M_ij = R_ij s_j, dM = 2 gs M  ->  dR_ij = 2 gm_ij s_j, ds_j = sum_i 2 gm_ij R_ij
        gr = (
            2 * gm[0] * s0,
            2 * gm[1] * s1,
            2 * gm[2] * s2,
            2 * gm[3] * s0,
            2 * gm[4] * s1,
            2 * gm[5] * s2,
            2 * gm[6] * s0,
            2 * gm[7] * s1,
            2 * gm[8] * s2,
        )
        g_log_scales[n, 0] = 2 * (gm[0] * r[0] + gm[3] * r[3] + gm[6] * r[6]) * s0
        g_log_scales[n, 1] = 2 * (gm[1] * r[1] + gm[4] * r[4] + gm[7] * r[7]) * s1
        g_log_scales[n, 2] = 2 * (gm[2] * r[2] + gm[5] * r[5] + gm[8] * r[8]) * s2
        if inv == 0.0:
            g_quats[n, 0] = g_quats[n, 1] = g_quats[n, 2] = g_quats[n, 3] = 0.0
            continue
        gw_ = 2.0 * (-qz * gr[1] + qy * gr[2] + qz * gr[3] - qx * gr[5] - qy * gr[6] + qx * gr[7])
        gx_ = 2.0 * (
            qy * gr[1]
            + qz * gr[2]
            + qy * gr[3]
            - 2 * qx * gr[4]
            - qw * gr[5]
            + qz * gr[6]
            + qw * gr[7]
            - 2 * qx * gr[8]
        )
        gy_ = 2.0 * (
            -2 * qy * gr[0]
            + qx * gr[1]
            + qw * gr[2]
            + qx * gr[3]
            + qz * gr[5]
            - qw * gr[6]
            + qz * gr[7]
            - 2 * qy * gr[8]
        )
        gz_ = 2.0 * (
            -2 * qz * gr[0]
            - qw * gr[1]
            + qx * gr[2]
            + qw * gr[3]
            - 2 * qz * gr[4]
            + qy * gr[5]
            + qx * gr[6]
            + qy * gr[7]
        )
        dot = qw * gw_ + qx * gx_ + qy * gy_ + qz * gz_
        g_quats[n, 0] = (gw_ - qw * dot) * inv
        g_quats[n, 1] = (gx_ - qx * dot) * inv
        g_quats[n, 2] = (gy_ - qy * dot) * inv
        g_quats[n, 3] = (gz_ - qz * dot) * inv
