"""Cold ``aes-planner suggest`` processes of main's venv and this branch's, alternated: the bench's
``cold_case`` by hand (the whole process, then a process that only imports what it imports, in
swapped order every round), user + system CPU and wall of each child, and whether the two JSONs
agree but for ``latency_ms`` (docs/benchmarks.md, "perf-2, session 27"). Both sides write their
bytecode under one private prefix (``PYTHONPYCACHEPREFIX``), so a shell that sets
``PYTHONDONTWRITEBYTECODE`` does not compile every module from source in every process.

    .venv/bin/aes-planner sim render --scene indoor:3 --out /tmp/ds
    .venv/bin/python scripts/cold_suggest_ab.py /work/main/.venv/bin/python /tmp/ds 8
"""

from __future__ import annotations

import json
import logging
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from aes_planner.bench.search import _SUGGEST_IMPORTS

log = logging.getLogger("cold_suggest_ab")


def child(argv: list[str], env: dict) -> tuple[float, float]:
    """Wall and CPU (user + system) milliseconds of a child process, start to exit."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, timeout=1800)
    wall = (time.perf_counter() - t0) * 1e3
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime) * 1e3


def spread(values: list[float]) -> str:
    return f"{statistics.median(values):.0f} ({min(values):.0f}-{max(values):.0f})"


def main(argv: list[str]) -> None:
    main_python, data, rounds = argv[0], argv[1], int(argv[2])
    sides = {"main": main_python, "branch": sys.executable}
    tmp = Path(tempfile.mkdtemp(prefix="cold-ab-"))
    env = dict(os.environ, PYTHONPYCACHEPREFIX=str(tmp / "pyc"))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    res = {s: {"process": [], "imports": [], "process_wall": [], "imports_wall": []} for s in sides}
    loads = []
    for r in range(rounds + 1):  # the first round warms the page cache and writes the bytecode
        for name, python in sides.items() if r % 2 == 0 else reversed(sides.items()):
            cases = [
                ("process", [python, "-m", "aes_planner", "suggest", data, "--preset", "balanced",
                             "--json", str(tmp / f"{name}.json")]),
                ("imports", [python, "-c", _SUGGEST_IMPORTS]),
            ]  # fmt: skip
            for case, cmd in cases if r % 2 == 0 else reversed(cases):
                wall, cpu = child(cmd, env)
                if r:
                    res[name][case].append(cpu)
                    res[name][f"{case}_wall"].append(wall)
        loads.append(os.getloadavg()[0])
    for name, d in res.items():
        after = [p - i for p, i in zip(d["process"], d["imports"])]
        after_wall = [p - i for p, i in zip(d["process_wall"], d["imports_wall"])]
        log.info("%s: CPU ms process %s, imports %s, after the imports %s; wall ms process %s, imports %s, after %s",
                 name, spread(d["process"]), spread(d["imports"]), spread(after), spread(d["process_wall"]),
                 spread(d["imports_wall"]), spread(after_wall))  # fmt: skip
    m, b = res["main"], res["branch"]
    diff = [(mp - mi) - (bp - bi) for mp, mi, bp, bi in zip(m["process"], m["imports"], b["process"], b["imports"])]
    log.info("after the imports, main - branch, paired: %s ms CPU over %d rounds; load %.1f-%.1f",
             spread(diff), rounds, min(loads), max(loads))  # fmt: skip
    docs = [json.loads((tmp / f"{n}.json").read_text()) for n in sides]
    for doc in docs:
        doc.pop("latency_ms", None)
    log.info("the JSONs agree but for latency_ms: %s", docs[0] == docs[1])


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main(sys.argv[1:])
