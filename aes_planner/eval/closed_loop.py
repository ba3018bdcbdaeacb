"""Closed-loop evaluation: how good the views a closed loop ended on are, on a simulated scene
where ground truth exists at every pose (``aes-planner demo``'s ``summary.json`` and ``report.png``).

* :func:`true_scores`: the teacher's scores of ground-truth renders at poses;
* :func:`score_map`: ground-truth scores over a rig's pan x tilt grid;
* :func:`evaluate_run`: a finished run scored against the oracle
  (:func:`aes_planner.search.oracle_search`, exhaustive on ground truth) and normalised by
  :func:`aes_planner.search.normalized`: ``(s - mean random) / (oracle - mean random)``, the mean
  over the oracle's random poses (the platform's sampler,
  :func:`~aes_planner.search.space.random_poses`), as ``eval search`` does.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from pathlib import Path

import numpy as np
import torch

from aes_planner.geometry.pantilt import PanTilt
from aes_planner.messages import to_jsonable
from aes_planner.paths import output_in
from aes_planner.platform import RigPlatform
from aes_planner.search import normalized, oracle_search

log = logging.getLogger(__name__)

__all__ = ["evaluate_run", "score_map", "true_scores", "write_report"]


def true_scores(source, teacher, cam2world: np.ndarray, batch: int = 16) -> np.ndarray:  # [N, 4, 4] -> [N]
    """The teacher's scores of the source's ground-truth renders at ``cam2world``."""
    poses = np.asarray(cam2world, dtype=np.float64).reshape(-1, 4, 4)
    out = []
    for i in range(0, len(poses), batch):
        img = torch.from_numpy(source.render_rgb(poses[i : i + batch])).permute(0, 3, 1, 2)  # [b, 3, H, W]
        with torch.no_grad():
            out.append(teacher.score(img).double().numpy())
    return np.concatenate(out) if out else np.zeros(0)


def score_map(source, teacher, rig: PanTilt, n_pan: int = 31, n_tilt: int = 11) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth scores on a pan x tilt grid covering the limits: (joints [T, P, 2], scores [T, P])."""
    joints = rig.joint_grid(n_pan, n_tilt, margin=0.0)  # [T*P, 2] pan fastest
    scores = true_scores(source, teacher, rig.forward(joints[:, 0], joints[:, 1]))
    return joints.reshape(n_tilt, n_pan, 2), scores.reshape(n_tilt, n_pan)


