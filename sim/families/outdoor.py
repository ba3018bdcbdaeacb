"""``outdoor``: a meadow with a horizon, hills, trees, a house, a fence line, a path and a pond.

The rig stands 1.5 m above the ground at the origin facing +x. The house and most trees lie
in front, hills ring the horizon, the fence draws a long line across part of the view; behind
and above there is mostly grass and sky, the weak views.
"""

from __future__ import annotations

import math

import numpy as np

from aes_planner.sim.families._kit import ACCENTS, Builder, ambient, rig, sun, tree, wall_frame
from aes_planner.sim.spec import SceneSpec, SkySpec

GRASS = (0.36, 0.52, 0.24)


def _polar(bearing_deg: float, distance_m: float) -> tuple[float, float]:
    a = math.radians(bearing_deg)
    return distance_m * math.cos(a), distance_m * math.sin(a)


def _house(b: Builder, x: float, y: float, facing_deg: float) -> None:
    """A house facing ``facing_deg``: walls, a gable roof (a box turned 45 deg about its ridge),
    a door and windows."""
    length, depth, height = b.uniform(7, 11), b.uniform(5, 7), b.uniform(3, 4.5)
    wall = b.pick([(0.9, 0.88, 0.8), (0.75, 0.45, 0.35), (0.85, 0.8, 0.65), (0.6, 0.65, 0.7)])
    b.box("house", (x, y, height / 2), (depth, length, height), b.tint(wall, 0.03), yaw_deg=facing_deg)
    side = depth / math.sqrt(2) * 1.08
    roof = b.pick([(0.55, 0.2, 0.15), (0.3, 0.3, 0.33), (0.45, 0.3, 0.2)])
    b.box(
        "roof",
        (x, y, height),
        (side, length + 0.6, side),
        roof,
        rpy_deg=(0.0, 45.0, facing_deg),
        pattern=b.pattern("stripes", np.asarray(roof) * 0.7, 0.3, duty=0.2),
    )
    normal, right = wall_frame(facing_deg)
    front = np.array([x, y, 0.0]) + normal * (depth / 2 + 0.01)
    door_at = b.uniform(-0.3, 0.3) * length
    b.quad("door", front + right * door_at + np.array([0, 0, 1.05]), (1.0, 2.1), b.pick(ACCENTS), yaw_deg=facing_deg)
    glass = (0.55, 0.7, 0.85)
    for k, along in enumerate(np.linspace(-0.38, 0.38, 4) * length):
        if abs(along - door_at) < 1.2:
            continue
        b.quad(
            f"window{k}",
            front + right * along + np.array([0, 0, height * 0.55]),
            (1.1, 1.2),
            glass,
            yaw_deg=facing_deg,
            pattern=b.pattern("checker", (0.35, 0.45, 0.6), 0.3),
        )


