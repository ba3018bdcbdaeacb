"""Ground-truth scores on a fine pan x tilt grid around given joints (deg) of a scene.

python scripts/loop_truth_around.py SCENE PAN TILT HALF_DEG STEP_DEG (a rig scene; degrees)
"""

import math
import sys

import numpy as np

from aes_planner.eval.closed_loop import true_scores
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

scene, pan0, tilt0, half, step = sys.argv[1], *map(float, sys.argv[2:6])
source = SimSource(scene, supersample=2)
teacher = get_teacher("composition").freeze()
kin = source.platform.kinematics
pans = np.arange(pan0 - half, pan0 + half + 1e-9, step)
tilts = np.arange(tilt0 - half, tilt0 + half + 1e-9, step)
poses, keep = [], []
for t in tilts[::-1]:
    for p in pans:
        poses.append(kin.forward(math.radians(p), math.radians(t)))
s = true_scores(source, teacher, np.stack(poses)).reshape(len(tilts), len(pans))
print("tilt\\pan " + " ".join(f"{p:6.1f}" for p in pans))
for t, row in zip(tilts[::-1], s):
    print(f"{t:7.1f}  " + " ".join(f"{v:6.3f}" for v in row))
