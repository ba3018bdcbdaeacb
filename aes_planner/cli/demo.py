"""``aes-planner demo``: the simulated closed loop, end to end, measured against the oracle.

Runs ``launch/sim_closed_loop.yaml`` (``--mode rig``: sim camera on a pan-tilt rig, the real
Dynamixel driver on the servo emulator's pty, the planner's active loop) or ``launch/drone.yaml``
with a simulated drone (``--mode drone``) on a scene, prints each capture as it happens, then
scores the views with the teacher on ground-truth renders (:mod:`aes_planner.eval.closed_loop`)
and writes a run folder:

* ``summary.json``: ``initial``, ``final``, ``oracle``, ``normalized`` (``(s - mean random) /
  (oracle - mean random)``), ``moves``, ``time_s``, ``scene``, ``mode``, ``initial_cam2world``,
  ``final_cam2world`` (and for the rig ``final_pan_deg``, ``final_tilt_deg``), ``clock`` (``sim``
  or ``wall``) and on a simulated clock ``sim_time_s`` (when the loop ended, simulated seconds);
* ``suggestions.json``: every suggestion the planner published; ``captures.json``: every capture
  (``stamp_s``: when, on the graph's clock);
* ``report.png``: the input views, each move's view with its true score, the rig's pan x tilt
  ground-truth score map with the path taken, and the final view beside the oracle's best.

The graph runs on a simulated clock in lockstep by default (``--clock sim``): the same scene gives
the same views, moves and scores idle or loaded, in one process or with ``--processes``;
``--clock wall`` runs it in real time (docs/guides/clock.md). A MAVLink vehicle runs in real time.

The last line printed is the path of ``summary.json``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from aes_planner.errors import AesPlannerError
from aes_planner.paths import output_in

DEFAULT_SCENE = "indoor:3"


def register(sub: argparse._SubParsersAction) -> None:
    from aes_planner.platform import KIND_WORDS

    p = sub.add_parser(
        "demo",
        help="the simulated closed loop on a scene: explore, suggest, move, verify, polish, settle; scored against the oracle",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--scene", default=DEFAULT_SCENE, metavar="FILE_OR_FAMILY:SEED", help=f"scene (default {DEFAULT_SCENE})"
    )
    p.add_argument(
        "--mode",
        choices=KIND_WORDS,
        default=None,
        help="the platform: pan-tilt rig or drone (free: the older word for drone; default: what the scene has; "
        "a drone on a rig scene flies the box around the rig's base)",
    )
    p.add_argument(
        "--drone",
        choices=("sim", "mavlink"),
        default="sim",
        help="a drone: a simulated one, or a MAVLink vehicle (launch/drone_mavlink.yaml; the package's emulator "
        "unless --set drone.emulate=false --set drone.connection=...)",
    )
    p.add_argument("--out", default=None, metavar="DIR", help="run folder (default runs/demo-<time>)")
    p.add_argument("--moves", type=int, default=4, help="suggestion-driven moves at most (default 4)")
    p.add_argument(
        "--set", action="append", default=[], metavar="ID.KEY=VALUE", help="override a launch-file value (repeatable)"
    )
    p.add_argument("--timeout", type=float, default=600.0, help="give up after this many seconds (default 600)")
    from aes_planner.cli.processes import add_clock_flag, add_transport_flags

    add_clock_flag(p, "sim (wall with --drone mavlink)")
    add_transport_flags(p, "run the gimbal and the camera each in its own process over Zenoh (the planner stays here)")
    p.set_defaults(func=run)


#: Platform kind -> the launch file that runs it, and its settings.
LAUNCH_FILES = {
    "rig": ("sim_closed_loop.yaml", []),
    "drone": ("drone.yaml", ["drone.type=sim", "planner.platform.type=drone"]),
}
#: Scene platforms a drone can fly around (a box around a rig's base).
CAN_FLY_AROUND = ("rig",)

#: What a run writes into its folder.
RUN_FILES = ("summary.json", "suggestions.json", "captures.json", "report.png", "recording.mcap")


def run(args: argparse.Namespace) -> int:
    from aes_planner.cli.processes import check_timeout
    from aes_planner.config import ConfigError

    if args.moves < 0:
        raise ConfigError("--moves", f"must be >= 0, got {args.moves}")
    check_timeout(args.timeout)
    if args.out:  # a bad run folder fails now, before the loop runs
        from aes_planner.paths import output_folder

        for name in RUN_FILES:
            output_in(output_folder(args.out, "--out"), name)
    out = Path(args.out) if args.out else Path("runs") / f"demo-{dt.datetime.now().strftime('%Y%m%d-%H%M%S')}"
    result = run_demo(
        args.scene,
        args.mode,
        out,
        args.moves,
        args.set,
        args.timeout,
        progress=print,
        transport=args,
        drone=args.drone,
        clock=args.clock,
    )
    print_summary(result)
    print(out.resolve() / "summary.json")
    return 0 if result["state"] == "done" else 1


def run_demo(
    scene: str,
    mode: str | None,
    out: Path,
    moves: int = 4,
    overrides=(),
    timeout_s: float = 600.0,
    progress=None,
    planner_overrides: dict | None = None,
    transport: argparse.Namespace | None = None,
    drone: str = "sim",
    hook=None,
    clock: str | None = None,
) -> dict:
    """Run the closed loop and write the run folder; returns the summary dict (plus ``state``).

    ``mode``: the platform kind, ``rig`` or ``drone`` (``free`` read as drone); ``None`` takes what
    the scene has (a rig, else its drone box). ``clock``: ``sim`` (default) or ``wall``. ``hook(nodes)``:
    called with the built nodes before they run (``eval loop``'s perturbations).

    ``transport``: the ``--processes/--listen/--foxglove/--record`` flags (see
    :mod:`aes_planner.cli.processes`); every topic is recorded to ``out/recording.mcap``."""
    from aes_planner.cli.processes import attach_viewers
    from aes_planner.config import ConfigError
    from aes_planner.geometry.poses import cam2world_to_view
    from aes_planner.graph import Launch, build_nodes, load_launch
    from aes_planner.graph.runner import run_graph
    from aes_planner.graph.signals import SignalShutdown
    from aes_planner.platform import DronePlatform, parse_kind
    from aes_planner.sim import load_scene
    from aes_planner.sim.source import platform_of

    say = progress or (lambda *_: None)
    scene_kind = platform_of(load_scene(scene)).kind  # a bad scene fails here, with its key named
    kind = parse_kind(mode, "--mode") if mode else scene_kind
    if kind != scene_kind and scene_kind not in CAN_FLY_AROUND:
        raise ConfigError("--mode", f"scene {scene!r} has a drone box, not a pan-tilt rig: use --mode drone")
    launch_file, sets = LAUNCH_FILES[kind]
    if drone == "mavlink":  # a MAVLink vehicle (aes_planner.drone.demo)
        from aes_planner.drone import demo as mavlink_demo

        kind, launch_file, sets = DronePlatform.kind, mavlink_demo.LAUNCH_FILE, ["planner.platform.type=drone"]
    if drone == "mavlink" and clock == "sim":
        raise ConfigError("--clock", "a MAVLink vehicle (and its emulator) flies in real time: use --clock wall")
    clock = clock or ("wall" if drone == "mavlink" else "sim")
    sets = [f"scene={scene}", f"planner.max_moves={moves}", f"clock={clock}", *sets]
    sets += [f"planner.{k}={json.dumps(v)}" for k, v in (planner_overrides or {}).items()]
    spec = load_launch(launch_file, [*sets, *overrides])
    nodes = build_nodes(spec)
    planner = next(n for n, _ in nodes if n.node_id == "planner")
    if hook is not None:
        hook(nodes)
    say(
        f"demo: {kind} on {scene}, {spec.clock.source} clock: "
        + ", ".join(f"{n.node_id} ({type(n).__name__})" for n, _ in nodes)
    )
    from aes_planner.gaussians.warmup import warm_kernels

    warm_kernels()  # a fresh install compiles them here (and says so), not in the loop's first plan
    t0 = time.time()
    shown = 0

    def report_progress() -> bool:
        nonlocal shown
        caps = planner.captures
        while shown < len(caps):
            c = caps[shown]
            view = cam2world_to_view(c.cam2world)
            where = (
                f"pan {math.degrees(c.pan_rad):+7.1f} tilt {math.degrees(c.tilt_rad):+6.1f} deg"
                if c.pan_rad is not None
                else "x {:+.2f} y {:+.2f} z {:+.2f} yaw {:+6.1f} pitch {:+5.1f}".format(
                    *view[:3], *np.degrees(view[3:])
                )
            )
            pred = f" (predicted {c.predicted:.3f})" if c.predicted is not None and c.kind == "move" else ""
            when = f"sim {c.stamp_s:6.2f} s" if spec.clock.sim else f"{time.time() - t0:5.1f} s"
            say(f"  [{when}] {c.kind:8s} {where}  score {c.score:.3f}{pred}")
            shown += 1
        return planner.finished

    transport = transport or argparse.Namespace(processes=False, foxglove=None, record=None)
    if transport.processes:  # the other nodes in their own processes over Zenoh, supervised
        from aes_planner.graph.supervisor import Supervisor

        local = [(n, r) for n, r in nodes if n.node_id == "planner"]
        launch = Supervisor(
            launch_file,
            [*sets, *overrides],
            endpoint=transport.listen,
            connect=transport.connect,
            allow_remote=transport.allow_remote,
            local_nodes=local,
            out=sys.stdout,
        )
    else:
        launch = Launch(nodes, clock=spec.clock)
    out.mkdir(parents=True, exist_ok=True)
    recording = output_in(out, "recording.mcap")
    viewers = argparse.Namespace(foxglove=transport.foxglove, record=transport.record or str(recording))
    # SIGTERM / Ctrl-C: the nodes stop, the servos are left with torque off, then exit 128 + signal
    ended = (lambda: mavlink_demo.aborted(nodes)) if drone == "mavlink" else (lambda: False)
    ok, stop = run_graph(
        launch,
        timeout_s=timeout_s,
        until=lambda: report_progress() or ended(),
        open_sinks=lambda bus: attach_viewers(bus, viewers, spec),
    )
    if stop.signum is not None:
        say(f"demo: stopped by {stop.name}: every node stopped, servos left with torque off; not scored")
        raise SignalShutdown(stop.signum)
    report_progress()
    loop_s = time.time() - t0
    if drone == "mavlink" and mavlink_demo.aborted(nodes):
        reason = mavlink_demo.abort_reason(nodes)
        say(f"demo: {reason}")
        if not planner.captures:  # nothing to score: the reason is the error, not "captured nothing"
            raise AesPlannerError(f"demo: the vehicle was not flown: {reason}")
    elif not ok and not planner.finished:
        say(f"demo: the loop did not finish within {timeout_s:g} s (state {planner.state})")
    say(f"demo: loop {planner.state} after {loop_s:.1f} s; scoring against the oracle ...")
    from aes_planner.eval.closed_loop import evaluate_run

    summary = evaluate_run(planner, scene, kind, out, loop_s)
    summary["time_s"] = round(time.time() - t0, 2)
    summary["clock"] = spec.clock.source
    if spec.clock.sim and planner.finished_s is not None:
        summary["sim_time_s"] = round(planner.finished_s, 6)
    if drone == "mavlink":
        summary["drone"] = mavlink_demo.drone_summary(nodes)
    output_in(out, "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def print_summary(s: dict) -> None:
    print(
        f"{s['mode']} on {s['scene']}: initial {s['initial']:.3f} -> final {s['final']:.3f} "
        f"(oracle {s['oracle']:.3f}, random {s['random_mean']:.3f}); normalized {s['normalized']:.2f} "
        f"(initial view {s['initial_normalized']:.2f}) in {s['moves']} move{'' if s['moves'] == 1 else 's'} after {s['explore_captures']} "
        f"exploration captures, {s.get('verify_captures', 0)} verifying and {s['polish_captures']} polishing; {s['time_s']:.1f} s ({s['loop_s']:.1f} s in the loop)"
    )
    if "final_pan_deg" in s:
        print(f"final view: pan {s['final_pan_deg']:+.1f} deg, tilt {s['final_tilt_deg']:+.1f} deg")
