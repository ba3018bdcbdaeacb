"""Read ``framing_ensemble_check.py`` rows: how far members disagree, and the picks of ensembles.

.venv/bin/python scripts/framing_ensemble_report.py ROWS.jsonl [ROWS.jsonl ...]
"""

from __future__ import annotations

import itertools
import json
import sys

import numpy as np


def spearman(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 3 or a.std() == 0 or b.std() == 0:
        return float("nan")
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def obj(row: dict, name: str) -> np.ndarray:
    m = row[name]
    return np.asarray(m["score"]) - row["coverage_penalty"] * np.clip(
        row["coverage_min"] - np.asarray(m["cov"]), 0, None
    )


def norm(row: dict, t) -> float:
    return (float(t) - row["mean_teacher"]) / (row["best_teacher"] - row["mean_teacher"])


def pick_score(row: dict, score: np.ndarray, top: int) -> tuple[float, bool]:
    s = np.asarray(score)[:top]
    i = int(np.argmax(s))
    return norm(row, row["teacher"][i]), bool(row["holds"][i])


def summary(vals: list[float]) -> str:
    v = np.asarray(vals)
    return f"median {np.median(v):.2f} mean {v.mean():.2f} >=0.85 {(v >= 0.85).sum()}"


def main(paths: list[str]) -> None:
    rows = [json.loads(line) for p in paths for line in open(p)]
    rows = [r for r in rows if "teacher" in r]
    names = [k for k in rows[0] if isinstance(rows[0][k], dict) and "score" in rows[0][k] and k != "base"]
    print(f"{len(rows)} cases; members: {names}")
    print("pick == pool[0]:", sum(r["pick_in_pool"] == 0 and r["pick_dist"] < 1e-6 for r in rows))
    print("\n## disagreement with the shipped build over the pool (Spearman, median / quartiles over cases)")
    for n in ["base", *names]:
        with_base = [spearman(obj(r, "base"), obj(r, n)) for r in rows]
        with_truth = [spearman(obj(r, n), r["teacher"]) for r in rows]
        print(f"{n:12s} vs base {np.nanmedian(with_base):+.2f} [{np.nanpercentile(with_base, 25):+.2f}, "
              f"{np.nanpercentile(with_base, 75):+.2f}]  vs truth {np.nanmedian(with_truth):+.2f}")  # fmt: skip
    for top in (8, 16, 32):
        print(f"\n## picks in the top {top} (norm teacher; photo 18 / procedural 17 / all)")
        base = [pick_score(r, obj(r, "base"), top)[0] for r in rows]
        best = [max(norm(r, t) for t in r["teacher"][:top]) for r in rows]
        print(f"{'best in pool':32s} {summary(best)}")
        print(f"{'base':32s} {summary(base)}")
        others = [n for n in names if n != "base_again"]
        combos = [(n,) for n in others] + list(itertools.combinations(others, 2)) + [
            ("render40", "render56"), ("turn0.3_1", "turn0.3_2", "turn0.3_3"),
            ("scale055", "scale075", "render40", "render56"), tuple(others)]  # fmt: skip
        for combo in combos:
            for c in (0.0, 1.0):
                picks, holds = [], []
                for r in rows:
                    objs = np.stack([obj(r, n) for n in ("base", *combo)])  # [K, P]
                    s = objs.mean(0) - c * objs.std(0)
                    p, h = pick_score(r, s, top)
                    picks.append(p)
                    holds.append(h)
                d = np.asarray(picks) - np.asarray(base)
                label = "+".join(("base", *combo)) + (f" -{c:g}sd" if c else "")
                if len(combo) > 2 and c == 0 or len(combo) <= 2:
                    print(f"{label[:60]:60s} {summary(picks)} held {sum(holds)} down>0.1 {(d < -0.1).sum()} "
                          f"up>0.1 {(d > 0.1).sum()}")  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1:])
