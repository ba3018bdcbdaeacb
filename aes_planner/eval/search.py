"""``aes-planner eval search``: the paper's suggestion experiments against a true oracle.

For every scene (held-out seeds by default), number of input views and mode (rig: the scene's
pan-tilt rig; free: a drone box around the rig's base), each method suggests one view and is
measured on the **ground-truth render** at that view:

* ``teacher``: the teacher's score (what the search maximises; the paper's VEN column),
* ``evaluator``: the independent evaluator's score (the paper's SAMPNet column; never searched on),
* ``normalized``: ``(teacher - mean random) / (oracle - mean random)`` — 1 optimal, 0 chance.

Single scenes swing by up to 0.5 between neighbouring settings, so every mean comes with its
spread: ``normalized_se`` (standard error over the scenes) and, for each method against
``field_balanced`` on the same scenes, the paired difference with its standard error and how
many scenes it did better, the same (within ``SAME_TOL``) or worse.

Methods: ``field_fast``/``field_balanced`` (the two-stage search on the field at each preset), ``rgb`` (the same pipeline on RGB scoring, balanced), ``best_input``,
``inplane`` and ``rotation`` (exhaustive local sampling around each input, scored on ground
truth: the paper's starred upper bounds of single-view methods), ``random`` (feasible random
views: its mean), ``oracle`` (:func:`aes_planner.search.oracle_search`) and ``covered_oracle``
(:func:`covered_oracle`: the best of the oracle's grid among the views the inputs cover, what one
shot can know; the row's ``oracle_coverage`` says how much of the oracle's view the inputs saw).

Also Table 3 (gradient-ascent gain from random starts, field vs RGB), Tables 4/S1 (K, steps and
S x N ablations of the field search), the Fig. 5 analogue (stage-1 candidates coloured by score
over a top view) and, on a rig, the pan x tilt map of the field's score beside ground truth.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from aes_planner.errors import AesPlannerError
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.paths import output_in
from aes_planner.platform import RIG_FREE_BOX_HALF_M, DronePlatform, Platform, RigPlatform, parse_kind
from aes_planner.search import (
    GroundTruthScorer,
    SearchConfig,
    build_search_scorer,
    normalized,
    oracle_search,
    search_views,
)
from aes_planner.search.pipeline import SearchError, refine_params
from aes_planner.search.space import RigSpace, SearchSpace, random_poses, space_for
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator

log = logging.getLogger(__name__)

__all__ = [
    "HELD_OUT_SCENES",
    "HELD_OUT_SEED_START",
    "METHODS",
    "SearchEvalConfig",
    "paired_difference",
    "run_search_eval",
    "standard_error",
]

#: First scene seed of the search's (and the closed loop's) held-out scenes: seeds 100, 101, ...
#: with the families round-robin. The field never saw them: it trains on seeds >= 1000, validates
#: on 500-505 and ``eval field`` uses 0, 1, ... (the seed table in docs/field.md).
HELD_OUT_SEED_START = 100
HELD_OUT_FAMILIES = ("indoor", "outdoor", "tabletop", "gallery")
HELD_OUT_SCENES = [f"{HELD_OUT_FAMILIES[i % 4]}:{HELD_OUT_SEED_START + i}" for i in range(6)]
METHODS = [
    "field_fast",
    "field_balanced",
    "rgb",
    "best_input",
    "inplane",
    "rotation",
    "random",
    "oracle",
    "covered_oracle",
]
FIELD_PRESETS = {"field_fast": "fast", "field_balanced": "balanced"}
#: The method every other one is compared with, scene by scene (``vs_field_balanced``).
REFERENCE_METHOD = "field_balanced"
#: Paired differences of normalized score within this count as the same (1 % of oracle - random).
SAME_TOL = 0.01


@dataclasses.dataclass
class SearchEvalConfig:
    """What ``eval search`` runs. ``scenes``: FILE_OR_FAMILY:SEED specs; ``views``: input counts;
    ``modes``: platform kinds, ``rig`` and/or ``drone`` (``free``, the older word, is read as drone;
    a drone scene runs as a drone only: rig mode alone on one is an error); ``oracle_step_deg``: the rig oracle's grid step; ``supersample``: of the
    ground-truth renders; ``ablations``: run Tables 3, 4 and S1 on the first ``ablation_scenes``
    rig scenes (rig, 4 views); ``free_box_m``: half-size of the drone box around a rig scene's
    base for a drone (a drone scene flies its own box); ``width``/``height`` override the scenes' camera (tests);
    ``seed``: of the oracle and the random views (the normalisation); ``search_seed``: the searches'
    own sampling seed (``rgb`` and the field presets), so a figure's spread over seeds can be
    measured against one oracle."""

    scenes: list[str] = dataclasses.field(default_factory=lambda: HELD_OUT_SCENES[:4])
    views: list[int] = dataclasses.field(default_factory=lambda: [4])
    modes: list[str] = dataclasses.field(default_factory=lambda: ["rig", "drone"])
    methods: list[str] = dataclasses.field(default_factory=lambda: list(METHODS))
    oracle_step_deg: float = 5.0
    oracle_free_positions: tuple[int, int, int] = (3, 3, 2)
    oracle_free_step_deg: float = 30.0
    oracle_min_step_deg: float = 0.5
    oracle_refine_starts: int = 3
    supersample: int = 1
    ablations: bool = True
    ablation_scenes: int = 2
    gradient_starts: int = 4
    free_box_m: tuple[float, float, float] = RIG_FREE_BOX_HALF_M
    local_grid: int = 5
    random_samples: int = 64
    width: int | None = None
    height: int | None = None
    cache_dir: str | None = None
    seed: int = 0
    search_seed: int = 0

    def __post_init__(self):
        from aes_planner.config import distinct, require

        require(isinstance(self.modes, list), "modes", f"must be a list of rig and/or drone, got {self.modes!r}")
        self.modes = [parse_kind(m, "modes") for m in self.modes]  # 'free' (the older word) is a drone
        for name in ("scenes", "views", "modes", "methods"):
            setattr(self, name, distinct(getattr(self, name), name))
        require(len(self.scenes) >= 1, "scenes", "give at least one scene (FAMILY:SEED or a YAML file)")
        require(
            isinstance(self.search_seed, int) and not isinstance(self.search_seed, bool) and self.search_seed >= 0,
            "search_seed",
            f"must be an integer >= 0, got {self.search_seed!r}",
        )
        require(
            bool(self.views) and all(isinstance(v, int) and 1 <= v <= 16 for v in self.views),
            "views",
            f"must be integers in [1, 16]: {self.views}",
        )
        require(bool(self.modes), "modes", "give rig and/or drone")
        unknown = sorted(set(self.methods) - set(METHODS))
        require(not unknown, "methods", f"unknown {unknown}; choose from {METHODS}")
        require(
            math.isfinite(self.oracle_step_deg) and 0.5 <= self.oracle_step_deg <= 45,
            "oracle_step_deg",
            f"must be in [0.5, 45] deg (finer grids do not fit in memory), got {self.oracle_step_deg}",
        )


class SearchEvalError(AesPlannerError, ValueError):
    """A search evaluation that cannot run as asked (e.g. rig mode on a drone scene)."""


# ------------------------------------------------------------------------------------ set-up
def _free_platform(source, box_half_m) -> Platform:
    """A drone scene's own box; for a rig scene, a box around the rig's base (a drone flies near it)."""
    return DronePlatform(source.platform.intrinsics, source.platform.free_box(box_half_m))


def _mode_platform(source, kind: str, box_half_m) -> Platform:
    """The scene's own platform when it is of ``kind``, else a drone in the box around it."""
    return source.platform if source.platform.kind == kind else _free_platform(source, box_half_m)


