"""The scene format: typed dataclasses that a scene YAML file loads into, and back.

Every section of a scene file is one dataclass here, built with
:func:`aes_planner.config.from_dict`, so an unknown key or a bad value raises
:class:`~aes_planner.config.ConfigError` naming its dotted path
(``objects[3].material.pattern.kind: must be one of [...]``). Objects and lights are tagged by a
``type`` key (:data:`OBJECT_TYPES`, :data:`LIGHT_TYPES`). ``sim/README.md`` documents the format
with a full example; the field docstrings below are the reference.

Colours are display values in ``[0, 1]`` (RGB, no gamma); lengths in metres; angles in degrees
(this is the YAML edge). Orientations ``rpy_deg`` are static roll, pitch, yaw about world x, y, z
(``R = Rz(yaw) Ry(pitch) Rx(roll)``), as in :class:`~aes_planner.geometry.PanTiltConfig`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np

from aes_planner.config import from_dict, require, require_finite, tag_of, to_dict
from aes_planner.geometry import Intrinsics, PanTilt, PanTiltConfig, rot_x, rot_y, rot_z
from aes_planner.geometry.camera import MAX_CAMERA_PIXELS, MAX_CAMERA_SIDE_PX
from aes_planner.geometry.plausible import intrinsics_problem
from aes_planner.geometry.rig import rig_dict
from aes_planner.platform import DroneBox

__all__ = [
    "AmbientLightSpec",
    "BoxSpec",
    "CameraSpec",
    "CylinderSpec",
    "DirectionalLightSpec",
    "DroneSpec",
    "LIGHT_TYPES",
    "MaterialSpec",
    "OBJECT_TYPES",
    "PATTERN_KINDS",
    "PatternSpec",
    "PlaneSpec",
    "QuadSpec",
    "RigSpec",
    "SceneSpec",
    "SkySpec",
    "SphereSpec",
    "spec_to_dict",
]

Vec3 = tuple[float, float, float]
RGB = tuple[float, float, float]
PATTERN_KINDS = ("checker", "stripes", "noise", "gradient")


#: Brightest light (and emission) a scene may have, as a multiple of a white surface's full
#: brightness: past a few the image is white anyway; 1e308 would overflow to inf and NaN.
MAX_LIGHT_INTENSITY = 100.0


def _require_intensity(value: float, key: str) -> None:
    require_finite(value, key)
    require(0.0 <= value <= MAX_LIGHT_INTENSITY, key, f"must be within [0, {MAX_LIGHT_INTENSITY:g}], got {value:g}")


def _require_rgb(value: RGB, key: str) -> None:
    require_finite(list(value), key)
    require(all(0.0 <= v <= 1.0 for v in value), key, f"colour components must be in [0, 1], got {list(value)}")


def _require_positive(values: Any, key: str) -> None:
    values = list(values) if isinstance(values, (tuple, list)) else [values]
    require(all(v > 0 for v in values), key, f"must be > 0, got {values if len(values) > 1 else values[0]}")
    # Beyond 1000 km a size squares past float64 in the ray-box arithmetic; no scene needs it.
    require(
        all(v <= 1e6 for v in values), key, f"must be at most 1e6 m, got {values if len(values) > 1 else values[0]}"
    )


def _require_camera_size(width: int | None, height: int | None, base: tuple[int, int] = (1, 1)) -> None:
    """Refuse cameras beyond :data:`~aes_planner.geometry.camera.MAX_CAMERA_PIXELS` before they allocate."""
    w, h = width or base[0], height or base[1]
    require(
        max(w, h) <= MAX_CAMERA_SIDE_PX and w * h <= MAX_CAMERA_PIXELS,
        "width" if w >= h else "height",
        f"a {w}x{h} camera is too large: at most {MAX_CAMERA_SIDE_PX} pixels per side and {MAX_CAMERA_PIXELS} in all",
    )


#: Pattern scales and texture tiles, metres: finer than a tenth of a millimetre is noise at any
#: camera distance, and overflows the texel arithmetic (a 1e-320 m tile cast inf to int: black);
#: coarser than 1000 km loses the float64 precision of the surface coordinates.
FEATURE_SIZE_RANGE_M = (1e-4, 1e6)


def _require_feature_size(value: float, key: str) -> None:
    lo, hi = FEATURE_SIZE_RANGE_M
    require(lo <= value <= hi, key, f"must be in [{lo:g}, {hi:g}] metres, got {value!r}")


def _require_direction(value: Vec3, key: str) -> None:
    require(math.hypot(*value) > 1e-9, key, f"must be a non-zero direction, got {list(value)}")


def _orientation(yaw_deg: float | None, rpy_deg: Vec3 | None) -> np.ndarray:
    """Rotation ``[3, 3]`` (local -> world) from ``yaw_deg`` or ``rpy_deg`` (neither: identity)."""
    roll, pitch, yaw = (math.radians(a) for a in (rpy_deg or (0.0, 0.0, yaw_deg or 0.0)))
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


class _SizedAndTurned:
    """For specs with ``size_m``, ``yaw_deg`` and ``rpy_deg`` fields (box, quad)."""

    def __post_init__(self):
        _require_positive(self.size_m, "size_m")
        require(self.yaw_deg is None or self.rpy_deg is None, "rpy_deg", "give yaw_deg or rpy_deg, not both")

    def rotation(self) -> np.ndarray:
        return _orientation(self.yaw_deg, self.rpy_deg)


def frame_from_axis(axis: np.ndarray) -> np.ndarray:
    """A rotation ``[3, 3]`` whose third column is ``axis [3]`` (normalised), the first as close
    to world +x as possible (world +y when the axis is along x). Deterministic, so textures on
    cylinders and planes do not depend on anything but the axis."""
    z = np.asarray(axis, dtype=np.float64)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = helper - z * (helper @ z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


# ------------------------------------------------------------------------------ materials
@dataclass
class PatternSpec:
    """A procedural pattern that mixes the material's ``albedo`` with ``colour2``.

    Patterns are drawn in the surface's own 2D coordinates ``(u, v)`` in metres (see the README
    for each primitive), rotated by ``angle_deg`` (from u toward v).

    * ``checker``: squares of side ``scale_m``.
    * ``stripes``: bands across u, period ``scale_m``; ``duty`` is the fraction in ``colour2``.
    * ``noise``: smooth value noise, feature size ``scale_m``, ``octaves`` layers, ``seed``.
    * ``gradient``: ``albedo`` at ``u = -scale_m / 2`` to ``colour2`` at ``+scale_m / 2``,
      centred on the object; ``angle_deg: 90`` makes it run along v (bottom to top on a quad).
    """

    kind: Literal["checker", "stripes", "noise", "gradient"]
    colour2: RGB = (0.15, 0.15, 0.15)
    scale_m: float = 0.25
    angle_deg: float = 0.0
    duty: float = 0.5
    octaves: int = 3
    seed: int = 0

    def __post_init__(self):
        _require_rgb(self.colour2, "colour2")
        _require_feature_size(self.scale_m, "scale_m")
        require(0.0 < self.duty < 1.0, "duty", f"must be in (0, 1), got {self.duty}")
        require(1 <= self.octaves <= 8, "octaves", f"must be in [1, 8], got {self.octaves}")


@dataclass
class MaterialSpec:
    """Surface colour and how it is lit.

    * ``albedo``: base colour (Lambertian reflectance).
    * ``pattern``: optional :class:`PatternSpec` mixing ``albedo`` and ``pattern.colour2``.
    * ``image``: optional image file (PNG, JPEG: anything cv2 reads), relative to the scene
      file; its texels replace ``albedo``. ``board:SPEC`` (``board:chessboard:9x6:0.06``) draws
      a calibration board instead (:func:`aes_planner.geometry.board.board_texture`: the pattern
      with one white square of margin; size the quad to match, 0.72 x 0.54 m for that one). Stretched over a quad; tiled in squares of
      ``tile_m`` metres on other primitives (default 1 m) and on quads that set ``tile_m``.
    * ``emission``: light the surface gives off, as a multiple of its own colour, added to
      what it reflects (a window, a lamp shade, a lit screen).
    """

    albedo: RGB = (0.7, 0.7, 0.7)
    pattern: PatternSpec | None = None
    image: str | None = None
    tile_m: float | None = None
    emission: float = 0.0

    def __post_init__(self):
        _require_rgb(self.albedo, "albedo")
        require(self.pattern is None or self.image is None, "image", "give a pattern or an image, not both")
        require(self.image is None or bool(self.image.strip()), "image", "must be a file path, got an empty string")
        if self.tile_m is not None:
            _require_feature_size(self.tile_m, "tile_m")
        _require_intensity(self.emission, "emission")


# -------------------------------------------------------------------------------- objects
@dataclass
class BoxSpec(_SizedAndTurned):
    """A box: ``centre_m``, full edge lengths ``size_m`` along its local x, y, z, turned by
    ``yaw_deg`` (about world z) or ``rpy_deg``."""

    type: ClassVar[str] = "box"
    centre_m: Vec3
    size_m: Vec3
    yaw_deg: float | None = None
    rpy_deg: Vec3 | None = None
    name: str = ""
    material: MaterialSpec = field(default_factory=MaterialSpec)


@dataclass
class SphereSpec:
    """A sphere: ``centre_m``, ``radius_m``; ``rpy_deg`` turns its texture (poles on local z)."""

    type: ClassVar[str] = "sphere"
    centre_m: Vec3
    radius_m: float
    rpy_deg: Vec3 | None = None
    name: str = ""
    material: MaterialSpec = field(default_factory=MaterialSpec)

    def __post_init__(self):
        _require_positive(self.radius_m, "radius_m")

    def rotation(self) -> np.ndarray:
        return _orientation(None, self.rpy_deg)


@dataclass
class CylinderSpec:
    """A finite, capped cylinder: ``centre_m`` (middle of the axis), ``radius_m``, ``height_m``
    along ``axis`` (a direction, default world up)."""

    type: ClassVar[str] = "cylinder"
    centre_m: Vec3
    radius_m: float
    height_m: float
    axis: Vec3 = (0.0, 0.0, 1.0)
    name: str = ""
    material: MaterialSpec = field(default_factory=MaterialSpec)

    def __post_init__(self):
        _require_positive(self.radius_m, "radius_m")
        _require_positive(self.height_m, "height_m")
        _require_direction(self.axis, "axis")

    def rotation(self) -> np.ndarray:
        return frame_from_axis(np.asarray(self.axis))


@dataclass
class PlaneSpec:
    """An infinite plane through ``point_m`` with ``normal`` (seen from both sides)."""

    type: ClassVar[str] = "plane"
    point_m: Vec3 = (0.0, 0.0, 0.0)
    normal: Vec3 = (0.0, 0.0, 1.0)
    name: str = ""
    material: MaterialSpec = field(default_factory=MaterialSpec)

    def __post_init__(self):
        _require_direction(self.normal, "normal")

    def rotation(self) -> np.ndarray:
        return frame_from_axis(np.asarray(self.normal))


@dataclass
class QuadSpec(_SizedAndTurned):
    """A flat rectangle (a picture, a window, a sign): ``centre_m``, ``size_m`` = (width, height).

    Unturned, it stands upright facing world +x: its normal is local +x, the width runs along
    local y and the height along local z; an image on it reads upright to a viewer in front.
    ``yaw_deg`` or ``rpy_deg`` turn it (``yaw_deg: 180`` faces -x, ``rpy_deg: [0, -90, 0]``
    lies flat facing up). Seen from both sides.
    """

    type: ClassVar[str] = "quad"
    centre_m: Vec3
    size_m: tuple[float, float]
    yaw_deg: float | None = None
    rpy_deg: Vec3 | None = None
    name: str = ""
    material: MaterialSpec = field(default_factory=MaterialSpec)


OBJECT_TYPES: dict[str, type] = {c.type: c for c in (BoxSpec, SphereSpec, CylinderSpec, PlaneSpec, QuadSpec)}
ObjectSpec = BoxSpec | SphereSpec | CylinderSpec | PlaneSpec | QuadSpec


# ---------------------------------------------------------------------------- lights, sky
@dataclass
class AmbientLightSpec:
    """Light from everywhere: every surface gets ``colour * intensity`` of its albedo."""

    type: ClassVar[str] = "ambient"
    colour: RGB = (1.0, 1.0, 1.0)
    intensity: float = 0.35

    def __post_init__(self):
        _require_rgb(self.colour, "colour")
        _require_intensity(self.intensity, "intensity")


@dataclass
class DirectionalLightSpec:
    """A distant light (the sun): ``direction`` is where its rays travel, from the light toward
    the scene (``[0, 0, -1]`` is a noon sun). Lambertian; ``shadows`` casts shadow rays."""

    type: ClassVar[str] = "directional"
    direction: Vec3 = (-0.4, -0.3, -1.0)
    colour: RGB = (1.0, 0.97, 0.92)
    intensity: float = 0.75
    shadows: bool = True

    def __post_init__(self):
        _require_direction(self.direction, "direction")
        _require_rgb(self.colour, "colour")
        _require_intensity(self.intensity, "intensity")


LIGHT_TYPES: dict[str, type] = {c.type: c for c in (AmbientLightSpec, DirectionalLightSpec)}
LightSpec = AmbientLightSpec | DirectionalLightSpec


def default_lights() -> list:
    """What a scene without a ``lights`` key gets: an ambient term and a sun with shadows."""
    return [AmbientLightSpec(), DirectionalLightSpec()]


@dataclass
class SkySpec:
    """Colour of rays that hit nothing, by elevation: ``horizon`` at 0 deg blending to
    ``zenith`` straight up; ``nadir`` for every ray below the horizon."""

    horizon: RGB = (0.85, 0.88, 0.92)
    zenith: RGB = (0.32, 0.5, 0.82)
    nadir: RGB = (0.42, 0.4, 0.37)

    def __post_init__(self):
        for name in ("horizon", "zenith", "nadir"):
            _require_rgb(getattr(self, name), name)


# ---------------------------------------------------------------------------- rig, drone
@dataclass
class CameraSpec:
    """The simulated camera: image size in pixels and horizontal field of view (square pixels,
    centred principal point)."""

    width: int = 128
    height: int = 96
    hfov_deg: float = 60.0

    def __post_init__(self):
        require(self.width >= 1, "width", f"must be >= 1 pixel, got {self.width}")
        require(self.height >= 1, "height", f"must be >= 1 pixel, got {self.height}")
        require(0.0 < self.hfov_deg < 180.0, "hfov_deg", f"must be in (0, 180), got {self.hfov_deg}")
        _require_camera_size(self.width, self.height)
        problem = intrinsics_problem(self.intrinsics())  # what every frame it renders must pass
        require(problem is None, "hfov_deg", str(problem))

    def intrinsics(self) -> Intrinsics:
        return Intrinsics.from_fov(self.width, self.height, self.hfov_deg)


@dataclass
class RigSpec:
    """A camera on a pan-tilt gimbal: the kinematics (:class:`PanTiltConfig`: base pose, joint
    limits, tilt offset, lever arm) and the camera it carries."""

    pan_tilt: PanTiltConfig = field(default_factory=PanTiltConfig)
    camera: CameraSpec = field(default_factory=CameraSpec)

    def kinematics(self) -> PanTilt:
        return PanTilt(self.pan_tilt)

    def intrinsics(self) -> Intrinsics:
        return self.camera.intrinsics()


@dataclass
class DroneSpec:
    """A camera on a drone that may fly anywhere inside the axis-aligned box
    ``[bounds_min_m, bounds_max_m]`` (world metres)."""

    bounds_min_m: Vec3
    bounds_max_m: Vec3
    camera: CameraSpec = field(default_factory=CameraSpec)

    def __post_init__(self):
        require(
            all(lo < hi for lo, hi in zip(self.bounds_min_m, self.bounds_max_m)),
            "bounds_max_m",
            f"every component must exceed bounds_min_m, got min {list(self.bounds_min_m)} max {list(self.bounds_max_m)}",
        )
        DroneBox(tuple(self.bounds_min_m), tuple(self.bounds_max_m))  # its size limits, with these keys

    def intrinsics(self) -> Intrinsics:
        return self.camera.intrinsics()

    def contains(self, xyz_m: Any) -> bool:
        p = np.asarray(xyz_m, dtype=np.float64)
        return bool(np.all(p >= self.bounds_min_m) and np.all(p <= self.bounds_max_m))

    def clamp(self, xyz_m: Any) -> np.ndarray:
        """``xyz_m [3]`` moved to the nearest point of the flight box."""
        return np.clip(np.asarray(xyz_m, dtype=np.float64), self.bounds_min_m, self.bounds_max_m)

    def survey_poses(self, n: int, pitch_deg: float = -10.0) -> np.ndarray:
        """``n`` cam2world ``[n, 4, 4]`` on an arc inside the box, looking across its centre
        (:meth:`aes_planner.platform.DroneBox.survey_poses`)."""
        return DroneBox(tuple(self.bounds_min_m), tuple(self.bounds_max_m)).survey_poses(n, pitch_deg)


# ---------------------------------------------------------------------------------- scene
def _parse_tagged(item: Any, key: str, table: Mapping[str, type]) -> Any:
    """A typed spec from a mapping with a ``type`` key (or a spec instance, kept as it is)."""
    if isinstance(item, tuple(table.values())):
        return item
    kind = tag_of(item, key, table)
    return from_dict(table[kind], {k: v for k, v in item.items() if k != "type"}, key)


@dataclass
class SceneSpec:
    """A whole scene: objects (instance id = index + 1), lights, sky, and a rig or a drone.

    ``lights`` and ``objects`` hold typed specs; mappings with a ``type`` key (as read from
    YAML) are parsed into them on construction. Without a ``lights`` key a scene gets
    :func:`default_lights`; ``lights: []`` means no light at all (only emission shows).
    Exactly one of ``rig`` and ``drone`` must be given.
    """

    name: str = "scene"
    sky: SkySpec = field(default_factory=SkySpec)
    lights: list[Any] = field(default_factory=default_lights)
    objects: list[Any] = field(default_factory=list)
    rig: RigSpec | None = None
    drone: DroneSpec | None = None

    def __post_init__(self):
        self.lights = [_parse_tagged(x, f"lights[{i}]", LIGHT_TYPES) for i, x in enumerate(self.lights)]
        self.objects = [_parse_tagged(x, f"objects[{i}]", OBJECT_TYPES) for i, x in enumerate(self.objects)]
        require(
            (self.rig is None) != (self.drone is None),
            "rig" if self.rig is None else "drone",
            "a scene needs exactly one of a 'rig' section (pan-tilt camera) and a 'drone' section",
        )


def _drop_none(data: Any) -> Any:
    if isinstance(data, dict):
        return {k: _drop_none(v) for k, v in data.items() if v is not None}
    if isinstance(data, list):
        return [_drop_none(v) for v in data]
    return data


def _tagged_dict(spec: Any) -> dict:
    return {"type": spec.type, **to_dict(spec)}


def spec_to_dict(spec: SceneSpec) -> dict:
    """The plain mapping a scene YAML file holds (``type`` keys added, unset options left out);
    ``from_dict(SceneSpec, spec_to_dict(s))`` equals ``s``."""
    out: dict[str, Any] = {"name": spec.name, "sky": to_dict(spec.sky)}
    out["lights"] = [_tagged_dict(x) for x in spec.lights]
    for section in ("rig", "drone"):
        if getattr(spec, section) is not None:
            out[section] = to_dict(getattr(spec, section))
    if "rig" in out:  # a rig field added later is written only when set: older scenes' text stays
        out["rig"]["pan_tilt"] = rig_dict(spec.rig.pan_tilt)
    out["objects"] = [_tagged_dict(x) for x in spec.objects]
    return _drop_none(out)
