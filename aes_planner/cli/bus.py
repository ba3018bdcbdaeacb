"""Shell tools on the Zenoh bus, like ``ros2 topic`` and ``ros2 bag``:

* ``aes-planner echo TOPIC [--once] [--json]``: print messages as they arrive (images summarised).
* ``aes-planner topics [--duration S] [--json]``: topics with their types, publishers,
  subscribers and rates (over S <= 600 seconds).

Everything printed that came from the bus (topic and type names, messages, errors quoting them)
has its non-printable characters escaped: a peer cannot write control sequences into a terminal.
* ``aes-planner record [TOPIC ...] -o FILE.mcap``: record (all topics by default) until Ctrl-C.
* ``aes-planner replay FILE.mcap [--rate R] [--loop | --count N] [--duration S]``: publish a
  recording again (once, N times, or until Ctrl-C or S seconds).
* ``aes-planner foxglove [--port P]``: serve the bus live to the Foxglove app (loopback).

Each joins the network of ``aes-planner launch --processes`` of its domain (``--domain N`` or
``AES_PLANNER_DOMAIN``, default 0: ``tcp/127.0.0.1:7390``) unless ``--connect`` says otherwise.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import threading
import time

from aes_planner.cli import terminal_safe
from aes_planner.cli.processes import DEFAULT_ENDPOINT, add_domain_flag
from aes_planner.errors import AesPlannerError
from aes_planner.graph.signals import stop_on_signals


def _bus_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("bus")
    g.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"Zenoh endpoint to connect to (repeatable; default: the domain's hub, {DEFAULT_ENDPOINT} in domain 0)",
    )
    g.add_argument(
        "--listen", action="append", metavar="ENDPOINT", help="endpoint to listen on (default: a free loopback port)"
    )
    add_domain_flag(g)
    g.add_argument("--prefix", default=None, help="key prefix of the topics (default: the domain's, aes in domain 0)")
    g.add_argument("--allow-remote", action="store_true", help="allow listening beyond loopback")


def open_cli_bus(args: argparse.Namespace):
    """A Zenoh bus from the ``--connect/--listen/--prefix`` flags."""
    from aes_planner.config import ConfigError
    from aes_planner.transport import ZenohConfig
    from aes_planner.transport.zenoh_bus import ZenohBus

    kw = {"allow_remote": args.allow_remote}
    if args.prefix:
        kw["prefix"] = args.prefix
    if args.connect:
        kw["connect"] = tuple(args.connect)
    if args.listen:
        kw["listen"] = tuple(args.listen)
    try:
        cfg = ZenohConfig(**kw)
    except ConfigError as exc:
        if not exc.key or exc.key.isupper():  # AES_PLANNER_DOMAIN: named as it is
            raise
        raise ConfigError(f"--{exc.key.split('[')[0]}", exc.message) from None
    return ZenohBus(cfg)


def register(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser(
        "echo",
        help="print the messages of a topic as they arrive",
        description="Print each message on TOPIC (a name, or a pattern with * and **) as it arrives; "
        "images are summarised. Malformed messages are reported on stderr and counted.",
    )
    e.add_argument("topic", help="topic name or pattern, e.g. planner/suggestion or 'gimbal/**'")
    e.add_argument("--once", action="store_true", help="exit after the first message")
    e.add_argument("--json", action="store_true", help="one JSON object per line")
    e.add_argument("--timeout", type=float, default=None, metavar="S", help="give up after S seconds")
    _bus_flags(e)
    e.set_defaults(func=run_echo)

    t = sub.add_parser(
        "topics",
        help="list the topics on the bus with types and rates",
        description="List topics with a live publisher or subscriber, their message types, and the "
        "rates measured over --duration seconds.",
    )
    t.add_argument("--duration", type=float, default=2.0, metavar="S", help="listen this long for rates (default 2)")
    t.add_argument("--json", action="store_true", help="print JSON")
    _bus_flags(t)
    t.set_defaults(func=run_topics)

    r = sub.add_parser(
        "record",
        help="record topics to an MCAP file (Ctrl-C to stop)",
        description="Record topics (all by default) into an MCAP file: our own channels carry the exact "
        "bytes (for replay), Foxglove-typed channels show the images, camera, suggestions and scores.",
    )
    r.add_argument("topics", nargs="*", default=["**"], help="topics or patterns (default: all)")
    r.add_argument("-o", "--output", required=True, metavar="FILE.mcap", help="the MCAP file to write")
    r.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    r.add_argument("--no-viz", action="store_true", help="only our channels, no Foxglove-typed ones")
    _bus_flags(r)
    r.set_defaults(func=run_record)

    p = sub.add_parser(
        "replay",
        help="publish an MCAP recording on the bus again",
        description="Publish the messages of a recording with their recorded timing.",
    )
    p.add_argument("file", metavar="FILE.mcap")
    p.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1; 0 = as fast as possible)")
    p.add_argument("--loop", action="store_true", help="start over at the end until Ctrl-C (or --count, --duration)")
    p.add_argument("--count", type=int, default=None, metavar="N", help="play the recording N times (implies --loop)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--topics", nargs="+", default=None, help="only these topics")
    p.add_argument("--wait", type=float, default=1.0, metavar="S", help="wait for subscribers first (default 1 s)")
    _bus_flags(p)
    p.set_defaults(func=run_replay)

    f = sub.add_parser(
        "foxglove",
        help="serve the bus live to the Foxglove app (WebSocket, loopback)",
        description="Bridge every topic of the bus to a Foxglove WebSocket server; open "
        "ws://127.0.0.1:PORT in the Foxglove app.",
    )
    f.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765)")
    f.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    _bus_flags(f)
    f.set_defaults(func=run_foxglove)


def _say(text: str, *, err: bool = False) -> None:
    print(terminal_safe(text), file=sys.stderr if err else sys.stdout, flush=True)


#: Longest ``topics --duration``: it measures rates, it does not watch.
MAX_RATE_WINDOW_S = 600.0


def _check_seconds(value: float | None, flag: str) -> None:
    if value is not None and (not math.isfinite(value) or value <= 0 or value > 1e7):
        raise AesPlannerError(f"{flag} must be a positive number of seconds, got {value}")


def _short(obj, depth: int = 0):
    """Numbers rounded for reading; 4x4 matrices kept (they are small)."""
    if isinstance(obj, float):
        return round(obj, 5)
    if isinstance(obj, dict):
        return {k: _short(v, depth + 1) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_short(v, depth + 1) for v in obj]
    return obj


def run_echo(args: argparse.Namespace) -> int:
    import yaml

    from aes_planner.messages import MessageError, decode, to_jsonable
    from aes_planner.transport import validate_pattern

    _check_seconds(args.timeout, "--timeout")
    pattern = validate_pattern(args.topic)
    printed = rejected = 0
    with stop_on_signals() as stop, contextlib.closing(open_cli_bus(args)) as bus:
        sub = bus.subscribe_raw(pattern, depth=100)
        end = None if args.timeout is None else time.monotonic() + args.timeout
        while not stop.is_set():
            left = None if end is None else end - time.monotonic()
            if left is not None and left <= 0:
                break
            if not sub.wait(min(0.2, left) if left is not None else 0.2):
                continue
            for sample in sub.take():
                try:
                    msg = decode(sample.data)
                except MessageError as exc:
                    rejected += 1
                    _say(f"rejected on {sample.topic}: {exc}", err=True)
                    continue
                body = {"topic": sample.topic, **_short(to_jsonable(msg))}
                if args.json:
                    _say(json.dumps(body))
                else:
                    _say(yaml.safe_dump(body, sort_keys=False, width=120).rstrip() + "\n---")
                printed += 1
                if args.once:
                    return 0
        rejected += sub.rejected
        interrupted = stop.is_set()
    if rejected:
        print(f"{rejected} malformed message(s) rejected", file=sys.stderr)
    if printed == 0 and not interrupted:
        raise AesPlannerError(
            terminal_safe(f"no message on {args.topic} within {args.timeout:g} s; is a publisher running?")
        )
    return 0


def run_topics(args: argparse.Namespace) -> int:
    from aes_planner.messages import MessageError, peek_header

    _check_seconds(args.duration, "--duration")
    if args.duration > MAX_RATE_WINDOW_S:
        raise AesPlannerError(f"--duration is the window rates are measured over: at most {MAX_RATE_WINDOW_S:g} s")
    bus = open_cli_bus(args)
    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    try:
        sub = bus.subscribe_raw("**", depth=100_000, catch_up=False)
        with stop_on_signals() as stop:
            stop.wait(args.duration)
        for s in sub.take():
            counts[s.topic] = counts.get(s.topic, 0) + 1
            try:
                types.setdefault(s.topic, peek_header(s.data).type_name)
            except MessageError:
                types.setdefault(s.topic, "?")
        infos = {i.topic: i for i in bus.topics()}
    finally:
        bus.close()
    rows = []
    for topic in sorted(set(infos) | set(counts)):
        info = infos.get(topic)
        rows.append(
            {
                "topic": topic,
                "type": (info.type_name if info and info.type_name else types.get(topic, "?")),
                "publishers": info.publishers if info else 0,
                "subscribers": info.subscribers if info else 0,
                "latched": bool(info and info.latched),
                "rate_hz": counts.get(topic, 0) / args.duration,
            }
        )
    if args.json:
        _say(json.dumps(rows, indent=1))
        return 0
    if not rows:
        print("no topics (is `aes-planner launch ... --processes` running? see --connect)")
        return 0
    print(f"{'topic':32} {'type':16} {'pubs':>4} {'subs':>4} {'rate_hz':>8}")
    for r in rows:
        latched = " latched" if r["latched"] else ""
        topic, kind = terminal_safe(r["topic"]), terminal_safe(r["type"])
        _say(f"{topic:32} {kind:16} {r['publishers']:4d} {r['subscribers']:4d} {r['rate_hz']:8.2f}{latched}")
    return 0


def run_record(args: argparse.Namespace) -> int:
    from aes_planner.paths import output_file
    from aes_planner.transport import validate_pattern
    from aes_planner.transport.record import Recorder

    _check_seconds(args.duration, "--duration")
    patterns = [validate_pattern(t) for t in args.topics]
    output_file(args.output, "-o")  # not a symlink, a folder or a fifo, in a folder that can be written
    rec = Recorder(args.output, viz=not args.no_viz)
    with contextlib.closing(rec), stop_on_signals() as stop, contextlib.closing(open_cli_bus(args)) as bus:
        rec.attach(bus, patterns)
        print(f"recording {', '.join(args.topics)} to {args.output} (Ctrl-C to stop)", file=sys.stderr)
        stop.wait(args.duration)
    print(f"{rec.written} messages written to {args.output}")
    return 0


def run_replay(args: argparse.Namespace) -> int:
    from aes_planner.transport.record import read_recording, replay

    if not math.isfinite(args.rate) or not (args.rate == 0 or 1e-3 <= args.rate <= 1e3):
        raise AesPlannerError(f"--rate must be 0 (as fast as possible) or in [0.001, 1000], got {args.rate}")
    from aes_planner.transport import validate_topic

    for t in args.topics or ():
        validate_topic(t)
    if not math.isfinite(args.wait) or not 0 <= args.wait <= 60:
        raise AesPlannerError(f"--wait must be in [0, 60] seconds, got {args.wait}")
    _check_seconds(args.duration, "--duration")
    if args.count is not None and not 1 <= args.count <= 1_000_000:
        raise AesPlannerError(f"--count must be in [1, 1000000] passes, got {args.count}")
    passes = args.count if args.count is not None else (None if args.loop else 1)
    next(iter(read_recording(args.file)), None)  # a clear error for a bad file before joining the bus
    with stop_on_signals() as stop, contextlib.closing(open_cli_bus(args)) as bus:
        until = threading.Event()  # a signal, or --duration after the start
        threading.Thread(target=lambda: (stop.wait(args.duration), until.set()), daemon=True).start()
        until.wait(args.wait)
        n = done = 0
        while not until.is_set() and (passes is None or done < passes):
            got = replay(args.file, bus, rate=args.rate, topics=args.topics, stop=until)
            n, done = n + got, done + 1
            if got == 0:
                break
        time.sleep(0.2)  # let the last samples leave before the session closes
    print(f"{n} messages replayed from {args.file}")
    return 0


def run_foxglove(args: argparse.Namespace) -> int:
    from aes_planner.transport.record import FoxgloveLive

    _check_seconds(args.duration, "--duration")
    if not 0 <= args.port <= 65535:
        raise AesPlannerError(f"--port must be in 0..65535, got {args.port}")
    live = FoxgloveLive(port=args.port)
    with contextlib.closing(live), stop_on_signals() as stop, contextlib.closing(open_cli_bus(args)) as bus:
        live.attach(bus)
        live.advertise_bus_topics(bus)  # the topics published now, before their next message
        print(f"Foxglove: open ws://127.0.0.1:{live.port} in the Foxglove app (Ctrl-C to stop)", file=sys.stderr)
        stop.wait(args.duration)
    return 0
