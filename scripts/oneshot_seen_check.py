"""Are the cells the field gets wrong unseen by every input, or holes of the reconstruction?
(dev scenes only; issue 41 item 4, docs/results/oneshot/rank_diagnosis.md)

For the ``TOP`` best stage-1 candidates of balanced (as ``scripts/oneshot_rank_check.py``), each
pixel of the ground-truth render is "seen" when its true 3D point (ground-truth depth; a pixel
without depth: its direction) falls inside an input view and is not hidden there (the input's
ground-truth depth within 5 % + 5 cm). Per teacher cell: the share of seen pixels against the
reconstruction's alpha. The teacher's head on hybrid maps (truth in some cells, the field's in
the rest) says which cells carry the ranking error: ``hole`` = cells the inputs saw but the
reconstruction left empty (alpha < 0.5), ``unseen`` = cells no input saw.

    .venv/bin/python scripts/oneshot_seen_check.py indoor:500,textured:indoor:510 0
"""

import json
import sys

import numpy as np
import torch
import torch.nn.functional as F
from oneshot_dev_check import dev_cases  # scripts/ is on the path when run

from aes_planner.search import GroundTruthScorer, SearchConfig, build_search_scorer, normalized, search_views
from aes_planner.teachers import get_teacher

TOP = 24


def seen_mask(target_pose, target_depth, frames, k) -> np.ndarray:  # -> [H, W] bool
    d = np.asarray(target_depth, np.float64)
    uv = np.stack(np.meshgrid(np.arange(k.width) + 0.5, np.arange(k.height) + 0.5), -1)  # [H, W, 2]
    sky = d <= 0
    p_cam = k.unproject(uv, np.where(sky, 1e4, d))  # far along the ray where there is no depth
    p_w = p_cam @ target_pose[:3, :3].T + target_pose[:3, 3]
    seen = np.zeros(d.shape, bool)
    for f in frames:
        w2c = np.linalg.inv(f.cam2world)
        q = p_w @ w2c[:3, :3].T + w2c[:3, 3]
        z = q[..., 2]
        ok = z > 1e-3
        uvq = f.intrinsics.project(np.where(ok[..., None], q, 1.0))
        inside = ok & (uvq[..., 0] >= 0) & (uvq[..., 0] < f.width) & (uvq[..., 1] >= 0) & (uvq[..., 1] < f.height)
        ui = np.clip(uvq[..., 0].astype(int), 0, f.width - 1)
        vi = np.clip(uvq[..., 1].astype(int), 0, f.height - 1)
        di = f.depth_m[vi, ui]
        vis = np.where(sky, di <= 0, (di > 0) & (np.abs(di - z) <= 0.05 * z + 0.05))
        seen |= inside & vis
    return seen


def main(scenes, seeds):
    teacher = get_teacher()
    for spec, case in dev_cases(scenes, teacher):
        source, platform, inputs, frames = case.source, case.platform, case.inputs, case.frames
        o_score, o_extra = case.oracle_score, case.oracle_extra
        m = o_extra["mean_random"]
        k = platform.intrinsics
        for seed in seeds:
            scfg = SearchConfig.preset("balanced", mode="rig", seed=seed)
            field = build_search_scorer("field", frames, scfg, teacher)
            result = search_views(field, inputs, platform, scfg)
            obj = np.asarray(result.candidates_score, float) - scfg.coverage_penalty * np.maximum(
                0.0, scfg.coverage_min - np.asarray(result.candidates_coverage, float)
            )
            idx = np.argsort(-obj, kind="stable")[:TOP]
            poses = result.candidates_cam2world[idx]
            with torch.no_grad():
                fmaps, _ = field.render_maps(torch.as_tensor(poses))
                gt = teacher.features(GroundTruthScorer(source, teacher).render(torch.as_tensor(poses)))
                rgb = build_search_scorer("rgb", frames, scfg.__class__.preset("balanced", mode="rig", seed=seed,
                                          render_width_px=k.width), teacher)  # fmt: skip
                alpha = rgb.render(torch.as_tensor(poses))[1]  # [P, H, W]
            seen = np.stack([seen_mask(p, source.capture(p).depth_m, frames, k) for p in poses])  # [P, H, W]
            n = teacher.feature_size
            cell_a = F.adaptive_avg_pool2d(alpha[:, None].float(), n)[:, 0]
            cell_s = F.adaptive_avg_pool2d(torch.from_numpy(seen[:, None].astype(np.float32)), n)[:, 0]
            recon = (cell_a >= 0.5)[:, None].expand_as(fmaps)
            truly = (cell_s >= 0.5)[:, None].expand_as(fmaps)
            hole = truly & ~recon
            unseen = ~truly
            truth = teacher.head(gt).double().numpy()
            heads = {
                "field": fmaps,
                "fix_hole": torch.where(hole, gt, fmaps),
                "fix_unseen": torch.where(unseen, gt, fmaps),
                "fix_recon_seen": torch.where(recon, gt, fmaps),
                "fix_all_empty": torch.where(~recon, gt, fmaps),
            }
            row = {"scene": spec, "seed": seed,
                   "cells_alpha": float((cell_a >= 0.5).float().mean()), "cells_seen": float((cell_s >= 0.5).float().mean()),
                   "cells_hole": float(hole[:, 0].float().mean()), "cells_recon_not_seen": float((recon & unseen)[:, 0].float().mean()),
                   "truth": [normalized(t, o_score, m) for t in truth]}  # fmt: skip
            for name, mp in heads.items():
                s = teacher.head(mp).double().numpy()
                row[name] = s.tolist()
            print("ROW", json.dumps(row), flush=True)


if __name__ == "__main__":
    torch.set_grad_enabled(True)
    main(sys.argv[1].split(","), [int(s) for s in sys.argv[2].split(",")])
