"""A drone ``eval loop`` run folder's path against the oracle's view: the oracle's place and way,
each capture's distance (metres, degrees) from it, the captures nearest it, and what the moves
hoped for against what they captured.

``python scripts/loop_drone_path_vs_oracle.py RUN_DIR ...`` (``RUN_DIR``: ``OUT/runs/<scene>__<perturbation>``).
"""

import json
import math
import sys
from pathlib import Path

import numpy as np


def ang(a, b):
    za, zb = np.asarray(a)[:3, 2], np.asarray(b)[:3, 2]
    c = float(za @ zb / np.linalg.norm(za) / np.linalg.norm(zb))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def view(c2w):
    c2w = np.asarray(c2w)
    z = c2w[:3, 2]
    yaw = math.degrees(math.atan2(z[1], z[0]))
    pitch = math.degrees(math.asin(z[2] / np.linalg.norm(z)))
    return c2w[:3, 3], yaw, pitch


def fmt(c2w):
    p, y, t = view(c2w)
    return f"({p[0]:+.2f} {p[1]:+.2f} {p[2]:.2f}) yaw {y:6.1f} pitch {t:5.1f}"


for d in sys.argv[1:]:
    d = Path(d)
    s = json.loads((d / "summary.json").read_text())
    caps = json.loads((d / "captures.json").read_text())
    oc = np.asarray(s["oracle_cam2world"])
    print(f"== {d.name}: norm {s['normalized']:.3f} final {s['final']:.3f} oracle {s['oracle']:.3f} moves {s['moves']}")
    print(f"   oracle {fmt(oc)}")
    print(f"   final  {fmt(s['final_cam2world'])}")
    rows = []
    for i, c in enumerate(caps):
        m = float(np.linalg.norm(np.asarray(c["cam2world"])[:3, 3] - oc[:3, 3]))
        rows.append((m, ang(c["cam2world"], oc), i, c))
    print("   nearest captures to the oracle (m + deg/100):")
    for m, a, i, c in sorted(rows, key=lambda r: r[0] + r[1] / 100)[:5]:
        print(f"     #{i:2d} {c['kind']:8s} {m:.2f} m {a:5.1f} deg true {c['true_score']:.3f} {fmt(c['cam2world'])}")
    print("   path (kind, place/way, hope -> true, nearest earlier capture m/deg):")
    for i, c in enumerate(caps):
        if c["kind"] in ("polish",):
            continue
        prev = [
            (
                float(np.linalg.norm(np.asarray(q["cam2world"])[:3, 3] - np.asarray(c["cam2world"])[:3, 3])),
                ang(q["cam2world"], c["cam2world"]),
            )
            for q in caps[:i]
        ]
        near = min(prev, key=lambda r: r[0] + r[1] / 100) if prev else (0, 0)
        pred = c.get("predicted")
        ps = f"{pred:.3f}" if pred is not None else "  -  "
        print(
            f"     #{i:2d} {c['kind']:8s} {fmt(c['cam2world'])} hope {ps} true {c['true_score']:.3f}"
            f"  near {near[0]:.2f} m {near[1]:5.1f} deg; to oracle {rows[i][0]:.2f} m {rows[i][1]:5.1f} deg"
        )
    best = max(caps, key=lambda c: c["true_score"])
    print(f"   best capture {best['kind']} true {best['true_score']:.3f} {fmt(best['cam2world'])}")
