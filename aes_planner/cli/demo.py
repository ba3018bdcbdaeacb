"""``aes-planner demo``: the main job of ``make demo``.

Until the planner's closed loop lands, it renders a simulated scene from a sweep of rig poses
into a run folder (a dataset folder plus a contact sheet) and prints where it went.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the demonstration (make demo)")
    p.add_argument(
        "--scene", default="indoor:3", metavar="FILE_OR_FAMILY:SEED", help="scene to render (default indoor:3)"
    )
    p.add_argument("--views", type=int, default=6, help="number of rig views (default 6)")
    p.add_argument("--runs", default="runs", help="parent folder of the run folder (default runs/)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from aes_planner.dataset import load_dataset
    from aes_planner.geometry import cam2world_to_view
    from aes_planner.sim import render_survey

    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(args.runs) / f"demo-{stamp}"
    render_survey(args.scene, args.views, out, contact_sheet=True)
    ds = load_dataset(out)
    print(f"rendered {len(ds)} rig views of {args.scene}:")
    print("  view  pan_deg tilt_deg    x_m    y_m    z_m  yaw_deg pitch_deg")
    for f in ds.frames:
        pan, tilt = f.extras["meta"]["joints_rad"]
        x, y, z, yaw, pitch = cam2world_to_view(f.cam2world)
        print(
            f"  {f.frame_id[-6:]} {math.degrees(pan):8.1f} {math.degrees(tilt):8.1f} "
            f"{x:6.2f} {y:6.2f} {z:6.2f} {math.degrees(yaw):8.1f} {math.degrees(pitch):8.1f}"
        )
    print(f"run folder: {out.resolve()}")
    print("  cameras.json, images/, depth/ and contact_sheet.png (RGB over depth)")
    return 0
