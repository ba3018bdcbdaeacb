"""Writes session 28's derived dev loop scenes into ``sim/scenes/loop_dev/`` (docs/benchmarks.md,
"Widening the dev rigs, session 28"): procedural scenes of free dev seeds (271-275, docs/field.md)
with real photographs (CC0, ``sim/assets/photos``) hung at pans drawn over the whole pan range,
a pan range widened to +-170 deg, or a tilt range reaching -88 deg. Development set only.

    .venv/bin/python scripts/loop_dev_scenes_s28.py
"""

import math
from pathlib import Path

import numpy as np
import yaml

from aes_planner.sim.scene import load_scene, scene_to_yaml

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "sim" / "scenes" / "loop_dev"

#: name -> (procedural spec, photos hung, pan limits or None, tilt limits or None, what it is)
SCENES = {
    "photo_tabletop_271": ("tabletop:271", ("chelsea", "coffee"), (-170.0, 170.0), None, "two photographs, pan +-170"),
    "photo_gallery_272": ("gallery:272", ("camera", "chelsea"), None, None, "two photographs among the works"),
    "photo_outdoor_273": ("outdoor:273", ("coffee", "camera"), None, None, "two photographs on boards"),
    "wide_indoor_274": ("indoor:274", ("chelsea",), (-170.0, 170.0), None, "one photograph, pan +-170"),
    "steep_tabletop_275": ("tabletop:275", (), None, (-88.0, 40.0), "tilt down to -88 deg"),
}


def derived(name: str, spec: str, photos, pan, tilt, what: str) -> str:
    scene = load_scene(spec)
    data = yaml.safe_load(scene_to_yaml(scene))
    pt = data["rig"]["pan_tilt"]
    if pan is not None:
        pt["pan_limits_deg"] = list(pan)
    if tilt is not None:
        pt["tilt_limits_deg"] = list(tilt)
    lo, hi = pt["pan_limits_deg"]
    rng = np.random.default_rng(int(spec.split(":")[1]) + 28)
    base = np.asarray(pt["base_xyz_m"], float)
    yaw0 = float(pt["base_rpy_deg"][2])
    for i, photo in enumerate(photos):
        pan_deg = rng.uniform(lo + 10.0, hi - 10.0)
        a = math.radians(pan_deg + yaw0)
        d = rng.uniform(2.0, 3.0)
        c = base + np.array([d * math.cos(a), d * math.sin(a), rng.uniform(-0.3, 0.3)])
        w = rng.uniform(0.6, 1.1)
        data["objects"].append(
            {
                "type": "quad",
                "centre_m": [round(float(v), 4) for v in c],
                "size_m": [round(w, 3), round(w * 2 / 3, 3) if photo in ("chelsea", "coffee") else round(w, 3)],
                "rpy_deg": [0.0, 0.0, round(math.degrees(a) + 180.0, 2)],
                "name": f"photo{i}_{photo}",
                "material": {"albedo": [0.7, 0.7, 0.7], "image": f"../../assets/photos/{photo}.jpg", "emission": 0.0},
            }
        )
    head = (
        f"# eval loop scene (aes_planner.eval.loop): {spec} with {what} (scripts/loop_dev_scenes_s28.py).\n"
        "# development set: tune on it.\n"
    )
    data["name"] = name
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)


if __name__ == "__main__":
    for name, args in SCENES.items():
        path = OUT / f"{name}.yaml"
        path.write_text(derived(name, *args))
        load_scene(path)  # loads back
        print(path)
