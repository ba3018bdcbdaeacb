"""Rankers of the views the lift keeps, tried offline on the arrays of ``scripts/framing_gap_check.py``
(docs/results/framing_gap_dev.md, "What was tried"): each picks its argmax among a case's kept
grid views; printed per ranker: median, mean and count >= 0.85 of the picks (normalised teacher).

    .venv/bin/python scripts/framing_gap_rankers.py /tmp/framing_gap
"""

import glob
import sys

import numpy as np


def zscore(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    return (x - x[m].mean()) / (x[m].std() + 1e-12)


def ranks(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    out = np.full(len(x), np.nan)
    idx = np.flatnonzero(m)
    out[idx] = np.argsort(np.argsort(x[idx])) / max(len(idx) - 1, 1)
    return out


def picks(d) -> dict[str, float]:
    kept, t, obj, cover = d["feas"], d["t"], d["obj"], d["cover"]
    photo = np.nan_to_num(d["photo"], nan=-1.0)

    def pick(score, m=kept):
        return float(t[int(np.argmax(np.where(m, score, -np.inf)))])

    zf, zp = zscore(obj, kept), zscore(photo, kept)
    out = {"best kept view": float(np.nanmax(np.where(kept, t, np.nan))), "field": pick(obj), "photo": pick(photo)}
    for a in (0.1, 0.5):
        out[f"photo - {a} x uncovered"] = pick(photo - a * (1 - cover))
    for c in (0.7, 0.8, 0.9):
        m = kept & (cover >= c)
        out[f"photo where cover >= {c}, else field"] = pick(photo, m) if m.any() else pick(obj)
    out["z blend by cover"] = pick(cover * zp + (1 - cover) * zf)
    out["z blend by cover^2"] = pick(cover**2 * zp + (1 - cover**2) * zf)
    out["rank average"] = pick(ranks(obj, kept) + ranks(photo, kept))
    idx = np.flatnonzero(kept)
    for k in (3, 5, 10):
        top = np.zeros_like(kept)
        top[idx[np.argsort(-obj[idx])[:k]]] = True
        out[f"field top {k}, then photo"] = pick(photo, top)
    return out


def main(folder: str) -> None:
    table: dict[str, list[float]] = {}
    for f in sorted(glob.glob(f"{folder}/*.npz")):
        d = np.load(f)
        if not d["feas"].any():
            continue
        for name, v in picks(d).items():
            table.setdefault(name, []).append(v)
    for name, v in table.items():
        a = np.array(v)
        print(f"{name:40s} median {np.median(a):5.2f} mean {a.mean():5.2f} >=0.85 {int((a >= 0.85).sum())} of {len(a)}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "/tmp/framing_gap")
