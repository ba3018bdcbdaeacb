"""Does the teacher on the input photos warped into a candidate view rank the views that hold a
kept subject (dev scenes only; docs/results/framing_photo_rank_dev.md)?

For each case of ``aes-planner eval framing`` the framed search runs once (the default
FramingConfig). Pool A: its 32 best feasible stage-1 candidates by the objective. Pool B: turns
and tilts around each input view (up to ``--turn`` deg, 2 deg apart) and around the 8 best of A
(up to 4 deg) that hold the lifted subject. Every view of A and B gets the teacher's score of the
input photos warped into it (:func:`aes_planner.search.photo_warp.photo_composite`: the photo
nearest in direction first, the others filling the rest, through the plane at the subject's
distance), the share of its image the photos cover and, when covered, the teacher's score of
its ground-truth render normalised to the constrained oracle. One JSON line per case, prefixed
ROW; the rankers are compared offline (``--summary`` over the ROW lines of a log).

    .venv/bin/python scripts/framing_photo_rank_check.py tabletop:3,indoor:4,outdoor:5,gallery:6 0,1
    .venv/bin/python scripts/framing_photo_rank_check.py --summary LOG
"""

import argparse
import json
import math
import time

import cv2
import numpy as np
import torch
from framing_loss_check import (  # the cases of eval framing (scripts/ is on the path when run)
    cases,
    framed_search,
    spearman,
)

from aes_planner.eval.framing import true_holds
from aes_planner.search.framing import rendered_rgb
from aes_planner.search.photo_warp import warped_photo_scores


def render_fill(scorer, k):
    """Fills what the photos do not cover with the reconstruction's RGB render."""

    def fill(views, size):
        rgbs = rendered_rgb(scorer, torch.as_tensor(views), k, size[0])
        imgs = torch.cat(list(rgbs)).clamp(0, 1).permute(0, 2, 3, 1).mul(255).byte().numpy()
        return [cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in imgs]

    return fill


def offsets(turn_deg: float, step_deg: float = 2.0) -> torch.Tensor:  # -> [G, 2] rad
    s = np.radians(np.arange(-turn_deg, turn_deg + 1e-9, step_deg))
    a, b = np.meshgrid(s, s, indexing="ij")
    return torch.as_tensor(np.stack([a.ravel(), b.ravel()], -1))


def around(space, poses: np.ndarray, turn_deg: float) -> torch.Tensor:  # [P, 4, 4] -> [P * G, D] params
    base = space.from_poses(poses)  # [P, D]
    off = offsets(turn_deg).to(base.dtype)  # [G, 2]
    p = base[:, None, :].repeat(1, len(off), 1)
    p[..., -2:] += off[None]  # rig: pan, tilt; free/drone: yaw, pitch
    return space.project(p.reshape(-1, base.shape[-1]))


def main(scenes: list[str], seeds: list[int], turn_deg: float) -> None:
    for c in cases(scenes, seeds):
        k, judge, space, scorer, inputs, points, oracle = c.k, c.judge, c.space, c.scorer, c.inputs, c.points, c.oracle
        run = framed_search(c)
        if run is None:
            continue
        framing, result, poses, obj = run.framing, run.result, run.poses, run.obj
        top = np.argsort(-obj, kind="stable")[:32]
        pool_a = poses[top]
        extra = torch.cat([around(space, inputs, turn_deg), around(space, pool_a[:8], 4.0)])
        extra_poses = space.to_poses(extra)
        extra_poses = extra_poses[framing.feasible(extra_poses)].numpy()
        pool = np.concatenate([pool_a, extra_poses, inputs])
        src = ["A"] * len(pool_a) + ["B"] * len(extra_poses) + ["I"] * len(inputs)
        t0 = time.perf_counter()
        images = [f.image for f in c.frames]
        centre = np.mean([s.centre_m for s in framing.keep], 0)
        warped, cover = warped_photo_scores(judge.gt.teacher, images, inputs, k, pool, centre)
        fill = render_fill(scorer, k)
        warped_r, _ = warped_photo_scores(judge.gt.teacher, images, inputs, k, pool, centre, fill=fill)
        t_warp = time.perf_counter() - t0
        fout = framing.wrap(scorer).score_batched(torch.as_tensor(pool), 64)
        m, b = oracle["mean_teacher"], oracle["best_teacher"]
        truth = (np.asarray(judge.measure(pool)[0], float) - m) / (b - m)
        pick = (float(judge.measure(result.best.cam2world[None])[0][0]) - m) / (b - m)
        inputs_truth = (np.asarray(judge.measure(inputs)[0], float) - m) / (b - m)
        row = {"scene": c.spec, "seed": c.seed, "n_a": len(pool_a), "n_b": len(extra_poses), "src": src,
               "warped": warped.tolist(), "warped_render": warped_r.tolist(), "cover": cover.tolist(), "gt": [None if math.isnan(t) else t for t in truth],
               "obj": obj[top].tolist() + [None] * (len(pool) - len(pool_a)),
               "holds": true_holds(points, pool, k).tolist(), "pick_norm": pick, "inputs_gt": inputs_truth.tolist(),
               "field": fout.score.double().numpy().tolist(), "field_cov": fout.coverage.double().numpy().tolist(),
               "feas": framing.feasible(torch.as_tensor(pool)).tolist(), "warp_s": t_warp}  # fmt: skip
        print("ROW", json.dumps(row), flush=True)


def summary(log: str) -> None:
    rows = [json.loads(line[4:]) for line in open(log) if line.startswith("ROW ")]
    picks = {}
    for r in rows:
        w, cv, gt = np.array(r["warped"]), np.array(r["cover"]), np.array(r["gt"], float)
        holds, feas, src = np.array(r["holds"]), np.array(r["feas"]), np.array(r["src"])
        res = {"objective": r["pick_norm"]}
        for th in (0.97, 0.9, 0.8, 0.6, 0.0):
            for name, sel in (("A", src == "A"), ("AB", src != "I"), ("ABI", feas)):
                sel = sel & (cv >= th)
                key = f"{name}@{th}"
                i = np.flatnonzero(sel)[np.argmax(w[sel])] if sel.any() else None
                res[key] = float(gt[i]) if i is not None else r["pick_norm"]
                res[key + "_held"] = bool(holds[i]) if i is not None else True
                res[key + "_best"] = float(np.nanmax(gt[sel])) if sel.any() else np.nan
                res[key + "_rho"] = spearman(w[sel], gt[sel]) if sel.sum() > 2 else np.nan
        print(r["scene"], r["seed"], "n", len(w), "obj", round(r["pick_norm"], 2),
              {k: round(v, 2) for k, v in res.items() if "@" in k and "_" not in k})  # fmt: skip
        for k, v in res.items():
            picks.setdefault(k, []).append(v)
    for k, v in picks.items():
        x = np.array(v, float)
        if k.endswith("_held"):
            print(f"{k}: {int(x.sum())}/{len(x)}")
        else:
            x = x[np.isfinite(x)]
            print(f"{k}: median {np.median(x):.2f} mean {x.mean():.2f} >=0.85 {int((x >= 0.85).sum())}/{len(x)}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="?")
    ap.add_argument("seeds", nargs="?")
    ap.add_argument("--turn", type=float, default=12.0)
    ap.add_argument("--summary")
    args = ap.parse_args()
    if args.summary:
        summary(args.summary)
    else:
        main(args.scenes.split(","), [int(s) for s in args.seeds.split(",")], args.turn)
