"""Flight modes of PX4 and ArduPilot (copter) as ``HEARTBEAT.custom_mode`` numbers and names.

PX4 packs its mode into ``custom_mode``: main mode in bits 16-23, sub mode in bits 24-31
(``OFFBOARD`` = main 6; ``AUTO.LOITER`` (hold) = main 4, sub 3). ArduPilot copter uses the mode
number itself (``GUIDED`` = 4, ``LOITER`` = 5). Both need ``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED``
(1) in ``base_mode`` to be read, and switch on ``MAV_CMD_DO_SET_MODE`` (param1 = base mode with
that flag, param2 = custom (main) mode, param3 = PX4 sub mode).
"""

from __future__ import annotations

import os

__all__ = [
    "ARDUPILOT_MODES",
    "AUTOPILOTS",
    "PX4_MAIN_MODES",
    "PX4_AUTO_SUB_MODES",
    "control_mode",
    "mavlink",
    "mode_name",
    "px4_custom_mode",
    "set_mode_params",
]

PX4_MAIN_MODES = {
    1: "MANUAL",
    2: "ALTCTL",
    3: "POSCTL",
    4: "AUTO",
    5: "ACRO",
    6: "OFFBOARD",
    7: "STABILIZED",
    8: "RATTITUDE",
}
PX4_AUTO_SUB_MODES = {
    1: "READY",
    2: "TAKEOFF",
    3: "LOITER",
    4: "MISSION",
    5: "RTL",
    6: "LAND",
    8: "FOLLOW_TARGET",
    9: "PRECLAND",
}
ARDUPILOT_MODES = {
    0: "STABILIZE",
    1: "ACRO",
    2: "ALT_HOLD",
    3: "AUTO",
    4: "GUIDED",
    5: "LOITER",
    6: "RTL",
    7: "CIRCLE",
    9: "LAND",
    11: "DRIFT",
    13: "SPORT",
    16: "POSHOLD",
    17: "BRAKE",
    18: "THROW",
    20: "GUIDED_NOGPS",
    21: "SMART_RTL",
}
#: The flight stacks whose modes this module knows: ``autopilot:`` settings and ``--autopilot`` choices.
AUTOPILOTS = ("px4", "ardupilot")
CUSTOM_MODE_ENABLED = 1  # MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (checked against pymavlink in the tests)


def mavlink():
    """pymavlink's MAVLink 2 ``common`` dialect module: the messages and the named constants
    (``MAV_CMD_DO_SET_MODE``, ``MAV_MODE_FLAG_SAFETY_ARMED``...) every MAVLink file here uses."""
    os.environ.setdefault("MAVLINK20", "1")  # read by pymavlink when it loads a dialect
    from pymavlink.dialects.v20 import common

    return common


def px4_custom_mode(main: int, sub: int = 0) -> int:
    return (main & 0xFF) << 16 | (sub & 0xFF) << 24


def mode_name(autopilot: str, base_mode: int, custom_mode: int) -> str:
    """``"OFFBOARD"``, ``"AUTO.LOITER"``, ``"GUIDED"``... or ``"UNKNOWN(n)"``."""
    if not base_mode & CUSTOM_MODE_ENABLED:
        return f"UNKNOWN(base {base_mode})"
    if autopilot == "px4":
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        name = PX4_MAIN_MODES.get(main, f"UNKNOWN({main})")
        if main == 4:
            return f"AUTO.{PX4_AUTO_SUB_MODES.get(sub, str(sub))}"
        return name
    return ARDUPILOT_MODES.get(custom_mode, f"UNKNOWN({custom_mode})")


def control_mode(autopilot: str) -> str:
    """The mode in which the vehicle flies the companion's setpoints."""
    return "OFFBOARD" if autopilot == "px4" else "GUIDED"


def set_mode_params(autopilot: str, name: str) -> tuple[float, float, float]:
    """``MAV_CMD_DO_SET_MODE`` params 1-3 for mode ``name`` (``OFFBOARD``, ``AUTO.LOITER``, ``GUIDED``...)."""
    if autopilot == "px4":
        main_name, _, sub_name = name.partition(".")
        main = next(k for k, v in PX4_MAIN_MODES.items() if v == main_name)
        sub = next((k for k, v in PX4_AUTO_SUB_MODES.items() if v == sub_name), 0) if sub_name else 0
        return float(CUSTOM_MODE_ENABLED), float(main), float(sub)
    number = next(k for k, v in ARDUPILOT_MODES.items() if v == name)
    return float(CUSTOM_MODE_ENABLED), float(number), 0.0
