"""Gimbal messages in joint terms: ``GimbalCommand`` (to the gimbal) and ``GimbalState`` (from it).

Joints are ``pan`` (about the base's +z) and ``tilt`` (positive looks up), in radians, as in
:mod:`aes_planner.geometry.pantilt`. These are not view yaw/pitch: with a tilted base they differ.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from aes_planner.messages.codec import Message, MessageError, Reader, Writer, register_message
from aes_planner.messages.fields import check_finite, check_optional_finite, check_sequence, check_text

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

    kind: str = "move"
    pan_rad: float = 0.0
    tilt_rad: float = 0.0
    speed_rad_s: float | None = None
    stamp_s: float = 0.0
    sequence: int = 0

    def __post_init__(self):
        if self.kind not in COMMAND_KINDS:
            raise MessageError(f"GimbalCommand.kind must be one of {COMMAND_KINDS}, got {self.kind!r}")
        self.pan_rad = check_finite(self.pan_rad, "GimbalCommand.pan_rad")
        self.tilt_rad = check_finite(self.tilt_rad, "GimbalCommand.tilt_rad")
        self.speed_rad_s = check_optional_finite(self.speed_rad_s, "GimbalCommand.speed_rad_s")
        if self.speed_rad_s is not None and self.speed_rad_s <= 0:
            raise MessageError(f"GimbalCommand.speed_rad_s must be > 0 (or None), got {self.speed_rad_s}")
        self.stamp_s = check_finite(self.stamp_s, "GimbalCommand.stamp_s")
        self.sequence = check_sequence(self.sequence, "GimbalCommand.sequence")

    def _write(self, w: Writer) -> None:
        w.u8(COMMAND_KINDS.index(self.kind))
        w.f64(self.pan_rad)
        w.f64(self.tilt_rad)
        w.opt_f64(self.speed_rad_s)
        w.f64(self.stamp_s)
        w.u64(self.sequence)

    @classmethod
    def _read(cls, r: Reader, version: int) -> GimbalCommand:
        code = r.u8("kind")
        if code >= len(COMMAND_KINDS):
            raise MessageError(f"GimbalCommand.kind code {code} unknown")
        return cls(
            COMMAND_KINDS[code],
            r.f64("pan_rad"),
            r.f64("tilt_rad"),
            r.opt_f64("speed_rad_s"),
            r.f64("stamp_s"),
            r.u64("sequence"),
        )


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

    :meth:`from_device` converts the device layer's dataclass (:class:`aes_planner.devices.GimbalState`).
    """

    TYPE_NAME: ClassVar[str] = "GimbalState"
    SCHEMA_VERSION: ClassVar[int] = 1
    MAX_BYTES: ClassVar[int] = 16384

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
        for name in ("pan_rad", "tilt_rad", "goal_pan_rad", "goal_tilt_rad", "stamp_s"):
            setattr(self, name, check_finite(getattr(self, name), f"GimbalState.{name}"))
        if not isinstance(self.moving, bool):
            raise MessageError(f"GimbalState.moving must be a bool, got {self.moving!r}")
        temps = tuple(self.temperature_c) if isinstance(self.temperature_c, (tuple, list)) else None
        if temps is None or len(temps) != 2:
            raise MessageError(f"GimbalState.temperature_c must be (pan, tilt), got {self.temperature_c!r}")
        self.temperature_c = tuple(check_finite(t, "GimbalState.temperature_c") for t in temps)
        if not isinstance(self.hardware_error, (tuple, list)) or len(self.hardware_error) > MAX_FAULTS:
            raise MessageError(f"GimbalState.hardware_error must be a tuple of at most {MAX_FAULTS} strings")
        self.hardware_error = tuple(check_text(f, "GimbalState.hardware_error") for f in self.hardware_error)
        self.sequence = check_sequence(self.sequence, "GimbalState.sequence")
        self.status = check_text(self.status, "GimbalState.status", 64)

    @classmethod
    def from_device(cls, state, *, sequence: int = 0, status: str | None = None) -> GimbalState:
        """From the device layer's state (:class:`aes_planner.devices.GimbalState`)."""
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

    def to_device(self):
        """The device layer's dataclass with the same values."""
        from aes_planner.devices import GimbalState as DeviceState

        return DeviceState(
            pan_rad=self.pan_rad,
            tilt_rad=self.tilt_rad,
            goal_pan_rad=self.goal_pan_rad,
            goal_tilt_rad=self.goal_tilt_rad,
            moving=self.moving,
            temperature_c=self.temperature_c,
            hardware_error=self.hardware_error,
            stamp_s=self.stamp_s,
        )

    def _write(self, w: Writer) -> None:
        for v in (self.pan_rad, self.tilt_rad, self.goal_pan_rad, self.goal_tilt_rad):
            w.f64(v)
        w.bool(self.moving)
        w.f64(self.temperature_c[0])
        w.f64(self.temperature_c[1])
        w.u8(len(self.hardware_error))
        for f in self.hardware_error:
            w.str(f)
        w.f64(self.stamp_s)
        w.u64(self.sequence)
        w.str(self.status)

    @classmethod
    def _read(cls, r: Reader, version: int) -> GimbalState:
        joints = [r.f64(n) for n in ("pan_rad", "tilt_rad", "goal_pan_rad", "goal_tilt_rad")]
        moving = r.bool("moving")
        temps = (r.f64("temperature_c"), r.f64("temperature_c"))
        n = r.u8("hardware_error")
        if n > MAX_FAULTS:
            raise MessageError(f"GimbalState: {n} hardware errors exceed the cap of {MAX_FAULTS}")
        faults = tuple(r.str("hardware_error", 1024) for _ in range(n))
        stamp_s = r.f64("stamp_s")
        sequence = r.u64("sequence")
        status = r.str("status", 256)
        return cls(*joints, moving, temps, faults, stamp_s, sequence, status)
