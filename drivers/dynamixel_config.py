"""Settings of the Dynamixel pan-tilt: :class:`DynamixelPanTiltConfig` (``dynamixel_pan_tilt``)
and :class:`EmulatedPanTiltConfig` (``emulated_pan_tilt``).

No SDK import here: a launch file or a ``--config`` file is validated without the hardware extra.
Servo facts (baud tables, register ranges) come from :mod:`.dynamixel_models`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from aes_planner.config import ConfigError, require, require_numbers
from aes_planner.devices import MAX_WAIT_S
from aes_planner.drivers.dynamixel_models import MODELS, SDK_BAUD_RATES, JointCalibration, model_by_name
from aes_planner.geometry.rig import JointLimits, PanTiltConfig

__all__ = [
    "DynamixelPanTiltConfig",
    "EmulatedPanTiltConfig",
    "JOINTS",
    "MAX_LATENCY_TIMER_MS",
    "MAX_BACKOFF_S",
    "MAX_POLL_INTERVAL_S",
    "MAX_MOVE_TIMEOUT_S",
    "MAX_REBOOT_TIMEOUT_S",
    "MAX_RECONNECT_BACKOFF_S",
    "MAX_ARRIVAL_TOLERANCE_DEG",
    "arrival_settings",
    "joint_limits",
]

JOINTS = ("pan", "tilt")
# Upper bounds of the time-like settings: a value that passes validation never hangs a command.
MAX_LATENCY_TIMER_MS = 255.0  # the FTDI latency timer's own maximum
MAX_BACKOFF_S = 1.0  # also the cap of each doubled wait between retries
MAX_POLL_INTERVAL_S = 1.0
MAX_MOVE_TIMEOUT_S = MAX_WAIT_S
MAX_REBOOT_TIMEOUT_S = 60.0
MAX_RECONNECT_BACKOFF_S = 2.0  # also the cap of each doubled wait between tries to reopen a lost port
MAX_ARRIVAL_TOLERANCE_DEG = 45.0


def joint_limits(pan_limits_deg, tilt_limits_deg) -> JointLimits:
    """A gimbal config's joint limits, through the rig's own checks (finite, min < max, tilt within
    +-90 deg, pan within 360 deg); a failure is the config's :class:`ConfigError` (its key and
    message, no chained traceback)."""
    try:
        rig = PanTiltConfig(pan_limits_deg=tuple(pan_limits_deg), tilt_limits_deg=tuple(tilt_limits_deg))
    except ConfigError as exc:
        raise ConfigError(exc.key, exc.message) from None
    return JointLimits.from_config(rig)


def arrival_settings(config, timeout_s: float | None) -> tuple[float, float, float]:
    """``(timeout_s, tolerance_rad, poll_interval_s)`` for :func:`~aes_planner.devices.wait_for_arrival`
    from a gimbal config's ``move_timeout_s`` (unless ``timeout_s`` is given),
    ``arrival_tolerance_deg`` and ``poll_interval_s``: the real and the simulated pan-tilt share them."""
    return (
        config.move_timeout_s if timeout_s is None else timeout_s,
        math.radians(config.arrival_tolerance_deg),
        config.poll_interval_s,
    )


@dataclass
class DynamixelPanTiltConfig:
    """Settings of a Dynamixel pan-tilt (the ``dynamixel_pan_tilt`` launch type).

    * ``port``: serial device (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``); ``baud``: the servos'
      rate (one of :data:`SDK_BAUD_RATES`).
    * ``pan_id``/``tilt_id``: servo ids. ``*_zero_offset_ticks``: servo ticks from the centre
      (2048) to the joint's zero; ``*_direction``: +1 when positive servo ticks turn the joint
      positive (pan left, tilt up), else -1.
    * ``*_limits_deg``: joint limits, written to Min/Max Position Limit and enforced in software.
    * ``profile_velocity_deg_s``/``profile_acceleration_deg_s2``: motion profile (0 = no limit);
      refused beyond what the servos can be set to (about 1400 deg/s, the Velocity Limit register's
      range, and 700000 deg/s^2, the Profile Acceleration register's).
    * ``retries``/``backoff_s``: retries of a failed exchange (0..20), the first wait (doubling
      after, each wait at most :data:`MAX_BACKOFF_S`).
    * ``latency_timer_ms``: the USB adapter's latency timer; the SDK waits ``2 x`` this plus
      transmission time for a reply. 16 is the FTDI default; 1 after the udev rule of docs/guides/hardware.md.
    * ``move_timeout_s``: default of :meth:`DynamixelPanTilt.wait_until_reached`;
      ``arrival_tolerance_deg``: how close counts as arrived; ``poll_interval_s``: its poll rate.
    * ``reboot_timeout_s``: how long a rebooted servo may take to answer again.
    * ``reconnect_backoff_s``: after a lost port, the wait between tries to reopen it (doubling
      after each failed try, each wait at most :data:`MAX_RECONNECT_BACKOFF_S`).

    Every time-like setting has an upper bound (``MAX_*`` in this module), so that no value that
    passes validation can make a command hang.
    """

    port: str
    baud: int = 1_000_000
    pan_id: int = 1
    tilt_id: int = 2
    pan_zero_offset_ticks: int = 0
    tilt_zero_offset_ticks: int = 0
    pan_direction: int = 1
    tilt_direction: int = 1
    pan_limits_deg: tuple[float, float] = (-150.0, 150.0)
    tilt_limits_deg: tuple[float, float] = (-60.0, 60.0)
    profile_velocity_deg_s: float = 60.0
    profile_acceleration_deg_s2: float = 300.0
    retries: int = 3
    backoff_s: float = 0.005
    latency_timer_ms: float = 16.0
    move_timeout_s: float = 10.0
    arrival_tolerance_deg: float = 1.0
    poll_interval_s: float = 0.01
    reboot_timeout_s: float = 2.0
    reconnect_backoff_s: float = 0.05

    def __post_init__(self):
        self._check_port()
        require(
            self.baud in SDK_BAUD_RATES,
            "baud",
            f"{self.baud} is not a rate both dynamixel-sdk and X-series servos use; one of {list(SDK_BAUD_RATES)}",
        )
        for name in ("pan_id", "tilt_id"):
            require(0 <= getattr(self, name) <= 252, name, f"servo ids are 0..252, got {getattr(self, name)}")
        require(self.pan_id != self.tilt_id, "tilt_id", f"pan and tilt need different ids, both are {self.pan_id}")
        for name in ("pan_direction", "tilt_direction"):
            require(getattr(self, name) in (1, -1), name, f"must be 1 or -1, got {getattr(self, name)}")
        self.limits()  # the rig's own checks of the two ranges
        for joint in JOINTS:
            lo, hi = self.calibration(joint).tick_limits
            require(
                0 <= lo and hi <= 4095,
                f"{joint}_limits_deg",
                f"the limits map to ticks {lo}..{hi}, outside the servo's 0..4095 in position mode; "
                f"narrow the limits or change {joint}_zero_offset_ticks",
            )
        require_numbers(
            self,
            ("profile_velocity_deg_s", "profile_acceleration_deg_s2", "backoff_s", "reconnect_backoff_s"),
            strict=False,
        )
        require(0 <= self.retries <= 20, "retries", f"must be 0..20, got {self.retries}")
        require_numbers(
            self, ("latency_timer_ms", "move_timeout_s", "arrival_tolerance_deg", "poll_interval_s", "reboot_timeout_s")
        )
        for name, bound, unit in (
            ("latency_timer_ms", MAX_LATENCY_TIMER_MS, "ms (the FTDI latency timer's maximum; 16 is its default)"),
            ("backoff_s", MAX_BACKOFF_S, "s"),
            ("poll_interval_s", MAX_POLL_INTERVAL_S, "s"),
            ("move_timeout_s", MAX_MOVE_TIMEOUT_S, "s"),
            ("reboot_timeout_s", MAX_REBOOT_TIMEOUT_S, "s"),
            ("reconnect_backoff_s", MAX_RECONNECT_BACKOFF_S, "s"),
            ("arrival_tolerance_deg", MAX_ARRIVAL_TOLERANCE_DEG, "deg"),
        ):
            require(
                getattr(self, name) <= bound, name, f"must be at most {bound:g} {unit}, got {getattr(self, name)!r}"
            )
        # in the control table's units, for every model the driver may find on the bus: a value the
        # 32-bit register cannot hold would wrap (1e30 deg/s -> 0 = "no limit")
        for name, limit in (
            ("profile_velocity_deg_s", "max_profile_velocity_deg_s"),
            ("profile_acceleration_deg_s2", "max_profile_acceleration_deg_s2"),
        ):
            bound = min(getattr(m, limit) for m in MODELS)
            require(
                getattr(self, name) <= bound,
                name,
                f"must be at most {bound:.6g} (the servos' register range; 0 = no limit), got {getattr(self, name)!r}",
            )

    def _check_port(self) -> None:
        require(isinstance(self.port, str) and bool(self.port), "port", "set the serial device, e.g. /dev/ttyUSB0")

    def limits(self) -> JointLimits:
        return joint_limits(self.pan_limits_deg, self.tilt_limits_deg)

    def calibration(self, joint: str) -> JointCalibration:
        lo, hi = getattr(self, f"{joint}_limits_deg")
        return JointCalibration(
            zero_offset_ticks=getattr(self, f"{joint}_zero_offset_ticks"),
            direction=getattr(self, f"{joint}_direction"),
            limits_rad=(math.radians(lo), math.radians(hi)),
        )

    def joint_id(self, joint: str) -> int:
        return getattr(self, f"{joint}_id")


@dataclass
class EmulatedPanTiltConfig(DynamixelPanTiltConfig):
    """The ``emulated_pan_tilt`` launch type: the same driver on a built-in servo emulator.

    ``models`` are the emulated servos, ids 1..N in order (pan and tilt ids must be among them);
    ``port``, when set, is a symlink path the emulator keeps pointing at its pty.
    """

    port: str = ""
    models: tuple[str, ...] = ("xm430-w350", "xm430-w350")

    def _check_port(self) -> None:
        require(isinstance(self.port, str), "port", f"a symlink path or empty, got {self.port!r}")

    def __post_init__(self):
        super().__post_init__()
        for i, name in enumerate(self.models):
            try:
                model_by_name(name)
            except KeyError as exc:
                raise ConfigError(f"models[{i}]", str(exc.args[0])) from None
        for name in ("pan_id", "tilt_id"):
            require(
                1 <= getattr(self, name) <= len(self.models),
                name,
                f"the emulator gives ids 1..{len(self.models)}; got {getattr(self, name)}",
            )
