from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from aes_planner.gaussians.kernels.common import G_A, G_B, G_C, G_O, G_U, G_V, G_Z, _mm, _opts, _quat_rotation, _sym, _t
from aes_planner.gaussians.kernels.project import _camera, _clamp_ratio, _cov2d
from aes_planner.gaussians.numerics import BLUR_PX2, DET_MIN


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
    # One block of Gaussians per worker wk, its pose-gradient sums in g_cam[wk], not in the running
    # thread's row: which thread runs which block varies from call to call, so per-thread rows made
    # the sums' order, and the pose gradient's last bits, vary too (a float64 gradcheck saw it).
    n_all = means.shape[0]
    workers = g_cam.shape[0]
    per = -(-n_all // workers)
    for worker in prange(workers):
        wk = np.int64(worker)  # prange's index can be unsigned: int64 keeps the mixed arithmetic integral
        for n in range(wk * per, min((wk + 1) * per, n_all)):
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
                        g_cam[wk, b, 4 * i + j] += 2.0 * gw[3 * i + j] + gp[i] * mm[j]
                    g_cam[wk, b, 4 * i + 3] += gp[i]
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
