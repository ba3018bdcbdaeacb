"""CPU threads of the process's compute: torch's intra-op pool and numba's rasterizer.

On a 2-core machine with another busy process, torch's OpenMP threads spin against it and a
``balanced`` suggestion takes about 2.5x longer with 2 threads than with 1; on an idle machine 2
threads are faster (figures: docs/benchmarks.md, "Threading layer"). The planner node and
``aes-planner suggest`` take the count as a knob (``threads``, 0 = torch's default: all cores).
"""

from __future__ import annotations

import torch

__all__ = ["set_threads"]


def set_threads(n: int) -> None:
    """Use ``n`` CPU threads: torch's for the whole process, numba's for the calling thread (numba
    counts per thread, so call it from the thread that renders)."""
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise ValueError(f"threads: must be an integer >= 1, got {n!r}")
    torch.set_num_threads(n)
    try:
        import numba
    except ImportError:  # the torch backend needs no numba
        return
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
