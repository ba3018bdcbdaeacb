"""Rasterizer numerics, shared by every backend (gsplat / Inria conventions; docs/rasterizer.md).

* Gaussians with camera z-depth ``<= NEAR_M`` or ``>= FAR_M`` are culled.
* ``BLUR_PX2`` is added to the diagonal of every projected 2D covariance (anti-aliasing floor).
* The 2D covariance determinant is clamped at ``DET_MIN`` before inversion.
* The Jacobian of the projection uses ``x/z`` and ``y/z`` clamped to ``FRUSTUM_SLACK`` half
  fields of view beyond the image border (gsplat), so Gaussians far outside the view do not
  get huge footprints from a linearisation that no longer holds.
* Per pixel: ``sigma = 0.5 (A dx^2 + C dy^2) + B dx dy`` with the conic ``(A, B, C)`` and
  ``(dx, dy)`` from the Gaussian's 2D mean to the pixel centre (``+0.5``); ``sigma < 0`` is
  skipped; ``alpha = min(ALPHA_MAX, opacity * exp(-sigma))``; ``alpha < ALPHA_MIN`` is skipped.
* Front to back: a Gaussian that would bring the transmittance ``T (1 - alpha)`` to
  ``T_STOP`` or below is not composited and ends the pixel.
* Backward divides by ``max(ONE_MINUS_ALPHA_MIN, 1 - alpha)``.
* Images are cut in ``TILE`` x ``TILE`` pixel tiles; a Gaussian is listed in every tile that its
  ``alpha >= ALPHA_MIN`` pixel box (widened by ``BOX_MARGIN_PX`` against rounding) touches.
"""

from __future__ import annotations

import math

NEAR_M = 0.01
FAR_M = 1e10
BLUR_PX2 = 0.3
DET_MIN = 1e-10
FRUSTUM_SLACK = 0.3
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_STOP = 1e-4
ONE_MINUS_ALPHA_MIN = 1e-6
# sigma is clamped here before exp(-sigma). Any sigma above ln(255) ~ 5.5 already gives
# alpha < ALPHA_MIN for opacity <= 1 (the pixel is skipped, value and gradient), so the clamp never
# changes a result; it keeps exp away from denormals (slow on CPUs; figures: docs/benchmarks.md,
# "Figures behind code comments") and inside [0, 16], where the compiled kernels' polynomial exp
# is accurate (relative error 1e-7 in float32).
SIGMA_CLAMP = 16.0
LOG_INV_ALPHA_MIN = math.log(255.0)
# depth = sum(w z) / max(alpha, DEPTH_ALPHA_MIN); alpha is 0 or at least ~1/255 where drawn
DEPTH_ALPHA_MIN = 1e-10
# Tile side in pixels (both tiled backends): one tile row is one 16-lane vector in the kernels.
TILE = 16
# The alpha >= 1/255 pixel box is widened by this much against rounding; the per-pixel test decides.
BOX_MARGIN_PX = 1e-2
