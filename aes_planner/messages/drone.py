"""``DroneState``: what a flying vehicle reports, in the package's frames (``drone/state``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from aes_planner.messages.codec import Array, Message, MessageError, Scalar, Str, register_message, text_cap
from aes_planner.messages.fields import check_finite, check_pose, check_sequence, check_text

__all__ = ["DroneState"]


def _vector(value, name: str, n: int) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise MessageError(f"{name} must be {n} finite numbers, got {np.asarray(value).tolist()}")
    return a


@register_message
@dataclass
class DroneState(Message):
    """What ``drone/state`` carries (world = ENU at the vehicle's local origin, metres, radians).

    * ``cam2world``: the camera's pose ``[4, 4]`` (vehicle pose, then gimbal attitude, then the
      camera's mount), OpenCV camera frame; ``stamp_s``: when the telemetry it comes from arrived.
    * ``position_m``, ``velocity_m_s``: the vehicle's, ENU; ``attitude_wxyz``: body FLU in ENU.
    * ``gimbal_pitch_rad`` (positive up, from the horizon), ``gimbal_yaw_rad`` (from the vehicle's
      heading, positive left).
    * ``mode``: the flight mode (``OFFBOARD``, ``AUTO.LOITER``, ``GUIDED``...); ``armed``;
      ``system_id`` of the vehicle; ``link``: ``ok`` or ``lost``; ``status``: the bridge's state
      word (``flying``, ``waiting_for_offboard``, ``link_lost``, ``unexpected_mode``...).
    """

    TYPE_NAME: ClassVar[str] = "DroneState"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 4096
    FIELDS = (
        Scalar("stamp_s", "f64", doc="when the telemetry it comes from arrived"),
        Scalar("sequence", "u64", doc="the bridge's state counter: 1 for its first, +1 for each published"),
        Array("cam2world", "f8", (4, 4), exact=True, doc="the camera's pose (vehicle, gimbal, mount), OpenCV axes"),
        Array("position_m", "f8", (3,), exact=True, doc="the vehicle's position, ENU"),
        Array("velocity_m_s", "f8", (3,), exact=True, doc="ENU"),
        Array("attitude_wxyz", "f8", (4,), exact=True, doc="body (FLU) in ENU, quaternion w x y z"),
        Scalar("gimbal_pitch_rad", "f64", doc="positive up, from the horizon"),
        Scalar("gimbal_yaw_rad", "f64", doc="from the vehicle's heading, positive left"),
        Str("mode", 256, doc="flight mode (`OFFBOARD`, `AUTO.LOITER`, `GUIDED`, ...)"),
        Scalar("armed", "bool"),
        Scalar("system_id", "u32", doc="the vehicle's MAVLink system id, 0-255"),
        Str("link", 16, doc="`ok` or `lost`"),
        Str("status", 1024, doc="the bridge's state word (`flying`, `waiting_for_offboard`, `link_lost`, ...)"),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = (
        "a `cam2world` that is not rigid (as `PosedFrame.cam2world`)",
        "a `system_id` above 255, or a `link` other than `ok` and `lost`",
    )

    stamp_s: float
    cam2world: np.ndarray
    position_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity_m_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    attitude_wxyz: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))
    gimbal_pitch_rad: float = 0.0
    gimbal_yaw_rad: float = 0.0
    mode: str = ""
    armed: bool = False
    system_id: int = 0
    link: str = "ok"
    status: str = ""
    sequence: int = 0

    def __post_init__(self):
        self.stamp_s = check_finite(self.stamp_s, "DroneState.stamp_s")
        self.cam2world = check_pose(self.cam2world, "DroneState.cam2world")
        self.position_m = _vector(self.position_m, "DroneState.position_m", 3)
        self.velocity_m_s = _vector(self.velocity_m_s, "DroneState.velocity_m_s", 3)
        self.attitude_wxyz = _vector(self.attitude_wxyz, "DroneState.attitude_wxyz", 4)
        for name in ("gimbal_pitch_rad", "gimbal_yaw_rad"):
            setattr(self, name, check_finite(getattr(self, name), f"DroneState.{name}"))
        if not isinstance(self.armed, (bool, np.bool_)):
            raise MessageError(f"DroneState.armed must be a bool, got {self.armed!r}")
        self.armed = bool(self.armed)
        self.system_id = check_sequence(self.system_id, "DroneState.system_id")
        if self.system_id > 255:
            raise MessageError(f"DroneState.system_id must be 0-255, got {self.system_id}")
        if self.link not in ("ok", "lost"):
            raise MessageError(f"DroneState.link must be 'ok' or 'lost', got {self.link!r}")
        self.mode = check_text(self.mode, "DroneState.mode", text_cap(self.FIELDS, "mode"))
        self.status = check_text(self.status, "DroneState.status", text_cap(self.FIELDS, "status"))
        self.sequence = check_sequence(self.sequence, "DroneState.sequence")
