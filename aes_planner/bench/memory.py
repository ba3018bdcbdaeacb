"""Benchmark group ``memory``: resident memory of a suggestion and of a planner node, each in a
fresh process (so one measurement's allocations do not hide in another's peak).

* ``memory.suggest_balanced.imports_rss_mb``: RSS of a process that imported what a
  suggestion needs (torch, the field, the search, numba's kernels loaded);
* ``memory.suggest_balanced.peak_rss_mb``: the same process's peak RSS (``VmHWM``) after one
  ``balanced`` field suggestion from 4 views of 128 x 96 (``indoor:100``, rig);
* ``memory.planner_100_frames.rss_mb`` / ``.peak_rss_mb``: a passive planner node (the field,
  the ``fast`` search, its default bound of 24 frames) after 100 frames of 64 x 48, each
  followed by a suggestion; ``.growth_mb``: RSS after frame 100 minus RSS after frame 40 (the
  frame bound is reached by then: a leak shows as growth).

Ceilings: :data:`SUGGEST_PEAK_CEILING_MB` and :data:`PLANNER_CEILING_MB`, today's figures with
head room (docs/benchmarks.md, "Memory"); ``tests/bench/test_memory.py`` holds the code to them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from aes_planner.bench import Recorder

#: Peak RSS a balanced suggestion from 4 views may reach, MB (measured 2026-11-28: ~530 MB).
SUGGEST_PEAK_CEILING_MB = 700.0
#: RSS a planner node may hold after 100 frames, MB (measured 2026-11-28: ~560 MB).
PLANNER_CEILING_MB = 750.0
#: RSS a planner node may gain between frame 40 and frame 100, MB (measured: a few MB).
PLANNER_GROWTH_CEILING_MB = 60.0

_SUGGEST = r"""
import json, sys
from aes_planner.bench.memory import rss_mb
from aes_planner.eval.search import HELD_OUT_SCENES
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.gaussians import numba_backend
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

numba_backend.warmup()
source = SimSource(HELD_OUT_SCENES[0], supersample=1)
pt = PanTilt(source.platform.rig)
j = pt.sweep(4)
inputs = pt.forward(j[:, 0], j[:, 1])
frames = [source.capture(p) for p in inputs]
teacher = get_teacher()
before = rss_mb()
cfg = SearchConfig.preset(sys.argv[1])
search_views(build_search_scorer("field", frames, cfg, teacher), inputs, source.platform, cfg)
print(json.dumps({"imports_rss_mb": before, "peak_rss_mb": rss_mb("VmHWM")}))
"""

_PLANNER = r"""
import json, sys
from aes_planner.bench.memory import planner_frames
print(json.dumps(planner_frames(int(sys.argv[1]))))
"""


def rss_mb(field: str = "VmRSS") -> float:
    """This process's resident memory (``VmRSS``) or its peak (``VmHWM``) in MB, from /proc."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"/proc/self/status has no {field}")


def planner_frames(n_frames: int, scene: str = "indoor:3", width: int = 64) -> dict:
    """Feed ``n_frames`` frames (a sweep of ``scene``, cycled, new stamps) to a passive planner
    node that suggests after each one; RSS after frame 40 (or the last) and at the end, and the peak."""
    from aes_planner.graph.base import LaunchContext
    from aes_planner.node.planner import PlannerConfig, PlannerNode
    from aes_planner.platform import RigPlatformConfig
    from aes_planner.sim import SimCamera, SimCameraConfig, load_scene

    sc = load_scene(scene)
    cam = SimCamera(sc, SimCameraConfig(width=width, height=width * 3 // 4))
    views = [cam.capture_joints(p, t, stamp_s=0.0) for p, t in sc.rig.kinematics().sweep(12)]
    node = PlannerNode(
        PlannerConfig(
            scorer="field", preset="fast", active=False, min_suggest_period_s=0.5, platform=RigPlatformConfig()
        ),
        context=LaunchContext(scene=scene),
    )
    node.start()
    mid = None
    suggestions = 0
    for i in range(n_frames):
        v = views[i % len(views)]
        frame = type(v)(v.image, v.intrinsics, v.cam2world, float(i + 1), v.depth_m, v.frame_id)
        out = node.step({"camera/frame": [frame]}, float(i + 1))
        suggestions += len(out.get("planner/suggestion", []))
        if i + 1 == min(40, n_frames):
            mid = rss_mb()
    return {"rss_mb": rss_mb(), "mid_rss_mb": mid, "peak_rss_mb": rss_mb("VmHWM"), "suggestions": suggestions}


def _child(code: str, *args: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=1800, env=os.environ.copy()
    )
    if out.returncode:
        raise RuntimeError(f"memory bench child failed: {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def suggest_memory(preset: str = "balanced") -> dict:
    """``{imports_rss_mb, peak_rss_mb}`` of a fresh process making one suggestion (module docstring)."""
    return _child(_SUGGEST, preset)


def planner_memory(n_frames: int = 100) -> dict:
    """``{rss_mb, mid_rss_mb, peak_rss_mb, suggestions}`` of a fresh process running a planner node."""
    return _child(_PLANNER, str(n_frames))


def run(rec: Recorder, quick: bool) -> None:
    runs = 1 if quick else 3
    sug = [suggest_memory() for _ in range(runs)]
    for key in ("imports_rss_mb", "peak_rss_mb"):
        rec.record_spread(f"memory.suggest_balanced.{key}", [s[key] for s in sug], "MB")
    t0 = time.perf_counter()
    node = planner_memory(40 if quick else 100)
    rec.record("memory.planner_100_frames.rss_mb", node["rss_mb"], "MB")
    rec.record("memory.planner_100_frames.peak_rss_mb", node["peak_rss_mb"], "MB")
    rec.record("memory.planner_100_frames.growth_mb", node["rss_mb"] - node["mid_rss_mb"], "MB")
    rec.record("memory.planner_100_frames.suggestions", node["suggestions"], "messages")
    rec.record("memory.planner_100_frames.wall_s", time.perf_counter() - t0, "s")