def _scene_modes(scene, modes: list[str]) -> list[str]:
    """The platform kinds of ``modes`` a scene supports: a drone scene (no rig) is a drone only."""
    return [m for m in modes if m == DronePlatform.kind or scene.rig is not None]


def _drone_inputs(platform: Platform, n: int) -> np.ndarray:  # -> [n, 4, 4]
    """n views along the box's diagonal, yaw spread around the circle from +x, pitched
    alternately 10 deg down and 5 deg up."""
    views = np.zeros((n, 5))
    views[:, :3] = platform.drone.diagonal_positions_m(n)
    yaw_rad = 2 * np.pi * np.arange(n) / n
    views[:, 3] = np.arctan2(np.sin(yaw_rad), np.cos(yaw_rad))
    views[:, 4] = np.where(np.arange(n) % 2 == 0, math.radians(-10.0), math.radians(5.0))
    return view_to_cam2world(torch.as_tensor(views)).numpy()


def _inputs(source, platform: Platform, n: int) -> np.ndarray:  # -> [n, 4, 4]
    """Rig: the survey sweep. Free: the sweep's directions from positions along the box's diagonal;
    a drone scene (no rig) turns around the circle instead, as the planner's exploration does."""
    if source.platform.rig is None:
        return _drone_inputs(platform, n)
    pt = PanTilt(source.platform.rig)
    j = pt.sweep(n)
    poses = pt.forward(j[:, 0], j[:, 1])
    if isinstance(platform, DronePlatform):
        poses = poses.copy()
        poses[:, :3, 3] = platform.drone.diagonal_positions_m(n)
    return poses


def _local_grid(space: SearchSpace, anchor: torch.Tensor, half_rad: float, half_m: float, n: int, kind: str):
    """``inplane``: shifts of the image plane (free: translations along right/down; rig: the
    small pan/tilt equivalent of a crop shift); ``rotation``: pan/tilt or yaw/pitch offsets."""
    offs = np.linspace(-1.0, 1.0, n)
    a, b = np.meshgrid(offs, offs, indexing="ij")
    a, b = torch.as_tensor(a.ravel()), torch.as_tensor(b.ravel())
    if isinstance(space, RigSpace):
        scale = half_rad * (0.3 if kind == "inplane" else 1.0)
        return space.project(anchor[None] + torch.stack([a, b], -1) * scale)
    p = anchor[None].repeat(len(a), 1)
    if kind == "rotation":
        p[:, 3] += a * half_rad
        p[:, 4] += b * half_rad
    else:
        pose = space.to_poses(anchor[None])[0]
        p[:, :3] += (a[:, None] * pose[:3, 0] + b[:, None] * pose[:3, 1]) * half_m
    return space.project(p)


# ------------------------------------------------------------------------------------ measuring
def covered_oracle(frames, platform: Platform, oracle_pose: np.ndarray, oracle_extra: dict, teacher):
    """What one shot can know: the oracle grid's best ground-truth view among the views the inputs
    cover (the reconstruction's alpha over the view >= the search's ``coverage_min``), as
    ``(pose [4, 4], coverage of the oracle's own view)``. Where it is well below the oracle, the
    best view lies where no input looked: a one-shot search cannot know it, a loop must go and see.
    Falls back to the best-covered grid view when no grid view is covered."""
    scfg = SearchConfig.preset("balanced", mode=platform.kind)
    rgb = build_search_scorer("rgb", frames, scfg, teacher)  # alpha only: rasterised, never scored
    space = space_for(platform, scfg)
    grid = torch.as_tensor(oracle_extra["grid_params"])  # [G, D]
    cov = []
    with torch.no_grad():
        for start in range(0, len(grid), 256):
            cov.append(rgb.render(space.to_poses(grid[start : start + 256]))[1].double().mean((1, 2)))
        oracle_cov = float(rgb.render(torch.as_tensor(oracle_pose[None]))[1].double().mean())
    cov_np = torch.cat(cov).numpy()  # [G]
    scores = np.asarray(oracle_extra["grid_scores"], dtype=np.float64)  # [G]
    covered = cov_np >= scfg.coverage_min
    i = int(np.argmax(np.where(covered, scores, -np.inf))) if covered.any() else int(np.argmax(cov_np))
    return space.to_poses(grid[i : i + 1])[0].numpy(), oracle_cov


