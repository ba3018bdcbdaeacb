"""Benchmark group ``teachers``: features and head speed per teacher, and the evaluator's agreement.

Figures (per image, median of several runs after a warm-up; batch time divided by the batch):

* ``teachers.<name>.features_<S>_b<B>.ms`` and ``teachers.<name>.head_<S>_b<B>.ms`` for
  ``S`` in 128, 224 (square inputs) and ``B`` in 1, 64, for ``composition`` and ``ven`` (random
  weights: the time does not depend on their values);
* ``teachers.<name>.head_grad_b64.ms``: head forward + backward to the map, what the search pays;
* ``teachers.correlation_<source>.plcc`` / ``.srcc`` / ``.n``: the independent evaluator against
  the composition teacher on random views, ``source`` = ``sim`` (random rig views of the
  simulator's procedural families, when ``aes_planner.sim`` is installed) and ``synthetic``
  (random drawn compositions, always);
* ``teachers.<judge>.subject_*`` and ``.sweep_*`` (``judge`` = ``composition`` or
  ``evaluator``): whether the judge prefers views that frame a real subject over views of bare
  structure and repeated texture, against the simulator's ground truth (instance masks); see
  :func:`subject_metrics` for the figures and :func:`classify_object` for what counts as a
  subject.

**Subjects versus structure.** Each scene object is, by its name, either *structure* (surfaces
and architecture: floors, walls, ceilings, ground, hills, rugs, cloths, table tops, doors,
window frames, fences, paths, ponds, labels) or part of a *subject* (furniture, plants, trees,
paintings, sculptures, houses, the still-life items...). Primitives of one thing are grouped
(``painting_sofa_frame`` and ``painting_sofa_canvas`` are one painting; ``plant1_pot`` and
``plant1_leaves0`` one plant). A view **frames a subject** when one subject covers at least
:data:`SUBJECT_MIN_COVER` of the frame and at least :data:`SUBJECT_MIN_INSIDE` of what the same
camera sees of it over twice the field (so it is not mostly cut by the border); it shows
**structure only** when all subject pixels together cover less than
:data:`STRUCTURE_MAX_SUBJECT`. Views in between (a sliver of sofa, a speck of a vase) are
neither, and take no part in the pairs.
"""

from __future__ import annotations

import logging
import re
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from aes_planner.bench import Recorder, time_ms
from aes_planner.metrics import srcc
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
                f_ms = time_ms(lambda x=images: teacher.features(x), runs=runs, warmup=warmup)
                h_ms = time_ms(lambda f=fmap: teacher.head(f), runs=max(runs, 5), warmup=1)
            rec.record(f"{prefix}.features_{size}_b{batch}.ms", statistics.median(f_ms) / batch, "ms", runs)
            rec.record(f"{prefix}.head_{size}_b{batch}.ms", statistics.median(h_ms) / batch, "ms", max(runs, 5))
    grad_map = fmap.detach().requires_grad_(True)

    def head_grad():
        grad_map.grad = None
        teacher.head(grad_map).sum().backward()

    g_ms = time_ms(head_grad, runs=max(runs, 3), warmup=1)
    rec.record(
        f"{prefix}.head_grad_b{grad_map.shape[0]}.ms", statistics.median(g_ms) / grad_map.shape[0], "ms", max(runs, 3)
    )


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


# ------------------------------------------------------------ subjects versus structure (sim)
SUBJECT_MIN_COVER = 0.03  # share of the frame one subject must cover for the view to frame it
SUBJECT_MIN_INSIDE = 0.5  # share of the subject (as seen over twice the field) inside the frame
STRUCTURE_MAX_SUBJECT = 0.015  # all subject pixels together below this: a structure-only view
TEXTURE_MIN_COVER = 0.25  # a structure-only view with this much checker / stripes is a texture view
QUALITY_COVER = 0.10  # subject cover at which the coverage quality saturates
FAMILIES_ORDER = ("gallery", "indoor", "outdoor", "tabletop")

