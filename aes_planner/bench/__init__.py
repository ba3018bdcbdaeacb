"""Benchmarks: ``aes-planner bench [GROUP ...] [--quick] [--json PATH]``.

Each group is a module of this package with a ``run(rec: Recorder, quick: bool)`` function that
times its cases and records figures under ``group.case.figure`` keys. The JSON written is::

    {"_meta": {...machine, torch, backends, date, commit...},
     "sim.render_128.ms": {"value": 12.3, "unit": "ms", "runs": 7}, ...}

Timings are medians of several runs after a warm-up. A comparison (fast path against its
reference) is measured in the same run and recorded as a ratio. Speed targets live here, never
in timed tests.
"""

from __future__ import annotations

import datetime as _dt
import importlib
import json
import logging
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from aes_planner.errors import AesPlannerError

log = logging.getLogger(__name__)

# Group name -> module. Planned groups that are not built yet are absent, not stubbed.
GROUPS: dict[str, str] = {
    "sim": "aes_planner.bench.sim",
    "raster": "aes_planner.bench.raster",
    "reconstruct": "aes_planner.bench.reconstruct",
    "teachers": "aes_planner.bench.teachers",
    "gimbal": "aes_planner.bench.gimbal",
    "drone": "aes_planner.bench.drone",
    "search": "aes_planner.bench.search",
    "node": "aes_planner.bench.node",
    "field": "aes_planner.bench.field",
    "ros2": "aes_planner.bench.ros2",
    "transport": "aes_planner.bench.transport",
    "photos": "aes_planner.bench.photos",
    "memory": "aes_planner.bench.memory",
}

__all__ = ["GROUPS", "Recorder", "run_groups", "time_ms", "time_wall_cpu_ms", "machine_info"]


def time_ms(fn: Callable[[], Any], runs: int = 7, warmup: int = 1) -> list[float]:
    """Wall-clock samples of ``fn()`` in milliseconds, after ``warmup`` untimed calls."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        samples.append((time.perf_counter() - t0) * 1e3)
    return samples


def time_wall_cpu_ms(fn: Callable[[], Any], runs: int, warmup: int = 2) -> tuple[list[float], list[float]]:
    """Wall-clock and process CPU time (all threads) of each of ``runs`` calls of ``fn()``, in ms,
    after ``warmup`` untimed calls: on a shared machine the CPU time is the work done, the wall
    time what else ran as well."""
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(runs):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append((time.perf_counter() - w0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return wall, cpu


class Recorder:
    """Collects figures for the JSON file; ``meta`` holds machine and backend facts."""

    def __init__(self) -> None:
        self.results: dict[str, dict[str, Any]] = {}
        self.meta: dict[str, Any] = {"backends": {}}

    def record(self, key: str, value: float, unit: str, runs: int = 1) -> None:
        if key.count(".") < 2:
            raise ValueError(f"benchmark key {key!r} must read group.case.figure")
        self.results[key] = {"value": float(value), "unit": unit, "runs": int(runs)}
        log.debug("%s = %.4g %s (runs=%d)", key, value, unit, runs)

    def record_spread(self, key: str, samples: list[float], unit: str) -> float:
        """The median of ``samples`` under ``key`` and their spread beside it (``key`` + ``_min``
        and ``_max``: the machine is shared, a median alone hides how far runs wander); returns
        the median."""
        if not samples:
            raise ValueError(f"benchmark {key!r}: no samples")
        median = statistics.median(samples)
        self.record(key, median, unit, len(samples))
        self.record(f"{key}_min", min(samples), unit, len(samples))
        self.record(f"{key}_max", max(samples), unit, len(samples))
        return median

    def time(self, key: str, fn: Callable[[], Any], runs: int = 7, warmup: int = 1, cpu: bool = False) -> float:
        """Time ``fn`` and record the median in ms under ``key`` with its spread (``_min``,
        ``_max``: :meth:`record_spread`); returns the median. With ``cpu``, the process CPU time
        of the same calls too, under ``key``'s last part prefixed ``cpu_`` (``g.case.ms`` ->
        ``g.case.cpu_ms``), with its spread."""
        if not cpu:
            return self.record_spread(key, time_ms(fn, runs=runs, warmup=warmup), "ms")
        wall, cpu_ms = time_wall_cpu_ms(fn, runs=runs, warmup=warmup)
        group_case, _, figure = key.rpartition(".")
        self.record_spread(f"{group_case}.cpu_{figure}", cpu_ms, "ms")
        return self.record_spread(key, wall, "ms")

    def to_json(self) -> dict[str, Any]:
        return {"_meta": self.meta, **dict(sorted(self.results.items()))}


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            cwd=Path(__file__).resolve().parent,
        )
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def _load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (None where the OS has none)."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None


def host_counters() -> dict[str, float]:
    """Counters that say what a group's timings ran beside, for :func:`host_delta`: the machine's
    CPU time stolen by the hypervisor (``steal``, all cores, from /proc/stat; absent where it cannot
    be read) and its context switches, and this process's user and system CPU time and its
    voluntary and involuntary context switches (children excluded)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    out = {
        "process_user_s": usage.ru_utime,
        "process_sys_s": usage.ru_stime,
        "process_voluntary_switches": float(usage.ru_nvcsw),
        "process_involuntary_switches": float(usage.ru_nivcsw),
    }
    try:
        with open("/proc/stat") as f:
            for line in f:
                name, _, rest = line.partition(" ")
                if name == "cpu":  # user nice system idle iowait irq softirq steal ...
                    ticks = rest.split()
                    if len(ticks) > 7:
                        out["steal_s"] = int(ticks[7]) / _ticks_per_s()
                elif name == "ctxt":
                    out["machine_switches"] = float(rest)
    except (OSError, ValueError):
        pass
    return out


