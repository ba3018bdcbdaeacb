"""Pan-tilt rig configuration and joint limits, without torch or numpy.

The hardware bridge imports this module alone (a driver process must start in well under a
second, even on a small computer); :mod:`aes_planner.geometry.pantilt` adds the kinematics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from aes_planner.config import require, require_finite, to_dict
from aes_planner.errors import AesPlannerError

__all__ = ["JOINT_LIMIT_TOLERANCE_RAD", "JointCommandError", "JointLimits", "PanTiltConfig", "rig_dict"]


class JointCommandError(AesPlannerError, ValueError):
    """A joint command that must not reach a motor (NaN, Inf)."""


#: Farthest a rig's base may sit from the origin, and longest its arms (tilt offset, lever arm), metres.
MAX_BASE_M = 1e9
MAX_ARM_M = 100.0

#: How far beyond its limits a joint angle may be and still pass :meth:`JointLimits.check`,
#: radians (0.2 deg, two Dynamixel ticks of 0.088 deg and a little): a servo reads back a tick or
#: two past a limit it was sent to, and a capture's joints, read from the gimbal, are sent again to
#: settle on it. A command that far beyond a gimbal node's launch limits reaches the device as sent.
JOINT_LIMIT_TOLERANCE_RAD = math.radians(0.2)


@dataclass
class PanTiltConfig:
    """Geometry and limits of a pan-tilt rig (degrees and metres: this is the YAML edge).

    * ``base_xyz_m``: pan-axis origin in the world.
    * ``base_rpy_deg``: base orientation, static roll/pitch/yaw about world x, y, z
      (``R = Rz(yaw) Ry(pitch) Rx(roll)``); (0, 0, 0) is upright facing +x.
    * ``tilt_offset_m``: tilt-axis origin in the pan frame (x forward, y left, z up).
    * ``lever_arm_m``: camera optical centre in the tilt frame.
    * ``pan_limits_deg``, ``tilt_limits_deg``: (min, max) joint limits, inclusive.
    * ``camera_roll_deg``: the camera's rotation about its optical axis in the tilt frame
      (positive: clockwise as seen from behind the camera, so the image's content turns
      counter-clockwise). 0: the image's up is the tilt frame's up. 180 for a rig hung upside
      down (``base_rpy_deg = (180, 0, 0)``) whose camera flips its image, as ceiling mounts do,
      so the images come out upright; leave 0 if its images come out upside down.
    * ``camera_mount_rpy_deg``: the camera's small mounting error on the tilt bracket, static roll,
      pitch, yaw (``R = Rz(yaw) Ry(pitch) Rx(roll)``, as ``base_rpy_deg``) about the tilt frame's
      x (forward, the nominal optical axis), y (left) and z (up), applied after ``lever_arm_m`` and
      before ``camera_roll_deg``: positive roll turns the image as ``camera_roll_deg`` does, positive
      pitch points the lens down (REP-103), positive yaw points it left. ``aes-planner calibrate rig``
      estimates it; (0, 0, 0) is the drawing's ideal mount.
    * ``camera_latency_s``: how long after the joint states a camera frame shows them (its
      exposure precedes its stamp by this); the camera node poses each frame at the joints of
      ``stamp - camera_latency_s``. ``aes-planner calibrate rig --latency`` estimates it.
    """

    base_xyz_m: tuple[float, float, float] = (0.0, 0.0, 1.2)
    base_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tilt_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.05)
    lever_arm_m: tuple[float, float, float] = (0.03, 0.0, 0.02)
    pan_limits_deg: tuple[float, float] = (-150.0, 150.0)
    tilt_limits_deg: tuple[float, float] = (-60.0, 60.0)
    camera_roll_deg: float = 0.0
    camera_mount_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    camera_latency_s: float = 0.0

    def __post_init__(self):
        for name in (
            "base_xyz_m",
            "base_rpy_deg",
            "tilt_offset_m",
            "lever_arm_m",
            "pan_limits_deg",
            "tilt_limits_deg",
            "camera_mount_rpy_deg",
        ):
            require_finite(list(getattr(self, name)), name)
        require_finite(self.camera_roll_deg, "camera_roll_deg")
        for name, most in (("base_xyz_m", MAX_BASE_M), ("tilt_offset_m", MAX_ARM_M), ("lever_arm_m", MAX_ARM_M)):
            far = max(abs(v) for v in getattr(self, name))
            require(far <= most, name, f"a coordinate of {far:.3g} m is beyond {most:g} m")
        require(
            -360.0 <= self.camera_roll_deg <= 360.0,
            "camera_roll_deg",
            f"must be in [-360, 360] deg (180 for an image flipped upside down), got {self.camera_roll_deg}",
        )
        require_finite(self.camera_latency_s, "camera_latency_s")
        require(
            -1.0 <= self.camera_latency_s <= 10.0,
            "camera_latency_s",
            f"must be in [-1, 10] s (a camera's delay behind the joint states), got {self.camera_latency_s}",
        )
        worst = max(abs(v) for v in self.camera_mount_rpy_deg)
        require(
            worst <= 45.0,
            "camera_mount_rpy_deg",
            f"a mounting error of {worst:g} deg is not small; at most 45 deg (rotate the image with camera_roll_deg)",
        )
        lo, hi = self.pan_limits_deg
        require(lo < hi, "pan_limits_deg", f"min must be below max, got ({lo}, {hi})")
        require(hi - lo <= 360.0, "pan_limits_deg", f"a range over 360 deg is not a position-mode joint: ({lo}, {hi})")
        lo, hi = self.tilt_limits_deg
        require(lo < hi, "tilt_limits_deg", f"min must be below max, got ({lo}, {hi})")
        require(-90.0 <= lo and hi <= 90.0, "tilt_limits_deg", f"tilt must stay within [-90, 90] deg, got ({lo}, {hi})")


#: Fields added after rigs were first saved, with the value every older rig had. :func:`rig_dict`
#: leaves them out at that value, so older scene files and oracle cache keys stay the same.
LATER_FIELD_DEFAULTS = {"camera_roll_deg": 0.0, "camera_mount_rpy_deg": [0.0, 0.0, 0.0], "camera_latency_s": 0.0}


def rig_dict(config: PanTiltConfig) -> dict:
    """``config`` as plain lists and numbers (:func:`~aes_planner.config.to_dict`), without the
    later fields that still hold their old value."""
    return {k: v for k, v in to_dict(config).items() if LATER_FIELD_DEFAULTS.get(k, object()) != v}


@dataclass(frozen=True)
class JointLimits:
    """Inclusive (min, max) joint limits in radians, and the one clamp every command passes.

    **The clamp rule.** :meth:`clamp` is applied once, last, by whatever drives the joints: the
    :class:`~aes_planner.devices.Gimbal` device (every driver's ``move_to``), or, when ROS 2
    drives them, the bridge's outbound joint command (:mod:`aes_planner.ros2.inbound`). Everything
    before it (the planner's motion, the gimbal node's launch limits) only check (:meth:`check`): a
    command beyond the limits is refused and counted, never moved inside them.
    """

    pan_rad: tuple[float, float]
    tilt_rad: tuple[float, float]

    @classmethod
    def from_config(cls, config: PanTiltConfig) -> JointLimits:
        return cls(
            tuple(math.radians(a) for a in config.pan_limits_deg),  # type: ignore[arg-type]
            tuple(math.radians(a) for a in config.tilt_limits_deg),  # type: ignore[arg-type]
        )

    def clamp(self, pan_rad: float, tilt_rad: float) -> tuple[float, float]:
        """Clamp joint angles to the limits; NaN or Inf raise :class:`JointCommandError`."""
        if not (math.isfinite(pan_rad) and math.isfinite(tilt_rad)):
            raise JointCommandError(
                f"joint command must be finite, got pan={pan_rad!r} rad, tilt={tilt_rad!r} rad; refusing to move"
            )
        (plo, phi), (tlo, thi) = self.pan_rad, self.tilt_rad
        return min(max(pan_rad, plo), phi), min(max(tilt_rad, tlo), thi)

    def check(self, pan_rad: float, tilt_rad: float, tol_rad: float = JOINT_LIMIT_TOLERANCE_RAD) -> tuple[float, float]:
        """The joint angles unchanged when they are finite and inside the limits (widened by
        ``tol_rad``); else :class:`JointCommandError` saying which joint and by how much. The check
        of everything before the one clamp (see the class docstring): it refuses, it never moves."""
        if not (math.isfinite(pan_rad) and math.isfinite(tilt_rad)):
            raise JointCommandError(
                f"joint command must be finite, got pan={pan_rad!r} rad, tilt={tilt_rad!r} rad; refusing to move"
            )
        for name, value, (lo, hi) in (("pan", pan_rad, self.pan_rad), ("tilt", tilt_rad, self.tilt_rad)):
            if not lo - tol_rad <= value <= hi + tol_rad:
                raise JointCommandError(
                    f"{name} {math.degrees(value):.3f} deg is beyond the limits "
                    f"[{math.degrees(lo):.3f}, {math.degrees(hi):.3f}] deg; refusing to move "
                    "(command an angle inside them)"
                )
        return pan_rad, tilt_rad

    def within(self, pan_rad: float, tilt_rad: float, tol_rad: float = 1e-9) -> bool:
        """Whether the joints are inside the limits (widened by ``tol_rad``)."""
        (plo, phi), (tlo, thi) = self.pan_rad, self.tilt_rad
        return plo - tol_rad <= pan_rad <= phi + tol_rad and tlo - tol_rad <= tilt_rad <= thi + tol_rad
