"""Process CPU of whole `balanced` suggestions (build + search, one thread) and their picks, for a
paired comparison of two trees' rasterizers in alternating processes (docs/benchmarks.md,
"perf-2, the rasterizer's runs"): run it with each tree's interpreter in turn,

    for r in 1 2 3; do for t in /work/main /work/wt/perf2; do
        $t/.venv/bin/python scripts/raster_suggest_ab.py indoor:100,outdoor:101 3 >> ab.jsonl; done; done

One JSON line per scene: the tree, the CPU ms of each suggestion after a warm-up one, the time
inside the rasterizer's autograd bodies, and the best view's pan, tilt and score (full precision).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numba
import torch

import aes_planner
from aes_planner.field.model import clear_feature_cache
from aes_planner.gaussians import numba_backend
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    numba.set_num_threads(1)
    scenes, runs = argv[0].split(","), int(argv[1])
    cfg = SearchConfig.preset("balanced")
    teacher = get_teacher()
    tree = str(Path(aes_planner.__file__).resolve().parents[1])
    for spec in scenes:
        source = SimSource(spec, supersample=1)
        pt = PanTilt(source.platform.rig)
        joints = pt.sweep(4)
        inputs = pt.forward(joints[:, 0], joints[:, 1])
        frames = [source.capture(p) for p in inputs]
        cpu, raster, picks = [], [], []
        for r in range(runs + 1):  # the first warms up
            clear_feature_cache()
            with numba_backend.profile_stages() as prof:
                c0 = time.process_time()
                res = search_views(build_search_scorer("field", frames, cfg, teacher), inputs, source.platform, cfg)
                dt = (time.process_time() - c0) * 1e3
                bodies = sum(prof[k][0] for k in ("fwd_body", "bwd_body") if k in prof) * 1e3
            if r:
                cpu.append(dt)
                raster.append(bodies)
            picks.append([res.best.pan_rad, res.best.tilt_rad, float(res.best.score)])
        print(json.dumps(dict(tree=tree, scene=spec, cpu_ms=cpu, raster_body_cpu_ms=raster, picks=picks)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