_STRUCTURE = re.compile(
    r"^(floor|ceiling(_edge)?|wall(_\w+)?|baseboard|window_(mullion|transom|sill)|ground(_outside)?|hill\d*"
    r"|path|pond|rug|cloth|table_top|table_leg\d*|door|label\d*|post\d*|rail\d*)$"
)
# (pattern, group): the first match names the subject a primitive belongs to ("\1" = group 1).
_GROUPS = (
    (re.compile(r"^(painting_[a-z]+|work\d+|tree\d+|plant\d+|table\d+|bottle\d+|bush\d+|lamp|bench)_"), r"\1"),
    (re.compile(r"^(sofa_\w+|cushion\d+)$"), "sofa"),
    (re.compile(r"^(shelf_case|book\d+_\d+)$"), "shelf"),
    (re.compile(r"^(house|roof|window\d+)$"), "house"),
    (re.compile(r"^(plinth|sculpture\d+)$"), "sculpture"),
    (re.compile(r"^(vase|vase_belly|stem\d+|bloom\d+)$"), "vase"),
    (re.compile(r"^(bowl|fruit\d+)$"), "bowl"),
    (re.compile(r"^book\d+$"), "books"),
    (re.compile(r"^(candle|flame)$"), "candle"),
)


def classify_object(name: str) -> str | None:
    """The subject a scene object belongs to (its group name), or None for structure.

    Structure is matched by name (see the module docstring); everything else is a subject,
    its primitives grouped by the rules of ``_GROUPS`` (an unmatched name is a subject of its
    own, e.g. ``cup0``, ``rock2``).
    """
    if _STRUCTURE.match(name):
        return None
    for pattern, group in _GROUPS:
        m = pattern.match(name)
        if m:
            return m.expand(group)
    return name


@dataclass(frozen=True)
class ViewLabel:
    """Ground truth of one sim view.

    ``subject``: the best-framed subject's group when the view frames one, else None.
    ``structure_only``: subject pixels cover less than :data:`STRUCTURE_MAX_SUBJECT`.
    ``quality``: subject coverage quality in [0, 1], ``max_g min(1, cover_g / QUALITY_COVER) *
    inside_g`` over the subjects ``g`` in view. ``cover``/``inside``: of that best subject.
    ``texture``: share of the frame on checker- or stripe-patterned structure.
    """

    subject: str | None
    structure_only: bool
    quality: float
    cover: float
    inside: float
    texture: float


@dataclass
class SubjectViews:
    """Labelled sim views: ``images[i]`` is ``[3, H, W]`` in [0, 1], of scene ``scenes[i]``;
    ``sweep[i]`` says whether it belongs to that scene's rig sweep (else a random view)."""

    images: list[torch.Tensor] = field(default_factory=list)
    labels: list[ViewLabel] = field(default_factory=list)
    scenes: list[str] = field(default_factory=list)
    sweep: list[bool] = field(default_factory=list)


