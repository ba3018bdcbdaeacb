"""Hardware-free device interfaces: the :class:`Device` ABC, the :class:`Gimbal` and
:class:`Camera` interfaces and a registry that maps the ``type:`` word of a launch file to an
implementation. A camera is a device like a motor: the camera nodes read images through
:meth:`Camera.read` whether the camera is an OpenCV capture (``opencv_camera``) or the simulator's
(:class:`aes_planner.sim.SimCamera`, built by the sim nodes from the launch's scene).

Real and simulated implementations are registered side by side::

    gimbal:
      type: dynamixel_pan_tilt        # or emulated_pan_tilt: same driver on the built-in emulator,
      port: /dev/ttyUSB0              # or sim_pan_tilt: an in-process simulation, no serial port

:func:`make_device` looks the type word up, builds the class's config dataclass from the other
keys (unknown keys are errors naming the key) and returns an unconnected device. Implementations
are named by import path, so this module never imports ``aes_planner.drivers`` (or any vendor
SDK) until a launch file asks for one.

Joint angles are **pan** and **tilt** (radians), never yaw/pitch: the kinematics of
:mod:`aes_planner.geometry.rig` turn them into a view, and with a tilted or rotated base the
view's yaw/pitch differ from the joint angles. ``pan`` turns about the base's +z (positive turns
left), ``tilt`` about the pan link's axis (positive looks up).
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

from aes_planner.config import ConfigError, from_dict, tag_of
from aes_planner.errors import AesPlannerError

__all__ = [
    "Device",
    "Camera",
    "CameraError",
    "CameraImage",
    "Gimbal",
    "GimbalReading",
    "GimbalFaults",
    "DeviceError",
    "GimbalCommError",
    "GimbalPortLostError",
    "GimbalHardwareError",
    "GimbalProtocolError",
    "GimbalTimeoutError",
    "DEVICE_TYPES",
    "register_device",
    "device_class",
    "make_device",
    "make_camera",
    "RAW_KEY",
    "joint_command",
    "wait_for_arrival",
]

log = logging.getLogger(__name__)


class DeviceError(AesPlannerError):
    """A device could not do what was asked; the message says what to check."""


class CameraError(DeviceError):
    """A camera gave an image it should not (a size that does not match its calibration...)."""


class GimbalCommError(DeviceError):
    """No valid reply from the gimbal after every retry (cable, power, baud, id, latency)."""


class GimbalPortLostError(GimbalCommError):
    """The serial port disappeared; the driver reopens it when it returns."""


class GimbalProtocolError(DeviceError):
    """A servo answered but refused the instruction (range, access, length)."""


class GimbalTimeoutError(DeviceError):
    """The gimbal did not report arrival at its goal in time."""


class GimbalHardwareError(DeviceError):
    """A servo raised its hardware alert; motion is refused until :meth:`Gimbal.reboot`.

    ``faults`` maps a joint name (``"pan"``, ``"tilt"``) to the fault names it reports
    (``("overload",)``).
    """

    def __init__(self, message: str, faults: Mapping[str, tuple[str, ...]]):
        super().__init__(message)
        self.faults = dict(faults)


@dataclass(frozen=True)
class GimbalReading:
    """What a gimbal reports, read from its servos (the device layer's view, numpy-free so that a
    driver process starts fast). On the bus it travels as the message
    :class:`aes_planner.messages.GimbalState` (``GimbalState.from_device``).

    * ``pan_rad``, ``tilt_rad``: present pan and tilt joint angles (``pan_deg``/``tilt_deg`` too).
    * ``goal_pan_rad``, ``goal_tilt_rad``: the goal the servos are moving to.
    * ``moving``: True while either joint is still moving (or not yet at its goal).
    * ``temperature_c``: (pan, tilt) motor temperatures.
    * ``hardware_error``: active faults as ``"joint: fault"`` strings, empty when healthy.
    * ``stamp_s``: wall-clock time of the reading (``time.time()``), to match camera frames.
    """

    pan_rad: float
    tilt_rad: float
    goal_pan_rad: float
    goal_tilt_rad: float
    moving: bool
    temperature_c: tuple[float, float]
    hardware_error: tuple[str, ...]
    stamp_s: float

    @property
    def pan_deg(self) -> float:
        return math.degrees(self.pan_rad)

    @property
    def tilt_deg(self) -> float:
        return math.degrees(self.tilt_rad)

    @property
    def goal_pan_deg(self) -> float:
        return math.degrees(self.goal_pan_rad)

    @property
    def goal_tilt_deg(self) -> float:
        return math.degrees(self.goal_tilt_rad)

    def summary(self) -> str:
        """One line for logs and the CLI."""
        temps = "/".join(f"{t:.0f}" for t in self.temperature_c)
        fault = ", ".join(self.hardware_error) or "none"
        return (
            f"pan {self.pan_deg:+.2f} deg, tilt {self.tilt_deg:+.2f} deg "
            f"(goal {math.degrees(self.goal_pan_rad):+.2f}, {math.degrees(self.goal_tilt_rad):+.2f}), "
            f"{'moving' if self.moving else 'still'}, {temps} C, hardware error: {fault}"
        )


class Device(ABC):
    """A piece of hardware (or its simulation): connect, use, disconnect.

    Used as a context manager, ``disconnect()`` runs however the block ends. ``disconnect()`` must
    be safe to call twice and on a device that never connected. Subclasses set ``config_class``
    (the dataclass :func:`make_device` builds from a launch file) and take it as their only
    constructor argument.
    """

    config_class: ClassVar[type | None] = None

    @abstractmethod
    def connect(self) -> None:
        """Open the device; raise a :class:`DeviceError` that says what to check when it fails."""

    @abstractmethod
    def disconnect(self) -> None:
        """Leave the device safe (motors unpowered) and release it."""

    @property
    @abstractmethod
    def connected(self) -> bool:
        """True between a successful :meth:`connect` and :meth:`disconnect`."""

    def __enter__(self):
        self.connect()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.disconnect()


class Gimbal(Device):
    """A two-axis pan-tilt gimbal commanded in joint radians.

    Implementations clamp every command to their joint limits (the one clamp a joint command
    passes: :class:`~aes_planner.geometry.rig.JointLimits`), refuse NaN/Inf with
    :class:`~aes_planner.geometry.pantilt.JointCommandError` (nothing is sent), and are safe to
    call from several threads.
    """

    @abstractmethod
    def move_to(self, pan_rad: float, tilt_rad: float) -> tuple[float, float]:
        """Start moving to the joint angles; return the (clamped) angles actually commanded.

        Returns without waiting; see :meth:`wait_until_reached`.
        """

    @abstractmethod
    def state(self) -> GimbalReading:
        """Read the present state."""

    @abstractmethod
    def wait_until_reached(self, timeout_s: float | None = None) -> GimbalReading:
        """Block until the last goal is reached and the joints are still; return that state.

        Raises :class:`GimbalTimeoutError` after ``timeout_s`` (the implementation's default
        when None) and :class:`GimbalHardwareError` when a fault appears on the way.
        """

    def reboot(self) -> None:
        """Clear a latched hardware error (after its cause is removed). No-op by default."""


@dataclass(frozen=True)
class CameraImage:
    """One image read from a :class:`Camera`.

    * ``image``: ``[H, W, 3]`` uint8, RGB, the camera's :attr:`Camera.intrinsics` (undistorted).
    * ``stamp_s``: when it was taken, on the clock the reader gave (:meth:`Camera.read`).
    * ``depth_m``: ``[H, W]`` float32 z-depth in metres where the camera measures it, else None.
    * ``cam2world``: ``[4, 4]`` the pose the camera itself reports (a simulation knows it); None
      when the platform poses it (a rig's kinematics at the gimbal's joints at ``stamp_s``).
    """

    image: Any
    stamp_s: float
    depth_m: Any = None
    cam2world: Any = None


class Camera(Device):
    """A camera: :meth:`read` the next image. ``intrinsics`` (an
    :class:`~aes_planner.geometry.camera.Intrinsics`) is set by the implementation once known
    (from the calibration, or the simulated camera's field of view).

    A camera whose config has a ``undistort`` field (:data:`RAW_KEY`; ``opencv_camera``) gives raw
    frames, as the sensor took them, when it is false: what a calibration needs
    (:func:`make_camera` with ``raw=True``)."""

    intrinsics: Any = None

    @property
    def ready(self) -> bool:
        """True when :meth:`read` can give an image now (connected; a simulated camera: placed)."""
        return self.connected

    @abstractmethod
    def read(self, stamp_s: float) -> CameraImage | None:
        """The next image, stamped ``stamp_s``; None when there is none to give now (a failed
        read, a simulated camera not yet placed). Raises :class:`CameraError` for an image that
        does not match the camera's calibration."""


def joint_command(pan_rad: Any, tilt_rad: Any) -> tuple[float, float]:
    """Two joint angles as floats, or :class:`~aes_planner.geometry.rig.JointCommandError`.

    Accepts anything ``float()`` takes except text and booleans (numpy and 0-d torch scalars
    work); finiteness is checked by the check or clamp that follows (:class:`JointLimits`).
    """
    from aes_planner.geometry.rig import JointCommandError

    try:
        if any(isinstance(v, (str, bytes, bool)) for v in (pan_rad, tilt_rad)):
            raise TypeError(f"got {type(pan_rad).__name__}, {type(tilt_rad).__name__}")
        return float(pan_rad), float(tilt_rad)
    except (TypeError, ValueError, OverflowError) as exc:
        raise JointCommandError(
            f"joint command must be two finite numbers of radians: {exc}; refusing to move"
        ) from None


@runtime_checkable
class GimbalFaults(Protocol):
    """Fault injection offered by the simulated gimbals (``emulated_pan_tilt``: the real driver on
    the servo emulator; ``sim_pan_tilt``), for closed-loop fault tests. Callable mid-run, from any
    thread, while the gimbal is connected. Arguments out of range raise :class:`ValueError`.

    * ``inject_comm_faults(lost=0, corrupt=0, delayed=0, delay_s=None)``: the next replies are
      lost, corrupt (bad CRC) or ``delay_s`` late; the driver retries, then raises
      :class:`GimbalCommError` with torque off.
    * ``inject_hardware_error(joint, fault="overload")``: the servo's alert (``"overload"``,
      ``"overheating"``, ``"input voltage"``, ``"motor encoder"``, ``"electrical shock"``): torque
      off, latched, motion refused until :meth:`Gimbal.reboot`.
    * ``inject_stall(joint, stalled=True)``: an obstruction; waits end in :class:`GimbalTimeoutError`.
    * ``vanish_port()`` / ``restore_port()``: the adapter unplugged (:class:`GimbalPortLostError`)
      and back (the next call reconnects).
    * ``clear_faults()``: no more injected faults (hardware errors stay latched until reboot).
    """

    def inject_comm_faults(
        self, lost: int = 0, corrupt: int = 0, delayed: int = 0, delay_s: float | None = None
    ) -> None: ...

    def inject_hardware_error(self, joint: str, fault: str = "overload") -> None: ...

    def inject_stall(self, joint: str, stalled: bool = True) -> None: ...

    def vanish_port(self) -> None: ...

    def restore_port(self) -> None: ...

    def clear_faults(self) -> None: ...


MAX_WAIT_S = 600.0  # the longest wait_until_reached() accepts


def wait_for_arrival(
    read_state: Callable[[], GimbalReading],
    timeout_s: float,
    tolerance_rad: float,
    poll_interval_s: float,
    *,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    faults: Callable[[], Mapping[str, tuple[str, ...]]] = dict,
    hint: str = "",
) -> GimbalReading:
    """The loop behind :meth:`Gimbal.wait_until_reached`: poll ``read_state()`` until the joints are
    still and within ``tolerance_rad`` of the goal.

    Raises :class:`GimbalHardwareError` (with ``faults()``) as soon as a state reports one,
    :class:`GimbalTimeoutError` after ``timeout_s`` (the last sleep is cut to the deadline, so the
    wait ends at most one ``read_state()`` late), and a :class:`ConfigError` for a timeout outside
    (0, :data:`MAX_WAIT_S`]. ``hint`` is appended to the errors (what to do).
    """
    timeout_s = float(timeout_s)
    if not (math.isfinite(timeout_s) and 0 < timeout_s <= MAX_WAIT_S):
        raise ConfigError("timeout_s", f"must be a number of seconds in (0, {MAX_WAIT_S:g}], got {timeout_s!r}")
    deadline = clock() + timeout_s
    while True:
        st = read_state()
        if st.hardware_error:
            raise GimbalHardwareError(f"stopped on the way: {', '.join(st.hardware_error)}{hint}", faults())
        still = not st.moving
        if (
            still
            and abs(st.pan_rad - st.goal_pan_rad) <= tolerance_rad
            and abs(st.tilt_rad - st.goal_tilt_rad) <= tolerance_rad
        ):
            return st
        remaining_s = deadline - clock()
        if remaining_s <= 0:
            raise GimbalTimeoutError(
                f"the gimbal did not reach its goal within {timeout_s:g} s: {st.summary()}; check for an "
                "obstruction, raise the profile velocity, or allow a longer timeout"
            )
        sleep(min(poll_interval_s, remaining_s))


# type word -> "module:Class". Simulated gimbals register here beside the real ones.
DEVICE_TYPES: dict[str, str | type[Device]] = {
    "dynamixel_pan_tilt": "aes_planner.drivers.dynamixel:DynamixelPanTilt",
    "emulated_pan_tilt": "aes_planner.drivers.emulated:EmulatedPanTilt",
    "sim_pan_tilt": "aes_planner.drivers.sim_gimbal:SimPanTilt",
    "opencv_camera": "aes_planner.drivers.camera:OpenCVCamera",
}


def register_device(type_name: str, target: str | type[Device]) -> None:
    """Register an implementation (a class or ``"module:Class"``) under a launch-file type word."""
    if not type_name or not type_name.replace("_", "").isalnum():
        raise ValueError(f"device type must be a word like 'sim_pan_tilt', got {type_name!r}")
    DEVICE_TYPES[type_name] = target


def device_class(type_name: str, key: str = "type") -> type[Device]:
    """The class registered under ``type_name``, imported on first use."""
    target = DEVICE_TYPES.get(type_name)
    if target is None:
        raise ConfigError(key, f"unknown device type {type_name!r}; known types: {', '.join(sorted(DEVICE_TYPES))}")
    if isinstance(target, type):
        return target
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise DeviceError(
            f"device type {type_name!r} needs the Python module {exc.name!r}, which is not installed; "
            "install the hardware extra: pip install 'aes-planner[hardware]'"
        ) from exc
    return getattr(module, attr)


#: The camera config field that, false, makes a camera give raw (not undistorted) frames.
RAW_KEY = "undistort"


def make_camera(spec: Mapping[str, Any], key: str = "camera", raw: bool = False) -> Camera:
    """An unconnected :class:`Camera` from a launch file's ``camera: {type: word, ...}`` mapping,
    through the same factory as every device (:func:`make_device`). ``raw``: frames as the sensor
    took them, not undistorted (what ``aes-planner calibrate`` reads); a camera type that cannot
    give them is a :class:`~aes_planner.config.ConfigError` naming ``key.type``."""
    if not raw:
        return make_device(spec, key, kind=Camera)  # type: ignore[return-value]
    type_key = f"{key}.type" if key else "type"
    cls = device_class(tag_of(spec, key, DEVICE_TYPES), type_key)
    fields = {f.name for f in dataclasses.fields(cls.config_class)} if cls.config_class is not None else set()
    if not issubclass(cls, Camera) or RAW_KEY not in fields:
        raise ConfigError(
            type_key,
            f"calibration reads raw (not undistorted) frames, and camera type {spec['type']!r} cannot give them "
            f"(its config has no {RAW_KEY!r} setting); use a camera type that has one, e.g. opencv_camera",
        )
    return make_device({**spec, RAW_KEY: False}, key, kind=Camera)  # type: ignore[return-value]


def make_device(spec: Mapping[str, Any], key: str = "", kind: type[Device] = Device) -> Device:
    """Build an unconnected device from a launch-file mapping ``{type: word, <config keys>}``;
    ``kind``: the interface the caller needs (a :class:`Gimbal`, a :class:`Camera`)."""
    type_key = f"{key}.type" if key else "type"
    cls = device_class(tag_of(spec, key, DEVICE_TYPES), type_key)
    if not issubclass(cls, kind):
        raise ConfigError(type_key, f"device type {spec['type']!r} is a {cls.__name__}, not a {kind.__name__}")
    fields = {k: v for k, v in spec.items() if k != "type"}
    if cls.config_class is None:
        if fields:
            raise ConfigError(key, f"device type {spec['type']!r} takes no settings, got {sorted(fields)}")
        return cls()
    return cls(from_dict(cls.config_class, fields, key))
