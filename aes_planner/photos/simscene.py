"""Simulated hand-held photo sets: a scene textured with photographs and a photographer walking an
arc around it, for tests, the ``bench photos`` figure and trying ``aes-planner pose`` without a camera.

The scene is plain data (a scene YAML mapping, :mod:`aes_planner.sim.spec`'s format): a floor and a
back wall carrying photographs, boxes and panels with photographs on their faces at several depths
(parallax), under soft light. The photographs are the caller's image files (``textures``); without
them procedural noise patterns stand in (less like a real photo, and poorer in corners).
:func:`cc0_photos` lists the real photographs the package ships for this (six CC0 photographs from
scikit-image's data, ``sim/assets/photos``); :func:`dead_leaves_textures` writes stand-ins with a
photograph's statistics (occluding discs of every size: edges, corners and texture at every scale).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from aes_planner.geometry.poses import look_at

__all__ = ["arc_poses", "cc0_photos", "dead_leaves_textures", "photo_scene"]

#: Where the photographed subject stands (world metres): the arc's cameras look at it.
SUBJECT_M = (3.0, 0.0, 0.7)


def cc0_photos() -> list[Path]:
    """The real photographs shipped for photo-textured scenes (CC0; ``sim/assets/photos/README.md``
    names each one's photographer), sorted by name."""
    from importlib import resources

    return sorted(Path(str(resources.files("aes_planner.sim") / "assets" / "photos")).glob("*.jpg"))


def dead_leaves_textures(out_dir: str | Path, n: int = 6, size_px: int = 256, seed: int = 0) -> list[Path]:
    """Write ``n`` "dead leaves" images (``size_px`` square PNGs, discs of random colours and radii
    falling on one another, radii spread as 1/r^3 like a photograph's objects) into ``out_dir``;
    returns their paths. A classic model of natural image statistics, for scenes without photos."""
    import cv2

    rng = np.random.default_rng(seed)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        img = np.full((size_px, size_px, 3), rng.integers(0, 256, 3), np.uint8)
        r_min, r_max = 2.0, size_px / 4
        for _ in range(900):
            u = rng.uniform()  # inverse CDF of p(r) ~ r^-3 on [r_min, r_max]
            r = 1.0 / math.sqrt(u / r_max**2 + (1 - u) / r_min**2)
            centre = (int(rng.integers(0, size_px)), int(rng.integers(0, size_px)))
            cv2.circle(img, centre, int(round(r)), [int(c) for c in rng.integers(0, 256, 3)], -1, cv2.LINE_AA)
        path = out / f"leaves_{i}.png"
        cv2.imwrite(str(path), img)
        paths.append(path)
    return paths


def _material(textures: Sequence[str], i: int, rng: np.random.Generator) -> dict:
    if textures:
        return {"image": str(textures[i % len(textures)])}
    colour = [round(float(c), 3) for c in rng.uniform(0.15, 0.9, 3)]
    colour2 = [round(float(c), 3) for c in rng.uniform(0.15, 0.9, 3)]
    scale = round(float(rng.uniform(0.04, 0.12)), 3)
    return {
        "albedo": colour,
        "pattern": {"kind": "noise", "colour2": colour2, "scale_m": scale, "octaves": 4, "seed": i},
    }


def photo_scene(
    textures: Sequence[str | Path] = (),
    seed: int = 0,
    camera: tuple[int, int, float] = (640, 480, 60.0),
    name: str = "photos",
    board: str | None = None,
) -> dict:
    """A scene mapping: photographs (``textures``, image files; noise patterns without them) on a
    back wall, on boxes and on standing panels around :data:`SUBJECT_M`, a textured floor, soft
    light; a drone section only to carry the camera (``width``, ``height``, ``hfov_deg``). ``board``
    (a ``--board`` spec, e.g. ``chessboard:9x6:0.06``) stands a printed board on an easel in front of
    the subject, facing the arc's middle: the metric scale for ``pose --board``."""
    rng = np.random.default_rng(seed)
    tex = [str(Path(t).resolve()) for t in textures]
    sx, sy, _ = SUBJECT_M
    objects: list[dict] = [
        {"type": "plane", "name": "floor", "point_m": [0, 0, 0], "normal": [0, 0, 1],
         "material": {**_material(tex, 0, rng), "tile_m": 0.9} if tex else _material(tex, 0, rng)},
        {"type": "box", "name": "wall", "centre_m": [sx + 2.2, sy, 1.5], "size_m": [0.2, 8.0, 3.0],
         "material": {"albedo": [0.85, 0.83, 0.8]}},
    ]  # fmt: skip
    k = 1
    for j, y in enumerate(np.linspace(-2.4, 2.4, 4)):  # framed photographs on the wall
        w = float(rng.uniform(0.9, 1.3))
        objects.append(
            {"type": "quad", "name": f"picture{j}", "centre_m": [sx + 2.09, float(y), float(rng.uniform(1.2, 1.8))],
             "size_m": [w, w * 0.75], "yaw_deg": 180.0, "material": _material(tex, k, rng)}
        )  # fmt: skip
        k += 1
    for j in range(5):  # boxes at several depths, photographs wrapped on them
        cx, cy = sx + float(rng.uniform(-0.9, 1.2)), sy + float(rng.uniform(-1.6, 1.6))
        size = [float(rng.uniform(0.4, 0.8)), float(rng.uniform(0.4, 0.8)), float(rng.uniform(0.3, 1.0))]
        objects.append(
            {"type": "box", "name": f"box{j}", "centre_m": [cx, cy, size[2] / 2], "size_m": size,
             "yaw_deg": float(rng.uniform(0, 90)), "material": {**_material(tex, k, rng), "tile_m": 0.5}
             if tex else _material(tex, k, rng)}
        )  # fmt: skip
        k += 1
    for j in range(2):  # panels standing on the floor, a photograph on each face
        cy = sy + (-0.9 if j == 0 else 1.1)
        objects.append(
            {"type": "quad", "name": f"panel{j}", "centre_m": [sx + 0.4 * j - 0.2, cy, 0.9], "size_m": [0.9, 0.7],
             "yaw_deg": 180.0 + (25.0 if j == 0 else -25.0), "material": _material(tex, k, rng)}
        )  # fmt: skip
        k += 1
    if board is not None:
        from aes_planner.geometry.board import parse_board

        bw, bh = parse_board(board).size_m(1)
        objects.append(
            {"type": "quad", "name": "board", "centre_m": [sx - 1.3, sy, 0.25 + bh / 2], "size_m": [bw, bh],
             "rpy_deg": [0.0, -15.0, 180.0], "material": {"image": f"board:{board}"}}
        )  # fmt: skip
    w, h, hfov = camera
    return {
        "name": name,
        "sky": {"horizon": [0.8, 0.85, 0.9], "zenith": [0.5, 0.65, 0.9], "nadir": [0.4, 0.38, 0.35]},
        "lights": [
            {"type": "ambient", "intensity": 0.6},
            {"type": "directional", "direction": [0.4, 0.3, -1.0], "intensity": 0.5, "shadows": False},
        ],
        "objects": objects,
        "drone": {"bounds_min_m": [-6.0, -6.0, 0.2], "bounds_max_m": [8.0, 6.0, 3.0],
                  "camera": {"width": w, "height": h, "hfov_deg": hfov}},
    }  # fmt: skip


def arc_poses(
    n: int,
    arc_deg: float = 80.0,
    radius_m: float = 3.0,
    height_m: float = 1.5,
    seed: int = 0,
    hand_jitter: bool = True,
) -> np.ndarray:  # -> [n, 4, 4] cam2world
    """``n`` cameras of a photographer walking an ``arc_deg`` arc of ``radius_m`` around
    :data:`SUBJECT_M`, each aimed near it; ``hand_jitter`` adds what a hand does: the height
    varies by +-10 cm, the aim by a few degrees and the roll by up to 3 degrees."""
    rng = np.random.default_rng(seed)
    subject = np.asarray(SUBJECT_M)
    angles = np.radians(np.linspace(180.0 - arc_deg / 2, 180.0 + arc_deg / 2, n))
    out = []
    for a in angles:
        eye = subject + radius_m * np.array([math.cos(a), math.sin(a), 0.0])
        eye[2] = height_m
        target = subject.copy()
        if hand_jitter:
            eye[2] += rng.uniform(-0.1, 0.1)
            target = target + rng.uniform(-0.25, 0.25, 3) * [1.0, 1.0, 0.5]
        pose = look_at(eye, target)
        if hand_jitter:  # roll about the optical axis
            r = math.radians(rng.uniform(-3.0, 3.0))
            c, s = math.cos(r), math.sin(r)
            pose[:3, :3] = pose[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        out.append(pose)
    return np.stack(out)
