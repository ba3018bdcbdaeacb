"""``aes-planner export rosbag2 RECORDING.mcap OUT_DIR``: a recording as a rosbag2 folder (ROS 2 types)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="convert a recording for other tools (rosbag2)",
        description="Convert a package recording (.mcap) into another tool's format.",
    )
    s = p.add_subparsers(dest="export_format", metavar="FORMAT")
    b = s.add_parser(
        "rosbag2",
        help="a rosbag2 folder (MCAP, ROS 2 types) for ros2 bag and Foxglove",
        description="Write OUT_DIR (a new folder) as a rosbag2 bag: metadata.yaml and an MCAP file with the "
        "ROS 2 topics and types of `aes-planner ros2 bridge` (README, 'ROS 2'). Needs the ros2 extra.",
    )
    b.add_argument("recording", metavar="RECORDING.mcap")
    b.add_argument("out_dir", metavar="OUT_DIR")
    b.add_argument("--config", metavar="FILE.yaml", help="a ros2_bridge config (topic names, frames, rig)")
    b.add_argument(
        "--scene", default=None, metavar="SPEC", help="take the rig's kinematics (tf links) from a sim scene"
    )
    b.set_defaults(func=run_rosbag2)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _demo_scene(recording: Path) -> str | None:
    """The simulated rig scene of the demo run folder the recording is in (its summary.json)."""
    import json

    try:
        summary = json.loads((recording.parent / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    scene = summary.get("scene") if isinstance(summary, dict) and summary.get("mode") == "rig" else None
    if isinstance(scene, str) and scene:
        print(f"rig tf links from the run's scene {scene} (--scene to choose another)")
        return scene
    return None


def run_rosbag2(args: argparse.Namespace) -> int:
    from aes_planner.config import from_dict, load_yaml
    from aes_planner.errors import AesPlannerError

    try:
        from aes_planner.ros2.bag import export_rosbag2
        from aes_planner.ros2.bridge import Ros2BridgeConfig
    except ImportError as exc:
        raise AesPlannerError(
            f"export rosbag2 needs the ros2 extra ({exc.name} is missing): pip install 'aes-planner[ros2]'"
        ) from None
    cfg = from_dict(Ros2BridgeConfig, load_yaml(args.config) or {}, "--config") if args.config else None
    scene = args.scene if args.scene is not None else _demo_scene(Path(args.recording))
    rig = None
    if scene is not None and (cfg is None or cfg.rig is None):
        from aes_planner.sim import load_scene

        sim_rig = load_scene(scene).rig
        rig = sim_rig.pan_tilt if sim_rig is not None else None
    counts = export_rosbag2(args.recording, args.out_dir, cfg, rig=rig)
    for topic, n in sorted(counts.items()):
        print(f"{topic:32} {n:6d}")
    print(f"wrote {args.out_dir} ({sum(v for k, v in counts.items() if k.startswith('/'))} messages)")
    return 0
