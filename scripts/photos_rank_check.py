"""How well each estimate ranks a hand-held search's candidates, on scenes textured with the
shipped CC0 photographs (the set-up of ``scripts/photos_suggest_check.py``, in one process): the
field, the teacher on renders of the reconstruction (48 and 128 px wide), each as is and
anchored at the nearest photo (its error there, the teacher on the real photo minus the
estimate, added), and the mean of the anchored field and renders. For each: the true score
(teacher on the simulator's render in the true frame) of the candidate it ranks first, and its
rank correlation with the true scores over all candidates.

    .venv/bin/python scripts/photos_rank_check.py SEED      # one JSON line, prefixed ROW
"""

import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import cv2  # noqa: F401  (before pycolmap, always)
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from photos_suggest_check import score

from aes_planner.bench.photos import render_photo_set
from aes_planner.dataset import load_dataset
from aes_planner.photos import pose_errors, pose_images
from aes_planner.platform import platform_from_meta
from aes_planner.search import SearchConfig, build_search_scorer, search_views
from aes_planner.sim import load_scene
from aes_planner.teachers import get_teacher

seed = int(sys.argv[1])
out = Path(tempfile.mkdtemp())
images, truth, scene_file = render_photo_set(out / "set", 10, (640, 480), seed=seed)
res = pose_images(images, out / "posed")
data = load_dataset(out / "posed")
idx = [int(n[4:8]) for n in data.meta["photos"]]
err = pose_errors(data.cam2worlds(), truth[idx])


k = data.frames[0].intrinsics
platform = platform_from_meta(data.meta, k)
cfg = SearchConfig.preset("balanced", mode=platform.kind)
field = build_search_scorer("field", data.frames, cfg)
rgbs = {w: build_search_scorer("rgb", data.frames, dataclasses.replace(cfg, render_width_px=w)) for w in (48, 128)}
result = search_views(field, data.cam2worlds(), platform, dataclasses.replace(cfg, top_k=64))
cands = np.stack([s.cam2world for s in result.suggestions])
photos = data.cam2worlds()
teacher = get_teacher()
with torch.no_grad():
    batch = torch.from_numpy(np.stack([f.image for f in data.frames])).permute(0, 3, 1, 2).float() / 255.0
    real = teacher.score(batch).double().numpy()
    f_c = field.score(torch.as_tensor(cands)).score.double().numpy()
    f_p = field.score(torch.as_tensor(photos)).score.double().numpy()
    r = {
        w: (
            s.score_batched(torch.as_tensor(cands), 64).score.double().numpy(),
            s.score_batched(torch.as_tensor(photos), 64).score.double().numpy(),
        )
        for w, s in rgbs.items()
    }
near = np.array([int(np.argmin(np.linalg.norm(photos[:, :3, 3] - c[:3, 3], axis=1))) for c in cands])
scene = load_scene(scene_file, allow_outside=True)
true_c = score(teacher, scene, np.stack([err.to_true(c) for c in cands]))
true_in = score(teacher, scene, truth)
rank = {"field": f_c, "field_anch": f_c + (real - f_p)[near]}
for w, (rc, rp) in r.items():
    rank[f"rgb{w}"] = rc
    rank[f"rgb{w}_anch"] = rc + (real - rp)[near]
    rank[f"mix{w}"] = 0.5 * (rank["field_anch"] + rank[f"rgb{w}_anch"])
row = {
    "seed": seed,
    "best_input": round(float(true_in.max()), 3),
    "best_cand": round(float(true_c.max()), 3),
    "n": len(cands),
}
for name, v in rank.items():
    row[name] = round(float(true_c[int(np.argmax(v))]), 3)
    row[name + "_rho"] = round(float(np.corrcoef(np.argsort(np.argsort(v)), np.argsort(np.argsort(true_c)))[0, 1]), 2)
print("ROW", json.dumps(row), flush=True)
