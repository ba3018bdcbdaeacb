"""What separates a framed suggestion from the constrained oracle, per case (docs/results/framing_gap_dev.md).

The cases are those of ``aes-planner eval framing``. Every view of the oracle's 5-degree grid
that holds the subject (true geometry) or that the search counts as holding it (the lifted
subject with the margin) is scored on its ground-truth render, by the field, and by the teacher
on the input photos warped into it (with the share of its image they cover). Every score is
normalised to the constrained oracle (0: the mean view that holds the subject, 1: the best).
The row then says where the loss is:

* ``grid_true``: the best grid view that holds the subject (the oracle before its compass search);
* ``grid_true_cov{50,90}``: the same among the views the photos cover at least 50 / 90 % of
  (the "covered constrained oracle": what the inputs could tell);
* ``grid_feas``: the best view the search's feasibility keeps (lifted subject, margin), and
  ``feas_recall`` (how many of the true holding views it keeps), ``feas_precision``;
* ``pick_field`` / ``pick_photo`` / ``pick_blend``: the grid view among the feasible ones the
  field's objective / the warped photos / a coverage blend picks;
* ``suggestion``: the search's own pick (the default settings).

    .venv/bin/python scripts/framing_gap_check.py tabletop:3,indoor:4 0,1 [ARRAYS_DIR]
    # one JSON line per case, prefixed ROW; the per-view arrays of each case go to ARRAYS_DIR
    # (default /tmp/framing_gap) for scripts/framing_gap_rankers.py and framing_lift_sweep.py
"""

import json
import sys

import framing_loss_check as flc  # the cases of eval framing (scripts/ is on the path when run)
import numpy as np
import torch

from aes_planner.eval.framing import true_holds
from aes_planner.eval.search import Judge
from aes_planner.search.photo_warp import warped_photo_scores


class CachedJudge(Judge):
    """A judge that scores each pose once (the oracle and this script measure the same grid)."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.cache = {}

    def measure(self, poses):
        poses = np.asarray(poses, np.float64).reshape(-1, 4, 4)
        keys = [np.round(p, 9).tobytes() for p in poses]
        todo = [i for i, k in enumerate(keys) if k not in self.cache]
        if todo:
            t, e = super().measure(poses[todo])
            for i, a, b in zip(todo, t, e):
                self.cache[keys[i]] = (float(a), float(b))
        return np.array([self.cache[k][0] for k in keys]), np.array([self.cache[k][1] for k in keys])


def arrays_path(folder: str, spec: str, seed: int) -> str:
    return f"{folder}/{spec.replace(':', '_')}_{seed}.npz"


def main(scenes: list[str], seeds: list[int], folder: str = "/tmp/framing_gap") -> None:
    import os

    os.makedirs(folder, exist_ok=True)
    flc.Judge = CachedJudge  # the cases' judges cache their scores
    for c in flc.cases(scenes, seeds):
        run = flc.framed_search(c)
        if run is None:
            continue
        framing, result = run.framing, run.result
        mean, span = c.oracle["mean_teacher"], c.oracle["best_teacher"] - c.oracle["mean_teacher"]
        norm = lambda t, m=mean, d=span: (np.asarray(t, float) - m) / d  # noqa: E731
        grid, _, _ = c.space.exhaustive_grid(
            c.cfg.oracle_step_deg, c.cfg.oracle_free_step_deg, c.cfg.oracle_free_positions
        )
        poses = c.space.to_poses(grid).detach().numpy()  # [G, 4, 4]
        true = true_holds(c.points, poses, c.k)
        feas = framing.feasible(torch.as_tensor(poses)).numpy()
        use = np.flatnonzero(true | feas)
        t = np.full(len(poses), np.nan)
        t[use] = norm(c.judge.measure(poses[use])[0])
        with torch.no_grad():
            out = c.scorer.score_batched(torch.as_tensor(poses), 64)
        fc = framing.cfg
        field = np.nan_to_num(out.score.double().numpy(), nan=-1e9)
        cov_f = out.coverage.double().numpy()
        obj = field - fc.coverage_penalty * np.clip(fc.coverage_min - cov_f, 0, None)
        obj = obj + framing.soft_terms(torch.as_tensor(poses)).numpy()
        photo = np.full(len(poses), np.nan)
        cover = np.zeros(len(poses))
        fr = c.frames
        photo[use], cover[use] = warped_photo_scores(c.scorer.teacher, [f.image for f in fr],
                                                     np.stack([f.cam2world for f in fr]), fr[0].intrinsics,
                                                     poses[use], framing.keep[0].centre_m, fc.photo_width_px)  # fmt: skip

        def best(mask, t=t):
            return float(np.nanmax(t[mask])) if mask.any() else None

        def pick(score, mask, t=t):
            if not mask.any():
                return None
            i = np.flatnonzero(mask)[int(np.nanargmax(np.where(np.isfinite(score[mask]), score[mask], -np.inf)))]
            return float(t[i])

        def z(x, mask):
            v = x[mask]
            return (x - np.nanmean(v)) / (np.nanstd(v) + 1e-12)

        zf, zp = z(obj, feas), z(np.nan_to_num(photo, nan=0.0), feas)
        blend = cover * zp + (1 - cover) * zf
        sug = result.best.cam2world
        row = {
            "scene": c.spec, "seed": c.seed, "grid_true_n": int(true.sum()), "grid_feas_n": int(feas.sum()),
            "feas_recall": float((true & feas).sum() / max(true.sum(), 1)),
            "feas_precision": float((true & feas).sum() / max(feas.sum(), 1)),
            "grid_true": best(true), "grid_true_cov50": best(true & (cover >= 0.5)),
            "grid_true_cov90": best(true & (cover >= 0.9)), "grid_true_cov97": best(true & (cover >= 0.97)),
            "grid_true_fcov50": best(true & (cov_f >= 0.5)),
            "grid_feas": best(feas), "grid_feas_true": best(feas & true), "grid_feas_cov90": best(feas & (cover >= 0.9)),
            "share_true_cov90": float((true & (cover >= 0.9)).sum() / max(true.sum(), 1)),
            "pick_field": pick(obj, feas), "pick_photo": pick(photo, feas), "pick_blend": pick(blend, feas),
            "pick_photo_cov90": pick(photo, feas & (cover >= 0.9)),
            "spearman_field_feas": flc.spearman(obj[feas], t[feas]) if feas.sum() > 2 else None,
            "spearman_photo_feas": flc.spearman(np.nan_to_num(photo[feas]), t[feas]) if feas.sum() > 2 else None,
            "spearman_photo_feas_cov90": flc.spearman(photo[feas & (cover >= 0.9)], t[feas & (cover >= 0.9)])
            if (feas & (cover >= 0.9)).sum() > 2 else None,
            "best_true_cover": float(cover[np.flatnonzero(true)[int(np.nanargmax(t[true]))]]) if true.any() else None,
            "suggestion": float(norm(c.judge.measure(sug[None])[0])[0]),
            "suggestion_cover": float(warped_photo_scores(c.scorer.teacher, [f.image for f in fr],
                                                          np.stack([f.cam2world for f in fr]), fr[0].intrinsics,
                                                          sug[None], framing.keep[0].centre_m, fc.photo_width_px,
                                                          1.1)[1][0]),
        }  # fmt: skip
        print("ROW", json.dumps(row), flush=True)
        np.savez_compressed(arrays_path(folder, c.spec, c.seed), poses=poses, true=true,
                            feas=feas, t=t, field=field, cov_f=cov_f, obj=obj, photo=photo, cover=cover,
                            sug=sug, sug_t=row["suggestion"])  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], *sys.argv[3:4])
