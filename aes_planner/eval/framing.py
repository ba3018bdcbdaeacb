"""``aes-planner eval framing``: does ``suggest --keep`` hold the subject, and how good is the view?

For every scene (held-out seeds by default) and seed, a subject is picked among the scene's
objects (the simulator's instance ids): an object that is not a plane, that fills between
``min_frac`` and ``max_frac`` of the input view that shows most of it, whose pixels there do
not touch the image border and cover at least ``min_shown`` of its true silhouette there (so its
box holds all of it, not a corner peeking out from behind another object). Seed ``s`` takes the ``s``-th such object,
largest first (none once the eligible objects run out). Its box in that view (the bounding rectangle of its instance pixels) is given to
the search as ``--keep`` would give it, and the suggestion is measured with the **true** scene:

* ``holds``: every point of the object's true surface (box corners, a cylinder's rims, points on
  a sphere) projects inside the frame, in front of the camera;
* ``evaluator`` / ``teacher``: the independent evaluator's and the teacher's scores of the
  ground-truth render at the suggestion;
* against a **constrained oracle**: the platform's exhaustive grid (as :func:`oracle_search`
  builds it) kept to the views that hold the object (true geometry), scored on ground-truth
  renders, then a compass search from the best of them that never leaves that set.
  ``normalized_*`` = ``(score - mean) / (best - mean)``, with ``mean`` the mean over the grid's
  views that hold the object (the "mean view" of the constrained problem): 1 = the best view
  that holds it, 0 = an average view that holds it;
* whether the two judges agree on the grid's views that hold the object: ``judges_rank_corr``
  (Spearman of the teacher's and the evaluator's scores) and ``evaluator_at_teacher_best`` (the
  evaluator's normalised score of the teacher's best grid view).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from typing import Any

import numpy as np
import torch

from aes_planner.errors import AesPlannerError
from aes_planner.eval.search import HELD_OUT_SCENES, Judge, _inputs, _mode_platform, _source
from aes_planner.field.scorer import ScoreOutput, Scorer
from aes_planner.platform import RIG_FREE_BOX_HALF_M, parse_kind
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.search.framing import FramingConfig, FramingError, Region, build_framing
from aes_planner.search.oracle import pattern_search
from aes_planner.search.space import space_for
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator

log = logging.getLogger(__name__)

__all__ = ["FramingEvalConfig", "markdown", "object_points", "pick_subject", "run_framing_eval", "true_holds"]


@dataclasses.dataclass
class FramingEvalConfig:
    """What ``eval framing`` runs (see the module docstring)."""

    scenes: list[str] = dataclasses.field(default_factory=lambda: HELD_OUT_SCENES[:4])
    seeds: list[int] = dataclasses.field(default_factory=lambda: [0, 1])
    subjects: list[str] = dataclasses.field(default_factory=list)
    views: int = 4
    mode: str = "rig"
    preset: str = "balanced"
    keep_margin: float = 0.05
    verify_top: int = FramingConfig.verify_top
    verify_weight: float = FramingConfig.verify_weight
    coverage_min: float = FramingConfig.coverage_min
    coverage_penalty: float = FramingConfig.coverage_penalty
    photo_rank: bool = FramingConfig.photo_rank
    hold_by: str = FramingConfig.hold_by
    min_frac: float = 0.01
    max_frac: float = 0.4
    min_shown: float = 0.6
    oracle_step_deg: float = 5.0
    oracle_free_positions: tuple[int, int, int] = (3, 3, 2)
    oracle_free_step_deg: float = 30.0
    oracle_min_step_deg: float = 1.0
    supersample: int = 1
    free_box_m: tuple[float, float, float] = RIG_FREE_BOX_HALF_M
    width: int | None = None
    height: int | None = None

    def __post_init__(self):
        from aes_planner.config import require

        self.mode = parse_kind(self.mode, "mode")
        require(bool(self.scenes), "scenes", "give at least one scene (FAMILY:SEED or a YAML file)")
        require(bool(self.seeds) and all(isinstance(s, int) and s >= 0 for s in self.seeds), "seeds", "must be >= 0")
        require(
            all(isinstance(n, str) and n.strip() for n in self.subjects),
            "subjects",
            "must be object names of the scenes (non-empty strings)",
        )
        require(isinstance(self.views, int) and 1 <= self.views <= 16, "views", f"must be in [1, 16], got {self.views}")
        require(0 < self.min_frac < self.max_frac <= 1, "min_frac", "must satisfy 0 < min_frac < max_frac <= 1")
        self.framing()  # the margin's and the verification's own checks

    def framing(self) -> FramingConfig:
        """The framing constraint the searches run with."""
        return FramingConfig(margin_frac=self.keep_margin, verify_top=self.verify_top, verify_weight=self.verify_weight,
                             coverage_min=self.coverage_min, coverage_penalty=self.coverage_penalty,
                             photo_rank=self.photo_rank, hold_by=self.hold_by)  # fmt: skip


class FramingEvalError(AesPlannerError, ValueError):
    """A framing evaluation that cannot run as asked."""


# ------------------------------------------------------------------------------ the true subject
def object_points(obj) -> np.ndarray:  # -> [P, 3] world
    """Points whose projections bound an object's true projection: a box's corners, a quad's,
    a cylinder's two rims (48 points each), a sphere's surface (a Fibonacci lattice of 400
    points, pushed out by 1 / cos of half the lattice spacing so that it encloses the sphere)."""
    from aes_planner.sim.shapes import shape_of

    kind, origin, dims = shape_of(obj)
    rot = np.asarray(obj.rotation(), dtype=np.float64)  # local -> world
    if kind.kind == "box":
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * dims
    elif kind.kind == "quad":
        local = np.array([[0.0, sy, sz] for sy in (-1, 1) for sz in (-1, 1)]) * dims
    elif kind.kind == "cylinder":
        a = np.linspace(0, 2 * math.pi, 48, endpoint=False)
        ring = np.stack([np.cos(a), np.sin(a)], -1) * dims[0] / math.cos(math.pi / 48)
        local = np.concatenate([np.c_[ring, np.full(48, z)] for z in (-dims[2], dims[2])])
    elif kind.kind == "sphere":
        n = 400
        i = np.arange(n) + 0.5
        phi, theta = np.arccos(1 - 2 * i / n), math.pi * (1 + 5**0.5) * i
        unit = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], -1)
        local = unit * dims[0] / math.cos(math.sqrt(4 * math.pi / n) / 2)
    else:
        raise FramingEvalError(f"object type {kind.kind!r} has no finite extent to hold")
    return origin + local @ rot.T


def true_holds(points: np.ndarray, poses: np.ndarray, intrinsics) -> np.ndarray:  # [P, 3], [B, 4, 4] -> [B] bool
    """Whether every point projects inside the frame ``[0, W] x [0, H]``, in front of the camera."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    rel = points[None] - poses[:, None, :3, 3]  # [B, P, 3]
    pc = np.einsum("bji,bpj->bpi", poses[:, :3, :3], rel)  # R^T (p - t)
    z = pc[..., 2]
    zs = np.where(z > 1e-6, z, 1.0)
    u = intrinsics.fx * pc[..., 0] / zs + intrinsics.cx
    v = intrinsics.fy * pc[..., 1] / zs + intrinsics.cy
    ok = (z > 1e-6) & (u >= 0) & (u <= intrinsics.width) & (v >= 0) & (v <= intrinsics.height)
    return ok.all(-1)


