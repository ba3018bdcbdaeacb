"""Servo facts as data: control tables, units, factory defaults, model numbers, operating modes,
baud-rate tables, hardware-error bits; and the tick <-> radian map.

The one place for servo facts: the driver (:mod:`.dynamixel`), its config
(:mod:`.dynamixel_config`) and the emulator (:mod:`.emulator`) read them from here. Adding a model
is adding a :class:`ServoModel` to :data:`MODELS` (its control table, units and defaults). Addresses, sizes and
the ROBOTIS e-manual (X series, Protocol 2.0) and the tables shipped with dynamixel-sdk's
easy-SDK; factory defaults matter only to the emulator (the driver writes what it relies on).

:class:`JointCalibration` is the only place where servo ticks become joint radians and back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Literal

__all__ = [
    "Item",
    "ServoModel",
    "MODELS",
    "model_by_name",
    "model_by_number",
    "HARDWARE_ERROR_BITS",
    "decode_hardware_error",
    "to_signed",
    "to_unsigned",
    "JointCalibration",
    "TICKS_PER_REV",
    "CENTER_TICKS",
    "OperatingMode",
    "BAUD_RATES",
    "SDK_BAUD_RATES",
    "supported_models",
]

TICKS_PER_REV = 4096
CENTER_TICKS = 2048


class OperatingMode(IntEnum):
    """Values of the Operating Mode register (addr 11) on the X series; each model lists the ones
    it has in :attr:`ServoModel.operating_modes`. The driver uses :attr:`POSITION` only."""

    CURRENT = 0
    VELOCITY = 1
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5
    PWM = 16


# Baud Rate register (addr 8) value -> bits per second (X series).
BAUD_RATES: dict[int, int] = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}
# The rates both dynamixel-sdk (PortHandler.getCFlagBaud) and the X series accept: what the
# driver may be configured with (4.5 Mbps is not one of the SDK's).
SDK_BAUD_RATES: tuple[int, ...] = (9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)

# Hardware Error Status (addr 70) bits -> fault names, as the e-manual lists them.
HARDWARE_ERROR_BITS: dict[int, str] = {
    0: "input voltage",
    2: "overheating",
    3: "motor encoder",
    4: "electrical shock",
    5: "overload",
}


def decode_hardware_error(status: int) -> tuple[str, ...]:
    """Fault names set in a Hardware Error Status byte (empty when healthy)."""
    return tuple(name for bit, name in HARDWARE_ERROR_BITS.items() if status & (1 << bit))


def to_signed(value: int, size: int) -> int:
    """Two's complement decode of an unsigned ``size``-byte register value."""
    bits = 8 * size
    value &= (1 << bits) - 1
    return value - (1 << bits) if value & (1 << (bits - 1)) else value


def to_unsigned(value: int, size: int) -> int:
    """Two's complement encode of a signed value into ``size`` bytes."""
    return value & ((1 << (8 * size)) - 1)


@dataclass(frozen=True)
class Item:
    """One control-table entry.

    ``access`` is ``"R"`` (read only) or ``"RW"``; items below ``ServoModel.ram_start`` are EEPROM
    (writable only with torque off). ``lo``/``hi`` bound writable values (decoded as signed when
    ``signed``); ``choices`` lists the only legal values where the table has a set, not a range.
    """

    addr: int
    size: int
    access: Literal["R", "RW"] = "RW"
    default: int = 0
    lo: int | None = None
    hi: int | None = None
    signed: bool = False
    choices: tuple[int, ...] = ()


