"""CPU time of one drone one-shot suggestion (scorer build + search) for each candidate preset,
alternated in one process on one thread (torch and numba): the time figure of the drone front rule
(docs/results/drone_front_s29/rule.md). The candidates are the rig's one-shot preset with the fields
given here on top; the drone's inputs are ``eval search``'s.

    .venv/bin/python scripts/drone_preset_cpu.py indoor:500,outdoor:501 3
"""

from __future__ import annotations

import logging
import statistics
import sys
import time

import numba
import torch

from aes_planner.eval.search import SearchEvalConfig, _free_platform, _inputs, _source
from aes_planner.field.model import clear_feature_cache
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.sim.scene import load_scene
from aes_planner.teachers import get_teacher

log = logging.getLogger("drone_preset_cpu")

#: name -> (preset, fields on top of the rig's one-shot preset)
CANDIDATES = {
    "fast": ("fast", {}),
    "today": ("balanced", dict(samples_per_segment=32, top_k=3, screen_keep=0, steps=25, explore_keep=0)),
    "screen": ("balanced", dict(samples_per_segment=32, top_k=3, screen_keep=128, steps=25, explore_keep=0)),
    "screen20": ("balanced", dict(samples_per_segment=32, top_k=3, screen_keep=128)),
    "rig": ("balanced", {}),
    "dense": ("balanced", dict(samples_per_segment=64, top_k=3, screen_keep=128, steps=25, explore_keep=0)),
    "k4": ("balanced", dict(samples_per_segment=32, top_k=4, screen_keep=128, steps=25, explore_keep=0)),
}


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    numba.set_num_threads(1)
    scenes, rounds = argv[0].split(","), int(argv[1])
    names = argv[2].split(",") if len(argv) > 2 else list(CANDIDATES)
    configs = {n: SearchConfig.preset(CANDIDATES[n][0], mode="rig", **CANDIDATES[n][1]) for n in names}
    teacher = get_teacher()
    ecfg = SearchEvalConfig(modes=["drone"])
    medians: dict[str, list[float]] = {n: [] for n in names}
    for spec in scenes:
        source = _source(load_scene(spec), ecfg)
        platform = _free_platform(source, ecfg.free_box_m) if source.platform.rig is not None else source.platform
        inputs = _inputs(source, platform, 4)
        frames = [source.capture(p) for p in inputs]
        cpu: dict[str, list[float]] = {n: [] for n in names}
        for r in range(rounds + 1):  # the first round warms up; the order flips every round
            for name in names if r % 2 == 0 else list(reversed(names)):
                cfg = configs[name]
                clear_feature_cache()
                c0 = time.process_time()
                search_views(build_search_scorer("field", frames, cfg, teacher), inputs, platform, cfg)
                if r:
                    cpu[name].append((time.process_time() - c0) * 1e3)
        for name, values in cpu.items():
            medians[name].append(statistics.median(values))
            log.info("%s %s: CPU median %.0f ms (%.0f-%.0f)", spec, name, medians[name][-1], min(values), max(values))
    for name, values in medians.items():
        log.info("all: %s CPU median of scene medians %.0f ms (%.0f-%.0f)", name, statistics.median(values),
                 min(values), max(values))  # fmt: skip


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main(sys.argv[1:])
