"""Around the framed pick: a local pan x tilt grid scored on ground truth and on the input photos
warped into each view (docs/results/framing_quality_dev.md, "a local polish").

    .venv/bin/python scripts/framing_local_dump.py tabletop:3,indoor:4 0,1 /tmp/fq   # reads /tmp/fq/<case>.npz
    # writes /tmp/fq/<case>.local.npz
"""

import os
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(__file__))
from framing_loss_check import subjects

from aes_planner.eval.framing import true_holds
from aes_planner.eval.search import Judge
from aes_planner.search import search_views
from aes_planner.search.framing import PhotoSet, build_framing
from aes_planner.search.photo_warp import warped_photo_scores
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator


def main(scenes, seeds, folder, half_deg=6.0, step_deg=1.5):
    teacher, ev = get_teacher(), CompositionEvaluator()
    for s in subjects(scenes, seeds):
        base = f"{folder}/{s.spec.replace(':', '_')}_{s.seed}"
        if not os.path.exists(base + ".npz") or os.path.exists(base + ".local.npz"):
            continue
        from aes_planner.search.space import space_for

        space = space_for(s.platform, s.scfg)
        judge = Judge(s.source, teacher, ev)
        framing = build_framing(s.scorer, s.named, [s.picked[2]], [], s.k, s.cfg.framing())
        result = search_views(s.scorer, s.inputs, s.platform, s.scfg, framing=framing)
        pick = space.from_poses(result.best.cam2world[None])[0]
        off = np.radians(np.arange(-half_deg, half_deg + 1e-9, step_deg))
        grid = torch.as_tensor(np.stack(np.meshgrid(off, off, indexing="xy"), -1).reshape(-1, 2)) + pick
        grid = space.project(grid)
        poses = space.to_poses(grid).detach()
        lift = framing.feasible(poses).numpy()
        grid, poses = grid[lift], poses[lift]
        photos = PhotoSet.of(s.frames)
        centre = np.mean([k.centre_m for k in framing.keep], axis=0)
        warped, cover = warped_photo_scores(teacher, photos.images, photos.cam2world, photos.intrinsics,
                                            poses.numpy(), centre, 160, 0.0, 32)  # fmt: skip
        t, e = judge.measure(poses.numpy())
        with torch.no_grad():
            f = s.scorer.score_batched(poses, 32)
        np.savez(base + ".local.npz", params=grid.numpy(), pick=pick.numpy(), warped=warped, cover=cover,
                 teacher=t, evaluator=e, field=f.score.double().numpy(), cov=f.coverage.double().numpy(),
                 true=true_holds(s.points, poses.numpy(), s.k))  # fmt: skip
        print("DONE", base, len(grid), flush=True)


if __name__ == "__main__":
    main(sys.argv[1].split(","), [int(x) for x in sys.argv[2].split(",")], sys.argv[3])
