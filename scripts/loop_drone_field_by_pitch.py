"""For a drone ``eval loop`` run: per pitch band, the field's best turn and the ground truth's best
turn at a few places (the start, and any given x,y,z), the field built from the run's captures up to
its first verification (what the verifications chose from). Shows whether the field ever ranks a
pitch band the run never looked at.

``python scripts/loop_drone_field_by_pitch.py RUN_DIR [x,y,z ...] [+yaw,pitch ...]`` (``RUN_DIR``:
``OUT/runs/<scene>__<perturbation>``; ``+yaw,pitch``: one more input, a ground-truth capture from the
start place looking that way, added to the field -- what an exploration capture there would tell it)
"""

import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

from aes_planner.eval.closed_loop import true_scores
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.node.proposer import FieldProposer
from aes_planner.sim import SimSource
from aes_planner.teachers import get_teacher

torch.set_num_threads(1)
d = Path(sys.argv[1])
s = json.loads((d / "summary.json").read_text())
caps = json.loads((d / "captures.json").read_text())
first_verify = next(i for i, c in enumerate(caps) if c["kind"] == "verify")
held = caps[:first_verify]
src = SimSource(s["scene"].removesuffix("@drone"), supersample=1)
truth_src = SimSource(s["scene"], supersample=2)
teacher = get_teacher("composition").freeze()
prop = FieldProposer("field", "balanced", max_frames=24)
for c in held:
    prop.add_frame(src.capture(np.asarray(c["cam2world"]), stamp_s=c["stamp_s"]), keep=True)
start = np.asarray(held[0]["cam2world"])[:3, 3]
for a in (a for a in sys.argv[2:] if a.startswith("+")):
    yaw, pitch = (math.radians(float(v)) for v in a[1:].split(","))
    pose = view_to_cam2world(torch.tensor([*start, yaw, pitch], dtype=torch.float64)).numpy()
    prop.add_frame(src.capture(pose, stamp_s=held[-1]["stamp_s"] + 0.1), keep=True)
    print(f"  + an input at the start place looking yaw {a[1:]}")
rand, oracle = s["random_mean"], s["oracle"]
places = [start] + [np.array([float(v) for v in a.split(",")]) for a in sys.argv[2:] if not a.startswith("+")]
yaws = np.arange(-180, 180, 30.0)
pitches = np.arange(-60, 30 + 1e-9, 15.0)
print(
    f"== {d.name}: field from {len(held)} captures (pitches {min(math.degrees(math.asin(c['cam2world'][2][2])) for c in held):.0f}..{max(math.degrees(math.asin(c['cam2world'][2][2])) for c in held):.0f}); oracle {oracle:.3f}, random {rand:.3f}"
)
for p in places:
    views = [(y, t) for t in pitches for y in yaws]
    poses = np.stack(
        [
            view_to_cam2world(torch.tensor([*p, math.radians(y), math.radians(t)], dtype=torch.float64)).numpy()
            for y, t in views
        ]
    )
    pred = prop.score_views(poses).reshape(len(pitches), len(yaws))
    true = np.asarray(true_scores(truth_src, teacher, poses)).reshape(len(pitches), len(yaws))
    print(f"  place ({p[0]:+.2f} {p[1]:+.2f} {p[2]:.2f}): pitch: field best (yaw) | truth best (yaw)")
    for k, t in enumerate(pitches):
        i, j = int(np.argmax(pred[k])), int(np.argmax(true[k]))
        print(
            f"    {t:+5.0f}: field {pred[k, i]:.3f} ({yaws[i]:+4.0f}) | truth {true[k, j]:.3f} ({yaws[j]:+4.0f}); truth at the field's pick {true[k, i]:.3f}"
        )
