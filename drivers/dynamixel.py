"""``DynamixelPanTilt``: a pan-tilt gimbal of two Dynamixel X-series servos on ``dynamixel-sdk``.

Protocol 2.0, position mode. The life of a command::

    move_to(pan_rad, tilt_rad)
      -> NaN/Inf refused (JointCommandError, nothing sent); clamped to the joint limits
      -> JointCalibration: radians -> ticks, clamped again to the tick limits
      -> first move only: EEPROM checked (position mode, Min/Max Position Limit = joint limits;
         written with torque off when they differ), profile velocity/acceleration, torque on
      -> one sync write of both goals
    state()  -> one sync read of Goal Position .. Present Temperature of both servos

Faults: every SDK exchange runs under one lock, resets the SDK's ``is_using`` flag afterwards and
is retried with exponential backoff on timeouts and corrupt replies (a short status packet counts
as corrupt; the SDK would index past its end). Late replies: a status packet does not say which
instruction it answers, and the SDK takes any status of the right id. A reply that comes after the
driver gave up on it (a servo on a loaded USB adapter, an emulator starved of CPU) would answer the
next instruction to that servo: a late reply to a READ of Firmware Version (45) once read as a
PING's model number 48429 (its data byte and its CRC's low byte). So every reply must have the
length its instruction calls for (a READ's data, a PING's three bytes, none for a WRITE or a
REBOOT), else it counts as corrupt; and after a try that went unanswered the driver clears the
line before its next instruction: a READ of a length no other exchange uses (and not the length
of the clearing READ before it, whose reply may still be on its way: taken for the new one's, it
left the new one's reply to answer the instruction after it, "Incorrect status packet" on every
try), every status before its reply dropped (servos answer in order). A status with the hardware-alert bit reads
Hardware Error Status, reports the fault in :class:`GimbalReading`, turns torque off on both
servos and refuses motion until :meth:`DynamixelPanTilt.reboot`. Communication lost after every
retry is fatal too (torque off, best effort). :meth:`DynamixelPanTilt.set_patience` makes the
last try of an exchange wait longer for its reply (the gimbal node does on a simulated clock, where
the servos are the emulator and a late reply is the machine's load; docs/guides/clock.md).

Reconnection: a port that disappears (USB cable pulled, adapter reset, emulator restarted)
raises :class:`GimbalPortLostError`. Every later call reopens it once its path exists again (a
missing path costs one ``stat``); a port that opens but whose servos do not answer (still powering
up) is polled again at most once per back-off wait (``reconnect_backoff_s``, doubled after each
failed try, capped at :data:`MAX_RECONNECT_BACKOFF_S`; ``state()`` calls in between raise at once,
while a command, a move or a reboot, always tries). A
reopened bus is identified again (ping, models, latched faults). If the driver had control when
the port went, it takes control again as on a first move (position mode and the position limits
checked in EEPROM, profile velocity/acceleration written, torque on) and re-sends the last goal,
which was clamped to the limits when it was commanded: servos that lost power come back holding
where they were told to be, never somewhere else. A servo that reports a hardware error on
reconnection keeps torque off and refuses motion until :meth:`DynamixelPanTilt.reboot`.
``port_losses``, ``reconnects`` and ``port_lost`` report it (the gimbal node puts them in its
diagnostics).
"""

from __future__ import annotations

import logging
import math
import os
import termios
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import dynamixel_sdk as sdk

from aes_planner.devices import (
    DeviceError,
    Gimbal,
    GimbalCommError,
    GimbalHardwareError,
    GimbalPortLostError,
    GimbalProtocolError,
    GimbalReading,
    joint_command,
    wait_for_arrival,
)
from aes_planner.drivers.dynamixel_config import (  # noqa: F401  (re-exported: the old import paths)
    JOINTS,
    MAX_ARRIVAL_TOLERANCE_DEG,
    MAX_BACKOFF_S,
    MAX_LATENCY_TIMER_MS,
    MAX_MOVE_TIMEOUT_S,
    MAX_POLL_INTERVAL_S,
    MAX_REBOOT_TIMEOUT_S,
    MAX_RECONNECT_BACKOFF_S,
    DynamixelPanTiltConfig,
    EmulatedPanTiltConfig,
    arrival_settings,
)
from aes_planner.drivers.dynamixel_models import (
    SDK_BAUD_RATES,
    OperatingMode,
    ServoModel,
    decode_hardware_error,
    model_by_number,
    supported_models,
    to_signed,
    to_unsigned,
)
from aes_planner.drivers.protocol import ERRBIT_ALERT, ErrNum

log = logging.getLogger(__name__)

