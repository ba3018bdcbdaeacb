"""Scenes for the reconstruction tests: an analytic one (ground, sphere, wall) whose surfaces are
known in closed form, and helpers to capture posed frames from the simulator."""

import numpy as np
import pytest

from aes_planner.config import from_dict
from aes_planner.geometry import Intrinsics, look_at
from aes_planner.messages import PosedFrame

SPHERE_CENTRE = np.array([3.0, 0.4, 0.8])
SPHERE_RADIUS = 0.5
WALL_X = 6.0  # the wall's front face

ANALYTIC = {
    "name": "analytic",
    "objects": [
        {
            "type": "plane",
            "name": "ground",
            "point_m": [0, 0, 0],
            "normal": [0, 0, 1],
            "material": {
                "albedo": [0.7, 0.6, 0.5],
                "pattern": {"kind": "checker", "colour2": [0.3, 0.3, 0.35], "scale_m": 0.4},
            },
        },
        {
            "type": "sphere",
            "name": "ball",
            "centre_m": SPHERE_CENTRE.tolist(),
            "radius_m": SPHERE_RADIUS,
            "material": {
                "albedo": [0.2, 0.4, 0.8],
                "pattern": {"kind": "noise", "colour2": [0.9, 0.9, 0.9], "scale_m": 0.1, "octaves": 2, "seed": 3},
            },
        },
        {
            "type": "box",
            "name": "wall",
            "centre_m": [WALL_X + 0.1, 0, 2],
            "size_m": [0.2, 12, 4],
            "material": {
                "albedo": [0.8, 0.75, 0.7],
                "pattern": {
                    "kind": "stripes",
                    "colour2": [0.5, 0.3, 0.3],
                    "scale_m": 0.6,
                    "duty": 0.4,
                    "angle_deg": 30,
                },
            },
        },
    ],
    "rig": {
        "pan_tilt": {"base_xyz_m": [0.0, 0.0, 1.2], "pan_limits_deg": [-60, 60], "tilt_limits_deg": [-40, 30]},
        "camera": {"width": 64, "height": 48, "hfov_deg": 60.0},
    },
}


def surface_distance(points: np.ndarray) -> np.ndarray:
    """Distance (m) from each point ``[N, 3]`` to the nearest analytic surface seen from the front."""
    ground = np.abs(points[:, 2])
    sphere = np.abs(np.linalg.norm(points - SPHERE_CENTRE, axis=1) - SPHERE_RADIUS)
    wall = np.abs(points[:, 0] - WALL_X)
    return np.minimum(np.minimum(ground, sphere), wall)


@pytest.fixture(scope="session")
def analytic_scene():
    from aes_planner.sim import load_scene
    from aes_planner.sim.spec import SceneSpec

    return load_scene(from_dict(SceneSpec, ANALYTIC))


def capture(
    scene, cam2world: np.ndarray, intrinsics: Intrinsics, with_depth: bool = True, supersample: int = 1
) -> PosedFrame:
    from aes_planner.sim import render

    out = render(scene, cam2world, intrinsics, supersample)
    return PosedFrame(
        out.rgb,
        intrinsics,
        cam2world,
        depth_m=out.depth_m if with_depth else None,
        extras={"instance_id": out.instance_id},
    )


def looking_at_ball(eye) -> np.ndarray:
    return look_at(np.asarray(eye, float), SPHERE_CENTRE)