# Entries shared by the X-series tables below (XM430-W350, XL430-W250). Each model spells out the
# entries that differ; a new model can start from a copy of this dict or from scratch.
_X_SERIES: dict[str, Item] = {
    "model_number": Item(0, 2, "R"),
    "model_information": Item(2, 4, "R"),
    "firmware_version": Item(6, 1, "R"),
    "id": Item(7, 1, default=1, lo=0, hi=252),
    "baud_rate": Item(8, 1, default=1, lo=0, hi=7),
    "return_delay_time": Item(9, 1, default=250, lo=0, hi=254),
    "drive_mode": Item(10, 1, default=0, lo=0, hi=13),
    "operating_mode": Item(11, 1, default=3),
    "secondary_id": Item(12, 1, default=255, lo=0, hi=255),
    "protocol_type": Item(13, 1, default=2, choices=(1, 2)),
    "homing_offset": Item(20, 4, default=0, lo=-1_044_479, hi=1_044_479, signed=True),
    "moving_threshold": Item(24, 4, default=10, lo=0, hi=1023),
    "temperature_limit": Item(31, 1, default=80, lo=0, hi=100),
    "max_voltage_limit": Item(32, 2, default=140, lo=60, hi=140),
    "min_voltage_limit": Item(34, 2, default=60, lo=60, hi=140),
    "pwm_limit": Item(36, 2, default=885, lo=0, hi=885),
    "velocity_limit": Item(44, 4, default=265, lo=0, hi=1023),
    "max_position_limit": Item(48, 4, default=4095, lo=0, hi=4095),
    "min_position_limit": Item(52, 4, default=0, lo=0, hi=4095),
    "shutdown": Item(63, 1, default=52, lo=0, hi=255),
    "torque_enable": Item(64, 1, default=0, lo=0, hi=1),
    "led": Item(65, 1, default=0, lo=0, hi=1),
    "status_return_level": Item(68, 1, default=2, lo=0, hi=2),
    "registered_instruction": Item(69, 1, "R"),
    "hardware_error_status": Item(70, 1, "R"),
    "velocity_i_gain": Item(76, 2, default=1000, lo=0, hi=16383),
    "velocity_p_gain": Item(78, 2, default=100, lo=0, hi=16383),
    "position_d_gain": Item(80, 2, default=4000, lo=0, hi=16383),
    "position_i_gain": Item(82, 2, default=0, lo=0, hi=16383),
    "position_p_gain": Item(84, 2, default=640, lo=0, hi=16383),
    "feedforward_2nd_gain": Item(88, 2, default=0, lo=0, hi=16383),
    "feedforward_1st_gain": Item(90, 2, default=0, lo=0, hi=16383),
    "bus_watchdog": Item(98, 1, default=0, lo=0, hi=127),
    "goal_pwm": Item(100, 2, default=0, lo=-885, hi=885, signed=True),
    "goal_velocity": Item(104, 4, default=0, lo=-265, hi=265, signed=True),
    "profile_acceleration": Item(108, 4, default=0, lo=0, hi=32767),
    "profile_velocity": Item(112, 4, default=0, lo=0, hi=32767),
    "goal_position": Item(116, 4, default=0, lo=-1_048_575, hi=1_048_575, signed=True),
    "realtime_tick": Item(120, 2, "R"),
    "moving": Item(122, 1, "R"),
    "moving_status": Item(123, 1, "R"),
    "present_pwm": Item(124, 2, "R", signed=True),
    "present_load": Item(126, 2, "R", signed=True),
    "present_velocity": Item(128, 4, "R", signed=True),
    "present_position": Item(132, 4, "R", signed=True),
    "velocity_trajectory": Item(136, 4, "R", signed=True),
    "position_trajectory": Item(140, 4, "R", signed=True),
    "present_input_voltage": Item(144, 2, "R"),
    "present_temperature": Item(146, 1, "R"),
}


