"""Rank the framed pool by the field corrected by its errors at the input views, and by the
unseen-cells variant (docs/results/framing_ensemble_dev.md, "Two more rankers").

    .venv/bin/python scripts/framing_resid_report.py RESID.jsonl [--cells CELLS.jsonl ...]
"""

from __future__ import annotations

import json
import sys

import numpy as np
from framing_ensemble_report import norm, obj, spearman, summary


def view_angles(pool: np.ndarray, inputs: np.ndarray) -> np.ndarray:  # [P, 4, 4], [V, 4, 4] -> [P, V] degrees
    za, zb = pool[:, :3, 2], inputs[:, :3, 2]
    cos = np.clip(za @ zb.T, -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def corrected(row: dict, length_deg: float) -> np.ndarray:
    """The objective plus the inputs' local errors (``captures.hopes`` without optimism; the
    median offset is the same for every candidate and left out)."""
    resid = np.asarray(row["inputs_teacher"]) - np.asarray(row["inputs_field"])  # [V]
    resid = resid - np.median(resid)
    w = np.exp(
        -((view_angles(np.asarray(row["pool_cam2world"]), np.asarray(row["inputs_cam2world"])) / length_deg) ** 2)
    )
    return obj(row, "base") + (w * resid).sum(1) / (1.0 + w.sum(1))


def report(label: str, rows: list[dict], score_of) -> None:
    base = np.array([norm(r, r["teacher"][int(np.argmax(obj(r, "base")))]) for r in rows])
    picks, holds, sp = [], [], []
    for r in rows:
        s = score_of(r)
        i = int(np.argmax(s))
        picks.append(norm(r, r["teacher"][i]))
        holds.append(r["holds"][i])
        sp.append(spearman(s, r["teacher"]))
    d = np.asarray(picks) - base
    photo = np.array([r["photo"] for r in rows])
    p = np.asarray(picks)
    print(f"{label:34s} all {summary(p)} | photo {np.median(p[photo]):.2f}/{p[photo].mean():.2f} "
          f"proc {np.median(p[~photo]):.2f}/{p[~photo].mean():.2f} | held {sum(holds)} down>0.1 {(d < -0.1).sum()} "
          f"(worst {d.min():+.2f}) up>0.1 {(d > 0.1).sum()} | spearman {np.nanmedian(sp):+.2f}")  # fmt: skip


def main(args: list[str]) -> None:
    resid_paths = [a for a in args if not a.startswith("--cells=")]
    cells_paths = [a.split("=", 1)[1] for a in args if a.startswith("--cells=")]
    rows = [json.loads(line) for p in resid_paths for line in open(p)]
    rows = [r for r in rows if "teacher" in r]
    ang = np.concatenate(
        [view_angles(np.asarray(r["pool_cam2world"]), np.asarray(r["inputs_cam2world"])).min(1) for r in rows]
    )
    res = np.concatenate([np.asarray(r["inputs_teacher"]) - np.asarray(r["inputs_field"]) for r in rows])
    print(f"{len(rows)} cases; pool views' angle to the nearest input: median {np.median(ang):.1f} deg "
          f"(quartiles {np.percentile(ang, 25):.1f}-{np.percentile(ang, 75):.1f}); input residuals "
          f"median {np.median(res):+.3f}, spread (sd) {res.std():.3f}")  # fmt: skip
    report("base (the shipped pick)", rows, lambda r: obj(r, "base"))
    for length in (15.0, 30.0):
        report(f"input residuals, {length:g} deg", rows, lambda r, L=length: corrected(r, L))
    if cells_paths:
        cells = {(c["scene"], c["seed"], c["subject"]): c for p in cells_paths for c in map(json.loads, open(p))}
        both = [r for r in rows if (r["scene"], r["seed"], r["subject"]) in cells]
        for r in both:
            r["cells_inputs"] = cells[(r["scene"], r["seed"], r["subject"])]["cells_inputs"]
        print(f"unseen cells: {len(both)} cases")
        report("base (same cases)", both, lambda r: obj(r, "base"))
        report("unseen cells = inputs", both, lambda r: obj(r, "cells_inputs"))
        report("mean of base and unseen = inputs", both, lambda r: (obj(r, "base") + obj(r, "cells_inputs")) / 2)


if __name__ == "__main__":
    main(sys.argv[1:])
