"""Framing-specific rankers inside the feasible set, on the oracle's grid (docs/results/framing_lift_views_dev.md).

Reads what ``scripts/framing_lift_dump.py`` wrote, lifts each subject with the default
``FramingConfig`` and picks, among the grid views it keeps, by each ranker: the field's objective,
the same among the better-covered views, a blend with the inputs' coverage, the field's top 5
then the most covered, the field averaged over the 5 nearest kept views. Prints each ranker's
median, mean and count >= 0.85 of the teacher normalised to the constrained oracle.

    .venv/bin/python scripts/framing_lift_rankers.py /tmp/framing_lift2
"""

import glob
import os
import sys

import numpy as np
from framing_lift_views import holds  # scripts/ is on the path when run

from aes_planner.geometry.camera import Intrinsics
from aes_planner.search.framing import FramingConfig, Region, lift_region


def case_picks(path: str) -> dict[str, float]:
    d = np.load(path)
    k = Intrinsics(*[float(x) for x in d["k"][:4]], int(d["k"][4]), int(d["k"][5]))
    view, cfg = int(d["view"]), FramingConfig()
    s = lift_region(d["means"], d["opac"], d["c2w"][view], k, Region("v", *d["box"]), cfg, depth_map=d["depths"][view])
    kept = holds(s.hold_points_m(cfg.hold_by, cfg.occluded_max), d["poses"], d["gk"], cfg.margin_frac)
    t, obj, cov, poses = d["t"], d["obj"], d["cov_f"], d["poses"]
    m = np.flatnonzero(kept)

    def pick(score: np.ndarray, mask: np.ndarray | None = None) -> float:
        mm = m if mask is None or not mask[m].any() else m[mask[m]]
        return float(t[mm[int(np.argmax(score[mm]))]])

    zo = (obj - obj[m].mean()) / (obj[m].std() + 1e-9)
    zc = (cov - cov[m].mean()) / (cov[m].std() + 1e-9)
    top = m[np.argsort(-obj[m])[:5]]
    fwd = poses[m, :3, 2]  # [M, 3] viewing directions
    near = np.argsort(-(fwd @ fwd.T), 1)[:, :5]  # each kept view's 5 nearest kept views (itself first)
    smooth = np.full(len(t), -1e9)
    smooth[m] = obj[m][near].mean(1)
    return {
        "the field's objective": pick(obj),
        "the same, coverage >= its median": pick(obj, cov >= np.median(cov[m])),
        "the same, coverage >= 0.7": pick(obj, cov >= 0.7),
        "z(field) + 0.5 z(coverage)": pick(zo + 0.5 * zc),
        "the field's top 5, then the most covered": float(t[top[np.argmax(cov[top])]]),
        "the field over the 5 nearest kept views": pick(smooth),
    }


def main(folder: str) -> None:
    rows = [case_picks(p) for p in sorted(glob.glob(f"{folder}/*.npz"))]
    for name in rows[0]:
        a = np.array([r[name] for r in rows])
        print(f"{name:44s} median {np.median(a):.2f} mean {a.mean():.2f} >=0.85 {int((a >= 0.85).sum())}")
    print("cases", len(rows), os.path.basename(folder))


if __name__ == "__main__":
    main(sys.argv[1])
