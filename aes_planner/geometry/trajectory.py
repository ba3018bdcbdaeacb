"""Pose interpolation along an input trajectory: slerp on rotations, lerp on positions.

Stage 1 of the paper's search joins the input views into a continuous trajectory and samples
it; :func:`interpolate_poses` does that for full 6-DoF poses (rotations by quaternion slerp
along the shortest arc), :func:`interpolate_views` for 5-DoF views (yaw along the shortest arc,
pitch linearly, roll stays 0 — the form a pan-tilt rig or a drone gimbal can reach).
:class:`JointHistory` keeps a pan-tilt's joint angles over time and gives them at a stamp: where a
rig's camera was when an image was exposed.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Iterable

import numpy as np

from aes_planner.geometry.poses import (
    PoseError,
    cam2world_to_view,
    matrix_to_quat,
    quat_to_matrix,
    wrap_angle,
)

__all__ = ["JointHistory", "slerp", "interpolate_poses", "interpolate_views"]


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (w, x, y, z) along the shortest arc.

    ``q0, q1``: ``[4]``; ``t``: scalar or ``[T]`` in [0, 1]; returns ``[4]`` or ``[T, 4]``.
    Identical (or nearly identical) inputs fall back to normalised lerp; rotations 180 degrees
    apart (quaternion dot 0) are well defined.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    n0, n1 = np.linalg.norm(q0), np.linalg.norm(q1)
    if n0 < 1e-12 or n1 < 1e-12:
        raise PoseError("slerp: zero-length quaternion")
    q0, q1 = q0 / n0, q1 / n1
    dot = float(np.dot(q0, q1))
    if dot < 0.0:  # q and -q are the same rotation: take the shorter way round
        q1, dot = -q1, -dot
    t_arr = np.asarray(t, dtype=np.float64)
    tt = t_arr[..., None]
    if dot > 1.0 - 1e-10:
        out = (1.0 - tt) * q0 + tt * q1
    else:
        theta = math.acos(min(1.0, dot))
        s = math.sin(theta)
        out = (np.sin((1.0 - tt) * theta) / s) * q0 + (np.sin(tt * theta) / s) * q1
    out = out / np.linalg.norm(out, axis=-1, keepdims=True)
    return out


def _segment_params(n_poses: int, samples_per_segment: int, include_end: bool) -> list[tuple[int, float]]:
    if n_poses < 1:
        raise PoseError("interpolation needs at least one pose")
    if samples_per_segment < 1:
        raise PoseError(f"samples_per_segment must be >= 1, got {samples_per_segment}")
    params = [(i, k / samples_per_segment) for i in range(n_poses - 1) for k in range(samples_per_segment)]
    if include_end or n_poses == 1:
        params.append((max(n_poses - 2, 0), 1.0 if n_poses > 1 else 0.0))
    return params


def interpolate_poses(cam2worlds: np.ndarray, samples_per_segment: int, include_end: bool = True) -> np.ndarray:
    """Sample the trajectory through ``cam2worlds [N, 4, 4]``: ``S`` samples per segment.

    Each segment i -> i+1 contributes samples at t = 0, 1/S, ..., (S-1)/S; the last pose is
    appended when ``include_end``. Returns ``[(N-1)*S (+1), 4, 4]`` float64. Rotations are
    slerped, positions lerped (the paper's stage-1 trajectory).
    """
    poses = np.asarray(cam2worlds, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise PoseError(f"cam2worlds must be [N, 4, 4], got shape {poses.shape}")
    quats = matrix_to_quat(poses[:, :3, :3])  # [N, 4]
    params = _segment_params(len(poses), samples_per_segment, include_end)
    out = np.zeros((len(params), 4, 4))
    out[:, 3, 3] = 1.0
    q = np.empty((len(params), 4))  # [T, 4]
    for k, (i, t) in enumerate(params):
        j = min(i + 1, len(poses) - 1)
        q[k] = slerp(quats[i], quats[j], t)
        out[k, :3, 3] = (1.0 - t) * poses[i, :3, 3] + t * poses[j, :3, 3]
    # one call for every sample: elementwise, so each row is what a call of its own gives, and
    # ~30x faster than 49 calls of ~0.1 ms (docs/benchmarks.md, "perf-2, ninth round")
    out[:, :3, :3] = quat_to_matrix(q)
    return out


def interpolate_views(views: np.ndarray, samples_per_segment: int, include_end: bool = True) -> np.ndarray:
    """Sample the trajectory through 5-DoF ``views [N, 5]``; returns ``[M, 5]`` float64.

    Positions and pitch are lerped, yaw follows the shortest arc (a difference of exactly pi
    turns counter-clockwise) and is wrapped to (-pi, pi]; roll stays 0 throughout.
    """
    v = np.asarray(views, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 5:
        raise PoseError(f"views must be [N, 5], got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise PoseError("views contain NaN or Inf")
    out = []
    for i, t in _segment_params(len(v), samples_per_segment, include_end):
        j = min(i + 1, len(v) - 1)
        dyaw = float(wrap_angle(v[j, 3] - v[i, 3]))
        row = (1.0 - t) * v[i] + t * v[j]
        row[3] = float(wrap_angle(v[i, 3] + t * dyaw))
        out.append(row)
    return np.stack(out)


def views_of(cam2worlds: np.ndarray) -> np.ndarray:
    """Convenience: ``[N, 4, 4]`` -> ``[N, 5]`` (roll discarded)."""
    return cam2world_to_view(np.asarray(cam2worlds, dtype=np.float64))


class JointHistory:
    """A pan-tilt's joint angles over the last ``history_s`` seconds (of the readings' own stamps),
    linearly interpolated at a stamp and held at the ends: where a rig's camera was at a stamp.
    The one history of the camera nodes and the ROS 2 bridge."""

    def __init__(self, history_s: float):
        self.history_s = float(history_s)
        self._stamps: deque[float] = deque()
        self._joints: deque[tuple[float, float]] = deque()

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp_s: float, pan_rad: float, tilt_rad: float) -> None:
        """Keep a reading newer than the newest kept (an older or equal stamp is ignored); forget
        those more than ``history_s`` older than it (keeping two at least)."""
        if self._stamps and stamp_s <= self._stamps[-1]:
            return
        self._stamps.append(float(stamp_s))
        self._joints.append((float(pan_rad), float(tilt_rad)))
        while len(self._stamps) > 2 and self._stamps[0] < stamp_s - self.history_s:
            self._stamps.popleft()
            self._joints.popleft()

    def extend(self, states: Iterable) -> None:
        """:meth:`add` each of ``states`` (anything with ``stamp_s``, ``pan_rad``, ``tilt_rad``: a
        :class:`~aes_planner.messages.GimbalState`)."""
        for s in states:
            self.add(s.stamp_s, s.pan_rad, s.tilt_rad)

    def joints_at(self, stamp_s: float) -> tuple[float, float] | None:
        """(pan, tilt) at ``stamp_s``, linearly interpolated between the two readings around it
        (held at the ends); None before any reading, or before the history."""
        if not self._stamps or stamp_s < self._stamps[0] - self.history_s:
            return None
        stamps = list(self._stamps)
        i = bisect.bisect_right(stamps, stamp_s)
        if i == 0:
            return self._joints[0]
        if i == len(stamps):
            return self._joints[-1]
        t0, t1 = stamps[i - 1], stamps[i]
        (p0, q0), (p1, q1) = self._joints[i - 1], self._joints[i]
        w = (stamp_s - t0) / (t1 - t0) if t1 > t0 else 1.0
        return p0 + w * (p1 - p0), q0 + w * (q1 - q0)

    @property
    def newest_stamp_s(self) -> float | None:
        """The newest reading's stamp; None before any."""
        return self._stamps[-1] if self._stamps else None

    def latest(self) -> tuple[float, float] | None:
        """The newest reading's (pan, tilt); None before any."""
        return self._joints[-1] if self._joints else None