def evaluate_run(planner, scene: str, kind: str, out: Path, loop_s: float) -> dict:
    """Score a finished closed loop (a :class:`~aes_planner.node.planner.PlannerNode` on the sim
    scene ``scene``) and write ``summary.json``'s figures, ``suggestions.json``, ``captures.json``
    and ``report.png`` into ``out``; returns the summary (``kind``: the platform kind run)."""
    from aes_planner.sim import SimSource

    out.mkdir(parents=True, exist_ok=True)
    source = SimSource(scene, supersample=2)
    teacher = planner.teacher
    platform = planner.platform if planner.platform is not None else source.platform
    platform = dataclasses.replace(platform, intrinsics=source.platform.intrinsics)  # the renders' camera
    caps = [c for c in planner.captures if math.isfinite(c.score)]
    if not caps:
        from aes_planner.graph import NodeError

        raise NodeError(
            f"the planner captured nothing (state {planner.state}) within the run; see the log above, or give it "
            "more time (--timeout)"
        )
    poses = np.stack([_true_pose(platform, c) for c in caps])  # [M, 4, 4]
    truth = true_scores(source, teacher, poses)  # [M]
    best_oracle, oracle_c2w, extras = oracle_search(source, teacher, platform)
    rand = float(extras["mean_random"])  # the oracle's random poses: the platform's sampler
    final_i = len(caps) - 1 if caps[-1].kind == "settle" else int(np.argmax([c.score for c in caps]))
    initial, final = float(truth[0]), float(truth[final_i])
    summary = {
        "scene": scene,
        "mode": kind,
        "state": planner.state,
        "initial": round(initial, 4),
        "final": round(final, 4),
        "oracle": round(max(best_oracle, final), 4),
        "random_mean": round(rand, 4),
        "normalized": round(normalized(final, max(best_oracle, final), rand), 4),
        "initial_normalized": round(normalized(initial, max(best_oracle, final), rand), 4),
        "moves": planner.moves,
        "explore_captures": sum(c.kind == "explore" for c in caps),
        "polish_captures": sum(c.kind == "polish" for c in caps),
        "verify_captures": sum(c.kind == "verify" for c in caps),
        "captures": len(caps),
        "loop_s": round(loop_s, 2),
        "time_s": None,
        "initial_cam2world": poses[0].tolist(),
        "final_cam2world": poses[final_i].tolist(),
        "oracle_cam2world": np.asarray(oracle_c2w).tolist(),
        "scorer": planner.config.scorer,
        "preset": planner.config.preset,
    }
    if caps[final_i].pan_rad is not None:
        summary["final_pan_deg"] = round(math.degrees(caps[final_i].pan_rad), 3)
        summary["final_tilt_deg"] = round(math.degrees(caps[final_i].tilt_rad), 3)
    output_in(out, "suggestions.json").write_text(json.dumps([to_jsonable(s) for s in planner.suggestions], indent=1))
    output_in(out, "captures.json").write_text(
        json.dumps(
            [
                {
                    "kind": c.kind,
                    "stamp_s": c.stamp_s,
                    "captured_score": c.score,
                    "true_score": float(t),
                    "predicted": c.predicted,
                    "pan_rad": c.pan_rad,
                    "tilt_rad": c.tilt_rad,
                    "cam2world": p.tolist(),
                }
                for c, t, p in zip(caps, truth, poses)
            ],
            indent=1,
        )
    )
    try:
        write_report(
            output_in(out, "report.png"),
            caps,
            truth,
            source,
            teacher,
            platform,
            oracle_c2w,
            best_oracle,
            extras,
        )
    except Exception as exc:  # the figures must not lose the measurement
        log.warning("report image failed: %s", exc)
    return summary


def _true_pose(platform, cap) -> np.ndarray:  # -> [4, 4]
    """Where a capture looked: a rig's joints through its kinematics, else the frame's pose."""
    if cap.pan_rad is not None:  # joints: a rig's capture
        return platform.kinematics.forward(cap.pan_rad, cap.tilt_rad)
    return cap.cam2world


