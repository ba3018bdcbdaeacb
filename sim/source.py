"""``SimSource``: a simulated scene as a :class:`~aes_planner.sources.SceneSource`."""

from __future__ import annotations

import numpy as np

from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import validate_cam2world
from aes_planner.messages import PosedFrame
from aes_planner.platform import DroneBox, DronePlatform, Platform, RigPlatform
from aes_planner.sim.camera import SimCamera, SimCameraConfig
from aes_planner.sim.raycast import render
from aes_planner.sim.scene import Scene, load_scene
from aes_planner.sources import SceneSource

__all__ = ["SimSource", "platform_of"]


def platform_of(scene: Scene, intrinsics: Intrinsics | None = None) -> Platform:
    """The :class:`Platform` of a scene's rig or drone section."""
    k = intrinsics or scene.intrinsics()
    if scene.rig is not None:
        return RigPlatform(k, scene.rig.pan_tilt)
    box = DroneBox(tuple(scene.drone.bounds_min_m), tuple(scene.drone.bounds_max_m))
    return DronePlatform(k, box)


class SimSource(SceneSource):
    """Frames and ground-truth renders of a simulated scene (``"indoor:3"``, a YAML path or a Scene).

    ``supersample`` anti-aliases both (the ground truth the teacher scores should not alias).
    """

    def __init__(self, scene: Scene | str, supersample: int = 2, camera: SimCameraConfig | None = None):
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
        self.name = str(scene) if not isinstance(scene, Scene) else self.scene.name
        self.camera = SimCamera(self.scene, camera or SimCameraConfig(supersample=supersample))
        self.platform = platform_of(self.scene, self.camera.intrinsics)
        self.supersample = supersample

    def capture(self, cam2world: np.ndarray, depth: bool = True, stamp_s: float = 0.0) -> PosedFrame:
        frame = self.camera.capture_pose(np.asarray(cam2world, dtype=np.float64), stamp_s=stamp_s)
        if not depth:
            frame.depth_m = None
        return frame

    def render_rgb(self, cam2world: np.ndarray, intrinsics: Intrinsics | None = None) -> np.ndarray:
        poses = np.asarray(cam2world, dtype=np.float64).reshape(-1, 4, 4)
        k = intrinsics or self.platform.intrinsics
        out = np.empty((len(poses), k.height, k.width, 3), np.float32)
        for i, pose in enumerate(poses):
            rgb = render(self.scene, validate_cam2world(pose), k, supersample=self.supersample).rgb  # [H, W, 3] uint8
            out[i] = rgb.astype(np.float32) / 255.0
        return out
