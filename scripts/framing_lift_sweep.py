"""How strict the lifted subject is: per lift setting, the grid views it keeps (docs/results/framing_gap_dev.md).

Reads the per-view arrays ``scripts/framing_gap_check.py`` wrote (the oracle's 5-degree grid, which
views truly hold the subject, their normalised ground-truth teacher scores), lifts each case's
subject again with each setting (``FramingConfig`` keys as JSON) and prints, per setting: cases
with no kept view, views kept that do not truly hold the subject (the lift's safety), the median
share of the truly holding views kept, and the best kept view (normalised; 0 when none is kept).

    .venv/bin/python scripts/framing_lift_sweep.py tabletop:3,indoor:4 0,1 /tmp/framing_gap '{}' '{"depth_cap": 0.3}'
"""

import dataclasses
import json
import sys

import numpy as np
import torch
from framing_gap_check import arrays_path  # scripts/ is on the path when run
from framing_loss_check import subjects

from aes_planner.search.framing import FramingError, build_framing


def main(scenes: list[str], seeds: list[int], folder: str, variants: list[dict]) -> None:
    rows: dict[int, list] = {i: [] for i in range(len(variants))}
    for c in subjects(scenes, seeds):
        try:
            d = np.load(arrays_path(folder, c.spec, c.seed))
        except FileNotFoundError:
            continue
        poses, t, true = torch.as_tensor(d["poses"]), d["t"], d["true"]
        for i, v in enumerate(variants):
            try:
                fc = dataclasses.replace(c.cfg.framing(), **v)
                kept = build_framing(c.scorer, c.named, [c.picked[2]], [], c.k, fc).feasible(poses).numpy()
            except FramingError:
                kept = np.zeros(len(poses), bool)
            best = float(np.nanmax(t[kept & true])) if (kept & true).any() else None
            rows[i].append((f"{c.spec}/{c.seed}", int(kept.sum()), float((kept & true).sum() / max(true.sum(), 1)),
                            int((kept & ~true).sum()), best))  # fmt: skip
    for i, v in enumerate(variants):
        r = rows[i]
        best = np.array([np.nan if x[4] is None else x[4] for x in r])
        print(json.dumps(v), f"empty {sum(x[1] == 0 for x in r)}", f"wrongly kept {sum(x[3] for x in r)}",
              f"kept share median {np.median([x[2] for x in r]):.2f}",
              f"best median {np.nanmedian(best):.2f} mean (0 when none) {np.mean(np.nan_to_num(best)):.2f}",
              f">=0.85 {int(np.sum(best >= 0.85))}")  # fmt: skip
        print("   ", " ".join(f"{x[0]}:{x[1]}/{x[3]}/{'-' if x[4] is None else round(x[4], 2)}" for x in r))


if __name__ == "__main__":
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], sys.argv[3],
         [json.loads(a) for a in sys.argv[4:]] or [{}])  # fmt: skip
