"""How well refining at the best photo does (:mod:`aes_planner.photos.refine`), on scenes textured
with the shipped CC0 photographs (the set-up of ``scripts/photos_suggest_check.py``, in one
process): every candidate of a wide grid (turns up to ``--turn`` deg, steps forward up to 0.3 of
the subject's distance) is scored on the photos warped into it and, mapped back into the true
frame, on the simulator's render; for each radius (largest turn) and forward step, the pick's
true score against the best input photo's true render, and the estimate's rank correlation.

    .venv/bin/python scripts/photos_refine_check.py SEED [--turn 10]   # one JSON line, prefixed ROW
"""

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import cv2  # before pycolmap, always
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from photos_suggest_check import score

from aes_planner.bench.photos import render_photo_set
from aes_planner.dataset import load_dataset
from aes_planner.geometry.poses import cam2world_to_view
from aes_planner.images import MAX_WORKING_SIDE_PX
from aes_planner.photos import pose_errors, pose_images
from aes_planner.photos.refine import RefineConfig, photo_composite, refine_at_best_photo, subject_distance
from aes_planner.platform import HandHeldPlatform
from aes_planner.sim import load_scene
from aes_planner.teachers import get_teacher

ap = argparse.ArgumentParser()
ap.add_argument("seed", type=int)
ap.add_argument("--turn", type=float, default=10.0)
ap.add_argument("--around", type=int, default=2, help="refine at this many of the best photos")
ap.add_argument("--keep-roll", action="store_true", help="turn the photos as taken (RefineConfig.keep_roll)")
ap.add_argument("--turns", action="store_true", help="also the best photo as taken turned on the spot (the fall-back)")
ap.add_argument(
    "--planes",
    default="0.7,1.4",
    help="also score each candidate through planes at these multiples of the subject's distance",
)
args = ap.parse_args()
out = Path(tempfile.mkdtemp())
images, truth, scene_file = render_photo_set(out / "set", 10, (640, 480), seed=args.seed)
pose_images(images, out / "posed")
data = load_dataset(out / "posed", max_side_px=MAX_WORKING_SIDE_PX)
idx = [int(n[4:8]) for n in data.meta["photos"]]
err = pose_errors(data.cam2worlds(), truth[idx])


photos = data.cam2worlds()
k = data.frames[0].intrinsics
platform = HandHeldPlatform.around_photos(k, photos)
teacher = get_teacher()
cfg = RefineConfig(
    max_turn_deg=args.turn,
    turn_step_deg=2.0,
    forward_fracs=(0.0, 0.1, 0.2, 0.3),
    around_best=args.around,
    keep_roll=args.keep_roll,
)
found = refine_at_best_photo(teacher, photos, [f.image for f in data.frames], k, cfg, platform)
cands, best, real_best = found.suggestions, found.best_photo, float(found.photo_scores.max())
scene = load_scene(scene_file, allow_outside=True)
true_in = score(teacher, scene, truth)
# the best photo's own pose mapped back through the similarity (what the fall-back "as taken" renders)
true_as_taken_sim = float(score(teacher, scene, err.to_true(photos[best])[None])[0])
true_c = score(teacher, scene, np.stack([err.to_true(c.cam2world) for c in cands]))
est = np.array([c.score for c in cands])
rows = []
for c, b in zip(cands, found.photo_of):
    base = cam2world_to_view(photos[b])
    dist = subject_distance(photos, int(b))
    v = cam2world_to_view(c.cam2world)
    step = float(np.linalg.norm(v[:3] - base[:3]))
    rows.append((math.degrees(v[3] - base[3]), math.degrees(v[4] - base[4]), step / dist if dist else 0.0))
