"""``aes-planner demo``: the simulated closed loop, end to end, measured against the oracle.

Runs ``launch/sim_closed_loop.yaml`` (``--mode rig``: sim camera on a pan-tilt rig, the real
Dynamixel driver on the servo emulator's pty, the planner's active loop) or ``launch/drone.yaml``
with a simulated drone (``--mode free``) on a scene, prints each capture as it happens, then
scores the views with the teacher on ground-truth renders and writes a run folder:

* ``summary.json``: ``initial``, ``final``, ``oracle``, ``normalized`` (``(s - mean random) /
  (oracle - mean random)``), ``moves``, ``time_s``, ``scene``, ``mode``, ``initial_cam2world``,
  ``final_cam2world`` (and for the rig ``final_pan_deg``, ``final_tilt_deg``);
* ``suggestions.json``: every suggestion the planner published; ``captures.json``: every capture;
* ``report.png``: the input views, each move's view with its true score, the rig's pan x tilt
  ground-truth score map with the path taken, and the final view beside the oracle's best.

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

from aes_planner.paths import output_in

DEFAULT_SCENE = "indoor:3"


def register(sub: argparse._SubParsersAction) -> None:
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
        choices=("rig", "free"),
        default=None,
        help="pan-tilt rig or a free-flying drone (default: what the scene has, a rig or a drone box)",
    )
    p.add_argument(
        "--drone",
        choices=("sim", "mavlink"),
        default="sim",
        help="free mode: a simulated drone, or a MAVLink vehicle (launch/drone_mavlink.yaml; the package's emulator "
        "unless --set drone.emulate=false --set drone.connection=...)",
    )
    p.add_argument("--out", default=None, metavar="DIR", help="run folder (default runs/demo-<time>)")
    p.add_argument("--moves", type=int, default=6, help="suggestion-driven moves at most (default 6)")
    p.add_argument(
        "--set", action="append", default=[], metavar="ID.KEY=VALUE", help="override a launch-file value (repeatable)"
    )
    p.add_argument("--timeout", type=float, default=600.0, help="give up after this many seconds (default 600)")
    from aes_planner.cli.processes import add_transport_flags

    add_transport_flags(p, "run the gimbal and the camera each in its own process over Zenoh (the planner stays here)")
    p.set_defaults(func=run)


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
        args.scene, args.mode, out, args.moves, args.set, args.timeout, progress=print, transport=args, drone=args.drone
    )
    print_summary(result)
    print(out.resolve() / "summary.json")
    return 0 if result["state"] == "done" else 1


def run_demo(
    scene: str,
    mode: str | None,
    out: Path,
    moves: int = 6,
    overrides=(),
    timeout_s: float = 600.0,
    progress=None,
    planner_overrides: dict | None = None,
    transport: argparse.Namespace | None = None,
    drone: str = "sim",
) -> dict:
    """Run the closed loop and write the run folder; returns the summary dict (plus ``state``).

    ``mode``: ``rig`` or ``free``; ``None`` takes what the scene has (a rig, else its drone box).

    ``transport``: the ``--processes/--listen/--foxglove/--record`` flags (see
    :mod:`aes_planner.cli.processes`); every topic is recorded to ``out/recording.mcap``."""
    from aes_planner.cli.processes import attach_viewers
    from aes_planner.config import ConfigError
    from aes_planner.graph import Launch, build_nodes, load_launch
    from aes_planner.graph.runner import run_graph
    from aes_planner.graph.signals import SignalShutdown
    from aes_planner.sim import load_scene

    say = progress or (lambda *_: None)
    has_rig = load_scene(scene).rig is not None  # a bad scene fails here, with its key named
    mode = mode or ("rig" if has_rig else "free")
    if mode == "rig" and not has_rig:
        raise ConfigError("--mode", f"scene {scene!r} has a drone box, not a pan-tilt rig: use --mode free")
    sets = [f"scene={scene}", f"planner.max_moves={moves}"]
    if drone == "mavlink":  # a MAVLink vehicle (aes_planner.drone.demo)
        from aes_planner.drone import demo as mavlink_demo

        mode, launch_file = "free", mavlink_demo.LAUNCH_FILE
        sets += ["planner.mode=free"]
    elif mode == "rig":
        launch_file = "sim_closed_loop.yaml"
    else:
        launch_file = "drone.yaml"
        sets += ["drone.type=sim", "planner.mode=free"]
    sets += [f"planner.{k}={json.dumps(v)}" for k, v in (planner_overrides or {}).items()]
    spec = load_launch(launch_file, [*sets, *overrides])
    nodes = build_nodes(spec)
    planner = next(n for n, _ in nodes if n.node_id == "planner")
    say(f"demo: {mode} mode on {scene}: {', '.join(f'{n.node_id} ({type(n).__name__})' for n, _ in nodes)}")
    from aes_planner.gaussians.warmup import warm_kernels

    warm_kernels()  # a fresh install compiles them here (and says so), not in the loop's first plan
    t0 = time.time()
    shown = 0

    def report_progress() -> bool:
        nonlocal shown
        caps = planner.captures
        while shown < len(caps):
            c = caps[shown]
            where = (
                f"pan {math.degrees(c.pan_rad):+7.1f} tilt {math.degrees(c.tilt_rad):+6.1f} deg"
                if c.pan_rad is not None
                else "x {:+.2f} y {:+.2f} z {:+.2f} yaw {:+6.1f} pitch {:+5.1f}".format(
                    *_view(c.cam2world)[:3], *np.degrees(_view(c.cam2world)[3:])
                )
            )
            pred = f" (predicted {c.predicted:.3f})" if c.predicted is not None and c.kind == "move" else ""
            say(f"  [{time.time() - t0:5.1f} s] {c.kind:8s} {where}  score {c.score:.3f}{pred}")
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
        launch = Launch(nodes)
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
        say(f"demo: {mavlink_demo.abort_reason(nodes)}")
    elif not ok and not planner.finished:
        say(f"demo: the loop did not finish within {timeout_s:g} s (state {planner.state})")
    say(f"demo: loop {planner.state} after {loop_s:.1f} s; scoring against the oracle ...")
    summary = evaluate_run(planner, scene, mode, out, loop_s)
    summary["time_s"] = round(time.time() - t0, 2)
    if drone == "mavlink":
        summary["drone"] = mavlink_demo.drone_summary(nodes)
    output_in(out, "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def _view(c2w: np.ndarray) -> np.ndarray:
    from aes_planner.geometry.poses import cam2world_to_view

    return np.asarray(cam2world_to_view(c2w), dtype=np.float64)


def evaluate_run(planner, scene: str, mode: str, out: Path, loop_s: float) -> dict:
    from aes_planner.messages import to_jsonable
    from aes_planner.node.evaluate import normalized, oracle, random_poses, true_scores
    from aes_planner.sim import SimSource

    out.mkdir(parents=True, exist_ok=True)
    source = SimSource(scene, supersample=2)
    teacher = planner.teacher
    platform = planner.platform if planner.platform is not None else source.platform
    platform = type(platform)(platform.kind, source.platform.intrinsics, platform.rig, platform.drone)
    caps = [c for c in planner.captures if math.isfinite(c.score)]
    if not caps:
        from aes_planner.graph import NodeError

        raise NodeError(
            f"the planner captured nothing (state {planner.state}) within the run; see the log above, or give it "
            "more time (--timeout)"
        )
    poses = np.stack([_true_pose(planner, c) for c in caps])  # [M, 4, 4]
    truth = true_scores(source, teacher, poses)  # [M]
    best_oracle, oracle_c2w, extras = oracle(source, teacher, platform)
    if "mean_random" in extras:  # the search's oracle samples feasible random views itself
        rand = float(extras["mean_random"])
    else:
        rand = float(true_scores(source, teacher, random_poses(platform, 48, seed=7)).mean())
    final_i = len(caps) - 1 if caps[-1].kind == "settle" else int(np.argmax([c.score for c in caps]))
    initial, final = float(truth[0]), float(truth[final_i])
    summary = {
        "scene": scene,
        "mode": mode,
        "state": planner.state,
        "initial": round(initial, 4),
        "final": round(final, 4),
        "oracle": round(max(best_oracle, final), 4),
        "random_mean": round(rand, 4),
        "normalized": round(normalized(final, max(best_oracle, final), rand), 4),
        "initial_normalized": round(normalized(initial, max(best_oracle, final), rand), 4),
        "moves": planner.moves,
        "explore_captures": sum(c.kind == "explore" for c in caps),
        "polish_captures": sum(c.kind == "polish" for c in caps),
        "captures": len(caps),
        "loop_s": round(loop_s, 2),
        "time_s": None,
        "initial_cam2world": poses[0].tolist(),
        "final_cam2world": poses[final_i].tolist(),
        "oracle_cam2world": np.asarray(oracle_c2w).tolist(),
        "scorer": planner.config.scorer,
        "preset": planner.config.preset,
    }
    if caps[final_i].pan_rad is not None:
        summary["final_pan_deg"] = round(math.degrees(caps[final_i].pan_rad), 3)
        summary["final_tilt_deg"] = round(math.degrees(caps[final_i].tilt_rad), 3)
    output_in(out, "suggestions.json").write_text(json.dumps([to_jsonable(s) for s in planner.suggestions], indent=1))
    output_in(out, "captures.json").write_text(
        json.dumps(
            [
                {
                    "kind": c.kind,
                    "captured_score": c.score,
                    "true_score": float(t),
                    "predicted": c.predicted,
                    "pan_rad": c.pan_rad,
                    "tilt_rad": c.tilt_rad,
                    "cam2world": p.tolist(),
                }
                for c, t, p in zip(caps, truth, poses)
            ],
            indent=1,
        )
    )
    try:
        write_report(
            output_in(out, "report.png"),
            planner,
            caps,
            truth,
            source,
            teacher,
            platform,
            oracle_c2w,
            best_oracle,
            extras,
        )
    except Exception as exc:  # the figures must not lose the measurement
        print(f"warning: report image failed: {exc}", file=sys.stderr)
    return summary


def _true_pose(planner, cap) -> np.ndarray:
    if cap.pan_rad is not None and planner.kinematics is not None:
        return planner.kinematics.forward(cap.pan_rad, cap.tilt_rad)
    return cap.cam2world


def write_report(path, planner, caps, truth, source, teacher, platform, oracle_c2w, oracle_score, extras) -> None:
    import cv2

    from aes_planner.geometry.pantilt import PanTilt
    from aes_planner.node.evaluate import score_map

    tile_w = 192

    def tile(img_rgb: np.ndarray, label: str) -> np.ndarray:
        h = int(round(img_rgb.shape[0] * tile_w / img_rgb.shape[1]))
        t = cv2.resize(img_rgb, (tile_w, h), interpolation=cv2.INTER_AREA)
        t = cv2.copyMakeBorder(t, 0, 18, 0, 0, cv2.BORDER_CONSTANT, value=(255, 255, 255))
        cv2.putText(t, label, (3, h + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
        return t

    def row(tiles: list[np.ndarray], title: str) -> np.ndarray:
        if not tiles:
            return np.zeros((0, 0, 3), np.uint8)
        h = max(t.shape[0] for t in tiles)
        tiles = [
            cv2.copyMakeBorder(t, 0, h - t.shape[0], 0, 4, cv2.BORDER_CONSTANT, value=(255, 255, 255)) for t in tiles
        ]
        body = np.concatenate(tiles, axis=1)
        head = np.full((20, body.shape[1], 3), 255, np.uint8)
        cv2.putText(head, title, (3, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        return np.concatenate([head, body], axis=0)

    inputs = [
        tile(c.image, f"{c.kind} {t:.3f}")
        for c, t in zip(caps, truth)
        if c.kind in ("initial", "explore") and c.image is not None
    ]
    moves = [
        tile(c.image, f"move {i + 1}: {t:.3f}")
        for i, (c, t) in enumerate((c, t) for c, t in zip(caps, truth) if c.kind == "move")
        if c.image is not None
    ]
    final_i = len(caps) - 1 if caps[-1].kind == "settle" else int(np.argmax(truth))
    final_img = (source.render_rgb(_true_pose(planner, caps[final_i])[None])[0] * 255).astype(np.uint8)
    oracle_img = (source.render_rgb(np.asarray(oracle_c2w)[None])[0] * 255).astype(np.uint8)
    last = [tile(final_img, f"final {truth[final_i]:.3f}"), tile(oracle_img, f"oracle {oracle_score:.3f}")]
    if platform.kind == "rig":
        rig = PanTilt(platform.rig)
        if "grid_scores" in extras and "grid_joints" in extras:
            joints, scores = np.asarray(extras["grid_joints"]), np.asarray(extras["grid_scores"])
        elif "grid_scores" in extras and "pan_values" in extras and "tilt_values" in extras:
            pans, tilts = np.asarray(extras["pan_values"]), np.asarray(extras["tilt_values"])
            scores = np.asarray(extras["grid_scores"]).reshape(len(tilts), len(pans))
            joints = np.stack(np.meshgrid(pans, tilts), -1)
        else:
            joints, scores = score_map(source, teacher, rig, 25, 9)
        last.insert(0, _score_map_image(rig, joints, scores, caps, 2 * tile_w))
    rows = [
        row(inputs, "inputs: initial view and exploration captures (true score)"),
        row(moves, "moves: captured view (true score)"),
        row(last, "pan x tilt ground-truth score map with the path; final view; the oracle's best"),
    ]
    rows = [r for r in rows if r.size]
    width = max(r.shape[1] for r in rows)
    rows = [
        cv2.copyMakeBorder(r, 0, 6, 0, width - r.shape[1], cv2.BORDER_CONSTANT, value=(255, 255, 255)) for r in rows
    ]
    sheet = np.concatenate(rows, axis=0)
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))


def _score_map_image(rig, joints: np.ndarray, scores: np.ndarray, caps, width: int) -> np.ndarray:
    """Scores [T, P] (tilt rows bottom-up) as a colour map, the captures' path drawn over it."""
    import cv2

    (plo, phi), (tlo, thi) = rig.pan_limits_rad, rig.tilt_limits_rad
    lo, hi = float(scores.min()), float(scores.max())
    norm = ((scores - lo) / max(hi - lo, 1e-9) * 255).astype(np.uint8)[::-1]  # top row = highest tilt
    height = max(int(width * (thi - tlo) / max(phi - plo, 1e-9)), 60)
    img = cv2.applyColorMap(cv2.resize(norm, (width, height), interpolation=cv2.INTER_NEAREST), cv2.COLORMAP_VIRIDIS)
    img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)

    def px(pan, tilt):
        return (int((pan - plo) / (phi - plo) * (width - 1)), int((thi - tilt) / (thi - tlo) * (height - 1)))

    pts = [px(c.pan_rad, c.tilt_rad) for c in caps if c.pan_rad is not None]
    for a, b in zip(pts, pts[1:]):
        cv2.line(img, a, b, (255, 255, 255), 1, cv2.LINE_AA)
    for p, c in zip(pts, [c for c in caps if c.pan_rad is not None]):
        colour = {
            "initial": (255, 255, 255),
            "explore": (200, 200, 200),
            "move": (255, 80, 80),
            "polish": (255, 200, 0),
            "settle": (255, 0, 0),
        }.get(c.kind, (255, 255, 255))
        cv2.circle(img, p, 4 if c.kind != "settle" else 6, colour, -1 if c.kind != "settle" else 2, cv2.LINE_AA)
    return img


def print_summary(s: dict) -> None:
    print(
        f"{s['mode']} on {s['scene']}: initial {s['initial']:.3f} -> final {s['final']:.3f} "
        f"(oracle {s['oracle']:.3f}, random {s['random_mean']:.3f}); normalized {s['normalized']:.2f} "
        f"(initial view {s['initial_normalized']:.2f}) in {s['moves']} move{'' if s['moves'] == 1 else 's'} after {s['explore_captures']} "
        f"exploration captures and {s['polish_captures']} polishing; {s['time_s']:.1f} s ({s['loop_s']:.1f} s in the loop)"
    )
    if "final_pan_deg" in s:
        print(f"final view: pan {s['final_pan_deg']:+.1f} deg, tilt {s['final_tilt_deg']:+.1f} deg")
