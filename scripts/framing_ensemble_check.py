"""Do differently built fields disagree on the framed search's feasible pool? (docs/results/framing_ensemble_dev.md)

For each case of stored ``eval framing --json`` runs, the framed search runs once with the shipped
field; its feasible stage-1 candidates scored by the field itself (not a screen) are ranked by the
search's objective and the best ``POOL`` kept. Every member field (built from the same four input
frames with a different build) then scores that pool; the teacher on ground-truth renders gives the
truth, normalised with the stored constrained oracle. One JSON line per case (arrays per member),
analysed by ``scripts/framing_ensemble_report.py``.

    .venv/bin/python scripts/framing_ensemble_check.py OUT.jsonl RUN.json [RUN.json ...] [--members=builds|cells|none]
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
import time

import numpy as np
import torch

from aes_planner.eval.framing import FramingEvalConfig, object_points, pick_subject, true_holds
from aes_planner.eval.search import Judge, _inputs, _mode_platform, _source
from aes_planner.field import build_scorer
from aes_planner.field.model import NOCOND_CHECKPOINT
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.search.framing import FramingError, build_framing
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator

POOL = 32
log = logging.getLogger("framing_ensemble_check")


def _turned(frames: list, deg: float, seed: int) -> list:
    """The frames with their poses turned by ``deg`` about a random axis each (a pose error a
    rig's encoders have anyway): a differently built reconstruction of the same photos."""
    rng = np.random.default_rng(seed)
    out = []
    for f in frames:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        a = np.deg2rad(deg)
        kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        rot = np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx
        c2w = np.array(f.cam2world, dtype=np.float64)
        c2w[:3, :3] = c2w[:3, :3] @ rot
        out.append(dataclasses.replace(f, cam2world=c2w))
    return out


def members(frames: list, scfg: SearchConfig, which: str = "builds") -> dict:
    """name -> scorer: the shipped build and the variants (``which``: "builds", or "cells" for the
    field whose unseen cells hold the inputs' maps, ``ScorerConfig.unseen_cells``)."""
    base = {"render_width_px": scfg.render_width_px}
    if scfg.max_gaussians is not None:
        base["max_gaussians"] = scfg.max_gaussians
    if which == "none":
        return {}
    if which == "cells":
        return {"cells_inputs": build_scorer("field", frames, **base, unseen_cells="inputs")}
    out = {
        "base_again": build_scorer("field", frames, **base),
        "stereo3": build_scorer("field", frames, **base, reconstruct={"stereo_neighbours": 3}),
        "merge2": build_scorer("field", frames, **base, reconstruct={"merge_cell_factor": 2.0}),
        "scale055": build_scorer("field", frames, **base, reconstruct={"scale_factor": 0.55}),
        "scale075": build_scorer("field", frames, **base, reconstruct={"scale_factor": 0.75}),
        "render40": build_scorer("field", frames, **{**base, "render_width_px": 40}),
        "render56": build_scorer("field", frames, **{**base, "render_width_px": 56}),
        "nocond": build_scorer("field", frames, **base, model=NOCOND_CHECKPOINT),
    }
    for s in (1, 2, 3):
        out[f"turn0.3_{s}"] = build_scorer("field", _turned(frames, 0.3, s), **base)
    return out


def run(paths: list[str], out: str, which: str = "builds") -> None:
    teacher, evaluator = get_teacher(), CompositionEvaluator()
    with open(out, "w") as fh:
        for path in paths:
            doc = json.load(open(path))
            conf = doc["config"]
            cfg = FramingEvalConfig(scenes=conf["scenes"], seeds=conf["seeds"] or [0])
            by_scene: dict[str, list] = {}
            for r in doc["rows"]:
                if "mean_teacher" in r:
                    by_scene.setdefault(r["scene"], []).append(r)
            for spec, rows in by_scene.items():
                source = _source(spec, cfg)
                platform = _mode_platform(source, cfg.mode, cfg.free_box_m)
                inputs = _inputs(source, platform, cfg.views)
                frames = [source.capture(p) for p in inputs]
                k = platform.intrinsics
                judge = Judge(source, teacher, evaluator)
                scfg = SearchConfig.preset(cfg.preset, mode=platform.kind)
                scorer = build_search_scorer("field", frames, scfg)
                inputs_np = np.stack([np.asarray(p, dtype=np.float64) for p in inputs])  # [V, 4, 4]
                inputs_t = judge.measure(inputs_np)[0]  # the teacher on the input photos (ground-truth renders)
                with torch.no_grad():
                    inputs_f = scorer.score(torch.as_tensor(inputs_np)).score.double().numpy()
                t0 = time.process_time()
                mem = members(frames, scfg, which)
                build_cpu = (time.process_time() - t0) / max(len(mem), 1)
                named = {f"view{i}": (f.cam2world, f.intrinsics, (f.intrinsics.width, f.intrinsics.height))
                         for i, f in enumerate(frames)}  # fmt: skip
                for r in rows:
                    name = r["subject"] if conf["subjects"] else None
                    obj_i, view, region = pick_subject(source.scene, inputs, frames[0].intrinsics, r["seed"], cfg, name)
                    points = object_points(source.scene.objects[obj_i])
                    row = {"scene": spec, "seed": r["seed"], "subject": r["subject"], "photo": "loop_dev/" in spec,
                           "mean_teacher": r["mean_teacher"], "best_teacher": r["best_teacher"],
                           "build_cpu_s": build_cpu}  # fmt: skip
                    try:
                        fcfg = cfg.framing()
                        framing = build_framing(scorer, named, [region], [], k, fcfg, frames)
                        result = search_views(scorer, inputs, platform, scfg, framing=framing)
                    except FramingError as exc:
                        row["error"] = str(exc)[:200]
                        print(json.dumps(row), file=fh, flush=True)
                        continue
                    fc = framing.cfg
                    exact = np.asarray(result.candidates_exact, bool)
                    poses = result.candidates_cam2world[exact]
                    field = np.nan_to_num(result.candidates_score[exact], nan=-1e9)
                    cov = result.candidates_coverage[exact]
                    obj = field - fc.coverage_penalty * np.clip(fc.coverage_min - cov, 0, None)
                    top = np.argsort(-obj, kind="stable")[:POOL]
                    pool = poses[top]
                    t, _ = judge.measure(pool)
                    pick = result.best.cam2world
                    row["pick_in_pool"] = int(np.argmin(np.abs(pool - pick[None]).reshape(len(pool), -1).sum(1)))
                    row["pick_dist"] = float(np.abs(pool[row["pick_in_pool"]] - pick).sum())
                    tp, _ = judge.measure(pick[None])
                    row["pick_teacher"] = float(tp[0])
                    row["pick_holds"] = bool(true_holds(points, pick[None], k)[0])
                    row["holds"] = true_holds(points, pool, k).astype(bool).tolist()
                    row["teacher"] = t.tolist()
                    row["coverage_min"], row["coverage_penalty"] = fc.coverage_min, fc.coverage_penalty
                    row["base"] = {"score": field[top].tolist(), "cov": cov[top].tolist()}
                    row["pool_cam2world"] = pool.round(6).tolist()
                    row["inputs_cam2world"] = inputs_np.round(6).tolist()
                    row["inputs_teacher"], row["inputs_field"] = inputs_t.tolist(), inputs_f.tolist()
                    with torch.no_grad():
                        for mname, m in mem.items():
                            o = m.score(torch.as_tensor(pool))
                            row[mname] = {"score": np.nan_to_num(o.score.double().numpy(), nan=-1e9).tolist(),
                                          "cov": o.coverage.double().numpy().tolist()}  # fmt: skip
                    print(json.dumps(row), file=fh, flush=True)
                    log.info("%s %s %s done", spec, r["seed"], r["subject"])


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO)
    args = [a for a in sys.argv[2:] if not a.startswith("--members=")]
    which = next((a.split("=", 1)[1] for a in sys.argv[2:] if a.startswith("--members=")), "builds")
    run(args, sys.argv[1], which)
