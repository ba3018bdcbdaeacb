"""A stateful Protocol 2.0 servo bus on a pseudo-terminal, for tests and dry runs.

The real ``dynamixel_sdk`` opens the pty's slave side like a USB adapter; the emulator answers on
the master side as a chain of servos would:

* instructions: ping (also broadcast), read, write, reg write + action, reboot, sync read/write,
  bulk read/write; anything else gets an instruction error;
* byte stuffing and CRC both ways; a packet with a bad CRC gets a CRC-error status;
* error statuses: writing a read-only item or EEPROM with torque on (access), values outside an
  item's range (data range), partial items (data length), goal outside the position limits
  (data limit);
* each model's control table (:mod:`.dynamixel_models`), Status Return Level, Return Delay Time,
  and the line's baud rate: a servo whose Baud Rate register does not match the rate the client
  set on the port does not hear it (as on a real bus), and replies take the time their bytes
  need on the wire at that rate (10 bits a byte);
* motion: a trapezoidal profile from Profile Velocity/Acceleration (capped by Velocity Limit and
  the model's top speed), Present Position following Goal Position, Moving and Moving Status;
  torque off or a shutdown stops the motor where it is;
* faults (:class:`FaultPlan`, :meth:`ServoEmulator.inject_hardware_error`,
  :meth:`ServoEmulator.vanish`): dropped, corrupted, truncated and delayed replies, hardware
  errors (overload, overheating, ...), a port that disappears and comes back.

Time: the servos' motion runs on ``clock`` (``time.monotonic`` by default); a graph on a simulated
clock gives them its time through a :class:`FileClock` (``--clock-file``), so a move takes the same
simulated time however slowly the machine runs. The serial line (reply timing, a reboot's deaf
moment) stays in real time: it is the link, not the world.

Run it in a background thread (``with ServoEmulator() as emu: emu.port``), in the foreground
(``aes-planner gimbal emulate``), or in a child process (:class:`EmulatorProcess`, which shares no
GIL with the driver, as real servos would not). State is guarded by ``emu.lock``; tests may inspect
``emu.servos`` and ``emu.goal_log`` under it, after :meth:`ServoEmulator.wait_idle` when a client
has just written (on a loaded machine the I/O loop may not have read its last instructions yet).
"""

from __future__ import annotations

import logging
import math
import os
import queue
import random
import select
import subprocess
import sys
import termios
import threading
import time
import tty
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from aes_planner.devices import DeviceError
from aes_planner.drivers.dynamixel_models import (
    BAUD_RATES,
    CENTER_TICKS,
    HARDWARE_ERROR_BITS,
    TICKS_PER_REV,
    OperatingMode,
    ServoModel,
    model_by_name,
    to_signed,
    to_unsigned,
)
from aes_planner.drivers.motion import trapezoid_step
from aes_planner.drivers.protocol import (
    BROADCAST_ID,
    ERRBIT_ALERT,
    MAX_ID,
    ErrNum,
    Inst,
    Packet,
    PacketParser,
    build_packet,
    build_status,
)
from aes_planner.errors import AesPlannerError

log = logging.getLogger(__name__)

__all__ = [
    "BAUD_RATES",
    "LinkError",
    "check_link_path",
    "FaultPlan",
    "EmulatedServo",
    "ServoBus",
    "ServoEmulator",
    "EmulatorProcess",
    "FileClock",
]

_FAULT_BITS = {name: bit for bit, name in HARDWARE_ERROR_BITS.items()}
_BOOT_TIME_S = 0.05  # a rebooting servo does not answer for this long
MAX_SERVOS = 32  # more than any pan-tilt needs; keeps a typo in --models from building a huge bus


def _termios_bauds() -> dict[int, int]:
    out = {}
    for rate in set(BAUD_RATES.values()) | {19_200, 38_400, 230_400, 460_800, 500_000, 921_600}:
        const = getattr(termios, f"B{rate}", None)
        if const is not None:
            out[const] = rate
    return out


_TERMIOS_BAUDS = _termios_bauds()


class LinkError(AesPlannerError, ValueError):
    """``--link PATH`` names something the emulator must not replace."""


def check_link_path(link: Path) -> None:
    """Raise :class:`LinkError` unless the emulator may put its symlink at ``link``.

    Allowed: nothing there, or a *dangling* symlink (what an emulator that was killed leaves
    behind; its pty is gone). Refused: a file, a directory, a device, or a symlink that still
    points at something that exists (another running emulator's pty, a ``/dev/serial/by-id``
    link, a user's file): never touch what is not ours.
    """
    if not os.path.lexists(link):
        if not link.parent.is_dir():
            raise LinkError(f"--link {link}: the folder {link.parent} does not exist")
        return
    if not link.is_symlink():
        kind = "folder" if link.is_dir() else "file"
        raise LinkError(
            f"--link {link}: a {kind} exists there; choose a path that does not exist (it is never replaced)"
        )
    if link.exists():
        raise LinkError(
            f"--link {link}: a symlink to {os.readlink(link)}, which exists (another emulator or device?), is there; "
            "remove it yourself or choose another path"
        )


