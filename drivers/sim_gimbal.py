"""``SimPanTilt``: a light in-process simulated pan-tilt gimbal, no serial port, no SDK.

The ``sim_pan_tilt`` launch type, for fast node tests and simulated closed loops. It keeps the
:class:`~aes_planner.devices.Gimbal` contract of the real driver:

* ``move_to(pan_rad, tilt_rad)`` refuses NaN/Inf (:class:`JointCommandError`, nothing changes),
  clamps to the joint limits, turns torque on and returns the clamped goal at once;
* each joint moves toward its goal with a trapezoidal profile (``max_velocity_deg_s``,
  ``max_acceleration_deg_s2``), integrated in steps of at most 2 ms whenever the gimbal is read;
* torque off (``disconnect()``, a hardware error, communication lost after the retries) stops
  the joints where they are;
* time comes from ``clock`` (seconds; ``time.time`` by default, so that ``GimbalReading.stamp_s``
  is wall-clock time as on the real driver) and waits go through ``sleep``. Pass a
  :class:`SimClock` to run faster than real time: its ``sleep`` advances it instantly.

Fault injection (the same method names as :class:`~aes_planner.drivers.emulated.EmulatedPanTilt`,
so that a test can drive either):

* :meth:`SimPanTilt.inject_hardware_error` -- a servo alert (``"overload"``, ...): torque off on
  both joints, latched, motion refused until :meth:`SimPanTilt.reboot`;
* :meth:`SimPanTilt.inject_comm_faults` -- the next replies are lost, corrupt or late; each call
  retries ``retries`` times as the driver does, then raises :class:`GimbalCommError` with torque
  off; a late reply costs ``delay_s`` of (simulated) time;
* :meth:`SimPanTilt.vanish_port` / :meth:`SimPanTilt.restore_port` -- calls raise
  :class:`GimbalPortLostError` until the port is back;
* :meth:`SimPanTilt.inject_stall` -- a joint stops moving (an obstruction): waits time out.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from aes_planner.config import require, require_numbers
from aes_planner.devices import (
    DeviceError,
    Gimbal,
    GimbalCommError,
    GimbalHardwareError,
    GimbalPortLostError,
    GimbalReading,
    joint_command,
    wait_for_arrival,
)
from aes_planner.drivers.dynamixel_config import (
    MAX_ARRIVAL_TOLERANCE_DEG,
    MAX_MOVE_TIMEOUT_S,
    MAX_POLL_INTERVAL_S,
    arrival_settings,
    joint_limits,
)
from aes_planner.drivers.dynamixel_models import HARDWARE_ERROR_BITS
from aes_planner.drivers.motion import trapezoid_step
from aes_planner.geometry.rig import JointLimits

log = logging.getLogger(__name__)

__all__ = ["SimPanTiltConfig", "SimPanTilt", "SimClock", "HARDWARE_FAULTS"]

JOINTS = ("pan", "tilt")
HARDWARE_FAULTS = tuple(HARDWARE_ERROR_BITS.values())
_STEP_S = 0.002
_MAX_VELOCITY_DEG_S = 36_000.0
_MAX_ACCELERATION_DEG_S2 = 1e6


@dataclass
class SimPanTiltConfig:
    """Settings of the simulated pan-tilt (the ``sim_pan_tilt`` launch type).

    * ``pan_limits_deg``/``tilt_limits_deg``: joint limits (the rig's checks apply).
    * ``initial_pan_deg``/``initial_tilt_deg``: where the joints stand at power-up (clamped).
    * ``max_velocity_deg_s``/``max_acceleration_deg_s2``: the motion profile (> 0, bounded).
    * ``move_timeout_s``, ``arrival_tolerance_deg``, ``poll_interval_s``: as on the real driver.
    * ``retries``: how many lost/corrupt replies one call survives (as the driver's retries).
    * ``temperature_c``: what both motors report.
    """

    pan_limits_deg: tuple[float, float] = (-150.0, 150.0)
    tilt_limits_deg: tuple[float, float] = (-60.0, 60.0)
    initial_pan_deg: float = 0.0
    initial_tilt_deg: float = 0.0
    max_velocity_deg_s: float = 60.0
    max_acceleration_deg_s2: float = 300.0
    move_timeout_s: float = 10.0
    arrival_tolerance_deg: float = 1.0
    poll_interval_s: float = 0.01
    retries: int = 3
    temperature_c: float = 30.0

    def __post_init__(self):
        self.limits()  # the rig's own checks of the two ranges
        require_numbers(self, ("initial_pan_deg", "initial_tilt_deg", "temperature_c"), minimum=-math.inf)
        require_numbers(
            self,
            (
                "max_velocity_deg_s",
                "max_acceleration_deg_s2",
                "move_timeout_s",
                "arrival_tolerance_deg",
                "poll_interval_s",
            ),
        )
        for name, bound in (
            ("max_velocity_deg_s", _MAX_VELOCITY_DEG_S),
            ("max_acceleration_deg_s2", _MAX_ACCELERATION_DEG_S2),
            ("move_timeout_s", MAX_MOVE_TIMEOUT_S),
            ("arrival_tolerance_deg", MAX_ARRIVAL_TOLERANCE_DEG),
            ("poll_interval_s", MAX_POLL_INTERVAL_S),
            ("temperature_c", 200.0),
        ):
            require(getattr(self, name) <= bound, name, f"must be at most {bound:g}, got {getattr(self, name)!r}")
        require(
            isinstance(self.retries, int) and 0 <= self.retries <= 20, "retries", f"must be 0..20, got {self.retries!r}"
        )

    def limits(self) -> JointLimits:
        return joint_limits(self.pan_limits_deg, self.tilt_limits_deg)


class SimClock:
    """A manual clock for :class:`SimPanTilt`: ``clock()`` reads it, ``clock.sleep(dt)`` and
    ``clock.advance(dt)`` move it forward instantly (so a 10 s move settles in microseconds)."""

    def __init__(self, start_s: float = 0.0):
        self._now = float(start_s)
        self._lock = threading.Lock()

    def __call__(self) -> float:
        return self._now

    def advance(self, dt_s: float) -> None:
        if not (math.isfinite(dt_s) and dt_s >= 0):
            raise ValueError(f"a clock only moves forward by a finite amount, got {dt_s!r}")
        with self._lock:
            self._now += dt_s

    sleep = advance


class _Joint:
    """One joint's motion: position and velocity in radians, stepped toward ``goal``, stopped at
    ``limits`` (a goal reversed mid-move brakes, and the braking never carries the joint past its
    limit: a servo's position limit stops it there)."""

    def __init__(self, position_rad: float, limits: tuple[float, float]):
        self.limits = limits
        self.position = position_rad
        self.velocity = 0.0
        self.goal = position_rad
        self.stalled = False

    def advance(self, dt: float, v_max: float, a_max: float) -> None:
        if self.stalled:
            self.velocity = 0.0
            return
        while dt > 0.0:
            step = min(dt, _STEP_S)
            dt -= step
            self.position, self.velocity, settled = trapezoid_step(
                self.position, self.velocity, self.goal, v_max, a_max, step
            )
            lo, hi = self.limits
            if not lo <= self.position <= hi:
                self.position, self.velocity = min(max(self.position, lo), hi), 0.0
            if settled:
                return


class SimPanTilt(Gimbal):
    """A simulated :class:`~aes_planner.devices.Gimbal`; see the module docstring.

    ``clock`` returns seconds; ``sleep`` waits (default: ``clock.sleep`` when the clock has one,
    else :func:`time.sleep`). Thread-safe: one lock guards the state.
    """

    config_class = SimPanTiltConfig

    def __init__(
        self,
        config: SimPanTiltConfig | None = None,
        *,
        clock: Callable[[], float] = time.time,
        sleep: Callable[[float], None] | None = None,
    ):
        config = SimPanTiltConfig() if config is None else config
        if not isinstance(config, SimPanTiltConfig):
            raise TypeError(f"expected a SimPanTiltConfig, got {type(config).__name__}")
        self.config = config
        self.clock = clock
        self.sleep = sleep or getattr(clock, "sleep", None) or time.sleep
        self._lock = threading.RLock()
        self._limits = config.limits()
        pan, tilt = self._limits.clamp(math.radians(config.initial_pan_deg), math.radians(config.initial_tilt_deg))
        self._joints = {"pan": _Joint(pan, self._limits.pan_rad), "tilt": _Joint(tilt, self._limits.tilt_rad)}
        self._t_last = clock()
        self._connected = False
        self._torque = False
        self._port_present = True
        self._faults: dict[str, tuple[str, ...]] = {}
        self._comm_faults: list[str] = []  # queued: "lost", "corrupt", "delayed"
        self.delay_s = 0.05
        self.commands: list[tuple[float, float]] = []  # every goal accepted, clamped (pan_rad, tilt_rad)

    # ------------------------------------------------------------------------------ Device
    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def torque_on(self) -> bool:
        return self._torque

    @property
    def faults(self) -> dict[str, tuple[str, ...]]:
        """Latched hardware faults per joint (empty when healthy)."""
        return dict(self._faults)

    def connect(self) -> None:
        with self._lock:
            if not self._port_present:
                raise GimbalCommError("the simulated port is unplugged (vanish_port()); call restore_port() first")
            self._advance()
            self._connected = True

    def disconnect(self) -> None:
        """Torque off (the joints stop where they are). Safe to call twice."""
        with self._lock:
            self._advance()
            self._torque_off()
            self._connected = False

    # ------------------------------------------------------------------------------ Gimbal
    def move_to(self, pan_rad: float, tilt_rad: float) -> tuple[float, float]:
        pan_rad, tilt_rad = joint_command(pan_rad, tilt_rad)
        pan_rad, tilt_rad = self._limits.clamp(pan_rad, tilt_rad)  # NaN/Inf raise here
        with self._lock:
            self._exchange("sync write goal_position")
            if self._faults:
                raise GimbalHardwareError(f"refusing to move: {self._fault_text()}; call reboot()", self._faults)
            self._torque = True
            self._joints["pan"].goal, self._joints["tilt"].goal = pan_rad, tilt_rad
            self.commands.append((pan_rad, tilt_rad))
        return pan_rad, tilt_rad

    def state(self) -> GimbalReading:
        with self._lock:
            self._exchange("sync read state")
            pan, tilt = self._joints["pan"], self._joints["tilt"]
            return GimbalReading(
                pan_rad=pan.position,
                tilt_rad=tilt.position,
                goal_pan_rad=pan.goal,
                goal_tilt_rad=tilt.goal,
                moving=self._torque and any(j.velocity != 0.0 or j.position != j.goal for j in (pan, tilt)),
                temperature_c=(self.config.temperature_c, self.config.temperature_c),
                hardware_error=tuple(f"{j}: {f}" for j in JOINTS for f in self._faults.get(j, ())),
                stamp_s=self._t_last,
            )

    def use_clock(self, clock: Callable[[], float]) -> None:
        """Take time from ``clock`` from now on (a graph's simulated time); the joints stand
        where they are at its present time."""
        self.clock = clock
        self._t_last = clock()

    def wait_until_reached(self, timeout_s: float | None = None) -> GimbalReading:
        return wait_for_arrival(
            self.state,
            *arrival_settings(self.config, timeout_s),
            clock=self.clock,
            sleep=self.sleep,
            faults=lambda: self._faults,
            hint="; call reboot()",
        )

    def reboot(self) -> None:
        """Clear latched faults; torque stays off until the next :meth:`move_to`."""
        with self._lock:
            self._exchange("reboot")
            self._faults.clear()
            self._torque_off()

    # ------------------------------------------------------------------------------ faults
    def inject_hardware_error(self, joint: str, fault: str = "overload") -> None:
        """A servo alert on ``joint``: latched, torque off on both joints (as the driver does)."""
        if joint not in JOINTS:
            raise ValueError(f"joint must be one of {JOINTS}, got {joint!r}")
        if fault not in HARDWARE_FAULTS:
            raise ValueError(f"unknown hardware fault {fault!r}; one of {sorted(HARDWARE_FAULTS)}")
        with self._lock:
            self._advance()
            self._faults[joint] = tuple(sorted(set(self._faults.get(joint, ())) | {fault}))
            self._torque_off()
            log.error("simulated hardware error: %s", self._fault_text())

    def inject_comm_faults(
        self, lost: int = 0, corrupt: int = 0, delayed: int = 0, delay_s: float | None = None
    ) -> None:
        """The next ``lost`` + ``corrupt`` replies fail (each call retries ``retries`` times) and
        ``delayed`` replies come ``delay_s`` late (simulated time through ``sleep``)."""
        for name, n in (("lost", lost), ("corrupt", corrupt), ("delayed", delayed)):
            if not (isinstance(n, int) and 0 <= n <= 10_000):
                raise ValueError(f"{name} must be a count 0..10000, got {n!r}")
        if delay_s is not None:
            if not (math.isfinite(delay_s) and 0 <= delay_s <= 10.0):
                raise ValueError(f"delay_s must be within [0, 10] s, got {delay_s!r}")
            self.delay_s = float(delay_s)
        with self._lock:
            self._comm_faults += ["lost"] * lost + ["corrupt"] * corrupt + ["delayed"] * delayed

    def clear_faults(self) -> None:
        """Drop queued communication faults, un-stall the joints and restore the port (hardware
        errors stay latched until :meth:`reboot`, as on the servos)."""
        with self._lock:
            self._comm_faults.clear()
            for j in self._joints.values():
                j.stalled = False
            self._port_present = True

    def vanish_port(self) -> None:
        """Unplug: every call raises :class:`GimbalPortLostError` until :meth:`restore_port`."""
        with self._lock:
            self._port_present = False

    def restore_port(self) -> None:
        with self._lock:
            self._port_present = True

    def inject_stall(self, joint: str, stalled: bool = True) -> None:
        """An obstruction: ``joint`` stops moving (waits time out) until un-stalled."""
        if joint not in JOINTS:
            raise ValueError(f"joint must be one of {JOINTS}, got {joint!r}")
        with self._lock:
            self._advance()
            self._joints[joint].stalled = stalled

    # ------------------------------------------------------------------------------ internals
    def _exchange(self, what: str) -> None:
        """Check the link and spend the queued communication faults, as one driver exchange."""
        if not self._connected:
            raise DeviceError("the gimbal is not connected; call connect() first or use it in a `with` block")
        if not self._port_present:
            raise GimbalPortLostError(
                "the simulated serial port disappeared (vanish_port()); restore_port() brings it back"
            )
        for _ in range(self.config.retries + 1):
            fault = self._comm_faults.pop(0) if self._comm_faults else None
            if fault == "delayed":
                self.sleep(self.delay_s)
                fault = None
            if fault is None:
                self._advance()
                return
        self._advance()
        self._torque_off()
        raise GimbalCommError(
            f"{what}: no valid reply after {self.config.retries + 1} tries (simulated {fault} replies)"
        )

    def _advance(self) -> None:
        now = self.clock()
        dt = max(0.0, now - self._t_last)
        self._t_last = max(now, self._t_last)
        if not self._torque:
            for j in self._joints.values():
                j.velocity = 0.0
            return
        v_max = math.radians(self.config.max_velocity_deg_s)
        a_max = math.radians(self.config.max_acceleration_deg_s2)
        for j in self._joints.values():
            j.advance(dt, v_max, a_max)

    def _torque_off(self) -> None:
        """The joints stop where they are (the goal is kept, as in the servos' register)."""
        self._torque = False
        for j in self._joints.values():
            j.velocity = 0.0

    def _fault_text(self) -> str:
        return "; ".join(f"{j} servo reports {', '.join(f)}" for j, f in self._faults.items())