__all__ = [
    "DynamixelPanTiltConfig",
    "DynamixelPanTilt",
    "EmulatedPanTiltConfig",
    "ScanResult",
    "scan",
    "SDK_BAUD_RATES",
]

# One sync read covers Goal Position (116) .. Present Temperature (146) on every X-series table.
STATE_FIRST_ITEM, STATE_LAST_ITEM = "goal_position", "present_temperature"

_ERRNUM_TEXT = {
    ErrNum.RESULT_FAIL: "result fail",
    ErrNum.INSTRUCTION: "instruction error",
    ErrNum.CRC: "CRC error",
    ErrNum.DATA_RANGE: "data range error",
    ErrNum.DATA_LENGTH: "data length error",
    ErrNum.DATA_LIMIT: "data limit error",
    ErrNum.ACCESS: "access error",
}
_NO_REPLY_HINT = (
    "check that the servos are powered, that --baud matches their Baud Rate register "
    "(factory default 57600), that the ids are right (aes-planner gimbal scan), that they speak "
    "Protocol 2.0, and the USB adapter's latency timer (README: Real hardware)"
)


class _Port(sdk.PortHandler):
    """The SDK's port with the reply timeout taken from the config instead of a module global."""

    def __init__(self, port_name: str, latency_timer_ms: float):
        super().__init__(port_name)
        self.latency_timer_ms = latency_timer_ms
        self.patience_ms = 0.0  # the least a reply is waited for (DynamixelPanTilt.set_patience)

    def setPacketTimeout(self, packet_length):
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = max(
            self.tx_time_per_byte * packet_length + 2.0 * self.latency_timer_ms + 2.0, self.patience_ms
        )


# I/O errors of a serial port that went away (pyserial raises SerialException, an OSError;
# termios calls raise termios.error).
_PORT_ERRORS = (OSError, termios.error)
#: The lengths of the READs that clear the line after an unanswered try, in turn (no other exchange
#: reads them: items are 1, 2 or 4 bytes, a ping's reply 3, the state's sync read 31). In turn:
#: a clearing READ that went unanswered too leaves its reply on the way, and the next one must not
#: take that reply for its own (it would then leave its own reply to answer the instruction after it).
_SETTLE_READ_LENGTHS = (5, 6, 7, 8)
#: The longest :meth:`DynamixelPanTilt.set_patience` may make a last try wait for its reply.
MAX_PATIENCE_S = 120.0


def _open_port(port_name: str, baud: int, latency_timer_ms: float) -> _Port:
    port = _Port(port_name, latency_timer_ms)
    try:
        ok = port.setBaudRate(baud)  # opens the port
    except _PORT_ERRORS as exc:
        hint = "check that it exists (ls /dev/ttyUSB* /dev/serial/by-id) and that no other program holds it"
        if "Permission denied" in str(exc):
            hint = "add yourself to the dialout group (sudo usermod -aG dialout $USER, then log in again)"
        raise GimbalCommError(f"cannot open serial port {port_name}: {exc}; {hint}") from exc
    if not ok:
        raise GimbalCommError(f"dynamixel-sdk refused baud {baud}; use one of {list(SDK_BAUD_RATES)}")
    return port


def _close_port(port: _Port | None) -> None:
    if port is None or port.ser is None:
        return
    try:
        port.closePort()
    except _PORT_ERRORS:
        pass


