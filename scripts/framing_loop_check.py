"""The active loop with a keep region: does the view it ends on hold the subject, and how good is it?

For every scene x seed, the simulated closed loop (``aes-planner demo``'s rig loop, sim clock) runs;
right after its first capture a keep region is set on the planner (the ``PlannerRequest`` a GUI
sends): the box of the ``seed``-th object ``eval framing``'s rules pick in that first view
(:func:`aes_planner.eval.framing.pick_subject`, largest first). The final view is measured as
``eval framing`` measures a suggestion: ``holds`` by the object's true geometry, the teacher's score
of its ground-truth render normalised to the constrained oracle (0 = the mean view that holds the
subject, 1 = the best one).

``--today`` runs the loop as it was before the loop respected the framing (the searches apply the
keep region, the loop's picks do not): a paired comparison on the same cases.

usage: .venv/bin/python scripts/framing_loop_check.py --scene tabletop:3 --seed 0 --out /tmp/fl [--today]
Rows go to OUT/rows.jsonl (a case already there is not run again); the constrained oracles are cached in
OUT/oracles.json.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

log = logging.getLogger("framing_loop_check")


def run_case(spec: str, seed: int, out: Path, today: bool, moves: int) -> dict:
    from aes_planner.cli.demo import run_demo
    from aes_planner.eval.framing import (
        FramingEvalConfig,
        _norm,
        constrained_oracle,
        object_points,
        pick_subject,
        true_holds,
    )
    from aes_planner.eval.search import Judge, _mode_platform, _source
    from aes_planner.field.model import clear_feature_cache
    from aes_planner.messages import PlannerRequest
    from aes_planner.messages.diagnostics import FramingRegion
    from aes_planner.search import SearchConfig
    from aes_planner.search.space import space_for
    from aes_planner.teachers import get_teacher
    from aes_planner.teachers.evaluator import CompositionEvaluator

    cfg = FramingEvalConfig(scenes=[spec], seeds=[seed])
    source = _source(spec, cfg)
    seen: dict = {}

    def hook(nodes) -> None:
        planner = next(n for n, _ in nodes if n.node_id == "planner")
        seen["planner"] = planner
        record = planner._record_capture

        def recorded(target, frame) -> None:
            record(target, frame)
            if len(planner.captures) != 1:
                return
            picked = pick_subject(source.scene, frame.cam2world[None], frame.intrinsics, seed, cfg)
            if picked is None:
                return
            obj_i, _, r = picked
            seen["object"], seen["box"] = obj_i, [r.x0, r.y0, r.x1, r.y1]
            req = PlannerRequest(
                "suggest",
                set_framing=True,
                keep=[FramingRegion("latest", r.x0, r.y0, r.x1, r.y1)],
                keep_margin=cfg.keep_margin,
            )
            if not planner._set_framing(req):
                raise RuntimeError(f"{spec}/{seed}: the keep region was refused")
            if today:  # the searches apply it, the loop's own picks do not (as before)
                planner.proposer.framed_views = lambda: None

        planner._record_capture = recorded

    clear_feature_cache()
    t0 = time.time()
    summary = run_demo(spec, "rig", out / "runs" / f"{spec.replace(':', '_')}_{seed}{'_today' if today else ''}",
                       moves, planner_overrides={"seed": 0}, hook=hook)  # fmt: skip
    row = {"scene": spec, "seed": seed, "today": today, "state": summary.get("state"), "wall_s": time.time() - t0}
    if "object" not in seen:
        row["error"] = "no object fits the subject rules in the first view"
        return row
    planner = seen["planner"]
    obj_i = seen["object"]
    row.update(subject=source.scene.objects[obj_i].name or f"object {obj_i + 1}", box=seen["box"])
    points = object_points(source.scene.objects[obj_i])
    k = planner.platform.intrinsics
    final = np.asarray(summary["final_cam2world"], dtype=np.float64)
    row["holds"] = bool(true_holds(points, final[None], k)[0])
    caps = np.stack([c.cam2world for c in planner.captures])
    row["captures"] = len(caps)
    row["captures_holding"] = int(true_holds(points, caps, k).sum())
    row["settled_on_suggestion"] = int(planner.counters.get("framing_settled_on_suggestion", 0))
    row["final_cam2world"] = final.tolist()
    oracles_path = out / "oracles.json"
    oracles = json.loads(oracles_path.read_text()) if oracles_path.exists() else {}
    key = f"{spec}/{obj_i}"
    judge = Judge(source, get_teacher(), CompositionEvaluator())
    if key not in oracles:
        platform = _mode_platform(source, "rig", cfg.free_box_m)
        space = space_for(platform, SearchConfig.preset(cfg.preset, mode=platform.kind))
        oracles[key] = constrained_oracle(space, judge, points, platform.intrinsics, cfg)
        oracles_path.write_text(json.dumps(oracles))
    oracle = oracles[key]
    if oracle is None:
        row["error"] = "no grid view holds the subject"
        return row
    t, _ = judge.measure(final[None])
    row["teacher"] = float(t[0])
    row["normalized_teacher"] = _norm(float(t[0]), oracle["mean_teacher"], oracle["best_teacher"])
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", action="append", required=True)
    ap.add_argument("--seed", action="append", type=int, default=None)
    ap.add_argument("--out", required=True)
    ap.add_argument("--today", action="store_true", help="the loop's picks ignore the framing (as before)")
    ap.add_argument("--moves", type=int, default=4)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(message)s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.jsonl"
    done = set()
    if rows_path.exists():
        for line in rows_path.read_text().splitlines():
            r = json.loads(line)
            done.add((r["scene"], r["seed"], r["today"]))
    for spec in args.scene:
        for seed in args.seed or [0, 1]:
            if (spec, seed, args.today) in done:
                continue
            row = run_case(spec, seed, out, args.today, args.moves)
            print(json.dumps({k: v for k, v in row.items() if k != "final_cam2world"}), flush=True)
            with rows_path.open("a") as f:
                f.write(json.dumps(row) + "\n")
    rows = [json.loads(line) for line in rows_path.read_text().splitlines()]
    for today in (True, False):
        sel = [r for r in rows if r["today"] == today and "holds" in r]
        if not sel:
            continue
        norm = [r["normalized_teacher"] for r in sel if "normalized_teacher" in r]
        print(
            f"{'today' if today else 'framed loop'}: held {sum(r['holds'] for r in sel)}/{len(sel)}; "
            f"normalised teacher median {np.median(norm) if norm else math.nan:.2f} "
            f"(min {min(norm) if norm else math.nan:.2f}, max {max(norm) if norm else math.nan:.2f})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
