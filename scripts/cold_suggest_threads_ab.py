"""Cold ``aes-planner suggest`` processes of two venvs alternated, with the CPU time of the main
thread apart from the process's other threads (the kernel loads' thread, numba's and torch's
workers): where a cold suggestion's work runs, which a loaded machine's wall clock cannot show
(docs/benchmarks.md, "perf-2, session 28"). Each child prints, at its exit, its main thread's CPU
time (``time.thread_time`` in an ``atexit`` handler, run by the main thread after the others
ended) and its process CPU time.

    .venv/bin/aes-planner sim render --scene indoor:3 --out /tmp/ds
    .venv/bin/python scripts/cold_suggest_threads_ab.py /tmp/ds 8 /tmp/base/.venv/bin/python .venv/bin/python
"""

from __future__ import annotations

import logging
import os
import statistics
import subprocess
import sys

log = logging.getLogger("cold_suggest_threads_ab")

_PROBE = (
    "import atexit, sys, time\n"
    "atexit.register(lambda: print('CPU', time.thread_time() * 1e3, time.process_time() * 1e3))\n"
    "from aes_planner.cli import main\n"
    "sys.argv = ['aes-planner', 'suggest', {folder!r}, '--preset', 'balanced']\n"
    "sys.exit(main())\n"
)


def child(python: str, folder: str) -> tuple[float, float]:
    """(main thread CPU ms, process CPU ms) of one cold suggest process."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}  # as an install runs
    out = subprocess.run(
        [python, "-c", _PROBE.format(folder=folder)], capture_output=True, text=True, env=env, check=True
    )
    fields = [line for line in out.stdout.splitlines() if line.startswith("CPU")][-1].split()
    return float(fields[1]), float(fields[2])


def spread(values: list[float]) -> str:
    return f"{statistics.median(values):.0f} ({min(values):.0f}-{max(values):.0f})"


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    folder, rounds, pythons = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    runs: dict[str, list[tuple[float, float]]] = {p: [] for p in pythons}
    for r in range(rounds + 1):  # the first round warms the page cache
        for python in pythons:
            main_ms, process_ms = child(python, folder)
            if r:
                runs[python].append((main_ms, process_ms))
    for python, values in runs.items():
        main_ms = [m for m, _ in values]
        process_ms = [p for _, p in values]
        log.info(
            "%s: main thread CPU %s ms, process %s, other threads %s",
            python,
            spread(main_ms),
            spread(process_ms),
            spread([p - m for m, p in values]),
        )


if __name__ == "__main__":
    main()
