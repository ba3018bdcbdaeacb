"""Does the lift's feasible set hold the subject by the true geometry? (geometry only, no oracle)

For each named subject of each scene (boxed as ``eval framing --subject`` boxes it), the subject is
lifted as ``suggest --keep`` lifts it, and the rig's exhaustive 5-degree grid is checked twice:
by the lift (``Framing.feasible``) and by the true object (``true_holds``). Reported per case:
how many grid views the lift calls feasible, how many of those cut the subject (unsafe), how many
truly hold it, and the lift's open sides. Then the search's own pick, and whether it holds.

    .venv/bin/python scripts/framing_hold_check.py OUT.jsonl SCENE.yaml[,SCENE.yaml...] picture0,picture1,picture2 [key=value ...]
    # key=value: FramingConfig overrides (e.g. grow_beyond_frame=False)
"""

from __future__ import annotations

import ast
import dataclasses
import json
import sys

import numpy as np
import torch

from aes_planner.eval.framing import FramingEvalConfig, _shown, object_points, pick_subject, true_holds
from aes_planner.eval.search import _inputs, _mode_platform, _source
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.search.framing import FramingError, build_framing
from aes_planner.search.space import space_for


def main(out: str, scenes: list[str], names: list[str], overrides: dict) -> None:
    cfg = FramingEvalConfig(scenes=scenes, subjects=names)
    fcfg = dataclasses.replace(cfg.framing(), **overrides)
    with open(out, "w") as fh:
        for spec in scenes:
            source = _source(spec, cfg)
            platform = _mode_platform(source, cfg.mode, cfg.free_box_m)
            inputs = _inputs(source, platform, cfg.views)
            frames = [source.capture(p) for p in inputs]
            k = platform.intrinsics
            scfg = SearchConfig.preset(cfg.preset, mode=platform.kind)
            space = space_for(platform, scfg)
            grid, _, _ = space.exhaustive_grid(cfg.oracle_step_deg, cfg.oracle_free_step_deg, cfg.oracle_free_positions)
            poses = space.to_poses(grid)
            scorer = None
            named = {f"view{i}": (f.cam2world, f.intrinsics, (f.intrinsics.width, f.intrinsics.height))
                     for i, f in enumerate(frames)}  # fmt: skip
            for name in names:
                seed, obj_name = (int(name[1:]), None) if name.startswith("#") else (0, name)
                picked = pick_subject(source.scene, inputs, frames[0].intrinsics, seed, cfg, obj_name)
                if picked is None:
                    continue
                obj_i, view, region = picked
                points = object_points(source.scene.objects[obj_i])
                truth = true_holds(points, poses.detach().numpy(), k)
                row = {"scene": spec, "subject": source.scene.objects[obj_i].name, "seed": seed, "box": [region.x0, region.y0, region.x1, region.y1],
                       "shown": round(_shown(source.scene, obj_i, inputs[view], k), 3),
                       "true_views": int(truth.sum()), "grid": len(truth)}  # fmt: skip
                scorer = scorer or build_search_scorer("field", frames, scfg)
                try:
                    framing = build_framing(scorer, named, [region], [], k, fcfg, frames)
                except FramingError as exc:
                    row["error"] = str(exc)[:200]
                    print(json.dumps(row), file=fh, flush=True)
                    continue
                s = framing.keep[0]
                lift = framing.feasible(poses).numpy()
                row.update(lift_views=int(lift.sum()), unsafe=int((lift & ~truth).sum()),
                           kept=int((lift & truth).sum()), open=list(s.open_sides), grown=s.grown,
                           size_m=np.round(s.size_m, 2).tolist())  # fmt: skip
                try:
                    result = search_views(scorer, inputs, platform, scfg, framing=framing)
                    row["pick_holds"] = bool(true_holds(points, result.best.cam2world[None], k)[0])
                except FramingError as exc:
                    row["search_error"] = str(exc)[:200]
                print(json.dumps(row), file=fh, flush=True)


if __name__ == "__main__":
    over = {}
    for kv in sys.argv[4:]:
        key, val = kv.split("=", 1)
        over[key] = ast.literal_eval(val)
    torch.set_num_threads(1)
    main(sys.argv[1], sys.argv[2].split(","), sys.argv[3].split(","), over)
