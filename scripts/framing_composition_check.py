"""Does the subject's size or placement in a framed view explain the teacher's score, and does a
composition prior break the field's near-ties better (docs/results/framing_composition_dev.md)?

Reads the per-view arrays of ``scripts/framing_gap_check.py`` (the oracle's 5-degree grid, which
views truly hold the subject, their normalised ground-truth teacher scores, the field's
objective), lifts each case's subject again with the default ``FramingConfig`` and writes, per
grid view, the composition of the subject in it to ``FOLDER/comp_<case>.npz``:

* ``lift_area`` / ``true_area``: the share of the frame covered by the bounding rectangle of the
  lifted box's / the true object's projection;
* ``true_h``: the true object's projected height share; ``cx``, ``cy``: the true object's projected
  centre (0..1); ``centre_d`` / ``thirds_d``: its distance to the image centre / to the nearest
  thirds crossing (as ``Framing.placement`` measures it, on the lifted box);
* ``slack``: how far the lifted box's nearest corner is inside the shrunk frame (0 on the
  constraint's edge), ``kept``: the search's feasibility (lifted box, 5 % margin).

Then it prints, per case, the Spearman correlation of the teacher with each feature over the kept
views, where the field's pick and the best kept view sit, and (with an ``eval framing`` JSON of
the same cases) the composition of the suggestion itself. Last, the tie-breakers: among the kept
views whose field objective is within ``tau`` of the kept maximum, each rule picks one (rules and
bands fixed before they were run): the field itself, the subject nearest the centre, nearest a
thirds crossing, furthest inside the shrunk frame, largest, lowest in the frame; and the field's
pick when the margin is 0.

    .venv/bin/python scripts/framing_composition_check.py tabletop:3,indoor:4 0,1 /tmp/framing_gap [EVAL_JSON]
"""

import json
import sys

import numpy as np
import torch
from framing_gap_check import arrays_path  # scripts/ is on the path when run
from framing_loss_check import spearman, subjects

from aes_planner.search.framing import FramingError, build_framing, project_corners


def rect(u: np.ndarray, v: np.ndarray) -> tuple:  # [B, P] normalised -> bounding rectangles
    return u.min(-1), u.max(-1), v.min(-1), v.max(-1)


def features(framing, points: np.ndarray, poses: np.ndarray, k) -> dict[str, np.ndarray]:
    p = torch.as_tensor(poses)
    u, v, _ = project_corners(framing._keep, p, framing.intrinsics)  # [B, 1, 8]
    u0, u1, v0, v1 = (x[:, 0] for x in rect(u.numpy(), v.numpy()))
    m = framing.cfg.margin_frac
    slack = np.minimum.reduce([u0 - m, (1 - m) - u1, v0 - m, (1 - m) - v1])
    tu, tv, _ = project_corners(torch.as_tensor(points)[None], p, k)  # [B, 1, P]
    a0, a1, b0, b1 = (x[:, 0] for x in rect(tu.numpy(), tv.numpy()))
    cx, cy = 0.5 * (a0 + a1), 0.5 * (b0 + b1)
    thirds = np.array([1 / 3, 2 / 3])
    du = np.abs(cx[:, None] - thirds).min(-1)
    dv = np.abs(cy[:, None] - thirds).min(-1)
    return {
        "lift_area": (u1 - u0) * (v1 - v0), "true_area": (a1 - a0) * (b1 - b0), "true_h": b1 - b0,
        "true_w": a1 - a0, "cx": cx, "cy": cy, "centre_d": np.hypot(cx - 0.5, cy - 0.5),
        "thirds_d": np.hypot(du, dv), "slack": slack,
    }  # fmt: skip


RULES = {
    "field": lambda f: f["obj"],
    "centre": lambda f: -f["centre_d"],
    "thirds": lambda f: -f["thirds_d"],
    "inside the frame": lambda f: f["slack"],
    "larger": lambda f: f["lift_area"],
    "lower in the frame": lambda f: f["cy"],
}


def tie_breakers(comps: list[dict]) -> None:
    """Median / mean / count >= 0.85 of each rule's pick (normalised teacher) over the cases."""
    res: dict[str, list[float]] = {}
    for f in comps:
        m = f["kept"] & np.isfinite(f["t"])
        if not m.any():
            continue
        res.setdefault("best kept view", []).append(float(np.nanmax(np.where(m, f["t"], np.nan))))
        m0 = f["kept_m0"] & np.isfinite(f["t"])
        res.setdefault("field, margin 0", []).append(float(f["t"][int(np.argmax(np.where(m0, f["obj"], -np.inf)))]))
        for tau in (0.01, 0.02, 0.05):
            band = m & (f["obj"] >= f["obj"][m].max() - tau)
            res.setdefault(f"band {tau}: views in it (median)", []).append(float(band.sum()))
            for name, rule in RULES.items():
                res.setdefault(f"band {tau}: {name}", []).append(
                    float(f["t"][int(np.argmax(np.where(band, rule(f), -np.inf)))])
                )
    for name, v in res.items():
        a = np.array(v)
        print(
            f"TIE {name:38s} median {np.median(a):5.2f} mean {a.mean():5.2f} >=0.85 {int((a >= 0.85).sum())} of {len(a)}"
        )


def main(scenes: list[str], seeds: list[int], folder: str, eval_json: str | None = None) -> None:
    suggested = {}
    if eval_json:
        with open(eval_json) as fh:
            suggested = {f"{r['scene']}/{r['seed']}": r for r in json.load(fh)["rows"] if r.get("cam2world")}
    comps = []
    for c in subjects(scenes, seeds):
        try:
            d = np.load(arrays_path(folder, c.spec, c.seed))
            framing = build_framing(c.scorer, c.named, [c.picked[2]], [], c.k, c.cfg.framing())
        except (FileNotFoundError, FramingError):
            continue
        poses, t, obj, true = d["poses"], d["t"], d["obj"], d["true"]
        kept = framing.feasible(torch.as_tensor(poses)).numpy()
        kept_m0 = framing.with_margin(0.0).feasible(torch.as_tensor(poses)).numpy()
        f = features(framing, c.points, poses, c.k)
        comps.append({"kept": kept, "kept_m0": kept_m0, "t": t, "obj": obj, **f})
        np.savez_compressed(f"{folder}/comp_{c.spec.replace(':', '_')}_{c.seed}.npz", kept=kept, kept_m0=kept_m0,
                            t=t, obj=obj, true=true, **f)  # fmt: skip
        m = kept & true & np.isfinite(t)
        row = {"case": f"{c.spec}/{c.seed}", "kept": int(m.sum())}
        s = suggested.get(row["case"])
        if s is not None:
            sf = features(framing, c.points, np.asarray(s["cam2world"])[None], c.k)
            row.update({"suggestion_t": s["normalized_teacher"], **{f"sug_{n}": float(x[0]) for n, x in sf.items()}})
        if m.sum() >= 3:
            i_pick = np.flatnonzero(m)[int(np.argmax(obj[m]))]
            i_best = np.flatnonzero(m)[int(np.nanargmax(t[m]))]
            row.update(pick_t=float(t[i_pick]), best_t=float(t[i_best]))
            for name, x in f.items():
                row[f"rho_{name}"] = spearman(x[m], t[m])
                row[f"pick_{name}"], row[f"best_{name}"] = float(x[i_pick]), float(x[i_best])
                row[f"med_{name}"] = float(np.median(x[m]))
        print("ROW", json.dumps(row), flush=True)
    tie_breakers(comps)


if __name__ == "__main__":
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], sys.argv[3], *sys.argv[4:5])