def write_report(path, caps, truth, source, teacher, platform, oracle_c2w, oracle_score, extras) -> None:
    """``report.png``: the inputs, each move's view, a rig's pan x tilt ground-truth score map with
    the path taken, and the final view beside the oracle's best."""
    import cv2

    tile_w = 192

    def tile(img_rgb: np.ndarray, label: str) -> np.ndarray:
        h = int(round(img_rgb.shape[0] * tile_w / img_rgb.shape[1]))
        t = cv2.resize(img_rgb, (tile_w, h), interpolation=cv2.INTER_AREA)
        t = cv2.copyMakeBorder(t, 0, 18, 0, 0, cv2.BORDER_CONSTANT, value=(255, 255, 255))
        cv2.putText(t, label, (3, h + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
        return t

    def row(tiles: list[np.ndarray], title: str) -> np.ndarray:
        if not tiles:
            return np.zeros((0, 0, 3), np.uint8)
        h = max(t.shape[0] for t in tiles)
        tiles = [
            cv2.copyMakeBorder(t, 0, h - t.shape[0], 0, 4, cv2.BORDER_CONSTANT, value=(255, 255, 255)) for t in tiles
        ]
        body = np.concatenate(tiles, axis=1)
        head = np.full((20, body.shape[1], 3), 255, np.uint8)
        cv2.putText(head, title, (3, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        return np.concatenate([head, body], axis=0)

    inputs = [
        tile(c.image, f"{c.kind} {t:.3f}")
        for c, t in zip(caps, truth)
        if c.kind in ("initial", "explore") and c.image is not None
    ]
    moves = [
        tile(c.image, f"move {i + 1}: {t:.3f}")
        for i, (c, t) in enumerate((c, t) for c, t in zip(caps, truth) if c.kind == "move")
        if c.image is not None
    ]
    final_i = len(caps) - 1 if caps[-1].kind == "settle" else int(np.argmax(truth))
    final_img = (source.render_rgb(_true_pose(platform, caps[final_i])[None])[0] * 255).astype(np.uint8)
    oracle_img = (source.render_rgb(np.asarray(oracle_c2w)[None])[0] * 255).astype(np.uint8)
    last = [tile(final_img, f"final {truth[final_i]:.3f}"), tile(oracle_img, f"oracle {oracle_score:.3f}")]
    if isinstance(platform, RigPlatform):
        rig = platform.kinematics
        if "grid_scores" in extras and "grid_joints" in extras:
            joints, scores = np.asarray(extras["grid_joints"]), np.asarray(extras["grid_scores"])
        elif "grid_scores" in extras and "pan_values" in extras and "tilt_values" in extras:
            pans, tilts = np.asarray(extras["pan_values"]), np.asarray(extras["tilt_values"])
            scores = np.asarray(extras["grid_scores"]).reshape(len(tilts), len(pans))
            joints = np.stack(np.meshgrid(pans, tilts), -1)
        else:
            joints, scores = score_map(source, teacher, rig, 25, 9)
        last.insert(0, _score_map_image(rig, joints, scores, caps, 2 * tile_w))
    rows = [
        row(inputs, "inputs: initial view and exploration captures (true score)"),
        row(moves, "moves: captured view (true score)"),
        row(last, "pan x tilt ground-truth score map with the path; final view; the oracle's best"),
    ]
    rows = [r for r in rows if r.size]
    width = max(r.shape[1] for r in rows)
    rows = [
        cv2.copyMakeBorder(r, 0, 6, 0, width - r.shape[1], cv2.BORDER_CONSTANT, value=(255, 255, 255)) for r in rows
    ]
    sheet = np.concatenate(rows, axis=0)
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))


def _score_map_image(rig, joints: np.ndarray, scores: np.ndarray, caps, width: int) -> np.ndarray:
    """Scores [T, P] (tilt rows bottom-up) as a colour map, the captures' path drawn over it."""
    import cv2

    (plo, phi), (tlo, thi) = rig.pan_limits_rad, rig.tilt_limits_rad
    lo, hi = float(scores.min()), float(scores.max())
    norm = ((scores - lo) / max(hi - lo, 1e-9) * 255).astype(np.uint8)[::-1]  # top row = highest tilt
    height = max(int(width * (thi - tlo) / max(phi - plo, 1e-9)), 60)
    img = cv2.applyColorMap(cv2.resize(norm, (width, height), interpolation=cv2.INTER_NEAREST), cv2.COLORMAP_VIRIDIS)
    img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    def px(pan, tilt):
        return (int((pan - plo) / (phi - plo) * (width - 1)), int((thi - tilt) / (thi - tlo) * (height - 1)))

    pts = [px(c.pan_rad, c.tilt_rad) for c in caps if c.pan_rad is not None]
    for a, b in zip(pts, pts[1:]):
        cv2.line(img, a, b, (255, 255, 255), 1, cv2.LINE_AA)
    for p, c in zip(pts, [c for c in caps if c.pan_rad is not None]):
        colour = {
            "initial": (255, 255, 255),
            "explore": (200, 200, 200),
            "move": (255, 80, 80),
            "polish": (255, 200, 0),
            "verify": (80, 200, 255),
            "settle": (255, 0, 0),
        }.get(c.kind, (255, 255, 255))
        cv2.circle(img, p, 4 if c.kind != "settle" else 6, colour, -1 if c.kind != "settle" else 2, cv2.LINE_AA)
    return img
