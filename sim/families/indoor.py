"""``indoor``: a furnished room with a window, paintings, plants, shelves and a sofa.

The room spans ``x in [0, L]``, ``y in [-W/2, W/2]``, ``z in [0, H]``. The far wall (x = L)
has a window open to the sky, through which the sun throws a patch of light; a ground plane
and a few trees stand outside. The rig stands near the back wall facing +x, so its sweep sees
the window wall and the furnished sides, and also bare wall, ceiling and floor.
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
    painting,
    plant,
    rig,
    sun,
    tree,
)
from aes_planner.sim.spec import DirectionalLightSpec, SceneSpec

WALL_T = 0.1  # wall thickness, metres


def _walls(b: Builder, length: float, width: float, height: float, wall, window) -> None:
    """Floor, ceiling, four walls; the far wall is built around the window opening."""
    floor_pattern = b.pick(
        [
            b.pattern("stripes", b.tint((0.45, 0.3, 0.18)), 0.18, duty=0.12),
            b.pattern("checker", (0.2, 0.2, 0.22), 0.5),
            b.pattern("noise", b.tint((0.5, 0.4, 0.3)), 0.3, octaves=2),
        ]
    )
    b.box(
        "floor",
        (length / 2, 0, -0.05),
        (length + 2 * WALL_T, width + 2 * WALL_T, 0.1),
        b.pick(WOOD_TONES),
        pattern=floor_pattern,
    )
    b.box("ceiling", (length / 2, 0, height + 0.05), (length + 2 * WALL_T, width + 2 * WALL_T, 0.1), (0.93, 0.93, 0.92))
    b.box("wall_back", (-WALL_T / 2, 0, height / 2), (WALL_T, width, height), wall)
    b.box("wall_left", (length / 2, width / 2 + WALL_T / 2, height / 2), (length + 2 * WALL_T, WALL_T, height), wall)
    b.box("wall_right", (length / 2, -width / 2 - WALL_T / 2, height / 2), (length + 2 * WALL_T, WALL_T, height), wall)
    wy, ww, sill, wh = window
    x = length + WALL_T / 2
    left, right = wy + ww / 2, wy - ww / 2
    b.box("wall_far_left", (x, (left + width / 2) / 2, height / 2), (WALL_T, width / 2 - left, height), wall)
    b.box("wall_far_right", (x, (right - width / 2) / 2, height / 2), (WALL_T, right + width / 2, height), wall)
    b.box("wall_far_below", (x, wy, sill / 2), (WALL_T, ww, sill), wall)
    b.box("wall_far_above", (x, wy, (sill + wh + height) / 2), (WALL_T, ww, height - sill - wh), wall)
    frame = (0.95, 0.95, 0.93)
    b.box("window_mullion", (x, wy, sill + wh / 2), (0.06, 0.05, wh), frame)
    b.box("window_transom", (x, wy, sill + wh * 0.62), (0.06, ww, 0.05), frame)
    b.box("window_sill", (length - 0.06, wy, sill - 0.02), (0.16, ww + 0.2, 0.04), frame)


def _sofa(b: Builder, x: float, side: float, width: float, length: float) -> None:
    """A sofa against the side wall ``side`` (+1 left, -1 right), centred at ``x``."""
    fabric = b.pick(FABRIC_TONES)
    depth = 0.85
    y_wall = side * width / 2
    y = y_wall - side * depth / 2
    b.box("sofa_seat", (x, y, 0.22), (length, depth, 0.44), fabric)
    b.box("sofa_back", (x, y_wall - side * 0.1, 0.55), (length, 0.2, 0.5), b.tint(fabric, 0.03))
    for k, end in enumerate((-1, 1)):
        b.box(f"sofa_arm{k}", (x + end * (length / 2 - 0.1), y, 0.32), (0.2, depth, 0.64), b.tint(fabric, 0.03))
    for k in range(b.integer(1, 3)):
        b.box(
            f"cushion{k}",
            (x + b.uniform(-0.35, 0.35) * length, y_wall - side * 0.3, 0.6),
            (0.4, 0.14, 0.38),
            b.pick(ACCENTS),
            yaw_deg=b.uniform(-15, 15),
            pattern=b.pattern("checker", b.pick(ACCENTS), 0.1) if b.chance(0.4) else None,
        )


def _table(b: Builder, name: str, x: float, y: float, size_m: float) -> None:
    """A round table on one pedestal, with a vase or a bowl of fruit on it."""
    wood = b.pick(WOOD_TONES)
    top_z = 0.74
    b.cylinder(f"{name}_top", (x, y, top_z - 0.02), size_m / 2, 0.04, wood)
    b.cylinder(f"{name}_leg", (x, y, (top_z - 0.04) / 2), 0.05, top_z - 0.04, b.tint(wood, 0.03))
    if b.chance(0.5):
        h = b.uniform(0.2, 0.35)
        b.cylinder(f"{name}_vase", (x, y, top_z + h / 2), 0.06, h, b.pick(ACCENTS))
        for k in range(b.integer(2, 4)):
            b.sphere(
                f"{name}_flower{k}",
                (x + b.uniform(-0.08, 0.08), y + b.uniform(-0.08, 0.08), top_z + h + b.uniform(0.03, 0.12)),
                b.uniform(0.03, 0.05),
                b.pick(ACCENTS),
            )
    else:
        b.cylinder(f"{name}_bowl", (x, y, top_z + 0.04), 0.16, 0.08, (0.92, 0.92, 0.9))
        for k in range(b.integer(2, 4)):
            b.sphere(
                f"{name}_fruit{k}",
                (x + b.uniform(-0.08, 0.08), y + b.uniform(-0.08, 0.08), top_z + 0.12),
                0.045,
                b.pick([(0.85, 0.2, 0.1), (0.95, 0.7, 0.1), (0.4, 0.7, 0.2)]),
            )


def _shelf(b: Builder, x: float, side: float, width: float, height_m: float) -> None:
    """A bookcase against a side wall, its shelves cluttered with books."""
    wood = b.pick(WOOD_TONES)
    depth, length = 0.32, b.uniform(0.9, 1.4)
    y = side * (width / 2 - depth / 2)
    b.box("shelf_case", (x, y + side * 0.01, height_m / 2), (length, depth - 0.02, height_m), b.tint(wood, 0.03))
    levels = b.integer(2, 3)
    for level in range(levels):
        z0 = 0.2 + level * (height_m - 0.3) / levels + 0.02
        cursor = x - length / 2 + 0.06
        k = 0
        while cursor < x + length / 2 - 0.12 and k < 6:
            w = b.uniform(0.04, 0.09)
            h = b.uniform(0.18, 0.28)
            b.box(
                f"book{level}_{k}",
                (cursor + w / 2, y - side * 0.04, z0 + h / 2),
                (w, 0.22, h),
                b.tint(b.pick(ACCENTS + FABRIC_TONES), 0.05),
                yaw_deg=None,
            )
            cursor += w + b.uniform(0.0, 0.12)
            k += 1


def _lamp(b: Builder, x: float, y: float) -> None:
    """A floor lamp with a glowing shade."""
    b.cylinder("lamp_pole", (x, y, 0.8), 0.02, 1.6, (0.15, 0.15, 0.15))
    b.cylinder("lamp_shade", (x, y, 1.62), 0.2, 0.28, (0.98, 0.92, 0.78), emission=0.45)


def indoor(seed: int) -> SceneSpec:
    """A furnished room (see the module docstring); ``seed`` picks sizes, layout and colours."""
    b = Builder(seed)
    length, width, height = b.uniform(5.0, 7.0), b.uniform(4.0, 5.5), b.uniform(2.6, 3.0)
    wall = b.tint(b.pick(WALL_TONES), 0.03)
    window = (b.uniform(-0.25, 0.25) * width, b.uniform(1.1, 1.7), b.uniform(0.8, 1.0), b.uniform(1.1, 1.4))
    _walls(b, length, width, height, wall, window)

    # outside: ground and trees seen through the window
    b.plane(
        "ground_outside", (0, 0, -0.3), (0, 0, 1), (0.35, 0.5, 0.25), pattern=b.pattern("noise", (0.25, 0.4, 0.18), 2.0)
    )
    for k in range(b.integer(1, 3)):
        tree(b, f"tree{k}", (length + b.uniform(4, 12), window[0] + b.uniform(-4, 4)), -0.3, b.uniform(4, 7))

    cam_xy = (b.uniform(0.7, 1.0), b.uniform(-0.25, 0.25) * width)
    taken = Footprints()
    taken.add(*cam_xy, 0.8)

    side = b.pick([1.0, -1.0])
    sofa_len = b.uniform(1.6, 2.2)
    sofa_x = b.uniform(0.5, 0.75) * length
    _sofa(b, sofa_x, side, width, sofa_len)
    taken.add(sofa_x, side * (width / 2 - 0.45), sofa_len / 2)
    painting(
        b,
        "painting_sofa",
        (sofa_x, side * width / 2, b.uniform(1.45, 1.7)),
        -90.0 * side,
        b.uniform(0.8, 1.3),
        b.uniform(0.5, 0.8),
    )

    shelf_x = b.uniform(0.35, 0.6) * length
    if abs(shelf_x - sofa_x) > 1.6 or b.chance(0.5):
        shelf_side = -side
    else:
        shelf_side = side
        shelf_x = sofa_x - sofa_len / 2 - 0.9 if sofa_x > length / 2 else sofa_x + sofa_len / 2 + 0.9
    _shelf(b, shelf_x, shelf_side, width, b.uniform(1.5, 2.0))
    taken.add(shelf_x, shelf_side * (width / 2 - 0.2), 0.7)

    for k in range(b.integer(1, 2)):
        spot = taken.place(b, (0.5, length - 0.8), (-width / 2 + 0.5, width / 2 - 0.5), 0.55)
        if spot:
            _table(b, f"table{k}", *spot, b.uniform(0.6, 0.9))
    rug_xy = (b.uniform(0.45, 0.65) * length, b.uniform(-0.15, 0.15) * width)
    b.box(
        "rug",
        (rug_xy[0], rug_xy[1], 0.005),
        (b.uniform(1.6, 2.4), b.uniform(1.2, 1.8), 0.01),
        b.pick(FABRIC_TONES),
        yaw_deg=b.uniform(-10, 10),
        pattern=b.pick([b.pattern("stripes", b.pick(ACCENTS), 0.25), b.pattern("checker", b.pick(ACCENTS), 0.3)]),
    )
    for k in range(b.integer(1, 3)):
        spot = taken.place(b, (1.0, length - 0.3), (-width / 2 + 0.3, width / 2 - 0.3), 0.3)
        if spot:
            plant(b, f"plant{k}", spot, 0.0, b.uniform(0.8, 1.4))
    if b.chance(0.7):
        spot = taken.place(b, (1.2, length - 0.3), (-width / 2 + 0.3, width / 2 - 0.3), 0.25)
        if spot:
            _lamp(b, *spot)
    # paintings on the far wall beside the window and on the bare side wall
    far_free = width / 2 - abs(window[0]) - window[1] / 2
    if far_free > 1.0:
        y = window[0] + math.copysign(window[1] / 2 + far_free / 2, -window[0])
        painting(b, "painting_far", (length, y, 1.5), 180.0, min(0.8, far_free * 0.6), b.uniform(0.5, 0.9))
    if b.chance(0.6):
        painting(
            b,
            "painting_side",
            (b.uniform(0.3, 0.7) * length, -side * width / 2, 1.55),
            90.0 * side,
            b.uniform(0.5, 0.9),
            b.uniform(0.6, 1.0),
        )
    b.box("door", (-0.01, b.pick([-1, 1]) * (width / 2 - 0.7), 1.02), (0.04, 0.9, 2.04), b.tint(b.pick(WOOD_TONES)))

    lights = [
        ambient(0.5),
        sun(b, azimuth_deg=b.uniform(-25, 25), elevation_deg=b.uniform(25, 40), intensity=0.9),
        DirectionalLightSpec(direction=(0.6, 0.35, -0.7), colour=(1.0, 0.96, 0.9), intensity=0.4, shadows=False),
    ]
    cam = rig((cam_xy[0], cam_xy[1], b.uniform(1.2, 1.5)), 0.0, (-150, 150), (-55, 50), hfov_deg=b.uniform(55, 70))
    return b.scene(f"indoor-{seed}", lights, cam)
