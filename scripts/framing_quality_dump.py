"""Per-case arrays for the framing quality diagnosis (docs/results/framing_quality_dev.md).

For each case of ``aes-planner eval framing`` (same subject rules, same field, same search) this
writes ``OUT/<scene>_<seed>.npz`` with:

* the constrained oracle of ``eval framing`` (``oracle_*``: best teacher / evaluator, their
  means over the grid views that hold the object, the best pose);
* a fine pan x tilt grid (``fine_step_deg``, 2.5 degrees by default) over the rig's range:
  ``fine_params [G, 2]``, ``fine_true [G]`` (holds the object, true geometry), ``fine_lift [G]``
  (holds the lifted subject: what the search counts as feasible), and on the views that are
  either: the teacher and evaluator on ground-truth renders, the field's score and coverage;
* the search's stage-1 feasible pool (``pool_params``, ``pool_field``, ``pool_cov``) with the
  teacher and evaluator on ground truth, and the pick (``pick_params``);
* the picks with ``keep_at`` thirds and centre (``pick_thirds``, ``pick_centre``) and their scores.

    .venv/bin/python scripts/framing_quality_dump.py tabletop:3,indoor:4 0,1 /tmp/fq
"""

import dataclasses
import json
import logging
import math
import os
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(__file__))
from framing_loss_check import cases

from aes_planner.eval.framing import true_holds
from aes_planner.search import search_views
from aes_planner.search.framing import FramingError, build_framing

log = logging.getLogger("framing_quality_dump")


def _span(lo: float, hi: float, step: float) -> np.ndarray:
    n = max(1, int(math.ceil((hi - lo) / step)))
    return np.linspace(lo, hi, n + 1)


def main(scenes: list[str], seeds: list[int], out: str, fine_step_deg: float = 2.5) -> None:
    os.makedirs(out, exist_ok=True)
    for c in cases(scenes, seeds):
        path = os.path.join(out, f"{c.spec.replace(':', '_').replace('/', '_')}_{c.seed}.npz")
        if os.path.exists(path):
            continue
        space, judge, k = c.space, c.judge, c.k
        try:
            framing = build_framing(c.scorer, c.named, [c.picked[2]], [], k, c.cfg.framing())
            result = search_views(c.scorer, c.inputs, c.platform, c.scfg, framing=framing)
        except FramingError as exc:
            log.warning("%s/%d: %s", c.spec, c.seed, exc)
            continue
        lo, hi = space.lower.numpy(), space.upper.numpy()
        step = math.radians(fine_step_deg)
        pans, tilts = np.meshgrid(_span(lo[0], hi[0], step), _span(lo[1], hi[1], step), indexing="xy")
        fine = torch.as_tensor(np.stack([pans.ravel(), tilts.ravel()], -1))  # [G, 2]
        fposes = space.to_poses(fine).detach()  # [G, 4, 4]
        f_true = true_holds(c.points, fposes.numpy(), k)
        f_lift = framing.feasible(fposes).numpy()
        sel = np.flatnonzero(f_true | f_lift)
        ft, fe = judge.measure(fposes[sel].numpy())
        with torch.no_grad():
            fo = c.scorer.score_batched(fposes[sel], c.scfg.batch_size)
        pool_poses = result.candidates_cam2world
        pool_params = space.from_poses(pool_poses).numpy()
        pt, pe = judge.measure(pool_poses)
        pick = result.best.cam2world
        arrays = {
            "fine_params": fine.numpy(), "fine_true": f_true, "fine_lift": f_lift, "fine_sel": sel,
            "fine_teacher": ft, "fine_evaluator": fe,
            "fine_field": fo.score.double().numpy(), "fine_cov": fo.coverage.double().numpy(),
            "pool_params": pool_params, "pool_field": result.candidates_score, "pool_cov": result.candidates_coverage,
            "pool_teacher": pt, "pool_evaluator": pe, "pool_true": true_holds(c.points, pool_poses, k),
            "pick_params": space.from_poses(pick[None]).numpy()[0],
            "inputs_params": space.from_poses(c.inputs).numpy(),
        }  # fmt: skip
        t, e = judge.measure(pick[None])
        arrays["pick_teacher"], arrays["pick_evaluator"] = t[0], e[0]
        for at in ("thirds", "centre"):
            fc = dataclasses.replace(c.cfg.framing(), keep_at=at)
            try:
                r = search_views(c.scorer, c.inputs, c.platform, c.scfg,
                                 framing=build_framing(c.scorer, c.named, [c.picked[2]], [], k, fc))  # fmt: skip
            except FramingError:
                continue
            t, e = judge.measure(r.best.cam2world[None])
            arrays[f"pick_{at}"] = space.from_poses(r.best.cam2world[None]).numpy()[0]
            arrays[f"pick_{at}_teacher"], arrays[f"pick_{at}_evaluator"] = t[0], e[0]
            arrays[f"pick_{at}_holds"] = true_holds(c.points, r.best.cam2world[None], k)[0]
        o = c.oracle
        meta = {"scene": c.spec, "seed": c.seed, "subject": c.source.scene.objects[c.picked[0]].name,
                "oracle": {k2: v for k2, v in o.items() if k2 != "best_cam2world"},
                "pick_holds": bool(true_holds(c.points, pick[None], k)[0])}  # fmt: skip
        arrays["oracle_params"] = space.from_poses(np.asarray(o["best_cam2world"])[None]).numpy()[0]
        np.savez(path, meta=json.dumps(meta), **arrays)
        print("DONE", path, json.dumps(meta), flush=True)


if __name__ == "__main__":
    logging.basicConfig(level=logging.WARNING)
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], sys.argv[3])
