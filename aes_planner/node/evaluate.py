"""Measuring a closed-loop run on a simulated scene: true teacher scores of ground-truth renders.

* :func:`true_scores`: the teacher's scores of ground-truth renders at poses;
* :func:`random_poses`: feasible random poses (rig: uniform joints; free: uniform in the box,
  yaw uniform, pitch uniform in [-60, 30] deg), seeded;
* :func:`oracle`: the best feasible view, from the search's oracle
  (``aes_planner.search.oracle_search``, exhaustive on ground truth) when it is installed, else
  a pan x tilt grid (rig) or a dense random sample (free) here;
* :func:`normalized`: ``(s - mean random) / (oracle - mean random)``: 1 = optimal, 0 = chance.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import torch

from aes_planner.geometry.pantilt import PanTilt
from aes_planner.geometry.poses import view_to_cam2world

log = logging.getLogger(__name__)

__all__ = ["normalized", "oracle", "random_poses", "score_map", "true_scores"]


def true_scores(source, teacher, cam2world: np.ndarray, batch: int = 16) -> np.ndarray:  # [N, 4, 4] -> [N]
    poses = np.asarray(cam2world, dtype=np.float64).reshape(-1, 4, 4)
    out = []
    for i in range(0, len(poses), batch):
        img = torch.from_numpy(source.render_rgb(poses[i : i + batch])).permute(0, 3, 1, 2)  # [b, 3, H, W]
        with torch.no_grad():
            out.append(teacher.score(img).double().numpy())
    return np.concatenate(out) if out else np.zeros(0)


def random_poses(platform, n: int, seed: int = 0) -> np.ndarray:  # -> [n, 4, 4]
    rng = np.random.default_rng(seed)
    if platform.kind == "rig":
        rig = PanTilt(platform.rig)
        (plo, phi), (tlo, thi) = rig.pan_limits_rad, rig.tilt_limits_rad
        return rig.forward(rng.uniform(plo, phi, n), rng.uniform(tlo, thi, n))
    box = platform.drone
    xyz = rng.uniform(box.bounds_min_m, box.bounds_max_m, (n, 3))
    yaw = rng.uniform(-math.pi, math.pi, n)
    pitch = rng.uniform(math.radians(-60), math.radians(30), n)
    views = np.concatenate([xyz, yaw[:, None], pitch[:, None]], axis=1)
    return view_to_cam2world(torch.as_tensor(views)).numpy()


def score_map(source, teacher, rig: PanTilt, n_pan: int = 31, n_tilt: int = 11) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth scores on a pan x tilt grid covering the limits: (joints [T, P, 2], scores [T, P])."""
    joints = rig.joint_grid(n_pan, n_tilt, margin=0.0)  # [T*P, 2] pan fastest
    scores = true_scores(source, teacher, rig.forward(joints[:, 0], joints[:, 1]))
    return joints.reshape(n_tilt, n_pan, 2), scores.reshape(n_tilt, n_pan)


def oracle(source, teacher, platform) -> tuple[float, np.ndarray, dict]:
    """(best score, its cam2world [4, 4], extras) of the best feasible view."""
    try:
        from aes_planner.search import oracle_search
    except ImportError:
        oracle_search = None
    if oracle_search is not None:
        best, c2w, extras = oracle_search(source, teacher, platform)
        return float(best), np.asarray(c2w, dtype=np.float64), dict(extras or {})
    log.warning("aes_planner.search.oracle_search is not installed; using a local grid oracle")
    if platform.kind == "rig":
        rig = PanTilt(platform.rig)
        joints, scores = score_map(source, teacher, rig, 37, 13)
        i = np.unravel_index(int(np.argmax(scores)), scores.shape)
        pan, tilt = joints[i]
        # local refinement: a finer grid around the best cell
        dp = (rig.pan_limits_rad[1] - rig.pan_limits_rad[0]) / 36
        dt = (rig.tilt_limits_rad[1] - rig.tilt_limits_rad[0]) / 12
        fine = np.stack(np.meshgrid(np.linspace(-dp, dp, 5) + pan, np.linspace(-dt, dt, 5) + tilt), -1).reshape(-1, 2)
        fine = np.array([rig.clamp(p, t) for p, t in fine])
        fs = true_scores(source, teacher, rig.forward(fine[:, 0], fine[:, 1]))
        j = int(np.argmax(fs))
        best = max(float(scores[i]), float(fs[j]))
        c2w = rig.forward(*fine[j]) if fs[j] >= scores[i] else rig.forward(pan, tilt)
        return best, c2w, {"grid_joints": joints, "grid_scores": scores}
    poses = random_poses(platform, 384, seed=12345)
    scores = true_scores(source, teacher, poses)
    j = int(np.argmax(scores))
    return float(scores[j]), poses[j], {}


def normalized(score: float, oracle_score: float, random_mean: float) -> float:
    span = oracle_score - random_mean
    return float((score - random_mean) / span) if span > 1e-9 else 0.0