def _silhouette_px(points: np.ndarray, pose: np.ndarray, intrinsics) -> float:
    """Area in pixels of the convex hull of ``points`` projected at ``pose`` (all in front)."""
    import cv2

    rel = points - pose[:3, 3]
    pc = rel @ pose[:3, :3]
    if (pc[:, 2] <= 1e-6).any():
        return float("inf")
    uv = np.stack(
        [intrinsics.fx * pc[:, 0] / pc[:, 2] + intrinsics.cx, intrinsics.fy * pc[:, 1] / pc[:, 2] + intrinsics.cy], -1
    )
    return float(cv2.contourArea(cv2.convexHull(uv.astype(np.float32))))


def _shown(scene, obj_i: int, pose: np.ndarray, intrinsics) -> float:
    """The share of object ``obj_i``'s true silhouette that its pixels at ``pose`` cover (what
    the frame's border and the objects in front leave of it)."""
    from aes_planner.sim import render

    n = int((render(scene, pose, intrinsics, supersample=1).instance_id == obj_i + 1).sum())
    return n / max(_silhouette_px(object_points(scene.objects[obj_i]), pose, intrinsics), 1.0)


def pick_subject(scene, inputs: np.ndarray, intrinsics, seed: int, cfg: FramingEvalConfig, name: str | None = None):
    """``(object index, input view index, Region)`` of the ``seed``-th eligible object, largest first (none once
    the eligible objects run out); with ``name``, the object of that name instead, whatever the rules say, in
    the input view that shows most of it (none when no input view shows it)."""
    from aes_planner.sim import render

    counts, boxes = {}, {}
    hw = intrinsics.width * intrinsics.height
    for v, pose in enumerate(inputs):
        ids = render(scene, pose, intrinsics, supersample=1).instance_id  # [H, W]
        for i in np.unique(ids):
            if i <= 0 or scene.objects[i - 1].type == "plane":
                continue
            ys, xs = np.nonzero(ids == i)
            if len(xs) > counts.get(i, (0, 0))[0]:
                counts[i] = (len(xs), v)
                boxes[i] = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1)
    if name is not None:
        named = [i for i in counts if scene.objects[i - 1].name == name]
        if not named:
            return None
        i = max(named, key=lambda j: counts[j][0])
        x0, y0, x1, y1 = boxes[i]
        return i - 1, counts[i][1], Region(f"view{counts[i][1]}", float(x0), float(y0), float(x1), float(y1))
    eligible = []
    for i, (n, v) in counts.items():
        x0, y0, x1, y1 = boxes[i]
        border = x0 == 0 or y0 == 0 or x1 == intrinsics.width or y1 == intrinsics.height
        if cfg.min_frac * hw <= n <= cfg.max_frac * hw and not border:
            shown = n / max(_silhouette_px(object_points(scene.objects[i - 1]), inputs[v], intrinsics), 1.0)
            if shown >= cfg.min_shown:  # the view shows the object, not a corner of it behind another one
                eligible.append((n, i, v))
    if not eligible:
        return None
    eligible.sort(reverse=True)
    if seed >= len(eligible):
        return None
    n, i, v = eligible[seed]
    x0, y0, x1, y1 = boxes[i]
    return i - 1, v, Region(f"view{v}", float(x0), float(y0), float(x1), float(y1))


