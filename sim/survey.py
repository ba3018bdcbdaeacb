"""Survey renders: a scene seen from poses spread over the rig's joint range (or the drone's box),
saved as a dataset folder (``aes-planner sim render`` and ``aes-planner demo``)."""

from __future__ import annotations

import logging
import math
from pathlib import Path

from aes_planner.dataset import DatasetError, save_dataset
from aes_planner.dataset.folder import check_intrinsics, check_output_folder
from aes_planner.geometry.plausible import FOV_RANGE_DEG
from aes_planner.images import write_contact_sheet
from aes_planner.platform import platform_to_meta
from aes_planner.sim.camera import SimCamera, SimCameraConfig
from aes_planner.sim.scene import load_scene
from aes_planner.sim.source import platform_of

log = logging.getLogger(__name__)

#: Most views one survey renders (each is a full ray-cast render kept in memory until saved).
MAX_VIEWS = 10_000

__all__ = ["render_survey"]


def render_survey(
    scene_spec: str,
    views: int,
    out: str | Path,
    width: int | None = None,
    height: int | None = None,
    supersample: int = 2,
    depth: bool = True,
    contact_sheet: bool = False,
    allow_outside: bool = False,
) -> Path:
    """Render ``views`` frames of a scene from survey poses and save them as a dataset folder; returns the folder.

    ``allow_outside``: let a scene file's image paths leave its folder (see :class:`~aes_planner.sim.Scene`)."""
    if isinstance(views, bool) or not isinstance(views, int) or not 1 <= views <= MAX_VIEWS:
        raise DatasetError(f"--views must be an integer in [1, {MAX_VIEWS}], got {views!r}")
    check_output_folder(out)
    scene = load_scene(scene_spec, allow_outside=allow_outside)
    cam = SimCamera(scene, SimCameraConfig(width=width, height=height, supersample=supersample))
    k = cam.intrinsics
    try:  # a folder its own loader would refuse is not written (checked before the renders)
        check_intrinsics(k, "camera")
    except DatasetError:
        lo, hi = FOV_RANGE_DEG
        raise DatasetError(
            f"camera: {k.width}x{k.height} px with {math.degrees(k.hfov_rad):.3g} x {math.degrees(k.vfov_rad):.3g} deg "
            f"fields of view; a dataset holds {lo} to {hi} deg both ways: change the scene camera's hfov_deg "
            "or --width / --height"
        ) from None
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
        # the rig's kinematics and joint limits (or the drone's box), for `aes-planner suggest`
        **platform_to_meta(platform_of(scene, cam.intrinsics)),
    }
    path = save_dataset(out, frames, meta=meta, frame_meta=frame_meta)
    if contact_sheet:
        write_contact_sheet(frames, Path(out) / "contact_sheet.png")
    log.info("rendered %d views of %s into %s", len(frames), scene_spec, path.parent)
    return path.parent
