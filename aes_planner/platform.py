"""Platforms: where the camera can go, and how it gets there.

A platform is a :class:`RigPlatform` (a camera on a pan-tilt rig: its kinematics and joint limits),
a :class:`DronePlatform` (a camera that flies inside an axis-aligned box) or a
:class:`HandHeldPlatform` (a photographer's camera: the region they walked, around the photos'
cameras with a margin; ``aes-planner pose`` writes it). The platform owns
everything that differs between the two, so code above it asks the platform instead of testing
its kind:

* what the search moves (the search owns its spaces: :func:`aes_planner.search.space.space_for`
  opens a rig's joints, a drone's or a hand-held camera's 5-DoF views; this module is a leaf that
  imports no search);
* what a command must stay inside (:meth:`RigPlatform.check`: the joint limits, a command beyond
  them or NaN/Inf refused, never clamped -- the one clamp is the device's,
  :class:`~aes_planner.geometry.rig.JointLimits`; :meth:`DronePlatform.clamp`: a pose moved into
  the box);
* the box free flight takes around it (:meth:`Platform.free_box`: a rig's is
  ``RIG_FREE_BOX_HALF_M`` around its base, a drone's is its own);
* the arrival test (:meth:`RigPlatform.arrived`: the gimbal at its goal, the goal ours;
  :meth:`DronePlatform.arrived`: a frame's pose close to the target's).

**One word for the kind**: ``rig``, ``drone`` or ``handheld`` (:attr:`Platform.kind`; ``handheld``
only where photos are read: the search and ``suggest``, not a launch file's node). ``free`` -- the word the
search, the launch files and the command line used for a drone before -- is still accepted
wherever a kind is read (:func:`parse_kind`), so no launch file or command breaks.
"""

from __future__ import annotations

import functools
import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from aes_planner.config import ConfigError, from_dict, require, require_finite, short_repr, tag_of, to_dict
from aes_planner.geometry.camera import Intrinsics
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world
from aes_planner.geometry.rig import PanTiltConfig

__all__ = [
    "KINDS",
    "KIND_WORDS",
    "PLATFORM_TYPES",
    "RIG_FREE_BOX_HALF_M",
    "DroneBox",
    "DronePlatform",
    "DronePlatformConfig",
    "HandHeldPlatform",
    "Platform",
    "RigPlatform",
    "RigPlatformConfig",
    "free_box_around",
    "parse_kind",
    "parse_platform",
    "platform_from_meta",
    "platform_to_meta",
    "view_angle_deg",
]

#: The platform kinds, and the older words read as one of them (``free`` flew a drone).
KINDS = ("rig", "drone")
_ALIASES = {"rig": "rig", "drone": "drone", "free": "drone"}
#: Every word a kind is read from (:func:`parse_kind`): the command lines' ``--mode`` choices.
KIND_WORDS = tuple(_ALIASES)
#: The hand-held photographer's kind (:class:`HandHeldPlatform`): searched, never driven by a node.
HANDHELD = "handheld"
#: How far beyond the photos' own pitches a hand-held search looks, degrees.
HANDHELD_PITCH_MARGIN_DEG = 10.0

#: Half-size of the box free flight takes around a rig's base, metres: ``eval search``'s drone mode
#: on a rig scene, the field's ``survey`` training inputs, and the simulated drone of ``demo --mode
#: drone`` on a rig scene. (The sim drone flew +-1 m x 1 m x 0.5 m before; this box is the one the
#: committed ``eval search`` tables and the shipped field's training inputs were made with.)
RIG_FREE_BOX_HALF_M = (0.8, 0.8, 0.3)

#: A drone box's largest side and farthest coordinate, metres (a search samples inside it).
MAX_BOX_SIDE_M = 1e6
#: A drone box's smallest side, metres: a drone holds its position to about this; a thinner box
#: (a side of 0 or 1e-300 m) is a mistake, and would leave the search nowhere to go.
MIN_BOX_SIDE_M = 0.1
MAX_COORDINATE_M = 1e9


def parse_kind(word, key: str = "kind", allow_auto: bool = False, allow_handheld: bool = False) -> str:
    """``rig`` or ``drone`` from what a user wrote (``free`` means ``drone``; ``auto`` passes through
    when ``allow_auto``, ``handheld`` when ``allow_handheld``); anything else is a
    :class:`~aes_planner.config.ConfigError` on ``key``."""
    if allow_auto and word == "auto":
        return "auto"
    if allow_handheld and word == HANDHELD:
        return HANDHELD
    if isinstance(word, str) and word in _ALIASES:
        return _ALIASES[word]
    choices = ("auto, " if allow_auto else "") + ("rig, drone or handheld" if allow_handheld else "rig or drone")
    raise ConfigError(key, f"must be {choices} ('free' is read as drone), got {short_repr(word)}")


