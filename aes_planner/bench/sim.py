"""Benchmark group ``sim``: the ray caster on procedural scenes, seen from their rigs.

Figures (medians of several runs after a warm-up; each run renders the next of a fixed set of
rig views, so the median is over views as well as over time):

* ``sim.render_128.ms``, ``sim.render_256.ms``: ``indoor:0``, square images with the rig's
  horizontal field of view.
* ``sim.render_128_aa3.ms``: the same at 128 with 3 x 3 supersampling.
* ``sim.family_<name>_128.ms``: one seed of each family at 128.
* ``sim.build_indoor.ms``: generating and compiling ``indoor:0`` (no rendering).
"""

from __future__ import annotations

import itertools

import numpy as np

from aes_planner.bench import Recorder
from aes_planner.geometry import Intrinsics


def _views(scene, n_pan: int = 4, n_tilt: int = 3) -> list[np.ndarray]:
    kin = scene.rig.kinematics()
    return [kin.forward(pan, tilt) for pan, tilt in kin.joint_grid(n_pan, n_tilt)]


def _time_renders(rec: Recorder, key: str, scene, size: int, runs: int, supersample: int = 1) -> float:
    from aes_planner.sim import render

    intrinsics = Intrinsics.from_fov(size, size, scene.rig.camera.hfov_deg)
    views = itertools.cycle(_views(scene))
    return rec.time(key, lambda: render(scene, next(views), intrinsics, supersample), runs=runs, warmup=2)


def run(rec: Recorder, quick: bool) -> None:
    from aes_planner.sim import FAMILIES, load_scene

    rec.meta["backends"]["sim"] = f"numpy {np.__version__} (float64 ray casting)"
    runs = 3 if quick else 15
    indoor = load_scene("indoor:0")
    _time_renders(rec, "sim.render_128.ms", indoor, 128, runs)
    _time_renders(rec, "sim.render_256.ms", indoor, 256, runs)
    _time_renders(rec, "sim.render_128_aa3.ms", indoor, 128, max(3, runs // 3), supersample=3)
    for name in FAMILIES:
        _time_renders(rec, f"sim.family_{name}_128.ms", load_scene(f"{name}:1"), 128, max(3, runs // 3))
    rec.time("sim.build_indoor.ms", lambda: load_scene("indoor:0"), runs=max(3, runs // 3))
