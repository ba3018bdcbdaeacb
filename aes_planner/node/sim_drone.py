"""``SimDrone``: a velocity- and acceleration-limited 5-DoF pose follower inside its flight box,
and ``SimDroneNode``: that drone with the sim camera on it, so the free mode runs closed in
simulation (the planner's top candidate on ``planner/suggestion`` is the drone's target; the
frames it publishes on ``camera/frame`` show where it actually is).

Motion model, per :meth:`SimDrone.advance` of ``dt`` seconds: each of position (as a 3-vector),
yaw and pitch moves toward its target with a speed that may change by at most the acceleration
limit times ``dt``, never exceeds the speed limit, and brakes in time to stop at the target
(speed <= sqrt(2 a d)). The position is kept inside the box, the pitch inside ``pitch_limits_deg``,
the yaw wraps.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch

from aes_planner.config import require, require_numbers
from aes_planner.devices import CameraImage
from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world
from aes_planner.graph.base import Input, LaunchContext, NodeError
from aes_planner.messages import ViewSuggestion
from aes_planner.node.sim_camera import SimCameraNode, SimCameraNodeConfig
from aes_planner.platform import DroneBox

__all__ = ["SimDrone", "SimDroneConfig", "SimDroneNode", "SimDroneNodeConfig"]


@dataclass
class SimDroneConfig:
    """Limits of the simulated drone's motion."""

    max_speed_m_s: float = 2.0
    max_accel_m_s2: float = 4.0
    max_yaw_rate_deg_s: float = 120.0
    max_pitch_rate_deg_s: float = 90.0
    max_angular_accel_deg_s2: float = 360.0
    pitch_limits_deg: tuple[float, float] = (-80.0, 60.0)

    def __post_init__(self):
        require_numbers(
            self,
            (
                "max_speed_m_s",
                "max_accel_m_s2",
                "max_yaw_rate_deg_s",
                "max_pitch_rate_deg_s",
                "max_angular_accel_deg_s2",
            ),
        )
        lo, hi = self.pitch_limits_deg
        require(
            -90.0 <= lo < hi <= 90.0, "pitch_limits_deg", f"must be within [-90, 90] with min < max, got {(lo, hi)}"
        )


def _approach(x: float, v: float, goal: float, v_max: float, a_max: float, dt: float) -> tuple[float, float]:
    """One axis: new (position, velocity) after ``dt`` toward ``goal``. A step that would pass the
    goal stops on it; the speed left over (the discrete braking curve) decays at ``a_max``."""
    err = goal - x
    v_des = math.copysign(min(v_max, math.sqrt(2.0 * a_max * abs(err))), err) if err else 0.0
    v = v + max(-a_max * dt, min(a_max * dt, v_des - v))
    step = v * dt
    if err == 0 or (step * err >= 0 and abs(step) >= abs(err)):
        return goal, v
    return x + step, v


