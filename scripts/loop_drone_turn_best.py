"""For a drone ``eval loop`` run: the best ground-truth view from each place the run captured at,
turning only (a yaw x pitch grid), normalised with the run's oracle -- what a polish that only turns
could reach from each visited place, against what the run ended on.

``python scripts/loop_drone_turn_best.py RUN_DIR [YAW_STEP_DEG PITCH_STEP_DEG]``
"""

import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

from aes_planner.eval.closed_loop import true_scores
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

d = Path(sys.argv[1])
ystep = float(sys.argv[2]) if len(sys.argv) > 2 else 15.0
pstep = float(sys.argv[3]) if len(sys.argv) > 3 else 10.0
s = json.loads((d / "summary.json").read_text())
caps = json.loads((d / "captures.json").read_text())
source = SimSource(s["scene"], supersample=2)
teacher = get_teacher("composition").freeze()
rand, oracle = s["random_mean"], s["oracle"]
places, kinds = [], []
for c in caps:
    p = np.asarray(c["cam2world"])[:3, 3]
    if all(np.linalg.norm(p - q) > 0.05 for q in places):
        places.append(p)
        kinds.append(c["kind"])
yaws = np.arange(-180, 180, ystep)
pitches = np.arange(-60, 30 + 1e-9, pstep)
print(f"== {d.name}: final norm {s['normalized']:.3f}; {len(places)} places; grid {len(yaws)} x {len(pitches)}")
for p, k in zip(places, kinds):
    views = [(y, t) for y in yaws for t in pitches]
    poses = np.stack(
        [
            view_to_cam2world(torch.tensor([*p, math.radians(y), math.radians(t)], dtype=torch.float64)).numpy()
            for y, t in views
        ]
    )
    sc = true_scores(source, teacher, poses)
    i = int(np.argmax(sc))
    n = (sc[i] - rand) / (oracle - rand)
    print(
        f"  {k:8s} ({p[0]:+.2f} {p[1]:+.2f} {p[2]:.2f}): best turn {sc[i]:.3f} (norm {n:.3f}) yaw {views[i][0]:6.1f} pitch {views[i][1]:5.1f}"
    )
