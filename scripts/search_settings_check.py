"""Oracle-normalised score of the best suggestion for named search settings, as ``aes-planner eval
search`` computes it (rig, the survey sweep's 4 views, the same oracle, inputs and judge), per
scene and search seed; with the suggestion's process CPU (docs/benchmarks.md, "perf-2, eighth round").

    .venv/bin/python scripts/search_settings_check.py indoor:500,outdoor:501 0,1,2 out.json \
        'base={}' 'c20k96={"steps":20,"screen_keep":96}' 'fast={"preset":"fast"}'

Each setting is ``NAME=JSON``: SearchConfig fields over ``balanced`` (``"preset"`` names another).
Tune on dev and validation scenes only; the held-out ones confirm a rule decided there.
"""

from __future__ import annotations

import json
import logging
import sys
import time

import numpy as np

from aes_planner.eval.search import Judge, SearchEvalConfig, _inputs, _mode_platform, _source, normalized, scene_oracle
from aes_planner.field.model import clear_feature_cache
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.sim.scene import load_scene
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator

log = logging.getLogger("search_settings_check")


def main(argv: list[str]) -> None:
    scenes, seeds, out_path = argv[0].split(","), [int(s) for s in argv[1].split(",")], argv[2]
    settings = {a.split("=", 1)[0]: json.loads(a.split("=", 1)[1]) for a in argv[3:]}
    teacher = get_teacher()
    ecfg = SearchEvalConfig(scenes=scenes, modes=["rig"], ablations=False)
    results: dict = {}
    for spec in scenes:
        source = _source(load_scene(spec), ecfg)
        source.name = spec
        platform = _mode_platform(source, "rig", ecfg.free_box_m)
        o_score, _, o_extra = scene_oracle(spec, source, teacher, platform, ecfg)
        judge = Judge(source, teacher, CompositionEvaluator())
        inputs = _inputs(source, platform, 4)
        frames = [source.capture(p) for p in inputs]
        for name, fields in settings.items():
            fields = dict(fields)
            preset = fields.pop("preset", "balanced")
            for seed in seeds:
                cfg = SearchConfig.preset(preset, mode="rig", seed=seed, **fields)
                clear_feature_cache()  # a build from scratch, as the bench's
                c0 = time.process_time()
                result = search_views(build_search_scorer("field", frames, cfg, teacher), inputs, platform, cfg)
                cpu_ms = (time.process_time() - c0) * 1e3
                teacher_score = float(judge.measure(result.best.cam2world[None])[0][0])
                norm = normalized(teacher_score, o_score, o_extra["mean_random"])
                results.setdefault(name, {}).setdefault(spec, {})[seed] = {
                    "norm": norm, "cpu_ms": cpu_ms, "pan": result.best.pan_rad, "tilt": result.best.tilt_rad,
                }  # fmt: skip
                log.info("%s %s seed %d: normalized %.4f, %.0f ms CPU", spec, name, seed, norm, cpu_ms)
        with open(out_path, "w") as f:  # after every scene: a stopped run keeps what it measured
            json.dump(results, f, indent=1)
    for name, per_scene in results.items():
        cells = [c["norm"] for s in per_scene.values() for c in s.values()]
        log.info("%s: mean %.4f over %d cells", name, float(np.mean(cells)), len(cells))


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main(sys.argv[1:])
