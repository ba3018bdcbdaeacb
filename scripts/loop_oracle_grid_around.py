"""The oracle's cached 5-deg ground-truth grid of a scene around pan/tilt (deg).

python scripts/loop_oracle_grid_around.py SCENE PAN TILT HALF_DEG (a rig scene; degrees)
"""

import sys

import numpy as np

from aes_planner.search import oracle_search
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

scene, pan0, tilt0, half = sys.argv[1], *map(float, sys.argv[2:5])
source = SimSource(scene, supersample=2)
teacher = get_teacher("composition").freeze()
best, c2w, ex = oracle_search(source, teacher, source.platform)
print("cached", ex["cached"], "oracle", best)
pv, tv = np.degrees(ex["pan_values"]), np.degrees(ex["tilt_values"])
g = np.asarray(ex["grid_scores"]).reshape(len(tv), len(pv))
pi = [i for i, p in enumerate(pv) if abs(p - pan0) <= half]
ti = [i for i, t in enumerate(tv) if abs(t - tilt0) <= half]
print("tilt\\pan " + " ".join(f"{pv[i]:6.1f}" for i in pi))
for j in ti[::-1]:
    print(f"{tv[j]:7.1f}  " + " ".join(f"{g[j, i]:6.3f}" for i in pi))
