"""The trapezoidal motion profile of a position-controlled joint, shared by the servo emulator
(in ticks) and the simulated gimbal (in radians): the units are the caller's."""

from __future__ import annotations

import math

__all__ = ["trapezoid_step"]


def trapezoid_step(
    position: float, velocity: float, goal: float, v_max: float, a_max: float, dt: float
) -> tuple[float, float, bool]:
    """One integration step: ``(position, velocity, settled)`` after ``dt``.

    Toward the goal the speed is the least of ``v_max``, the speed after accelerating for ``dt``
    and the braking curve ``sqrt(2 a d)`` that stops exactly at the goal; moving away from it (a
    goal changed mid-move), the joint first brakes. ``a_max`` may be ``inf`` (no acceleration
    limit). ``settled`` is True once the joint stands at the goal.
    """
    d = goal - position
    if d == 0.0 and velocity == 0.0:
        return position, velocity, True
    s = 1.0 if d > 0 else -1.0
    if math.isinf(a_max):
        v = s * v_max
    elif velocity * s < 0:
        v = velocity + s * a_max * dt
    else:
        v = s * min(v_max, abs(velocity) + a_max * dt, math.sqrt(2.0 * a_max * abs(d)))
    nxt = position + v * dt
    if v * s > 0 and (goal - nxt) * s <= 0:  # reaches the goal within this step
        return goal, 0.0, True
    return nxt, v, False
