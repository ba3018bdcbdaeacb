"""A suggested view said the way a photographer acts on it: from the nearest input photo, how far
to step right / up / forward and how much to turn and tilt ("from IMG_0042.jpg: 0.6 m right,
0.1 m up, turn 12 deg left, tilt 5 deg down").

Directions are those of the photo's camera, levelled: *right* and *forward* along the photo's
horizontal right and viewing directions, *up* along world +z; *turn* is the change of yaw (left:
counter-clockwise seen from above), *tilt* the change of pitch (up: looking higher), as the 5-DoF
views of :mod:`aes_planner.geometry` define them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aes_planner.geometry.poses import cam2world_to_view, wrap_angle

__all__ = ["RelativeMove", "moves_from_photos", "nearest_photo", "relative_move"]

#: Below these a component is not worth saying ("0.0 m right").
SAY_MIN_LENGTH = 0.05
SAY_MIN_DEG = 1.0


@dataclass
class RelativeMove:
    """The move from photo ``photo`` to a suggested view: steps in the photo's levelled frame
    (``unit`` lengths) and the turn / tilt in degrees."""

    photo: str
    right: float
    up: float
    forward: float
    turn_left_deg: float
    tilt_up_deg: float
    unit: str = "m"
    photo_index: int = -1  # the photo's index among the inputs

    def text(self) -> str:
        u = "m" if self.unit == "m" else "units"
        parts = []
        for value, pos, neg in (
            (self.right, "right", "left"),
            (self.up, "up", "down"),
            (self.forward, "forward", "back"),
        ):
            if abs(value) >= SAY_MIN_LENGTH:
                parts.append(f"{abs(value):.1f} {u} {pos if value > 0 else neg}")
        if abs(self.turn_left_deg) >= SAY_MIN_DEG:
            parts.append(f"turn {abs(self.turn_left_deg):.0f} deg {'left' if self.turn_left_deg > 0 else 'right'}")
        if abs(self.tilt_up_deg) >= SAY_MIN_DEG:
            parts.append(f"tilt {abs(self.tilt_up_deg):.0f} deg {'up' if self.tilt_up_deg > 0 else 'down'}")
        return f"from {self.photo}: " + (", ".join(parts) if parts else "stay where it was taken")

    def to_json(self) -> dict:
        return {
            "photo": self.photo,
            "right": self.right,
            "up": self.up,
            "forward": self.forward,
            "turn_left_deg": self.turn_left_deg,
            "tilt_up_deg": self.tilt_up_deg,
            "unit": self.unit,
            "photo_index": self.photo_index,
            "text": self.text(),
        }


def nearest_photo(target: np.ndarray, photos_cam2world: np.ndarray, scale: float) -> int:
    """The index of the photo ``[N, 4, 4]`` nearest ``target [4, 4]``: distance over ``scale`` (a
    length worth one radian of view change, e.g. the cameras' spread) plus the angle between the
    optical axes, so that a photo from the same spot looking the same way wins."""
    d = np.linalg.norm(photos_cam2world[:, :3, 3] - target[:3, 3], axis=1) / max(scale, 1e-12)
    cos = np.clip(photos_cam2world[:, :3, 2] @ target[:3, 2], -1.0, 1.0)
    return int(np.argmin(d + np.arccos(cos)))


def moves_from_photos(
    targets: np.ndarray, photos_cam2world: np.ndarray, names: list[str], unit: str = "m"
) -> list[RelativeMove]:
    """Each of ``targets [K, 4, 4]`` as a :class:`RelativeMove` from its :func:`nearest_photo` among
    ``photos_cam2world [N, 4, 4]`` (named ``names``), the cameras' spread weighing distance against angle."""
    photos = np.asarray(photos_cam2world, np.float64)
    spread = float(np.max(np.linalg.norm(photos[:, None, :3, 3] - photos[None, :, :3, 3], axis=-1)))
    out = []
    for target in np.asarray(targets, np.float64).reshape(-1, 4, 4):
        j = nearest_photo(target, photos, spread)
        out.append(relative_move(names[j], photos[j], target, unit, j))
    return out


def relative_move(
    photo: str, photo_cam2world: np.ndarray, target: np.ndarray, unit: str = "m", photo_index: int = -1
) -> RelativeMove:
    """The :class:`RelativeMove` from a photo's pose to ``target`` (both cam2world ``[4, 4]``, world z up)."""
    va, vb = (
        cam2world_to_view(np.asarray(photo_cam2world, np.float64)),
        cam2world_to_view(np.asarray(target, np.float64)),
    )
    yaw = float(va[3])
    forward = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    step = np.asarray(target)[:3, 3] - np.asarray(photo_cam2world)[:3, 3]
    return RelativeMove(
        photo,
        right=float(-step @ left),
        up=float(step[2]),
        forward=float(step @ forward),
        turn_left_deg=math.degrees(float(wrap_angle(np.asarray(vb[3] - va[3])))),
        tilt_up_deg=math.degrees(float(vb[4] - va[4])),
        unit=unit,
        photo_index=photo_index,
    )
