"""The one check that a 4x4 pose is rigid, in numpy only (messages import it without torch)."""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_COORD_M", "check_rigid"]

MAX_COORD_M = 1e12  # beyond any GNSS/UTM coordinate; keeps R^T R and every product finite


def check_rigid(value, name: str, tol: float, error: type[Exception]) -> np.ndarray:
    """``value`` as a float64 ``[4, 4]`` (a ``[3, 4]`` gets its last row) if it is a rigid transform:
    finite, translation within :data:`MAX_COORD_M`, last row ``[0, 0, 0, 1]``, rotation orthonormal
    to ``tol`` with determinant +1. Otherwise raises ``error`` naming ``name`` and what to fix.
    Entries are bounded before any product, so no check overflows."""
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{name} must be a 4x4 matrix of numbers, got {type(value).__name__}") from None
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if m.shape != (4, 4):
        raise error(f"{name}: expected a 4x4 (or 3x4) matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise error(f"{name}: contains NaN or Inf; every pose entry must be a finite number")
    if np.abs(m[:3, :3]).max() > 1.0 + tol:
        raise error(f"{name}: rotation is not orthonormal (entries exceed 1); export the pose as a rigid transform")
    if np.abs(m[:3, 3]).max() > MAX_COORD_M:
        raise error(f"{name}: translation beyond {MAX_COORD_M:g} m")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise error(f"{name}: last row must be [0, 0, 0, 1], got {m[3].tolist()}")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > tol:
        raise error(
            f"{name}: rotation is not orthonormal (max |R^T R - I| = {err:.3g}); "
            "export the pose as a rigid transform without scale or shear"
        )
    if np.linalg.det(r) < 0:
        raise error(f"{name}: rotation has determinant -1 (a reflection); check the axis convention")
    return m
