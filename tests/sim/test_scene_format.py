"""The YAML scene format: hand-written scenes load, errors name the key, YAML round trips."""

import copy
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import yaml

from aes_planner.config import ConfigError, from_dict
from aes_planner.sim import SceneError, SceneSpec, load_scene, render, save_scene, scene_to_yaml
from aes_planner.sim.spec import OBJECT_TYPES, PATTERN_KINDS, spec_to_dict

SCENES = Path(str(resources.files("aes_planner.sim") / "scenes"))
SHOWCASE = SCENES / "showcase.yaml"


def showcase_data() -> dict:
    return yaml.safe_load(SHOWCASE.read_text())


def test_showcase_uses_every_primitive_pattern_and_an_image():
    scene = load_scene(SHOWCASE)
    kinds = {type(o).type for o in scene.objects}
    patterns = {o.material.pattern.kind for o in scene.objects if o.material.pattern}
    assert kinds == set(OBJECT_TYPES)
    assert patterns == set(PATTERN_KINDS)
    textured = [i for i, o in enumerate(scene.objects) if o.material.image]
    assert textured and type(scene.objects[textured[0]]).type == "quad"
    assert scene.textures[textured[0]].shape == (32, 48, 3)
    assert {type(light).type for light in scene.lights} == {"ambient", "directional"}
    assert scene.rig is not None and scene.drone is None


def test_every_shipped_scene_renders_and_shows_its_objects():
    for path in sorted(SCENES.glob("*.yaml")):
        scene = load_scene(path)
        cam = scene.rig or scene.drone
        out = render(scene, _overview_pose(scene), cam.intrinsics())
        assert out.rgb.shape == (cam.camera.height, cam.camera.width, 3)
        assert len(np.unique(out.instance_id)) >= 4, path.name


def _overview_pose(scene):
    if scene.rig is not None:
        return scene.rig.kinematics().forward(0.0, -0.2)
    from aes_planner.geometry import look_at

    lo, hi = np.array(scene.drone.bounds_min_m), np.array(scene.drone.bounds_max_m)
    return look_at(np.array([lo[0], (lo[1] + hi[1]) / 2, hi[2]]), np.array([hi[0], (lo[1] + hi[1]) / 2, 0.0]))


@pytest.mark.parametrize(
    "edit, key, message",
    [
        (
            lambda d: d["objects"][3]["material"].update(pattern={"kind": "dots"}),
            "objects[3].material.pattern.kind",
            "must be one of",
        ),
        (lambda d: d["objects"][1].update(colour=[1, 0, 0]), "objects[1].colour", "unknown key"),
        (lambda d: d["objects"][1].update(type="cone"), "objects[1].type", "must be one of"),
        (lambda d: d["objects"][1].update(size_m=[1, -1, 1]), "objects[1].size_m", "> 0"),
        (lambda d: d["objects"][1].update(rpy_deg=[0, 0, 1]), "objects[1].rpy_deg", "not both"),
        (lambda d: d["objects"][2]["material"].update(albedo=[1.2, 0, 0]), "objects[2].material.albedo", r"\[0, 1\]"),
        (lambda d: d["objects"][2]["material"].update(image="x.png"), "objects[2].material.image", "not both"),
        (lambda d: d["objects"][6]["material"].update(image="missing.png"), "objects[6].material.image", "not found"),
        (lambda d: d["objects"][4].update(axis=[0, 0, 0]), "objects[4].axis", "non-zero"),
        (lambda d: d["objects"][2].update(radius_m="big"), "objects[2].radius_m", "expected a number"),
        (lambda d: d["lights"][1].update(intensity=-1), "lights[1].intensity", "must be within"),
        (lambda d: d["lights"].append({"type": "spot"}), "lights[2].type", "must be one of"),
        (
            lambda d: d["rig"]["pan_tilt"].update(pan_limits_deg=[10, -10]),
            "rig.pan_tilt.pan_limits_deg",
            "min must be below max",
        ),
        (lambda d: d["rig"]["camera"].update(hfov_deg=200), "rig.camera.hfov_deg", r"\(0, 180\)"),
        (lambda d: d["sky"].update(zenit=[0, 0, 1]), "sky.zenit", "unknown key"),
        (lambda d: d.pop("rig"), "rig", "exactly one"),
        (lambda d: d.update(drone={"bounds_min_m": [0, 0, 0], "bounds_max_m": [1, 1, 1]}), "drone", "exactly one"),
    ],
)
def test_bad_scene_names_the_key(tmp_path, edit, key, message):
    data = showcase_data()
    edit(data)
    (tmp_path / "scenes").mkdir()
    (tmp_path / "assets").mkdir()  # the same layout as the package, so ../assets/sunset.png resolves
    (tmp_path / "assets" / "sunset.png").write_bytes((SCENES.parent / "assets" / "sunset.png").read_bytes())
    path = tmp_path / "scenes" / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message) as info:
        load_scene(path)
    assert info.value.key == key
    assert str(info.value).startswith(f"{key}: ")