@dataclass(frozen=True)
class DroneBox:
    """The axis-aligned box a drone may fly in, world metres."""

    bounds_min_m: tuple[float, float, float]
    bounds_max_m: tuple[float, float, float]

    def __post_init__(self):
        require_finite(list(self.bounds_min_m) + list(self.bounds_max_m), "bounds_m")
        require(
            len(self.bounds_min_m) == 3 and len(self.bounds_max_m) == 3,
            "bounds_m",
            f"need 3 numbers each (x, y, z), got {list(self.bounds_min_m)} / {list(self.bounds_max_m)}",
        )
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

    @property
    def diagonal_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.bounds_max_m, self.bounds_min_m)))

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


def view_angle_deg(a: np.ndarray, b: np.ndarray) -> float:  # [4, 4], [4, 4] -> degrees
    """Angle between two cam2world poses' optical axes, degrees."""
    za, zb = a[:3, 2], b[:3, 2]
    return math.degrees(math.atan2(np.linalg.norm(np.cross(za, zb)), float(np.dot(za, zb))))


def free_box_around(rig: PanTiltConfig, half_m=RIG_FREE_BOX_HALF_M) -> DroneBox:
    """The box free flight takes around a rig's base: ``half_m`` each way, the floor at 0.3 m."""
    return DroneBox.around(rig.base_xyz_m, np.asarray(half_m))


@dataclass(frozen=True)
class Platform(ABC):
    """Where the camera can go (see the module docstring). ``rig`` / ``drone`` are the
    :class:`PanTiltConfig` / :class:`DroneBox` of the platform that has one, else None."""

    intrinsics: Intrinsics
    kind: ClassVar[str]
    rig = None
    drone = None

    @abstractmethod
    def free_box(self, half_m=RIG_FREE_BOX_HALF_M) -> DroneBox:
        """The box a drone flies in here: a rig's ``half_m`` around its base, a drone's own."""

    def as_drone(self) -> DronePlatform:
        """The drone platform of :meth:`free_box` (itself for a drone)."""
        return DronePlatform(self.intrinsics, self.free_box())

    @abstractmethod
    def to_meta(self) -> dict:
        """The JSON-ready description a dataset folder's ``meta`` carries."""


@dataclass(frozen=True)
class RigPlatform(Platform):
    """A camera on a pan-tilt rig: joints inside their limits, through the rig's kinematics."""

    rig: PanTiltConfig
    kind: ClassVar[str] = "rig"

    def __post_init__(self):
        require(isinstance(self.rig, PanTiltConfig), "rig", f"a rig platform needs a PanTiltConfig, got {self.rig!r}")

    @functools.cached_property
    def kinematics(self) -> PanTilt:
        return PanTilt(self.rig)

    def check(self, pan_rad: float, tilt_rad: float) -> tuple[float, float]:
        """The joints unchanged when inside the limits (:meth:`JointLimits.check`: within
        ``JOINT_LIMIT_TOLERANCE_RAD``); beyond them, or NaN/Inf,
        :class:`~aes_planner.geometry.JointCommandError`. The planner refuses what fails; the
        device applies the one clamp (:class:`~aes_planner.geometry.rig.JointLimits`)."""
        return self.kinematics.limits.check(pan_rad, tilt_rad)

    def arrived(self, state, pan_rad: float, tilt_rad: float, tol_rad: float, any_goal: bool = False) -> bool:
        """Whether a gimbal ``state`` (:class:`~aes_planner.messages.GimbalState`) stands still at
        its goal, and that goal is ``(pan_rad, tilt_rad)`` within ``tol_rad`` (``any_goal``: any
        goal, for a device that clamped ours to narrower limits)."""
        if state is None or state.moving:
            return False
        at_goal = (
            abs(state.pan_rad - state.goal_pan_rad) < tol_rad and abs(state.tilt_rad - state.goal_tilt_rad) < tol_rad
        )
        ours = abs(state.goal_pan_rad - pan_rad) < tol_rad and abs(state.goal_tilt_rad - tilt_rad) < tol_rad
        return at_goal and (ours or any_goal)

    def free_box(self, half_m=RIG_FREE_BOX_HALF_M) -> DroneBox:
        return free_box_around(self.rig, half_m)

    def to_meta(self) -> dict:
        return {"platform": "rig", "rig": to_dict(self.rig)}


