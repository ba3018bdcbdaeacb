"""Dump what the lift sees per framing case, so lift rules can be compared without the field
(docs/results/framing_lift_views_dev.md).

Per case of ``aes-planner eval framing`` that ``scripts/framing_gap_check.py`` has arrays for
(the oracle's 5-degree grid, which views truly hold the subject, their normalised teacher
scores), writes ``OUT/<scene>_<seed>.npz``: the Gaussians' centres and opacities, the
reconstruction's depth rendered at every input view, the input poses and intrinsics, the
subject's region (input view, box), the object's true points and the grid arrays.

    .venv/bin/python scripts/framing_lift_dump.py tabletop:3,indoor:4 0,1 /tmp/framing_gap /tmp/framing_lift2
"""

import sys

import numpy as np
from framing_gap_check import arrays_path  # scripts/ is on the path when run
from framing_loss_check import subjects

from aes_planner.search.framing import render_depth, world_gaussians


def main(scenes: list[str], seeds: list[int], grid_folder: str, out: str) -> None:
    for c in subjects(scenes, seeds):
        try:
            d = dict(np.load(arrays_path(grid_folder, c.spec, c.seed)))
        except FileNotFoundError:
            continue
        means, opac = world_gaussians(c.scorer)
        k = c.frames[0].intrinsics
        depths = np.stack([render_depth(c.scorer, f.cam2world, f.intrinsics) for f in c.frames])
        r = c.picked[2]
        np.savez_compressed(
            arrays_path(out, c.spec, c.seed), means=means, opac=opac, depths=depths,
            c2w=np.stack([f.cam2world for f in c.frames]), k=np.array([k.fx, k.fy, k.cx, k.cy, k.width, k.height]),
            gk=np.array([c.k.fx, c.k.fy, c.k.cx, c.k.cy, c.k.width, c.k.height]),
            view=int(r.frame.removeprefix("view")), box=np.array([r.x0, r.y0, r.x1, r.y1], float),
            points=c.points, poses=d["poses"], true=d["true"], t=d["t"], obj=d["obj"], cov_f=d["cov_f"],
        )  # fmt: skip
        print("dumped", c.spec, c.seed, len(means), flush=True)


if __name__ == "__main__":
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], sys.argv[3], sys.argv[4])
