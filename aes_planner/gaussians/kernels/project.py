from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from aes_planner.gaussians.kernels.common import P_A, P_B, P_C, P_O, P_U, P_V, P_Z, _opts, _sym
from aes_planner.gaussians.kernels.covariance import _covariance
from aes_planner.gaussians.numerics import (
    ALPHA_MIN,
    BLUR_PX2,
    BOX_MARGIN_PX,
    DET_MIN,
    FAR_M,
    FRUSTUM_SLACK,
    LOG_INV_ALPHA_MIN,
    NEAR_M,
)


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
