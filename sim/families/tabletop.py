"""``tabletop``: a still life — vase, fruit, bottles, cups, books, a candle — on a table.

The table top (``z = TOP``) spans ``x in [0, D]``, ``y in [-W/2, W/2]``; a wall stands behind it
at ``x = D + gap``. The rig sits at the near edge just above the top, looking along +x: panning
and tilting moves between the arrangement, bare cloth, the wall and the floor.
"""

from __future__ import annotations

import math

from aes_planner.sim.families._kit import (
    ACCENTS,
    FABRIC_TONES,
    WALL_TONES,
    WOOD_TONES,
    Builder,
    Footprints,
    ambient,
    rig,
    sun,
)
from aes_planner.sim.spec import DirectionalLightSpec, SceneSpec

TOP = 0.75  # table height, metres


def _vase(b: Builder, x: float, y: float) -> None:
    h, r = b.uniform(0.22, 0.4), b.uniform(0.05, 0.09)
    colour = b.pick(ACCENTS)
    b.cylinder(
        "vase",
        (x, y, TOP + h / 2),
        r,
        h,
        colour,
        pattern=b.pattern("stripes", b.tint(colour, 0.2), 0.05, angle_deg=90, duty=0.3) if b.chance(0.5) else None,
    )
    b.sphere("vase_belly", (x, y, TOP + h * 0.3), r * 1.5, colour)
    for k in range(b.integer(3, 6)):
        stem = b.uniform(0.1, 0.25)
        fx, fy = x + b.uniform(-0.06, 0.06), y + b.uniform(-0.06, 0.06)
        b.cylinder(f"stem{k}", (fx, fy, TOP + h + stem / 2), 0.005, stem, (0.25, 0.45, 0.2))
        b.sphere(f"bloom{k}", (fx, fy, TOP + h + stem), b.uniform(0.025, 0.045), b.pick(ACCENTS))


def _fruit_bowl(b: Builder, x: float, y: float) -> None:
    r = b.uniform(0.12, 0.18)
    b.cylinder("bowl", (x, y, TOP + 0.035), r, 0.07, b.pick([(0.95, 0.95, 0.92), (0.3, 0.45, 0.6), (0.75, 0.55, 0.35)]))
    for k in range(b.integer(3, 6)):
        a = 2 * math.pi * k / 6 + b.uniform(-0.3, 0.3)
        fr = b.uniform(0.03, 0.05)
        b.sphere(
            f"fruit{k}",
            (x + 0.5 * r * math.cos(a), y + 0.5 * r * math.sin(a), TOP + 0.07 + fr * 0.8),
            fr,
            b.pick([(0.85, 0.15, 0.1), (0.95, 0.65, 0.1), (0.45, 0.7, 0.15), (0.5, 0.1, 0.35)]),
        )


def _bottle(b: Builder, name: str, x: float, y: float) -> None:
    h, r = b.uniform(0.2, 0.3), b.uniform(0.03, 0.045)
    glass = b.pick([(0.15, 0.35, 0.2), (0.45, 0.25, 0.1), (0.2, 0.25, 0.4)])
    b.cylinder(f"{name}_body", (x, y, TOP + h / 2), r, h, glass)
    b.cylinder(f"{name}_neck", (x, y, TOP + h + 0.04), r * 0.35, 0.08, glass)
    b.quad(f"{name}_label", (x - r - 0.001, y, TOP + h * 0.5), (r * 1.6, h * 0.35), b.pick(ACCENTS), yaw_deg=180.0)


def _books(b: Builder, x: float, y: float) -> None:
    z = TOP
    for k in range(b.integer(2, 4)):
        t = b.uniform(0.025, 0.05)
        b.box(
            f"book{k}",
            (x + b.uniform(-0.02, 0.02), y + b.uniform(-0.02, 0.02), z + t / 2),
            (b.uniform(0.15, 0.22), b.uniform(0.2, 0.28), t),
            b.pick(ACCENTS + FABRIC_TONES),
            yaw_deg=b.uniform(-25, 25),
        )
        z += t


