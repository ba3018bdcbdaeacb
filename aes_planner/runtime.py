"""Process-wide runtime settings for the compute: CPU threads (torch's intra-op pool and numba's
rasterizer), how long torch's idle OpenMP threads spin, and glibc malloc's thresholds.

* **Threads.** On a 2-core machine with another busy process, torch's OpenMP threads spin
  against it and a ``balanced`` suggestion takes about 2.5x longer with 2 threads than with 1;
  idle, 2 threads are faster. The planner node and ``aes-planner suggest`` take the count as a
  knob (``threads``, 0 = torch's default: all cores).
* **OpenMP spinning.** torch's threads (GNU OpenMP) spin ``GOMP_SPINCOUNT`` rounds after each
  parallel op before they sleep: 300,000 by default, long enough that they were still spinning
  on both cores while the rasterizer's threads ran next. :func:`tune_openmp` lowers it to
  30,000 (unless ``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY`` is set): the rasterizer's share of a
  ``balanced`` suggestion went from 136-164 ms to 108-115 ms, the whole suggestion from
  614-738 ms to 575-614 ms. libgomp reads it once, when torch loads it, so the package sets it
  on import, before it imports torch; a process that imported torch first keeps the default.
  Beside a busy process it does not help (the ``threads`` knob does).
* **malloc.** glibc serves large blocks with fresh ``mmap`` pages and raises that threshold as
  blocks are freed, so the same array is sometimes fresh pages, sometimes recycled heap.
  Fresh pages first touched by both threads of a parallel kernel (the rasterizer's per-thread
  gradient buffers) fault under one lock, and freeing them flushes the other core's TLB: a
  view's forward+backward flipped between 8 and 12-13 ms within one process. Fixed thresholds
  keep such blocks on the heap.

Figures: docs/benchmarks.md, "Threading layer".
"""

from __future__ import annotations

import ctypes
import logging
import os
import sys

__all__ = ["GOMP_SPINCOUNT", "MAX_THREADS", "set_threads", "tune_malloc", "tune_openmp"]

log = logging.getLogger(__name__)

# glibc's mallopt parameters (malloc.h); 32 MiB is the largest mmap threshold glibc accepts on
# 64-bit systems
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 32 << 20
TRIM_THRESHOLD_BYTES = 64 << 20
_tuned: bool | None = None
#: Most CPU threads any setting may ask for (numba segfaulted at 100000).
MAX_THREADS = 256
#: Spin rounds of torch's idle OpenMP threads before they sleep (libgomp's default: 300,000).
GOMP_SPINCOUNT = 30_000


def tune_openmp() -> bool:
    """Set ``GOMP_SPINCOUNT`` for this process and its children unless the caller chose a wait
    policy (``GOMP_SPINCOUNT`` or ``OMP_WAIT_POLICY`` set). Effective only before torch is
    imported (libgomp reads it once, when loaded). Returns whether the value is ours."""
    if any(name in os.environ for name in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")):
        return False
    if "torch" in sys.modules:
        log.debug("torch is already imported: its OpenMP threads keep their default spin count")
    os.environ["GOMP_SPINCOUNT"] = str(GOMP_SPINCOUNT)
    return True


def set_threads(n: int) -> None:
    """Use ``n`` CPU threads: torch's for the whole process, numba's for the calling thread (numba
    counts per thread, so call it from the thread that renders)."""
    if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= MAX_THREADS:
        raise ValueError(f"threads: must be an integer in [1, {MAX_THREADS}], got {n!r}")
    import torch  # here, not at the top: the package imports this module before torch

    torch.set_num_threads(n)
    try:
        import numba
    except ImportError:  # the torch backend needs no numba
        return
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))


def tune_malloc() -> bool:
    """Fix glibc malloc's mmap threshold at 32 MiB and its trim threshold at 64 MiB, once per
    process. Left alone when ``MALLOC_MMAP_THRESHOLD_`` or ``MALLOC_TRIM_THRESHOLD_`` is set
    (the caller's choice) and off glibc Linux. Returns whether the thresholds are ours."""
    global _tuned
    if _tuned is not None:
        return _tuned
    _tuned = False
    if not sys.platform.startswith("linux") or any(
        name in os.environ for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
    ):
        return _tuned
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return _tuned
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    _tuned = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )
    log.debug("malloc thresholds %s", "fixed" if _tuned else "left to glibc (mallopt refused)")
    return _tuned
