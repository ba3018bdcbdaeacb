"""Write the photo-textured framing dev scenes (sim/scenes/loop_dev/photo_*.yaml).

Each scene is a procedural family scene at a dev seed (2xx: the loop's dev range) with real
photographs (the CC0 set of sim/assets/photos, and sunset.png) hung where the rig's input sweep
sees them: a picture is placed at a pixel of one input view (``at``: view, u, v as fractions of
the frame), on the surface the ray hits there (``wall``: flush, facing out along the surface's
normal) or on a stand on the ground (``stand``: a poster on a board with two posts, facing the
rig). Picking the pixel makes the cases of issue 40's check on purpose: a picture at the border
of the view that shows most of it, one that nearly fills the frame, several side by side.

    .venv/bin/python scripts/framing_photo_scenes.py      # writes the YAML files and prints a table

Dev only: nothing here looked at the held-out photo scenes' files.
"""

from __future__ import annotations

import math
import zlib
from pathlib import Path

import numpy as np
import yaml

from aes_planner.config import from_dict
from aes_planner.geometry.pantilt import PanTilt
from aes_planner.sim import render
from aes_planner.sim.families import FAMILIES
from aes_planner.sim.scene import Scene
from aes_planner.sim.spec import SceneSpec, spec_to_dict

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "sim" / "scenes" / "loop_dev"
PHOTOS = ROOT / "sim" / "assets" / "photos"
ASPECT = {"chelsea.jpg": None, "coffee.jpg": None, "camera.jpg": None, "brick.jpg": None, "sunset.png": 1.5}

# name: family, seed, rig overrides, pictures (image, where, width m, placement)
RECIPES: dict[str, dict] = {
    # a gallery wall: one photograph at the left border of its best view, one in the middle
    "photo_gallery_edge": dict(
        family="gallery",
        seed=230,
        rig={},
        pictures=[
            ("chelsea.jpg", (1, 0.04, 0.45), 0.35, "wall"),
            ("coffee.jpg", (2, 0.55, 0.40), 0.25, "wall"),
        ],
    ),
    # a room: a large photograph that nearly fills the view it is seen in
    "photo_room_large": dict(
        family="indoor",
        seed=231,
        rig={},
        pictures=[
            ("camera.jpg", (2, 0.5, 0.5), 0.6, "wall"),
        ],
    ),
    # three photographs side by side on one wall, the right one cut by the frame
    "photo_triptych": dict(
        family="gallery",
        seed=232,
        rig={},
        pictures=[
            ("chelsea.jpg", (2, 0.22, 0.45), 0.2, "wall"),
            ("sunset.png", (2, 0.55, 0.45), 0.22, "wall"),
            ("coffee.jpg", (2, 0.95, 0.45), 0.2, "wall"),
        ],
    ),
    # outdoors: posters on stands in a meadow, one at the bottom border
    "photo_posters_outdoor": dict(
        family="outdoor",
        seed=233,
        rig={},
        pictures=[
            ("camera.jpg", (1, 0.40, 0.60), 0.3, "stand"),
            ("sunset.png", (2, 0.65, 0.85), 0.25, "stand"),
        ],
    ),
    # a tight rig (pan +-40, tilt +-20) facing a wall of photographs
    "photo_tight_rig": dict(
        family="gallery",
        seed=234,
        rig={"pan_limits_deg": [-40.0, 40.0], "tilt_limits_deg": [-20.0, 20.0]},
        pictures=[
            ("coffee.jpg", (0, 0.10, 0.50), 0.3, "wall"),
            ("chelsea.jpg", (2, 0.92, 0.35), 0.3, "wall"),
        ],
    ),
    # a room: a photograph at the top border, another near the corner of its view
    "photo_room_corner": dict(
        family="indoor",
        seed=235,
        rig={},
        pictures=[
            ("sunset.png", (1, 0.50, 0.08), 0.35, "wall"),
            ("brick.jpg", (3, 0.88, 0.80), 0.3, "wall"),
        ],
    ),
    # outdoors, a tight rig: a large poster close by, filling most of the view
    "photo_poster_close": dict(
        family="outdoor",
        seed=236,
        rig={"pan_limits_deg": [-60.0, 60.0], "tilt_limits_deg": [-25.0, 25.0]},
        pictures=[
            ("chelsea.jpg", (1, 0.5, 0.55), 0.7, "stand"),
            ("coffee.jpg", (3, 0.06, 0.55), 0.35, "stand"),
        ],
    ),
    # a tabletop: photographs hung on the back wall, one at the right border
    "photo_tabletop": dict(
        family="tabletop",
        seed=237,
        rig={},
        pictures=[
            ("camera.jpg", (0, 0.45, 0.30), 0.3, "wall"),
            ("sunset.png", (2, 0.95, 0.40), 0.3, "wall"),
        ],
    ),
}


