"""Rasterizer numerics, shared by every backend (gsplat / Inria conventions, DESIGN.md).

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
# exp(-sigma) for sigma above this is below any alpha that survives ALPHA_MIN (exp(-80) ~ 1.8e-35);
# clamping avoids denormal exp results, which are ~60x slower on CPUs.
SIGMA_CLAMP = 80.0
LOG_INV_ALPHA_MIN = math.log(255.0)
