"""A `balanced` one-shot suggestion with main's code and this branch's, alternated in one process
on a fixed thread count: the process CPU of a whole suggestion (build + search, the teacher-map
caches emptied first), the paired ratio per round, and whether the two give bit for bit the same
search result (every stage-1 candidate's score, coverage and exact flag, each suggestion's pose,
score and objective, the exploratory candidate, the covered fraction). Main's side is main's
``AestheticField.score_screened``, read from a checkout of main (docs/benchmarks.md, "perf-2,
session 27").

    .venv/bin/python scripts/balanced_session27_ab.py /work/main indoor:100,outdoor:101 5 1 [0,1,2]
"""

from __future__ import annotations

import logging
import statistics
import sys
import time
import types

import numpy as np

import aes_planner.field.model as fm
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.runtime import set_threads
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

log = logging.getLogger("balanced_session27_ab")


def main_module(root: str, relpath: str, name: str) -> types.ModuleType:
    """A module of main's checkout, executed beside this branch's (its imports are this branch's)."""
    mod = types.ModuleType(name)
    mod.__file__ = f"{root}/{relpath}"
    sys.modules[name] = mod  # dataclasses look their module up
    with open(mod.__file__) as f:
        exec(compile(f.read(), mod.__file__, "exec"), mod.__dict__)
    return mod


def sides(root: str) -> tuple[dict, types.ModuleType]:
    mm = main_module(root, "aes_planner/field/model.py", "main_field_model")
    patches = [
        (fm.AestheticField, "score_screened", mm.AestheticField.__dict__["score_screened"]),
    ]
    return {
        "main": [(owner, attr, m) for owner, attr, m in patches],
        "branch": [(owner, attr, owner.__dict__[attr]) for owner, attr, _ in patches],
    }, mm


def fingerprint(res) -> np.ndarray:  # every number of the search result that a pick depends on
    parts = [res.candidates_score, res.candidates_coverage, res.candidates_exact.astype(float)]
    for s in res.suggestions + ([res.explore] if res.explore else []):
        parts += [s.cam2world.ravel(), np.array([s.score, s.coverage, s.objective, s.stage1_score])]
    parts.append(np.array([-1.0 if res.covered_fraction is None else res.covered_fraction]))
    return np.concatenate([np.asarray(p, dtype=np.float64).ravel() for p in parts])


def main(argv: list[str]) -> None:
    root, scenes, rounds = argv[0], argv[1].split(","), int(argv[2])
    threads = int(argv[3]) if len(argv) > 3 else 1
    seeds = [int(s) for s in argv[4].split(",")] if len(argv) > 4 else [0]
    set_threads(threads)  # pinned: search_views's thread governor keeps it (torch's and numba's counts)
    patches, mm = sides(root)
    teacher = get_teacher()
    ratios_all, same_all = [], []
    for spec in scenes:
        source = SimSource(spec, supersample=1)
        pt = PanTilt(source.platform.rig)
        joints = pt.sweep(4)
        inputs = pt.forward(joints[:, 0], joints[:, 1])
        frames = [source.capture(p) for p in inputs]
        for seed in seeds:
            cfg = SearchConfig.preset("balanced", seed=seed)
            cpu: dict[str, list[float]] = {"main": [], "branch": []}
            prints: dict[str, np.ndarray] = {}
            for r in range(rounds + 1):  # the first round warms up; the order flips every round
                for side in ("main", "branch") if r % 2 == 0 else ("branch", "main"):
                    for owner, attr, value in patches[side]:
                        setattr(owner, attr, value)
                    fm.clear_feature_cache()
                    mm.clear_feature_cache()
                    c0 = time.process_time()
                    res = search_views(build_search_scorer("field", frames, cfg, teacher), inputs, source.platform, cfg)
                    dt = (time.process_time() - c0) * 1e3
                    if r:
                        cpu[side].append(dt)
                    prints[side] = fingerprint(res)
            for owner, attr, value in patches["branch"]:
                setattr(owner, attr, value)
            ratios = [b / m for b, m in zip(cpu["branch"], cpu["main"])]
            ratios_all += ratios
            same = prints["main"].shape == prints["branch"].shape and np.array_equal(prints["main"], prints["branch"])
            same_all.append(same)
            log.info("%s seed %d: main %.0f ms (%.0f-%.0f), branch %.0f (%.0f-%.0f), paired %.3f (%.3f-%.3f); "
                     "bit for bit the same result: %s", spec, seed, statistics.median(cpu["main"]), min(cpu["main"]),
                     max(cpu["main"]), statistics.median(cpu["branch"]), min(cpu["branch"]), max(cpu["branch"]),
                     statistics.median(ratios), min(ratios), max(ratios), same)  # fmt: skip
    log.info("all: paired median %.3f (%.3f-%.3f) over %d rounds, %d thread(s); %d of %d results the same",
             statistics.median(ratios_all), min(ratios_all), max(ratios_all), len(ratios_all), threads,
             sum(same_all), len(same_all))  # fmt: skip


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main(sys.argv[1:])
