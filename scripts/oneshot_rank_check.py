"""Why the field mis-ranks its own best candidates (dev and validation scenes only; issue 41 item 4).

For each scene (rig, the survey sweep's 4 views, as ``aes-planner eval search``) and search seed,
balanced's stage-1 candidates are searched once, and a pool is taken from them: the ``TOP`` best
by the search's objective and ``TOP`` more drawn at random. Every pool view is scored by:

* ``field``: the field at the preset's render width (what the search ranks by);
* ``splat``: the splatted teacher map alone (the field without its decoder, same width);
* ``gt_w``: the teacher on the ground-truth render at the field's render width (width loss);
* ``gt``: the teacher on the ground-truth render at the scene's own width (the truth);
* ``rgb_w`` / ``rgb``: the teacher on the reconstruction's RGB render at both widths;
* ``hyb_seen`` / ``hyb_unseen``: the teacher's head on a map that is the truth's map where the
  inputs saw the cell (alpha >= 0.5) and the field's elsewhere, and the other way round: how much
  of the field's error lies in what the inputs saw (distillation) and what they did not
  (reconstruction of unseen regions);
* ``alpha``: the reconstruction's coverage of the view.

The maps (field, truth, the cells' alpha, the inputs' maps) go to OUT/SCENE_sSEED.npz. One JSON line per (scene, seed), prefixed ROW, with every array (pool order), and the truth
oracle-normalised. Scene specs as ``scripts/oneshot_dev_check.py`` (``textured:FAMILY:SEED[:PHOTO]``);
held-out scenes are refused.

    .venv/bin/python scripts/oneshot_rank_check.py indoor:500,textured:indoor:510 0,1,2 /tmp/rank_maps [PRESET]
    .venv/bin/python scripts/oneshot_rank_check.py --summary LOG...   # the table of the ROW lines
"""

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from oneshot_dev_check import dev_cases, use_model  # scripts/ is on the path when run

from aes_planner.eval.search import Judge
from aes_planner.field.common import render_intrinsics
from aes_planner.field.model import render_pooled
from aes_planner.field.splat import SplatScorer
from aes_planner.search import GroundTruthScorer, SearchConfig, build_search_scorer, normalized, search_views
from aes_planner.teachers import get_teacher
from aes_planner.teachers.evaluator import CompositionEvaluator

TOP = 24
SEEN_ALPHA = 0.5


def main(scenes: list[str], seeds: list[int], out: Path, preset: str = "balanced") -> None:
    teacher = get_teacher()
    evaluator = CompositionEvaluator()
    out.mkdir(parents=True, exist_ok=True)
    for spec, case in dev_cases(scenes, teacher):
        source, platform, inputs, frames = case.source, case.platform, case.inputs, case.frames
        o_score, o_extra = case.oracle_score, case.oracle_extra
        m = o_extra["mean_random"]
        judge = Judge(source, teacher, evaluator)
        for seed in seeds:
            scfg = SearchConfig.preset(preset, mode="rig", seed=seed)
            field = build_search_scorer("field", frames, scfg, teacher)
            result = search_views(field, inputs, platform, scfg)
            obj = np.asarray(result.candidates_score, float) - scfg.coverage_penalty * np.maximum(
                0.0, scfg.coverage_min - np.asarray(result.candidates_coverage, float)
            )
            order = np.argsort(-obj, kind="stable")
            rng = np.random.default_rng(seed)
            rest = order[TOP:]
            idx = np.concatenate([order[:TOP], rng.choice(rest, size=min(TOP, len(rest)), replace=False)])
            poses = torch.as_tensor(result.candidates_cam2world[idx])  # [P, 4, 4]
            row = {"scene": spec, "seed": seed, "preset": preset, "n_top": TOP, "obj": obj[idx].tolist()}
            width = scfg.render_width_px
            with torch.no_grad():
                fmaps, cov = field.render_maps(poses)  # [P, C, n, n], [P]
                row["field"] = teacher.head(fmaps).double().tolist()
                row["alpha"] = cov.tolist()
                splat = SplatScorer(field.inputs, teacher, field.config)
                row["splat"] = splat.score_batched(poses, 64).score.double().tolist()
                pooled, _ = render_pooled(field.model, field.gaussians, field.local_frame, poses, field.intrinsics)
                smaps = field.model.splat_maps(pooled)  # [P, C, n, n]: the decoder's starting point
                gt_img = GroundTruthScorer(source, teacher).render(poses)  # [P, 3, H, W] scene width
                gt_maps = teacher.features(gt_img)
                row["gt_raw"] = teacher.head(gt_maps).double().tolist()
                row["gt"] = [normalized(t, o_score, m) for t in row["gt_raw"]]
                k_w = render_intrinsics(platform.intrinsics, width)
                row["gt_w"] = teacher.score(GroundTruthScorer(source, teacher, k_w).render(poses)).double().tolist()
                for name, w in (("rgb_w", width), ("rgb", platform.intrinsics.width)):
                    rgb = build_search_scorer("rgb", frames, dataclasses.replace(scfg, render_width_px=w), teacher)
                    row[name] = rgb.score_batched(poses, 64).score.double().tolist()
                    if name == "rgb":
                        alpha = rgb.render(poses)[1]  # [P, H, W]
                # which teacher cells the inputs saw: the alpha pooled as the teacher pools the frame
                cell = F.adaptive_avg_pool2d(alpha[:, None].float(), teacher.feature_size)  # [P, 1, n, n]
                seen = (cell >= SEEN_ALPHA).expand_as(fmaps)
                row["cells_seen"] = seen[:, 0].float().mean((1, 2)).double().tolist()
                row["hyb_seen"] = teacher.head(torch.where(seen, gt_maps, fmaps)).double().tolist()
                row["hyb_unseen"] = teacher.head(torch.where(seen, fmaps, gt_maps)).double().tolist()
                err = (fmaps - gt_maps).pow(2).mean(1)  # [P, n, n]
                s = seen[:, 0]
                row["map_err_seen"] = (err * s).sum((1, 2)).div(s.sum((1, 2)).clamp_min(1)).double().tolist()
                row["map_err_unseen"] = (err * ~s).sum((1, 2)).div((~s).sum((1, 2)).clamp_min(1)).double().tolist()
            row["pick_gt"] = normalized(float(judge.measure(result.best.cam2world[None])[0][0]), o_score, m)
            name = spec.replace(":", "_").replace("/", "_")
            np.savez_compressed(
                out / f"{name}_s{seed}.npz",
                field=fmaps.numpy(), gt=gt_maps.numpy(), cell_alpha=cell[:, 0].numpy(),
                splat=smaps.numpy(),
                inputs=field.inputs.fmaps.numpy(), gt_norm=np.asarray(row["gt"]), gt_raw=np.asarray(row["gt_raw"]),
                o_score=o_score, mean_random=m,
            )  # fmt: skip
            print("ROW", json.dumps(row), flush=True)


