"""Process-wide runtime settings for the compute: CPU threads (torch's intra-op pool and numba's
rasterizer), how long torch's idle OpenMP threads spin, and glibc malloc's thresholds.

* **Threads.** On a 2-core machine with another busy process, torch's OpenMP threads spin
  against it and a ``balanced`` suggestion takes about 2.5x longer with 2 threads than with 1;
  idle, 2 threads are faster. Every suggestion is computed inside :func:`suggestion_threads`,
  the one place that picks its thread count: the library's :func:`~aes_planner.search.search_views`,
  ``aes-planner suggest``, ``bench search`` and the planner node. A count set explicitly
  (:func:`set_threads`: ``suggest --threads N``, a node's ``threads: N``) is kept. Otherwise a
  :class:`ThreadGovernor` picks it: the node's own (``adapt_threads``), or one per process
  for the others, which starts from the cores that are idle right now (:func:`threads_for_load`,
  a 50 ms look at ``/proc/stat``, or in the program a look over its own start-up:
  :func:`start_load_window`; one thread beside a busy process on two cores). A governor
  notices when suggestions stop getting the cores they ask for, tries one thread, probes all
  of them now and then, and keeps whichever count runs them faster.
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

import contextlib
import ctypes
import logging
import math
import os
import statistics
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass

__all__ = [
    "apply_pending_numba_threads",
    "GOMP_SPINCOUNT",
    "MAX_THREADS",
    "SuggestionJob",
    "ThreadGovernor",
    "available_cores",
    "idle_cores",
    "light_numba_cache_loads",
    "reset_suggestion_governor",
    "set_threads",
    "start_load_window",
    "suggestion_threads",
    "threads_for_load",
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
    counts per thread, so call it from the thread that renders). An explicit choice: the
    suggestions computed in this thread keep it (:func:`suggestion_threads` does not adapt it)."""
    if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= MAX_THREADS:
        raise ValueError(f"threads: must be an integer in [1, {MAX_THREADS}], got {n!r}")
    _apply_threads(n)
    _local.pinned = n


def _apply_threads(n: int) -> None:
    import torch  # here, not at the top: the package imports this module before torch

    numba = _numba()
    if numba is not None:
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    else:  # the kernels are not loaded yet: they take this count when they are (apply_pending_numba_threads)
        _local.pending_numba = n
    if torch.get_num_threads() != n:  # after numba: starting numba's OpenMP pool resets the shared count
        torch.set_num_threads(n)


def _numba():
    """numba once the rasterizer's kernels are loaded, else None. Until then numba is not touched:
    ``numba.set_num_threads`` starts numba's thread pool, and started before the kernels chose
    their threading layer (``tbb``) it fell back to ``omp``, whose start reset torch's shared
    OpenMP count: a count of 1 (beside a busy process) ran torch on 2 threads and numba on the
    layer that loses most beside a busy process (docs/benchmarks.md, perf-2). The first time, its
    cached kernels' loads are made lighter (:func:`light_numba_cache_loads`)."""
    if "aes_planner.gaussians.kernels" not in sys.modules:
        return None
    import numba

    light_numba_cache_loads()
    return numba


_light_loads: bool | None = None


def light_numba_cache_loads() -> bool:
    """Load numba's cached kernels without first refreshing its whole target context.

    Before it loads a kernel from its on-disk cache, numba (0.59-0.68, ``Cache.load_overload``)
    refreshes its target context: it imports ~70 of its modules (numpy's linalg, random,
    polynomials, typed containers, jitclass, cffi, scipy's BLAS), installs every typing and
    lowering registry and scans the installed packages' entry points for extensions. Only a
    compile uses them, and numba's compiler refreshes the context itself before every compile
    (``CompilerBase``); a cached kernel is machine code that needs numba's runtime (NRT) and
    nothing else. Here a load initialises the runtime and loads: the same kernels, ~100 ms less
    CPU in a cold ``aes-planner suggest`` (docs/benchmarks.md, "perf-2, session 27"). Once per
    process; numba is left as it is when its cache class is not the one this was written for.
    Returns whether the loads are the lighter ones."""
    global _light_loads
    if _light_loads is not None:
        return _light_loads
    _light_loads = False
    try:
        from numba.core import caching
        from numba.core.runtime import nrt
    except ImportError:
        return False
    cache = caching.Cache
    if not (
        hasattr(cache, "_load_overload")
        and hasattr(cache, "_guard_against_spurious_io_errors")
        and callable(getattr(getattr(nrt, "rtsys", None), "initialize", None))
    ):
        log.debug("numba's cache loads left as they are (numba %s: not the expected internals)", _version("numba"))
        return False

    def load_overload(self, sig, target_context):  # numba's Cache.load_overload without the refresh
        nrt.rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    cache.load_overload = load_overload
    _light_loads = True
    return True