def test_exact_pattern_kind_message():
    data = showcase_data()
    data["objects"][3]["material"]["pattern"]["kind"] = "dots"
    with pytest.raises(ConfigError) as info:
        from_dict(SceneSpec, data)
    assert (
        str(info.value)
        == "objects[3].material.pattern.kind: must be one of ['checker', 'stripes', 'noise', 'gradient'], got 'dots'"
    )


def test_not_yaml_and_not_a_mapping(tmp_path):
    (tmp_path / "a.yaml").write_text("objects: [\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scene(tmp_path / "a.yaml")
    (tmp_path / "b.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="must hold a mapping"):
        load_scene(tmp_path / "b.yaml")


def test_unknown_family_and_missing_file():
    with pytest.raises(SceneError, match="unknown scene family 'castle'.*indoor"):
        load_scene("castle:3")
    with pytest.raises(SceneError, match="neither a file nor FAMILY:SEED"):
        load_scene("no/such/scene.yaml")


def test_spec_dict_round_trip_is_exact():
    spec = load_scene(SHOWCASE).spec
    again = from_dict(SceneSpec, spec_to_dict(spec))
    assert again == spec
    assert spec_to_dict(again) == spec_to_dict(spec)


def test_camera_roll_is_written_only_when_set():
    """A rig's camera_roll_deg (added after the first scenes) is left out of the text at its
    default, so older scenes' YAML (and the oracle cache keyed by it) does not change; set, it
    round-trips."""
    import dataclasses

    spec = load_scene(SHOWCASE).spec
    assert "camera_roll_deg" not in spec_to_dict(spec)["rig"]["pan_tilt"]
    rolled = dataclasses.replace(spec.rig, pan_tilt=dataclasses.replace(spec.rig.pan_tilt, camera_roll_deg=180.0))
    spec = dataclasses.replace(spec, rig=rolled)
    assert spec_to_dict(spec)["rig"]["pan_tilt"]["camera_roll_deg"] == 180.0
    assert from_dict(SceneSpec, spec_to_dict(spec)) == spec


def test_yaml_round_trip_renders_the_same(tmp_path):
    scene = load_scene(SHOWCASE)
    path = save_scene(scene, tmp_path / "sub" / "copy.yaml")
    back = load_scene(path)
    picture = scene.objects[6].material.image
    assert back.image_path(back.objects[6].material.image) == scene.image_path(
        picture
    )  # same file, found from the new place
    pose = scene.rig.kinematics().forward(-0.14, -0.2)
    a, b = render(scene, pose, scene.intrinsics()), render(back, pose, back.intrinsics())
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth_m, b.depth_m)
    assert np.array_equal(a.instance_id, b.instance_id)
    assert back.spec.objects[6].material.image != scene.spec.objects[6].material.image  # it moved
    # absolute image paths when no destination is given
    assert str(SCENES.parent.resolve() / "assets" / "sunset.png") in scene_to_yaml(scene)


def test_defaults_fill_in_lights_and_objects_may_be_typed_specs():
    data = {"rig": {}, "objects": [{"type": "sphere", "centre_m": [3, 0, 1], "radius_m": 0.5}]}
    spec = from_dict(SceneSpec, data)
    assert [type(light).type for light in spec.lights] == ["ambient", "directional"]
    again = SceneSpec(objects=copy.deepcopy(spec.objects), rig=spec.rig)
    assert again == spec
    assert from_dict(SceneSpec, {**data, "lights": []}).lights == []


def test_the_readme_example_is_the_showcase():
    readme = (SCENES.parent / "README.md").read_text()
    block = readme.split("```yaml\n", 1)[1].split("```", 1)[0]
    assert from_dict(SceneSpec, yaml.safe_load(block)) == from_dict(SceneSpec, showcase_data())
    drone = readme.split("```yaml\n", 2)[2].split("```", 1)[0]
    spec = from_dict(SceneSpec, {**yaml.safe_load(drone), "objects": []})
    assert spec.drone.contains([0, 0, 10]) and spec.rig is None
