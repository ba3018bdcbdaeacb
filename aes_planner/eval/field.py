"""Novel-view aesthetic prediction (the paper's Table 1 and its view-conditioning ablation).

For each scene and each number of input views: input frames from the protocol of
:mod:`aes_planner.field.protocol` (``rig``: an RGB pan sweep, sphere mode; ``free``: a
translating trajectory with depth), 100 held-out target poses along a trajectory, the teacher's
scores of ground-truth renders there, and each method's predicted scores:

* ``rgb``: RGB rendered from the reconstruction, scored by the teacher;
* ``splat``: each Gaussian carries its input view's teacher features (no learning);
* ``field_nocond``: the field trained without view conditioning;
* ``field``: the field.

Per scene PLCC, SRCC, the smoothness ratio (total variation of the predicted scores along the
trajectory over that of the truth) and the mean coverage; then averaged over scenes. Scenes are
the simulator's families at evaluation seeds (``EVAL_SEED_START`` on, never used in training)
unless given. The scene sources come from the caller (the CLI uses the simulator).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from aes_planner.config import distinct, require
from aes_planner.field.common import ScorerConfig
from aes_planner.field.model import AestheticField, FieldInputs, FieldModel
from aes_planner.field.protocol import SOURCES, plan_views
from aes_planner.field.rgb import RGBScorer
from aes_planner.field.splat import SplatScorer
from aes_planner.field.train import EVAL_SEED_START, FAMILIES
from aes_planner.metrics import plcc, srcc, tv_ratio
from aes_planner.paths import output_in
from aes_planner.reconstruct import Reconstruction
from aes_planner.sources import SceneSource
from aes_planner.teachers import Teacher

__all__ = ["METHODS", "FieldEvalConfig", "default_scenes", "evaluate_field", "write_report"]

log = logging.getLogger(__name__)

METHODS = ("rgb", "splat", "field_nocond", "field")


@dataclass
class FieldEvalConfig:
    """``source``: ``rig`` or ``free``; ``views``: input view counts; ``targets``: held-out
    poses per trajectory; ``seed``: the pose plans; ``scorer``: render width and budget."""

    source: str = "rig"
    views: list[int] = field(default_factory=lambda: [2, 4, 6])
    targets: int = 100
    seed: int = 0
    scorer: ScorerConfig = field(default_factory=ScorerConfig)

    def __post_init__(self):
        self.views = distinct(self.views, "views")
        require(self.source in SOURCES, "source", f"must be one of {list(SOURCES)}, got {self.source!r}")
        require(
            len(self.views) >= 1 and all(isinstance(v, int) and 1 <= v <= 16 for v in self.views),
            "views",
            f"each view count must be an integer in [1, 16], got {self.views}",
        )
        require(3 <= self.targets <= 10000, "targets", f"must be in [3, 10000] poses, got {self.targets}")


def default_scenes(n: int) -> list[str]:
    """``n`` evaluation scenes: the families round-robin at evaluation seeds."""
    return [f"{FAMILIES[i % len(FAMILIES)]}:{EVAL_SEED_START + i // len(FAMILIES)}" for i in range(n)]


def _scorers(
    inputs: FieldInputs, teacher: Teacher, models: dict[str, FieldModel], cfg: ScorerConfig
) -> dict[str, object]:
    rec = Reconstruction(inputs.splats.to_gaussians(), inputs.local_frame, inputs.modes, {}, inputs.splats)
    out = {"rgb": RGBScorer(rec, teacher, inputs.intrinsics, cfg), "splat": SplatScorer(inputs, teacher, cfg)}
    for name, model in models.items():
        out[name] = AestheticField.from_inputs(inputs, model, teacher, cfg)
    return out


def evaluate_scene(
    source: SceneSource, teacher: Teacher, models: dict[str, FieldModel], config: FieldEvalConfig, scene_index: int
) -> dict[str, dict]:
    """``{views: {"truth": [T], method: {"scores": [T], "coverage": [T]}}}`` for one scene."""
    out = {}
    for views in config.views:
        rng = np.random.default_rng([config.seed, scene_index, views])
        plan = plan_views(source.platform, config.source, views, config.targets, rng)
        frames = [source.capture(p, depth=plan.depth) for p in plan.inputs]
        inputs = FieldInputs.from_frames(frames, teacher, config.scorer.reconstruct_config())
        gt = torch.from_numpy(source.render_rgb(plan.targets)).permute(0, 3, 1, 2)
        with torch.no_grad():
            truth = teacher.score(gt).numpy()
        poses = torch.from_numpy(plan.targets)
        res = {"truth": truth}
        for name, scorer in _scorers(inputs, teacher, models, config.scorer).items():
            s = scorer.score_batched(poses, 50)
            res[name] = {"scores": s.score.numpy(), "coverage": s.coverage.numpy()}
        out[views] = res
    return out


def evaluate_field(
    scenes: list[str],
    make_source: Callable[[str], SceneSource],
    teacher: Teacher,
    models: dict[str, FieldModel],
    config: FieldEvalConfig,
    progress: Callable[[Iterable], Iterable] = lambda it: it,
) -> tuple[dict, list[dict]]:
    """The summary JSON (the shape `eval field` has always written) and the raw per-scene results (for plots)."""
    raw = []
    for i, name in enumerate(progress(scenes)):
        raw.append(evaluate_scene(make_source(name), teacher, models, config, i))
    methods = [m for m in METHODS if m in ("rgb", "splat") or m in models]
    summary = {"source": config.source, "teacher": teacher.name, "scenes": list(scenes), "views": {}}
    for views in config.views:
        per_method = {}
        for m in methods:
            rows = [
                (
                    plcc(r[views][m]["scores"], r[views]["truth"]),
                    srcc(r[views][m]["scores"], r[views]["truth"]),
                    tv_ratio(r[views][m]["scores"], r[views]["truth"]),
                    float(np.mean(r[views][m]["coverage"])),
                )
                for r in raw
            ]
            a = np.array(rows)
            per_method[m] = {
                "plcc": float(a[:, 0].mean()),
                "srcc": float(a[:, 1].mean()),
                "tv_ratio": float(np.median(a[:, 2])),
                "coverage": float(a[:, 3].mean()),
                "plcc_per_scene": [round(float(v), 4) for v in a[:, 0]],
            }
        summary["views"][str(views)] = per_method
    return summary, raw


# ---------------------------------------------------------------------------------- report
_COLOURS = {  # BGR
    "truth": (0, 0, 0),
    "rgb": (40, 40, 220),
    "splat": (40, 160, 40),
    "field_nocond": (200, 140, 40),
    "field": (200, 40, 160),
}


def _plot(raw_scene: dict, views: int, title: str, path: Path) -> None:
    """Fig. 4(a)-like: predicted and ground-truth scores over consecutive poses (OpenCV drawing)."""
    import cv2

    w, h, m = 900, 420, 50
    img = np.full((h, w, 3), 255, np.uint8)
    series = {"truth": raw_scene[views]["truth"]}
    series.update({k: v["scores"] for k, v in raw_scene[views].items() if k != "truth"})
    lo = min(float(np.min(s)) for s in series.values())
    hi = max(float(np.max(s)) for s in series.values())
    lo, hi = lo - 0.02, hi + 0.02
    cv2.rectangle(img, (m, m // 2), (w - m // 2, h - m), (180, 180, 180), 1)
    for frac in (0.0, 0.5, 1.0):
        y = int(h - m - frac * (h - 1.5 * m))
        cv2.putText(img, f"{lo + frac * (hi - lo):.2f}", (2, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    for i, (name, s) in enumerate(series.items()):
        s = np.asarray(s, np.float64)
        xs = m + np.arange(len(s)) * (w - 1.5 * m) / max(1, len(s) - 1)
        ys = h - m - (s - lo) / (hi - lo) * (h - 1.5 * m)
        pts = np.stack([xs, ys], 1).round().astype(np.int32)
        cv2.polylines(img, [pts], False, _COLOURS.get(name, (100, 100, 100)), 2 if name == "truth" else 1, cv2.LINE_AA)
        cv2.putText(img, name, (m + 10 + 150 * i, h - 15), cv2.FONT_HERSHEY_SIMPLEX, 0.5, _COLOURS.get(name, 0), 1)
    cv2.putText(img, title, (m, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
    cv2.imwrite(str(path), img)


def write_report(summary: dict, raw: list[dict], out_dir: Path, json_path: Path | None = None) -> list[Path]:
    """Markdown table, JSON and one plot per view count (first scene) into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    src = summary["source"]
    lines = [
        f"# Novel-view aesthetic prediction ({src} inputs, teacher `{summary['teacher']}`)",
        "",
        f"Scenes: {', '.join(summary['scenes'])}. PLCC/SRCC per scene then averaged; tv = median total-variation "
        "ratio (predicted / ground truth, 1 = as smooth as the truth); cov = mean coverage.",
        "",
        "| views | method | PLCC | SRCC | tv | cov |",
        "|---|---|---|---|---|---|",
    ]
    for views, methods in summary["views"].items():
        for m, r in methods.items():
            lines.append(
                f"| {views} | {m} | {r['plcc']:.3f} | {r['srcc']:.3f} | {r['tv_ratio']:.2f} | {r['coverage']:.2f} |"
            )
    paths = [output_in(out_dir, f"field_eval_{src}.md")]
    paths[0].write_text("\n".join(lines) + "\n")
    if raw:
        for views in raw[0]:
            p = output_in(out_dir, f"field_eval_{src}_{views}v.png")
            _plot(raw[0], views, f"{summary['scenes'][0]}, {src}, {views} input views", p)
            paths.append(p)
    jp = json_path or output_in(out_dir, f"field_eval_{src}.json")
    jp.parent.mkdir(parents=True, exist_ok=True)
    jp.write_text(json.dumps(summary, indent=1))
    paths.append(jp)
    return paths
