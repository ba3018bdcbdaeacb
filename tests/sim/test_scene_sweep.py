"""Bad-input sweep: scene YAML files and FAMILY:SEED specs through load_scene.

Each case ends in a ConfigError / SceneError (an AesPlannerError) with one line naming the key,
quickly, or loads as documented; nothing reads files outside the scene's folder unless asked.
"""

import shutil
import struct
import zlib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.config import from_dict
from aes_planner.errors import AesPlannerError
from aes_planner.sim import Scene, SceneSpec, SimCamera, SimCameraConfig, load_scene, render
from aes_planner.sim.survey import render_survey
from tests.helpers import write_file

SHOWCASE = Path(str(resources.files("aes_planner.sim") / "scenes" / "showcase.yaml"))
ASSET = Path(str(resources.files("aes_planner.sim") / "assets" / "sunset.png"))
IMAGE_OBJ = 6  # the showcase's textured quad


def png_header(width: int, height: int) -> bytes:
    """A PNG whose header claims ``width x height`` (a decompression bomb's header), data damaged."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk)) + b"\0" * 64


@pytest.fixture
def scene_dir(tmp_path):
    """A scene folder: the showcase with its picture copied beside it."""
    folder = tmp_path / "scene"
    folder.mkdir()
    shutil.copy(ASSET, folder / "sunset.png")
    data = yaml.safe_load(SHOWCASE.read_text())
    data["objects"][IMAGE_OBJ]["material"]["image"] = "sunset.png"
    data["rig"]["camera"].update(width=16, height=12)

    def write(edit=None, text=None) -> Path:
        d = yaml.safe_load(yaml.safe_dump(data))
        if edit is not None:
            edit(d)
        path = folder / "scene.yaml"
        path.write_text(text if text is not None else yaml.safe_dump(d))
        return path

    return folder, write


def _mat(d, **kw):
    d["objects"][IMAGE_OBJ]["material"].update(kw)


def _cam(d, **kw):
    d["rig"]["camera"].update(kw)


SCENE_CASES = [
    (lambda d: _cam(d, width=100000, height=100000), "rig.camera.width", "too large"),
    (lambda d: _cam(d, width=40000), "rig.camera.width", "too large"),
    (lambda d: _cam(d, width=0), "rig.camera.width", ">= 1"),
    (lambda d: _cam(d, width=1.5), "rig.camera.width", "integer"),
    (lambda d: _cam(d, hfov_deg=180), "hfov_deg", "(0, 180)"),
    (lambda d: _cam(d, hfov_deg="wide"), "hfov_deg", "expected a number"),
    (lambda d: _cam(d, hfov_deg=1e400), "hfov_deg", "finite"),
    (lambda d: _mat(d, tile_m=1e-320), "tile_m", "metres"),
    (lambda d: _mat(d, tile_m=1e300), "tile_m", "metres"),
    (lambda d: d["objects"][3]["material"]["pattern"].update(scale_m=1e-300), "scale_m", "metres"),
    (lambda d: d["objects"][1].update(size_m=[1e300, 1, 1]), "objects[1].size_m", "at most 1e6"),
    (lambda d: d["objects"][1].update(size_m=[1, 1]), "objects[1].size_m", "expected 3 values"),
    (lambda d: d["objects"][1].update(size_m="big"), "objects[1].size_m", "expected a list"),
    (lambda d: d["objects"][1].update(centre_m=[float("nan"), 0, 0]), "objects[1].centre_m", "finite"),
    (lambda d: d["objects"][0]["material"].update(albedo=[2, 0, 0]), "albedo", "[0, 1]"),
    (lambda d: d["objects"][0].update(type="torus"), "objects[0].type", "must be one of"),
    (lambda d: d["objects"][0].pop("type"), "objects[0].type", "must be one of"),
    (lambda d: d.update(objects={"a": 1}), "objects", "expected a list"),
    (lambda d: d.update(objects=[1, 2]), "objects[0]", "mapping"),
    (lambda d: d.update(colour="red"), "colour", "unknown key"),
    (lambda d: d["rig"]["pan_tilt"].update(pan_limits_deg=[10, -10]), "pan_limits_deg", ""),
    (lambda d: d.pop("rig"), "rig", "exactly one"),
    (lambda d: _mat(d, image="/etc/hostname"), "material.image", "leads outside"),
    (lambda d: _mat(d, image="../outside.png"), "material.image", "leads outside"),
    (lambda d: _mat(d, image="~/x.png"), "material.image", "not found"),  # no home expansion in scene files
    (lambda d: _mat(d, image="sun\x00set.png"), "material.image", "NUL"),
    (lambda d: _mat(d, image="missing.png"), "material.image", "not found"),
    (lambda d: _mat(d, image="bomb.png"), "material.image", "100000x100000 pixels"),
    (lambda d: _mat(d, image="junk.png"), "material.image", "not an image"),
    (lambda d: _mat(d, image=""), "material.image", "empty"),
    (lambda d: _mat(d, image=["a"]), "material.image", "expected a string"),
    # lights of absurd intensity (a third sweep): refused at load, never rendered as NaN
    (lambda d: d["lights"][0].update(intensity=1e308), "lights[0].intensity", "within [0, 100]"),
    (lambda d: d["lights"][1].update(intensity=1e30), "lights[1].intensity", "within [0, 100]"),
    (lambda d: d["lights"][1].update(intensity=float("inf")), "lights[1].intensity", "finite"),
    (lambda d: d["lights"][0].update(intensity=float("nan")), "lights[0].intensity", "finite"),
    (lambda d: d["lights"][0].update(intensity=-1), "lights[0].intensity", "within [0, 100]"),
    (lambda d: _mat(d, emission=1e300), "material.emission", "within [0, 100]"),
]


@pytest.mark.parametrize("edit, key, match", SCENE_CASES, ids=range(len(SCENE_CASES)))
def test_bad_scene_values_name_the_key(scene_dir, clean_error, edit, key, match):
    folder, write = scene_dir
    (folder / "bomb.png").write_bytes(png_header(100000, 100000))
    (folder / "junk.png").write_bytes(b"not an image at all" * 10)
    (folder.parent / "outside.png").write_bytes(ASSET.read_bytes())
    err = clean_error(load_scene, write(edit), match=match)
    assert key in str(err)


def test_symlink_out_of_the_scene_folder_is_refused_unless_allowed(scene_dir, clean_error):
    folder, write = scene_dir
    outside = folder.parent / "elsewhere"
    outside.mkdir()
    shutil.copy(ASSET, outside / "pic.png")
    (folder / "link.png").symlink_to(outside / "pic.png")
    path = write(lambda d: _mat(d, image="link.png"))
    clean_error(load_scene, path, match="leads outside")
    scene = load_scene(path, allow_outside=True)  # the explicit opt-in
    assert IMAGE_OBJ in scene.textures
    # a symlink that stays inside is fine
    (folder / "inside.png").symlink_to(folder / "sunset.png")
    assert IMAGE_OBJ in load_scene(write(lambda d: _mat(d, image="inside.png"))).textures


def test_valid_scene_with_yaml_1_2_numbers_loads(scene_dir):
    _, write = scene_dir
    scene = load_scene(write(text=write().read_text().replace("radius_m: 0.25", "radius_m: 25e-2")))
    assert any(getattr(o, "radius_m", None) == 0.25 for o in scene.objects)
    out = render(scene, scene.rig.kinematics().forward(0.0, 0.0), scene.rig.intrinsics())
    assert np.isfinite(out.rgb).all()


@pytest.mark.parametrize(
    "spec, match",
    [
        ("indoor:-1", "out of range"),
        ("indoor:" + "9" * 30, "out of range"),
        ("indoor:" + "9" * 5000, "neither a file nor"),
        ("nowhere:3", "unknown scene family"),
        ("indoor:three", "neither a file nor"),
        ("indoor\x00:3", "neither a file nor"),
        ("x" * 5000, "neither a file nor"),
        ("", "neither a file nor"),
    ],
)
def test_bad_family_specs(spec, match, clean_error):
    clean_error(load_scene, spec, match=match)


def test_scene_files_that_are_not_scenes(tmp_path, clean_error):
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    clean_error(load_scene, tmp_path / "list.yaml", match="must hold a mapping")
    (tmp_path / "bin.yaml").write_bytes(bytes(range(256)))
    clean_error(load_scene, tmp_path / "bin.yaml", match="not UTF-8")
    clean_error(load_scene, tmp_path, match="neither a file nor")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"width": 100000}, "width"),
        ({"width": 8192, "height": 8193}, "too large"),
        ({"supersample": 0}, "supersample"),
        ({"supersample": 1000}, "supersample"),
        ({"pixel_noise_sigma": float("inf")}, "pixel_noise_sigma"),
        ({"latency_s": -1.0}, "latency_s"),
    ],
)
def test_sim_camera_config_bounds(kwargs, match, clean_error):
    clean_error(SimCameraConfig, **kwargs, match=match)


def test_huge_camera_refused_before_allocating(clean_error, tmp_path):
    from aes_planner.geometry import Intrinsics

    clean_error(Intrinsics, 5e4, 5e4, 5e4, 5e4, 100000, 100000, match="too large")
    clean_error(Intrinsics.from_fov, 8192, 8193, 60.0, match="too large")
    scene = load_scene("indoor:3")
    cam = SimCamera(scene, SimCameraConfig(width=8, height=6))  # a small one still works
    assert cam.capture_joints(0.0, 0.0).image.shape == (6, 8, 3)
    for views in (0, -1, 10**9, 2.5, True):
        clean_error(render_survey, "indoor:3", views, tmp_path / "out", match="--views")
    assert not (tmp_path / "out").exists()


_EXTREMES = st.one_of(
    st.sampled_from([0.0, -0.0, 1e-320, 1e-300, 1e-5, 1e6, 1e12, 1e300, -1e300, 180.0, 1e30]),
    st.floats(allow_nan=True, allow_infinity=True),
)
_FIELDS = [
    ("rig.camera.hfov_deg", lambda d, v: d["rig"]["camera"].update(hfov_deg=v)),
    ("objects[1].size_m", lambda d, v: d["objects"][1].update(size_m=[v, 1.0, 1.0])),
    ("objects[2].radius_m", lambda d, v: d["objects"][2].update(radius_m=v)),
    ("objects[2].centre_m", lambda d, v: d["objects"][2].update(centre_m=[v, 0.0, 1.0])),
    ("objects[3].material.pattern.scale_m", lambda d, v: d["objects"][3]["material"]["pattern"].update(scale_m=v)),
    ("objects[3].material.pattern.angle_deg", lambda d, v: d["objects"][3]["material"]["pattern"].update(angle_deg=v)),
    ("objects[6].material.tile_m", lambda d, v: d["objects"][6]["material"].update(tile_m=v)),
    ("objects[1].material.emission", lambda d, v: d["objects"][1]["material"].update(emission=v)),
    ("lights[1].intensity", lambda d, v: d["lights"][1].update(intensity=v)),
    ("lights[1].direction", lambda d, v: d["lights"][1].update(direction=[v, 0.1, -1.0])),
    ("rig.pan_tilt.base_xyz_m", lambda d, v: d["rig"]["pan_tilt"].update(base_xyz_m=[v, 0.0, 1.0])),
]


@settings(max_examples=80)
@given(field=st.sampled_from(_FIELDS), value=_EXTREMES)
def test_extreme_numbers_give_a_config_error_or_a_finite_render(field, value):
    data = yaml.safe_load(SHOWCASE.read_text())
    data["objects"][IMAGE_OBJ]["material"]["image"] = str(ASSET)
    data["rig"]["camera"].update(width=12, height=9)
    field[1](data, value)
    try:
        scene = Scene(from_dict(SceneSpec, data))
        out = render(scene, scene.rig.kinematics().forward(0.1, -0.1), scene.rig.intrinsics())
    except AesPlannerError as exc:
        assert "\n" not in str(exc)
        return
    assert np.isfinite(out.rgb).all() and np.isfinite(out.depth_m).all() and (out.depth_m >= 0).all(), field[0]


SCENE_EDITS = {
    "type_list": ("- type: box", "- type: [box]", "objects[1].type"),
    "type_mapping": ("- type: box", "- type: {box: 1}", "objects[1].type"),
    "light_type_list": ("- type: ambient", "- type: [ambient]", "lights[0].type"),
    "seed_huge_int": ("seed: 7}", "seed: 100000000000000000000000}", "64 bits"),
    "seed_float": ("seed: 7}", "seed: 1e23}", "seed"),
    "octaves_huge": ("octaves: 3,", "octaves: 100000000000000000000000,", "64 bits"),
}


@pytest.mark.parametrize("name", sorted(SCENE_EDITS))
def test_scene_file_of_the_wrong_shape_names_the_key(tmp_path, cli_error, name):
    old, new, key = SCENE_EDITS[name]
    showcase = (Path(__file__).parents[2] / "sim" / "scenes" / "showcase.yaml").read_text()
    assert old in showcase
    scene = write_file(tmp_path, "s.yaml", showcase.replace(old, new, 1))
    argv = ["sim", "render", "--scene", scene, "--views", "1", "--out", tmp_path / "out", "--allow-outside-paths"]
    cli_error([*argv, "--width", "32", "--height", "24"], key, seconds=60)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("intensity", [0.0, 1.0, 100.0])
def test_the_brightest_allowed_lights_render_without_nan(scene_dir, intensity):
    import warnings

    folder, write = scene_dir

    def bright(d):
        for light in d["lights"]:
            light["intensity"] = intensity
        d["objects"][0]["material"]["emission"] = intensity

    scene = load_scene(write(bright))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a NaN cast to uint8 warns
        out = render(scene, scene.rig.kinematics().forward(0.0, 0.0), scene.rig.intrinsics())
    assert out.rgb.dtype == np.uint8 and out.rgb.max() <= 255