@dataclass(frozen=True)
class DronePlatform(Platform):
    """A camera that flies inside ``drone`` (a :class:`DroneBox`), 5 DoF (x, y, z, yaw, pitch)."""

    drone: DroneBox
    kind: ClassVar[str] = "drone"

    def __post_init__(self):
        require(isinstance(self.drone, DroneBox), "drone", f"a drone platform needs a DroneBox, got {self.drone!r}")

    @property
    def box(self) -> DroneBox:
        return self.drone

    def clamp(self, cam2world: np.ndarray) -> np.ndarray:  # [4, 4] -> [4, 4], the position inside the box
        """The pose with its position moved into the box (the same pose when it is inside)."""
        if bool(self.drone.contains(cam2world[:3, 3])):
            return cam2world
        out = np.array(cam2world, dtype=np.float64)
        out[:3, 3] = self.drone.clamp(out[:3, 3])
        return out

    def arrived(self, cam2world: np.ndarray, target: np.ndarray, tol_deg: float, tol_m: float) -> bool:
        """Whether a camera at ``cam2world [4, 4]`` looks within ``tol_deg`` of the way ``target
        [4, 4]`` does, from within ``tol_m`` of its place."""
        close = view_angle_deg(cam2world, target) < tol_deg
        return close and bool(np.linalg.norm(cam2world[:3, 3] - target[:3, 3]) < tol_m)

    def free_box(self, half_m=RIG_FREE_BOX_HALF_M) -> DroneBox:
        return self.drone

    def as_drone(self) -> DronePlatform:
        return self

    def to_meta(self) -> dict:
        box = self.drone
        return {
            "platform": "drone",
            "drone": {"bounds_min_m": list(box.bounds_min_m), "bounds_max_m": list(box.bounds_max_m)},
        }


def walked_edges(centres_m: np.ndarray) -> np.ndarray:  # [N, 3] -> [max(N - 1, 1), 2] indices
    """The edges of the minimum spanning tree of the camera centres (Prim's, O(N^2)): the paths
    between neighbouring photos, whatever order the files are in. One camera: a single (0, 0) edge."""
    n = len(centres_m)
    if n < 2:
        return np.zeros((1, 2), dtype=np.int64)
    d = np.linalg.norm(centres_m[:, None] - centres_m[None], axis=-1)  # [N, N]
    inside = np.zeros(n, bool)
    inside[0] = True
    best, parent = d[0].copy(), np.zeros(n, np.int64)
    edges = []
    for _ in range(n - 1):
        j = int(np.argmin(np.where(inside, np.inf, best)))
        edges.append((int(parent[j]), j))
        inside[j] = True
        closer = d[j] < best
        best = np.where(closer, d[j], best)
        parent = np.where(closer, j, parent)
    return np.asarray(edges, dtype=np.int64)


