"""CPU time of a drone's turn scoring (``verify_turns``: every captured place x 240 field views)
against one loop planning search, on a field of a run's captures before its polish (the first 15
initial/explore/move/verify captures), the two alternated in one process, 1 thread.

``python scripts/loop_drone_time_turns.py RUN_DIR`` (a drone ``eval loop`` run folder)
"""

import json
import statistics as st
import sys
import time

import numpy as np
import torch

from aes_planner.node.motion import DroneMotion
from aes_planner.node.proposer import FieldProposer
from aes_planner.search import SearchConfig
from aes_planner.sim import SimSource

torch.set_num_threads(1)
d = sys.argv[1]
s = json.loads(open(d + "/summary.json").read())
caps = json.loads(open(d + "/captures.json").read())
src = SimSource(s["scene"].removesuffix("@drone"), supersample=1)
caps = [c for c in caps if c["kind"] in ("initial", "explore", "move", "verify")][
    :15
]  # what the field holds at the polish
prop = FieldProposer("field", "balanced", max_frames=24)
prop.search_settings = {"steps": 25, "grid_points": 216}
for c in caps:
    prop.add_frame(src.capture(np.asarray(c["cam2world"]), stamp_s=c["stamp_s"]), keep=True)
platform = src.platform.as_drone()
motion = DroneMotion(platform.drone, SearchConfig.preset("balanced"))
motion.bind(platform.intrinsics)
places = []
for c in caps:
    p = np.asarray(c["cam2world"])[:3, 3]
    if all(np.linalg.norm(p - q) >= 0.1 for q in places):
        places.append(p)
views = np.concatenate([motion.turns(p) for p in places])
captured = np.stack([np.asarray(c["cam2world"]) for c in caps])
prop.score_views(views[:8])
prop.propose(platform, captured, 4, keep_near=0, search={"fixed_draws": True})  # warm
tt, tp = [], []
for _ in range(3):
    t0 = time.process_time()
    prop.score_views(views)
    tt.append(time.process_time() - t0)
    t0 = time.process_time()
    prop.propose(platform, captured, 4, keep_near=0, search={"fixed_draws": True})
    tp.append(time.process_time() - t0)
print(
    f"{len(places)} places, {len(views)} views: turns CPU {st.median(tt):.2f} s (runs {np.round(tt, 2)}); one planning search CPU {st.median(tp):.2f} s (runs {np.round(tp, 2)})"
)
