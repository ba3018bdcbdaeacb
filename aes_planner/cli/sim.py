"""``aes-planner sim render|families``: render simulated scenes into dataset folders."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="the synthetic camera simulator")
    ssub = p.add_subparsers(dest="sim_command", metavar="ACTION", required=True)

    r = ssub.add_parser(
        "render",
        help="render a scene from poses spread over the rig's joint range (or the drone's box) into a dataset folder",
    )
    r.add_argument("--scene", required=True, metavar="FILE_OR_FAMILY:SEED", help="a scene YAML file, or e.g. indoor:3")
    r.add_argument("--views", type=int, default=4, help="number of views (default 4)")
    r.add_argument("--out", required=True, help="output dataset folder (images + cameras.json)")
    r.add_argument("--width", type=int, help="override the scene camera's width in pixels")
    r.add_argument("--height", type=int, help="override the scene camera's height in pixels")
    r.add_argument("--supersample", type=int, default=2, help="anti-aliasing samples per pixel side (default 2)")
    r.add_argument("--no-depth", action="store_true", help="do not write depth files")
    r.add_argument("--contact-sheet", action="store_true", help="also write contact_sheet.png (RGB over depth)")
    r.set_defaults(func=run_render)

    f = ssub.add_parser("families", help="list the procedural scene families")
    f.set_defaults(func=run_families)


def render_survey(
    scene_spec: str,
    views: int,
    out: str | Path,
    width: int | None = None,
    height: int | None = None,
    supersample: int = 2,
    depth: bool = True,
    contact_sheet: bool = False,
) -> Path:
    """Render ``views`` frames of a scene from survey poses and save them as a dataset folder."""
    from aes_planner.dataset import DatasetError, save_dataset
    from aes_planner.sim import SimCamera, SimCameraConfig, load_scene

    if views < 1:
        raise DatasetError(f"--views must be at least 1, got {views}")
    scene = load_scene(scene_spec)
    cam = SimCamera(scene, SimCameraConfig(width=width, height=height, supersample=supersample))
    frames, frame_meta = [], []
    if scene.rig is not None:
        for i, (pan, tilt) in enumerate(cam.kinematics.sweep(views)):
            frames.append(cam.capture_joints(pan, tilt, stamp_s=float(i)))
            frame_meta.append({"joints_rad": [float(pan), float(tilt)]})
    else:
        for i, pose in enumerate(scene.drone.survey_poses(views)):
            frames.append(cam.capture_pose(pose, stamp_s=float(i)))
            frame_meta.append({})
    if not depth:
        for f in frames:
            f.depth_m = None
    meta = {
        "source": "aes-planner sim render",
        "scene": scene_spec,
        "scene_name": scene.name,
        "platform": "rig" if scene.rig is not None else "drone",
    }
    path = save_dataset(out, frames, meta=meta, frame_meta=frame_meta)
    if contact_sheet:
        write_contact_sheet(frames, Path(out) / "contact_sheet.png")
    log.info("rendered %d views of %s into %s", len(frames), scene_spec, path.parent)
    return path.parent


def write_contact_sheet(frames, path: Path) -> Path:
    """RGB on top, colour-mapped depth below, one column per frame."""
    import cv2
    import numpy as np

    cols = []
    for f in frames:
        rgb = cv2.cvtColor(f.image, cv2.COLOR_RGB2BGR)
        d = f.depth_m if f.depth_m is not None else np.zeros(f.image.shape[:2], np.float32)
        valid = d > 0
        scale = np.percentile(d[valid], 98) if valid.any() else 1.0
        d8 = np.where(valid, 255 - np.clip(d / scale * 255, 0, 255), 0).astype(np.uint8)
        cols.append(np.vstack([rgb, cv2.applyColorMap(d8, cv2.COLORMAP_VIRIDIS)]))
    sheet = np.hstack([np.pad(c, ((2, 2), (2, 2), (0, 0)), constant_values=255) for c in cols])
    cv2.imwrite(str(path), sheet)
    return path


def run_render(args: argparse.Namespace) -> int:
    out = render_survey(
        args.scene,
        args.views,
        args.out,
        args.width,
        args.height,
        args.supersample,
        depth=not args.no_depth,
        contact_sheet=args.contact_sheet,
    )
    print(f"wrote {args.views} views of {args.scene} to {out}")
    return 0


def run_families(args: argparse.Namespace) -> int:
    from aes_planner.sim import FAMILIES

    for name, fn in FAMILIES.items():
        doc = (fn.__doc__ or "").strip().splitlines()
        print(f"{name:10s} {doc[0] if doc else ''}")
    return 0