def label_view(scene, camera, frame) -> ViewLabel:
    """Label a :class:`PosedFrame` of ``camera`` in ``scene`` from its instance ids; the
    in-frame share of each subject comes from a second render of twice the field (same pixel
    count, half the focal length), whose central half is this frame."""
    from aes_planner.geometry import Intrinsics
    from aes_planner.sim import render

    ids = np.asarray(frame.extras["instance_id"])  # [H, W], 0 = sky, k = objects[k - 1]
    h, w = ids.shape
    k = camera.intrinsics
    wide_ids = render(
        scene, frame.extras["true_cam2world"], Intrinsics(k.fx / 2, k.fy / 2, k.cx, k.cy, w, h)
    ).instance_id
    groups = [classify_object(o.name) for o in scene.spec.objects]
    names = sorted({g for g in groups if g is not None})
    index = np.array([-1] + [names.index(g) if g is not None else -1 for g in groups])  # instance id -> group
    textured = np.array(
        [False]
        + [
            g is None and o.material.pattern is not None and o.material.pattern.kind in ("checker", "stripes")
            for g, o in zip(groups, scene.spec.objects)
        ]
    )
    n = len(names)

    def counts(a: np.ndarray) -> np.ndarray:  # [n] pixels per group
        g = index[a.ravel()]
        return np.bincount(g[g >= 0], minlength=n).astype(np.float64)

    cover = counts(ids) / ids.size
    r0, c0 = int(round(k.cy - h / 4)), int(round(k.cx - w / 4))
    inner, whole = counts(wide_ids[max(r0, 0) : r0 + h // 2, max(c0, 0) : c0 + w // 2]), counts(wide_ids)
    inside = np.where(whole > 0, inner / np.maximum(whole, 1.0), 0.0)
    framed = (cover >= SUBJECT_MIN_COVER) & (inside >= SUBJECT_MIN_INSIDE)
    quality = np.minimum(1.0, cover / QUALITY_COVER) * inside
    best = int(np.argmax(np.where(framed, cover, -1.0) if framed.any() else quality)) if n else -1
    return ViewLabel(
        subject=names[best] if n and framed[best] else None,
        structure_only=bool(cover.sum() < STRUCTURE_MAX_SUBJECT),
        quality=float(quality[best]) if n else 0.0,
        cover=float(cover[best]) if n else 0.0,
        inside=float(inside[best]) if n else 0.0,
        texture=float(textured[ids.ravel()].mean()),
    )


def subject_views(
    seeds: Sequence[int] = (0, 1, 2, 3, 4),
    random_views: int = 24,
    sweep: tuple[int, int] | None = (6, 4),
    width: int = 128,
    height: int = 96,
    families: Sequence[str] = FAMILIES_ORDER,
    seed: int = 0,
) -> SubjectViews | None:
    """Labelled views of every family and scene seed: ``random_views`` at joint angles drawn
    uniformly within the rig's limits, then a ``sweep = (n_pan, n_tilt)`` joint grid (none when
    None); None without the simulator."""
    try:
        from aes_planner.sim import SimCamera, SimCameraConfig, load_scene
    except ImportError:
        return None
    rng = np.random.default_rng(seed)
    out = SubjectViews()
    for family in families:
        for scene_seed in seeds:
            name = f"{family}:{scene_seed}"
            scene = load_scene(name)
            camera = SimCamera(scene, SimCameraConfig(width=width, height=height))
            (plo, phi), (tlo, thi) = camera.kinematics.pan_limits_rad, camera.kinematics.tilt_limits_rad
            joints = [(rng.uniform(plo, phi), rng.uniform(tlo, thi)) for _ in range(random_views)]
            if sweep is not None:
                joints += [tuple(j) for j in camera.kinematics.joint_grid(*sweep)]
            for i, (pan, tilt) in enumerate(joints):
                frame = camera.capture_joints(float(pan), float(tilt))
                out.images.append(torch.from_numpy(np.ascontiguousarray(frame.image)).permute(2, 0, 1).float() / 255.0)
                out.labels.append(label_view(scene, camera, frame))
                out.scenes.append(name)
                out.sweep.append(i >= random_views)
    return out


def subject_metrics(scores: Sequence[float], views: SubjectViews) -> dict[str, float]:
    """How well ``scores`` (one per view, higher = better) prefer framed subjects.

    * ``subject_pref_acc``: over all pairs (subject view, structure-only view) of random views
      of the same scene, the share where the subject view scores higher (ties count half);
      ``subject_pref_acc_<family>`` the same per family; ``subject_pref_acc_texture`` only
      against texture views (structure-only, at least :data:`TEXTURE_MIN_COVER` checker or
      stripes); ``subject_pairs`` / ``subject_pairs_texture`` the pair counts.
    * ``sweep_argmax_subject_rate``: share of scenes whose best-scoring sweep view frames a
      subject; ``sweep_subject_share`` the share of sweep views that do (what a random pick
      gets); ``sweep_argmax_structure_rate`` / ``sweep_argmax_texture_rate``: share of scenes
      whose best sweep view shows structure only / is a texture view (the rest of the scenes'
      best views are neither: several small subjects, or one mostly cut by the frame).
    * ``subject_srcc``: SRCC between the scores and the subject coverage quality over the
      random views of a scene, averaged over scenes (scenes with constant quality skipped).
    """
    scores = np.asarray(scores, np.float64)
    if scores.shape != (len(views.labels),):
        raise ValueError(f"subject_metrics needs one score per view ({len(views.labels)}), got shape {scores.shape}")
    out: dict[str, float] = {}
    wins: dict[str, list[float]] = {}
    srccs, argmax_subject, argmax_structure, argmax_texture, sweep_subject = [], [], [], [], []
    for name in dict.fromkeys(views.scenes):
        family = name.split(":")[0]
        idx = [i for i, s in enumerate(views.scenes) if s == name]
        rand = [i for i in idx if not views.sweep[i]]
        subj = [i for i in rand if views.labels[i].subject is not None]
        struct = [i for i in rand if views.labels[i].structure_only]
        for i in subj:
            for j in struct:
                win = 1.0 if scores[i] > scores[j] else 0.5 if scores[i] == scores[j] else 0.0
                wins.setdefault("all", []).append(win)
                wins.setdefault(family, []).append(win)
                if views.labels[j].texture >= TEXTURE_MIN_COVER:
                    wins.setdefault("texture", []).append(win)
        q = np.array([views.labels[i].quality for i in rand])
        if len(rand) > 2 and q.std() > 0 and scores[rand].std() > 0:
            srccs.append(srcc(scores[rand], q))
        sw = [i for i in idx if views.sweep[i]]
        if sw:
            best = sw[int(np.argmax(scores[sw]))]
            argmax_subject.append(views.labels[best].subject is not None)
            argmax_structure.append(views.labels[best].structure_only)
            argmax_texture.append(views.labels[best].structure_only and views.labels[best].texture >= TEXTURE_MIN_COVER)
            sweep_subject += [views.labels[i].subject is not None for i in sw]
    nan = float("nan")
    out["subject_pref_acc"] = float(np.mean(wins["all"])) if wins.get("all") else nan
    out["subject_pairs"] = float(len(wins.get("all", [])))
    out["subject_pref_acc_texture"] = float(np.mean(wins["texture"])) if wins.get("texture") else nan
    out["subject_pairs_texture"] = float(len(wins.get("texture", [])))
    for family in sorted({s.split(":")[0] for s in views.scenes}):
        out[f"subject_pref_acc_{family}"] = float(np.mean(wins[family])) if wins.get(family) else nan
    out["subject_srcc"] = float(np.mean(srccs)) if srccs else nan
    out["sweep_argmax_subject_rate"] = float(np.mean(argmax_subject)) if argmax_subject else nan
    out["sweep_argmax_structure_rate"] = float(np.mean(argmax_structure)) if argmax_structure else nan
    out["sweep_argmax_texture_rate"] = float(np.mean(argmax_texture)) if argmax_texture else nan
    out["sweep_subject_share"] = float(np.mean(sweep_subject)) if sweep_subject else nan
    return out


def bench_subjects(rec: Recorder, quick: bool) -> None:
    """Subject-versus-structure figures of the composition teacher and the evaluator (sim)."""
    views = subject_views(seeds=(0, 1) if quick else (0, 1, 2, 3, 4), random_views=16 if quick else 24)
    if views is None:
        log.info("no simulator: skipping the subject-versus-structure figures")
        return
    teacher, evaluator = CompositionTeacher(), CompositionEvaluator()
    with torch.no_grad():
        scores = torch.cat(
            [teacher.score(torch.stack(views.images[i : i + 64])) for i in range(0, len(views.images), 64)]
        )
    judges = {"composition": scores.numpy(), "evaluator": evaluator.evaluate(views.images)}
    for judge, s in judges.items():
        m = subject_metrics(s, views)
        for key, value in m.items():
            unit = "pairs" if "pairs" in key else ""
            rec.record(f"teachers.{judge}.{key}", value, unit, 1)
        log.info(
            "%s on %d sim views: subject preferred in %.1f %% of %d pairs (%.1f %% against texture), "
            "sweep argmax frames a subject in %.0f %% of scenes (chance %.0f %%), SRCC with subject quality %.3f",
            judge,
            len(views.images),
            100 * m["subject_pref_acc"],
            m["subject_pairs"],
            100 * m["subject_pref_acc_texture"],
            100 * m["sweep_argmax_subject_rate"],
            100 * m["sweep_subject_share"],
            m["subject_srcc"],
        )
    rec.meta.setdefault("teachers", {})["subject_views"] = len(views.images)


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
    bench_subjects(rec, quick)
