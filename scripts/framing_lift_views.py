"""Which views that truly hold the subject the lift rejects, and why (docs/results/framing_lift_views_dev.md).

Reads what ``scripts/framing_lift_dump.py`` wrote and lifts each case's subject again, without
the field, with each setting (``FramingConfig`` keys as JSON). Per case: the lifted box against
the object's true extent (in the box's axes: size ratio per axis, centre offset), the grid views
that truly hold the object (5-degree oracle grid), how many the lift keeps, and of those it
rejects, how many only for the margin (held at margin 0) and how many because the box sticks
out of the frame; the best view kept (teacher, normalised to the constrained oracle), against
the best that truly holds the object and the best the object's own points allow with the margin
(a perfect lift), and the field's pick among the kept views.

    .venv/bin/python scripts/framing_lift_views.py /tmp/framing_lift2 '{}' '{"depth_cap": 0.15}'
"""

import dataclasses
import glob
import json
import os
import sys

import numpy as np

from aes_planner.geometry.camera import Intrinsics
from aes_planner.search.framing import FramingConfig, FramingError, Region, lift_region


def holds(points: np.ndarray, poses: np.ndarray, k: np.ndarray, margin: float) -> np.ndarray:  # -> [B] bool
    rel = points[None] - poses[:, None, :3, 3]
    pc = np.einsum("bji,bpj->bpi", poses[:, :3, :3], rel)
    z = pc[..., 2]
    zs = np.where(z > 1e-6, z, 1.0)
    u = (k[0] * pc[..., 0] / zs + k[2]) / k[4]
    v = (k[1] * pc[..., 1] / zs + k[3]) / k[5]
    ok = (z > 0.05) & (u >= margin) & (u <= 1 - margin) & (v >= margin) & (v <= 1 - margin)
    return ok.all(-1)


def case_rows(path: str, variant: dict) -> dict:
    d = np.load(path)
    k = Intrinsics(*[float(x) for x in d["k"][:4]], int(d["k"][4]), int(d["k"][5]))
    view = int(d["view"])
    cfg = dataclasses.replace(FramingConfig(), **variant)
    region = Region(f"view{view}", *[float(x) for x in d["box"]])
    pts, poses, true, t, obj = d["points"], d["poses"], d["true"], d["t"], d["obj"]
    name = os.path.basename(path)[:-4]
    try:
        s = lift_region(d["means"], d["opac"], d["c2w"][view], k, region, cfg, depth_map=d["depths"][view])
    except FramingError as e:
        return {"case": name, "error": str(e)}
    corners = s.hold_points_m(cfg.hold_by, cfg.occluded_max)
    kept = holds(corners, poses, d["gk"], cfg.margin_frac)
    kept0 = holds(corners, poses, d["gk"], 0.0)
    perfect = holds(pts, poses, d["gk"], cfg.margin_frac)
    local = (pts - s.centre_m) @ s.axes.T  # the object in the box's axes
    lo, hi = local.min(0), local.max(0)
    ratio = (2 * s.half_extent_m) / np.maximum(hi - lo, 0.01)
    offset = 0.5 * (lo + hi)  # the object's centre from the box's, in the box's axes
    cam = d["c2w"][view][:3, 3]
    ray = np.linalg.norm(s.centre_m - cam) - np.linalg.norm(pts.mean(0) - cam)  # + : box farther than the object

    def best(mask):
        return float(np.nanmax(t[mask])) if mask.any() else None

    pick = None
    if (kept & true).any():
        m = np.flatnonzero(kept)
        pick = float(t[m[int(np.argmax(obj[m]))]])
    return {
        "case": name, "occluded": round(s.occluded_frac, 2), "true": int(true.sum()), "kept": int((kept & true).sum()), "wrong": int((kept & ~true).sum()),
        "rej_margin": int((true & ~kept & kept0).sum()), "rej_box": int((true & ~kept0).sum()),
        "size_ratio": np.round(ratio, 2).tolist(), "box_m": np.round(2 * s.half_extent_m, 2).tolist(),
        "true_m": np.round(hi - lo, 2).tolist(), "offset_m": np.round(offset, 2).tolist(), "ray_m": round(float(ray), 2),
        "best_true": best(true), "best_perfect": best(true & perfect), "best_kept": best(kept & true),
        "pick": pick,
    }  # fmt: skip


def main(folder: str, variants: list[dict]) -> None:
    paths = sorted(glob.glob(f"{folder}/*.npz"))
    for v in variants:
        rows = [case_rows(p, v) for p in paths]
        print("VARIANT", json.dumps(v))
        for r in rows:
            print("ROW", json.dumps(r))
        ok = [r for r in rows if "error" not in r]
        bk = np.array([np.nan if r["best_kept"] is None else r["best_kept"] for r in ok])
        pk = np.array([np.nan if r["pick"] is None else r["pick"] for r in ok])
        share = [r["kept"] / max(r["true"], 1) for r in ok]
        print(
            f"SUMMARY {json.dumps(v)} cases {len(rows)} errors {len(rows) - len(ok)} empty {int(np.isnan(bk).sum())} "
            f"wrong {sum(r['wrong'] for r in ok)} kept-share median {np.median(share):.2f} "
            f"best-kept median {np.nanmedian(bk):.2f} mean(0 none) {np.mean(np.nan_to_num(bk)):.2f} "
            f">=0.85 {int(np.sum(bk >= 0.85))} | field pick median {np.nanmedian(pk):.2f} "
            f"mean(0 none) {np.mean(np.nan_to_num(pk)):.2f} >=0.85 {int(np.sum(pk >= 0.85))}",
            flush=True,
        )


if __name__ == "__main__":
    main(sys.argv[1], [json.loads(a) for a in sys.argv[2:]] or [{}])
