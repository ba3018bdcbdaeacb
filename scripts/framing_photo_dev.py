"""Re-run the framed suggestion of ``eval framing`` cases against their stored constrained oracle.

``eval framing`` spends most of its time on the constrained oracle (the exhaustive grid scored on
ground-truth renders), which depends on the scene and the subject only, not on the search. To
compare changes to the lift or the ranking, this script re-runs only the lift and the search for
the cases of an ``eval framing --json`` file and normalises the new suggestion's teacher score
with that file's oracle (``mean_teacher``, ``best_teacher``). A case whose lift is refused
(``FramingError``) is reported as such.

    .venv/bin/python scripts/framing_photo_dev.py OUT.jsonl RUN.json [RUN.json ...] [key=value ...]
    # key=value: FramingConfig overrides (e.g. open_reach=1.0)
    # one JSON line per case; a summary line at the end (prefixed SUMMARY)
"""

from __future__ import annotations

import ast
import dataclasses
import json
import sys

import numpy as np

from aes_planner.eval.framing import FramingEvalConfig, _norm, object_points, pick_subject, true_holds
from aes_planner.eval.search import Judge, _inputs, _mode_platform, _source
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.search.framing import FramingError, build_framing
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator


def run(paths: list[str], out: str, overrides: dict | None = None) -> None:
    teacher, evaluator = get_teacher(), CompositionEvaluator()
    results = []
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
                named = {f"view{i}": (f.cam2world, f.intrinsics, (f.intrinsics.width, f.intrinsics.height))
                         for i, f in enumerate(frames)}  # fmt: skip
                for r in rows:
                    name = r["subject"] if conf["subjects"] else None
                    picked = pick_subject(source.scene, inputs, frames[0].intrinsics, r["seed"], cfg, name)
                    obj_i, view, region = picked
                    points = object_points(source.scene.objects[obj_i])
                    row = {"scene": spec, "seed": r["seed"], "subject": r["subject"], "box": r["box"],
                           "shown": r.get("shown"), "before_holds": r.get("holds"),
                           "before": r.get("normalized_teacher")}  # fmt: skip
                    try:
                        fcfg = dataclasses.replace(cfg.framing(), **(overrides or {}))
                        framing = build_framing(scorer, named, [region], [], k, fcfg, frames)
                        result = search_views(scorer, inputs, platform, scfg, framing=framing)
                    except FramingError as exc:
                        row["error"] = str(exc)[:300]
                        print(json.dumps(row), file=fh, flush=True)
                        results.append(row)
                        continue
                    pose = result.best.cam2world
                    row["holds"] = bool(true_holds(points, pose[None], k)[0])
                    t, _ = judge.measure(pose[None])
                    row["teacher"] = float(t[0])
                    row["normalized_teacher"] = _norm(float(t[0]), r["mean_teacher"], r["best_teacher"])
                    row["warnings"] = list(getattr(result, "warnings", []) or [])
                    row["subject_size_m"] = framing.keep[0].size_m.tolist()
                    print(json.dumps(row), file=fh, flush=True)
                    results.append(row)
    done = [r for r in results if "holds" in r]
    nt = np.array([r["normalized_teacher"] for r in done]) if done else np.zeros(0)
    summary = {"cases": len(results), "searched": len(done), "held": int(sum(r["holds"] for r in done)),
               "refused": len(results) - len(done),
               "median": float(np.median(nt)) if len(nt) else None, "mean": float(nt.mean()) if len(nt) else None,
               "at_least_0.85": int((nt >= 0.85).sum())}  # fmt: skip
    print("SUMMARY", json.dumps(summary))


if __name__ == "__main__":
    args = [a for a in sys.argv[2:] if "=" not in a]
    over = {a.split("=", 1)[0]: ast.literal_eval(a.split("=", 1)[1]) for a in sys.argv[2:] if "=" in a}
    run(args, sys.argv[1], over)