# ------------------------------------------------------------------------------ the constrained oracle
def constrained_oracle(space, judge: Judge, points: np.ndarray, intrinsics, cfg: FramingEvalConfig) -> dict | None:
    """Best teacher / evaluator scores over the views that hold ``points`` whole, and their means."""
    grid, step, steps = space.exhaustive_grid(cfg.oracle_step_deg, cfg.oracle_free_step_deg, cfg.oracle_free_positions)
    poses = space.to_poses(grid).detach().numpy()
    ok = true_holds(points, poses, intrinsics)
    if not ok.any():
        return None
    grid, poses = grid[torch.as_tensor(ok)], poses[ok]
    teacher, evaluator = judge.measure(poses)
    mean_t, mean_e = float(teacher.mean()), float(evaluator.mean())
    best = {
        "teacher": float(teacher.max()),
        "evaluator": float(evaluator.max()),
        "pose": poses[int(np.argmax(teacher))],
    }
    min_scale = math.radians(cfg.oracle_min_step_deg) / step * 2

    def holds(cam2world: torch.Tensor) -> np.ndarray:  # [M, 4, 4] -> [M] bool
        return true_holds(points, cam2world.numpy(), intrinsics)

    for key, scores in (("teacher", teacher), ("evaluator", evaluator)):  # from the best of each, inside the set
        i = int(np.argmax(scores))
        pattern_search(_Measured(judge, key, best), space, grid[i], float(scores[i]), steps, min_scale, holds)
    best_t, best_e, best_pose = best["teacher"], best["evaluator"], best["pose"]
    return {"best_teacher": best_t, "best_evaluator": best_e, "mean_teacher": mean_t, "mean_evaluator": mean_e,
            "holding_views": int(ok.sum()), "grid_views": int(len(ok)), "best_cam2world": best_pose.tolist(),
            **_judges_agree(np.asarray(teacher, float), np.asarray(evaluator, float), mean_e, best_e)}  # fmt: skip


def _judges_agree(teacher: np.ndarray, evaluator: np.ndarray, mean_e: float, best_e: float) -> dict[str, float]:
    """Whether the teacher and the independent evaluator agree on the grid's views that hold the
    subject (``teacher``, ``evaluator``: ``[G]``): ``judges_rank_corr``, their Spearman correlation,
    and ``evaluator_at_teacher_best``, the evaluator's normalised score of the teacher's best grid
    view (1: the evaluator's best too; 0: an average view to the evaluator)."""
    i = int(np.argmax(teacher))
    out = {"evaluator_at_teacher_best": _norm(float(evaluator[i]), mean_e, best_e), "judges_rank_corr": 0.0}
    if len(teacher) >= 3 and np.std(teacher) > 0 and np.std(evaluator) > 0:
        rt, re = np.argsort(np.argsort(teacher)), np.argsort(np.argsort(evaluator))
        out["judges_rank_corr"] = float(np.corrcoef(rt, re)[0, 1])
    return out


