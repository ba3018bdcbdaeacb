"""Building blocks shared by the scene families: a seeded builder and composite objects.

Every number that lands in a spec is a rounded Python float, so the YAML a family emits is
short, readable and loads back into exactly the same scene.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from aes_planner.geometry import PanTiltConfig
from aes_planner.sim.spec import (
    AmbientLightSpec,
    BoxSpec,
    CameraSpec,
    CylinderSpec,
    DirectionalLightSpec,
    MaterialSpec,
    PatternSpec,
    PlaneSpec,
    QuadSpec,
    RigSpec,
    SceneSpec,
    SkySpec,
    SphereSpec,
)

RGB = tuple[float, float, float]


def r(x: float, nd: int = 3) -> float:
    return round(float(x), nd)


def v3(p: Sequence[float], nd: int = 3) -> tuple[float, float, float]:
    return (r(p[0], nd), r(p[1], nd), r(p[2], nd))


def rgb(c: Sequence[float]) -> RGB:
    return v3(np.clip(c, 0.0, 1.0))


# Colour sets the families draw from: muted interior tones, saturated accents, nature.
WALL_TONES = [(0.86, 0.84, 0.79), (0.78, 0.82, 0.84), (0.88, 0.83, 0.74), (0.74, 0.78, 0.72), (0.9, 0.9, 0.88)]
WOOD_TONES = [(0.55, 0.38, 0.22), (0.66, 0.5, 0.33), (0.42, 0.28, 0.17), (0.74, 0.6, 0.42)]
FABRIC_TONES = [(0.25, 0.33, 0.5), (0.55, 0.22, 0.2), (0.3, 0.45, 0.35), (0.6, 0.55, 0.48), (0.35, 0.32, 0.38)]
ACCENTS = [
    (0.85, 0.2, 0.15),
    (0.95, 0.7, 0.1),
    (0.15, 0.45, 0.8),
    (0.2, 0.6, 0.3),
    (0.9, 0.45, 0.1),
    (0.6, 0.2, 0.6),
    (0.1, 0.7, 0.7),
    (0.95, 0.95, 0.9),
    (0.1, 0.1, 0.12),
]
LEAF_TONES = [(0.18, 0.42, 0.16), (0.25, 0.5, 0.2), (0.12, 0.35, 0.2), (0.35, 0.5, 0.15)]


class Builder:
    """Collects objects for one scene, with the seeded generator every choice comes from."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)
        self.objects: list = []

    # ----------------------------------------------------------------------- random picks
    def uniform(self, lo: float, hi: float) -> float:
        return float(self.rng.uniform(lo, hi))

    def integer(self, lo: int, hi: int) -> int:
        """An integer in ``[lo, hi]`` (inclusive)."""
        return int(self.rng.integers(lo, hi + 1))

    def pick(self, options: Sequence):
        return options[int(self.rng.integers(len(options)))]

    def chance(self, p: float) -> bool:
        return bool(self.rng.random() < p)

    def tint(self, colour: Sequence[float], spread: float = 0.06) -> RGB:
        """``colour`` with a little random variation."""
        return rgb(np.asarray(colour) + self.rng.uniform(-spread, spread, 3))

    def pattern(self, kind: str, colour2: Sequence[float], scale_m: float, **kw) -> PatternSpec:
        return PatternSpec(kind=kind, colour2=rgb(colour2), scale_m=r(scale_m), **kw)

    def material(self, albedo, pattern: PatternSpec | None = None, emission: float = 0.0) -> MaterialSpec:
        return MaterialSpec(albedo=rgb(albedo), pattern=pattern, emission=r(emission, 2))

    # -------------------------------------------------------------------------- primitives
    def box(self, name, centre, size, albedo, yaw_deg=None, rpy_deg=None, pattern=None, emission=0.0) -> BoxSpec:
        obj = BoxSpec(
            centre_m=v3(centre),
            size_m=v3(size),
            yaw_deg=None if yaw_deg is None else r(yaw_deg, 2),
            rpy_deg=None if rpy_deg is None else v3(rpy_deg, 2),
            name=name,
            material=self.material(albedo, pattern, emission),
        )
        self.objects.append(obj)
        return obj

    def sphere(self, name, centre, radius_m, albedo, pattern=None, emission=0.0) -> SphereSpec:
        obj = SphereSpec(
            centre_m=v3(centre), radius_m=r(radius_m), name=name, material=self.material(albedo, pattern, emission)
        )
        self.objects.append(obj)
        return obj

    def cylinder(
        self, name, centre, radius_m, height_m, albedo, axis=(0.0, 0.0, 1.0), pattern=None, emission=0.0
    ) -> CylinderSpec:
        obj = CylinderSpec(
            centre_m=v3(centre),
            radius_m=r(radius_m),
            height_m=r(height_m),
            axis=v3(axis),
            name=name,
            material=self.material(albedo, pattern, emission),
        )
        self.objects.append(obj)
        return obj

    def quad(self, name, centre, size, albedo, yaw_deg=None, rpy_deg=None, pattern=None, emission=0.0) -> QuadSpec:
        obj = QuadSpec(
            centre_m=v3(centre),
            size_m=(r(size[0]), r(size[1])),
            yaw_deg=None if yaw_deg is None else r(yaw_deg, 2),
            rpy_deg=None if rpy_deg is None else v3(rpy_deg, 2),
            name=name,
            material=self.material(albedo, pattern, emission),
        )
        self.objects.append(obj)
        return obj

    def plane(self, name, point, normal, albedo, pattern=None) -> PlaneSpec:
        obj = PlaneSpec(point_m=v3(point), normal=v3(normal), name=name, material=self.material(albedo, pattern))
        self.objects.append(obj)
        return obj

    # ------------------------------------------------------------------------------ scene
    def scene(self, name: str, lights: list, rig: RigSpec, sky: SkySpec | None = None) -> SceneSpec:
        return SceneSpec(name=name, sky=sky or SkySpec(), lights=lights, objects=list(self.objects), rig=rig)


