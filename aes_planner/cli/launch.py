"""``aes-planner launch FILE [--set ID.KEY=VALUE ...]``: run a launch file's nodes in one process.

FILE is a path or the name of a shipped launch file (``sim_closed_loop``, ``pan_tilt_rig``,
``drone``). The nodes run on the in-process bus until the planner finishes (exit 0),
``--timeout`` passes or a node fails (exit 1), or SIGINT / SIGTERM (exit 128 + the signal: 130,
143): every node is then stopped in reverse order, so a gimbal's servos are left unpowered, and
signals that follow wait for that clean-up.
"""

from __future__ import annotations

import argparse
import logging

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "launch",
        help="run the nodes of a launch file in one process",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "file", metavar="FILE", help="launch file path or shipped name (sim_closed_loop, pan_tilt_rig, drone)"
    )
    p.add_argument("--set", action="append", default=[], metavar="ID.KEY=VALUE", help="override a value (repeatable)")
    p.add_argument("--timeout", type=float, default=None, help="stop after this many seconds")
    from aes_planner.cli.processes import add_clock_flag, add_transport_flags

    add_clock_flag(p, "the launch file's clock: (sim_closed_loop: sim; the others: wall)")
    add_transport_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from aes_planner.cli.processes import attach_viewers, check_timeout, clock_overrides, run_processes
    from aes_planner.graph import Launch, build_nodes, load_launch
    from aes_planner.graph.runner import run_graph

    check_timeout(args.timeout)
    args.set = [*args.set, *clock_overrides(args)]
    if args.processes:  # one process per node over Zenoh (aes_planner.graph.supervisor)
        return run_processes(args)
    spec = load_launch(args.file, args.set)
    nodes = build_nodes(spec)
    print(f"launch {spec.path}: " + ", ".join(f"{n.node_id} ({type(n).__name__})" for n, _ in nodes), flush=True)
    launch = Launch(nodes, clock=spec.clock)
    finished, stop = run_graph(launch, timeout_s=args.timeout, open_sinks=lambda bus: attach_viewers(bus, args, spec))
    if stop.exit_code is not None:
        print(f"[launch] stopped by {stop.name}: every node stopped, servos left with torque off", flush=True)
        return stop.exit_code
    for r in launch.runners:
        line = r.node.outcome() if hasattr(r.node, "outcome") and r.node.finished else None
        if line is not None:
            print(line)
    return 0 if finished else 1
