"""Readying the rasterizer's compiled kernels before the first render needs them.

The dispatcher (:func:`~aes_planner.gaussians.rasterize.resolve_backend`) says which backend
would run; the numba backend compiles or loads its kernels. This module asks the one and drives
the other, so neither imports the other back."""

from __future__ import annotations

import logging

import torch

from aes_planner.gaussians import numba_backend
from aes_planner.gaussians.rasterize import resolve_backend

log = logging.getLogger(__name__)

__all__ = ["COMPILED_AFTER_S", "warm_kernels"]

#: A warm-up slower than this compiled the kernels (loading them from numba's cache takes ~0.5 s).
COMPILED_AFTER_S = 5.0


def warm_kernels() -> float | None:
    """Compile or load the float32 kernels of the backend ``rasterize`` would run, before the
    first render needs them: on a fresh install numba compiles them once (~40 s on two cores)
    and caches them on disk. Returns the seconds taken, ``None`` when the torch backend runs
    (nothing to compile). Logs a warning when it compiled."""
    if resolve_backend() != "numba":
        return None
    took_s = numba_backend.warmup(torch.float32)
    if took_s > COMPILED_AFTER_S:
        log.warning(
            "compiled the rasterizer's kernels in %.0f s (the first run after an install does; "
            "`aes-planner warmup`, run by `make install`, does it ahead)",
            took_s,
        )
    return took_s
