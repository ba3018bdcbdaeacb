"""Benchmark group ``teachers``: features and head speed per teacher, and the evaluator's agreement.

Figures (per image, median of several runs after a warm-up; batch time divided by the batch):

* ``teachers.<name>.features_<S>_b<B>.ms`` and ``teachers.<name>.head_<S>_b<B>.ms`` for
  ``S`` in 128, 224 (square inputs) and ``B`` in 1, 64, for ``composition`` and ``ven`` (random
  weights: the time does not depend on their values);
* ``teachers.<name>.head_grad_b64.ms``: head forward + backward to the map, what the search pays;
* ``teachers.correlation_<source>.plcc`` / ``.srcc`` / ``.n``: the independent evaluator against
  the composition teacher on random views, ``source`` = ``sim`` (random rig views of the
  simulator's procedural families, when ``aes_planner.sim`` is installed) and ``synthetic``
  (random drawn compositions, always).
"""

from __future__ import annotations

import logging
import statistics

import numpy as np
import torch

from aes_planner.bench import Recorder, time_ms
from aes_planner.teachers import CompositionTeacher, Teacher
from aes_planner.teachers.evaluator import CompositionEvaluator, correlation
from aes_planner.teachers.synthetic import random_composition
from aes_planner.teachers.ven import VENTeacher

log = logging.getLogger(__name__)

SIZES = (128, 224)
BATCHES = (1, 64)


def bench_teacher(rec: Recorder, teacher: Teacher, quick: bool, runs: int, warmup: int = 1) -> None:
    """Record features/head ms per image for every size and batch, and the head's gradient."""
    gen = torch.Generator().manual_seed(0)
    prefix = f"teachers.{teacher.name}"
    fmap = None
    for size in SIZES:
        for batch in BATCHES:
            images = torch.rand(batch, 3, size, size, generator=gen)
            with torch.no_grad():
                fmap = teacher.features(images)
                f_ms = time_ms(lambda: teacher.features(images), runs=runs, warmup=warmup)
                h_ms = time_ms(lambda: teacher.head(fmap), runs=max(runs, 5), warmup=1)
            rec.record(f"{prefix}.features_{size}_b{batch}.ms", statistics.median(f_ms) / batch, "ms", runs)
            rec.record(f"{prefix}.head_{size}_b{batch}.ms", statistics.median(h_ms) / batch, "ms", max(runs, 5))
    grad_map = fmap.detach().requires_grad_(True)

    def head_grad():
        grad_map.grad = None
        teacher.head(grad_map).sum().backward()

    g_ms = time_ms(head_grad, runs=max(runs, 3), warmup=1)
    rec.record(f"{prefix}.head_grad_b{grad_map.shape[0]}.ms", statistics.median(g_ms) / grad_map.shape[0], "ms", max(runs, 3))


def sim_views(count: int, seed: int = 0, width: int = 128, height: int = 96) -> list[torch.Tensor] | None:
    """``count`` views ``[3, H, W]`` at joint angles drawn uniformly within the rig's limits,
    spread over the simulator's procedural families and seeds; None without the simulator."""
    try:
        from aes_planner.sim import FAMILIES, SimCamera, SimCameraConfig, load_scene
    except ImportError:
        return None
    rng = np.random.default_rng(seed)
    families = sorted(FAMILIES)
    views: list[torch.Tensor] = []
    scene_seed = 0
    while len(views) < count:
        before = len(views)
        for family in families:
            scene = load_scene(f"{family}:{scene_seed}")
            if scene.rig is None:
                continue
            camera = SimCamera(scene, SimCameraConfig(width=width, height=height))
            (plo, phi), (tlo, thi) = camera.kinematics.pan_limits_rad, camera.kinematics.tilt_limits_rad
            for _ in range(min(8, count - len(views))):
                frame = camera.capture_joints(float(rng.uniform(plo, phi)), float(rng.uniform(tlo, thi)))
                views.append(torch.from_numpy(np.ascontiguousarray(frame.image)).permute(2, 0, 1).float() / 255.0)
        if len(views) == before:  # no family has a rig
            return None
        scene_seed += 1
    return views[:count]


def bench_correlation(rec: Recorder, quick: bool) -> None:
    teacher, evaluator = CompositionTeacher(), CompositionEvaluator()
    count = 60 if quick else 300
    sources = {"synthetic": [random_composition(np.random.default_rng(1000 + i)) for i in range(count)]}
    views = sim_views(count)
    if views:
        sources["sim"] = views
    for source, images in sources.items():
        r = correlation(teacher, images, evaluator)
        for k in ("plcc", "srcc"):
            rec.record(f"teachers.correlation_{source}.{k}", r[k], "", 1)
        rec.record(f"teachers.correlation_{source}.n", r["n"], "images", 1)
        log.info("evaluator vs composition on %d %s views: PLCC %.3f, SRCC %.3f", r["n"], source, r["plcc"], r["srcc"])
    rec.meta.setdefault("teachers", {})["correlation_sources"] = list(sources)


def run(rec: Recorder, quick: bool) -> None:
    bench_teacher(rec, CompositionTeacher(), quick, runs=3 if quick else 7)
    # VEN is a VGG-16: a 64-image batch takes tens of seconds here, so fewer runs.
    bench_teacher(rec, VENTeacher.random(), quick, runs=1 if quick else 3, warmup=0 if quick else 1)
    bench_correlation(rec, quick)
