"""An ``eval loop`` run folder's path against the oracle's view: the oracle's joints, the final
view's distance from it, the captures nearest it and the path's moves and verifications.

``python scripts/loop_path_vs_oracle.py RUN_DIR ...`` (``RUN_DIR``: ``OUT/runs/<scene>__<perturbation>``).
"""

import json
import math
import sys
from pathlib import Path

import numpy as np


def ang(a, b):
    za, zb = np.asarray(a)[:3, 2], np.asarray(b)[:3, 2]
    return math.degrees(math.acos(max(-1.0, min(1.0, float(za @ zb / np.linalg.norm(za) / np.linalg.norm(zb))))))


def pt(c2w):
    z = np.asarray(c2w)[:3, 2]
    return math.degrees(math.atan2(z[1], z[0])), math.degrees(math.asin(z[2] / np.linalg.norm(z)))


for d in sys.argv[1:]:
    d = Path(d)
    s = json.loads((d / "summary.json").read_text())
    caps = json.loads((d / "captures.json").read_text())
    oc = s["oracle_cam2world"]
    print(f"== {d.name}: norm {s['normalized']} final {s['final']} oracle {s['oracle']} moves {s['moves']}")
    from aes_planner.sim import SimSource

    kin = SimSource(s["scene"]).platform.kinematics
    oj = [math.degrees(v) for v in kin.direction_joints(np.asarray(oc)[:3, 2])]
    print(f"   oracle pan/tilt {oj[0]:.1f} {oj[1]:.1f}")
    print(
        f"   oracle yaw/pitch {pt(oc)[0]:.1f} {pt(oc)[1]:.1f}; final {pt(s['final_cam2world'])[0]:.1f} "
        f"{pt(s['final_cam2world'])[1]:.1f}; final-oracle {ang(s['final_cam2world'], oc):.2f} deg"
    )
    rows = [(ang(c["cam2world"], oc), i, c) for i, c in enumerate(caps)]
    near = sorted(rows, key=lambda r: r[0])[:6]
    print("   nearest captures to the oracle:")
    for a, i, c in near:
        y, p = math.degrees(c["pan_rad"]), math.degrees(c["tilt_rad"])
        print(f"     #{i} {c['kind']:8s} {a:5.2f} deg  yaw {y:6.1f} pitch {p:5.1f} true {c['true_score']:.4f}")
    print(
        "   path:",
        " ".join(
            f"{c['kind'][:2]}{math.degrees(c['pan_rad']):.1f}/{math.degrees(c['tilt_rad']):.1f}:{c['true_score']:.3f}"
            for c in caps
            if c["kind"] in ("initial", "explore", "move", "verify")
        ),
    )