@dataclass(frozen=True)
class ServoModel:
    """A servo model: its identity, control table and the units of its registers.

    * ``velocity_unit_rpm``: one unit of Profile Velocity / Velocity Limit / Present Velocity.
    * ``acceleration_unit_rev_min2``: one unit of Profile Acceleration (rev/min^2).
    * ``no_load_speed_rpm``: top speed at nominal voltage (what the emulator moves at when the
      profile velocity is 0 = unlimited).
    * ``operating_modes``: legal :class:`OperatingMode` values of this model.
    * ``ram_start``: first RAM address; items below it are EEPROM.
    * ``table_end``: one past the last address (reads beyond it are an access error).
    * ``nominal_voltage_dv``, ``idle_temperature_c``: what the emulator reports at rest.
    """

    name: str
    model_number: int
    firmware_version: int
    table: Mapping[str, Item]
    velocity_unit_rpm: float = 0.229
    acceleration_unit_rev_min2: float = 214.577
    no_load_speed_rpm: float = 46.0
    operating_modes: tuple[OperatingMode, ...] = (
        OperatingMode.VELOCITY,
        OperatingMode.POSITION,
        OperatingMode.EXTENDED_POSITION,
        OperatingMode.PWM,
    )
    ram_start: int = 64
    table_end: int = 147
    nominal_voltage_dv: int = 120
    idle_temperature_c: int = 30
    by_addr: dict[int, tuple[str, Item]] = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        by_addr = {item.addr: (name, item) for name, item in self.table.items()}
        if len(by_addr) != len(self.table):
            raise ValueError(f"{self.name}: two control-table items share an address")
        object.__setattr__(self, "by_addr", by_addr)

    def item(self, name: str) -> Item:
        try:
            return self.table[name]
        except KeyError:
            raise KeyError(f"{self.name} has no control-table item {name!r}") from None

    def is_eeprom(self, addr: int) -> bool:
        return addr < self.ram_start

    def velocity_units(self, deg_s: float) -> int:
        """Profile Velocity register value for ``deg_s`` (0 = no limit).

        Raises :class:`ValueError` for a value the register cannot hold (it would wrap: 1e30
        deg/s must never become 0, which means "no limit"); see :attr:`max_profile_velocity_deg_s`.
        """
        if not math.isfinite(deg_s):
            raise ValueError(f"profile velocity must be finite, got {deg_s!r} deg/s")
        if deg_s <= 0:
            return 0
        units = max(1, round(deg_s / 6.0 / self.velocity_unit_rpm))  # 1 rpm = 6 deg/s
        self._check_register("profile_velocity", units, f"{deg_s:g} deg/s")
        self._check_register("velocity_limit", units, f"{deg_s:g} deg/s")  # the servo never turns faster
        return units

    def acceleration_units(self, deg_s2: float) -> int:
        """Profile Acceleration register value for ``deg_s2`` (0 = no limit); raises
        :class:`ValueError` beyond the register's range (see :attr:`max_profile_acceleration_deg_s2`)."""
        if not math.isfinite(deg_s2):
            raise ValueError(f"profile acceleration must be finite, got {deg_s2!r} deg/s^2")
        if deg_s2 <= 0:
            return 0
        units = max(1, round(deg_s2 / self._acceleration_unit_deg_s2))
        self._check_register("profile_acceleration", units, f"{deg_s2:g} deg/s^2")
        return units

    @property
    def _acceleration_unit_deg_s2(self) -> float:
        return self.acceleration_unit_rev_min2 * 360.0 / 3600.0  # rev/min^2 -> deg/s^2

    @property
    def max_profile_velocity_deg_s(self) -> float:
        """The largest profile velocity that means something, in deg/s: what the Velocity Limit register
        holds (the servo never turns faster than its velocity limit; the Profile Velocity register
        itself would hold 32 times more)."""
        hi = min(self.item("profile_velocity").hi, self.item("velocity_limit").hi)
        return (hi + 0.49) * 6.0 * self.velocity_unit_rpm

    @property
    def max_profile_acceleration_deg_s2(self) -> float:
        """The largest profile acceleration the Profile Acceleration register holds, in deg/s^2."""
        return (self.item("profile_acceleration").hi + 0.49) * self._acceleration_unit_deg_s2

    def _check_register(self, name: str, units: int, what: str) -> None:
        item = self.item(name)
        if (item.hi is not None and units > item.hi) or (item.lo is not None and units < item.lo):
            raise ValueError(
                f"{what} is {units} units of {self.name}'s {name} register, whose range is {item.lo}..{item.hi}"
            )


