"""The composition teacher's head as one compiled kernel: its terms and the analytic gradient of
its score with respect to the map, in one pass per map (numba; imported only where numba is).

Why: the torch head is 643 aten calls forward and ~220 autograd nodes backward on maps of
``[2, 4, 16, 16]``: at a stage-2 step (2 maps) 4.0 ms of CPU, a third of the step, for ~0.3 M
floating-point operations (docs/benchmarks.md, "perf-2, seventh round"). Here the same
formulas, in the same order, are written out over the 16 x 16 cells, with every intermediate in
float64; the backward is the chain rule of :meth:`CompositionTeacher._terms` written by hand,
with torch's conventions at the kinks (``clamp`` passes the gradient at its bounds, ``relu``
does not at 0), so that it is the gradient autograd computes (tested against it in float64,
and with ``torch.autograd.gradcheck``).

The constants come in as an array (``consts``, indices ``K_*``), never as module globals:
numba freezes globals into its on-disk cache, which a change of the teacher's constants in
another file would not invalidate.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["NCONST", "NTERMS", "head"]

# Scalar constants of the head, in ``consts``.
(
    K_LIMIT,
    K_TINY,
    K_EPS,
    K_OBJECT_ENERGY,
    K_ISOLATION,
    K_PRESENCE_MASS,
    K_EDGE_FLOOR,
    K_EDGE,
    K_CONTENT_OBJECT,
    K_LINES_CONTENT,
    K_SAL_FLOOR,
    K_BALANCE_SIGMA,
    K_RING_FLOOR,
    K_BORDER_FREE,
    K_BORDER_SCALE,
    K_AREA_GAIN,
    K_IDEAL_AREA,
    K_SIZE_LOG_SIGMA,
    K_BUSY_ENERGY,
    K_CLUTTER_MID,
    K_CLUTTER_WIDTH,
    K_HORIZON_ENERGY,
    K_HORIZON_SIGMA,
    K_TILT_TOL,
) = range(24)
NCONST = 24
# Output columns of ``terms``: the score, the seven terms in the order of
# ``composition.TERMS`` (their weights in ``weights``), then the three factors.
T_SCORE = 0
T_THIRDS, T_BALANCE, T_BORDER, T_PLACEMENT, T_LEVEL, T_CLUTTER, T_SIZE = range(1, 8)
T_CONTENT, T_PRESENCE, T_HORIZON = range(8, 11)
NTERMS = 11

_opts = dict(cache=True, nogil=True, error_model="numpy")


# The products below are written as row updates (``out[r, :] += v * row``), which numba vectorises
# without fastmath; as dot products (a sum per output) they would not be (no reassociation), and
# ran at one add per add latency (the backward's annulus product was 3x the rest of the map).
@njit(**_opts)
def _matmul(x, y, out):
    """``out = x @ y`` (``x [r, k]``, ``y [k, c]`` C-contiguous)."""
    out[:] = 0.0
    for r in range(x.shape[0]):
        for k in range(x.shape[1]):
            v = x[r, k]
            for c in range(y.shape[1]):
                out[r, c] += v * y[k, c]


@njit(**_opts)
def _sandwich(m, m_t, x, out, tmp):
    """``out = m @ x @ m.T`` for square ``[n, n]`` matrices (``m_t = m.T`` contiguous, ``tmp`` scratch)."""
    _matmul(x, m_t, tmp)
    _matmul(m, tmp, out)


@njit(**_opts)
def _sandwich_t(m, m_t, x, out, tmp):
    """``out = m.T @ x @ m`` (the gradient of :func:`_sandwich` with respect to ``x``)."""
    _matmul(x, m, tmp)
    _matmul(m_t, tmp, out)


@njit(**_opts)
def head(
    fmap,
    box3,
    box3_t,
    annulus,
    annulus_t,
    thirds_t,
    xg,
    yg,
    ring,
    rows,
    row_blur,
    tw,
    weights,
    consts,
    want_grad,
    terms,
    grad,
):
    """Terms of each map and, when ``want_grad``, ``d score / d fmap``.

    ``fmap [B, 4, n, n]`` (float32 or float64). The teacher's tables, float32 or float64 (every
    intermediate is float64): ``box3 [n, n]`` and its transpose, ``annulus [N, N]`` (N = n * n)
    and its transpose, ``thirds_t``, ``xg``, ``yg``, ``ring`` ``[n, n]``, ``rows [n]``,
    ``row_blur [n, n]``, ``tw [n, 3]`` (columns to thirds of the width), ``weights [7]``;
    ``consts [NCONST]``. Writes ``terms [B, NTERMS]`` (float64) and ``grad [B, 4, n, n]`` (the
    gradient of the score alone; untouched unless ``want_grad``)."""
    bsz, n = fmap.shape[0], fmap.shape[2]
    nc = n * n
    lim, tiny, eps = consts[K_LIMIT], consts[K_TINY], consts[K_EPS]
    oe, iso = consts[K_OBJECT_ENERGY], consts[K_ISOLATION]
    sal_floor2 = consts[K_SAL_FLOOR] * consts[K_SAL_FLOOR]
    sqrt_tiny, sqrt_eps = math.sqrt(tiny), math.sqrt(eps)
    f = np.empty((4, n, n))  # the clamped map
    sal, jxx, jyy, jxy = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    a, b, c, tmp = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    root, u, corners = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    salient, surround, den, subject = np.empty(nc), np.empty(nc), np.empty(nc), np.empty(nc)
    p, q, m = np.empty(nc), np.empty(nc), np.empty(nc)
    line, lt, parts = np.empty((n, n)), np.empty((n, 3)), np.empty((n, 3))
    log_span, span, w4, band = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    row_jxy, row_jyy = np.empty(n), np.empty(n)
    # gradients of the score
    g_sal, g_jxx, g_jyy, g_jxy = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    g_corners, g_a, g_b, g_c, g_x = (
        np.empty((n, n)),
        np.empty((n, n)),
        np.empty((n, n)),
        np.empty((n, n)),
        np.empty((n, n)),
    )
    g_salient, g_subject, g_energy = np.empty(nc), np.empty(nc), np.empty(nc)
    g_p, g_q, g_m, g_surround = np.empty(nc), np.empty(nc), np.empty(nc), np.empty(nc)
    g_lt, g_parts, g_w4 = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    for bi in range(bsz):
        # ---------------------------------------------------------------- forward
        for ch in range(4):
            for r in range(n):
                for col in range(n):
                    v = np.float64(fmap[bi, ch, r, col])
                    if v < -lim:
                        v = -lim
                    elif v > lim:
                        v = lim
                    f[ch, r, col] = v
        for r in range(n):
            for col in range(n):
                sal[r, col] = max(f[0, r, col], 0.0)
                jxx[r, col] = max(f[1, r, col], 0.0)
                jyy[r, col] = max(f[2, r, col], 0.0)
                jxy[r, col] = f[3, r, col]
        _sandwich(box3, box3_t, jxx, a, tmp)
        _sandwich(box3, box3_t, jyy, b, tmp)
        _sandwich(box3, box3_t, jxy, c, tmp)
        corner_sum = 0.0
        for r in range(n):
            for col in range(n):
                d = a[r, col] - b[r, col]
                root[r, col] = math.sqrt(d * d + 4.0 * c[r, col] * c[r, col] + tiny)
                u[r, col] = 0.5 * (a[r, col] + b[r, col] - root[r, col] + sqrt_tiny)
                corners[r, col] = max(u[r, col], 0.0)
                corner_sum += corners[r, col]
                k = corners[r, col]
                o = k / (k + oe)
                salient[r * n + col] = sal[r, col] * (o * o)
        for j in range(nc):
            surround[j] = 0.0
        for i in range(nc):  # surround = salient @ annulus (rows of the annulus contiguous)
            si = salient[i]
            for j in range(nc):
                surround[j] += si * annulus[i, j]
        mass = 0.0
        for i in range(nc):
            den[i] = salient[i] + iso * surround[i] + tiny
            subject[i] = salient[i] * salient[i] / den[i]
            mass += subject[i]
        e_presence = math.exp(-mass / consts[K_PRESENCE_MASS])
        presence = 1.0 - e_presence

        above, busy_sum, q_sum, p_sum, s2_sum, sal_sum, ring_sum = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        for r in range(n):
            for col in range(n):
                i = r * n + col
                e = jxx[r, col] + jyy[r, col]
                above += max(e - consts[K_EDGE_FLOOR], 0.0)
                busy_sum += e / (e + consts[K_BUSY_ENERGY])
                q[i] = e + sal_floor2
                q_sum += q[i]
                s2 = subject[i] * subject[i]
                p[i] = s2 + sal_floor2
                p_sum += p[i]
                s2_sum += s2
                sal_sum += salient[i]
                ring_sum += salient[i] * ring[r, col]
        z_lines = above / nc / consts[K_EDGE]
        e_lines = math.exp(-z_lines)
        lines = 1.0 - e_lines
        z_content = corner_sum / nc / consts[K_CONTENT_OBJECT] + consts[K_LINES_CONTENT] * lines
        e_content = math.exp(-z_content)
        content = 1.0 - e_content

        thirds, cx, cy = 0.0, 0.0, 0.0
        s2_den = s2_sum + tiny
        mx, my = 0.0, 0.0
        for r in range(n):
            for col in range(n):
                i = r * n + col
                p[i] = p[i] / p_sum
                q[i] = q[i] / q_sum
                thirds += p[i] * thirds_t[r, col]
                w = 0.5 * (p[i] + q[i])
                cx += w * xg[r, col]
                cy += w * yg[r, col]
                m[i] = subject[i] * subject[i] / s2_den
                mx += m[i] * xg[r, col]
                my += m[i] * yg[r, col]
        two_bs2 = 2.0 * consts[K_BALANCE_SIGMA] ** 2
        balance = math.exp(-((cx - 0.5) ** 2 + 0.25 * (cy - 0.5) ** 2) / two_bs2)

        ring_den = sal_sum + consts[K_RING_FLOOR] * nc
        ring_share = ring_sum / ring_den
        border = math.exp(-max(ring_share - consts[K_BORDER_FREE], 0.0) / consts[K_BORDER_SCALE])

        vxx, vyy, vxy, mdx, mdy = 0.0, 0.0, 0.0, 0.0, 0.0
        for r in range(n):
            for col in range(n):
                i = r * n + col
                dx, dy = xg[r, col] - mx, yg[r, col] - my
                vxx += m[i] * dx * dx
                vyy += m[i] * dy * dy
                vxy += m[i] * dx * dy
                mdx += m[i] * dx
                mdy += m[i] * dy
        det_raw = vxx * vyy - vxy * vxy
        root_det = math.sqrt(max(det_raw, 0.0) + tiny)
        area = consts[K_AREA_GAIN] * 2.0 * math.pi * root_det
        log_area = math.log(area / consts[K_IDEAL_AREA])
        s_sigma2 = consts[K_SIZE_LOG_SIGMA] ** 2
        subject_size = math.exp(-(log_area * log_area) / (2.0 * s_sigma2))

        busy = busy_sum / nc
        clutter = 1.0 / (1.0 + math.exp(-(consts[K_CLUTTER_MID] - busy) / consts[K_CLUTTER_WIDTH]))

        # horizon
        for r in range(n):
            for col in range(n):
                x3 = jxy[r, col]
                line[r, col] = max(jyy[r, col] - jxx[r, col] - 0.25 * (math.sqrt(x3 * x3 + eps) - sqrt_eps), 0.0)
            for k3 in range(3):
                s = 0.0
                for col in range(n):
                    s += line[r, col] * tw[col, k3]
                lt[r, k3] = s
        ls_max = -np.inf
        for r in range(n):
            acc = 0.0
            for k3 in range(3):
                s = 0.0
                for rr in range(n):
                    s += row_blur[r, rr] * lt[rr, k3]
                parts[r, k3] = s
                acc += math.log(s + eps)
            log_span[r] = acc / 3.0
            span[r] = math.exp(log_span[r])
            ls_max = max(ls_max, 4.0 * log_span[r])
        w_sum = 0.0
        for r in range(n):
            w4[r] = math.exp(4.0 * log_span[r] - ls_max)
            w_sum += w4[r]
        strength, yv = 0.0, 0.0
        for r in range(n):
            w4[r] /= w_sum
            strength += w4[r] * span[r]
            yv += w4[r] * rows[r]
        e_horizon = math.exp(-strength / consts[K_HORIZON_ENERGY])
        horizon = 1.0 - e_horizon
        s2h = 2.0 * consts[K_HORIZON_SIGMA] ** 2
        g1 = math.exp(-((yv - 1.0 / 3.0) ** 2) / s2h)
        g2 = math.exp(-((yv - 2.0 / 3.0) ** 2) / s2h)
        placement = min(g1 + g2, 1.0)
        band_var = 2.0 * (2.0 / n) ** 2
        sxy, syy = 0.0, 0.0
        for r in range(n):
            band[r] = math.exp(-((rows[r] - yv) ** 2) / band_var)
            sx, sy = 0.0, 0.0
            for col in range(n):
                sx += jxy[r, col]
                sy += jyy[r, col]
            row_jxy[r], row_jyy[r] = sx, sy
            sxy += band[r] * sx
            syy += band[r] * sy
        tilt_root = math.sqrt(syy * syy + sxy * sxy + eps)
        sin_tilt = sxy / tilt_root
        tol = consts[K_TILT_TOL]
        level = math.exp(-(sin_tilt * sin_tilt) / (2.0 * tol * tol))

        # the score: horizon terms weighted by its presence, subject terms earned by the subject's
        t = (thirds, balance, border, placement, level, clutter, subject_size)
        num, w_tot = 0.0, 0.0
        for k in range(7):
            wk = weights[k] * (horizon if (k == 3 or k == 4) else 1.0)
            ek = presence if (k == 0 or k == 2 or k == 6) else 1.0
            num += wk * ek * t[k]
            w_tot += wk
        w_den = w_tot + eps
        composition = num / w_den
        terms[bi, T_SCORE] = content * composition
        terms[bi, T_THIRDS] = thirds
        terms[bi, T_BALANCE] = balance
        terms[bi, T_BORDER] = border
        terms[bi, T_PLACEMENT] = placement
        terms[bi, T_LEVEL] = level
        terms[bi, T_CLUTTER] = clutter
        terms[bi, T_SIZE] = subject_size
        terms[bi, T_CONTENT] = content
        terms[bi, T_PRESENCE] = presence
        terms[bi, T_HORIZON] = horizon
        if not want_grad:
            continue

        # ---------------------------------------------------------------- backward (of the score)
        d_content = composition
        d_num = content / w_den
        d_wden = -content * num / (w_den * w_den)
        dt = np.zeros(7)
        d_presence, d_horizon = 0.0, 0.0
        for k in range(7):
            hk = k == 3 or k == 4
            sk = k == 0 or k == 2 or k == 6
            wk = weights[k] * (horizon if hk else 1.0)
            ek = presence if sk else 1.0
            dt[k] = d_num * wk * ek
            if sk:
                d_presence += d_num * wk * t[k]
            if hk:
                d_horizon += (d_num * ek * t[k] + d_wden) * weights[k]
        for r in range(n):
            for col in range(n):
                g_sal[r, col] = 0.0
                g_jxx[r, col] = 0.0
                g_jyy[r, col] = 0.0
                g_jxy[r, col] = 0.0
                g_corners[r, col] = 0.0
        for i in range(nc):
            g_salient[i] = 0.0
            g_subject[i] = 0.0
            g_energy[i] = 0.0

        # content = 1 - exp(-(mean(corners) / CO + LC * lines)); lines = 1 - exp(-mean(relu(e - floor)) / E)
        dz = d_content * e_content
        d_lines = dz * consts[K_LINES_CONTENT]
        dc_cell = dz / (consts[K_CONTENT_OBJECT] * nc)
        dzl = d_lines * e_lines / (consts[K_EDGE] * nc)
        # presence = 1 - exp(-mass / PM)
        d_mass = d_presence * e_presence / consts[K_PRESENCE_MASS]
        # balance
        d_e = -dt[1] * balance / two_bs2
        d_cx = d_e * 2.0 * (cx - 0.5)
        d_cy = d_e * 0.5 * (cy - 0.5)
        # border = exp(-relu(rs - free) / scale)
        d_rs = 0.0
        if ring_share - consts[K_BORDER_FREE] > 0.0:
            d_rs = -dt[2] * border / consts[K_BORDER_SCALE]
        # subject size: exp(-log(area / ideal)^2 / (2 s^2)), area = G 2 pi sqrt(relu(det) + tiny)
        d_log_area = -dt[6] * subject_size * log_area / s_sigma2
        d_det = 0.0
        if det_raw > 0.0:
            d_det = d_log_area / area * consts[K_AREA_GAIN] * 2.0 * math.pi * 0.5 / root_det
        d_vxx, d_vyy, d_vxy = d_det * vyy, d_det * vxx, -2.0 * d_det * vxy
        d_mx = -2.0 * d_vxx * mdx - d_vxy * mdy
        d_my = -2.0 * d_vyy * mdy - d_vxy * mdx
        # clutter = sigmoid((mid - busy) / width), busy = mean(e / (e + BE))
        d_busy = -dt[5] * clutter * (1.0 - clutter) / consts[K_CLUTTER_WIDTH]
        # p, q normalised: d raw = (d p - sum(d p * p)) / sum(raw)
        gp_dot, gq_dot, gm_dot = 0.0, 0.0, 0.0
        for r in range(n):
            for col in range(n):
                i = r * n + col
                g_p[i] = dt[0] * thirds_t[r, col] + 0.5 * (d_cx * xg[r, col] + d_cy * yg[r, col])
                g_q[i] = 0.5 * (d_cx * xg[r, col] + d_cy * yg[r, col])
                dx, dy = xg[r, col] - mx, yg[r, col] - my
                g_m[i] = d_vxx * dx * dx + d_vyy * dy * dy + d_vxy * dx * dy + d_mx * xg[r, col] + d_my * yg[r, col]
                gp_dot += g_p[i] * p[i]
                gq_dot += g_q[i] * q[i]
                gm_dot += g_m[i] * m[i]
        for r in range(n):
            for col in range(n):
                i = r * n + col
                e = jxx[r, col] + jyy[r, col]
                ge = (g_q[i] - gq_dot) / q_sum
                ge += d_busy / nc * consts[K_BUSY_ENERGY] / ((e + consts[K_BUSY_ENERGY]) ** 2)
                if e - consts[K_EDGE_FLOOR] > 0.0:
                    ge += dzl
                g_energy[i] = ge
                s = subject[i]
                # p = s^2 + floor^2 (over its sum); m = s^2 / (sum s^2 + tiny)
                g_subject[i] = d_mass + (g_p[i] - gp_dot) / p_sum * 2.0 * s + (g_m[i] - gm_dot) / s2_den * 2.0 * s
                g_salient[i] = d_rs * (ring[r, col] / ring_den - ring_sum / (ring_den * ring_den))
                g_corners[r, col] = dc_cell
        # subject = salient^2 / (salient + iso * surround + tiny)
        for i in range(nc):
            s, dn = salient[i], den[i]
            gs = g_subject[i]
            g_salient[i] += gs * (2.0 * s / dn - s * s / (dn * dn))
            g_surround[i] = -gs * s * s / (dn * dn) * iso
        for j in range(nc):  # surround = salient @ annulus: g_salient += annulus @ g_surround
            gj = g_surround[j]
            for i in range(nc):
                g_salient[i] += annulus_t[j, i] * gj
        # salient = sal * objectness(corners); corners = relu(u)
        for r in range(n):
            for col in range(n):
                i = r * n + col
                k = corners[r, col]
                o = k / (k + oe)
                g_sal[r, col] = g_salient[i] * o * o
                g_corners[r, col] += g_salient[i] * sal[r, col] * 2.0 * o * oe / ((k + oe) * (k + oe))
                gu = g_corners[r, col] if u[r, col] > 0.0 else 0.0
                g_root = -0.5 * gu / (2.0 * root[r, col])  # d root / d D = 1 / (2 root)
                d = a[r, col] - b[r, col]
                g_a[r, col] = 0.5 * gu + g_root * 2.0 * d
                g_b[r, col] = 0.5 * gu - g_root * 2.0 * d
                g_c[r, col] = g_root * 8.0 * c[r, col]
        _sandwich_t(box3, box3_t, g_a, g_x, tmp)
        for r in range(n):
            for col in range(n):
                g_jxx[r, col] += g_x[r, col]
        _sandwich_t(box3, box3_t, g_b, g_x, tmp)
        for r in range(n):
            for col in range(n):
                g_jyy[r, col] += g_x[r, col]
        _sandwich_t(box3, box3_t, g_c, g_x, tmp)
        for r in range(n):
            for col in range(n):
                g_jxy[r, col] += g_x[r, col]

        # horizon: presence, placement, level -> y, strength, the band sums -> log_span -> line
        d_strength = d_horizon * e_horizon / consts[K_HORIZON_ENERGY]
        d_y = 0.0
        if g1 + g2 <= 1.0:
            d_y += dt[3] * (g1 * (-2.0 * (yv - 1.0 / 3.0) / s2h) + g2 * (-2.0 * (yv - 2.0 / 3.0) / s2h))
        d_sin = -dt[4] * level * sin_tilt / (tol * tol)
        root3 = tilt_root * tilt_root * tilt_root
        d_sxy = d_sin * (1.0 / tilt_root - sxy * sxy / root3)
        d_syy = d_sin * (-sxy * syy / root3)
        for r in range(n):
            d_band = d_sxy * row_jxy[r] + d_syy * row_jyy[r]
            d_y += d_band * band[r] * 2.0 * (rows[r] - yv) / band_var
            for col in range(n):
                g_jxy[r, col] += d_sxy * band[r]
                g_jyy[r, col] += d_syy * band[r]
        w_dot = 0.0
        for r in range(n):
            g_w4[r] = d_strength * span[r] + d_y * rows[r]
            w_dot += g_w4[r] * w4[r]
        for r in range(n):
            d_ls = 4.0 * w4[r] * (g_w4[r] - w_dot) + d_strength * w4[r] * span[r]
            for k3 in range(3):
                g_parts[r, k3] = d_ls / (3.0 * (parts[r, k3] + eps))
        for rr in range(n):
            for k3 in range(3):
                s = 0.0
                for r in range(n):
                    s += row_blur[r, rr] * g_parts[r, k3]
                g_lt[rr, k3] = s
        for r in range(n):
            for col in range(n):
                if line[r, col] > 0.0:
                    gl = g_lt[r, 0] * tw[col, 0] + g_lt[r, 1] * tw[col, 1] + g_lt[r, 2] * tw[col, 2]
                    x3 = jxy[r, col]
                    g_jyy[r, col] += gl
                    g_jxx[r, col] -= gl
                    g_jxy[r, col] -= gl * 0.25 * x3 / math.sqrt(x3 * x3 + eps)

        # energy = jxx + jyy; the clamps (torch's: the gradient passes at the bounds)
        for r in range(n):
            for col in range(n):
                i = r * n + col
                g_jxx[r, col] += g_energy[i]
                g_jyy[r, col] += g_energy[i]
                for ch in range(4):
                    v = fmap[bi, ch, r, col]
                    inside = v >= -lim and v <= lim
                    if ch == 0:
                        g = g_sal[r, col] if (inside and f[0, r, col] >= 0.0) else 0.0
                    elif ch == 1:
                        g = g_jxx[r, col] if (inside and f[1, r, col] >= 0.0) else 0.0
                    elif ch == 2:
                        g = g_jyy[r, col] if (inside and f[2, r, col] >= 0.0) else 0.0
                    else:
                        g = g_jxy[r, col] if inside else 0.0
                    grad[bi, ch, r, col] = g
