from __future__ import annotations

import ctypes
import math
import os
import site
import sys

import numba
import numpy as np
from numba import njit, types
from numba.extending import overload

from aes_planner.gaussians.numerics import (
    ALPHA_MAX,
    ALPHA_MIN,
    ONE_MINUS_ALPHA_MIN,
    SIGMA_CLAMP,
    T_STOP,
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

# Value channels + depth from which the channel loops go innermost (only contributing pixels
# visited) instead of pixels innermost. The forward's pixels-innermost loops stayed faster up to 36
# channels (measured on 8-lane row windows); the backward's need it from 8 (2.2x at 36 channels;
# docs/journal/rasterizer.md, "Alias checks, the 8-lane backward").
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
# docs/journal/rasterizer.md, "False sharing")
G_CAM_STRIDE = NPOSE + 8

_opts = dict(cache=True, error_model="numpy")


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
            # 2^-n built from its float32 bits (exponent 127 - n; n <= 23 here): exact, as the
            # product p 2^-n is. A shift by the variable n (1 << (24 - n)) ran as 64-bit shifts on
            # widened lanes, numba widening int32 arithmetic to int64; a shift by a constant narrows.
            return p * np.int32(np.int32(np.int32(127) - n) << np.int32(23)).view(np.float32)

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
