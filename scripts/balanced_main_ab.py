"""A `balanced` one-shot suggestion as main 7193e9b ran it and as this branch runs it, alternated
in one process on one thread: the process CPU of a whole suggestion (build + search, the
teacher-map cache emptied first) and the paired ratio per round (docs/benchmarks.md, "perf-2,
ninth round"). Main's side: 25 Adam steps, every partly covered explore view decoded, and the
trajectory's rotations converted one sample at a time (its interpolate_poses, copied here).

    .venv/bin/python scripts/balanced_main_ab.py indoor:100,outdoor:101 5
"""

from __future__ import annotations

import logging
import statistics
import sys
import time

import numba
import numpy as np
import torch

import aes_planner.search.pipeline as pipeline
from aes_planner.field.model import clear_feature_cache
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.geometry.poses import matrix_to_quat, quat_to_matrix
from aes_planner.geometry.trajectory import _segment_params, slerp
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

log = logging.getLogger("balanced_main_ab")


def main_interpolate_poses(cam2worlds, samples_per_segment, include_end=True):  # main 7193e9b's
    poses = np.asarray(cam2worlds, dtype=np.float64)
    quats = matrix_to_quat(poses[:, :3, :3])
    out = []
    for i, t in _segment_params(len(poses), samples_per_segment, include_end):
        j = min(i + 1, len(poses) - 1)
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix(slerp(quats[i], quats[j], t))
        m[:3, 3] = (1.0 - t) * poses[i, :3, 3] + t * poses[j, :3, 3]
        out.append(m)
    return np.stack(out)


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    numba.set_num_threads(1)
    scenes, rounds = argv[0].split(","), int(argv[1])
    branch_interp = pipeline.interpolate_poses
    sides = {
        "main": (SearchConfig.preset("balanced", steps=25, explore_keep=0), main_interpolate_poses),
        "branch": (SearchConfig.preset("balanced"), branch_interp),
    }
    teacher = get_teacher()
    ratios_all = []
    for spec in scenes:
        source = SimSource(spec, supersample=1)
        pt = PanTilt(source.platform.rig)
        joints = pt.sweep(4)
        inputs = pt.forward(joints[:, 0], joints[:, 1])
        frames = [source.capture(p) for p in inputs]
        cpu: dict[str, list[float]] = {name: [] for name in sides}
        best: dict[str, tuple] = {}
        for r in range(rounds + 1):  # the first round warms up; the order flips every round
            order = list(sides.items()) if r % 2 == 0 else list(reversed(sides.items()))
            for name, (cfg, interp) in order:
                pipeline.interpolate_poses = interp
                clear_feature_cache()
                c0 = time.process_time()
                res = search_views(build_search_scorer("field", frames, cfg, teacher), inputs, source.platform, cfg)
                dt = (time.process_time() - c0) * 1e3
                if r:
                    cpu[name].append(dt)
                best[name] = (round(res.best.pan_rad, 6), round(res.best.tilt_rad, 6))
        pipeline.interpolate_poses = branch_interp
        ratios = [b / m for b, m in zip(cpu["branch"], cpu["main"])]
        ratios_all += ratios
        for name, values in cpu.items():
            log.info(
                "%s %s: CPU median %.0f ms (%.0f-%.0f)", spec, name, statistics.median(values), min(values), max(values)
            )
        log.info("%s branch/main paired: median %.3f (%.3f-%.3f); best views %s", spec, statistics.median(ratios),
                 min(ratios), max(ratios), best)  # fmt: skip
    log.info("all scenes: paired median %.3f (%.3f-%.3f) over %d rounds", statistics.median(ratios_all),
             min(ratios_all), max(ratios_all), len(ratios_all))  # fmt: skip


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main(sys.argv[1:])