def outdoor(seed: int) -> SceneSpec:
    """A countryside view (see the module docstring); ``seed`` picks the layout and colours."""
    b = Builder(seed)
    b.plane(
        "ground",
        (0, 0, 0),
        (0, 0, 1),
        b.tint(GRASS, 0.04),
        pattern=b.pattern("noise", b.tint((0.28, 0.42, 0.18), 0.04), b.uniform(1.5, 3.0), octaves=2, seed=seed),
    )
    for k in range(b.integer(3, 5)):
        bearing = b.uniform(-120, 120)
        radius = b.uniform(40, 110)
        hx, hy = _polar(bearing, b.uniform(150, 320))
        b.sphere(
            f"hill{k}",
            (hx, hy, -radius * b.uniform(0.55, 0.8)),
            radius,
            b.tint((0.32, 0.45, 0.28), 0.05),
            pattern=b.pattern("noise", (0.25, 0.36, 0.22), radius * 0.2, octaves=2, seed=k),
        )
    house_bearing = b.uniform(-50, 50)
    hx, hy = _polar(house_bearing, b.uniform(18, 30))
    _house(b, hx, hy, house_bearing + 180 + b.uniform(-30, 30))
    # path from near the rig to the house door side
    path_len = math.hypot(hx, hy) - 4
    px, py = _polar(house_bearing, 2 + path_len / 2)
    b.box(
        "path",
        (px, py, 0.01),
        (path_len, 1.2, 0.02),
        (0.62, 0.56, 0.45),
        yaw_deg=house_bearing,
        pattern=b.pattern("noise", (0.5, 0.45, 0.36), 0.4, octaves=1),
    )
    # trees: a cluster near the house and a few loners, none close to the rig
    for k in range(b.integer(8, 14)):
        if k < 4:
            tx, ty = hx + b.uniform(-8, 8), hy + b.uniform(-10, 10)
            if math.hypot(tx - hx, ty - hy) < 6:
                continue
        else:
            tx, ty = _polar(b.uniform(-150, 150), b.uniform(12, 60))
        tree(b, f"tree{k}", (tx, ty), 0.0, b.uniform(5, 10))
    # fence: a row of posts and two rails, a strong line across part of the view
    fence_bearing = b.uniform(30, 90) * b.pick([-1, 1])
    start = np.array(_polar(fence_bearing, b.uniform(6, 9)))
    heading = math.radians(fence_bearing + b.uniform(-20, 20) + 90)
    direction = np.array([math.cos(heading), math.sin(heading)])
    posts, spacing = b.integer(6, 10), 2.0
    wood = b.tint((0.5, 0.36, 0.22))
    for k in range(posts):
        x, y = start + direction * spacing * (k - posts / 2)
        b.cylinder(f"post{k}", (x, y, 0.55), 0.06, 1.1, wood)
    mid = start + direction * spacing * (-0.5)
    for k, z in enumerate((0.45, 0.9)):
        b.box(f"rail{k}", (mid[0], mid[1], z), (spacing * (posts - 1), 0.05, 0.08), wood, yaw_deg=math.degrees(heading))
    px, py = _polar(b.uniform(-160, 160), b.uniform(10, 25))
    b.cylinder(
        "pond",
        (px, py, 0.01),
        b.uniform(2, 4),
        0.02,
        (0.25, 0.45, 0.65),
        pattern=b.pattern("noise", (0.35, 0.55, 0.75), 0.8, octaves=1),
    )
    for k in range(b.integer(3, 6)):  # bushes: low clutter along the ground
        bx, by = _polar(b.uniform(-170, 170), b.uniform(5, 30))
        for j in range(b.integer(1, 3)):
            radius = b.uniform(0.4, 0.9)
            b.sphere(
                f"bush{k}_{j}",
                (bx + b.uniform(-0.6, 0.6), by + b.uniform(-0.6, 0.6), radius * 0.6),
                radius,
                b.tint((0.22, 0.4, 0.17)),
                pattern=b.pattern("noise", (0.15, 0.3, 0.12), 0.15, octaves=2, seed=k),
            )
    for k in range(b.integer(2, 4)):
        rx, ry = _polar(b.uniform(-180, 180), b.uniform(4, 15))
        radius = b.uniform(0.3, 0.8)
        b.sphere(f"rock{k}", (rx, ry, radius * 0.3), radius, b.tint((0.55, 0.55, 0.52)))

    lights = [
        ambient(0.5, (0.85, 0.9, 1.0)),
        sun(b, azimuth_deg=b.uniform(-150, 150), elevation_deg=b.uniform(20, 55), intensity=0.8),
    ]
    sky = SkySpec(
        horizon=b.tint((0.85, 0.88, 0.92), 0.03), zenith=b.tint((0.3, 0.5, 0.85), 0.05), nadir=(0.4, 0.42, 0.36)
    )
    cam = rig((0.0, 0.0, 1.5), 0.0, (-170, 170), (-45, 45), hfov_deg=b.uniform(55, 75))
    return b.scene(f"outdoor-{seed}", lights, cam, sky)