def rig(
    xyz_m, yaw_deg: float, pan_deg: tuple[float, float], tilt_deg: tuple[float, float], hfov_deg: float = 60.0
) -> RigSpec:
    """A pan-tilt rig at ``xyz_m`` facing ``yaw_deg`` with the default lever arm, 128x96 camera."""
    return RigSpec(
        pan_tilt=PanTiltConfig(
            base_xyz_m=v3(xyz_m),
            base_rpy_deg=(0.0, 0.0, r(yaw_deg, 2)),
            pan_limits_deg=(r(pan_deg[0], 1), r(pan_deg[1], 1)),
            tilt_limits_deg=(r(tilt_deg[0], 1), r(tilt_deg[1], 1)),
        ),
        camera=CameraSpec(width=128, height=96, hfov_deg=r(hfov_deg, 1)),
    )


def sun(
    b: Builder, azimuth_deg: float, elevation_deg: float, intensity: float = 0.85, shadows: bool = True
) -> DirectionalLightSpec:
    """A directional light coming *from* ``azimuth_deg`` (about z, from +x) at ``elevation_deg``."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    toward_light = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    return DirectionalLightSpec(
        direction=v3(-toward_light), colour=b.tint((1.0, 0.95, 0.87), 0.03), intensity=r(intensity), shadows=shadows
    )


def ambient(intensity: float, colour: RGB = (1.0, 1.0, 1.0)) -> AmbientLightSpec:
    return AmbientLightSpec(colour=rgb(colour), intensity=r(intensity))


# ----------------------------------------------------------------------------- composites
def wall_frame(yaw_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The outward normal of a wall-hung object facing ``yaw_deg`` and its right-hand axis as
    a viewer in front sees it (the quad's local +y)."""
    a = math.radians(yaw_deg)
    return np.array([math.cos(a), math.sin(a), 0.0]), np.array([-math.sin(a), math.cos(a), 0.0])


def painting(b: Builder, name: str, centre, yaw_deg: float, width_m: float, height_m: float) -> None:
    """A framed picture hung with its back on a wall: frame, canvas and 2-4 motifs (discs,
    bands, blocks) so that it reads as a salient subject. ``centre`` is on the wall surface."""
    normal, right = wall_frame(yaw_deg)
    up = np.array([0.0, 0.0, 1.0])
    centre = np.asarray(centre, dtype=np.float64)
    border = b.uniform(0.04, 0.09)
    frame_colour = b.pick([(0.1, 0.08, 0.06), (0.75, 0.6, 0.3), (0.92, 0.92, 0.9), b.pick(WOOD_TONES)])
    b.box(
        f"{name}_frame",
        centre + normal * 0.02,
        (0.04, width_m + 2 * border, height_m + 2 * border),
        frame_colour,
        yaw_deg=yaw_deg,
    )
    background = b.pick(ACCENTS)
    style = b.pick(["landscape", "abstract", "stripes"])
    canvas_centre = centre + normal * 0.041
    if style == "landscape":
        sky_colour = b.tint(b.pick([(0.55, 0.7, 0.9), (0.95, 0.65, 0.4), (0.3, 0.3, 0.5)]))
        b.quad(
            f"{name}_canvas",
            canvas_centre,
            (width_m, height_m),
            sky_colour,
            yaw_deg=yaw_deg,
            pattern=b.pattern("gradient", (0.95, 0.92, 0.85), height_m, angle_deg=-90.0),
        )
        horizon = b.uniform(-0.25, 0.1) * height_m
        land_h = horizon + height_m / 2
        b.quad(
            f"{name}_land",
            canvas_centre + normal * 0.002 + up * (horizon - land_h / 2),
            (width_m, land_h),
            b.tint(b.pick(LEAF_TONES)),
            yaw_deg=yaw_deg,
            pattern=b.pattern("noise", b.tint((0.4, 0.35, 0.2)), 0.08),
        )
        b.cylinder(
            f"{name}_sun",
            canvas_centre
            + normal * 0.004
            + right * b.uniform(-0.3, 0.3) * width_m
            + up * b.uniform(0.15, 0.3) * height_m,
            b.uniform(0.06, 0.12) * min(width_m, height_m) * 1.5,
            0.004,
            b.pick([(0.98, 0.85, 0.3), (0.95, 0.95, 0.9)]),
            axis=normal,
        )
    else:
        pattern = (
            b.pattern(
                "stripes", b.tint(b.pick(ACCENTS)), b.uniform(0.08, 0.25) * width_m, angle_deg=b.pick([0.0, 90.0, 45.0])
            )
            if style == "stripes"
            else None
        )
        b.quad(
            f"{name}_canvas", canvas_centre, (width_m, height_m), b.tint(background), yaw_deg=yaw_deg, pattern=pattern
        )
        for k in range(b.integer(1, 3)):
            a, c = b.uniform(-0.3, 0.3) * width_m, b.uniform(-0.3, 0.3) * height_m
            pos = canvas_centre + normal * (0.003 + 0.002 * k) + right * a + up * c
            colour = b.tint(b.pick(ACCENTS))
            if b.chance(0.5):
                b.cylinder(
                    f"{name}_disc{k}", pos, b.uniform(0.1, 0.22) * min(width_m, height_m), 0.004, colour, axis=normal
                )
            else:
                size = (b.uniform(0.15, 0.45) * width_m, b.uniform(0.15, 0.45) * height_m)
                b.quad(f"{name}_block{k}", pos, size, colour, yaw_deg=yaw_deg)


