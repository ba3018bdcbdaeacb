"""Compiled CPU kernels of the rasterizer (numba, ``cache=True``), one module per stage. Imported
only when used (by :mod:`aes_planner.gaussians.numba_backend`).

Pipeline per call (B cameras, N Gaussians, Cv = 3 + C value channels, tiles of TILE x TILE px):

1-2. ``project_fwd``: per Gaussian the world covariance (float64, shared by all cameras), then
   per camera the EWA projection in float64 -> packed image-space parameters and the pixel box
   of the ``alpha >= 1/255`` ellipse (empty box = culled).
3. ``bin_cameras`` / ``fill_lists``: per camera, a stable radix sort of the visible Gaussians by
   depth, then per-tile lists in that order (counting pass, prefix sum, fill): no per-tile sorts.
   Cameras go to threads; a single camera splits in two (sort beside count, then two bands of fill).
4. ``raster_fwd``: parallel over (camera, tile), tiles interleaved across threads. Each Gaussian
   of the tile's depth-sorted list walks the tile rows of its ``alpha >= 1/255`` box as one
   contiguous run of pixels (rows x TILE; sigma, exp, alpha, transmittance, stop rule,
   vectorised across rows), then accumulates its values over the run pixel-wise (up to 63
   channels) or per contributing pixel with the channels innermost (64 or more). A tile stops
   once all its pixels are saturated. Stores the final transmittance and, per pixel, the list
   position after its last contributor.
5. ``raster_bwd``: the same traversal in reverse from the stored final transmittance (gsplat's
   backward) over the same runs, the gradient terms reduced over each run; channels pixel-wise
   up to 7, per contributing pixel from 8 (through one dot product per pixel). Parallel
   over cameras when there are enough of them (no write conflicts), else over tiles with a
   buffer per worker (a fixed share of the items, whichever thread runs it: the sums' order, and
   so every bit of the gradients, is the same from call to call).
6. ``project_bwd``: per Gaussian, the chain rule through projection and covariance for every
   camera; camera-pose gradients go to a buffer per worker (a fixed block of Gaussians).

Everything geometric is float64; image-space parameters and outputs are in the Gaussians' dtype.

Modules: ``common`` (threading layer, packed layouts, the typed constants, ``exp_neg``, 3x3
algebra), ``covariance`` (1), ``project`` (2), ``binning`` (3), ``tiles`` (the tile traversal
the forward and backward rasters share: a Gaussian's run of tile pixels and its row terms),
``raster_fwd`` (4), ``raster_bwd`` (5), ``project_bwd`` (6). Their twins (plain torch, for the tests) are in
:mod:`aes_planner.gaussians.twins`.
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def drop_stale_cache(here: Path = Path(__file__).parent, extra: tuple[Path, ...] = ()) -> None:
    """numba keys a cached kernel on the file that defines it, not on the files it calls into: a
    change to ``common.py`` (or to the constants in ``numerics.py``) would leave the stages'
    cached machine code in use. So the cache of this package is keyed here on all of its sources:
    when their hash changes, the package's cached kernels are removed and compile afresh."""
    sources = sorted(here.glob("*.py")) + list(extra)
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in sources)).hexdigest()
    cache = here / "__pycache__"
    stamp = cache / "kernel_sources.sha256"
    try:
        if stamp.is_file() and stamp.read_text().strip() == digest:
            return
        cache.mkdir(exist_ok=True)
        for path in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
            path.unlink()
        stamp.write_text(digest + "\n")
    except OSError as exc:  # a read-only install: numba caches elsewhere (NUMBA_CACHE_DIR) or not at all
        log.debug("kernel cache stamp not written: %s", exc)


drop_stale_cache(extra=(Path(__file__).parent.parent / "numerics.py",))

from aes_planner.gaussians.kernels.binning import bin_and_fill, bin_cameras, fill_lists  # noqa: E402
from aes_planner.gaussians.kernels.common import (  # noqa: E402
    CONSTS,
    G_CAM_STRIDE,
    NGRAD,
    NPOSE,
    NPROJ,
    numba,
)
from aes_planner.gaussians.kernels.project import camera_table, project_fwd  # noqa: E402
from aes_planner.gaussians.kernels.project_bwd import project_bwd  # noqa: E402
from aes_planner.gaussians.kernels.raster_bwd import raster_bwd  # noqa: E402
from aes_planner.gaussians.kernels.raster_fwd import raster_fwd  # noqa: E402

__all__ = [
    "CONSTS",
    "G_CAM_STRIDE",
    "NGRAD",
    "NPOSE",
    "NPROJ",
    "bin_and_fill",
    "bin_cameras",
    "camera_table",
    "fill_lists",
    "numba",
    "project_bwd",
    "project_fwd",
    "raster_bwd",
    "raster_fwd",
]
