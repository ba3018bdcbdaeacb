"""Named search settings alternated in one process on one thread: the process CPU of a whole
suggestion (build + search, the teacher-map cache emptied first), per setting, and its ratio to
the first setting's paired round by round (docs/benchmarks.md, "perf-2, eighth round").

    .venv/bin/python scripts/search_settings_ab.py indoor:100,outdoor:101 3 \
        'base={"steps":25,"screen_keep":128}' 'new={"steps":20,"screen_keep":96}'

Each setting is ``NAME=JSON``: SearchConfig fields over ``balanced`` (``"preset"`` names another).
"""

from __future__ import annotations

import json
import logging
import statistics
import sys
import time

import numba
import torch

from aes_planner.field.model import clear_feature_cache
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

log = logging.getLogger("search_settings_ab")


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    numba.set_num_threads(1)
    scenes, rounds = argv[0].split(","), int(argv[1])
    configs = {}
    for arg in argv[2:]:
        name, fields = arg.split("=", 1)
        fields = json.loads(fields)
        configs[name] = SearchConfig.preset(fields.pop("preset", "balanced"), **fields)
    teacher = get_teacher()
    for spec in scenes:
        source = SimSource(spec, supersample=1)
        pt = PanTilt(source.platform.rig)
        joints = pt.sweep(4)
        inputs = pt.forward(joints[:, 0], joints[:, 1])
        frames = [source.capture(p) for p in inputs]
        cpu: dict[str, list[float]] = {name: [] for name in configs}
        for r in range(rounds + 1):  # the first round warms up; the order flips every round
            order = list(configs.items()) if r % 2 == 0 else list(reversed(configs.items()))
            for name, cfg in order:
                clear_feature_cache()
                c0 = time.process_time()
                search_views(build_search_scorer("field", frames, cfg, teacher), inputs, source.platform, cfg)
                if r:
                    cpu[name].append((time.process_time() - c0) * 1e3)
        first = next(iter(configs))
        for name, values in cpu.items():
            ratios = [a / b for a, b in zip(values, cpu[first])]
            log.info("%s %s: CPU median %.0f ms (%.0f-%.0f), paired ratio %.3f (%.3f-%.3f)", spec, name,
                     statistics.median(values), min(values), max(values),
                     statistics.median(ratios), min(ratios), max(ratios))  # fmt: skip


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main(sys.argv[1:])
