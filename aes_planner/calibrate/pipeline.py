"""The calibration runs behind ``aes-planner calibrate rig|verify``: capture, solve, report.

:func:`calibrate_rig` finds the board, plans and captures views, solves the rig
(:mod:`aes_planner.calibrate.rig`) and returns the calibrated :class:`PanTiltConfig` with a report;
:func:`estimate_latency` times the camera against the joint states from a continuous sweep;
:func:`verify_rig` re-projects the board from new joint poses with a calibrated rig.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import yaml

from aes_planner.calibrate.board import BoardSpec, detect
from aes_planner.calibrate.capture import CameraModel, ViewSource, board_in_world, collect, find_board, plan_views
from aes_planner.calibrate.rig import (
    FREE_PARAMETERS,
    UNOBSERVABLE,
    RigCalibrationError,
    fit_board_pose,
    reprojection_rms,
    rezero_tilt,
    seen_joints,
    solve_rig,
)
from aes_planner.config import to_dict
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.geometry.rig import PanTiltConfig

log = logging.getLogger(__name__)

__all__ = ["calibrate_rig", "estimate_latency", "latency_sweep_centre", "rig_yaml", "verify_rig"]


def _value(config: PanTiltConfig, name: str) -> float:
    field, index = name[:-3], int(name[-2])
    return float(getattr(config, field)[index]) * (1000.0 if field.endswith("_m") else 1.0)


def calibrate_rig(
    source: ViewSource,
    nominal: PanTiltConfig,
    board: BoardSpec,
    n_views: int = 30,
    zero_offsets: str = "mount",
    tilt_direction: int = 1,
    seed: int = 0,
) -> tuple[PanTiltConfig, dict]:
    """Calibrate ``source``'s rig from the ``nominal`` guess; returns the rig and the JSON report."""
    if not board.orientation_unique:
        raise RigCalibrationError(
            f"--board {board}: a chessboard with {board.cols}x{board.rows} inner corners looks the same turned by 180 deg, "
            "so views cannot agree on which corner is which; use one with an even and an odd count (e.g. 9x6) or ChArUco"
        )
    t0 = time.monotonic()
    pan, tilt, found = find_board(source, nominal, board)
    board2world = board_in_world(source.camera, nominal, pan, tilt, found)
    joints = plan_views(source.camera, nominal, board, board2world, n_views, seed=seed)
    collected = collect(source, board, joints)
    t_capture = time.monotonic() - t0
    solution = solve_rig(collected.observations, nominal)
    config = solution.config
    report: dict = {}
    if zero_offsets == "joints":
        config, ticks = rezero_tilt(config, tilt_direction)
        report["driver"] = {
            "tilt_zero_offset_ticks_change": ticks,
            "note": "add this to the driver's tilt_zero_offset_ticks; the rig file is for the re-zeroed driver",
        }
    obs = collected.observations
    report.update(
        {
            "board": str(board),
            "views_planned": int(len(joints)),
            "views_used": int(obs.n_views - len(solution.dropped_views)),
            "views_rejected": collected.rejected
            + [
                {"view": v, "reason": "reprojection outlier (over 5x the median error)"} for v in solution.dropped_views
            ],
            "pan_span_deg": math.degrees(float(np.ptp(obs.pan_rad))),
            "tilt_span_deg": math.degrees(float(np.ptp(obs.tilt_rad))),
            "rms_before_px": solution.rms_before_px,
            "rms_after_px": solution.rms_after_px,
            "per_view_rms_px": solution.per_view_rms_px,
            "parameters": {
                name: {
                    "value": _value(config, name),
                    "nominal": _value(nominal, name),
                    "std": solution.std[name],
                    "unit": "mm" if "_m[" in name else "deg",
                }
                for name in FREE_PARAMETERS
            },
            "unobservable": UNOBSERVABLE,
            "joint_zero_offsets": {
                "pan_zero_offset_ticks_change": 0,
                "tilt_zero_offset_ticks_change": report.get("driver", {}).get("tilt_zero_offset_ticks_change", 0),
            },
            "board2world": solution.board2world.tolist(),
            "iterations": solution.iterations,
            "capture_s": t_capture,
            "solve_s": time.monotonic() - t0 - t_capture,
        }
    )
    return config, report


def rig_yaml(config: PanTiltConfig, comment: str = "") -> str:
    """The rig as YAML of :class:`PanTiltConfig` fields (lengths to the micrometre, angles to 1e-4
    deg): what ``suggest --rig``, a scene's ``rig.pan_tilt`` and a launch file's ``rig`` load."""
    data = to_dict(config)
    for k, v in data.items():
        if isinstance(v, list):
            data[k] = [round(float(x), 6 if k.endswith("_m") else 4) for x in v]
        elif isinstance(v, float):
            data[k] = round(v, 6 if k.endswith("_s") else 4)
    header = "".join(f"# {line}\n" for line in comment.splitlines())
    return header + yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


