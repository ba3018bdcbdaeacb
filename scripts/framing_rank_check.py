"""Which ranker picks the best view among those that hold a kept subject (dev scenes only;
docs/results/framing_rank_dev.md).

For each case of ``aes-planner eval framing`` the framed search runs once with the default
FramingConfig. Two pools of its feasible stage-1 candidates are taken: the ``--distinct`` best
(the duplicate check of the search, ranked by the objective) or the 32 best by the objective
(near-duplicates included). Each candidate gets the features a ranker could use (the field's
score, its coverage, the field averaged over 8 yaw/pitch jitters of 1.5, 3 and 5 degrees, the
teacher on an RGB render of the reconstruction, the subject's projected size and centre
distance, the angle to the nearest input view) and the teacher's score of its ground-truth
render, normalised to the constrained oracle. One JSON line per case, prefixed ROW; the rankers
are compared offline from these lines.

    .venv/bin/python scripts/framing_rank_check.py tabletop:3,indoor:4,outdoor:5,gallery:6 0,1 [--distinct]
"""

import json
import math
import sys

import numpy as np
import torch
from framing_loss_check import cases, framed_search  # the cases of eval framing (scripts/ is on the path when run)

from aes_planner.eval.framing import true_holds
from aes_planner.search.framing import project_corners, verified_scores
from aes_planner.search.pipeline import _select_distinct

JITTERS = 8


def jittered(poses: np.ndarray, deg: float, rng: np.random.Generator) -> np.ndarray:  # [P, 4, 4] -> [P * 8, 4, 4]
    """Each pose turned by up to ``deg`` (at least half of it) about a random axis in its image plane."""
    out = []
    for p in poses:
        for _ in range(JITTERS):
            axis = np.r_[rng.normal(size=2), 0.0]
            x, y, z = axis / np.linalg.norm(axis)
            k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
            ang = math.radians(deg) * rng.uniform(0.5, 1.0)
            q = p.copy()
            q[:3, :3] = p[:3, :3] @ (np.eye(3) + math.sin(ang) * k + (1 - math.cos(ang)) * k @ k)
            out.append(q)
    return np.stack(out)


def main(scenes: list[str], seeds: list[int], distinct: bool) -> None:
    for c in cases(scenes, seeds):
        k, judge, space, scorer, inputs, points, oracle = c.k, c.judge, c.space, c.scorer, c.inputs, c.points, c.oracle
        run = framed_search(c)
        if run is None:
            continue
        framing, result, poses, field, cov, obj = run.framing, run.result, run.poses, run.field, run.cov, run.obj
        if distinct:
            sel = _select_distinct(space, space.from_poses(poses), torch.as_tensor(obj), 24, None).numpy()
        else:
            sel = np.argsort(-obj, kind="stable")[:32]
        pool = poses[sel]
        feats = {"field": field[sel].tolist(), "obj": obj[sel].tolist(), "cov": cov[sel].tolist()}
        rng = np.random.default_rng(0)
        for deg in (1.5, 3, 5):
            out = scorer.score_batched(torch.as_tensor(jittered(pool, deg, rng)), 64)
            feats[f"jit{deg:g}"] = out.score.double().numpy().reshape(len(pool), JITTERS).mean(1).tolist()
        rendered = verified_scores(scorer, torch.as_tensor(pool), k, 96)
        feats["render_teacher"] = None if rendered is None else rendered.tolist()
        u, v, _ = project_corners(framing._keep, torch.as_tensor(pool), k)  # [P, 1, 8]
        feats["size"] = ((u.amax(-1) - u.amin(-1)).clamp(0, 1) * (v.amax(-1) - v.amin(-1)).clamp(0, 1))[:, 0].tolist()
        cu, cv = 0.5 * (u.amax(-1) + u.amin(-1)), 0.5 * (v.amax(-1) + v.amin(-1))
        feats["centre_d"] = torch.sqrt((cu - 0.5) ** 2 + (cv - 0.5) ** 2)[:, 0].tolist()
        cosines = np.clip(pool[:, :3, 2] @ inputs[:, :3, 2].T, -1, 1)
        feats["in_angle_deg"] = np.degrees(np.arccos(cosines).min(1)).tolist()
        params = space.from_poses(pool)
        feats["dist"] = space.distance(params, params).numpy().tolist()
        m, b = oracle["mean_teacher"], oracle["best_teacher"]
        truth = (np.asarray(judge.measure(pool)[0], float) - m) / (b - m)
        pick = (float(judge.measure(result.best.cam2world[None])[0][0]) - m) / (b - m)
        row = {"scene": c.spec, "seed": c.seed, "n": len(pool), "gt": truth.tolist(),
               "holds": true_holds(points, pool, k).tolist(), "pick_norm": pick, "feats": feats}  # fmt: skip
        print("ROW", json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], "--distinct" in sys.argv[3:])
