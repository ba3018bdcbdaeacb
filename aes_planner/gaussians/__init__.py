"""3D Gaussians and their differentiable, batched rasterizer.

* :class:`Gaussians`: means, quaternions (wxyz), log-scales, activated opacities, colours,
  C feature channels and per-Gaussian provenance; concatenation, indexing, ``.to()``, save/load.
* :func:`rasterize`: B cameras -> RGB ``[B,3,H,W]``, features ``[B,C,H,W]``, depth and alpha
  ``[B,H,W]``, differentiable w.r.t. the poses and every Gaussian parameter. Backends and how to
  pick one: :mod:`aes_planner.gaussians.rasterize`.
* :func:`~aes_planner.gaussians.reference.rasterize_dense`: the plain dense reference (tests and
  benchmarks only).
* :func:`random_scene`: seeded synthetic scenes for tests and benchmarks.
"""

from aes_planner.gaussians.container import GaussianError, Gaussians
from aes_planner.gaussians.grad_mode import autograd_on
from aes_planner.gaussians.rasterize import (
    BACKEND_ENV,
    BACKENDS,
    RasterOutput,
    rasterize,
    resolve_backend,
)
from aes_planner.gaussians.synthetic import random_scene

__all__ = [
    "BACKENDS",
    "BACKEND_ENV",
    "GaussianError",
    "Gaussians",
    "RasterOutput",
    "autograd_on",
    "random_scene",
    "rasterize",
    "resolve_backend",
]
