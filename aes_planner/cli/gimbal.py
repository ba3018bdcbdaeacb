"""``aes-planner gimbal emulate|scan|move|state|reboot``: the Dynamixel pan-tilt from a shell.

``emulate`` runs the Protocol 2.0 servo emulator in the foreground and prints its pty path; the
other commands talk to real servos or to that path. The driver and the SDK are imported only
when a subcommand runs, so ``aes-planner --help`` works without the hardware extra.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
import time
from typing import Any

from aes_planner.cli import drives_servos
from aes_planner.config import from_dict, load_yaml
from aes_planner.errors import AesPlannerError

DEFAULT_MODELS = "xm430-w350,xm430-w350"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "gimbal",
        help="Dynamixel pan-tilt: emulate, scan, move, state, reboot",
        description="Drive a Dynamixel pan-tilt (Protocol 2.0; pan id 1, tilt id 2, 1 Mbps by default) "
        "or emulate one on a pseudo-terminal for dry runs.",
    )
    gsub = p.add_subparsers(dest="gimbal_command", metavar="ACTION", required=True)

    e = gsub.add_parser(
        "emulate",
        help="run a servo emulator on a pty and print its path (Ctrl-C to stop)",
        description="Emulate a bus of Dynamixel servos (ids 1..N in the order of --models) on a "
        "pseudo-terminal that dynamixel-sdk opens like a USB adapter. Prints the pty path, then "
        "serves until Ctrl-C.",
    )
    e.add_argument("--models", default=DEFAULT_MODELS, help=f"comma-separated servo models (default {DEFAULT_MODELS})")
    e.add_argument("--baud", type=int, default=1_000_000, help="the servos' baud rate (default 1000000)")
    e.add_argument("--link", metavar="PATH", help="also keep a symlink at PATH pointing at the pty")
    e.add_argument("--drop-rate", type=float, default=0.0, help="fraction of replies to drop (fault injection)")
    e.add_argument("--corrupt-rate", type=float, default=0.0, help="fraction of replies with a broken CRC")
    e.add_argument("--seed", type=int, default=0, help="seed of the fault injection")
    e.add_argument(
        "--clock-file",
        metavar="PATH",
        help="take the servos' time from this file (a simulated clock's, written by the gimbal node) "
        "instead of the machine's",
    )
    e.add_argument(
        "--exit-with-parent",
        action="store_true",
        help="stop when the process that started this one goes away (how the gimbal node runs it)",
    )
    e.set_defaults(func=run_emulate)

    s = gsub.add_parser(
        "scan",
        help="list the servos on a port (ids, models, firmware)",
        description="Broadcast-ping the bus and list every servo that answers at this baud rate.",
    )
    s.add_argument("--port", required=True, help="serial device, e.g. /dev/ttyUSB0 or an emulator's pty")
    s.add_argument("--baud", type=int, default=1_000_000, help="baud rate to scan at (default 1000000)")
    s.set_defaults(func=run_scan)

    m = gsub.add_parser(
        "move",
        help="move to a pan/tilt and wait until the servos report arrival",
        description="Move the pan-tilt to the joint angles (clamped to the joint limits) and wait until "
        "both servos report arrival; exits with an error on timeout. Torque is turned off on exit, "
        "also on Ctrl-C or SIGTERM (exit status 130 / 143).",
    )
    _driver_args(m)
    m.add_argument("--pan-deg", type=float, help="pan joint angle, degrees (positive turns left); required")
    m.add_argument("--tilt-deg", type=float, help="tilt joint angle, degrees (positive looks up); required")
    # deprecated spellings (joint angles are not the view's yaw/pitch); hidden, they warn
    m.add_argument("--yaw-deg", type=float, dest="yaw_deg_deprecated", help=argparse.SUPPRESS)
    m.add_argument("--pitch-deg", type=float, dest="pitch_deg_deprecated", help=argparse.SUPPRESS)
    m.add_argument("--timeout-s", type=float, default=None, help="how long to wait for arrival (default: config, 10 s)")
    m.set_defaults(func=run_move)

    st = gsub.add_parser("state", help="print joint angles, motion, temperatures, hardware errors")
    _driver_args(st)
    st.set_defaults(func=run_state)

    r = gsub.add_parser(
        "reboot",
        help="reboot the servos to clear a hardware error (after removing its cause)",
    )
    _driver_args(r)
    r.set_defaults(func=run_reboot)


def _driver_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", help="serial device, e.g. /dev/ttyUSB0 or an emulator's pty")
    p.add_argument("--baud", type=int, help="baud rate (default 1000000)")
    p.add_argument("--pan-id", type=int, help="pan servo id (default 1)")
    p.add_argument("--tilt-id", type=int, help="tilt servo id (default 2)")
    p.add_argument("--config", metavar="YAML", help="DynamixelPanTiltConfig fields; flags override them")


def _driver_config(args: argparse.Namespace):
    from aes_planner.drivers.dynamixel import DynamixelPanTiltConfig

    data: dict[str, Any] = {}
    if args.config:
        loaded = load_yaml(args.config)
        if loaded is not None and not isinstance(loaded, dict):
            raise AesPlannerError(f"{args.config}: expected a mapping of gimbal settings")
        data.update(loaded or {})
    for flag in ("port", "baud", "pan_id", "tilt_id"):
        if getattr(args, flag) is not None:
            data[flag] = getattr(args, flag)
    if not data.get("port"):
        raise AesPlannerError("give the serial port: --port /dev/ttyUSB0 (or an emulator's pty), or port: in --config")
    return from_dict(DynamixelPanTiltConfig, data, args.config or "")


def _gimbal(args: argparse.Namespace):
    from aes_planner.drivers.dynamixel import DynamixelPanTilt

    return DynamixelPanTilt(_driver_config(args))


def run_emulate(args: argparse.Namespace) -> int:
    from aes_planner.drivers.emulator import FaultPlan, ServoEmulator

    models = [m.strip() for m in args.models.split(",") if m.strip()]
    try:
        faults = FaultPlan(drop_rate=args.drop_rate, corrupt_rate=args.corrupt_rate, seed=args.seed)
        clock = {}
        if args.clock_file:
            from aes_planner.drivers.emulator import FileClock

            clock = {"clock": FileClock(args.clock_file)}
        emu = ServoEmulator(models, baud=args.baud, link=args.link, faults=faults, **clock)
    except (KeyError, ValueError) as exc:
        raise AesPlannerError(f"cannot emulate: {exc.args[0] if exc.args else exc}") from None

    signal.signal(signal.SIGTERM, lambda signum, frame: emu.request_stop())
    if args.exit_with_parent:  # a node killed outright must not leave its emulator (and pty) behind
        parent_pid = os.getppid()

        def watch() -> None:
            while os.getppid() == parent_pid:
                time.sleep(0.2)
            emu.request_stop()

        threading.Thread(target=watch, daemon=True, name="parent-watch").start()
    try:
        print(emu.pty_path, flush=True)
        servos = ", ".join(f"id {i} {s.model.name}" for i, s in sorted(emu.servos.items()))
        where = emu.pty_path + (f" (link {emu.link})" if emu.link else "")
        print(f"emulating {servos} at {args.baud} baud on {where}; Ctrl-C to stop", file=sys.stderr, flush=True)
        emu.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
        # the last word of a dry run: did the driver leave the servos safe? (read by EmulatorProcess)
        with emu.lock:
            torque = {i: s.torque_on for i, s in sorted(emu.servos.items())}
        on, off = ([f"id {i}" for i, t in torque.items() if t == want] for want in (True, False))
        said = "; ".join(
            p for p in (on and f"torque ON on {', '.join(on)}", off and f"torque off on {', '.join(off)}") if p
        )
        print(f"servo emulator stopped: {said}", flush=True)
    return 0


@drives_servos
def run_scan(args: argparse.Namespace) -> int:
    from aes_planner.drivers.dynamixel import scan

    found = scan(args.port, args.baud)
    print(f"{len(found)} servo(s) on {args.port} at {args.baud} baud")
    for r in found:
        print(f"  id {r.dxl_id:3d}  model {r.model_number:5d} {r.model_name:<12}  firmware {r.firmware_version}")
    return 0


def _joint_args(args: argparse.Namespace) -> tuple[float, float]:
    """--pan-deg/--tilt-deg, accepting the deprecated --yaw-deg/--pitch-deg with a warning."""
    out = []
    for name, old in (("pan_deg", "yaw_deg"), ("tilt_deg", "pitch_deg")):
        flag, old_flag = f"--{name.replace('_', '-')}", f"--{old.replace('_', '-')}"
        value, deprecated = getattr(args, name), getattr(args, f"{old}_deprecated")
        if deprecated is not None:
            if value is not None:
                raise AesPlannerError(f"give {flag} only ({old_flag} is its deprecated spelling)")
            print(
                f"warning: {old_flag} is deprecated, use {flag} (joint angles, not the view's {old.split('_')[0]})",
                file=sys.stderr,
            )
            value = deprecated
        if value is None:
            raise AesPlannerError(f"give {flag} DEGREES (the {name.split('_')[0]} joint angle)")
        if not math.isfinite(value):
            raise AesPlannerError(f"{flag} must be a finite number of degrees, got {value}")
        out.append(value)
    return out[0], out[1]


@drives_servos
def run_move(args: argparse.Namespace) -> int:
    from aes_planner.drivers.dynamixel import MAX_MOVE_TIMEOUT_S

    pan_deg, tilt_deg = _joint_args(args)
    if args.timeout_s is not None and not (math.isfinite(args.timeout_s) and 0 < args.timeout_s <= MAX_MOVE_TIMEOUT_S):
        raise AesPlannerError(
            f"--timeout-s must be a number of seconds in (0, {MAX_MOVE_TIMEOUT_S:g}], got {args.timeout_s}"
        )
    with _gimbal(args) as gimbal:
        pan_rad, tilt_rad = gimbal.move_to(math.radians(pan_deg), math.radians(tilt_deg))
        clamped = (math.degrees(pan_rad), math.degrees(tilt_rad))
        note = (
            ""
            if math.isclose(clamped[0], pan_deg) and math.isclose(clamped[1], tilt_deg)
            else " (clamped to the joint limits)"
        )
        print(f"moving to pan {clamped[0]:+.2f} deg, tilt {clamped[1]:+.2f} deg{note}", flush=True)
        state = gimbal.wait_until_reached(args.timeout_s)
        print(f"arrived: {state.summary()}")
    print("torque off", file=sys.stderr)
    return 0


@drives_servos
def run_state(args: argparse.Namespace) -> int:
    with _gimbal(args) as gimbal:
        state = gimbal.state()
        servos = ", ".join(f"{j} {name}" for j, name in gimbal.models.items())
        print(f"{gimbal.config.port} at {gimbal.config.baud} baud: {servos}")
        print(state.summary())
    return 0


@drives_servos
def run_reboot(args: argparse.Namespace) -> int:
    with _gimbal(args) as gimbal:
        before = gimbal.faults
        gimbal.reboot()
        cleared = "; ".join(f"{j}: {', '.join(f)}" for j, f in before.items()) or "no hardware error was latched"
        print(f"rebooted; cleared {cleared}")
        print(gimbal.state().summary())
    return 0
