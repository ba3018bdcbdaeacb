"""``aes-planner launch FILE [--set ID.KEY=VALUE ...]``: run a launch file's nodes in one process.

FILE is a path or the name of a shipped launch file (``sim_closed_loop``, ``pan_tilt_rig``,
``drone``). The nodes run on the in-process bus until the planner finishes, ``--timeout``
passes, or Ctrl-C / SIGTERM: every node is then stopped in reverse order, so a gimbal's servos
are left unpowered.
"""

from __future__ import annotations

import argparse
import logging
import threading

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
    from aes_planner.cli.processes import add_transport_flags

    add_transport_flags(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from aes_planner.cli.processes import attach_viewers, check_timeout, close_viewers, run_processes
    from aes_planner.devices import stop_on_signals
    from aes_planner.graph import Launch, build_nodes, load_launch

    check_timeout(args.timeout)
    if args.processes:  # one process per node over Zenoh (aes_planner.graph.supervisor)
        return run_processes(args)
    spec = load_launch(args.file, args.set)
    nodes = build_nodes(spec)
    print(f"launch {spec.path}: " + ", ".join(f"{n.node_id} ({type(n).__name__})" for n, _ in nodes), flush=True)
    stop = threading.Event()

    def on_signal(signum: int) -> None:
        log.warning("signal %d: stopping the nodes (servos are left with torque off)", signum)
        stop.set()

    launch = Launch(nodes)
    # the drivers' safe shutdown: the first SIGINT/SIGTERM stops the loop, a second one raises,
    # and either way every node's stop() (a gimbal's torque-off) runs inside this block
    with stop_on_signals(on_signal=on_signal):
        sinks = attach_viewers(launch.bus, args, spec)  # --foxglove / --record
        try:
            launch.start()
            finished = launch.run(timeout_s=args.timeout, until=lambda: stop.is_set() or _all_finished(launch))
        finally:
            launch.stop()
            close_viewers(sinks)
    for r in launch.runners:
        line = r.node.outcome() if hasattr(r.node, "outcome") and r.node.finished else None
        if line is not None:
            print(line)
    return 0 if finished else 1


def _all_finished(launch) -> bool:
    from aes_planner.graph.base import Node

    finishing = [r.node for r in launch.runners if type(r.node).finished is not Node.finished]
    return bool(finishing) and all(n.finished for n in finishing)