def _aspect(image: str) -> float:  # width / height
    import cv2

    img = cv2.imread(str(PHOTOS / image if (PHOTOS / image).exists() else OUT / image))
    return img.shape[1] / img.shape[0]


def _image_ref(image: str) -> str:
    """The scene's path to a photograph: the project's own copy in sim/assets/photos, else beside the scene."""
    return f"../../assets/photos/{image}" if (PHOTOS / image).exists() else image


def _unproject(k, pose, u, v, d):
    ray = np.array([(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0])
    return pose[:3, :3] @ (ray * d) + pose[:3, 3]


def _place(scene: Scene, k, pose, at, width_m, how, image, name, rng) -> list[dict]:
    _, uf, vf = at
    u, v = uf * k.width, vf * k.height
    out = render(scene, pose, k, supersample=1)
    depth = out.depth_m
    iu, iv = int(min(max(u, 1), k.width - 2)), int(min(max(v, 1), k.height - 2))
    if how == "wall":  # the nearest pixel of the column (then of the image) that sees a wall
        walls = np.zeros(depth.shape, bool)
        for j, obj in enumerate(scene.objects):
            if "wall" in obj.name and "far" not in obj.name:
                walls |= out.instance_id == j + 1
        walls[[0, -1], :] = False
        walls[:, [0, -1]] = False
        ys, xs = np.nonzero(walls)
        if not len(xs):
            raise SystemExit(f"{name}: view {at[0]} sees no wall")
        i = int(np.argmin(4 * (xs - iu) ** 2 + (ys - iv) ** 2))
        iu, iv = int(xs[i]), int(ys[i])
        wall_rot = np.asarray(scene.objects[int(out.instance_id[iv, iu]) - 1].rotation(), dtype=np.float64)
    d = float(depth[iv, iu])
    width_m = round(width_m * d * k.width / k.fx, 3)  # given as a fraction of the frame's width at that depth
    height_m = width_m / _aspect(image)
    mat = {"albedo": [0.7, 0.7, 0.7], "image": _image_ref(image)}
    eye = pose[:3, 3]
    if how == "wall":
        p = _unproject(k, pose, iu + 0.5, iv + 0.5, d)
        px = _unproject(k, pose, iu + 1.5, iv + 0.5, float(depth[iv, iu + 1]))
        py = _unproject(k, pose, iu + 0.5, iv + 1.5, float(depth[iv + 1, iu]))
        n = np.cross(px - p, py - p)
        upright = np.abs(wall_rot[2]) < 0.5  # the wall box's upright faces: the one it hit
        n = wall_rot[:, int(np.argmax(np.where(upright, np.abs(wall_rot.T @ n), -1.0)))].copy()
        n[2] = 0.0
        n /= np.linalg.norm(n)
        if n @ (eye - p) < 0:
            n = -n
        yaw = math.degrees(math.atan2(n[1], n[0]))
        centre = p + 0.02 * n
        return [
            {
                "type": "quad",
                "centre_m": [round(float(c), 4) for c in centre],
                "size_m": [width_m, round(height_m, 4)],
                "yaw_deg": round(yaw, 2),
                "name": name,
                "material": mat,
            }
        ]
    # a poster on a stand: the ray's point at ground level pulled to 80 % of the distance, facing the rig
    ground = _unproject(k, pose, u, v, d)
    g = eye + 0.8 * (ground - eye)
    to_eye = eye - g
    to_eye[2] = 0.0
    n = to_eye / np.linalg.norm(to_eye)
    yaw = math.degrees(math.atan2(n[1], n[0])) + float(rng.uniform(-15, 15))
    yr = math.radians(yaw)
    n = np.array([math.cos(yr), math.sin(yr), 0.0])
    side = np.array([-n[1], n[0], 0.0])
    bottom = 0.5
    centre = np.array([g[0], g[1], bottom + height_m / 2])
    board = centre - 0.03 * n
    out = [
        {
            "type": "quad",
            "centre_m": [round(float(c), 4) for c in centre],
            "size_m": [width_m, round(height_m, 4)],
            "yaw_deg": round(yaw, 2),
            "name": name,
            "material": mat,
        },
        {
            "type": "box",
            "centre_m": [round(float(c), 4) for c in board],
            "size_m": [0.04, round(width_m + 0.1, 3), round(height_m + 0.1, 3)],
            "yaw_deg": round(yaw, 2),
            "name": f"{name}_board",
            "material": {"albedo": [0.25, 0.25, 0.27]},
        },
    ]
    for s, tag in ((-1, "l"), (1, "r")):
        post = board - 0.04 * n + side * s * (width_m / 2 - 0.05)
        post[2] = (bottom + height_m / 2) / 2
        out.append(
            {
                "type": "cylinder",
                "centre_m": [round(float(c), 4) for c in post],
                "radius_m": 0.03,
                "height_m": round(bottom + height_m / 2, 3),
                "axis": [0.0, 0.0, 1.0],
                "name": f"{name}_post{tag}",
                "material": {"albedo": [0.3, 0.25, 0.2]},
            }
        )
    return out


def build(name: str, recipe: dict) -> Path:
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    data = spec_to_dict(FAMILIES[recipe["family"]](recipe["seed"]))
    data["name"] = name
    data["rig"]["pan_tilt"].update(recipe["rig"])
    for i, (image, at, width_m, how) in enumerate(recipe["pictures"]):
        scene = Scene(from_dict(SceneSpec, data), base_dir=OUT)
        pt = PanTilt(scene.rig.pan_tilt) if hasattr(scene.rig, "pan_tilt") else scene.rig.kinematics()
        j = pt.sweep(4)
        poses = pt.forward(j[:, 0], j[:, 1])
        k = scene.intrinsics()
        data["objects"] += _place(scene, k, poses[at[0]], at, width_m, how, image, f"picture{i}", rng)
    path = OUT / f"{name}.yaml"
    head = (
        f"# framing dev scene (scripts/framing_photo_scenes.py): {recipe['family']}:{recipe['seed']} with real\n"
        "# photographs (CC0, sim/assets/photos/README.md; sunset.png) as subjects picture0, picture1, ...\n"
        "# development set: tune on it.\n"
    )
    path.write_text(head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=110), encoding="utf-8")
    return path