class DynamixelPanTilt(Gimbal):
    """Two Dynamixel X-series servos (pan, tilt) as a :class:`~aes_planner.devices.Gimbal`.

    ``connect()`` opens the port and pings both servos (their model must be in
    :data:`~aes_planner.drivers.dynamixel_models.MODELS`); it writes nothing. The first
    :meth:`move_to` takes control (EEPROM, profile, torque on). ``disconnect()`` turns torque off.
    Thread-safe: one lock serialises every exchange on the bus.
    """

    config_class = DynamixelPanTiltConfig

    def __init__(self, config: DynamixelPanTiltConfig):
        if not isinstance(config, DynamixelPanTiltConfig):
            raise TypeError(f"expected a DynamixelPanTiltConfig, got {type(config).__name__}")
        self.config = config
        self._lock = threading.RLock()
        self._ph = sdk.PacketHandler(2.0)
        self._port: _Port | None = None
        self._connected = False
        self._lost = False
        self._in_control = False
        self._cal = {j: config.calibration(j) for j in JOINTS}
        self._limits = config.limits()
        self._models: dict[str, ServoModel] = {}
        self._firmware: dict[str, int] = {}
        self._faults: dict[str, tuple[str, ...]] = {}
        self.torque_losses = 0  # times a move found a servo's torque off behind the driver's back
        self.port_losses = 0  # times the serial port disappeared
        self.reconnects = 0  # times it was reopened and the servos identified again
        self._last_goals: dict[str, int] | None = None  # ticks last sent: re-sent after a reconnection
        self._resume_control = False  # the driver had control when the port went
        self._reopen_wait_s = 0.0
        self._next_reopen_s = 0.0  # time.monotonic() of the next reopening try
        self._late_replies = False  # a try went unanswered: its reply may still come (module docstring)
        self._settles = 0  # clearing READs sent: picks the next one's length (_SETTLE_READ_LENGTHS)
        self.patience_s = 0.0  # how long the last try of an exchange waits for its reply (set_patience)

    # ------------------------------------------------------------------------------ Device
    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def models(self) -> dict[str, str]:
        """Joint -> model name, as the servos reported on connect."""
        return {j: m.name for j, m in self._models.items()}

    @property
    def port_lost(self) -> bool:
        """True from the loss of the serial port until it is reopened."""
        return self._lost

    @property
    def faults(self) -> dict[str, tuple[str, ...]]:
        """Latched hardware faults per joint (empty when healthy)."""
        return dict(self._faults)

    def connect(self) -> None:
        with self._lock:
            if self._connected:
                return
            self._port = _open_port(self.config.port, self.config.baud, self.config.latency_timer_ms)
            try:
                self._identify()
            except BaseException:
                self._release_port()
                raise
            self._connected, self._lost = True, False
            log.info("connected to pan-tilt on %s: %s", self.config.port, self._describe_servos())

    def disconnect(self) -> None:
        """Torque off on both servos (best effort), then close the port. Safe to call twice."""
        with self._lock:
            if self._port is not None and not self._lost:
                self._torque_off_all()
            self._release_port()
            self._connected = self._lost = self._in_control = self._resume_control = False
            self._last_goals = None

    def set_patience(self, last_try_s: float) -> None:
        """Let the last try of every exchange wait up to ``last_try_s`` (wall seconds) for its reply,
        however short the latency timer makes the others (0: as long as they do).

        On a simulated clock the servos are the emulator, whose replies always come unless a fault
        is injected: a reply that is late is the machine's load, not the link's fault. A try that
        times out is retried within the same step, which costs no simulated time; but an exchange
        that failed every try would change the run (a state not published, torque off by the
        fatal path, a move the planner sends again half a move timeout later). Waiting longer on the
        last try makes a loaded run take the same exchanges as an idle one. A reply that comes in
        time ends the wait, so an idle run pays nothing."""
        if not (math.isfinite(last_try_s) and 0.0 <= last_try_s <= MAX_PATIENCE_S):
            raise ValueError(f"last_try_s must be within [0, {MAX_PATIENCE_S:g}] s, got {last_try_s!r}")
        self.patience_s = float(last_try_s)

    # ------------------------------------------------------------------------------ Gimbal
    def move_to(self, pan_rad: float, tilt_rad: float) -> tuple[float, float]:
        """Send both goals in one sync write; returns the clamped joint angles commanded."""
        pan_rad, tilt_rad = joint_command(pan_rad, tilt_rad)
        asked = (pan_rad, tilt_rad)
        pan_rad, tilt_rad = self._limits.clamp(pan_rad, tilt_rad)  # NaN/Inf raise here, nothing is sent
        if (pan_rad, tilt_rad) != asked:
            log.warning(
                "command (%.4g, %.4g) rad clamped to the joint limits: (%.4f, %.4f) rad", *asked, pan_rad, tilt_rad
            )
        goals = {"pan": self._cal["pan"].to_ticks(pan_rad), "tilt": self._cal["tilt"].to_ticks(tilt_rad)}
        with self._lock:
            self._ensure_port()
            if self._faults:
                raise GimbalHardwareError(
                    f"refusing to move: {self._fault_text()}; {self._reboot_hint()}", self._faults
                )
            if self._in_control and not self._torque_still_on():
                self._in_control = False
            if not self._in_control:
                self._take_control()
            self._sync_write("goal_position", goals)
            self._last_goals = goals
        return pan_rad, tilt_rad

    def state(self) -> GimbalReading:
        with self._lock:
            self._ensure_port(polling=True)
            rows, alerts = self._sync_read_state()
            if alerts:
                self._on_alert(alerts)
            hardware_error = tuple(f"{j}: {f}" for j in JOINTS for f in self._faults.get(j, ()))
        stamp_s = time.time()
        pan, tilt = rows["pan"], rows["tilt"]
        return GimbalReading(
            pan_rad=self._cal["pan"].to_rad(pan["present_position"]),
            tilt_rad=self._cal["tilt"].to_rad(tilt["present_position"]),
            goal_pan_rad=self._cal["pan"].to_rad(pan["goal_position"]),
            goal_tilt_rad=self._cal["tilt"].to_rad(tilt["goal_position"]),
            moving=bool(pan["moving"] or tilt["moving"]),
            temperature_c=(float(pan["present_temperature"]), float(tilt["present_temperature"])),
            hardware_error=hardware_error,
            stamp_s=stamp_s,
        )

    def wait_until_reached(self, timeout_s: float | None = None) -> GimbalReading:
        return wait_for_arrival(
            self.state,
            *arrival_settings(self.config, timeout_s),
            clock=time.monotonic,
            sleep=time.sleep,
            faults=lambda: self._faults,
            hint=f"; {self._reboot_hint()}",
        )

    def reboot(self) -> None:
        """REBOOT the faulted servos (all when none is), wait until they answer, clear the latch.

        Torque stays off until the next :meth:`move_to`. Remove the fault's cause first
        (overload: free the joint; overheating: let it cool; voltage: check the supply).
        """
        with self._lock:
            self._resume_control = False  # a reboot leaves torque off, as documented
            self._ensure_port()
            self._in_control = False  # a rebooted servo comes back with torque off
            joints = [j for j in JOINTS if j in self._faults] or list(JOINTS)
            for joint in joints:
                log.warning("rebooting %s servo (id %d)", joint, self.config.joint_id(joint))
                self._exchange(joint, f"reboot {joint}", self._reboot_one)
            deadline = time.monotonic() + self.config.reboot_timeout_s
            for joint in joints:
                while True:
                    try:
                        self._exchange(joint, f"ping {joint}", self._ping, retries=0, fatal=False)
                        break
                    except GimbalCommError:
                        if time.monotonic() > deadline:
                            raise GimbalCommError(
                                f"the {joint} servo (id {self.config.joint_id(joint)}) did not answer within "
                                f"{self.config.reboot_timeout_s:g} s of its reboot; {_NO_REPLY_HINT}"
                            ) from None
                        time.sleep(min(0.01, max(0.0, deadline - time.monotonic())))
            self._faults.clear()
            self._in_control = False
            self._identify()

    # ------------------------------------------------------------------------------ set-up
    def _identify(self) -> None:
        """Ping both servos, check their models, pick up faults they already report."""
        alerts = []
        for joint in JOINTS:
            dxl_id = self.config.joint_id(joint)
            number, err = self._exchange(joint, f"ping {joint}", self._ping)
            model = model_by_number(number)
            if model is None:
                raise DeviceError(
                    f"the {joint} servo (id {dxl_id}) reports model number {number}, which has no control table here; "
                    f"supported: {supported_models()}; add a ServoModel to "
                    "aes_planner/drivers/dynamixel_models.py"
                )
            self._models[joint] = model
            self._firmware[joint] = self._read_item(joint, "firmware_version")
            if err & ERRBIT_ALERT:
                alerts.append(joint)
        if alerts:
            self._on_alert(alerts)

    def _torque_still_on(self) -> bool:
        """Whether both servos still hold the torque the driver turned on. A servo that rebooted
        behind the driver's back (a supply dip, another program's REBOOT) comes back with torque
        off: it would take every goal and never move. Read before each move (one byte a servo)."""
        off = [joint for joint in JOINTS if not self._read_item(joint, "torque_enable")]
        if off:
            self.torque_losses += 1
            log.warning(
                "%s servo: torque is off though the driver had turned it on (did it reboot? check the supply); "
                "taking control again",
                " and ".join(off),
            )
        return not off

    def _take_control(self) -> None:
        """Position mode and limits in EEPROM (written only when they differ), profile, torque on.

        A failure half-way leaves both servos with torque off, never one holding alone.
        """
        try:
            self._configure_and_enable()
        except BaseException:
            self._torque_off_all()
            raise
        self._in_control = True
        log.info(
            "torque on: pan limits %s deg, tilt limits %s deg", self.config.pan_limits_deg, self.config.tilt_limits_deg
        )

    def _configure_and_enable(self) -> None:
        c = self.config
        for joint in JOINTS:
            model = self._models[joint]
            lo, hi = self._cal[joint].tick_limits
            wanted = {"operating_mode": OperatingMode.POSITION, "min_position_limit": lo, "max_position_limit": hi}
            present = {name: self._read_item(joint, name) for name in wanted}
            if present != wanted:
                if self._read_item(joint, "torque_enable"):
                    log.warning("%s servo: torque off to update its EEPROM (%s -> %s)", joint, present, wanted)
                    self._write_item(joint, "torque_enable", 0)
                for name, value in wanted.items():
                    if present[name] != value:
                        self._write_item(joint, name, value)
            self._write_item(joint, "profile_acceleration", model.acceleration_units(c.profile_acceleration_deg_s2))
            self._write_item(joint, "profile_velocity", model.velocity_units(c.profile_velocity_deg_s))
            self._write_item(joint, "torque_enable", 1)

    def _describe_servos(self) -> str:
        return ", ".join(
            f"{j} id {self.config.joint_id(j)} {self._models[j].name} fw {self._firmware[j]}" for j in self._models
        )

    # ------------------------------------------------------------------------------ faults
    def _on_alert(self, joints: Sequence[str]) -> None:
        """Hardware alert: read which fault, latch it, torque off everywhere (fatal)."""
        new = False
        for joint in joints:
            try:
                status = self._read_item(joint, "hardware_error_status")
            except (GimbalCommError, GimbalProtocolError):
                status = 0
            faults = decode_hardware_error(status) or ("unknown hardware error",)
            if self._faults.get(joint) != faults:
                new = True
                self._faults[joint] = faults
        if new:
            log.error("hardware error: %s; turning torque off; %s", self._fault_text(), self._reboot_hint())
            self._torque_off_all()

    def _fault_text(self) -> str:
        return "; ".join(
            f"{j} servo (id {self.config.joint_id(j)}) reports {', '.join(f)}" for j, f in self._faults.items()
        )

    @staticmethod
    def _reboot_hint() -> str:
        return "remove the cause (free the joint, let it cool, check the supply), then call reboot() / run `aes-planner gimbal reboot`"

    def _torque_off_all(self) -> None:
        """Best effort with every retry: a failure is logged, never raised (this runs on the way
        out of errors)."""
        self._in_control = False
        for joint in JOINTS:
            if joint not in self._models or self._port is None:
                continue
            try:
                self._write_item(joint, "torque_enable", 0)
            except DeviceError as exc:
                log.error("could not turn torque off on the %s servo: %s", joint, exc)

    def _port_lost(self, exc: BaseException) -> GimbalPortLostError:
        self._release_port()
        if not self._lost:
            self.port_losses += 1
            self._reopen_wait_s = 0.0
            self._next_reopen_s = 0.0  # the first try is on the next call
        # lost again while taking control back: still to be resumed
        self._resume_control = self._resume_control or self._in_control
        self._lost, self._in_control = True, False
        log.error("serial port %s lost: %s", self.config.port, exc)
        return GimbalPortLostError(
            f"serial port {self.config.port} disappeared ({exc}); check the USB cable and the adapter's power; "
            "the driver reopens it on a later call once it is back"
        )

    def _ensure_port(self, polling: bool = False) -> None:
        """Reopen a lost port and resume control (module docstring). A poll (``state()``) tries at
        most once per back-off wait; a command (a move, a reboot) always tries at once."""
        if not self._connected:
            raise DeviceError("the gimbal is not connected; call connect() first or use it in a `with` block")
        if not (self._lost or self._resume_control):
            return
        if self._lost and not os.path.exists(self.config.port):  # cheap: no back-off needed
            raise GimbalPortLostError(f"serial port {self.config.port} is still missing; reconnect the adapter")
        now = time.monotonic()
        if polling and now < self._next_reopen_s:
            raise GimbalPortLostError(
                f"serial port {self.config.port} is back but the servos did not answer the last try; "
                f"next try in {self._next_reopen_s - now:.2f} s"
            )
        try:
            if self._lost:
                self._reopen()
            if self._resume_control:
                self._resume()
        except DeviceError:
            self._reopen_wait_s = min(
                MAX_RECONNECT_BACKOFF_S, max(self.config.reconnect_backoff_s, 2.0 * self._reopen_wait_s)
            )
            self._next_reopen_s = time.monotonic() + self._reopen_wait_s
            raise

    def _reopen(self) -> None:
        """Open the port again and identify the servos; raises while the port or they are not back."""
        try:
            self._port = _open_port(self.config.port, self.config.baud, self.config.latency_timer_ms)
        except GimbalCommError as exc:
            raise GimbalPortLostError(
                f"serial port {self.config.port} is still missing; reconnect the adapter ({exc})"
            ) from None
        try:
            self._identify()
        except DeviceError:
            self._release_port()
            raise
        self._lost = False
        self.reconnects += 1
        log.warning("serial port %s is back; reconnected (%s)", self.config.port, self._describe_servos())

    def _resume(self) -> None:
        """After a reconnection, take control again as the driver had it: EEPROM mode and limits,
        profile, torque on (all off again if any step fails), then the last goal, which was clamped
        to the limits when it was commanded. Not while a servo reports a hardware error."""
        if self._faults:
            log.error("after reconnecting: %s; torque stays off; %s", self._fault_text(), self._reboot_hint())
            self._resume_control = False
            return
        self._take_control()
        if self._last_goals is not None:
            self._sync_write("goal_position", self._last_goals)
        self._resume_control = False
        log.warning("torque on again, holding the last goal (%s ticks)", self._last_goals)

    def _release_port(self) -> None:
        _close_port(self._port)
        self._port = None
        self._late_replies = False  # whatever was on its way went with the port

    # ------------------------------------------------------------------------------ exchanges
    def _exchange(
        self,
        joint: str | None,
        what: str,
        fn: Callable[..., tuple],
        *args: Any,
        retries: int | None = None,
        fatal: bool = True,
    ):
        """One SDK exchange, retried: ``fn(port, id, *args) -> (value, comm_result, error)``.

        Returns ``(value, error_byte)``. Timeouts, corrupt or short replies and CRC-error statuses
        are retried with backoff; other error statuses raise :class:`GimbalProtocolError`; a port
        error raises :class:`GimbalPortLostError`; exhausted retries raise :class:`GimbalCommError`,
        after turning torque off (best effort) when the driver had it on, unless ``fatal`` is False
        (a poll that is expected to fail for a while). ``joint`` None means a broadcast exchange
        (``fn(port, *args)``).
        """
        retries = self.config.retries if retries is None else retries
        dxl_id = None if joint is None else self.config.joint_id(joint)
        wait_s = self.config.backoff_s
        comm = sdk.COMM_SUCCESS
        for attempt in range(retries + 1):
            with self._lock:
                port = self._port
                if port is None:
                    raise GimbalPortLostError(f"serial port {self.config.port} is not open; call connect()")
                # the last try is patient (set_patience), unless failing is expected (a rebooting servo's poll)
                port.patience_ms = 1000.0 * self.patience_s if attempt == retries and fatal else 0.0
                try:
                    settled = self._settle_line(port) if self._late_replies else sdk.COMM_SUCCESS
                    if settled != sdk.COMM_SUCCESS:
                        value, comm, err = None, settled, 0  # not sent: the line is not clear yet
                    else:
                        value, comm, err = fn(port, *args) if dxl_id is None else fn(port, dxl_id, *args)
                except IndexError:
                    value, comm, err = None, sdk.COMM_RX_CORRUPT, 0  # the SDK indexed a short status packet
                except _PORT_ERRORS as exc:
                    raise self._port_lost(exc) from exc
                finally:
                    port.is_using = False
                    port.patience_ms = 0.0
                if comm not in (sdk.COMM_SUCCESS, sdk.COMM_NOT_AVAILABLE):
                    self._late_replies = True  # unanswered, or answered by something else: more may come
            if comm == sdk.COMM_SUCCESS:
                errnum = err & ~ERRBIT_ALERT
                if errnum == ErrNum.NONE:
                    return value, err
                if errnum != ErrNum.CRC:
                    raise GimbalProtocolError(
                        f"{what}: the servo (id {dxl_id}) answered with a {_ERRNUM_TEXT.get(errnum, f'error {errnum}')}; "
                        "this is a driver or control-table bug, please report it with this message"
                    )
                reason = "the servo saw a corrupt instruction (CRC error status)"
            else:
                reason = self._ph.getTxRxResult(comm) or f"result {comm}"
            if attempt < retries:
                log.debug("%s: %s; retry %d/%d in %.3f s", what, reason, attempt + 1, retries, wait_s)
                time.sleep(wait_s)
                wait_s = min(2 * wait_s, MAX_BACKOFF_S)
        if fatal:
            log.error("%s failed after %d tries: %s", what, retries + 1, reason)
            if self._in_control:
                self._torque_off_all()  # the bus no longer answers while the motors hold
        who = f"id {dxl_id}" if dxl_id is not None else "ids " + ", ".join(str(self.config.joint_id(j)) for j in JOINTS)
        raise GimbalCommError(
            f"{what}: no valid reply from {who} on {self.config.port} "
            f"at {self.config.baud} baud after {retries + 1} tries ({reason}); {_NO_REPLY_HINT}"
        )

    def _read_item(self, joint: str, name: str, retries: int | None = None) -> int:
        item = self._models[joint].item(name)

        def read(port, dxl_id):
            # readTxRx would slice the CRC into the data of a short reply: build the READ here
            # and check the status packet's length field
            tx = [0] * 14
            tx[4], tx[5], tx[6], tx[7] = dxl_id, 7, 0, sdk.INST_READ
            tx[8:12] = [item.addr & 0xFF, item.addr >> 8, item.size & 0xFF, item.size >> 8]
            rx, comm, _ = self._ph.txRxPacket(port, tx)
            return _status_data(rx, comm, item.size)

        data, _ = self._exchange(joint, f"read {name} of {joint}", read, retries=retries)
        raw = int.from_bytes(bytes(data), "little")
        return to_signed(raw, item.size) if item.signed else raw

    def _write_item(self, joint: str, name: str, value: int, retries: int | None = None) -> None:
        item = self._models[joint].item(name)
        value = int(value)
        if (item.lo is not None and value < item.lo) or (item.hi is not None and value > item.hi):
            # never let to_unsigned() wrap a value into something else
            raise DeviceError(
                f"refusing to write {name}={value} to the {joint} servo: its range is {item.lo}..{item.hi}"
            )
        data = list(to_unsigned(value, item.size).to_bytes(item.size, "little"))
        what = "torque off" if (name, value) == ("torque_enable", 0) else f"write {name}={value} to {joint}"

        def write(port, dxl_id):
            tx = [0] * (12 + item.size)
            length = 5 + item.size  # INST + address + data + CRC
            tx[4], tx[5], tx[6], tx[7] = dxl_id, length & 0xFF, length >> 8, sdk.INST_WRITE
            tx[8], tx[9] = item.addr & 0xFF, item.addr >> 8
            tx[10 : 10 + item.size] = data
            rx, comm, _ = self._ph.txRxPacket(port, tx)
            _, comm, err = _status_data(rx, comm, 0)
            return None, comm, err

        self._exchange(joint, what, write, retries=retries)

    def _ping(self, port, dxl_id: int) -> tuple[int | None, int, int]:
        """PING with its reply's length checked (three data bytes: model number, firmware); the
        SDK's ping would take any status of the id (module docstring). ``(model number, comm, error)``."""
        tx = [0] * 10
        tx[4], tx[5], tx[6], tx[7] = dxl_id, 3, 0, sdk.INST_PING
        rx, comm, _ = self._ph.txRxPacket(port, tx)
        data, comm, err = _status_data(rx, comm, 3)
        return (None if data is None else data[0] | data[1] << 8), comm, err

    def _reboot_one(self, port, dxl_id: int) -> tuple[None, int, int]:
        """REBOOT with its reply checked (a status without data)."""
        tx = [0] * 10
        tx[4], tx[5], tx[6], tx[7] = dxl_id, 3, 0, sdk.INST_REBOOT
        rx, comm, _ = self._ph.txRxPacket(port, tx)
        _, comm, err = _status_data(rx, comm, 0)
        return None, comm, err

    def _settle_line(self, port) -> int:
        """Clear the line of late replies before the next instruction (module docstring): a READ
        at address 0 (Model Number, Model Information, ...) of 5 to 8 bytes in turn
        (:data:`_SETTLE_READ_LENGTHS`: no other exchange of the driver reads them) to the pan servo, and every status packet before its reply is
        dropped. Servos answer in order, so once that reply is in, every late one came before it.
        ``COMM_SUCCESS`` when the line is clear, else why not (no reply in time, or only corrupt
        ones): the instruction waits for the next try."""
        n_bytes = _SETTLE_READ_LENGTHS[self._settles % len(_SETTLE_READ_LENGTHS)]
        self._settles += 1
        tx = [0] * 14
        tx[4], tx[5], tx[6], tx[7] = self.config.joint_id("pan"), 7, 0, sdk.INST_READ
        tx[8:12] = [0, 0, n_bytes, 0]
        sent = self._ph.txPacket(port, tx)
        if sent != sdk.COMM_SUCCESS:
            return sent
        port.setPacketTimeout(n_bytes + 11)
        dropped, corrupt = 0, False
        for _ in range(64):  # bounded: each status packet, or the timeout, ends one rxPacket
            rx, comm = self._ph.rxPacket(port, False)
            if comm == sdk.COMM_RX_TIMEOUT:
                break
            if comm == sdk.COMM_SUCCESS and rx[4] == tx[4] and (rx[5] | rx[6] << 8) == n_bytes + 4:
                if dropped:
                    log.debug("dropped %d late replies on %s", dropped, self.config.port)
                self._late_replies = False
                return sdk.COMM_SUCCESS
            dropped += 1
            corrupt = corrupt or comm != sdk.COMM_SUCCESS
        return sdk.COMM_RX_CORRUPT if corrupt else sdk.COMM_RX_TIMEOUT

    def _sync_write(self, name: str, values: dict[str, int]) -> None:
        item = self._models["pan"].item(name)
        if any(self._models[j].item(name) != item for j in values):
            raise DeviceError(f"{name} sits at different addresses on the two servos; sync write needs the same")
        params = {
            self.config.joint_id(j): list(to_unsigned(v, item.size).to_bytes(item.size, "little"))
            for j, v in values.items()
        }

        def send(port):
            group = sdk.GroupSyncWrite(port, self._ph, item.addr, item.size)
            for dxl_id, data in params.items():
                group.addParam(dxl_id, data)
            return None, group.txPacket(), 0

        self._exchange(None, f"sync write {name}", send)

    def _sync_read_state(self) -> tuple[dict[str, dict[str, int]], list[str]]:
        """Sync read Goal Position..Present Temperature of both servos, decoded per item."""
        model = self._models["pan"]
        first, last = model.item(STATE_FIRST_ITEM), model.item(STATE_LAST_ITEM)
        addr, length = first.addr, last.addr + last.size - first.addr
        ids = [self.config.joint_id(j) for j in JOINTS]

        def sync_read(port):
            comm = self._ph.syncReadTx(port, addr, length, ids, len(ids), False)
            if comm != sdk.COMM_SUCCESS:
                return None, comm, 0
            blocks, errors = {}, 0
            for dxl_id in ids:
                for _ in range(8):  # as the SDK's readRx, without trusting the length; bounded
                    rx, comm = self._ph.rxPacket(port, False)
                    if comm != sdk.COMM_SUCCESS or rx[4] == dxl_id:
                        break
                else:
                    return None, sdk.COMM_RX_CORRUPT, 0  # a stream of replies from other ids
                data, comm, err = _status_data(rx, comm, length)
                if comm != sdk.COMM_SUCCESS or data is None:
                    return None, comm, err
                blocks[dxl_id] = (data, err)
                errors |= err
            return blocks, sdk.COMM_SUCCESS, errors

        blocks, _ = self._exchange(None, "sync read state", sync_read)
        rows, alerts = {}, []
        for joint, dxl_id in zip(JOINTS, ids):
            data, err = blocks[dxl_id]
            table = self._models[joint].table
            row = {}
            for name in ("goal_position", "moving", "present_position", "present_temperature"):
                item = table[name]
                raw = int.from_bytes(data[item.addr - addr : item.addr - addr + item.size], "little")
                row[name] = to_signed(raw, item.size) if item.signed else raw
            rows[joint] = row
            if err & ERRBIT_ALERT:
                alerts.append(joint)
        return rows, alerts


