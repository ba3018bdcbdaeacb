"""Benchmark group ``field``: building the aesthetic field and scoring with it, against RGB scoring.

Four RGB frames of 128 x 96 from a pan sweep of ``indoor:3`` (sphere mode, as a rig gives
them), the default scorer knobs (render width 64), the shipped model:

* ``field.build_4v.ms``: ``AestheticField.build`` (reconstruction, teacher maps of the inputs,
  embeddings); ``rgb.build_4v.ms`` the RGB scorer's build (reconstruction alone).
* ``field.score_b64.ms`` / ``rgb.score_b64.ms``: one ``score`` of 64 poses, no gradient.
* ``field.grad_b2.ms`` / ``rgb.grad_b2.ms``: ``score`` of 2 poses and the backward pass to them.
* ``field.score_b64_vs_rgb.ratio``, ``field.grad_b2_vs_rgb.ratio``: field time over RGB time.

Each time carries its spread over the runs beside it (``_min``, ``_max``: ``Recorder.time``),
and its process CPU time in the same calls (``field.build_4v.cpu_ms`` and so on, with spread):
on a shared machine the wall time depends on what else runs.
"""

from __future__ import annotations

import numpy as np
import torch

from aes_planner.bench import Recorder

SCENE = "indoor:3"


def _frames_and_poses():
    from aes_planner.geometry.pantilt import PanTilt
    from aes_planner.sim import SimSource

    src = SimSource(SCENE, supersample=1)
    pt = PanTilt(src.platform.rig)
    inputs = pt.forward(np.radians([-45.0, -15.0, 15.0, 45.0]), np.radians([-5.0, 0.0, -5.0, 0.0]))
    frames = [src.capture(p, depth=False) for p in inputs]
    pans = np.radians(np.linspace(-50.0, 50.0, 64))
    poses = pt.forward(pans, np.radians(8.0) * np.sin(np.linspace(0, 6.0, 64)))
    return frames, torch.from_numpy(poses)


def run(rec: Recorder, quick: bool = False) -> None:
    from aes_planner.field import AestheticField, RGBScorer

    frames, poses = _frames_and_poses()
    runs = 3 if quick else 7
    rec.time("field.build_4v.ms", lambda: AestheticField.build(frames), runs=runs, cpu=True)
    rec.time("rgb.build_4v.ms", lambda: RGBScorer.build(frames), runs=runs, cpu=True)
    scorers = {"field": AestheticField.build(frames), "rgb": RGBScorer.build(frames)}

    def grad(scorer):
        p = poses[:2].clone().requires_grad_(True)
        scorer.score(p).score.sum().backward()

    for name, scorer in scorers.items():
        with torch.no_grad():
            rec.time(f"{name}.score_b64.ms", lambda s=scorer: s.score(poses), runs=runs, cpu=True)
        rec.time(f"{name}.grad_b2.ms", lambda s=scorer: grad(s), runs=runs, cpu=True)
    for case in ("score_b64", "grad_b2"):
        f, r = rec.results[f"field.{case}.ms"]["value"], rec.results[f"rgb.{case}.ms"]["value"]
        rec.record(f"field.{case}_vs_rgb.ratio", f / r, "x", runs)