def tabletop(seed: int) -> SceneSpec:
    """A still life on a table (see the module docstring); ``seed`` picks the arrangement."""
    b = Builder(seed)
    depth, width = b.uniform(0.9, 1.3), b.uniform(1.4, 2.0)
    gap = b.uniform(0.2, 0.8)
    wood = b.pick(WOOD_TONES)
    b.plane(
        "floor", (0, 0, 0), (0, 0, 1), b.tint((0.6, 0.55, 0.5)), pattern=b.pattern("checker", (0.45, 0.42, 0.38), 0.4)
    )
    b.box(
        "wall",
        (depth + gap + 0.05, 0, 2.0),
        (0.1, 30.0, 4.0),
        b.tint(b.pick(WALL_TONES), 0.03),
        pattern=b.pattern("stripes", b.tint(b.pick(WALL_TONES), 0.05), 0.35, duty=0.5) if b.chance(0.4) else None,
    )
    b.box(
        "table_top",
        (depth / 2, 0, TOP - 0.02),
        (depth, width, 0.04),
        wood,
        pattern=b.pattern("stripes", b.tint(wood, 0.06), 0.09, duty=0.3),
    )
    for k, (lx, ly) in enumerate(((0.05, 0.05), (0.05, 0.95), (0.95, 0.05), (0.95, 0.95))):
        b.box(f"table_leg{k}", (lx * depth, (ly - 0.5) * width, (TOP - 0.04) / 2), (0.05, 0.05, TOP - 0.04), wood)
    cloth_w = b.uniform(0.5, 0.9) * width
    b.box(
        "cloth",
        (depth * 0.55, b.uniform(-0.2, 0.2) * width, TOP + 0.002),
        (depth * 0.6, cloth_w, 0.004),
        b.pick(ACCENTS),
        pattern=b.pick(
            [
                b.pattern("checker", (0.95, 0.95, 0.92), 0.06),
                b.pattern("stripes", (0.95, 0.95, 0.92), 0.08, angle_deg=90),
            ]
        ),
        yaw_deg=b.uniform(-8, 8),
    )

    taken = Footprints()
    taken.add(0.0, 0.0, 0.3)  # the rig's side of the table stays clear
    x_range, y_range = (0.35 * depth, 0.9 * depth), (-0.42 * width, 0.42 * width)
    for place, radius in ((_vase, 0.14), (_fruit_bowl, 0.2), (_books, 0.16)):
        spot = taken.place(b, x_range, y_range, radius)
        if spot:
            place(b, *spot)
    for k in range(b.integer(1, 3)):
        spot = taken.place(b, x_range, y_range, 0.07)
        if spot:
            _bottle(b, f"bottle{k}", *spot)
    for k in range(b.integer(1, 2)):
        spot = taken.place(b, x_range, y_range, 0.06)
        if spot:
            b.cylinder(f"cup{k}", (spot[0], spot[1], TOP + 0.045), 0.04, 0.09, b.pick(ACCENTS))
    spot = taken.place(b, x_range, y_range, 0.05)
    if spot:
        b.cylinder("candle", (spot[0], spot[1], TOP + 0.08), 0.02, 0.16, (0.95, 0.93, 0.85))
        b.sphere("flame", (spot[0], spot[1], TOP + 0.18), 0.012, (1.0, 0.8, 0.3), emission=1.5)

    lights = [
        ambient(0.45),
        sun(b, azimuth_deg=b.pick([-1, 1]) * b.uniform(50, 110), elevation_deg=b.uniform(30, 55), intensity=0.8),
        DirectionalLightSpec(direction=(1.0, 0.0, -0.6), colour=(1.0, 1.0, 1.0), intensity=0.25, shadows=False),
    ]
    cam = rig(
        (-0.15, b.uniform(-0.1, 0.1), TOP + b.uniform(0.25, 0.4)), 0.0, (-75, 75), (-70, 25), hfov_deg=b.uniform(50, 65)
    )
    return b.scene(f"tabletop-{seed}", lights, cam)
