"""Transport options of ``aes-planner launch`` and ``demo``: ``--processes`` (one process per node
over Zenoh, supervised), ``--listen``, ``--foxglove [PORT]`` (live view) and ``--record FILE``.

Not a command of its own: :mod:`aes_planner.cli.launch` and :mod:`aes_planner.cli.demo` call
:func:`add_transport_flags`, :func:`run_processes` and :func:`attach_viewers` (closed by
:func:`aes_planner.graph.runner.close_sinks`).
"""

from __future__ import annotations

import argparse
import logging
import sys

from aes_planner.errors import AesPlannerError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7390"  # aes_planner.transport.config.DEFAULT_ENDPOINT (why 7390: there)


def add_domain_flag(g) -> None:
    """``--domain N``: the graph's domain (docs/guides/graphs.md); read by every tool on the bus."""
    g.add_argument(
        "--domain",
        type=int,
        default=None,
        metavar="N",
        help="the graph's domain, 0-232 (default: AES_PLANNER_DOMAIN, else 0): graphs in different domains "
        "never see each other; hub port 7390 - N, key prefix aes<N> (docs/guides/graphs.md)",
    )


def add_transport_flags(p: argparse.ArgumentParser, processes_help: str | None = None) -> None:
    g = p.add_argument_group("transport")
    g.add_argument(
        "--processes",
        action="store_true",
        help=processes_help or "run each node in its own process over Zenoh (supervised; respawn: true restarts)",
    )
    add_domain_flag(g)
    g.add_argument(
        "--listen",
        default=None,
        metavar="ENDPOINT",
        help=f"with --processes: where the graph's hub listens (default: the launch file's bus.listen, else the "
        f"domain's hub, {DEFAULT_ENDPOINT} in domain 0); echo/record/replay and other machines connect here",
    )
    g.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="with --processes: also join the graph at this endpoint (another machine's hub; repeatable)",
    )
    g.add_argument("--allow-remote", action="store_true", help="allow --listen beyond loopback")
    g.add_argument(
        "--foxglove",
        nargs="?",
        const=8765,
        type=int,
        default=None,
        metavar="PORT",
        help="serve every topic live to the Foxglove app on ws://127.0.0.1:PORT (default 8765)",
    )
    g.add_argument("--record", default=None, metavar="FILE.mcap", help="record every topic to an MCAP file")


def add_clock_flag(p: argparse.ArgumentParser, default_help: str) -> None:
    """``--clock sim|wall``: the graph's time (docs/guides/clock.md)."""
    p.add_argument(
        "--clock",
        choices=("sim", "wall"),
        default=None,
        help="sim: simulated time in lockstep (a result depends on the scene and the code, not on the load); "
        f"wall: real time; default: {default_help}",
    )


def clock_overrides(args: argparse.Namespace) -> list[str]:
    """The ``--set`` a ``--clock`` flag stands for."""
    return [f"clock={args.clock}"] if getattr(args, "clock", None) else []


def declared_outputs(spec) -> list[tuple[str, type, bool]]:
    """``(topic, message type, latched)`` of every output a launch's nodes declare, remapped."""
    from aes_planner.graph.base import node_class, output_specs

    out = []
    for e in spec.nodes:
        if e.type != "external":
            for name, o in output_specs(node_class(e.type)).items():
                out.append((e.remap.get(name, name), o.msg_type, o.latched))
    return out


def attach_viewers(bus, args: argparse.Namespace, spec=None) -> list:
    """The Foxglove server and/or recorder that ``--foxglove`` / ``--record`` ask for, attached to
    ``bus``; close them (in reverse) when the run ends. The server advertises the outputs of
    ``spec``'s nodes (a launch spec) from the start."""
    from aes_planner.transport.record import FoxgloveLive, Recorder

    sinks = []
    try:
        if getattr(args, "record", None):
            rec = Recorder(args.record)
            sinks.append(rec)
            if spec is not None:  # which clock ran (a simulated run's stamps are simulated seconds)
                rec.add_metadata("run", {"clock": spec.clock.source, "clock_step_s": spec.clock.step_s})
            rec.attach(bus)
        port = getattr(args, "foxglove", None)
        if port is not None:
            if not 0 <= port <= 65535:
                raise AesPlannerError(f"--foxglove port must be in 0..65535, got {port}")
            declared = declared_outputs(spec) if spec is not None else ()
            live = FoxgloveLive(port=port, declared=declared).attach(bus)
            print(f"Foxglove: open ws://127.0.0.1:{live.port} in the Foxglove app", file=sys.stderr, flush=True)
            sinks.append(live)
    except BaseException:
        from aes_planner.graph.runner import close_sinks

        close_sinks(sinks)
        raise
    return sinks


def supervisor_from_args(args: argparse.Namespace, in_process=(), out=None):
    """A :class:`~aes_planner.graph.supervisor.Supervisor` for ``args.file`` / ``args.set``."""
    from aes_planner.config import ConfigError
    from aes_planner.graph.supervisor import Supervisor
    from aes_planner.transport.config import ZenohConfig, graph_domain, hub_endpoint

    try:
        ZenohConfig(
            listen=(args.listen or hub_endpoint(graph_domain()),),
            connect=tuple(args.connect),
            allow_remote=args.allow_remote,
        )
    except ConfigError as exc:
        raise ConfigError("--listen" if exc.key.startswith("listen") else "--connect", exc.message) from None
    level = logging.getLogger().getEffectiveLevel()
    supervisor = Supervisor(
        args.file,
        args.set,
        endpoint=args.listen,
        connect=args.connect,
        allow_remote=args.allow_remote,
        in_process=in_process,
        out=out,
        log_level=level,
    )
    if supervisor.spec.scene is not None:  # a bad scene fails here, not in every child
        from aes_planner.sim import load_scene

        load_scene(supervisor.spec.scene)
    return supervisor


def run_processes(args: argparse.Namespace) -> int:
    """``aes-planner launch FILE --processes``: supervise until the planner finishes (0), a node
    is lost or ``--timeout`` (1), or SIGINT / SIGTERM (128 + the first signal, after every child
    stopped)."""
    from aes_planner.graph.runner import run_graph
    from aes_planner.transport.config import graph_domain

    sup = supervisor_from_args(args)
    print(
        f"launch {sup.spec.path} (one process per node, domain {graph_domain()}, hub {sup.endpoint}): "
        + ", ".join(c.node_id for c in sup.children),
        flush=True,
    )
    finished, stop = run_graph(
        sup, timeout_s=getattr(args, "timeout", None), open_sinks=lambda bus: attach_viewers(bus, args, sup.spec)
    )
    if stop.exit_code is not None:
        print(f"[launch] stopped by {stop.name}: every node stopped", flush=True)
    died = [c.node_id for c in sup.children if any(code not in (0, 143, -15) for code in c.exit_codes)]
    if died:
        print(f"[launch] nodes that died during the run: {', '.join(died)}", flush=True)
    if stop.exit_code is not None:
        return stop.exit_code
    return 0 if finished else 1


def check_timeout(timeout_s: float | None) -> None:
    """``--timeout`` is None (no limit) or a finite number of seconds > 0."""
    import math

    from aes_planner.config import ConfigError

    if timeout_s is not None and not (math.isfinite(timeout_s) and timeout_s > 0):
        raise ConfigError("--timeout", f"must be a finite number of seconds > 0, got {timeout_s}")