rows = np.array(rows)  # [C, 3] turn, tilt (deg), forward fraction
# the same candidates warped through planes nearer and farther than the subject (how much each
# estimate leans on the plane's depth)
ww = cfg.work_width_px
h0, w0 = data.frames[0].image.shape[:2]
wh = max(8, round(ww * h0 / w0))
small = [cv2.resize(f.image, (ww, wh), interpolation=cv2.INTER_AREA) for f in data.frames]
kk = k.K.astype(np.float64).copy()
kk[0] *= ww / k.width
kk[1] *= wh / k.height
centres = photos[:, :3, 3]
plane_est = {}
for fac in [float(x) for x in args.planes.split(",") if x]:
    shots = []
    for c, b in zip(cands, found.photo_of):
        b = int(b)
        d = subject_distance(photos, b)
        fwd = photos[b, :3, 2]
        plane = None if d is None else (fwd, float(fwd @ photos[b, :3, 3]) + fac * d)
        xyz = c.cam2world[:3, 3]
        order = [b] + [int(j) for j in np.argsort(np.linalg.norm(centres - xyz, axis=1)) if j != b]
        shots.append(photo_composite(small, photos, kk, c.cam2world, order, plane)[0])
    vals = []
    for i in range(0, len(shots), 64):
        x = torch.from_numpy(np.stack(shots[i : i + 64])).permute(0, 3, 1, 2).float() / 255.0
        with torch.no_grad():
            vals.append(teacher.explain_map(teacher.features(x))["score"].double().numpy())
    plane_est[str(fac)] = np.concatenate(vals).tolist()
at_best = found.photo_of == best
dist = subject_distance(photos, best)
true_best_photo_pose = float(true_in[idx[best]])
res = {
    "seed": args.seed,
    "best_input": round(float(true_in.max()), 3),
    "best_photo_by_teacher_is_true_best": bool(idx[best] == int(np.argmax(true_in))),
    "true_at_teacher_best_photo": round(true_best_photo_pose, 3),
    "teacher_on_photo": round(real_best, 3),
    "subject_distance": dist,
    "n": len(cands),
    "rho_all": round(float(np.corrcoef(np.argsort(np.argsort(est)), np.argsort(np.argsort(true_c)))[0, 1]), 2),
    "best_cand": round(float(true_c.max()), 3),
    "by_radius": {},
}
for turn in (2, 4, 6, 8, 10):
    for fmax in (0.0, 0.1, 0.2, 0.3):
        sel = (np.abs(rows[:, 0]) <= turn + 1e-6) & (np.abs(rows[:, 1]) <= turn + 1e-6) & (rows[:, 2] <= fmax + 1e-6)
        sel &= at_best
        if not sel.any():
            continue
        i = np.flatnonzero(sel)[int(np.argmax(est[sel]))]
        res["by_radius"][f"t{turn}_f{fmax}"] = {
            "pick_true": round(float(true_c[i]), 3),
            "margin": round(float(true_c[i] - true_in.max()), 3),
            "pick_est": round(float(est[i]), 3),
            "pick": [round(float(x), 2) for x in rows[i]],
            "best_true_here": round(float(true_c[sel].max()), 3),
            "rho": round(
                float(np.corrcoef(np.argsort(np.argsort(est[sel])), np.argsort(np.argsort(true_c[sel])))[0, 1]), 2
            ),
        }
turns = {}
if args.turns:  # the fall-back's views: the best photo as taken (roll kept) turned and tilted on the spot
    tcfg = RefineConfig(max_turn_deg=args.turn, forward_fracs=(0.0,), around_best=1, keep_roll=True)
    tf = refine_at_best_photo(teacher, photos, [f.image for f in data.frames], k, tcfg, platform)
    base = cam2world_to_view(photos[best])
    turns = {
        "rows": [[math.degrees(cam2world_to_view(c.cam2world)[3] - base[3]),
                  math.degrees(cam2world_to_view(c.cam2world)[4] - base[4]), 0.0] for c in tf.suggestions],
        "est": [c.score for c in tf.suggestions],
        "own_cover": tf.own_cover.tolist(),
        "true": score(teacher, scene, np.stack([err.to_true(c.cam2world) for c in tf.suggestions])).tolist(),
    }  # fmt: skip
(out / "cands.json").write_text(
    json.dumps(
        {
            **{k: res[k] for k in ("seed", "best_input", "teacher_on_photo")},
            "photo_scores": found.photo_scores.tolist(),
            "true_inputs": true_in[idx].tolist(),
            "rows": rows.tolist(),
            "photo_of": found.photo_of.tolist(),
            "own_cover": found.own_cover.tolist(),
            "cover": [c.coverage for c in cands],
            "est": est.tolist(),
            "true": true_c.tolist(),
            "keep_roll": args.keep_roll,
            "turns": turns,
            "plane_est": plane_est,
            "true_as_taken_sim": true_as_taken_sim,
            "photos_c2w": photos.tolist(),
            "subject_dist": [subject_distance(photos, int(b)) for b in found.photo_of],
            "unit": data.meta.get("unit"),
        }
    )
)
print("ROW", json.dumps(res), flush=True)
print("CANDS", out / "cands.json")