@dataclass
class FaultPlan:
    """Faults applied to the emulator's replies, in this order of precedence.

    Counters (``*_next``) apply to the next N reply packets, then count down; rates apply to every
    reply with a seeded random generator (for dry runs with a flaky bus).

    * drop: the reply is not sent (the SDK reports "There is no status packet!").
    * corrupt: the reply's CRC is flipped ("Incorrect status packet!").
    * truncate: the reply loses the second half of its data, with a valid CRC (a short status
      packet: the SDK returns its CRC bytes as data, or raises IndexError).
    * delay: the reply is sent ``delay_s`` late (the bus stays busy meanwhile).
    """

    drop_next: int = 0
    corrupt_next: int = 0
    truncate_next: int = 0
    delay_next: int = 0
    delay_s: float = 0.05
    drop_rate: float = 0.0
    corrupt_rate: float = 0.0
    seed: int = 0

    def __post_init__(self):
        for name in ("drop_rate", "corrupt_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be within [0, 1], got {getattr(self, name)}")
        if not (isinstance(self.delay_s, (int, float)) and math.isfinite(self.delay_s) and 0 <= self.delay_s <= 10.0):
            raise ValueError(f"delay_s must be within [0, 10] s, got {self.delay_s!r}")
        for name in ("drop_next", "corrupt_next", "truncate_next", "delay_next"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be a count >= 0, got {getattr(self, name)!r}")
        self._rng = random.Random(self.seed)

    def take(self, has_data: bool) -> str | None:
        """The fault to apply to the next reply (None for a clean one)."""
        for name in ("drop", "corrupt", "truncate", "delay"):
            if name == "truncate" and not has_data:
                continue
            if getattr(self, f"{name}_next") > 0:
                setattr(self, f"{name}_next", getattr(self, f"{name}_next") - 1)
                return name
        if self.drop_rate and self._rng.random() < self.drop_rate:
            return "drop"
        if self.corrupt_rate and self._rng.random() < self.corrupt_rate:
            return "corrupt"
        return None


class EmulatedServo:
    """One servo: its control-table memory and its motion.

    Registers are kept as bytes, as on the device; the motion state (``position_ticks``,
    ``velocity_ticks_s``, floats) is folded into Present Position/Velocity by :meth:`update`.
    """

    def __init__(
        self, model: ServoModel, dxl_id: int, baud: int = 1_000_000, clock: Callable[[], float] = time.monotonic
    ):
        self.model = model
        self.clock = clock
        self.mem = bytearray(model.table_end)
        self.pending: tuple[int, bytes] | None = None  # REG_WRITE waiting for ACTION
        self.boot_until = 0.0
        self.load_percent = 0.0
        self.stalled = False  # an obstruction: the motor holds where it is, short of its goal
        self.factory_defaults()
        self.set("id", dxl_id)
        baud_index = next((k for k, v in BAUD_RATES.items() if v == baud), None)
        if baud_index is None:
            raise ValueError(f"baud {baud} is not an X-series rate; use one of {sorted(BAUD_RATES.values())}")
        self.set("baud_rate", baud_index)
        self.position_ticks = float(CENTER_TICKS)
        self.velocity_ticks_s = 0.0
        self.t_last = clock()
        self.set("goal_position", CENTER_TICKS)  # powered up holding where it stands
        self._publish()

    # ------------------------------------------------------------------------------ registers
    def factory_defaults(self) -> None:
        for item in self.model.table.values():
            self._put(item.addr, item.size, item.default)
        self.set("model_number", self.model.model_number)
        self.set("firmware_version", self.model.firmware_version)
        self.set("present_input_voltage", self.model.nominal_voltage_dv)
        self.set("present_temperature", self.model.idle_temperature_c)

    def _put(self, addr: int, size: int, value: int) -> None:
        self.mem[addr : addr + size] = to_unsigned(value, size).to_bytes(size, "little")

    def get(self, name: str) -> int:
        item = self.model.item(name)
        raw = int.from_bytes(self.mem[item.addr : item.addr + item.size], "little")
        return to_signed(raw, item.size) if item.signed else raw

    def set(self, name: str, value: int) -> None:
        item = self.model.item(name)
        self._put(item.addr, item.size, value)

    @property
    def dxl_id(self) -> int:
        return self.get("id")

    @property
    def baud(self) -> int:
        return BAUD_RATES.get(self.get("baud_rate"), 0)

    @property
    def torque_on(self) -> bool:
        return bool(self.get("torque_enable"))

    @property
    def hardware_error(self) -> int:
        return self.get("hardware_error_status")

    def error_byte(self, errnum: int = ErrNum.NONE) -> int:
        return errnum | (ERRBIT_ALERT if self.hardware_error else 0)

    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        """(error number, data) of a READ."""
        if length < 1 or addr < 0 or addr + length > self.model.table_end:
            return ErrNum.ACCESS, b""
        self.update()
        return ErrNum.NONE, bytes(self.mem[addr : addr + length])

    def check_write(self, addr: int, data: bytes) -> int:
        """The error a WRITE of ``data`` at ``addr`` would get (0 when it is accepted)."""
        end = addr + len(data)
        if not data or addr < 0 or end > self.model.table_end:
            return ErrNum.ACCESS
        pos = addr
        while pos < end:
            entry = self.model.by_addr.get(pos)
            if entry is None:
                return ErrNum.ACCESS  # an undefined address or the middle of an item
            name, item = entry
            if pos + item.size > end:
                return ErrNum.DATA_LENGTH
            if item.access != "RW":
                return ErrNum.ACCESS
            if self.model.is_eeprom(item.addr) and self.torque_on:
                return ErrNum.ACCESS
            raw = int.from_bytes(data[pos - addr : pos - addr + item.size], "little")
            value = to_signed(raw, item.size) if item.signed else raw
            if name == "operating_mode":
                if value not in self.model.operating_modes:
                    return ErrNum.DATA_RANGE
            elif item.choices and value not in item.choices:
                return ErrNum.DATA_RANGE
            elif (item.lo is not None and value < item.lo) or (item.hi is not None and value > item.hi):
                return ErrNum.DATA_RANGE
            if name == "goal_position" and self.get("operating_mode") == OperatingMode.POSITION:
                if not self.get("min_position_limit") <= value <= self.get("max_position_limit"):
                    return ErrNum.DATA_LIMIT
            pos += item.size
        return ErrNum.NONE

    def write(self, addr: int, data: bytes) -> int:
        """Apply a WRITE; returns the error number (the write is all or nothing)."""
        self.update()
        err = self.check_write(addr, data)
        if err:
            return err
        torque_before = self.torque_on
        self.mem[addr : addr + len(data)] = data
        if not torque_before and self.torque_on:
            if self.hardware_error & self.get("shutdown"):
                self.set("torque_enable", 0)  # a shut-down servo stays off until REBOOT
            else:
                # position mode starts by holding where it is
                self.set("goal_position", round(self.position_ticks))
        self._publish()
        return ErrNum.NONE

    def reboot(self) -> None:
        """REBOOT: RAM back to defaults, faults cleared, deaf for a moment; EEPROM kept."""
        self.update()
        for item in self.model.table.values():
            if not self.model.is_eeprom(item.addr):
                self._put(item.addr, item.size, item.default)
        self.set("present_temperature", self.model.idle_temperature_c)
        self.set("present_input_voltage", self.model.nominal_voltage_dv)
        self.set("goal_position", round(self.position_ticks))
        self.load_percent = 0.0
        self.velocity_ticks_s = 0.0
        self.pending = None
        self.boot_until = time.monotonic() + _BOOT_TIME_S  # the line's real time (module docstring)
        self._publish()

    def inject_fault(self, fault: str) -> None:
        """Raise a hardware error (``"overload"``, ``"overheating"``, ...) as the servo would."""
        if fault not in _FAULT_BITS:
            raise ValueError(f"unknown hardware fault {fault!r}; one of {sorted(_FAULT_BITS)}")
        self.update()
        bit = 1 << _FAULT_BITS[fault]
        self.set("hardware_error_status", self.hardware_error | bit)
        if fault == "overheating":
            self.set("present_temperature", self.get("temperature_limit") + 3)
        if fault == "overload":
            self.load_percent = 100.0
        if bit & self.get("shutdown"):
            self.set("torque_enable", 0)
        self._publish()

    # ------------------------------------------------------------------------------ motion
    def _limits_ticks_s(self) -> tuple[float, float]:
        m = self.model
        units = self.get("profile_velocity")
        vel_limit = self.get("velocity_limit")
        if units == 0 or (vel_limit and units > vel_limit):
            units = vel_limit
        rpm = units * m.velocity_unit_rpm if units else m.no_load_speed_rpm
        rpm = min(rpm, m.no_load_speed_rpm)
        v_max = rpm / 60.0 * TICKS_PER_REV
        acc = self.get("profile_acceleration")
        a_max = acc * m.acceleration_unit_rev_min2 / 3600.0 * TICKS_PER_REV if acc else math.inf
        return v_max, a_max

    def update(self, now: float | None = None) -> None:
        """Advance the motion to ``now`` and refresh the Present* registers."""
        now = self.clock() if now is None else now
        dt_total = max(0.0, now - self.t_last)
        self.t_last = now
        if not self.torque_on or self.stalled:
            self.velocity_ticks_s = 0.0
        else:
            goal = float(self.get("goal_position"))
            v_max, a_max = self._limits_ticks_s()
            remaining = dt_total
            while remaining > 0.0:
                dt = min(remaining, 0.002)
                remaining -= dt
                self.position_ticks, self.velocity_ticks_s, settled = trapezoid_step(
                    self.position_ticks, self.velocity_ticks_s, goal, v_max, a_max, dt
                )
                if settled:
                    break
        self._publish()

    def _publish(self) -> None:
        m = self.model
        pos = round(self.position_ticks)
        self.set("present_position", pos)
        self.set("position_trajectory", pos)
        vel_units = round(self.velocity_ticks_s / TICKS_PER_REV * 60.0 / m.velocity_unit_rpm)
        self.set("present_velocity", vel_units)
        self.set("velocity_trajectory", vel_units)
        load_item = "present_current" if "present_current" in m.table else "present_load"
        self.set(load_item, round(self.load_percent * 10))
        moving = self.torque_on and (self.velocity_ticks_s != 0.0 or pos != self.get("goal_position"))
        self.set("moving", int(moving))
        in_position = abs(self.get("goal_position") - pos) <= 1
        self.set("moving_status", (1 if in_position else 0) | (2 if moving else 0))
        self.set("realtime_tick", int(self.t_last * 1000) % 32768)


class ServoBus:
    """The servos on one bus and the instruction semantics (no I/O here).

    :meth:`handle` takes one decoded instruction packet and returns the status packets to send,
    in bus order, as ``(servo, packet bytes, carries_data)``.
    """

    def __init__(self, servos: Iterable[EmulatedServo]):
        servos = list(servos)
        self.servos = {s.dxl_id: s for s in servos}
        if len(self.servos) != len(servos):
            raise ValueError(f"two emulated servos share an id: {[s.dxl_id for s in servos]}")
        self.goal_log: list[tuple[int, int]] = []  # every Goal Position received: (id, ticks)

    def _listening(self, line_baud: int | None) -> dict[int, EmulatedServo]:
        now = time.monotonic()
        out = {}
        for servo in sorted(self.servos.values(), key=lambda s: s.dxl_id):
            if servo.boot_until > now:
                continue
            if line_baud is not None and servo.baud != line_baud:
                continue
            out[servo.dxl_id] = servo
        return out

    def _log_goals(self, dxl_id: int, addr: int, data: bytes, model: ServoModel) -> None:
        item = model.item("goal_position")
        offset = item.addr - addr
        if 0 <= offset and offset + item.size <= len(data):
            self.goal_log.append(
                (dxl_id, to_signed(int.from_bytes(data[offset : offset + item.size], "little"), item.size))
            )

    def handle(self, pkt: Packet, line_baud: int | None = None) -> list[tuple[EmulatedServo, bytes, bool]]:
        # keyed by the ID register, which a WRITE may have changed
        self.servos = {s.dxl_id: s for s in self.servos.values()}
        servos = self._listening(line_baud)
        replies: list[tuple[EmulatedServo, bytes, bool]] = []

        def status(servo: EmulatedServo, err: int, params: bytes = b"", is_read: bool = False) -> None:
            level = servo.get("status_return_level")
            if pkt.inst == Inst.PING or (is_read and level >= 1) or level >= 2:
                replies.append((servo, build_status(servo.dxl_id, servo.error_byte(err), params), bool(params)))

        target = servos.get(pkt.dxl_id)
        if not pkt.crc_ok:
            if target is not None:
                status(target, ErrNum.CRC)
            return replies
        p = pkt.params
        if pkt.inst == Inst.PING:
            for servo in servos.values() if pkt.dxl_id == BROADCAST_ID else [target] if target else []:
                m = servo.model
                replies.append(
                    (
                        servo,
                        build_status(
                            servo.dxl_id,
                            servo.error_byte(),
                            bytes([m.model_number & 0xFF, m.model_number >> 8, m.firmware_version]),
                        ),
                        True,
                    )
                )
            return replies
        if pkt.inst == Inst.ACTION:
            for servo in servos.values() if pkt.dxl_id == BROADCAST_ID else [target] if target else []:
                if servo.pending is not None:
                    addr, data = servo.pending
                    servo.pending = None
                    servo.set("registered_instruction", 0)
                    self._log_goals(servo.dxl_id, addr, data, servo.model)
                    servo.write(addr, data)
                if pkt.dxl_id != BROADCAST_ID:
                    status(servo, ErrNum.NONE)
            return replies
        if pkt.inst in (Inst.SYNC_READ, Inst.SYNC_WRITE):
            return self._sync(pkt, servos, status, replies)
        if pkt.inst in (Inst.BULK_READ, Inst.BULK_WRITE):
            return self._bulk(pkt, servos, status, replies)
        if target is None:
            return replies  # addressed to nobody here (or broadcast of a unicast instruction)
        if pkt.inst == Inst.READ:
            if len(p) != 4:
                status(target, ErrNum.DATA_LENGTH, is_read=True)
            else:
                err, data = target.read(p[0] | p[1] << 8, p[2] | p[3] << 8)
                status(target, err, data, is_read=True)
        elif pkt.inst in (Inst.WRITE, Inst.REG_WRITE):
            if len(p) < 3:
                status(target, ErrNum.DATA_LENGTH)
                return replies
            addr, data = p[0] | p[1] << 8, bytes(p[2:])
            if pkt.inst == Inst.WRITE:
                self._log_goals(target.dxl_id, addr, data, target.model)
                status(target, target.write(addr, data))
            else:
                err = target.check_write(addr, data)
                if not err:
                    target.pending = (addr, data)
                    target.set("registered_instruction", 1)
                status(target, err)
        elif pkt.inst == Inst.REBOOT:
            status(target, ErrNum.NONE)
            target.reboot()
        else:
            status(target, ErrNum.INSTRUCTION)
        return replies

    def _sync(self, pkt, servos, status, replies):
        p = pkt.params
        if len(p) < 4:
            return replies
        addr, length = p[0] | p[1] << 8, p[2] | p[3] << 8
        if pkt.inst == Inst.SYNC_READ:
            for dxl_id in p[4:]:
                servo = servos.get(dxl_id)
                if servo is not None:
                    err, data = servo.read(addr, length)
                    status(servo, err, data, is_read=True)
            return replies
        chunk = 1 + length
        body = p[4:]
        if length == 0 or len(body) % chunk:
            return replies  # malformed: a broadcast gets no status, the servos ignore it
        for i in range(0, len(body), chunk):
            servo = servos.get(body[i])
            data = bytes(body[i + 1 : i + chunk])
            self._log_goals(body[i], addr, data, (servo or next(iter(self.servos.values()))).model)
            if servo is not None:
                servo.write(addr, data)
        return replies

    def _bulk(self, pkt, servos, status, replies):
        p = pkt.params
        i = 0
        while i + 5 <= len(p):
            dxl_id, addr, length = p[i], p[i + 1] | p[i + 2] << 8, p[i + 3] | p[i + 4] << 8
            servo = servos.get(dxl_id)
            if pkt.inst == Inst.BULK_READ:
                if servo is not None:
                    err, data = servo.read(addr, length)
                    status(servo, err, data, is_read=True)
                i += 5
            else:
                data = bytes(p[i + 5 : i + 5 + length])
                if servo is not None:
                    self._log_goals(dxl_id, addr, data, servo.model)
                    servo.write(addr, data)
                i += 5 + length
        return replies


class ServoEmulator:
    """A :class:`ServoBus` served on a pty, in a background thread or in the foreground.

    ``models`` name the servos on the bus, given ids 1..N in order (or ``ids``). ``port`` is the
    pty's slave path, or ``link`` when given: a symlink kept pointing at the current pty, like a
    ``/dev/serial/by-id`` name that survives unplugging (see :meth:`vanish`).
    """

    def __init__(
        self,
        models: Sequence[str] = ("xm430-w350", "xm430-w350"),
        ids: Sequence[int] | None = None,
        *,
        baud: int = 1_000_000,
        link: str | os.PathLike | None = None,
        faults: FaultPlan | None = None,
        wire_timing: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ):
        if not models:
            raise ValueError("the emulator needs at least one servo model")
        ids = list(ids) if ids is not None else list(range(1, len(models) + 1))
        if len(ids) != len(models):
            raise ValueError(f"{len(models)} models but {len(ids)} ids")
        if len(models) > MAX_SERVOS:
            raise ValueError(f"at most {MAX_SERVOS} servos on one emulated bus, got {len(models)}")
        bad = [i for i in ids if not (isinstance(i, int) and 0 <= i <= MAX_ID)]
        if bad:
            raise ValueError(f"servo ids must be 0..{MAX_ID}, got {bad[:3]}")
        self.bus = ServoBus(EmulatedServo(model_by_name(name), i, baud, clock) for name, i in zip(models, ids))
        self.faults = faults or FaultPlan()
        self.link = Path(link) if link is not None else None
        if self.link is not None:
            check_link_path(self.link)  # before anything is opened: refuse early, touch nothing
        self.wire_timing = wire_timing
        self.lock = threading.RLock()
        self.packets_seen = 0
        # wait_idle's marker packets: sent, and reached by the I/O loop
        self._marker_id = next(i for i in range(MAX_ID, -1, -1) if i not in ids)
        self._markers = threading.Condition()
        self._markers_sent = self._markers_seen = 0
        self._master: int | None = None
        self._slave: int | None = None
        self._pty_path: str | None = None
        self._link_made = False  # True while the link is one this emulator made for its pty
        self._parser = PacketParser()
        self._commands: queue.Queue = queue.Queue()
        self._wake_r, self._wake_w = os.pipe()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        try:
            self._open_pty(strict=True)
        except BaseException:
            for fd in (self._wake_r, self._wake_w):
                os.close(fd)
            raise

    # ------------------------------------------------------------------------------ public
    @property
    def servos(self) -> dict[int, EmulatedServo]:
        return self.bus.servos

    @property
    def goal_log(self) -> list[tuple[int, int]]:
        return self.bus.goal_log

    @property
    def port(self) -> str:
        """The path a client opens: the symlink when one was asked for, else the pty."""
        if self.link is not None:
            return str(self.link)
        assert self._pty_path is not None
        return self._pty_path

    @property
    def pty_path(self) -> str | None:
        """The current pty slave path (None while the port has vanished)."""
        return self._pty_path

    def start(self) -> ServoEmulator:
        """Serve in a daemon thread; pair with :meth:`stop` (or use ``with``)."""
        if self._thread is not None:
            raise RuntimeError("emulator already started")
        self._thread = threading.Thread(target=self.serve_forever, name="servo-emulator", daemon=True)
        self._thread.start()
        return self

    def request_stop(self) -> None:
        """Ask :meth:`serve_forever` to return; safe from a signal handler or another thread."""
        self._stop.set()
        self._wake()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop serving, close the pty and remove the link. Safe to call twice."""
        self._stop.set()
        self._wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.error("servo emulator thread did not stop within %.1f s", timeout_s)
        self._thread = None
        self._close_pty()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._wake_r = self._wake_w = -1

    def __enter__(self) -> ServoEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def vanish(self, timeout_s: float = 2.0) -> None:
        """Unplug: close the pty (clients get I/O errors) and remove the link."""
        self._run_in_loop(self._close_pty, timeout_s)

    def restore(self, timeout_s: float = 2.0) -> None:
        """Plug back in: a new pty, and the link pointed at it. Servo state is kept."""
        self._run_in_loop(self._open_pty, timeout_s)

    def inject_hardware_error(self, dxl_id: int, fault: str) -> None:
        with self.lock:
            self._servo(dxl_id).inject_fault(fault)

    def inject_stall(self, dxl_id: int, stalled: bool = True) -> None:
        """Block (or free) a servo's motion: it stays where it is, Moving stays 1."""
        with self.lock:
            servo = self._servo(dxl_id)
            servo.update()
            servo.stalled = bool(stalled)

    def _servo(self, dxl_id: int) -> EmulatedServo:
        try:
            return self.servos[dxl_id]
        except KeyError:
            raise ValueError(f"no emulated servo with id {dxl_id!r}; ids: {sorted(self.servos)}") from None

    def serve_forever(self) -> None:
        """The I/O loop: read instructions, answer them. Returns after :meth:`stop`."""
        while not self._stop.is_set():
            self._drain_commands()
            fds = [self._wake_r] + ([self._master] if self._master is not None else [])
            try:
                ready, _, _ = select.select(fds, [], [], 0.1)
            except (OSError, ValueError):
                continue  # a fd closed under us by stop(); loop and re-check
            if self._wake_r in ready:
                try:
                    os.read(self._wake_r, 512)
                except OSError:
                    pass
            if self._master is not None and self._master in ready:
                try:
                    data = os.read(self._master, 4096)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    continue  # EIO while no client has the slave open
                for pkt in self._parser.feed(data):
                    if pkt.inst == Inst.PING and pkt.dxl_id == self._marker_id and self._markers_sent:
                        with self._markers:  # wait_idle's: everything written before it is handled
                            self._markers_seen += 1
                            self._markers.notify_all()
                        continue
                    self._answer(pkt)
        self._drain_commands()

    def wait_idle(self, timeout_s: float = 30.0) -> bool:
        """Wait until everything clients wrote to the bus so far has been read and answered
        (True), or ``timeout_s`` passed (False). A client that exits leaves its last instructions
        (a torque off) in the pty; on a loaded machine the I/O loop may not have read them yet
        when the client is gone: check the servos' state after this, not before.

        A barrier, not a poll: a PING to an id no servo had at start is written into the line
        behind what is there (the pty keeps its order), and the I/O loop counts it when it gets
        there (it is not answered, nor counted in ``packets_seen``)."""
        if self._thread is None or self._slave is None:
            return True
        with self._markers:
            target = self._markers_sent + 1  # the first of the two below
            self._markers_sent += 2
        try:
            # twice: a client killed half-way through a packet may swallow the first into its rest
            os.write(self._slave, build_packet(self._marker_id, Inst.PING) * 2)
        except OSError:
            return True  # the pty went (stop, vanish): nothing more will be read
        with self._markers:
            return self._markers.wait_for(lambda: self._markers_seen >= target, timeout_s)

    # ------------------------------------------------------------------------------ internals
    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass

    def _run_in_loop(self, fn: Callable[[], None], timeout_s: float) -> None:
        if self._thread is None:
            fn()
            return
        done = threading.Event()
        self._commands.put((fn, done))
        self._wake()
        if not done.wait(timeout_s):
            raise TimeoutError(f"emulator did not run {fn.__name__} within {timeout_s} s")

    def _drain_commands(self) -> None:
        while True:
            try:
                fn, done = self._commands.get_nowait()
            except queue.Empty:
                return
            try:
                fn()
            finally:
                done.set()

    def _open_pty(self, strict: bool = False) -> None:
        if self._master is not None:
            return
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self._pty_path = os.ttyname(slave)
        self._parser.clear()
        if self.link is not None:
            try:
                self._point_link()
            except (OSError, LinkError) as exc:
                if strict:
                    self._close_pty()
                    raise exc if isinstance(exc, LinkError) else LinkError(f"--link {self.link}: {exc}") from None
                # on restore() (in the I/O loop): serve on the pty anyway, say why the link is missing
                log.error("servo emulator: cannot keep the link %s: %s", self.link, exc)
        log.info("servo emulator on %s", self.port)

    def _point_link(self) -> None:
        """Point ``link`` at the current pty: atomically, and only over a path we may replace."""
        check_link_path(self.link)
        # a fresh temporary name beside the link: never overwrite anything that exists
        for _ in range(100):
            tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.{random.getrandbits(32):08x}.tmp")
            try:
                tmp.symlink_to(self._pty_path)
                break
            except FileExistsError:
                continue
        else:
            raise LinkError(f"cannot create a temporary link beside {self.link}")
        try:
            os.replace(tmp, self.link)
        except OSError:
            tmp.unlink(missing_ok=True)
            raise
        self._link_made = True

    def _remove_link(self) -> None:
        """Remove the link only while it is still ours: a symlink pointing at our pty."""
        if self.link is None or self._pty_path is None or not self._link_made:
            return
        self._link_made = False
        try:
            if self.link.is_symlink() and os.readlink(self.link) == self._pty_path:
                self.link.unlink()
            elif os.path.lexists(self.link):
                log.warning("servo emulator: %s no longer points at %s; leaving it alone", self.link, self._pty_path)
        except OSError as exc:
            log.warning("servo emulator: could not remove the link %s: %s", self.link, exc)

    def _close_pty(self) -> None:
        self._remove_link()
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None
        self._pty_path = None

    def _line_baud(self) -> int | None:
        """The baud rate the client set on the port (None when it cannot be told)."""
        try:
            ispeed = termios.tcgetattr(self._slave)[4]
        except (termios.error, TypeError):
            return None
        return _TERMIOS_BAUDS.get(ispeed)

    def _answer(self, pkt: Packet) -> None:
        line_baud = self._line_baud()
        byte_s = 10.0 / line_baud if (self.wire_timing and line_baud) else 0.0
        with self.lock:
            self.packets_seen += 1
            replies = self.bus.handle(pkt, line_baud)
            plan = [
                (servo.get("return_delay_time") * 2e-6 + len(raw) * byte_s, raw, self.faults.take(has_data))
                for servo, raw, has_data in replies
            ]
        if plan:  # the instruction itself took its time on the wire before anyone could answer
            first_delay_s, raw, fault = plan[0]
            plan[0] = (first_delay_s + (10 + len(pkt.params)) * byte_s, raw, fault)
        for delay_s, raw, fault in plan:
            if fault == "drop":
                log.debug("fault: dropped a reply")
                continue
            if fault == "corrupt":
                raw = raw[:-1] + bytes([raw[-1] ^ 0xFF])
            elif fault == "truncate":
                raw = _truncated(raw)
            elif fault == "delay":
                delay_s += self.faults.delay_s
            if delay_s > 0:
                time.sleep(delay_s)
            self._send(raw)

    def _send(self, raw: bytes) -> None:
        if self._master is None:
            return
        try:
            os.write(self._master, raw)
        except (BlockingIOError, OSError) as exc:
            log.debug("reply not delivered: %s", exc)


def _truncated(raw: bytes) -> bytes:
    """The same status packet without the second half of its data (and with a valid CRC)."""
    (pkt,) = PacketParser().feed(raw)
    data = pkt.params[1:]
    return build_status(pkt.dxl_id, pkt.error, data[: len(data) // 2])


class FileClock:
    """A time shared between processes through a small file: one float64 (seconds) that the
    owner :meth:`set` s and any process reads by calling the instance (a clock for
    :class:`EmulatedServo`). :meth:`create` makes the file (at 0.0); :meth:`close` by its creator
    removes it. Reads and writes are whole 8-byte aligned words of a shared mapping."""

    _FMT = "<d"

    def __init__(self, path: str | os.PathLike, *, owner: bool = False):
        import mmap

        self.path = Path(path)
        self.owner = owner
        try:
            with open(self.path, "r+b") as f:
                self._map = mmap.mmap(f.fileno(), 8)
        except (OSError, ValueError) as exc:
            raise DeviceError(f"clock file {self.path}: {exc}; it is made by the node that owns the time") from None

    @classmethod
    def create(cls, start_s: float = 0.0) -> FileClock:
        import struct
        import tempfile

        fd, path = tempfile.mkstemp(prefix="aes-planner-clock-")
        with os.fdopen(fd, "wb") as f:
            f.write(struct.pack(cls._FMT, float(start_s)))
        return cls(path, owner=True)

    def __call__(self) -> float:
        import struct

        return struct.unpack_from(self._FMT, self._map, 0)[0]

    def set(self, now_s: float) -> None:
        import struct

        struct.pack_into(self._FMT, self._map, 0, float(now_s))

    def close(self) -> None:
        try:
            self._map.close()
        except (BufferError, ValueError):
            pass
        if self.owner:
            self.path.unlink(missing_ok=True)


class EmulatorProcess:
    """``aes-planner gimbal emulate`` in a child process; ``port`` is the pty path it printed.

    Use as a context manager: the process is terminated (then killed) on exit. ``args`` are extra
    command-line options (``["--link", path]``, ``["--drop-rate", "0.1"]``).
    """

    def __init__(
        self,
        models: Sequence[str] = ("xm430-w350", "xm430-w350"),
        baud: int = 1_000_000,
        args: Sequence[str] = (),
        start_timeout_s: float = 30.0,
    ):
        self.argv = [
            sys.executable,
            "-m",
            "aes_planner",
            "gimbal",
            "emulate",
            "--models",
            ",".join(models),
            "--baud",
            str(baud),
            *args,
        ]
        self.start_timeout_s = start_timeout_s
        self.proc: subprocess.Popen | None = None
        self.port = ""

    def __enter__(self) -> EmulatorProcess:
        # its own session: a terminal's Ctrl-C reaches the driver, which turns torque off through
        # the emulator before it goes; it stops by itself when this process goes away
        self.proc = subprocess.Popen(
            [*self.argv, "--exit-with-parent"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        ready, _, _ = select.select([self.proc.stdout], [], [], self.start_timeout_s)
        self.port = self.proc.stdout.readline().strip() if ready else ""
        if not self.port.startswith("/"):
            # it exited (its own error on stderr), printed something else (--help), or hung
            said = " ".join((self.port or self._last_error_line()).split())[:200]
            self.stop()
            how = f"printed {said!r}" if said else f"printed nothing within {self.start_timeout_s:g} s"
            raise DeviceError(
                f"the servo emulator did not start: it {how} instead of its pty path; "
                f"check its arguments: {' '.join(self.argv[5:])}"
            )
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _last_error_line(self) -> str:
        """The last line the process wrote to stderr if it has exited (its own error message)."""
        try:
            self.proc.wait(1.0)
        except subprocess.TimeoutExpired:
            return ""  # still running, silent: reading its stderr would block
        try:
            lines = [ln for ln in self.proc.stderr.read(65536).splitlines() if ln.strip()]
        except (OSError, ValueError):
            return ""
        return lines[-1] if lines else ""

    def stop(self, timeout_s: float = 5.0) -> int | None:
        """Terminate the process (SIGTERM, then SIGKILL); returns its exit status."""
        proc = self.proc
        if proc is None:
            return None
        if proc.poll() is None:
            proc.terminate()
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout_s)
        if proc.stdout is not None:  # its last line says whether the servos were left with torque off
            for line in proc.stdout.read().splitlines():
                if line.startswith("servo emulator stopped:"):
                    (log.warning if "torque ON" in line else log.info)("%s", line)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
        return proc.returncode