# ------------------------------------------------------------------------------ latency
def estimate_latency(
    stream,
    camera: CameraModel,
    config: PanTiltConfig,
    board: BoardSpec,
    board2world: np.ndarray,
    centre: tuple[float, float],
    amplitude_rad: float,
    duration_s: float = 3.0,
    frequency_hz: float = 0.5,
) -> dict:
    """The camera's delay behind the joint states (seconds, positive = frames show the past).
    ``camera`` undistorts the corners (its ``K`` is the PnP's).

    ``stream(trajectory, duration_s)`` sweeps the pan along ``trajectory(t) -> (pan, tilt)`` and
    returns ``(frames, joint_states)``: ``[(stamp_s, gray)]`` as the camera stamps them and
    ``[(stamp_s, pan, tilt)]`` as the gimbal reports them. Each frame gives the pan it shows (the
    joints at which the calibrated rig re-projects the board, at its calibrated pose, where it was seen); the delay is the shift of
    the joint-state curve that matches those best (a constant pan bias allowed), to a millisecond.
    """
    p0, t0 = centre

    def trajectory(t: float) -> tuple[float, float]:
        return p0 + amplitude_rad * math.sin(2 * math.pi * frequency_hz * t), t0

    frames, states = stream(trajectory, duration_s)
    seen_t, seen_pan = [], []
    for stamp, gray in frames:
        found = detect(gray, board)
        if found is None:
            continue
        uv = camera.undistort(found.image_points)
        start = (seen_pan[-1], t0) if seen_pan else (p0, t0)
        pan, _, rms = seen_joints(config, board2world, camera.K, found.object_points, uv, start)
        if rms > 3.0:  # a view the rig cannot explain (a misdetection, motion blur): left out
            continue
        seen_t.append(stamp)
        seen_pan.append(pan)
    if len(seen_t) < 8:
        raise RigCalibrationError(
            f"the board was found in only {len(seen_t)} frames of the sweep; the latency needs 8 or more: slow the "
            "sweep (motion blur) or move the board to the middle of the pan range"
        )
    st = np.array([s[0] for s in states])
    sp = np.array([s[1] for s in states])
    ft, fp = np.array(seen_t), np.array(seen_pan)

    def cost(tau: float) -> float:
        pred = np.interp(ft - tau, st, sp)
        r = fp - pred
        return float(((r - r.mean()) ** 2).mean())

    taus = np.arange(-0.3, 0.5, 0.001)
    costs = np.array([cost(t) for t in taus])
    i = int(np.argmin(costs))
    tau = float(taus[i])
    if 0 < i < len(taus) - 1:  # parabola through the three best
        a, b, c = costs[i - 1 : i + 2]
        den = a - 2 * b + c
        if den > 0:
            tau += float(0.001 * 0.5 * (a - c) / den)
    return {
        "camera_latency_s": float(tau),
        "frames_used": len(ft),
        "frames": len(frames),
        "residual_rms_deg": math.degrees(math.sqrt(cost(tau))),
        "residual_rms_at_zero_deg": math.degrees(math.sqrt(cost(0.0))),
    }


# ------------------------------------------------------------------------------- verify
def verify_rig(source: ViewSource, config: PanTiltConfig, board: BoardSpec, n_views: int = 12, seed: int = 1) -> dict:
    """Re-project the board from new joint poses with ``config`` held fixed: the board's pose is
    fitted on every other view and the error measured on the others (held out), and on all."""
    pan, tilt, found = find_board(source, config, board)
    board2world = board_in_world(source.camera, config, pan, tilt, found)
    joints = plan_views(source.camera, config, board, board2world, 4 * n_views, seed=seed)
    rng = np.random.default_rng(seed)
    joints = joints[rng.permutation(len(joints))[:n_views]]  # not the calibration's farthest-point set
    obs = collect(source, board, joints).observations
    if obs.n_views < 4:
        raise RigCalibrationError(f"the board was found in only {obs.n_views} verification views; need 4 or more")
    fit_idx, test_idx = np.arange(0, obs.n_views, 2), np.arange(1, obs.n_views, 2)
    b2w, fit_rms, _ = fit_board_pose(obs.subset(fit_idx), config)
    held_rms, held_views = reprojection_rms(obs.subset(test_idx), config, b2w)
    _, all_rms, per_view = fit_board_pose(obs, config)
    return {
        "views": int(obs.n_views),
        "rms_px": all_rms,
        "held_out_rms_px": held_rms,
        "held_out_max_view_rms_px": float(held_views.max()),
        "fit_rms_px": fit_rms,
        "per_view_rms_px": [float(v) for v in per_view],
        "joints_deg": np.degrees(np.stack([obs.pan_rad, obs.tilt_rad], -1)).round(3).tolist(),
    }


def latency_sweep_centre(
    camera: CameraModel, config: PanTiltConfig, board: BoardSpec, board2world: np.ndarray
) -> tuple[tuple[float, float], float]:
    """The joint pose that centres the board, and the pan amplitude that keeps it in view."""
    joints = plan_views(camera, config, board, board2world, 200)
    kin = PanTilt(config)
    centre = board2world[:3, :3] @ board.object_points().mean(0) + board2world[:3, 3]
    aim = kin.inverse_look_at(centre)
    near = joints[np.abs(joints[:, 1] - aim.tilt_rad) < math.radians(2.0)]
    pool = near if len(near) >= 2 else joints
    amplitude = 0.45 * float(np.ptp(pool[:, 0]))
    return (float(np.median(pool[:, 0])), float(aim.tilt_rad)), max(amplitude, math.radians(1.0))
