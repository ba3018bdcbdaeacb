"""Does the lift find the subject the box was drawn around (docs/results/framing_composition_dev.md)?

Per case of ``aes-planner eval framing`` (scene, seed = the seed-th largest eligible object) and per
lift setting (``FramingConfig`` keys as JSON), the subject is lifted from its box and compared with
the object's true geometry: ``inside`` is the share of the object's points (corners, rims) inside
the lifted box, ``centre_err_m`` the distance between the lifted box's centre and the object's,
``size`` / ``true`` the box's and the object's axis-aligned sizes, ``thin`` the object's smallest
horizontal side over its height (a pole or a leg is thin). One JSON line per case and setting.

    .venv/bin/python scripts/framing_lift_check.py tabletop:3,tabletop:11 0,1,2,3 '{}' '{"ring_frac": 0}'
"""

import dataclasses
import json
import sys

import numpy as np
from framing_loss_check import subjects  # scripts/ is on the path when run

from aes_planner.search.framing import FramingError, build_framing


def main(scenes: list[str], seeds: list[int], variants: list[dict]) -> None:
    for c in subjects(scenes, seeds):
        obj, pts = c.source.scene.objects[c.picked[0]], c.points
        lo, hi = pts.min(0), pts.max(0)
        for v in variants:
            row = {"case": f"{c.spec}/{c.seed}", "subject": obj.name, "box": c.picked[2].text(), "variant": v,
                   "true": np.round(hi - lo, 3).tolist(),
                   "thin": round(float(min(hi[:2] - lo[:2]) / max(hi[2] - lo[2], 1e-6)), 3)}  # fmt: skip
            try:
                fc = dataclasses.replace(c.cfg.framing(), **v)
                s = build_framing(c.scorer, c.named, [c.picked[2]], [], c.k, fc).keep[0]
            except FramingError as e:
                row["error"] = str(e)
                print(json.dumps(row), flush=True)
                continue
            local = (pts - s.centre_m) @ s.axes.T
            row.update(inside=float(np.mean(np.all(np.abs(local) <= s.half_extent_m + 1e-6, -1))),
                       centre_err_m=round(float(np.linalg.norm(s.centre_m - 0.5 * (lo + hi))), 3),
                       size=np.round(s.size_m, 3).tolist(), slab_m=np.round(s.depth_range_m, 2).tolist())  # fmt: skip
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(
        sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], [json.loads(a) for a in sys.argv[3:]] or [{}]
    )