class SimDrone:
    """A 5-DoF (x, y, z, yaw, pitch) pose follower in ``box``; see the module docstring."""

    def __init__(self, box: DroneBox, config: SimDroneConfig | None = None, start_view=None):
        self.box = box
        self.config = config or SimDroneConfig()
        lo, hi = np.asarray(box.bounds_min_m), np.asarray(box.bounds_max_m)
        view = np.asarray(start_view if start_view is not None else [*(lo + hi) / 2, 0.0, 0.0], dtype=np.float64)
        self.position_m = box.clamp(view[:3])
        self.yaw_rad = float(view[3])
        self.pitch_rad = self._clamp_pitch(float(view[4]))
        self.velocity_m_s = np.zeros(3)
        self.yaw_rate = 0.0
        self.pitch_rate = 0.0
        self.target: np.ndarray | None = None  # [5]

    def _clamp_pitch(self, pitch_rad: float) -> float:
        lo, hi = (math.radians(a) for a in self.config.pitch_limits_deg)
        return min(max(pitch_rad, lo), hi)

    @property
    def view(self) -> np.ndarray:
        return np.array([*self.position_m, self.yaw_rad, self.pitch_rad])

    def cam2world(self) -> np.ndarray:
        return view_to_cam2world(torch.as_tensor(self.view)).numpy()

    def set_target(self, view) -> None:
        """Fly toward ``view [5]`` (clamped to the box and the pitch limits); non-finite is refused."""
        v = np.asarray(view, dtype=np.float64).reshape(-1)
        if v.shape != (5,) or not np.all(np.isfinite(v)):
            raise NodeError(f"drone target must be 5 finite numbers (x, y, z, yaw, pitch), got {v.tolist()}")
        self.target = np.array(
            [*self.box.clamp(v[:3]), math.atan2(math.sin(v[3]), math.cos(v[3])), self._clamp_pitch(v[4])]
        )

    def advance(self, dt_s: float) -> None:
        if self.target is None or not (dt_s > 0 and math.isfinite(dt_s)):
            return
        c = self.config
        dt_s = min(dt_s, 0.5)
        # translation along the straight line to the target
        delta = self.target[:3] - self.position_m
        dist = float(np.linalg.norm(delta))
        speed = float(np.dot(self.velocity_m_s, delta / dist)) if dist > 1e-9 else 0.0
        if dist > 1e-9:
            moved, speed = _approach(0.0, speed, dist, c.max_speed_m_s, c.max_accel_m_s2, dt_s)
            step = min(max(moved, 0.0), dist)
            self.position_m = self.box.clamp(self.position_m + delta / dist * step)
            self.velocity_m_s = delta / dist * speed
        else:  # at the target: any residual speed decays at the acceleration limit
            speed = float(np.linalg.norm(self.velocity_m_s))
            keep = max(speed - c.max_accel_m_s2 * dt_s, 0.0)
            self.velocity_m_s = self.velocity_m_s * (keep / speed) if speed > 0 else np.zeros(3)
        # yaw (wrapped) and pitch
        a = math.radians(c.max_angular_accel_deg_s2)
        yaw_err = math.atan2(math.sin(self.target[3] - self.yaw_rad), math.cos(self.target[3] - self.yaw_rad))
        y, self.yaw_rate = _approach(0.0, self.yaw_rate, yaw_err, math.radians(c.max_yaw_rate_deg_s), a, dt_s)
        self.yaw_rad = math.atan2(math.sin(self.yaw_rad + y), math.cos(self.yaw_rad + y))
        self.pitch_rad, self.pitch_rate = _approach(
            self.pitch_rad, self.pitch_rate, self.target[4], math.radians(c.max_pitch_rate_deg_s), a, dt_s
        )
        self.pitch_rad = self._clamp_pitch(self.pitch_rad)


@dataclass
class SimDroneNodeConfig(SimCameraNodeConfig):
    """The sim camera's settings plus the drone's motion limits and start view
    (``start_view``: x, y, z, yaw_deg, pitch_deg; default the first survey pose of the box)."""

    drone: SimDroneConfig | None = None
    start_view: tuple[float, float, float, float, float] | None = None

    def __post_init__(self):
        super().__post_init__()
        if self.drone is None:
            self.drone = SimDroneConfig()


class SimDroneNode(SimCameraNode):
    """A :class:`SimDrone` carrying the sim camera; follows the top candidate of ``planner/suggestion``."""

    config_class = SimDroneNodeConfig
    inputs = {"planner/suggestion": Input(ViewSuggestion, 4)}

    def __init__(
        self,
        config: SimDroneNodeConfig | None = None,
        node_id: str = "drone",
        context: LaunchContext | None = None,
        scene=None,
    ):
        super().__init__(config or SimDroneNodeConfig(), node_id, context, scene)
        c = self.config
        from aes_planner.sim.source import platform_of

        box = platform_of(self.scene).free_box()  # a rig scene: the box around the rig's base
        if c.start_view is not None:
            x, y, z, yaw, pitch = c.start_view
            start = [x, y, z, math.radians(yaw), math.radians(pitch)]
        else:
            start = cam2world_to_view(_survey_start(box)).tolist()
        self.drone = SimDrone(box, c.drone, start)
        self._last_s: float | None = None

    def _check_platform(self) -> None:
        pass  # a rig scene flies a box around the rig's base

    def observe(self, inputs: Mapping[str, list], now: float) -> None:
        for s in inputs.get("planner/suggestion", ()):
            if s.candidates:
                self.drone.set_target(s.candidates[0].view)
        if self._last_s is not None:
            self.drone.advance(now - self._last_s)
        self._last_s = now
        self.camera.move_to(self.drone.cam2world(), now)

    def pose(self, image: CameraImage):
        """Where the sim camera says the drone had it (no joints on a drone)."""
        return image.cam2world, None


def _survey_start(box: DroneBox) -> np.ndarray:
    lo, hi = np.asarray(box.bounds_min_m), np.asarray(box.bounds_max_m)
    c = (lo + hi) / 2
    return view_to_cam2world(torch.tensor([*c, 0.0, math.radians(-5.0)], dtype=torch.float64)).numpy()