class _Measured(Scorer):
    """Ground-truth renders scored by the teacher or the evaluator (``key``) for the compass
    search; the best teacher and evaluator scores seen (and the teacher's pose) go into ``best``."""

    name = "ground_truth"

    def __init__(self, judge: Judge, key: str, best: dict):
        self.judge, self.key, self.best = judge, key, best
        self.intrinsics = judge.gt.intrinsics

    def score(self, cam2world: torch.Tensor) -> ScoreOutput:  # [B, 4, 4] -> ScoreOutput [B]
        poses = cam2world.detach().numpy()
        t, e = self.judge.measure(poses)
        if float(t.max()) > self.best["teacher"]:
            self.best["teacher"], self.best["pose"] = float(t.max()), poses[int(np.argmax(t))]
        self.best["evaluator"] = max(self.best["evaluator"], float(e.max()))
        score = torch.as_tensor(t if self.key == "teacher" else e)
        return ScoreOutput(score, torch.ones_like(score), {"score": score})


def _norm(score: float, mean: float, best: float) -> float:
    return float((score - mean) / (best - mean)) if best - mean > 1e-9 else 0.0


# ------------------------------------------------------------------------------ the run
def _outline(image: np.ndarray, points: np.ndarray, pose: np.ndarray, intrinsics, colour) -> np.ndarray:
    """``image`` with the convex hull of ``points`` projected at ``pose`` drawn on it."""
    import cv2

    out = np.ascontiguousarray(image).copy()
    pc = (points - pose[:3, 3]) @ pose[:3, :3]
    front = pc[:, 2] > 1e-3
    if front.sum() >= 3:
        uv = np.stack([intrinsics.fx * pc[front, 0] / pc[front, 2] + intrinsics.cx,
                       intrinsics.fy * pc[front, 1] / pc[front, 2] + intrinsics.cy], -1)  # fmt: skip
        hull = cv2.convexHull(np.clip(uv, -1e4, 1e4).astype(np.float32)).round().astype(np.int32)
        cv2.polylines(out, [hull], True, colour, 1, cv2.LINE_AA)
    return out


def write_figure(path, rows: list[dict], sources: dict, cfg: FramingEvalConfig) -> None:
    """One row per searched case: the input view with the subject's box, the suggestion and the
    constrained oracle's view (ground-truth renders, the true outline drawn), with their scores."""
    import cv2

    from aes_planner.images import write_image

    tiles = []
    for r in rows:
        if "holds" not in r:
            continue
        source, inputs, k = sources[r["scene"]]
        points = object_points(source.scene.objects[r["object"]])
        views = [inputs[r["view"]], np.asarray(r["cam2world"]), np.asarray(r["best_cam2world"])]
        imgs = (source.render_rgb(np.stack(views), k) * 255).round().astype(np.uint8)
        x0, y0, x1, y1 = (int(round(v)) for v in r["box"])
        first = imgs[0].copy()
        cv2.rectangle(first, (x0, y0), (x1 - 1, y1 - 1), (40, 200, 60), 1)
        second = _outline(imgs[1], points, views[1], k, (40, 200, 60) if r["holds"] else (220, 40, 40))
        third = _outline(imgs[2], points, views[2], k, (40, 200, 60))
        labels = [
            f"{r['scene']} {r['subject']}"[:28],
            f"suggest t{r['teacher']:.2f} ({r['normalized_teacher']:.2f})",
            f"oracle t{r['best_teacher']:.2f}",
        ]
        row = []
        for img, label in zip((first, second, third), labels):
            big = cv2.resize(img, (img.shape[1] * 2, img.shape[0] * 2), interpolation=cv2.INTER_NEAREST)
            tile = np.full((big.shape[0] + 16, big.shape[1] + 4, 3), 255, np.uint8)
            tile[16:, 2:-2] = big
            cv2.putText(tile, label, (2, 12), cv2.FONT_HERSHEY_PLAIN, 0.9, (0, 0, 0), 1, cv2.LINE_AA)
            row.append(tile)
        tiles.append(np.hstack(row))
    if tiles:
        width = max(t.shape[1] for t in tiles)
        sheet = np.vstack([np.pad(t, ((0, 0), (0, width - t.shape[1]), (0, 0)), constant_values=255) for t in tiles])
        write_image(path, cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), "the framing figure")