def describe(path: Path) -> None:
    from aes_planner.eval.framing import FramingEvalConfig, _shown, pick_subject
    from aes_planner.sim import load_scene

    scene = load_scene(path)
    pt = scene.rig.kinematics()
    j = pt.sweep(4)
    poses = pt.forward(j[:, 0], j[:, 1])
    k = scene.intrinsics()
    cfg = FramingEvalConfig(scenes=[str(path)])
    for obj in scene.objects:
        if obj.name.startswith("picture") and "_" not in obj.name:
            got = pick_subject(scene, poses, k, 0, cfg, obj.name)
            if got is None:
                print(f"{path.name} {obj.name}: in no input view")
                continue
            oi, view, region = got
            print(
                f"{path.name} {obj.name}: view {view} box {region.x0:g},{region.y0:g},{region.x1:g},{region.y1:g} "
                f"shown {_shown(scene, oi, poses[view], k):.2f}"
            )


def sheet(paths: list[Path], out: str) -> None:
    """The four input views of each scene side by side (a look at what was built)."""
    import cv2

    from aes_planner.sim import load_scene

    rows = []
    for path in paths:
        scene = load_scene(path)
        pt = scene.rig.kinematics()
        j = pt.sweep(4)
        poses = pt.forward(j[:, 0], j[:, 1])
        rows.append(np.hstack([render(scene, p, scene.intrinsics(), supersample=1).rgb for p in poses]))
    cv2.imwrite(out, cv2.cvtColor(np.vstack(rows), cv2.COLOR_RGB2BGR))


def main() -> None:
    import sys

    paths = [build(name, recipe) for name, recipe in RECIPES.items()]
    for path in paths:
        describe(path)
    if len(sys.argv) > 1:
        sheet(paths, sys.argv[1])


if __name__ == "__main__":
    main()