def _version(module: str) -> str:
    return getattr(sys.modules.get(module), "__version__", "?")


def apply_pending_numba_threads() -> None:
    """Give numba the count this thread asked for before the kernels loaded (called by the
    numba backend once they are)."""
    n = getattr(_local, "pending_numba", None)
    numba = _numba()
    if n is not None and numba is not None:
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
        _local.pending_numba = None


def _numba_threads() -> int | None:
    numba = _numba()
    return None if numba is None else numba.get_num_threads()


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask; the CPU count where there is none)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _cpu_ticks(cpus: set[int]) -> tuple[int, int] | None:
    """``(idle, total)`` jiffies of ``cpus`` from /proc/stat (None where it cannot be read)."""
    try:
        with open("/proc/stat") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    idle = total = 0
    for line in lines:
        name, _, rest = line.partition(" ")
        if not (name.startswith("cpu") and name[3:].isdigit() and int(name[3:]) in cpus):
            continue
        ticks = [int(v) for v in rest.split()[:8]]  # user nice system idle iowait irq softirq steal
        idle += ticks[3] + ticks[4]
        total += sum(ticks)
    return (idle, total) if total else None


#: A look at the load started earlier (:func:`start_load_window`) serves the first
#: :func:`idle_cores` only while it is younger than this; older, the load then is not the load now.
LOAD_WINDOW_MAX_S = 10.0
_load_window: tuple[float, float, tuple[int, int]] | None = None  # (wall s, own CPU s, (idle, total) ticks)


def start_load_window() -> None:
    """Start a look at the load now that the process's first :func:`idle_cores` reads instead of
    waiting ``window_s`` for one of its own: the program calls it as it starts (its imports take
    ~1 s), so a cold ``aes-planner suggest`` does not sleep 50 ms before its suggestion
    (docs/benchmarks.md, "perf-2, session 27"). The process's own CPU time over the window is
    counted as idle (it is the cores others leave to it). One /proc/stat read; nothing where it
    cannot be read."""
    global _load_window
    ticks = _cpu_ticks(_own_cpus())
    _load_window = None if ticks is None else (time.monotonic(), time.process_time(), ticks)


def _own_cpus() -> set[int]:
    try:
        return set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return set(range(os.cpu_count() or 1))


def idle_cores(window_s: float = 0.05) -> float | None:
    """How many of this process's cores were idle over the next ``window_s`` (a sum of idle
    fractions, 0..available_cores()), from /proc/stat; None where that cannot be read. A window
    started by :func:`start_load_window` at least ``window_s`` and at most ``LOAD_WINDOW_MAX_S``
    ago is read instead (once), the process's own CPU time over it counted as idle."""
    global _load_window
    cpus = _own_cpus()
    started, _load_window = _load_window, None
    if started is not None and window_s <= time.monotonic() - started[0] <= LOAD_WINDOW_MAX_S:
        after = _cpu_ticks(cpus)
        if after is not None and after[1] > started[2][1]:
            own_ticks = (time.process_time() - started[1]) * _ticks_per_s()
            share = (after[0] - started[2][0] + own_ticks) / (after[1] - started[2][1])
            return max(0.0, min(1.0, share)) * len(cpus)
    before = _cpu_ticks(cpus)
    if before is None:
        return None
    time.sleep(window_s)
    after = _cpu_ticks(cpus)
    if after is None or after[1] <= before[1]:
        return None
    share = (after[0] - before[0]) / (after[1] - before[1])  # idle share of all those cores' time
    return max(0.0, min(1.0, share)) * len(cpus)


def _ticks_per_s() -> float:
    """/proc/stat's unit (USER_HZ, 100 on Linux)."""
    try:
        return float(os.sysconf("SC_CLK_TCK"))
    except (AttributeError, ValueError, OSError):
        return 100.0


