"""Gimbal messages in joint terms: ``GimbalCommand`` (to the gimbal) and ``GimbalState`` (from it).

Joints are ``pan`` (about the base's +z) and ``tilt`` (positive looks up), in radians, as in
:mod:`aes_planner.geometry.pantilt`. These are not view yaw/pitch: with a tilted base they differ.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aes_planner.geometry.plausible import MAX_JOINT_RAD
from aes_planner.messages.codec import (
    Enum,
    Fixed,
    List,
    Message,
    MessageError,
    Optional,
    Scalar,
    Str,
    register_message,
    text_cap,
)
from aes_planner.messages.fields import check_finite, check_joint, check_optional_finite, check_sequence, check_text

__all__ = ["GimbalCommand", "GimbalState", "COMMAND_KINDS"]

COMMAND_KINDS = ("move", "stop", "reboot")
MAX_FAULTS = 16


@register_message
@dataclass
class GimbalCommand(Message):
    """What ``gimbal/command`` carries.

    * ``kind``: ``"move"`` (to ``pan_rad``, ``tilt_rad``), ``"stop"`` (hold where it is, torque
      off as the gimbal node documents) or ``"reboot"`` (clear a latched hardware error).
    * ``pan_rad``, ``tilt_rad``: the goal, finite; the gimbal node clamps to its joint limits.
      Ignored (and 0) for stop and reboot.
    * ``speed_rad_s``: optional joint speed limit (> 0); None = the gimbal's configured profile.
    * ``stamp_s``, ``sequence``: when it was sent and the sender's counter.
    """

    TYPE_NAME: ClassVar[str] = "GimbalCommand"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 4096
    FIELDS = (
        Enum(
            "kind",
            COMMAND_KINDS,
            doc="`move`: to pan/tilt; `stop`: hold where it is now; `reboot`: reboot the servos to clear a latched "
            "hardware error",
        ),
        Scalar("pan_rad", "f64", doc="goal; 0 for stop and reboot; the gimbal clamps it to its joint limits"),
        Scalar("tilt_rad", "f64"),
        Optional(Scalar("speed_rad_s", "f64", doc="> 0; absent = the gimbal's configured profile")),
        Scalar("stamp_s", "f64", doc="when it was sent"),
        Scalar("sequence", "u64", doc="the sender's command counter (the planner's: 1 for its first, +1 for each)"),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = ("`speed_rad_s` present and <= 0",)

    kind: str = "move"
    pan_rad: float = 0.0
    tilt_rad: float = 0.0
    speed_rad_s: float | None = None
    stamp_s: float = 0.0
    sequence: int = 0

    def __post_init__(self):
        if self.kind not in COMMAND_KINDS:
            raise MessageError(f"GimbalCommand.kind must be one of {COMMAND_KINDS}, got {self.kind!r}")
        self.pan_rad = check_finite(self.pan_rad, "GimbalCommand.pan_rad")  # a goal: clamped to the limits
        self.tilt_rad = check_finite(self.tilt_rad, "GimbalCommand.tilt_rad")
        self.speed_rad_s = check_optional_finite(self.speed_rad_s, "GimbalCommand.speed_rad_s")
        if self.speed_rad_s is not None and self.speed_rad_s <= 0:
            raise MessageError(f"GimbalCommand.speed_rad_s must be > 0 (or None), got {self.speed_rad_s}")
        self.stamp_s = check_finite(self.stamp_s, "GimbalCommand.stamp_s")
        self.sequence = check_sequence(self.sequence, "GimbalCommand.sequence")


@register_message
@dataclass
class GimbalState(Message):
    """What ``gimbal/state`` carries (joint terms).

    * ``pan_rad``, ``tilt_rad``: present joint angles; ``goal_pan_rad``, ``goal_tilt_rad``: the goal.
    * ``moving``: True while either joint moves or has not reached its goal.
    * ``temperature_c``: (pan, tilt) motor temperatures.
    * ``hardware_error``: active faults as ``"joint: fault"`` strings (at most 16), empty when healthy.
    * ``status``: the gimbal node's state word (``"ok"``, ``"fault"``, ``"stopped"``, ...).
    * ``stamp_s``: time of the reading; ``sequence``: the node's counter.

    :meth:`from_device` converts the device layer's dataclass (:class:`aes_planner.devices.GimbalReading`).
    """

    TYPE_NAME: ClassVar[str] = "GimbalState"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 16384
    FIELDS = (
        Scalar("pan_rad", "f64", doc="present joints"),
        Scalar("tilt_rad", "f64"),
        Scalar("goal_pan_rad", "f64", doc="the goal the servos move to"),
        Scalar("goal_tilt_rad", "f64"),
        Scalar("moving", "bool", doc="either joint moves or has not reached its goal"),
        Fixed("temperature_c", Scalar("value", "f64"), 2, doc="pan, tilt motor temperatures"),
        List(
            "hardware_error",
            Str("fault", 1024),
            "u8",
            MAX_FAULTS,
            doc='active faults, `"joint: fault"`; the only `u8` count',
        ),
        Scalar("stamp_s", "f64", doc="when the servos were read"),
        Scalar("sequence", "u64", doc="the gimbal node's state counter: 1 for its first, +1 for each published"),
        Str("status", 256, doc="the gimbal node's state word: `ok`, `fault`, `comm_error`, `stopped`, ..."),
    )
    WIRE_RULES: ClassVar[tuple[str, ...]] = (f"a joint or goal beyond 4 pi = {MAX_JOINT_RAD!r} rad (two turns)",)

    pan_rad: float
    tilt_rad: float
    goal_pan_rad: float
    goal_tilt_rad: float
    moving: bool = False
    temperature_c: tuple[float, float] = (0.0, 0.0)
    hardware_error: tuple[str, ...] = ()
    stamp_s: float = 0.0
    sequence: int = 0
    status: str = "ok"

    def __post_init__(self):
        for name in ("pan_rad", "tilt_rad", "goal_pan_rad", "goal_tilt_rad"):
            setattr(self, name, check_joint(getattr(self, name), f"GimbalState.{name}"))
        self.stamp_s = check_finite(self.stamp_s, "GimbalState.stamp_s")
        if not isinstance(self.moving, bool):
            raise MessageError(f"GimbalState.moving must be a bool, got {self.moving!r}")
        temps = tuple(self.temperature_c) if isinstance(self.temperature_c, (tuple, list)) else None
        if temps is None or len(temps) != 2:
            raise MessageError(f"GimbalState.temperature_c must be (pan, tilt), got {self.temperature_c!r}")
        self.temperature_c = tuple(check_finite(t, "GimbalState.temperature_c") for t in temps)
        if not isinstance(self.hardware_error, (tuple, list)) or len(self.hardware_error) > MAX_FAULTS:
            raise MessageError(f"GimbalState.hardware_error must be a tuple of at most {MAX_FAULTS} strings")
        cap = text_cap(self.FIELDS, "hardware_error")
        self.hardware_error = tuple(check_text(f, "GimbalState.hardware_error", cap) for f in self.hardware_error)
        self.sequence = check_sequence(self.sequence, "GimbalState.sequence")
        self.status = check_text(self.status, "GimbalState.status", text_cap(self.FIELDS, "status"))

    @classmethod
    def from_device(cls, state, *, sequence: int = 0, status: str | None = None) -> GimbalState:
        """From the device layer's state (:class:`aes_planner.devices.GimbalReading`)."""
        faults = tuple(getattr(state, "hardware_error", ()))
        return cls(
            pan_rad=state.pan_rad,
            tilt_rad=state.tilt_rad,
            goal_pan_rad=state.goal_pan_rad,
            goal_tilt_rad=state.goal_tilt_rad,
            moving=bool(state.moving),
            temperature_c=tuple(state.temperature_c),
            hardware_error=faults,
            stamp_s=state.stamp_s,
            sequence=sequence,
            status=status if status is not None else ("fault" if faults else "ok"),
        )