def nearest_on_walk(xyz_m: np.ndarray, centres_m: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For points ``xyz_m [..., 3]``: the nearest point of the walked path (the segments ``edges``
    between ``centres_m``) ``[..., 3]`` and the distance to it ``[...]``."""
    p = np.asarray(xyz_m, dtype=np.float64)[..., None, :]  # [..., 1, 3]
    a, b = centres_m[edges[:, 0]], centres_m[edges[:, 1]]  # [E, 3]
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-18), 0.0, 1.0)  # [..., E]
    q = a + t[..., None] * ab  # [..., E, 3]
    d = np.linalg.norm(p - q, axis=-1)  # [..., E]
    k = np.argmin(d, axis=-1)[..., None]
    return np.take_along_axis(q, k[..., None], axis=-2)[..., 0, :], np.take_along_axis(d, k, axis=-1)[..., 0]


@dataclass(frozen=True)
class HandHeldPlatform(Platform):
    """A photographer's camera: 5 DoF like a drone, but inside the region they walked: within
    ``margin_m`` of the paths between neighbouring photos' cameras (``centres_m``, the minimum
    spanning tree's edges: a chain of capsules), not a box. ``margin_m`` is in the frame's unit
    (metres when the poses are metric)."""

    centres_m: tuple[tuple[float, float, float], ...]
    margin_m: float
    #: The pitch range searched, degrees: the photos' own pitches widened by ``HANDHELD_PITCH_MARGIN_DEG``
    #: (:meth:`around_photos`); a photographer who never aimed at the floor is not sent to.
    pitch_limits_deg: tuple[float, float] = (-90.0, 90.0)
    kind: ClassVar[str] = HANDHELD

    def __post_init__(self):
        c = np.asarray(self.centres_m, dtype=np.float64)
        require(c.ndim == 2 and c.shape[1] == 3 and len(c) >= 1, "centres_m", "needs camera centres [[x, y, z], ...]")
        require_finite(c.ravel().tolist() + [self.margin_m], "handheld")
        require(self.margin_m > 0, "margin_m", f"must be > 0, got {self.margin_m!r}")
        far = float(np.abs(c).max())
        require(far <= MAX_COORDINATE_M, "centres_m", f"a coordinate of {far:.3g} is beyond {MAX_COORDINATE_M:.0e}")
        lo, hi = self.pitch_limits_deg
        require_finite([lo, hi], "pitch_limits_deg")
        require(-90.0 <= lo < hi <= 90.0, "pitch_limits_deg", f"need -90 <= low < high <= 90, got {[lo, hi]}")

    @classmethod
    def around_photos(
        cls, intrinsics: Intrinsics, cam2world: np.ndarray, margin_m: float | None = None
    ) -> HandHeldPlatform:
        """The region walked by the photos at ``cam2world [N, 4, 4]``: within ``margin_m`` (default a
        quarter of the cameras' spread, at least 0.1) of the paths between them, pitched within
        ``HANDHELD_PITCH_MARGIN_DEG`` of the photos' own pitches."""
        poses = np.asarray(cam2world, dtype=np.float64)
        pos = poses[:, :3, 3]
        spread = float(np.max(np.linalg.norm(pos[:, None] - pos[None], axis=-1)))
        pitch = np.degrees(cam2world_to_view(poses)[:, 4])
        lo = max(-90.0, float(pitch.min()) - HANDHELD_PITCH_MARGIN_DEG)
        hi = min(90.0, float(pitch.max()) + HANDHELD_PITCH_MARGIN_DEG)
        margin = margin_m if margin_m is not None else max(0.25 * spread, 0.1)
        return cls(intrinsics, tuple(map(tuple, pos.tolist())), float(margin), (lo, hi))

    @functools.cached_property
    def centres(self) -> np.ndarray:  # [N, 3]
        return np.asarray(self.centres_m, dtype=np.float64)

    @functools.cached_property
    def edges(self) -> np.ndarray:  # [E, 2]
        return walked_edges(self.centres)

    def contains(self, xyz_m) -> np.ndarray:  # [..., 3] -> [...] bool
        return nearest_on_walk(xyz_m, self.centres, self.edges)[1] <= self.margin_m * (1 + 1e-9)

    def clamp(self, cam2world: np.ndarray) -> np.ndarray:  # [4, 4] -> [4, 4], the position inside the region
        """The pose with its position moved to the nearest point of the region (itself when inside)."""
        q, d = nearest_on_walk(cam2world[:3, 3], self.centres, self.edges)
        if d <= self.margin_m:
            return cam2world
        out = np.array(cam2world, dtype=np.float64)
        out[:3, 3] = q + (out[:3, 3] - q) * (self.margin_m / d)
        return out

    def free_box(self, half_m=RIG_FREE_BOX_HALF_M) -> DroneBox:
        """The region's bounding box (the cameras' grown by the margin; at least ``MIN_BOX_SIDE_M`` a side)."""
        lo, hi = self.centres.min(0) - self.margin_m, self.centres.max(0) + self.margin_m
        grow = np.maximum(MIN_BOX_SIDE_M - (hi - lo), 0.0) / 2
        return DroneBox(tuple((lo - grow).tolist()), tuple((hi + grow).tolist()))

    def to_meta(self) -> dict:
        return {
            "platform": HANDHELD,
            HANDHELD: {
                "centres_m": [list(c) for c in self.centres_m],
                "margin_m": self.margin_m,
                "pitch_limits_deg": list(self.pitch_limits_deg),
            },
        }


@dataclass(frozen=True)
class RigPlatformConfig:
    """A launch file's ``platform: {type: rig, <PanTiltConfig keys>}``: a camera on a pan-tilt rig.
    ``pan_tilt`` None (``platform: {type: rig}`` alone): the launch scene's rig."""

    pan_tilt: PanTiltConfig | None = None
    kind: ClassVar[str] = "rig"


@dataclass(frozen=True)
class DronePlatformConfig:
    """A launch file's ``platform: {type: drone, box: {bounds_min_m: [x, y, z], bounds_max_m: [x, y, z]}}``:
    a camera flying inside the box. ``box`` None (``platform: {type: drone}``): the launch scene's
    box, or on a rig scene the box around the rig's base (:meth:`Platform.free_box`)."""

    box: DroneBox | None = None
    kind: ClassVar[str] = "drone"


#: ``platform:``'s type words (``free``, the older word for a drone, is not one: the mapping is new).
#: A hand-held camera is searched from photos (``aes-planner suggest``), never driven by a node.
PLATFORM_TYPES: dict[str, type] = {"rig": RigPlatformConfig, "drone": DronePlatformConfig}


def parse_platform(spec: Any, key: str = "platform") -> RigPlatformConfig | DronePlatformConfig:
    """The typed platform of a tagged mapping ``{type: rig|drone, ...}`` (like a gimbal's
    ``device:``): a rig's other keys are its :class:`PanTiltConfig`, a drone's the one key ``box``.
    A typed config passes through. Unknown keys and types are :class:`ConfigError` s naming the key."""
    if isinstance(spec, (RigPlatformConfig, DronePlatformConfig)):
        return spec
    if isinstance(spec, Mapping) and spec.get("type") == HANDHELD:
        raise ConfigError(
            f"{key}.type",
            "a hand-held camera is not driven by a node: search from its photos with aes-planner suggest "
            "(docs/guides/photos.md); a node's platform is rig or drone",
        )
    word = tag_of(spec, key, PLATFORM_TYPES)
    rest = {k: v for k, v in spec.items() if k != "type"}
    if word == "rig":
        return RigPlatformConfig(from_dict(PanTiltConfig, rest, key) if rest else None)
    return from_dict(DronePlatformConfig, rest, key)


def platform_to_meta(platform: Platform) -> dict:
    """The JSON-ready description a dataset folder's ``meta`` carries: ``{"platform": "rig",
    "rig": {PanTiltConfig fields}}`` or ``{"platform": "drone", "drone": {"bounds_min_m", "bounds_max_m"}}``."""
    return platform.to_meta()


def platform_from_meta(meta: dict, intrinsics: Intrinsics) -> Platform | None:
    """The :class:`Platform` written by :func:`platform_to_meta`, or ``None`` when ``meta`` has none.

    Malformed sections raise :class:`~aes_planner.config.ConfigError` naming the key."""
    from aes_planner.config import from_dict

    kind = meta.get("platform")
    if kind is None:
        return None
    if kind not in (*KINDS, HANDHELD):
        raise ConfigError("meta.platform", f"must be 'rig', 'drone' or 'handheld', got {short_repr(kind)}")
    section = meta.get(kind)
    if section is None:
        return None
    if not isinstance(section, dict):
        raise ConfigError(f"meta.{kind}", f"expected a mapping, got {short_repr(section)}")
    if kind == HANDHELD:
        require(
            set(section) == {"centres_m", "margin_m", "pitch_limits_deg"},
            "meta.handheld",
            "needs centres_m, margin_m and pitch_limits_deg only",
        )
        centres, margin, pitch = section["centres_m"], section["margin_m"], section["pitch_limits_deg"]
        require(
            isinstance(pitch, list) and len(pitch) == 2 and all(isinstance(v, (int, float)) for v in pitch),
            "meta.handheld.pitch_limits_deg",
            "must be [low, high] degrees",
        )
        require(
            isinstance(centres, list)
            and all(isinstance(c, list) and len(c) == 3 for c in centres)
            and len(centres) >= 1,
            "meta.handheld.centres_m",
            "must be a list of [x, y, z] camera centres",
        )
        require(
            all(isinstance(v, (int, float)) and not isinstance(v, bool) for c in centres for v in c)
            and isinstance(margin, (int, float))
            and not isinstance(margin, bool),
            "meta.handheld",
            "centres_m and margin_m must be numbers",
        )
        try:
            return HandHeldPlatform(
                intrinsics,
                tuple(tuple(float(v) for v in c) for c in centres),
                float(margin),
                (float(pitch[0]), float(pitch[1])),
            )
        except ConfigError as exc:
            raise ConfigError(f"meta.handheld.{exc.key}", exc.message) from None
    if kind == "rig":
        rig = from_dict(
            PanTiltConfig, {k: tuple(v) if isinstance(v, list) else v for k, v in section.items()}, "meta.rig"
        )
        return RigPlatform(intrinsics, rig)
    require(set(section) == {"bounds_min_m", "bounds_max_m"}, "meta.drone", "needs bounds_min_m and bounds_max_m only")
    lo, hi = section["bounds_min_m"], section["bounds_max_m"]
    require(
        isinstance(lo, list) and isinstance(hi, list) and len(lo) == 3 and len(hi) == 3,
        "meta.drone",
        f"bounds must be 3 numbers each, got {lo!r} / {hi!r}",
    )
    try:
        box = DroneBox(tuple(lo), tuple(hi))
    except ConfigError as exc:
        raise ConfigError(f"meta.drone.{exc.key}", exc.message) from None
    return DronePlatform(intrinsics, box)
