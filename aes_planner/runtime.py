"""Process-wide runtime settings for the compute: CPU threads (torch's intra-op pool and numba's
rasterizer), how long torch's idle OpenMP threads spin, and glibc malloc's thresholds.

* **Threads.** On a 2-core machine with another busy process, torch's OpenMP threads spin
  against it and a ``balanced`` suggestion takes about 2.5x longer with 2 threads than with 1;
  idle, 2 threads are faster. The planner node and ``aes-planner suggest`` take the count as a
  knob (``threads``, 0 = torch's default: all cores). With all cores, the node's
  :class:`ThreadGovernor` (``adapt_threads``) notices when its suggestions stop getting the
  cores they ask for, tries one thread, and keeps whichever count runs them faster.
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
import math
import os
import statistics
import sys
from collections import deque

__all__ = [
    "GOMP_SPINCOUNT",
    "MAX_THREADS",
    "ThreadGovernor",
    "available_cores",
    "set_threads",
    "tune_malloc",
    "tune_openmp",
]

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


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask; the CPU count where there is none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


class ThreadGovernor:
    """Chooses the thread count of repeated compute-bound jobs (the planner's suggestions) by
    trying one thread when the jobs do not get the cores they ask for, and keeping whichever
    count ran faster.

    The trigger is each job's CPU efficiency, ``CPU time / (wall time x threads)``. Idle, a
    ``balanced`` suggestion on 2 threads runs at 0.84-0.91 (a process's first one at 0.60-0.65);
    beside one busy process at 0.50, when its threads wait for each other at every parallel op:
    2.5 s against 0.8 s on one thread (docs/benchmarks.md, "Threading layer"). But a low
    efficiency does not always mean one thread is faster (the closed loop's larger jobs beside a
    busy process: 2.6 s on two threads, 2.9 s on one), so the count is settled by wall times:

    * after ``patience`` jobs in a row below ``low_efficiency`` on all threads, a **trial** of
      ``patience`` jobs on one thread; their median wall time against the median of the jobs just
      before decides. A lost trial returns to all threads and waits ``backoff`` jobs before the
      trigger may fire again;
    * on one thread, every ``backoff`` jobs a **probe** of one job on all threads, kept if it beat
      the median of the one-thread jobs before it;
    * ``backoff`` starts at ``probe_every`` and doubles after each lost trial or probe, up to
      ``max_probe_every``; a won one resets it.

    Jobs are assumed to change size slowly (the field grows by a frame at a time). ``observe``
    after each job returns the count for the next one."""

    def __init__(
        self,
        max_threads: int,
        low_efficiency: float = 0.65,
        patience: int = 2,
        probe_every: int = 8,
        max_probe_every: int = 64,
    ) -> None:
        if not isinstance(max_threads, int) or isinstance(max_threads, bool) or not 1 <= max_threads <= MAX_THREADS:
            raise ValueError(f"max_threads: must be an integer in [1, {MAX_THREADS}], got {max_threads!r}")
        if not 0.0 < low_efficiency < 1.0:
            raise ValueError(f"low_efficiency: must be in (0, 1), got {low_efficiency!r}")
        if not isinstance(patience, int) or isinstance(patience, bool) or patience < 1:
            raise ValueError(f"patience: must be an integer >= 1, got {patience!r}")
        if not 1 <= probe_every <= max_probe_every:
            raise ValueError(
                f"probe_every: need 1 <= probe_every <= max_probe_every, got {probe_every}, {max_probe_every}"
            )
        self.max_threads = max_threads
        self.low_efficiency = low_efficiency
        self.patience = patience
        self.probe_every = probe_every
        self.max_probe_every = max_probe_every
        self.threads = max_threads
        self.backoff = probe_every
        self.walls = {1: deque(maxlen=patience), max_threads: deque(maxlen=patience)}  # recent wall s per count
        self.low_run = 0  # jobs in a row below low_efficiency on all threads
        self.jobs_here = 0  # jobs since the last switch
        self.quiet = 0  # jobs on all threads before the trigger may fire again
        self.trial = False
        self.probing = False
        self.changes = 0
        self.last_efficiency = math.nan

    def observe(self, wall_s: float, cpu_s: float) -> int:
        """Record one job; returns the thread count for the next. Jobs too short to judge (wall
        under 10 ms) and non-finite or negative times change nothing."""
        if not (math.isfinite(wall_s) and math.isfinite(cpu_s)) or wall_s < 0.01 or cpu_s < 0:
            return self.threads
        if self.max_threads == 1:
            return 1
        self.last_efficiency = cpu_s / (wall_s * self.threads)
        self.walls[self.threads].append(wall_s)
        self.jobs_here += 1
        if self.threads > 1:
            if self.probing:  # one job on all threads against the one-thread jobs before it
                self.probing = False
                self._settle(won=wall_s < _median(self.walls[1]), loser=1)
            else:
                self.low_run = self.low_run + 1 if self.last_efficiency < self.low_efficiency else 0
                if self.low_run >= self.patience and not self.quiet:
                    self.trial = True
                    self._switch(1)
                self.quiet = max(0, self.quiet - 1)
        elif self.trial:
            if self.jobs_here >= self.patience:  # one thread against the jobs that set off the trial
                self.trial = False
                won = _median(self.walls[1]) < _median(self.walls[self.max_threads])
                self._settle(won=won, loser=self.max_threads)
                if not won:
                    self.quiet = self.backoff
        elif self.jobs_here >= self.backoff:
            self.probing = True
            self._switch(self.max_threads)
        return self.threads

    def _settle(self, won: bool, loser: int) -> None:
        """After a trial or probe: keep the count it tried if it won, else go back to ``loser``."""
        if won:
            self.backoff = self.probe_every
        else:
            self.backoff = min(2 * self.backoff, self.max_probe_every)
            self._switch(loser)

    def _switch(self, n: int) -> None:
        log.info("threads %d -> %d (last job's CPU efficiency %.2f)", self.threads, n, self.last_efficiency)
        self.threads = n
        self.walls[n].clear()
        self.jobs_here = 0
        self.low_run = 0
        self.changes += 1


def _median(values) -> float:
    return statistics.median(values) if values else math.inf


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
