"""A drone scene's cached oracle grid (places x yaw x pitch, ground truth): the best view per pitch,
per place, and the grid's top views; optionally the truth at given 5-DoF views.

``python scripts/loop_drone_oracle_grid.py SCENE@drone [x,y,z,yaw_deg,pitch_deg ...]``
"""

import math
import sys

import numpy as np
import torch

from aes_planner.eval.closed_loop import true_scores
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.search import oracle_search
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

scene = sys.argv[1].removesuffix("@drone")
source = SimSource(scene, supersample=2)
teacher = get_teacher("composition").freeze()
best, c2w, ex = oracle_search(source, teacher, source.platform.as_drone())
g, s = np.asarray(ex["grid_params"]), np.asarray(ex["grid_scores"])  # [G, 5], [G]
print(
    f"cached {ex['cached']} oracle {best:.3f} mean random {ex['mean_random']:.3f}; oracle params",
    np.round(np.r_[ex["best_params"][:3], np.degrees(ex["best_params"][3:])], 2),
)
print("best per pitch (deg):")
for p in np.unique(np.round(g[:, 4], 6)):
    m = np.isclose(g[:, 4], p)
    i = np.flatnonzero(m)[np.argmax(s[m])]
    print(
        f"  pitch {math.degrees(p):6.1f}: best {s[i]:.3f} at {np.round(g[i, :3], 2)} yaw {math.degrees(g[i, 3]):6.1f}; mean {s[m].mean():.3f}"
    )
print("best per place:")
places = np.unique(np.round(g[:, :3], 6), axis=0)
for q in places:
    m = np.all(np.isclose(g[:, :3], q), axis=1)
    i = np.flatnonzero(m)[np.argmax(s[m])]
    print(f"  {np.round(q, 2)}: best {s[i]:.3f} yaw {math.degrees(g[i, 3]):6.1f} pitch {math.degrees(g[i, 4]):5.1f}")
print("top 12 grid views:")
for i in np.argsort(-s)[:12]:
    print(
        f"  {s[i]:.3f} at {np.round(g[i, :3], 2)} yaw {math.degrees(g[i, 3]):6.1f} pitch {math.degrees(g[i, 4]):5.1f}"
    )
if len(sys.argv) > 2:
    views = [[float(v) for v in a.split(",")] for a in sys.argv[2:]]
    poses = np.stack(
        [
            view_to_cam2world(torch.tensor([x, y, z, math.radians(yw), math.radians(pt)], dtype=torch.float64)).numpy()
            for x, y, z, yw, pt in views
        ]
    )
    for v, t in zip(views, true_scores(source, teacher, poses)):
        print(f"  truth at {v}: {t:.3f}")
