"""Scene sources and platforms: what training, evaluation and the search need from a scene.

The core never imports the simulator. Training and evaluation take a :class:`SceneSource`:
anything that yields posed frames at poses asked for and renders ground truth there. The
simulator is one (``aes_planner.sim.SimSource``); a source backed by a real rig that captures at
commanded poses is another. A :class:`Platform` says where the camera can go: a pan-tilt rig
(its kinematics and joint limits) or a drone (an axis-aligned flight box).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from aes_planner.config import require, require_finite, to_dict
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.poses import view_to_cam2world
from aes_planner.geometry.rig import PanTiltConfig
from aes_planner.messages import PosedFrame

__all__ = ["RIG_FREE_BOX_HALF_M", "DroneBox", "Platform", "SceneSource", "platform_from_meta", "platform_to_meta"]

#: Half-size of the box free flight takes around a rig's base (``eval search``'s free mode on a rig
#: scene, the field's ``survey`` training inputs).
RIG_FREE_BOX_HALF_M = (0.8, 0.8, 0.3)


#: A drone box's largest side and farthest coordinate, metres (a search samples inside it).
MAX_BOX_SIDE_M = 1e6
#: A drone box's smallest side, metres: a drone holds its position to about this; a thinner box
#: (a side of 0 or 1e-300 m) is a mistake, and would leave the search nowhere to go.
MIN_BOX_SIDE_M = 0.1
MAX_COORDINATE_M = 1e9


@dataclass(frozen=True)
class DroneBox:
    """The axis-aligned box a drone may fly in, world metres."""

    bounds_min_m: tuple[float, float, float]
    bounds_max_m: tuple[float, float, float]

    def __post_init__(self):
        require_finite(list(self.bounds_min_m) + list(self.bounds_max_m), "bounds_m")
        require(
            all(lo < hi for lo, hi in zip(self.bounds_min_m, self.bounds_max_m)),
            "bounds_max_m",
            f"every component must exceed bounds_min_m, got {list(self.bounds_min_m)} / {list(self.bounds_max_m)}",
        )
        for name in ("bounds_min_m", "bounds_max_m"):
            far = max(abs(v) for v in getattr(self, name))
            require(far <= MAX_COORDINATE_M, name, f"a coordinate of {far:.3g} m is beyond {MAX_COORDINATE_M:.0e} m")
        thin = min(hi - lo for lo, hi in zip(self.bounds_min_m, self.bounds_max_m))
        require(
            thin >= MIN_BOX_SIDE_M,
            "bounds_max_m",
            f"a box {thin:.3g} m thin is smaller than a drone holds its position ({MIN_BOX_SIDE_M} m); "
            "give every side at least that",
        )
        side = max(hi - lo for lo, hi in zip(self.bounds_min_m, self.bounds_max_m))
        require(
            side <= MAX_BOX_SIDE_M, "bounds_max_m", f"a box {side:.3g} m across is larger than {MAX_BOX_SIDE_M:.0e} m"
        )

    def contains(self, xyz_m) -> np.ndarray:  # [..., 3] -> [...] bool
        p = np.asarray(xyz_m, dtype=np.float64)
        return np.all((p >= self.bounds_min_m) & (p <= self.bounds_max_m), axis=-1)

    def clamp(self, xyz_m) -> np.ndarray:  # [..., 3] -> [..., 3]
        return np.clip(np.asarray(xyz_m, dtype=np.float64), self.bounds_min_m, self.bounds_max_m)

    @classmethod
    def around(cls, centre_m, half_m, floor_m: float = 0.3) -> DroneBox:
        """The box ``centre_m +- half_m`` (world metres), its floor raised to ``floor_m``."""
        half = np.broadcast_to(np.asarray(half_m, dtype=np.float64), (3,))
        require(bool(np.all(half > 0)), "half_m", f"must be > 0 in every axis, got {half.tolist()}")
        lo = np.asarray(centre_m, dtype=np.float64) - half
        hi = np.asarray(centre_m, dtype=np.float64) + half
        lo[2] = max(lo[2], floor_m)
        return cls(tuple(lo.tolist()), tuple(hi.tolist()))

    def diagonal_positions_m(self, n: int) -> np.ndarray:  # -> [n, 3]
        """``n`` positions from 1/4 to 3/4 along the box's horizontal diagonal, at mid height."""
        lo, hi = np.asarray(self.bounds_min_m), np.asarray(self.bounds_max_m)
        ts = np.linspace(0.25, 0.75, n) if n > 1 else np.array([0.5])
        return lo + ts[:, None] * (hi - lo) * np.array([1.0, 1.0, 0.0]) + np.array([0, 0, 0.5]) * (hi - lo)

    def survey_poses(self, n: int, pitch_deg: float = -10.0) -> np.ndarray:  # -> [n, 4, 4]
        """``n`` cam2world on an arc inside the box (a quarter of the way in from its walls, at mid
        height), each looking across the box centre, slightly down."""
        if n < 1:
            raise ValueError(f"survey_poses needs n >= 1 views, got {n}")
        lo, hi = np.asarray(self.bounds_min_m), np.asarray(self.bounds_max_m)
        centre, half = (lo + hi) / 2, (hi - lo) / 4
        angles = np.linspace(-0.75 * np.pi, 0.75 * np.pi, n) if n > 1 else np.zeros(1)
        views = np.stack(
            [
                centre[0] - half[0] * np.cos(angles),
                centre[1] - half[1] * np.sin(angles),
                np.full(n, centre[2]),
                angles,  # from the arc, looking back across the centre
                np.full(n, np.radians(pitch_deg)),
            ],
            axis=-1,
        )
        return view_to_cam2world(views)


