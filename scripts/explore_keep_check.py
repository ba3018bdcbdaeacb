"""The search's explore pass with ``explore_keep`` variants on the same scorer: the exploratory
candidate (its pan, tilt, field score and true teacher score), ``covered_fraction``, how many
views were partly covered and decoded, and the pass's process CPU on one thread, the variants
alternated round by round (docs/benchmarks.md, "perf-2, ninth round").

    .venv/bin/python scripts/explore_keep_check.py indoor:500,outdoor:501 4 out.json 0,8,16,24

Rig, the survey sweep's 4 views (as ``eval search``); explore_keep 0 = every partly covered view
decoded (the pass as it was). Tune on dev and validation scenes only.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import statistics
import sys
import time

import numba
import numpy as np
import torch

from aes_planner.eval.search import Judge, SearchEvalConfig, _inputs, _mode_platform, _source
from aes_planner.search import SearchConfig, build_search_scorer
from aes_planner.search.pipeline import _explore
from aes_planner.search.space import space_for
from aes_planner.sim.scene import load_scene
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator

log = logging.getLogger("explore_keep_check")


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    numba.set_num_threads(1)
    scenes, rounds, out_path = argv[0].split(","), int(argv[1]), argv[2]
    keeps = [int(k) for k in argv[3].split(",")]
    teacher = get_teacher()
    ecfg = SearchEvalConfig(scenes=scenes, modes=["rig"], ablations=False)
    results: dict = {}
    for spec in scenes:
        source = _source(load_scene(spec), ecfg)
        platform = _mode_platform(source, "rig", ecfg.free_box_m)
        judge = Judge(source, teacher, CompositionEvaluator())
        inputs = _inputs(source, platform, 4)
        frames = [source.capture(p) for p in inputs]
        base = SearchConfig.preset("balanced", mode="rig")
        scorer = build_search_scorer("field", frames, base, teacher)
        space = space_for(platform, base)
        cpu: dict[int, list[float]] = {k: [] for k in keeps}
        per: dict = {}
        for r in range(rounds + 1):  # round 0 warms up and records the outputs
            for k in keeps if r % 2 == 0 else list(reversed(keeps)):
                cfg = dataclasses.replace(base, explore_keep=k)
                c0 = time.process_time()
                fraction, explore, _ = _explore(scorer, space, cfg, np.random.default_rng(0))
                dt = (time.process_time() - c0) * 1e3
                if r:
                    cpu[k].append(dt)
                else:
                    true = float(judge.measure(explore.cam2world[None])[0][0]) if explore is not None else None
                    per[k] = {
                        "covered_fraction": fraction,
                        "pan_deg": None if explore is None else float(np.degrees(explore.pan_rad)),
                        "tilt_deg": None if explore is None else float(np.degrees(explore.tilt_rad)),
                        "field": None if explore is None else explore.score,
                        "coverage": None if explore is None else explore.coverage,
                        "teacher": true,
                    }
        for k in keeps:
            per[k]["cpu_ms"] = statistics.median(cpu[k]) if cpu[k] else None
            per[k]["cpu_ms_range"] = [min(cpu[k]), max(cpu[k])] if cpu[k] else None
            per[k]["ratio"] = statistics.median(a / b for a, b in zip(cpu[k], cpu[keeps[0]])) if cpu[k] else None
            log.info("%s keep %d: %s", spec, k, per[k])
        results[spec] = per
        with open(out_path, "w") as f:  # after every scene: a stopped run keeps what it measured
            json.dump(results, f, indent=1)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main(sys.argv[1:])