def run_framing_eval(cfg: FramingEvalConfig, progress=None, figure: str | None = None) -> dict[str, Any]:
    teacher = get_teacher()
    evaluator = CompositionEvaluator()
    rows = []
    sources = {}
    for spec in cfg.scenes:
        source = _source(spec, cfg)
        platform = _mode_platform(source, cfg.mode, cfg.free_box_m)
        if cfg.mode == "rig" and source.platform.rig is None:
            raise FramingEvalError(f"{spec}: a drone scene has no rig; run it with --mode drone")
        inputs = _inputs(source, platform, cfg.views)
        frames = [source.capture(p) for p in inputs]
        k = platform.intrinsics
        sources[spec] = (source, inputs, k)
        judge = Judge(source, teacher, evaluator)
        scfg = SearchConfig.preset(cfg.preset, mode=platform.kind)
        space = space_for(platform, scfg)
        scorer = None
        picks = list(enumerate(cfg.subjects)) if cfg.subjects else [(seed, None) for seed in cfg.seeds]
        for seed, name in picks:
            picked = pick_subject(source.scene, inputs, frames[0].intrinsics, seed, cfg, name)
            if progress:
                progress(f"{spec} seed {seed}" if name is None else f"{spec} subject {name}")
            if picked is None:
                if name is None:
                    log.warning("%s: no object fits the subject rules; skipped", spec)
                else:
                    log.warning("%s: no input view shows an object named %r; skipped", spec, name)
                continue
            obj_i, view, region = picked
            obj = source.scene.objects[obj_i]
            points = object_points(obj)
            row: dict[str, Any] = {"scene": spec, "seed": seed, "subject": obj.name or f"object {obj_i + 1}",
                                   "view": view, "box": [region.x0, region.y0, region.x1, region.y1], "object": obj_i}  # fmt: skip
            row["shown"] = _shown(source.scene, obj_i, inputs[view], k)
            if name is not None and row["shown"] < cfg.min_shown:
                log.warning("%s: view %d shows %.0f%% of %r; the rest is unknown to the lift",
                            spec, view, 100 * row["shown"], name)  # fmt: skip
            oracle = constrained_oracle(space, judge, points, k, cfg)
            if oracle is None:
                row["error"] = "no grid view holds the subject"
                rows.append(row)
                continue
            row.update(oracle)
            if scorer is None:
                scorer = build_search_scorer("field", frames, scfg)
            named = {f"view{i}": (f.cam2world, f.intrinsics, (f.intrinsics.width, f.intrinsics.height))
                     for i, f in enumerate(frames)}  # fmt: skip
            t0 = time.perf_counter()
            try:
                framing = build_framing(scorer, named, [region], [], k, cfg.framing(), frames)
                result = search_views(scorer, inputs, platform, scfg, framing=framing)
            except FramingError as exc:
                row["error"] = str(exc)
                rows.append(row)
                continue
            row["latency_ms"] = (time.perf_counter() - t0) * 1e3
            pose = result.best.cam2world
            row["cam2world"] = pose.tolist()
            row["holds"] = bool(true_holds(points, pose[None], k)[0])
            row["held_predicted"] = result.best.held
            row["covered_fraction"] = result.covered_fraction  # of the views that hold the subject, the share seen
            row["verify_ms"] = result.timings_ms.get("verify", 0.0)
            t, e = judge.measure(pose[None])
            row["teacher"], row["evaluator"] = float(t[0]), float(e[0])
            row["normalized_teacher"] = _norm(row["teacher"], oracle["mean_teacher"], oracle["best_teacher"])
            row["normalized_evaluator"] = _norm(row["evaluator"], oracle["mean_evaluator"], oracle["best_evaluator"])
            row["subject_box_m"] = framing.keep[0].to_json()
            row.update(_stage1_pool(result, judge, points, k, oracle))
            rows.append(row)
            log.info("%s", {k2: v for k2, v in row.items() if k2 != "subject_box_m"})
    if figure:
        write_figure(figure, rows, sources, cfg)
    return {"config": dataclasses.asdict(cfg), "rows": rows, "summary": summarize(rows)}