class Judge:
    """Ground-truth teacher and evaluator scores at poses of one scene (renders cached by pose)."""

    def __init__(self, source, teacher, evaluator: CompositionEvaluator):
        self.gt = GroundTruthScorer(source, teacher)
        self.evaluator = evaluator

    def measure(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # [B, 4, 4] -> teacher [B], evaluator [B]
        images = self.gt.render(torch.as_tensor(poses, dtype=torch.float64))
        with torch.no_grad():
            t = self.gt.teacher.score(images).double().numpy()
        e = np.asarray(self.evaluator.evaluate(images), dtype=np.float64)
        return t, e


def _method_pose(
    method: str, frames, inputs, platform, judge: Judge, teacher, cfg: SearchEvalConfig, timings: dict
) -> np.ndarray | None:
    """The pose ``[4, 4]`` a method suggests (None when the method cannot run in this build)."""
    t0 = time.perf_counter()
    try:
        if method in FIELD_PRESETS or method == "rgb":
            preset = FIELD_PRESETS.get(method, "balanced")
            scfg = SearchConfig.preset(preset, mode=platform.kind, seed=cfg.search_seed)
            scorer = build_search_scorer("field" if method != "rgb" else "rgb", frames, scfg, teacher)
            result = search_views(scorer, inputs, platform, scfg)
            return result.best.cam2world
        if method == "best_input":
            t, _ = judge.measure(inputs)
            return inputs[int(np.argmax(t))]
        if method in ("inplane", "rotation"):
            space = space_for(platform, SearchConfig())
            hfov = platform.intrinsics.hfov_rad
            diag = platform.drone.diagonal_m if platform.drone is not None else 0.0
            anchors = space.from_poses(inputs)
            cands = torch.cat(
                [_local_grid(space, a, 0.35 * hfov, 0.1 * diag, cfg.local_grid, method) for a in anchors]
            )  # [n * g * g, D]
            poses = space.to_poses(cands).numpy()
            t = judge.gt.score_batched(torch.as_tensor(poses)).score.numpy()
            return poses[int(np.argmax(t))]
    except SearchError as exc:
        log.warning("%s: skipped (%s)", method, exc)
        return None
    finally:
        timings[method] = (time.perf_counter() - t0) * 1e3
    raise ValueError(method)


def _warm_up(first, methods: list[str], teacher, cfg: SearchEvalConfig) -> None:
    """One untimed suggestion per scorer kind on the first scene, so that no method's latency
    carries the process's first-call costs (the preset front compares the latencies)."""
    spec, scene, modes = first
    source = _source(scene, cfg)
    platform = _mode_platform(source, modes[0], cfg.free_box_m)
    inputs = _inputs(source, platform, cfg.views[0])
    frames = [source.capture(p) for p in inputs]
    for kind in sorted({"rgb" if m == "rgb" else "field" for m in methods}):
        scfg = SearchConfig.preset("fast", mode=platform.kind, seed=cfg.search_seed)
        try:
            search_views(build_search_scorer(kind, frames, scfg, teacher), inputs, platform, scfg)
        except SearchError as exc:  # the method itself will say so, scene by scene
            log.warning("eval search: no warm-up for %s (%s)", kind, exc)


def run_search_eval(
    cfg: SearchEvalConfig, out_dir: str | Path | None = None, progress: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Run the evaluation; returns the JSON document (``views -> mode -> method -> figures``)."""
    from aes_planner.sim.scene import load_scene

    teacher = get_teacher()
    evaluator = CompositionEvaluator()
    per_scene: list[dict[str, Any]] = []
    figures: dict[str, Any] = {}
    out = Path(out_dir) if out_dir else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    scenes = []  # every scene and its modes checked before the long run
    for spec in cfg.scenes:
        scene = load_scene(spec)
        modes = _scene_modes(scene, cfg.modes)
        if not modes:
            raise SearchEvalError(f"scene {spec} has no rig (a drone scene): evaluate it with --modes drone")
        if len(modes) < len(cfg.modes):
            log.info("eval search: %s is a drone scene: drone only", spec)
        scenes.append((spec, scene, modes))
    warm = [m for m in cfg.methods if m in FIELD_PRESETS or m == "rgb"]
    if warm:  # the first timed method would pay the process's warm-up (kernels, torch) alone
        _warm_up(scenes[0], warm, teacher, cfg)
    for spec, scene, modes in scenes:
        source = _source(scene, cfg)
        source.name = spec
        for mode in modes:
            platform = _mode_platform(source, mode, cfg.free_box_m)
            if progress:
                progress(f"{spec} {mode}: oracle")
            o_score, o_pose, o_extra = scene_oracle(spec, source, teacher, platform, cfg)
            judge = Judge(source, teacher, evaluator)
            mean_random = o_extra["mean_random"]
            # the oracle's own random poses (same space, seed and count), so 'random' normalises to 0
            _, rand_e = judge.measure(random_poses(platform, cfg.random_samples, np.random.default_rng(cfg.seed)))
            for n in cfg.views:
                inputs = _inputs(source, platform, n)
                frames = [source.capture(p) for p in inputs]
                row: dict[str, Any] = {"scene": spec, "mode": mode, "views": n, "oracle": o_score,
                                       "mean_random": mean_random, "methods": {}, "latency_ms": {}}  # fmt: skip
                for method in cfg.methods:
                    if progress:
                        progress(f"{spec} {mode} {n} views: {method}")
                    if method == "random":
                        t, e = mean_random, float(np.mean(rand_e))
                    elif method == "oracle":
                        t, e = o_score, float(judge.measure(o_pose[None])[1][0])
                    elif method == "covered_oracle":
                        pose, row["oracle_coverage"] = covered_oracle(frames, platform, o_pose, o_extra, teacher)
                        tt, ee = judge.measure(pose[None])
                        t, e = float(tt[0]), float(ee[0])
                    else:
                        pose = _method_pose(method, frames, inputs, platform, judge, teacher, cfg, row["latency_ms"])
                        if pose is None:
                            continue
                        tt, ee = judge.measure(pose[None])
                        t, e = float(tt[0]), float(ee[0])
                    row["methods"][method] = {
                        "teacher": t,
                        "evaluator": e,
                        "normalized": normalized(t, o_score, mean_random),
                    }
                per_scene.append(row)
            if out and isinstance(platform, RigPlatform) and {"field_balanced", "rgb"} & set(cfg.methods):
                _rig_map(out, spec, source, platform, frames, teacher, o_extra, cfg)
            if out and isinstance(platform, DronePlatform) and {"field_balanced", "rgb"} & set(cfg.methods):
                _top_view(out, spec, platform, frames, inputs, teacher, cfg)
    doc = _aggregate(per_scene, cfg)
    if cfg.ablations:
        doc["ablations"] = run_ablations(cfg, teacher, progress)
    doc["per_scene"] = per_scene
    doc["figures"] = figures
    if out:
        output_in(out, "search_eval.json").write_text(json.dumps(doc, indent=1) + "\n")
        output_in(out, "search_eval.md").write_text(markdown(doc))
        write_front_plots(doc, out)
    return doc


#: A slower preset is on the front only when it beats the next faster one by this much (oracle-normalised).
FRONT_MIN_GAIN = 0.03
#: The presets in order of cost, and the reference points drawn beside them.
FRONT_PRESETS = ("field_fast", "field_balanced", "field_accurate")  # accurate: in results from before its removal
FRONT_REFERENCES = ("rgb", "best_input")


def preset_front(table: dict[str, Any], latency_ms: dict[str, float]) -> list[dict[str, Any]]:
    """The presets of one (views, mode) table, fastest first: latency, normalised score, the gain
    over the next faster preset on the front and whether the preset is on the front (it beats every
    faster one on it by at least ``FRONT_MIN_GAIN``; otherwise a faster preset is as good)."""
    rows, best = [], None
    for method in sorted((m for m in FRONT_PRESETS if m in table), key=lambda m: latency_ms.get(m, math.inf)):
        norm = float(table[method]["normalized"])
        gain = None if best is None else norm - best
        on = best is None or gain >= FRONT_MIN_GAIN
        rows.append({"method": method, "latency_ms": latency_ms.get(method), "normalized": norm,
                     "normalized_se": table[method].get("normalized_se"), "gain": gain, "on_front": on})  # fmt: skip
        if on:
            best = norm
    return rows


def _front_lines(table: dict[str, Any], latency_ms: dict[str, float]) -> list[str]:
    rows = preset_front(table, latency_ms)
    if len(rows) < 2:
        return []
    lines = [f"Preset front (a slower preset must beat the faster ones by >= {FRONT_MIN_GAIN}):", ""]
    for r in rows:
        ms = "?" if r["latency_ms"] is None else f"{r['latency_ms']:.0f} ms"
        gain = "" if r["gain"] is None else f", {r['gain']:+.3f} over the front so far"
        verdict = "on the front" if r["on_front"] else "NOT on the front (a faster preset is as good)"
        lines.append(f"- {r['method']}: {_pm(r['normalized'], r['normalized_se'])} in {ms}{gain}: {verdict}")
    for ref in FRONT_REFERENCES:
        if ref in table:
            ms = f"{latency_ms[ref]:.0f} ms" if ref in latency_ms else "?"
            lines.append(f"- reference {ref}: {_pm(table[ref]['normalized'], table[ref].get('normalized_se'))} in {ms}")
    return [*lines, ""]


def write_front_plots(doc: dict[str, Any], out: Path) -> list[Path]:
    """``preset_front_<views>v_<mode>.png`` per table: latency against oracle-normalised score, the
    presets joined, RGB scoring and best-input as reference points (:func:`write_pareto`)."""
    paths = []
    for n, modes in doc["views"].items():
        for mode, table in modes.items():
            if mode == "latency_ms":
                continue
            lat = modes.get("latency_ms", {}).get(mode, {})
            names = {"field_fast": "fast", "field_balanced": "balanced", "field_accurate": "accurate"}
            names["best_input"] = "input (best)"  # its own initial on the plot
            points = {
                names.get(m, m): (lat[m], table[m]["normalized"], table[m].get("normalized_se"))
                for m in (*FRONT_PRESETS, *FRONT_REFERENCES)
                if m in table and m in lat
            }
            if points:
                title = f"presets, {mode}, {n} views: time against oracle-normalised score"
                paths.append(write_pareto(points, output_in(out, f"preset_front_{n}v_{mode}.png"), title))
    return paths


def _oracle_kw(cfg: SearchEvalConfig) -> dict[str, Any]:
    return dict(
        step_deg=cfg.oracle_step_deg,
        free_positions=tuple(cfg.oracle_free_positions),
        free_step_deg=cfg.oracle_free_step_deg,
        min_step_deg=cfg.oracle_min_step_deg,
        refine_starts=cfg.oracle_refine_starts,
        random_samples=cfg.random_samples,
    )


def scene_oracle(spec: str, source, teacher, platform, cfg: SearchEvalConfig):
    """``oracle_search`` keyed by the scene spec and its YAML (so an edited file is a new entry)."""
    from aes_planner.sim.scene import scene_to_yaml

    key = f"{spec}#{hash_text(scene_to_yaml(source.scene))}"
    return oracle_search(
        source, teacher, platform, **_oracle_kw(cfg), scene_key=key, cache_dir=cfg.cache_dir, seed=cfg.seed
    )


def _source(scene, cfg: SearchEvalConfig):
    from aes_planner.sim import SimCameraConfig, SimSource

    camera = SimCameraConfig(width=cfg.width, height=cfg.height, supersample=cfg.supersample)
    return SimSource(scene, supersample=cfg.supersample, camera=camera)


def hash_text(text: str) -> str:
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()[:12]


def standard_error(values) -> float | None:
    """Standard error of the mean of ``values`` (sample standard deviation / sqrt(n)); ``None``
    for fewer than two values, where a spread cannot be estimated."""
    v = np.asarray(list(values), dtype=np.float64)
    return float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) >= 2 else None


def paired_difference(rows: list[dict[str, Any]], method: str, reference: str) -> dict[str, Any] | None:
    """``method`` minus ``reference`` in normalized score over the rows (scenes) that ran both:
    the mean difference, its standard error and the count of scenes better / the same (within
    ``SAME_TOL``) / worse. ``None`` when no row has both."""
    d = np.array(
        [r["methods"][method]["normalized"] - r["methods"][reference]["normalized"]
         for r in rows if method in r["methods"] and reference in r["methods"]]
    )  # fmt: skip
    if not len(d):
        return None
    return {
        "diff": float(d.mean()),
        "diff_se": standard_error(d),
        "better": int((d > SAME_TOL).sum()),
        "same": int((np.abs(d) <= SAME_TOL).sum()),
        "worse": int((d < -SAME_TOL).sum()),
    }


def _aggregate(rows: list[dict[str, Any]], cfg: SearchEvalConfig) -> dict[str, Any]:
    views: dict[str, Any] = {}
    for n in cfg.views:
        for mode in cfg.modes:
            sel = [r for r in rows if r["views"] == n and r["mode"] == mode]
            if not sel:  # e.g. rig mode when every scene is a drone scene
                continue
            table = {}
            for method in cfg.methods:
                vals = [r["methods"][method] for r in sel if method in r["methods"]]
                if vals:
                    table[method] = {
                        k: float(np.mean([v[k] for v in vals])) for k in ("teacher", "evaluator", "normalized")
                    }
                    table[method]["n"] = len(vals)
                    table[method]["normalized_se"] = standard_error(v["normalized"] for v in vals)
                    if method != REFERENCE_METHOD:
                        paired = paired_difference(sel, method, REFERENCE_METHOD)
                        if paired is not None:
                            table[method][f"vs_{REFERENCE_METHOD}"] = paired
            lat = {}
            for method in cfg.methods:
                ms = [r["latency_ms"][method] for r in sel if method in r["latency_ms"] and method in r["methods"]]
                if ms:
                    lat[method] = float(np.median(ms))
            views.setdefault(str(n), {})[mode] = table
            views[str(n)].setdefault("latency_ms", {})[mode] = lat
    return {"views": views, "scenes": list(cfg.scenes), "search_seed": cfg.search_seed}


# ------------------------------------------------------------------------------------ ablations
def run_ablations(cfg: SearchEvalConfig, teacher, progress=None) -> dict[str, Any]:
    """Table 3 (gradient gain from random starts, field vs RGB) and Tables 4/S1 (K, steps, S x N),
    on the first ``cfg.ablation_scenes`` rig scenes, rig mode, 4 input views."""
    from aes_planner.sim.scene import load_scene

    gains: dict[str, list[float]] = {"field": [], "rgb": []}
    by_k: dict[int, list[float]] = {1: [], 2: [], 3: []}
    by_steps: dict[int, list[float]] = {15: [], 20: [], 25: [], 30: []}
    sn_values = (4, 8, 16, 32)
    by_sn: dict[str, list[float]] = {f"{s}x{n}": [] for s in sn_values for n in sn_values}
    scorer_kind = "field"
    loaded = ((spec, load_scene(spec)) for spec in cfg.scenes)
    rig_scenes = [(spec, scene) for spec, scene in loaded if scene.rig is not None]
    if not rig_scenes:
        log.warning("ablations: none of the scenes has a rig (they run in rig mode); skipped")
        return {}
    for spec, scene in rig_scenes[: cfg.ablation_scenes]:
        source = _source(scene, cfg)
        platform = source.platform
        o_score, _, o_extra = scene_oracle(spec, source, teacher, platform, cfg)
        mean_random = o_extra["mean_random"]
        gt = GroundTruthScorer(source, teacher)
        inputs = _inputs(source, platform, 4)
        frames = [source.capture(p) for p in inputs]
        base = SearchConfig.preset("balanced", seed=cfg.seed)
        scorers = {}
        for kind in ("field", "rgb"):
            try:
                scorers[kind] = build_search_scorer(kind, frames, base, teacher)
            except SearchError as exc:
                log.warning("ablations: no %s scorer (%s)", kind, exc)
        if not scorers:
            continue
        scorer_kind = "field" if "field" in scorers else "rgb"
        space = space_for(platform, base)
        starts = space.random(cfg.gradient_starts, np.random.default_rng(cfg.seed + 7))
        start_gt = gt.score(space.to_poses(starts)).score.double()
        for kind, scorer in scorers.items():  # Table 3: 25 Adam steps from the same random starts
            if progress:
                progress(f"{spec}: gradient ascent on {kind}")
            obj0 = scorer.score_batched(space.to_poses(starts)).score.double()
            last, _, _ = refine_params(scorer, space, starts, obj0, dataclasses.replace(base, steps=25))
            end_gt = gt.score(space.to_poses(last)).score.double()
            gains[kind].extend((end_gt - start_gt).tolist())
        scorer = scorers[scorer_kind]

        def norm_of(
            scfg: SearchConfig, scorer=scorer, inputs=inputs, platform=platform, gt=gt, o=o_score, r=mean_random
        ):
            best = search_views(scorer, inputs, platform, scfg).best.cam2world
            return normalized(float(gt.score(torch.as_tensor(best[None])).score[0]), o, r)

        if progress:
            progress(f"{spec}: K / steps / S x N ablations on {scorer_kind}")
        for k in by_k:
            by_k[k].append(norm_of(dataclasses.replace(base, top_k=k)))
        for steps in by_steps:
            by_steps[steps].append(norm_of(dataclasses.replace(base, steps=steps)))
        for s in sn_values:
            for n in sn_values:
                by_sn[f"{s}x{n}"].append(norm_of(dataclasses.replace(base, samples_per_segment=s, neighbours=n)))

    def mean(d):
        return {str(k): (float(np.mean(v)) if v else None) for k, v in d.items()}

    def spread(d):
        return {str(k): standard_error(v) for k, v in d.items()}

    tables = {"gradient_gain": gains, "top_k": by_k, "steps": by_steps, "samples_x_neighbours": by_sn}
    return {
        "scorer": scorer_kind,
        "scenes": len(by_k[1]),  # the rig scenes the ablations ran on
        **{name: mean(d) for name, d in tables.items()},
        **{f"{name}_se": spread(d) for name, d in tables.items()},  # over scenes (Table 3: over starts)
    }


# ------------------------------------------------------------------------------------ report
def markdown(doc: dict[str, Any]) -> str:
    lines = ["# Search evaluation", "", f"Scenes: {', '.join(doc['scenes'])}", ""]
    for n, modes in doc["views"].items():
        for mode, table in modes.items():
            if mode == "latency_ms":
                continue
            lat = modes.get("latency_ms", {}).get(mode, {})
            scenes = max((v.get("n", 0) for v in table.values()), default=0)
            paired = REFERENCE_METHOD in table
            vs = f" vs {REFERENCE_METHOD}: diff ± s.e. (better / same / worse) |" if paired else ""
            lines += [f"## {n} input views, {mode} (Table 2 analogue, {scenes} scene{'s' * (scenes != 1)})", "",
                      f"| method | teacher | evaluator | normalized ± s.e. |{vs} latency ms |",
                      "|---|---|---|---|" + "---|" * paired + "---|"]  # fmt: skip
            for method, v in table.items():
                ms = f"{lat[method]:.0f}" if method in lat else ""
                cells = [
                    method,
                    f"{v['teacher']:.3f}",
                    f"{v['evaluator']:.3f}",
                    _pm(v["normalized"], v.get("normalized_se")),
                ]
                if paired:
                    d = v.get(f"vs_{REFERENCE_METHOD}")
                    cells.append(
                        "reference" if method == REFERENCE_METHOD else ""
                        if d is None else f"{_pm(d['diff'], d['diff_se'], '+')} ({d['better']} / {d['same']} / {d['worse']})"
                    )  # fmt: skip
                lines.append("| " + " | ".join([*cells, ms]) + " |")
            lines += ["", *_front_lines(table, lat)]
            lines += [*_per_scene_table(doc.get("per_scene", []), n, mode, list(table))]
    ab = doc.get("ablations")
    if ab:
        se = {name: ab.get(f"{name}_se", {}) for name in ("gradient_gain", "top_k", "steps", "samples_x_neighbours")}
        scenes = f", {ab['scenes']} scenes" if "scenes" in ab else ""
        lines += ["## Table 3 analogue: gradient-ascent gain over 25 steps (ground-truth teacher score, ± s.e. over starts)",
                  "", "| scorer | mean gain |", "|---|---|"]  # fmt: skip
        for k, v in ab["gradient_gain"].items():
            lines.append(f"| {k} | {_pm(v, se['gradient_gain'].get(k), '+')} |")
        lines += [
            "",
            f"## Table 4 analogue ({ab['scorer']} scorer, normalized score ± s.e.{scenes})",
            "",
            "| K | normalized |",
            "|---|---|",
        ]
        lines += [f"| {k} | {_pm(v, se['top_k'].get(k))} |" for k, v in ab["top_k"].items()]
        lines += ["", "| steps | normalized |", "|---|---|"]
        lines += [f"| {k} | {_pm(v, se['steps'].get(k))} |" for k, v in ab["steps"].items()]
        lines += ["", f"## Table S1 analogue (S x N, normalized ± s.e.{scenes})", ""]
        ss = sorted({int(k.split("x")[0]) for k in ab["samples_x_neighbours"]})
        grid, grid_se = ab["samples_x_neighbours"], se["samples_x_neighbours"]
        lines += ["| N \\ S | " + " | ".join(str(s) for s in ss) + " |", "|---" * (len(ss) + 1) + "|"]
        for n in ss:
            lines.append(f"| {n} | " + " | ".join(_pm(grid[f"{s}x{n}"], grid_se.get(f"{s}x{n}")) for s in ss) + " |")
        lines.append("")
    return "\n".join(lines) + "\n"


def _per_scene_table(rows: list[dict[str, Any]], views: str, mode: str, methods: list[str]) -> list[str]:
    """Markdown lines: each scene's normalized score per method (random and oracle are 0 and 1 by
    definition: the oracle's teacher score is shown instead); none when there are no rows."""
    rows = [r for r in rows if str(r["views"]) == views and r["mode"] == mode]
    shown = [m for m in methods if m not in ("random", "oracle")]
    if not rows or not shown:
        return []
    lines = [f"Per scene, normalized ({views} views, {mode}):", "",
             "| scene | " + " | ".join(shown) + " | oracle teacher |", "|---" * (len(shown) + 2) + "|"]  # fmt: skip
    for r in rows:
        name = Path(r["scene"]).name if r["scene"].endswith((".yaml", ".yml")) else r["scene"]
        cells = [_pm(r["methods"][m]["normalized"]) if m in r["methods"] else "" for m in shown]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {r['oracle']:.3f} |")
    return [*lines, ""]


def _pm(value: float | None, se: float | None = None, sign: str = "") -> str:
    """``value ± se`` to 3 decimals (``sign="+"`` always signs the value); empty for no value."""
    if value is None:
        return ""
    value = round(value, 3) + 0.0  # + 0.0: no "-0.000"
    return f"{value:{sign}.3f}" + ("" if se is None else f" ± {se:.3f}")


def _colour(values: np.ndarray) -> np.ndarray:  # [N] -> [N, 3] BGR uint8 (viridis)
    v = np.asarray(values, dtype=np.float64)
    lo, hi = np.nanmin(v), np.nanmax(v)
    u8 = np.clip((v - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
    return cv2.applyColorMap(u8[:, None], cv2.COLORMAP_VIRIDIS)[:, 0]


def _rig_map(out: Path, spec: str, source, platform, frames, teacher, o_extra, cfg: SearchEvalConfig) -> None:
    """Pan x tilt map: the field's score beside ground truth, suggestions marked."""
    scfg = SearchConfig.preset("balanced", seed=cfg.seed)
    try:
        scorer = build_search_scorer("field", frames, scfg, teacher)
        label = "field"
    except SearchError:
        scorer = build_search_scorer("rgb", frames, scfg, teacher)
        label = "rgb"
    grid = torch.as_tensor(o_extra["grid_params"])
    space = space_for(platform, scfg)
    pred = scorer.score_batched(space.to_poses(grid)).score.double().numpy()
    result = search_views(scorer, np.stack([f.cam2world for f in frames]), platform, scfg)
    pans, tilts = o_extra["pan_values"], o_extra["tilt_values"]
    panels = []
    for name, values in ((label, pred), ("ground truth", o_extra["grid_scores"])):
        img = _colour(values).reshape(len(tilts), len(pans), 3)[::-1]  # tilt up
        img = cv2.resize(img, (len(pans) * 6, len(tilts) * 6), interpolation=cv2.INTER_NEAREST)
        h, w = img.shape[:2]

        def px(pan, tilt, w=w, h=h):
            x = (pan - pans[0]) / max(pans[-1] - pans[0], 1e-9) * (w - 1)
            y = (1 - (tilt - tilts[0]) / max(tilts[-1] - tilts[0], 1e-9)) * (h - 1)
            return int(round(x)), int(round(y))

        for f in frames:
            p = space.from_poses(f.cam2world[None])[0]
            cv2.drawMarker(img, px(float(p[0]), float(p[1])), (255, 255, 255), cv2.MARKER_SQUARE, 8, 1)
        for s in result.suggestions:
            cv2.drawMarker(img, px(s.pan_rad, s.tilt_rad), (0, 0, 255), cv2.MARKER_CROSS, 12, 2)
        ob = o_extra["best_params"]
        cv2.drawMarker(img, px(float(ob[0]), float(ob[1])), (255, 0, 255), cv2.MARKER_STAR, 12, 1)
        canvas = np.full((h + 20, w, 3), 255, np.uint8)
        canvas[20:] = img
        cv2.putText(canvas, f"{name} (pan x tilt)", (2, 14), cv2.FONT_HERSHEY_PLAIN, 1.0, (0, 0, 0), 1, cv2.LINE_AA)
        panels.append(np.pad(canvas, ((4, 4), (4, 4), (0, 0)), constant_values=255))
    cv2.imwrite(str(output_in(out, f"rig_map_{spec.replace(':', '_').replace('/', '_')}.png")), np.hstack(panels))


def _top_view(out: Path, spec: str, platform, frames, inputs, teacher, cfg: SearchEvalConfig) -> None:
    """Fig. 5 analogue: stage-1 candidates seen from above (x right, y up), coloured by score."""
    scfg = SearchConfig.preset("balanced", mode=platform.kind, seed=cfg.seed)
    try:
        scorer = build_search_scorer("field", frames, scfg, teacher)
    except SearchError:
        scorer = build_search_scorer("rgb", frames, scfg, teacher)
    result = search_views(scorer, inputs, platform, scfg)
    lo, hi = np.asarray(platform.drone.bounds_min_m), np.asarray(platform.drone.bounds_max_m)
    size, margin = 480, 40
    scale = (size - 2 * margin) / max(hi[0] - lo[0], hi[1] - lo[1])
    img = np.full((size, size, 3), 255, np.uint8)

    def px(p):  # world x right, world y up
        return int(margin + (p[0] - lo[0]) * scale), int(size - margin - (p[1] - lo[1]) * scale)

    cv2.rectangle(img, px(lo), px(hi), (160, 160, 160), 1)
    colours = _colour(result.candidates_score)
    for pose, c in zip(result.candidates_cam2world, colours):
        a = px(pose[:3, 3])
        b = px(pose[:3, 3] + 0.15 * pose[:3, 2])
        cv2.arrowedLine(img, a, b, tuple(int(v) for v in c), 1, tipLength=0.3)
    for pose in inputs:
        cv2.drawMarker(img, px(pose[:3, 3]), (0, 0, 0), cv2.MARKER_SQUARE, 10, 2)
    for s in result.suggestions:
        cv2.drawMarker(img, px(s.position_m), (0, 0, 255), cv2.MARKER_CROSS, 14, 2)
    cv2.putText(img, f"{spec}: candidates by score (top view)", (4, 16), cv2.FONT_HERSHEY_PLAIN, 1.0, (0, 0, 0), 1)
    cv2.imwrite(str(output_in(out, f"top_view_{spec.replace(':', '_').replace('/', '_')}.png")), img)


#: How :func:`write_pareto` draws a point: BGR colour and marker; the presets joined in cost order.
_PARETO_STYLE = {
    "rgb": ((40, 40, 210), cv2.MARKER_SQUARE),  # RGB scoring: the reference the field must beat
    "input (best)": ((110, 110, 110), cv2.MARKER_TRIANGLE_UP),  # the best of the inputs: no search
}
_PRESET_COLOUR = (190, 110, 0)
_PRESET_CHAIN = ("fast", "balanced", "accurate")  # accurate: in results from before its removal


def write_pareto(points: dict[str, tuple], path: Path, title: str = "") -> Path:
    """Latency (log x) against oracle-normalised score (y); the presets joined, the references
    (``rgb``, ``input (best)``) drawn apart in their own colour and marker. ``points``:
    ``{name: (latency_ms, normalized)}`` or ``(latency_ms, normalized, standard_error | None)``,
    the error drawn as a bar of +-1 standard error over the scenes (``bench search`` and
    ``eval search --out`` draw it). Axes with ticks; the 0.8 and 0.9 goals and the 1 s goal as
    thin lines; each point's figures listed under the plot, so no label covers a point."""
    points = {name: (p[0], p[1], p[2] if len(p) > 2 else None) for name, p in points.items()}
    left, right, top, plot_h, w = 64, 24, 44, 260, 560
    legend_h = 20 + 16 * len(points)
    h = top + plot_h + 34 + legend_h
    img = np.full((h, w, 3), 255, np.uint8)
    lats = [p[0] for p in points.values()]
    lo, hi = np.log10(max(min(min(lats) / 2, 500.0), 1.0)), np.log10(max(max(lats) * 2, 2000.0))  # the 1 s goal in view
    y_lo, y_hi = -0.2, 1.1
    font, ink, grey = cv2.FONT_HERSHEY_PLAIN, (0, 0, 0), (215, 215, 215)

    def px(lat: float, norm: float) -> tuple[int, int]:
        x = left + (np.log10(max(lat, 1.0)) - lo) / max(hi - lo, 1e-9) * (w - left - right)
        y = top + plot_h - (np.clip(norm, y_lo, y_hi) - y_lo) / (y_hi - y_lo) * plot_h
        return int(round(x)), int(round(y))

    for norm in (0.0, 0.2, 0.4, 0.6, 0.8, 1.0):  # y ticks, with a light grid
        (x0, y), (x1, _) = px(10**lo, norm), px(10**hi, norm)
        cv2.line(img, (x0, y), (x1, y), grey, 1)
        cv2.putText(img, f"{norm:.1f}", (left - 30, y + 4), font, 0.9, ink, 1, cv2.LINE_AA)
    for decade in range(int(np.floor(lo)), int(np.ceil(hi)) + 1):  # x ticks: 1, 2, 5 per decade
        for mult in (1, 2, 5):
            lat = mult * 10.0**decade
            if not lo <= np.log10(lat) <= hi:
                continue
            x, y = px(lat, y_lo)
            cv2.line(img, (x, y), (x, y + 4), ink, 1)
            text = f"{lat / 1000:g} s" if lat >= 1000 else f"{lat:g}"
            cv2.putText(img, text, (x - 4 * len(text), y + 17), font, 0.9, ink, 1, cv2.LINE_AA)
    for goal, colour in ((0.8, (0, 160, 0)), (0.9, (0, 100, 0))):
        (x0, y), (x1, _) = px(10**lo, goal), px(10**hi, goal)
        cv2.line(img, (x0, y), (x1, y), colour, 1)
        cv2.putText(img, f"{goal} goal", (x1 - 62, y - 4), font, 0.8, colour, 1, cv2.LINE_AA)
    (xg, y0), (_, y1) = px(1000, y_lo), px(1000, y_hi)
    cv2.line(img, (xg, y0), (xg, y1), (150, 150, 230), 1)  # the 1 s goal
    cv2.rectangle(img, px(10**lo, y_hi), px(10**hi, y_lo), ink, 1)
    cv2.putText(img, "ms per suggestion (log)", (left + (w - left - right) // 2 - 80, top + plot_h + 32), font, 0.9, ink, 1, cv2.LINE_AA)  # fmt: skip
    heading = title or "time against oracle-normalised score"
    cv2.putText(img, heading, (left, top - 26), font, 1.0, ink, 1, cv2.LINE_AA)
    cv2.putText(img, "(1 = the oracle's view, 0 = chance; bars +-1 s.e. over scenes)", (left, top - 10), font, 0.8, ink, 1, cv2.LINE_AA)  # fmt: skip
    chain = [points[c][:2] for c in _PRESET_CHAIN if c in points]
    for a, b in zip(chain, chain[1:]):
        cv2.line(img, px(*a), px(*b), _PRESET_COLOUR, 2, cv2.LINE_AA)
    for i, (name, (lat, norm, se)) in enumerate(points.items()):
        colour, marker = _PARETO_STYLE.get(name, (_PRESET_COLOUR, None))
        x, y = px(lat, norm)
        if se is not None:  # +-1 standard error over the scenes, with caps
            (_, ya), (_, yb) = px(lat, norm - se), px(lat, norm + se)
            cv2.line(img, (x, ya), (x, yb), colour, 1)
            for yy in (ya, yb):
                cv2.line(img, (x - 4, yy), (x + 4, yy), colour, 1)
        if marker is None:
            cv2.circle(img, (x, y), 5, colour, -1, cv2.LINE_AA)
        else:
            cv2.drawMarker(img, (x, y), colour, marker, 12, 2)
        cv2.putText(img, name[0].upper(), (x + 7, y - 6), font, 1.0, colour, 1, cv2.LINE_AA)
        spread = "" if se is None else f" +- {se:.2f}"
        cv2.putText(img, f"{name[0].upper()}  {name}: {lat:.0f} ms, {norm:.2f}{spread}",
                    (left, top + plot_h + 56 + 16 * i), font, 0.95, colour, 1, cv2.LINE_AA)  # fmt: skip
    from aes_planner.images import write_image

    path.parent.mkdir(parents=True, exist_ok=True)
    return write_image(path, img, "the trade-off plot")