def threads_for_load(max_threads: int | None = None, window_s: float = 0.05) -> int:
    """The thread count a compute job should start with now: the cores that are idle (rounded
    down, with 0.35 of a core's slack), at least 1 and at most ``max_threads`` (default: the
    available cores). Two idle cores give 2; one busy process on two cores gives 1, where two
    threads would wait for each other at every parallel step. Where /proc/stat cannot be read,
    ``max_threads``."""
    max_threads = max_threads or available_cores()
    idle = idle_cores(window_s)
    if idle is None:
        return max_threads
    return max(1, min(max_threads, int(math.floor(idle + 0.35))))


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
        start: int | None = None,
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
        if start is not None and not (isinstance(start, int) and 1 <= start <= max_threads):
            raise ValueError(f"start: must be an integer in [1, max_threads={max_threads}], got {start!r}")
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
        if start is not None and start < max_threads:  # as after a won trial: probes all threads later
            self.threads = 1
            self.walls[1] = deque(maxlen=patience)

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


@dataclass
class SuggestionJob:
    """One suggestion's compute, as :func:`suggestion_threads` ran it: ``threads`` it ran on
    (None when nested in another job), and once it ended its ``wall_s`` and ``cpu_s``."""

    threads: int | None
    wall_s: float = math.nan
    cpu_s: float = math.nan


_local = threading.local()  # per thread: pinned (an explicit set_threads count), depth (nesting)
_governor_lock = threading.Lock()
_process_governor: ThreadGovernor | None = None


def suggestion_governor() -> ThreadGovernor:
    """The process's governor of suggestions computed outside a node (library calls, ``suggest``,
    ``bench``): made on first use, starting from :func:`threads_for_load`."""
    global _process_governor
    with _governor_lock:
        if _process_governor is None:
            import torch

            most = max(1, min(MAX_THREADS, torch.get_num_threads()))
            start = threads_for_load(most)
            _process_governor = ThreadGovernor(most, start=start)
            log.info("suggestions start on %d of %d threads (cores idle now)", start, most)
        return _process_governor


def reset_suggestion_governor() -> None:
    """Forget the process's governor: the next suggestion looks at the load again (tests, bench)."""
    global _process_governor
    with _governor_lock:
        _process_governor = None


@contextlib.contextmanager
def suggestion_threads(
    governor: ThreadGovernor | None = None,
    cpu_clock: Callable[[], float] = time.process_time,
    adapt: bool = True,
    wall_clock: Callable[[], float] = time.perf_counter,
) -> Iterator[SuggestionJob]:
    """Run one suggestion's compute (scorer build and search) on the thread count picked for it,
    and let the governor learn from its wall and CPU time (the module docstring says how).

    ``governor``: the caller's (a planner node's); default: the count pinned by :func:`set_threads`
    in this thread if any, else the process's :func:`suggestion_governor`, and the thread counts
    are restored afterwards; ``adapt=False``: the current count, only timed. Nested calls (a
    node's job around the library's search) run inside the outer job unchanged."""
    if getattr(_local, "depth", 0):
        yield SuggestionJob(None)
        return
    pinned = getattr(_local, "pinned", None)
    own = governor is None and pinned is None and adapt
    gov = governor if governor is not None else (suggestion_governor() if own else None)
    if own:
        import torch

        restore = (torch.get_num_threads(), _numba_threads())
    if gov is not None:
        _apply_threads(gov.threads)
    job = SuggestionJob(gov.threads if gov is not None else pinned)
    _local.depth = 1
    t0, c0 = wall_clock(), cpu_clock()
    try:
        yield job
    finally:
        _local.depth = 0
        job.wall_s, job.cpu_s = wall_clock() - t0, cpu_clock() - c0
        if gov is not None:
            with _governor_lock if own else contextlib.nullcontext():
                gov.observe(job.wall_s, job.cpu_s)
            if not own:
                _apply_threads(gov.threads)  # the caller's count for its next job
        if own:
            _restore_threads(*restore)


def _restore_threads(torch_threads: int, numba_threads: int | None) -> None:
    import torch

    if torch.get_num_threads() != torch_threads:
        torch.set_num_threads(torch_threads)
    numba = _numba()
    if numba_threads is not None and numba is not None:
        numba.set_num_threads(numba_threads)
    elif numba is not None:  # the kernels loaded during the job: back to numba's default count
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    else:
        _local.pending_numba = None  # nothing to restore yet: the kernels keep numba's default


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