#: how many of stage 1's best candidates (by the field) the loss breakdown scores on ground truth
POOL_TOP = 16


def _stage1_pool(result, judge: Judge, points: np.ndarray, intrinsics, oracle: dict) -> dict[str, Any]:
    """Where the framed suggestion loses: the field's ``POOL_TOP`` best stage-1 candidates that hold
    the subject by the true geometry, scored by the teacher on ground-truth renders. ``pool_best``:
    the best of them (normalised like the suggestion), ``pool_pick``: the field's first of them,
    ``pool_rank_corr``: Spearman correlation of the field's and the teacher's scores over them."""
    poses = np.asarray(result.candidates_cam2world)  # [C, 4, 4]
    field = np.asarray(result.candidates_score, float)  # [C]
    ok = np.flatnonzero(true_holds(points, poses, intrinsics) & np.isfinite(field))
    top = ok[np.argsort(-field[ok], kind="stable")][:POOL_TOP]
    if len(top) < 2:
        return {}
    t, _ = judge.measure(poses[top])
    t = np.asarray(t, float)  # [N], in the field's order
    rank_f = np.argsort(np.argsort(-field[top]))
    rank_t = np.argsort(np.argsort(-t))
    corr = float(np.corrcoef(rank_f, rank_t)[0, 1]) if np.std(rank_t) > 0 else 0.0
    mean, best = oracle["mean_teacher"], oracle["best_teacher"]
    return {"pool_n": len(top), "pool_best": _norm(float(t.max()), mean, best),
            "pool_pick": _norm(float(t[0]), mean, best), "pool_rank_corr": corr}  # fmt: skip


def summarize(rows: list[dict]) -> dict[str, Any]:
    done = [r for r in rows if "holds" in r]
    out: dict[str, Any] = {"cases": len(rows), "searched": len(done)}
    if not done:
        return out
    out["hold_rate"] = float(np.mean([r["holds"] for r in done]))
    for name in ("normalized_evaluator", "normalized_teacher"):
        vals = np.array([r[name] for r in done])
        out[f"{name}_median"] = float(np.median(vals))
        out[f"{name}_mean"] = float(vals.mean())
        out[f"{name}_min"] = float(vals.min())
        out[f"{name}_at_least_0.85"] = float(np.mean(vals >= 0.85))
    out["latency_ms_median"] = float(np.median([r["latency_ms"] for r in done]))
    out["verify_ms_median"] = float(np.median([r.get("verify_ms", 0.0) for r in done]))
    loss = ("pool_best", "pool_pick", "pool_rank_corr")  # the loss breakdown (_stage1_pool)
    judges = ("evaluator_at_teacher_best", "judges_rank_corr")  # do the two judges agree (_judges_agree)
    for name in loss + judges:
        vals = [r[name] for r in done if name in r]
        if vals:
            out[f"{name}_median"] = float(np.median(vals))
    return out


def markdown(doc: dict[str, Any]) -> str:
    lines = [
        "| scene | seed | subject | holds | evaluator (norm.) | teacher (norm.) | holding views |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in doc["rows"]:
        if "holds" not in r:
            lines.append(f"| {r['scene']} | {r['seed']} | {r['subject']} | - | {r.get('error', '')[:60]} | | |")
            continue
        lines.append(
            f"| {r['scene']} | {r['seed']} | {r['subject']} | {'yes' if r['holds'] else 'NO'} | "
            f"{r['evaluator']:.3f} ({r['normalized_evaluator']:.2f}) | {r['teacher']:.3f} ({r['normalized_teacher']:.2f}) "
            f"| {r['holding_views']}/{r['grid_views']} |"
        )
    s = doc["summary"]
    if "hold_rate" in s:
        lines.append("")
        lines.append(
            f"held whole in {s['hold_rate']:.0%} of {s['searched']} cases; normalised score (evaluator) median "
            f"{s['normalized_evaluator_median']:.2f}, min {s['normalized_evaluator_min']:.2f}; (teacher) median "
            f"{s['normalized_teacher_median']:.2f}; median latency {s['latency_ms_median']:.0f} ms"
        )
    if "judges_rank_corr_median" in s:
        lines.append(
            f"teacher and evaluator over the views that hold the subject: Spearman {s['judges_rank_corr_median']:.2f} "
            f"(median); the teacher's best grid view scores {s['evaluator_at_teacher_best_median']:.2f} on the evaluator"
        )
    return "\n".join(lines)