@dataclass(frozen=True)
class Platform:
    """Where the camera can go: ``kind = "rig"`` with ``rig`` set, or ``"drone"`` with ``drone``."""

    kind: str
    intrinsics: Intrinsics
    rig: PanTiltConfig | None = None
    drone: DroneBox | None = None

    def __post_init__(self):
        require(self.kind in ("rig", "drone"), "kind", f"must be 'rig' or 'drone', got {self.kind!r}")
        require(
            (self.rig is not None) == (self.kind == "rig") and (self.drone is not None) == (self.kind == "drone"),
            self.kind,
            f"a {self.kind!r} platform needs its {self.kind!r} section and not the other one",
        )


def platform_to_meta(platform: Platform) -> dict:
    """The JSON-ready description a dataset folder's ``meta`` carries: ``{"platform": "rig",
    "rig": {PanTiltConfig fields}}`` or ``{"platform": "drone", "drone": {"bounds_min_m", "bounds_max_m"}}``."""
    if platform.kind == "rig":
        return {"platform": "rig", "rig": to_dict(platform.rig)}
    box = platform.drone
    return {
        "platform": "drone",
        "drone": {"bounds_min_m": list(box.bounds_min_m), "bounds_max_m": list(box.bounds_max_m)},
    }


def platform_from_meta(meta: dict, intrinsics: Intrinsics) -> Platform | None:
    """The :class:`Platform` written by :func:`platform_to_meta`, or ``None`` when ``meta`` has none.

    Malformed sections raise :class:`~aes_planner.config.ConfigError` naming the key."""
    from aes_planner.config import ConfigError, from_dict, short_repr

    kind = meta.get("platform")
    if kind is not None and kind not in ("rig", "drone"):
        raise ConfigError("meta.platform", f"must be 'rig' or 'drone', got {short_repr(kind)}")
    if kind is not None and meta.get(kind) is not None and not isinstance(meta.get(kind), dict):
        raise ConfigError(f"meta.{kind}", f"expected a mapping, got {short_repr(meta[kind])}")
    if kind == "rig" and isinstance(meta.get("rig"), dict):
        rig = from_dict(
            PanTiltConfig, {k: tuple(v) if isinstance(v, list) else v for k, v in meta["rig"].items()}, "meta.rig"
        )
        return Platform("rig", intrinsics, rig=rig)
    if kind == "drone" and isinstance(meta.get("drone"), dict):
        d = meta["drone"]
        require(set(d) == {"bounds_min_m", "bounds_max_m"}, "meta.drone", "needs bounds_min_m and bounds_max_m only")
        lo, hi = d["bounds_min_m"], d["bounds_max_m"]
        require(
            isinstance(lo, list) and isinstance(hi, list) and len(lo) == 3 and len(hi) == 3,
            "meta.drone",
            f"bounds must be 3 numbers each, got {lo!r} / {hi!r}",
        )
        try:
            box = DroneBox(tuple(lo), tuple(hi))
        except ConfigError as exc:
            raise ConfigError(f"meta.drone.{exc.key}", exc.message) from None
        return Platform("drone", intrinsics, drone=box)
    return None


class SceneSource(ABC):
    """A scene that can be imaged at any pose: frames for the field, ground truth for scoring."""

    #: A name for reports (``indoor:3``, a file name...).
    name: str
    #: The camera's platform and intrinsics.
    platform: Platform

    @abstractmethod
    def capture(self, cam2world: np.ndarray, depth: bool = True, stamp_s: float = 0.0) -> PosedFrame:
        """One frame at ``cam2world [4, 4]`` (world, float64), with depth when ``depth`` and available."""

    @abstractmethod
    def render_rgb(self, cam2world: np.ndarray, intrinsics: Intrinsics | None = None) -> np.ndarray:
        """Ground-truth RGB ``[B, H, W, 3]`` float32 in [0, 1] at ``cam2world [B, 4, 4]``
        (the platform's intrinsics unless given)."""
