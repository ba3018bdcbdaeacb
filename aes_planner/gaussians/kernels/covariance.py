from __future__ import annotations

import math

import numpy as np
from numba import njit

from aes_planner.gaussians.kernels.common import _opts, _quat_rotation


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
