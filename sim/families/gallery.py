"""``gallery``: a long wall hung with framed works under a skylight, a sculpture and a bench.

The main wall stands at ``x = D`` facing the rig (at the origin, facing +x); side walls close
the room at ``y = +-W/2`` and a ceiling with a skylight strip along the main wall lets the sun
draw a band of light across it. Works of different sizes hang with uneven gaps, so the sweep
meets single works, groups, the sculpture, bare wall, floor and ceiling.
"""

from __future__ import annotations

from aes_planner.sim.families._kit import ACCENTS, WALL_TONES, WOOD_TONES, Builder, ambient, painting, rig, sun
from aes_planner.sim.spec import DirectionalLightSpec, SceneSpec

WALL_T = 0.1


def _sculpture(b: Builder, x: float, y: float) -> None:
    """A plinth with a stacked abstract sculpture on it."""
    h = b.uniform(0.8, 1.1)
    b.box("plinth", (x, y, h / 2), (0.5, 0.5, h), (0.95, 0.95, 0.94))
    z = h
    material = b.pick([(0.7, 0.5, 0.25), (0.2, 0.2, 0.22), (0.85, 0.85, 0.88), b.pick(ACCENTS)])
    for k in range(b.integer(2, 3)):
        kind = b.pick(["sphere", "box", "cylinder"])
        size = b.uniform(0.12, 0.22)
        if kind == "sphere":
            b.sphere(f"sculpture{k}", (x, y, z + size), size, material)
            z += 2 * size * 0.95
        elif kind == "box":
            b.box(f"sculpture{k}", (x, y, z + size / 2), (size, size * 1.4, size), material, yaw_deg=b.uniform(0, 90))
            z += size
        else:
            b.cylinder(f"sculpture{k}", (x, y, z + size), size * 0.5, 2 * size, material)
            z += 2 * size


def gallery(seed: int) -> SceneSpec:
    """A gallery wall (see the module docstring); ``seed`` picks the hang and the room."""
    b = Builder(seed)
    dist, width, height = b.uniform(4.0, 6.5), b.uniform(10.0, 14.0), b.uniform(3.5, 4.5)
    wall = b.tint(b.pick(WALL_TONES + [(0.95, 0.95, 0.93)] * 2), 0.02)
    floor_pattern = b.pick(
        [b.pattern("checker", (0.3, 0.3, 0.32), 0.6), b.pattern("stripes", b.tint((0.45, 0.32, 0.2)), 0.2, duty=0.1)]
    )
    b.box(
        "floor",
        (dist / 2, 0, -0.05),
        (dist + 6, width + 2 * WALL_T, 0.1),
        b.pick(WOOD_TONES + [(0.85, 0.85, 0.82)]),
        pattern=floor_pattern,
    )
    b.box("wall_main", (dist + WALL_T / 2, 0, height / 2), (WALL_T, width, height), wall)
    for side in (-1, 1):
        b.box(
            f"wall_side{(side + 1) // 2}",
            (dist / 2 - 1.5, side * (width / 2 + WALL_T / 2), height / 2),
            (dist + 3 + WALL_T, WALL_T, height),
            wall,
        )
    b.box("wall_back", (-3 - WALL_T / 2, 0, height / 2), (WALL_T, width, height), wall)
    skylight = (dist - 1.6, dist - 0.4)  # x range of the opening along the main wall
    ceiling = (0.93, 0.93, 0.92)
    back_len = skylight[0] + 3
    b.box("ceiling", (skylight[0] - back_len / 2, 0, height + 0.05), (back_len, width, 0.1), ceiling)
    b.box("ceiling_edge", ((skylight[1] + dist) / 2, 0, height + 0.05), (dist - skylight[1], width, 0.1), ceiling)
    b.box("baseboard", (dist - 0.01, 0, 0.06), (0.02, width, 0.12), (0.25, 0.25, 0.25))

    # the hang: works left to right with uneven gaps, centred near eye height
    y = width / 2 - b.uniform(0.8, 2.0)
    k = 0
    while k < 6:
        w, h = b.pick(
            [
                (b.uniform(0.5, 0.8), b.uniform(0.6, 0.9)),
                (b.uniform(1.2, 2.0), b.uniform(0.9, 1.4)),
                (b.uniform(0.4, 0.6), b.uniform(0.4, 0.6)),
            ]
        )
        if y - w < -width / 2 + 0.8:
            break
        painting(b, f"work{k}", (dist, y - w / 2, b.uniform(1.45, 1.7)), 180.0, w, h)
        b.quad(f"label{k}", (dist - 0.005, y - w - 0.2, 1.25), (0.12, 0.08), (0.98, 0.98, 0.96), yaw_deg=180.0)
        y -= w + b.uniform(0.6, 2.8)
        k += 1

    _sculpture(b, dist - b.uniform(1.2, 2.0), b.uniform(-0.35, 0.35) * width)
    bench_y = b.uniform(-0.2, 0.2) * width
    bench_x = b.uniform(0.4, 0.6) * dist
    wood = b.pick(WOOD_TONES)
    b.box("bench_seat", (bench_x, bench_y, 0.44), (0.45, 1.6, 0.06), wood)
    for k, dy in enumerate((-0.65, 0.65)):
        b.box(f"bench_leg{k}", (bench_x, bench_y + dy, 0.2), (0.4, 0.06, 0.4), (0.15, 0.15, 0.15))

    lights = [
        ambient(0.5),
        sun(b, azimuth_deg=b.uniform(160, 200), elevation_deg=b.uniform(55, 70), intensity=0.7),
        DirectionalLightSpec(direction=(0.8, 0.0, -0.6), colour=(1.0, 0.98, 0.94), intensity=0.35, shadows=False),
    ]
    cam = rig((0.0, b.uniform(-0.5, 0.5), b.uniform(1.4, 1.6)), 0.0, (-110, 110), (-40, 40), hfov_deg=b.uniform(55, 70))
    return b.scene(f"gallery-{seed}", lights, cam)