def _status_data(rx: list | None, comm: int, length: int) -> tuple[bytes | None, int, int]:
    """``(data, comm_result, error)`` of a status packet that must carry ``length`` data bytes.

    A reply of another length is corrupt (the SDK would hand back CRC bytes as data, or index
    past the end), unless it is an error status, which carries no data and is reported as such.
    """
    if comm != sdk.COMM_SUCCESS:
        return None, comm, 0
    err = rx[8]
    if (rx[5] | rx[6] << 8) != length + 4:  # LEN = INST + ERR + data + CRC
        return None, (sdk.COMM_SUCCESS if err & ~ERRBIT_ALERT else sdk.COMM_RX_CORRUPT), err
    return bytes(rx[9 : 9 + length]), comm, err


@dataclass(frozen=True)
class ScanResult:
    """One servo found by :func:`scan`."""

    dxl_id: int
    model_number: int
    model_name: str
    firmware_version: int


def scan(port: str, baud: int = 1_000_000, latency_timer_ms: float = 16.0) -> list[ScanResult]:
    """Broadcast-ping the bus; every servo at this baud answers with its model and firmware."""
    if baud not in SDK_BAUD_RATES:
        raise GimbalCommError(f"baud {baud} is not one of {list(SDK_BAUD_RATES)}")
    handle = _open_port(port, baud, latency_timer_ms)
    ph = sdk.PacketHandler(2.0)
    try:
        found, comm = ph.broadcastPing(handle)
    except _PORT_ERRORS as exc:
        raise GimbalPortLostError(f"serial port {port} failed during the scan: {exc}") from exc
    finally:
        handle.is_using = False
        _close_port(handle)
    if comm != sdk.COMM_SUCCESS and not found:
        raise GimbalCommError(
            f"no servo answered on {port} at {baud} baud ({ph.getTxRxResult(comm)}); {_NO_REPLY_HINT}"
        )
    out = []
    for dxl_id, (number, firmware) in sorted(found.items()):
        model = model_by_number(number)
        out.append(ScanResult(dxl_id, number, model.name if model else "unknown model", firmware))
    return out
