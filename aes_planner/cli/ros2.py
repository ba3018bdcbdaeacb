"""``aes-planner ros2 bridge``: the package's bus on a ROS 2 DDS domain, as a process of its own.

Joins the Zenoh bus as ``echo`` does (the hub of its ``--domain``, ``tcp/127.0.0.1:7390`` in domain
0, unless ``--connect``) and runs the ``ros2_bridge`` node (:mod:`aes_planner.ros2.bridge`) on it
until Ctrl-C. Its DDS domain is the graph's unless ``--domain-id`` or ``ROS_DOMAIN_ID`` says. ``ROS_DOMAIN_ID``,
``ROS_AUTOMATIC_DISCOVERY_RANGE``, ``ROS_STATIC_PEERS`` and ``CYCLONEDDS_URI`` are honoured as
rmw_cyclonedds does; discovery stays on this machine unless ``--discovery-range`` (with
``--allow-remote-dds``) says otherwise.
"""

from __future__ import annotations

import argparse
import contextlib
import sys

from aes_planner.cli.bus import _bus_flags, _check_seconds, open_cli_bus
from aes_planner.graph.signals import stop_on_signals


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ros2",
        help="bridge the bus to ROS 2 (DDS, no ROS install needed)",
        description="ROS 2 interop over DDS with ROS 2's wire names and stock message types.",
    )
    s = p.add_subparsers(dest="ros2_command", metavar="SUBCOMMAND")
    b = s.add_parser(
        "bridge",
        help="publish the planner's topics to ROS 2 (and read a ROS 2 rig with --inbound)",
        description="Join the bus and bridge it to a ROS 2 DDS domain until Ctrl-C: suggestions, joint "
        "states, images, camera info, tf and diagnostics out (README, 'ROS 2').",
    )
    b.add_argument("--config", metavar="FILE.yaml", help="a ros2_bridge config (topics, qos, frames, rig...)")
    b.add_argument(
        "--domain-id",
        type=int,
        default=None,
        help="DDS domain (default: ROS_DOMAIN_ID, else the graph's --domain, else 0)",
    )
    b.add_argument(
        "--discovery-range",
        choices=("loopback", "localhost", "subnet", "off", "system_default"),
        default=None,
        help="as ROS_AUTOMATIC_DISCOVERY_RANGE (default: that variable, else loopback: this machine over the "
        "loopback interface only; localhost: as rmw_cyclonedds does, to meet ROS 2 nodes run with LOCALHOST)",
    )
    b.add_argument("--allow-remote-dds", action="store_true", help="allow a discovery range beyond this machine")
    b.add_argument("--scene", default=None, metavar="SPEC", help="take the rig's kinematics (tf) from a sim scene")
    b.add_argument(
        "--ros-graph",
        choices=("jazzy", "humble"),
        default=None,
        help="announce the bridge as a ROS 2 node (ros2 node list) to nodes of this release (jazzy: Iron and later)",
    )
    b.add_argument("--inbound", action="store_true", help="also read a ROS 2 camera and gimbal (needs a rig)")
    b.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    _bus_flags(b)
    b.set_defaults(func=run_bridge)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def build_bridge(args: argparse.Namespace):
    """The bridge node from the flags (and ``--config``)."""
    from aes_planner.config import ConfigError, from_dict, load_yaml
    from aes_planner.graph.base import LaunchContext
    from aes_planner.ros2.bridge import Ros2BridgeConfig, Ros2BridgeNode
    from aes_planner.ros2.dds import MAX_DOMAIN_ID

    if args.domain_id is not None and not 0 <= args.domain_id <= MAX_DOMAIN_ID:
        raise ConfigError("--domain-id", f"must be in 0..{MAX_DOMAIN_ID} (as ROS_DOMAIN_ID), got {args.domain_id}")
    data = dict(load_yaml(args.config) or {}) if args.config else {}
    dds = dict(data.get("dds") or {})
    if args.domain_id is not None:
        dds["domain_id"] = args.domain_id
    if args.discovery_range is not None:
        dds["discovery_range"] = args.discovery_range
    if args.allow_remote_dds:
        dds["allow_remote"] = True
    data["dds"] = dds
    if args.inbound:
        data["inbound"] = True
    if args.ros_graph:
        data["ros_graph"] = args.ros_graph
    cfg = from_dict(Ros2BridgeConfig, data, "--config" if args.config else "")
    return Ros2BridgeNode(cfg, "ros2", LaunchContext(scene=args.scene))


def run_bridge(args: argparse.Namespace) -> int:
    from aes_planner.errors import AesPlannerError
    from aes_planner.graph.runner import NodeRunner

    _check_seconds(args.duration, "--duration")
    try:
        import cyclonedds  # noqa: F401
    except ImportError:
        raise AesPlannerError(
            "ros2 bridge needs the ros2 extra (cyclonedds): pip install 'aes-planner[ros2]'"
        ) from None
    node = build_bridge(args)
    with stop_on_signals() as stop, contextlib.closing(open_cli_bus(args)) as bus:
        runner = NodeRunner(node, bus)
        runner.open()
        try:
            node.start()
            d = node.dds
            print(
                f"ROS 2 bridge: DDS domain {d.domain_id}, discovery {d.discovery_range}; topics "
                f"{', '.join(node.config.topic(k) for k in node._writers)} (Ctrl-C to stop)",
                file=sys.stderr,
            )
            runner.start_thread()
            stop.wait(args.duration)
        finally:
            runner.request_stop()
            runner.join()
            node.stop()
            runner.close()
    sent = {k[5:]: v for k, v in node.counters.items() if k.startswith("sent.")}
    print("sent: " + (", ".join(f"{k} {v}" for k, v in sorted(sent.items())) or "nothing"))
    return stop.exit_code or 0  # 128 + signal after Ctrl-C or SIGTERM, as launch returns
