"""``aes-planner drone emulate``: the package's MAVLink vehicle in the foreground, for dry runs.

It sends to a companion as PX4 SITL does (``udpout:127.0.0.1:14540`` by default: start the
planner with ``--set drone.emulate=false --set drone.connection=udpin:127.0.0.1:14540``), starts
armed and hovering in hold, follows PX4's offboard rules (or ArduPilot's GUIDED), and on exit
(Ctrl-C, SIGTERM or ``--duration``) prints its report as JSON: modes, setpoint gaps, fence and NaN
rejections, forbidden requests. pymavlink is imported only when it runs.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import threading

from aes_planner.errors import AesPlannerError


def _triple(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers, got {text!r}")
    return values  # type: ignore[return-value]


def _window(text: str) -> list[float]:
    try:
        start, dur = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected START_S:DURATION_S, got {text!r}") from None
    return [start, dur]


def register(sub: argparse._SubParsersAction) -> None:
    from aes_planner.drone.modes import AUTOPILOTS

    p = sub.add_parser(
        "drone",
        help="MAVLink drone: emulate a PX4-like vehicle for dry runs",
        description="Tools for flying a MAVLink drone (see README, 'Flying a drone').",
    )
    dsub = p.add_subparsers(dest="drone_command", metavar="ACTION", required=True)
    e = dsub.add_parser(
        "emulate",
        help="run a PX4-like MAVLink vehicle on UDP (Ctrl-C to stop; prints a JSON report)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    e.add_argument("--connection", default="udpout:127.0.0.1:14540", help="where to send (default %(default)s)")
    e.add_argument("--autopilot", choices=AUTOPILOTS, default="px4")
    e.add_argument("--system-id", type=int, default=1)
    e.add_argument(
        "--start-ned",
        type=_triple,
        default=(0.0, 0.0, -2.0),
        metavar="N,E,D",
        help="start, local NED m (negative first: --start-ned=-1,0,-2)",
    )
    e.add_argument("--heading-deg", type=float, default=0.0, help="start heading (0 north, 90 east)")
    e.add_argument("--fence-min-ned", type=_triple, default=None, metavar="N,E,D")
    e.add_argument("--fence-max-ned", type=_triple, default=None, metavar="N,E,D")
    e.add_argument("--gimbal-axes", type=int, choices=(2, 3), default=2)
    e.add_argument("--max-speed", type=float, default=3.0, help="m/s (default 3)")
    e.add_argument("--packet-loss", type=float, default=0.0, help="fraction of packets lost each way")
    e.add_argument(
        "--link-loss", type=_window, action="append", default=[], metavar="START_S:DURATION_S", help="repeatable"
    )
    e.add_argument("--offboard-refused", action="store_true", help="deny every mode switch")
    e.add_argument("--wind", type=_triple, default=(0.0, 0.0, 0.0), metavar="N,E,D", help="drift, m/s NED")
    e.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: until Ctrl-C)")
    e.add_argument("--seed", type=int, default=0)
    e.set_defaults(func=run_emulate)


def run_emulate(args: argparse.Namespace) -> int:
    from aes_planner.config import from_dict

    try:
        import pymavlink  # noqa: F401

        from aes_planner.drone.emulator import EmulatorConfig, VehicleEmulator
    except ImportError:
        raise AesPlannerError("the drone emulator needs pymavlink: pip install 'aes-planner[drone]'") from None
    from aes_planner.drone.emulator import MAX_RUN_S

    if args.duration is not None and not (math.isfinite(args.duration) and 0 < args.duration <= MAX_RUN_S):
        raise AesPlannerError(
            f"--duration must be a number of seconds in (0, {MAX_RUN_S:g}], got {args.duration}; "
            "leave it out to run until Ctrl-C"
        )
    cfg = from_dict(
        EmulatorConfig,
        {
            "connection": args.connection,
            "autopilot": args.autopilot,
            "system_id": args.system_id,
            "start_ned_m": list(args.start_ned),
            "start_heading_deg": args.heading_deg,
            "fence_min_ned_m": list(args.fence_min_ned) if args.fence_min_ned else None,
            "fence_max_ned_m": list(args.fence_max_ned) if args.fence_max_ned else None,
            "gimbal_axes": args.gimbal_axes,
            "max_speed_m_s": args.max_speed,
            "packet_loss": args.packet_loss,
            "link_loss": args.link_loss,
            "offboard_refused": args.offboard_refused,
            "wind_m_s": list(args.wind),
            "seed": args.seed,
        },
        "drone emulate",
    )
    done = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: done.set())
    emu = VehicleEmulator(cfg)
    try:
        emu.start()
        print(f"emulating a {cfg.autopilot} vehicle (system {cfg.system_id}) sending to {cfg.connection}", flush=True)
        try:
            done.wait(args.duration)
        except KeyboardInterrupt:
            pass
    finally:
        emu.stop()
        signal.signal(signal.SIGTERM, previous)
    json.dump(emu.report(), sys.stdout, indent=1)
    print()
    return 0