def host_delta(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    """``after - before`` of :func:`host_counters` (the keys both have), rounded. A group whose
    kernels ran slow with ``process_sys_s`` high against ``process_user_s`` spent its time waking
    and parking threads (futexes), not computing; ``steal_s`` above zero lost the CPU to the host."""
    return {k: round(after[k] - before[k], 3) for k in before if k in after}


def _ticks_per_s() -> float:
    try:
        return float(os.sysconf("SC_CLK_TCK"))
    except (AttributeError, ValueError, OSError):
        return 100.0


def machine_info() -> dict[str, Any]:
    import torch

    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        # False under PYTHONDONTWRITEBYTECODE or -B: the cold-process figures then include
        # compiling the package's own modules from source in every process (a user's install
        # keeps their .pyc; docs/benchmarks.md, "perf-2 on the merged main, quiet (session 27)").
        "python_writes_bytecode": not sys.dont_write_bytecode,
    }


def run_groups(groups: list[str] | None, quick: bool = False) -> Recorder:
    """Run the named groups (all when empty) and return the recorder."""
    names = list(groups) if groups else list(GROUPS)
    unknown = [g for g in names if g not in GROUPS]
    if unknown:
        raise AesPlannerError(f"unknown benchmark group {unknown[0]!r}; available: {', '.join(GROUPS)}")
    rec = Recorder()
    rec.meta.update(
        machine=machine_info(),
        date=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        commit=_git_commit(),
        groups=names,
        quick=quick,
    )
    for name in names:
        log.info("bench group %s%s", name, " (quick)" if quick else "")
        t0 = time.perf_counter()
        load = rec.meta.setdefault("group_load_average", {})  # the machine is shared: say how busy it was
        load[name] = {"start": _load_average()}
        counters = host_counters()
        importlib.import_module(GROUPS[name]).run(rec, quick)
        load[name]["end"] = _load_average()
        rec.meta.setdefault("group_host", {})[name] = host_delta(counters, host_counters())
        rec.meta.setdefault("group_seconds", {})[name] = round(time.perf_counter() - t0, 2)
    return rec


def write_json(rec: Recorder, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(rec.to_json(), indent=2) + "\n")
    return path