_XM430_TABLE = {
    **_X_SERIES,
    "velocity_limit": Item(44, 4, default=200, lo=0, hi=1023),
    "current_limit": Item(38, 2, default=1193, lo=0, hi=1193),
    "max_voltage_limit": Item(32, 2, default=160, lo=95, hi=160),
    "min_voltage_limit": Item(34, 2, default=95, lo=95, hi=160),
    "position_d_gain": Item(80, 2, default=0, lo=0, hi=16383),
    "position_p_gain": Item(84, 2, default=800, lo=0, hi=16383),
    "velocity_i_gain": Item(76, 2, default=1920, lo=0, hi=16383),
    "goal_current": Item(102, 2, default=0, lo=-1193, hi=1193, signed=True),
    "goal_velocity": Item(104, 4, default=0, lo=-200, hi=200, signed=True),
    # XM430 reports motor current where the XL430 reports load; same address and size.
    "present_current": _X_SERIES["present_load"],
}
del _XM430_TABLE["present_load"]

MODELS: tuple[ServoModel, ...] = (
    ServoModel(
        name="XM430-W350",
        model_number=1020,
        firmware_version=45,
        table=_XM430_TABLE,
        no_load_speed_rpm=46.0,
        operating_modes=tuple(OperatingMode),
        nominal_voltage_dv=120,
    ),
    ServoModel(
        name="XL430-W250",
        model_number=1060,
        firmware_version=46,
        table=dict(_X_SERIES),
        no_load_speed_rpm=57.0,
        operating_modes=(
            OperatingMode.VELOCITY,
            OperatingMode.POSITION,
            OperatingMode.EXTENDED_POSITION,
            OperatingMode.PWM,
        ),
        table_end=147,
        nominal_voltage_dv=111,
    ),
)


def _key(name: str) -> str:
    return name.strip().lower().replace("_", "-")


def model_by_name(name: str) -> ServoModel:
    """Look a model up by name, case-insensitively (``xm430-w350``)."""
    for model in MODELS:
        if _key(model.name) == _key(name):
            return model
    known = ", ".join(m.name.lower() for m in MODELS)
    raise KeyError(f"unknown servo model {name!r}; known models: {known}")


def supported_models() -> str:
    """``"XM430-W350 (1020), XL430-W250 (1060)"``: the models with a control table, for messages."""
    return ", ".join(f"{m.name} ({m.model_number})" for m in MODELS)


def model_by_number(model_number: int) -> ServoModel | None:
    """The model with this Model Number (what PING returns), or None when unknown."""
    return next((m for m in MODELS if m.model_number == model_number), None)


@dataclass(frozen=True)
class JointCalibration:
    """The tick <-> radian map of one joint; nowhere else converts between them.

    ``joint_rad = direction * (ticks - 2048 - zero_offset_ticks) * 2 pi / 4096``. ``min_ticks`` and
    ``max_ticks`` are the joint limits in ticks, rounded inwards so that a limit in ticks never
    lies outside the limit in radians.
    """

    zero_offset_ticks: int
    direction: int
    limits_rad: tuple[float, float]

    def __post_init__(self):
        if self.direction not in (1, -1):
            raise ValueError(f"direction must be +1 or -1, got {self.direction}")

    def to_ticks_float(self, joint_rad: float) -> float:
        return CENTER_TICKS + self.zero_offset_ticks + self.direction * joint_rad * TICKS_PER_REV / (2 * math.pi)

    def to_ticks(self, joint_rad: float) -> int:
        """Goal ticks for a joint angle, clamped to the tick limits (the angle must be finite)."""
        if not math.isfinite(joint_rad):
            raise ValueError(f"joint angle must be finite, got {joint_rad!r}")
        lo, hi = self.tick_limits
        return min(max(round(self.to_ticks_float(joint_rad)), lo), hi)

    def to_rad(self, ticks: int) -> float:
        return self.direction * (ticks - CENTER_TICKS - self.zero_offset_ticks) * 2 * math.pi / TICKS_PER_REV

    @property
    def tick_limits(self) -> tuple[int, int]:
        """(min, max) ticks of the joint limits, rounded inwards; what Min/Max Position Limit get."""
        a, b = (self.to_ticks_float(v) for v in self.limits_rad)
        lo, hi = min(a, b), max(a, b)
        return math.ceil(lo - 1e-9), math.floor(hi + 1e-9)
