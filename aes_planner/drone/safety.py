"""``SetpointGate``: the one path by which a setpoint reaches the vehicle.

Every setpoint it returns is finite, inside the box (the planner's search box, shrunk by
``margin_m`` so that float32 rounding on the wire cannot put it outside a fence of the same
box), and reached at no more than ``max_speed_m_s`` and ``max_yaw_rate_deg_s``: the streamed
setpoint is a carrot that moves from where the vehicle was when control began toward the goal
at those rates, never more than ``lead_m`` ahead of the vehicle. A goal outside the box is
clamped into it (counted); a non-finite goal is refused (counted) and the carrot stays.
Positions are local NED, headings NED (radians).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aes_planner.drone.frames import wrap

__all__ = ["GateLimits", "SetpointGate"]


@dataclass
class GateLimits:
    max_speed_m_s: float = 1.0
    max_yaw_rate_deg_s: float = 45.0
    margin_m: float = 0.02
    lead_m: float = 1.0


class SetpointGate:
    def __init__(self, lo_ned_m, hi_ned_m, limits: GateLimits):
        lo, hi = np.asarray(lo_ned_m, dtype=np.float64), np.asarray(hi_ned_m, dtype=np.float64)
        m = np.minimum(limits.margin_m, (hi - lo) / 2)
        self.lo, self.hi = lo + m, hi - m
        self.limits = limits
        self.carrot: np.ndarray | None = None  # [3] NED
        self.heading: float | None = None
        self.goal: np.ndarray | None = None
        self.goal_heading: float | None = None
        self.counters = {"goals_clamped": 0, "goals_refused": 0, "setpoints_refused": 0}

    def outside_m(self, p_ned) -> float:
        """How far ``p_ned`` lies outside the (shrunk) box, metres (0 inside)."""
        p = np.asarray(p_ned, dtype=np.float64)
        return float(np.linalg.norm(np.maximum(self.lo - p, 0) + np.maximum(p - self.hi, 0)))

    def clamp(self, p_ned) -> np.ndarray:
        return np.clip(np.asarray(p_ned, dtype=np.float64), self.lo, self.hi)

    def reset(self, vehicle_ned, vehicle_heading: float) -> None:
        """Control begins (or resumes) here: the carrot and the goal at the vehicle (clamped)."""
        self.carrot = self.clamp(vehicle_ned)
        self.heading = wrap(vehicle_heading)
        self.goal, self.goal_heading = self.carrot.copy(), self.heading

    def set_goal(self, p_ned, heading: float) -> bool:
        """A new goal; False (refused, counted) unless finite. Clamped into the box (counted)."""
        p = np.asarray(p_ned, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)) or not math.isfinite(heading):
            self.counters["goals_refused"] += 1
            return False
        clamped = self.clamp(p)
        if np.any(clamped != p):
            self.counters["goals_clamped"] += 1
        self.goal, self.goal_heading = clamped, wrap(heading)
        return True

    def next(self, vehicle_ned, dt_s: float) -> tuple[np.ndarray, float] | None:
        """The setpoint to stream now (position NED [3], heading), or None (not reset yet, or a
        value that fails the final check: counted, nothing sent)."""
        if self.carrot is None or self.goal is None:
            return None
        lim = self.limits
        dt_s = min(max(dt_s, 0.0), 0.2)
        delta = self.goal - self.carrot
        dist = float(np.linalg.norm(delta))
        step = lim.max_speed_m_s * dt_s
        carrot = self.goal.copy() if dist <= step else self.carrot + delta / dist * step
        v = np.asarray(vehicle_ned, dtype=np.float64)
        if np.all(np.isfinite(v)):
            ahead = carrot - v
            far = float(np.linalg.norm(ahead))
            if far > lim.lead_m and float(np.linalg.norm(self.carrot - v)) <= far:
                carrot = self.carrot  # wait for the vehicle rather than run away from it
        dyaw = wrap(self.goal_heading - self.heading)
        max_dyaw = math.radians(lim.max_yaw_rate_deg_s) * dt_s
        heading = wrap(self.heading + max(-max_dyaw, min(max_dyaw, dyaw)))
        carrot = self.clamp(carrot)
        if not (np.all(np.isfinite(carrot)) and math.isfinite(heading)) or self.outside_m(carrot) > 0:
            self.counters["setpoints_refused"] += 1
            return None
        self.carrot, self.heading = carrot, heading
        return carrot.copy(), heading
