"""Figures of the framing quality diagnosis from ``scripts/framing_quality_dump.py``'s arrays.

    .venv/bin/python scripts/framing_quality_report.py /tmp/fq
    # one table row per case, then medians; teacher normalised to the constrained oracle

Columns: (a) where the field's pick sits against the constrained oracle (pan/tilt degrees, and
the teacher between them); (b) whether the stage-1 feasible pool and the lift's feasible set
reach the oracle; (c) how far the teacher and the independent evaluator agree over the views
that hold the subject; (d) ``keep_at`` thirds / centre; and offline rankers over the dense
feasible grid.
"""

import glob
import json
import sys

import numpy as np


def spearman(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    if len(a) < 3 or np.std(a) == 0 or np.std(b) == 0:
        return float("nan")
    return float(np.corrcoef(np.argsort(np.argsort(a)), np.argsort(np.argsort(b)))[0, 1])


def deg(a, b) -> np.ndarray:  # [..., 2] pan/tilt radians -> degrees on the sphere (approximate)
    a, b = np.asarray(a), np.asarray(b)
    dpan = (a[..., 0] - b[..., 0]) * np.cos(0.5 * (a[..., 1] + b[..., 1]))
    return np.degrees(np.hypot(dpan, a[..., 1] - b[..., 1]))


def load(path):
    z = np.load(path, allow_pickle=False)
    d = {k: z[k] for k in z.files}
    d["meta"] = json.loads(str(d["meta"]))
    return d


def objective(field, cov, cmin=0.5, pen=0.5):
    return np.nan_to_num(field, nan=-1e9) - pen * np.clip(cmin - cov, 0, None)


def case_figures(d: dict) -> dict:
    o = d["meta"]["oracle"]
    mt, bt, me, be = o["mean_teacher"], o["best_teacher"], o["mean_evaluator"], o["best_evaluator"]
    nt = lambda x: (np.asarray(x, float) - mt) / (bt - mt)  # noqa: E731
    ne = lambda x: (np.asarray(x, float) - me) / (be - me)  # noqa: E731
    sel = d["fine_sel"]
    fp = d["fine_params"][sel]
    true, lift = d["fine_true"][sel], d["fine_lift"][sel]
    ft, fe = nt(d["fine_teacher"]), ne(d["fine_evaluator"])
    fobj = objective(d["fine_field"], d["fine_cov"])
    orc, pick = d["oracle_params"], d["pick_params"]
    r = {"case": f"{d['meta']['scene']}/{d['meta']['seed']}", "subject": d["meta"]["subject"][:18]}
    r["pick"] = float(nt(d["pick_teacher"]))
    r["pick_e"] = float(ne(d["pick_evaluator"]))
    # (a) the pick against the oracle
    r["d_pick_oracle"] = float(deg(pick, orc))
    near_pick = true & (deg(fp, pick) <= 2.6)
    r["best_near_pick"] = float(ft[near_pick].max()) if near_pick.any() else float("nan")
    # the teacher's roughness: neighbouring truly holding fine views (2.5 deg apart), |delta|
    tp = fp[true]
    tt = ft[true]
    dd = deg(tp[:, None], tp[None])
    pairs = (dd > 0.1) & (dd < 2.6)
    r["rough_2p5"] = float(np.median(np.abs(tt[:, None] - tt[None])[pairs])) if pairs.any() else float("nan")
    # (b) coverage of the feasible set near the oracle
    pp, pt = d["pool_params"], nt(d["pool_teacher"])
    dpo = deg(pp, orc)
    r["pool_n"] = len(pp)
    r["d_pool_oracle"] = float(dpo.min())
    r["pool_best"] = float(pt[d["pool_true"]].max()) if d["pool_true"].any() else float("nan")
    r["pool_085"] = int((pt[d["pool_true"]] >= 0.85).sum())
    i_or = int(np.argmin(deg(fp, orc)))
    r["oracle_lift_ok"] = bool(lift[i_or])
    r["true_n"], r["lift_n"] = int(true.sum()), int(lift.sum())
    r["lift_kept"] = float((true & lift).sum() / max(true.sum(), 1))
    r["lift_best"] = float(ft[true & lift].max()) if (true & lift).any() else float("nan")
    r["true_best_fine"] = float(ft[true].max())
    r["n085_fine"] = int((ft[true] >= 0.85).sum())
    # the field's rank of the oracle's neighbourhood among the lift's views
    lf = np.flatnonzero(lift)
    ranks = np.argsort(np.argsort(-fobj[lf]))
    r["field_rank_oracle"] = int(ranks[np.argmin(deg(fp[lf], orc))]) if len(lf) else -1
    # (c) teacher vs evaluator over the truly holding views
    r["sp_t_e"] = spearman(ft[true], fe[true])
    r["sp_field_t"] = spearman(fobj[true & lift], ft[true & lift])
    top_t = ft[true] >= np.quantile(ft[true], 0.9)
    r["e_at_t_top10"] = float(np.median(fe[true][top_t]))
    # (d) placement
    for at in ("thirds", "centre"):
        r[at] = float(nt(d[f"pick_{at}_teacher"])) if f"pick_{at}_teacher" in d else float("nan")

    # offline rankers (argmax, then the teacher of what they pick; lift-feasible views only)
    def pick_of(mask_score):
        return float(ft[int(np.nanargmax(mask_score))])

    lift_obj = np.where(lift, fobj, -np.inf)
    r["R_fine"] = pick_of(lift_obj)  # the field's best on the dense feasible grid
    # hill-climb on the fine grid from the pick, by the field, inside the lift's set
    cur = int(np.argmin(np.where(lift, deg(fp, pick), np.inf)))
    for _ in range(50):
        nb = np.flatnonzero(lift & (deg(fp, fp[cur]) < 3.6))
        nxt = nb[int(np.argmax(fobj[nb]))]
        if fobj[nxt] <= fobj[cur]:
            break
        cur = nxt
    r["R_climb"] = float(ft[cur])
    r["R_climb_d"] = float(deg(fp[cur], pick))
    # the field smoothed on the grid (mean over lift views within 3.6 deg)
    nbm = (deg(fp[:, None], fp[None]) < 3.6) & lift[None]
    sm = np.where(lift, (nbm * fobj[None]).sum(1) / np.maximum(nbm.sum(1), 1), -np.inf)
    r["R_smooth"] = pick_of(sm)
    raw = np.where(lift, np.nan_to_num(d["fine_field"], nan=-1e9), -np.inf)
    r["R_fine_raw"] = pick_of(raw)  # the field alone, no coverage term
    coarse = lift & (np.round(np.degrees(fp[:, 0]) / 2.5) % 2 == 0) & (np.round(np.degrees(fp[:, 1]) / 2.5) % 2 == 0)
    r["R_fine5"] = pick_of(np.where(coarse, fobj, -np.inf))  # the same on a 5-degree grid
    # the pool and the dense grid together, by the objective
    pobj = objective(d["pool_field"], d["pool_cov"])
    if pobj.max() >= lift_obj.max():
        r["R_pool_fine"] = float(pt[int(np.argmax(pobj))])
    else:
        r["R_pool_fine"] = r["R_fine"]
    r["R_pool"] = float(pt[int(np.argmax(pobj))])
    # what the field's error goes with (lift views): the residual of its rank against the truth's
    m = lift & true
    if m.sum() >= 5:
        rf = np.argsort(np.argsort(fobj[m])) / m.sum()
        rt = np.argsort(np.argsort(ft[m])) / m.sum()
        resid = rf - rt  # > 0: the field over-rates the view
        r["res_cov"] = spearman(resid, d["fine_cov"][m])
        r["res_tilt"] = spearman(resid, fp[m, 1])
        r["res_dinput"] = spearman(resid, deg(fp[m][:, None], d["inputs_params"][None]).min(1))
        z = lambda x: (x - x.mean()) / max(x.std(), 1e-12)  # noqa: E731
        X = np.c_[z(fobj[m]), z(d["fine_cov"][m]), np.ones(m.sum())]
        coef = np.linalg.lstsq(X, z(ft[m]), rcond=None)[0]
        r["beta_cov"] = float(coef[1] / coef[0]) if abs(coef[0]) > 1e-6 else float("nan")
        r["coef_f"], r["coef_c"] = float(coef[0]), float(coef[1])
    cov = d["fine_cov"]
    mu_f, sd_f = fobj[lift].mean(), max(fobj[lift].std(), 1e-12)
    mu_c, sd_c = cov[lift].mean(), max(cov[lift].std(), 1e-12)
    for b in (0.25, 0.5, 1.0):
        r[f"R_zc{b}"] = pick_of(np.where(lift, (fobj - mu_f) / sd_f - b * (cov - mu_c) / sd_c, -np.inf))
    for lam in (0.02, 0.05, 0.1):
        r[f"R_c{lam}"] = pick_of(np.where(lift, fobj - lam * cov, -np.inf))
    return r


def main(folder: str) -> None:
    rows = [case_figures(load(p)) for p in sorted(glob.glob(f"{folder}/*_[0-9].npz"))]
    cols = list(max(rows, key=len))
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print(
            "| "
            + " | ".join(
                f"{r.get(c, np.nan):.2f}" if isinstance(r.get(c, np.nan), float) else str(r.get(c)) for c in cols
            )
            + " |"
        )
    med = {
        c: float(np.nanmedian([r.get(c, np.nan) for r in rows]))
        for c in cols
        if isinstance(rows[0][c], (float, int, bool))
    }
    print("| median | " + " | ".join(f"{med[c]:.2f}" if c in med else "" for c in cols[1:]) + " |")
    for c in ("beta_cov", "coef_f", "coef_c"):
        v = np.array([r.get(c, np.nan) for r in rows])
        print(c, np.round(v, 2), "median", round(float(np.nanmedian(v)), 2))
    for c in (
        "pick",
        "thirds",
        "centre",
        "R_pool",
        "R_fine",
        "R_fine5",
        "R_fine_raw",
        "R_pool_fine",
        "R_climb",
        "R_smooth",
        "R_zc0.25",
        "R_zc0.5",
        "R_zc1.0",
        "R_c0.02",
        "R_c0.05",
        "R_c0.1",
    ):
        v = np.array([r.get(c, np.nan) for r in rows])
        print(f"{c:10s} median {np.nanmedian(v):.2f} mean {np.nanmean(v):.2f} >=0.85 {(v >= 0.85).sum()} of {len(v)}")


if __name__ == "__main__":
    main(sys.argv[1])


def captures(folder: str, dedup_deg: float = 10.5, ks=(1, 2, 4, 8, 16)) -> None:
    """What K verification captures would buy: the field's K best distinct feasible stage-1
    candidates (no two within ``dedup_deg``), each captured and scored by the teacher, the best
    kept; teacher and evaluator of that pick, normalised."""
    out = {k: [] for k in ks}
    oute = {k: [] for k in ks}
    for p in sorted(glob.glob(f"{folder}/*_[0-9].npz")):
        d = load(p)
        o = d["meta"]["oracle"]
        nt = (d["pool_teacher"] - o["mean_teacher"]) / (o["best_teacher"] - o["mean_teacher"])
        ne = (d["pool_evaluator"] - o["mean_evaluator"]) / (o["best_evaluator"] - o["mean_evaluator"])
        obj = objective(d["pool_field"], d["pool_cov"])
        kept = []
        for i in np.argsort(-obj):
            if kept and deg(d["pool_params"][i], d["pool_params"][kept]).min() < dedup_deg:
                continue
            kept.append(int(i))
        row = []
        for k in ks:
            top = kept[:k]
            j = top[int(np.argmax(d["pool_teacher"][top]))]
            out[k].append(nt[j])
            oute[k].append(ne[j])
            row.append(f"{nt[j]:.2f}/{ne[j]:.2f}")
        print(d["meta"]["scene"], d["meta"]["seed"], " ".join(row))
    for k in ks:
        v, e = np.array(out[k]), np.array(oute[k])
        print(
            f"K={k:2d} teacher median {np.median(v):.2f} mean {v.mean():.2f} >=0.85 {(v >= 0.85).sum()}/{len(v)}"
            f"  evaluator median {np.median(e):.2f} >=0.85 {(e >= 0.85).sum()}"
        )


def summary_table(folder: str) -> None:
    """The table of docs/results/framing_quality_dev.md."""
    cols = [("case", "case"), ("subject", "subject"), ("pick", "pick"), ("pick_e", "pick (evaluator)"),
            ("d_pick_oracle", "pick to oracle, deg"), ("best_near_pick", "best within 2.5 deg of the pick"),
            ("rough_2p5", "truth step 2.5 deg"), ("pool_n", "pool"), ("d_pool_oracle", "pool to oracle, deg"),
            ("pool_best", "pool's best"), ("lift_kept", "lift keeps"), ("lift_best", "lift's best"),
            ("field_rank_oracle", "field's rank of the oracle"), ("lift_n", "of"), ("sp_field_t", "field~teacher"),
            ("sp_t_e", "teacher~evaluator"), ("e_at_t_top10", "evaluator at teacher's top 10 %"),
            ("thirds", "thirds"), ("centre", "centre"), ("R_fine", "field's best, 2.5 deg feasible grid"),
            ("R_climb", "field hill-climb from the pick")]  # fmt: skip
    rows = [case_figures(load(p)) for p in sorted(glob.glob(f"{folder}/*_[0-9].npz"))]
    print("| " + " | ".join(h for _, h in cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        cells = []
        for c, _ in cols:
            v = r.get(c, float("nan"))
            cells.append(f"{v:.2f}" if isinstance(v, float) else str(v))
        print("| " + " | ".join(cells) + " |")
    cells = []
    for c, _ in cols[2:]:
        cells.append(f"{np.nanmedian([float(r.get(c, np.nan)) for r in rows]):.2f}")
    print("| **median** | | " + " | ".join(cells) + " |")
    for at in ("thirds", "centre"):
        moved = [r["case"] for r in rows if abs(r[at] - r["pick"]) > 1e-6]
        print(at, "changed the pick in", len(moved), "cases:", moved)


def local(folder: str, covers=(0.9, 0.0)) -> None:
    """The local polish (``framing_local_dump.py``): around the pick, the view the warped photos
    score highest among those covered at least C (the pick always counts); its teacher and
    evaluator, normalised, against the pick's."""
    res = {c: [] for c in covers}
    base, held = [], {c: 0 for c in covers}
    for p in sorted(glob.glob(f"{folder}/*_[0-9].local.npz")):
        z = np.load(p)
        d = load(p.replace(".local.npz", ".npz"))
        o = d["meta"]["oracle"]
        nt = (z["teacher"] - o["mean_teacher"]) / (o["best_teacher"] - o["mean_teacher"])
        i0 = int(np.argmin(deg(z["params"], z["pick"])))  # the pick itself (offset 0)
        base.append(nt[i0])
        line = [
            f"{d['meta']['scene']}/{d['meta']['seed']}: pick {nt[i0]:.2f} (cover {z['cover'][i0]:.2f}),"
            f" best local {nt.max():.2f}, n {len(nt)}, warped~teacher {spearman(z['warped'], z['teacher']):.2f},"
            f" field~teacher {spearman(z['field'], z['teacher']):.2f}"
        ]
        for c in covers:
            ok = (z["cover"] >= c) & np.isfinite(z["warped"])
            ok[i0] = True
            j = int(np.argmax(np.where(ok, np.nan_to_num(z["warped"], nan=-np.inf), -np.inf)))
            res[c].append(nt[j])
            held[c] += bool(z["true"][j])
            line.append(f"C={c}: {nt[j]:.2f} ({deg(z['params'][j], z['pick']):.1f} deg)")
        print(" ".join(line))
    b = np.array(base)
    print(f"pick: median {np.median(b):.2f} mean {b.mean():.2f} >=0.85 {(b >= 0.85).sum()}/{len(b)}")
    for c in covers:
        v = np.array(res[c])
        print(
            f"C={c}: median {np.median(v):.2f} mean {v.mean():.2f} >=0.85 {(v >= 0.85).sum()}/{len(v)} "
            f"held {held[c]}/{len(v)}; lost from >=0.85: {int(((b >= 0.85) & (v < 0.85)).sum())}; "
            f"up {int((v > b + 0.01).sum())}, down {int((v < b - 0.01).sum())}"
        )