def plant(b: Builder, name: str, xy, floor_z: float, scale: float = 1.0) -> None:
    """A potted plant: pot, soil and a crown of 2-4 leafy spheres."""
    pot_h, pot_r = 0.35 * scale, 0.17 * scale
    x, y = xy
    b.cylinder(
        f"{name}_pot",
        (x, y, floor_z + pot_h / 2),
        pot_r,
        pot_h,
        b.pick([(0.7, 0.35, 0.2), (0.9, 0.9, 0.88), (0.2, 0.2, 0.22)]),
    )
    leaf = b.pick(LEAF_TONES)
    for k in range(b.integer(2, 4)):
        rad = b.uniform(0.16, 0.28) * scale
        off = b.rng.uniform(-0.12, 0.12, 2) * scale
        z = floor_z + pot_h + rad * 0.7 + b.uniform(0.0, 0.35) * scale
        b.sphere(
            f"{name}_leaves{k}",
            (x + off[0], y + off[1], z),
            rad,
            b.tint(leaf),
            pattern=b.pattern("noise", b.tint(np.asarray(leaf) * 0.6), 0.05 * scale, octaves=2, seed=b.integer(0, 999)),
        )


def tree(b: Builder, name: str, xy, ground_z: float, height_m: float) -> None:
    """A tree: trunk and one to three crown spheres."""
    x, y = xy
    trunk_h = height_m * b.uniform(0.4, 0.55)
    b.cylinder(f"{name}_trunk", (x, y, ground_z + trunk_h / 2), height_m * 0.035, trunk_h, b.tint((0.35, 0.25, 0.17)))
    leaf = b.pick(LEAF_TONES)
    crown_r = height_m * b.uniform(0.22, 0.32)
    for k in range(b.integer(1, 3)):
        off = b.rng.uniform(-0.35, 0.35, 2) * crown_r
        z = ground_z + trunk_h + crown_r * b.uniform(0.5, 1.0)
        b.sphere(
            f"{name}_crown{k}",
            (x + off[0], y + off[1], z),
            crown_r * b.uniform(0.75, 1.0),
            b.tint(leaf),
            pattern=b.pattern(
                "noise", b.tint(np.asarray(leaf) * 0.55), crown_r * 0.25, octaves=3, seed=b.integer(0, 999)
            ),
        )


class Footprints:
    """Circles already taken on a floor, to place furniture without overlaps."""

    def __init__(self):
        self.circles: list[tuple[float, float, float]] = []

    def add(self, x: float, y: float, radius: float) -> None:
        self.circles.append((x, y, radius))

    def free(self, x: float, y: float, radius: float) -> bool:
        return all(math.hypot(x - cx, y - cy) >= radius + cr for cx, cy, cr in self.circles)

    def place(self, b: Builder, x_range, y_range, radius: float, tries: int = 40):
        """A free spot ``(x, y)`` in the ranges (and claims it), or None."""
        for _ in range(tries):
            x, y = b.uniform(*x_range), b.uniform(*y_range)
            if self.free(x, y, radius):
                self.add(x, y, radius)
                return x, y
        return None
