"""Simulated calibration set-ups: a rig scene with a board texture, and rigs that differ from
their drawing, for tests, benchmarks and trying ``calibrate rig --scene`` without hardware.

The scene is plain data (a scene YAML mapping, :mod:`aes_planner.sim.spec`'s format): the board
is a quad with ``image: "board:SPEC"`` (the pattern with one white square of margin), facing the
rig's base, on a floor, under soft light.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from aes_planner.geometry.board import BoardSpec
from aes_planner.geometry.rig import PanTiltConfig, rig_dict

__all__ = ["board_scene", "perturbed_rig"]


def board_scene(
    truth: PanTiltConfig,
    board: BoardSpec,
    distance_m: float = 2.0,
    bearing_deg: float = 0.0,
    height_m: float | None = None,
    camera: tuple[int, int, float] = (640, 480, 60.0),
    name: str = "calibration",
) -> dict:
    """A scene mapping: ``truth`` as the rig, the board ``distance_m`` from the pan axis at
    ``bearing_deg`` (about the base's z, from +x), its centre at ``height_m`` (default: the base's)."""
    bx, by, bz = truth.base_xyz_m
    a = math.radians(bearing_deg)
    h = bz if height_m is None else height_m
    w, hgt = board.size_m(1)
    return {
        "name": name,
        "lights": [
            {"type": "ambient", "intensity": 0.65},
            {"type": "directional", "direction": [-0.3, -0.2, -1.0], "intensity": 0.45, "shadows": False},
        ],
        "objects": [
            {
                "type": "quad",
                "name": "board",
                "centre_m": [bx + distance_m * math.cos(a), by + distance_m * math.sin(a), h],
                "size_m": [w, hgt],
                "yaw_deg": bearing_deg + 180.0,  # facing the rig
                "material": {"image": f"board:{board}"},
            },
            {"type": "plane", "point_m": [0, 0, 0], "normal": [0, 0, 1], "material": {"albedo": [0.5, 0.45, 0.4]}},
        ],
        "rig": {
            "pan_tilt": rig_dict(truth),
            "camera": {"width": camera[0], "height": camera[1], "hfov_deg": camera[2]},
        },
    }


def perturbed_rig(
    nominal: PanTiltConfig, rng: np.random.Generator, offset_mm=(10.0, 40.0), mount_deg=(1.0, 2.0)
) -> PanTiltConfig:
    """A "true" rig off its drawing: lever arm and tilt offset each moved ``offset_mm`` (a random
    direction, a length in that range), the camera mount turned by ``mount_deg`` about a random axis."""

    def shift(v):
        d = rng.normal(size=3)
        return tuple(float(x) for x in np.asarray(v) + d / np.linalg.norm(d) * rng.uniform(*offset_mm) / 1000.0)

    axis = rng.normal(size=3)
    rpy = axis / np.linalg.norm(axis) * rng.uniform(*mount_deg)
    return replace(
        nominal,
        tilt_offset_m=shift(nominal.tilt_offset_m),
        lever_arm_m=shift(nominal.lever_arm_m),
        camera_mount_rpy_deg=tuple(float(x) for x in rpy),
    )