def rank_corr(a, b) -> float:  # Spearman's rho (no ties in these scores)
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def summary(logs: list[str]) -> None:
    """The table of docs/results/oneshot/rank_diagnosis.md from the ROW lines of ``logs`` (or the
    rows of docs/results/oneshot/rank_*.jsonl): per
    predictor, Spearman with the truth over the pool, within the top and the random half, the
    truth (oracle-normalised) at its argmax over the top, and its mean error (score units)."""
    lines = [line.removeprefix("ROW ") for log in logs for line in open(log)]
    rows = [json.loads(line) for line in lines if line.startswith("{")]  # a log's ROW lines or a .jsonl
    print(f"{len(rows)} runs; the search's pick {np.mean([r['pick_gt'] for r in rows]):.3f}; "
          f"best of the top {np.mean([max(r['gt'][: r['n_top']]) for r in rows]):.3f}; "
          f"cells seen: top {np.mean([np.mean(r['cells_seen'][: r['n_top']]) for r in rows]):.2f}, "
          f"random {np.mean([np.mean(r['cells_seen'][r['n_top'] :]) for r in rows]):.2f}")  # fmt: skip
    print("| predictor | Spearman, pool | top | random | truth at its argmax in the top | error, top | error, random |")
    print("|---|---|---|---|---|---|---|")
    for k in ("obj", "field", "splat", "gt_w", "rgb_w", "rgb", "hyb_seen", "hyb_unseen"):
        f = []
        for r in rows:
            n, raw, v = r["n_top"], np.asarray(r["gt_raw"]), np.asarray(r[k])
            f.append([rank_corr(v, raw), rank_corr(v[:n], raw[:n]), rank_corr(v[n:], raw[n:]),
                      r["gt"][int(np.argmax(v[:n]))], np.mean(v[:n] - raw[:n]), np.mean(v[n:] - raw[n:])])  # fmt: skip
        m = np.mean(f, 0)
        err = "- | -" if k == "obj" else f"{m[4]:+.3f} | {m[5]:+.3f}"
        print(f"| {k} | {m[0]:.2f} | {m[1]:.2f} | {m[2]:.2f} | {m[3]:.3f} | {err} |")


if __name__ == "__main__":
    if sys.argv[1] == "--summary":
        summary(sys.argv[2:])
        raise SystemExit(0)
    torch.set_grad_enabled(True)
    for a in [a for a in sys.argv if a.startswith("--model=")]:  # search over another field checkpoint
        use_model(a.split("=", 1)[1])
        sys.argv.remove(a)
    preset = sys.argv[4] if len(sys.argv) > 4 else "balanced"
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")], Path(sys.argv[3]), preset)
