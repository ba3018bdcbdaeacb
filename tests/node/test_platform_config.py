"""The planner's one ``platform:`` mapping: typed, checked, and the older keys refused with the rewrite."""

from __future__ import annotations

import math
from importlib.resources import files

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.config import ConfigError, from_dict, load_yaml
from aes_planner.geometry.rig import PanTiltConfig
from aes_planner.node.planner import PlannerNode
from aes_planner.node.planner_config import PlannerConfig
from aes_planner.platform import DroneBox, DronePlatformConfig, RigPlatformConfig, parse_platform


def planner(data: dict) -> PlannerConfig:
    return from_dict(PlannerConfig, data, "planner")


def test_a_rig_reads_its_kinematics_and_limits():
    c = planner({"platform": {"type": "rig", "base_xyz_m": [0, 0, 1.3], "pan_limits_deg": [-90, 90]}})
    assert isinstance(c.platform, RigPlatformConfig)
    assert c.rig.base_xyz_m == (0.0, 0.0, 1.3) and c.rig.pan_limits_deg == (-90.0, 90.0)
    assert c.drone is None


def test_a_drone_reads_its_box():
    c = planner({"platform": {"type": "drone", "box": {"bounds_min_m": [0, 0, 0.3], "bounds_max_m": [2, 2, 1.5]}}})
    assert c.drone == DroneBox((0.0, 0.0, 0.3), (2.0, 2.0, 1.5))
    assert c.rig is None


def test_the_type_alone_leaves_the_platform_to_the_scene():
    assert planner({"platform": {"type": "rig"}}).platform == RigPlatformConfig(None)
    assert planner({"platform": {"type": "drone"}}).platform == DronePlatformConfig(None)
    assert planner({}).platform is None


@pytest.mark.parametrize(
    ("data", "key", "words"),
    [
        ({"platform": {"type": "boat"}}, "planner.platform.type", "drone, rig"),
        ({"platform": {"pan_limits_deg": [1, 2]}}, "planner.platform.type", "missing"),
        ({"platform": {"type": "rig", "pan_limit_deg": [1, 2]}}, "planner.platform.pan_limit_deg", "unknown key"),
        ({"platform": {"type": "drone", "bounds_min_m": [0, 0, 0]}}, "planner.platform.bounds_min_m", "box"),
        ({"platform": {"type": "rig", "pan_limits_deg": [10, -10]}}, "planner.platform", ""),
        ({"platform": {"type": "handheld"}}, "planner.platform.type", "aes-planner suggest"),
        ({"platform": "rig"}, "planner.platform", "'type' key"),
    ],
)
def test_a_wrong_platform_names_the_key(data, key, words):
    with pytest.raises(ConfigError) as err:
        planner(data)
    assert err.value.key.startswith(key), err.value
    assert words in err.value.message


@pytest.mark.parametrize(
    ("old", "rewrite"),
    [
        ({"rig": {"pan_limits_deg": [-90, 90]}}, "platform: {type: rig"),
        ({"drone": {"bounds_min_m": [0, 0, 0], "bounds_max_m": [1, 1, 1]}}, "platform: {type: drone, box:"),
        ({"mode": "drone"}, "platform: {type: drone}"),
        ({"mode": "free"}, "platform: {type: drone}"),
    ],
)
def test_an_old_style_key_says_how_to_rewrite_it(old, rewrite):
    (word,) = old
    with pytest.raises(ConfigError) as err:
        planner({"scorer": "field", **old})
    assert err.value.key == f"planner.{word}"
    assert rewrite in err.value.message and "docs/decisions.md" in err.value.message


def test_a_typed_config_passes_through():
    rig = RigPlatformConfig(PanTiltConfig())
    assert parse_platform(rig) is rig
    assert PlannerConfig(platform=rig).rig == PanTiltConfig()


@pytest.mark.parametrize("name", ["pan_tilt_rig.yaml", "ros2_rig.yaml", "drone.yaml", "drone_mavlink.yaml"])
def test_every_shipped_launch_file_reads_its_platform(name):
    data = load_yaml(files("aes_planner.launch") / name)
    (node,) = [n for n in data["nodes"] if n["type"] == "planner"]
    c = planner(node["config"])
    assert c.platform is not None
    if "rig" in name:  # the anchor: the planner's rig is the camera node's
        (other,) = [n for n in data["nodes"] if n["type"] != "planner" and "rig" in n["config"]]
        assert c.rig == from_dict(PanTiltConfig, other["config"]["rig"])
    else:
        assert c.platform == DronePlatformConfig(None)


def test_a_drone_on_a_rig_scene_flies_the_box_around_the_rigs_base():
    from aes_planner.graph.base import LaunchContext

    ctx = LaunchContext(scene="indoor:3")
    rig_node = PlannerNode(PlannerConfig(), context=ctx)
    drone_node = PlannerNode(PlannerConfig(platform=DronePlatformConfig()), context=ctx)
    assert rig_node.kind == "rig" and rig_node.config.rig is not None
    assert drone_node.kind == "drone" and drone_node.config.drone is not None
    base = rig_node.config.rig.base_xyz_m
    assert bool(drone_node.config.drone.contains(base)) or drone_node.config.drone.bounds_min_m[2] > base[2]


_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8)
)
_values = st.recursive(
    _scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None)
@given(
    word=st.sampled_from(["rig", "drone", "handheld", "free", "", 3]),
    extra=st.dictionaries(
        st.sampled_from(["box", "pan_limits_deg", "tilt_limits_deg", "base_xyz_m", "camera_latency_s", "x"]),
        _values,
        max_size=3,
    ),
)
def test_any_platform_mapping_is_a_typed_platform_or_an_error_naming_platform(word, extra):
    try:
        c = planner({"platform": {"type": word, **extra}})
    except ConfigError as exc:
        assert exc.key.startswith("planner.platform"), exc
        return
    assert isinstance(c.platform, (RigPlatformConfig, DronePlatformConfig))
    box = c.drone
    if box is not None:  # a box that passed is finite and has room to fly
        assert all(math.isfinite(v) for v in (*box.bounds_min_m, *box.bounds_max_m))
        assert all(hi > lo for lo, hi in zip(box.bounds_min_m, box.bounds_max_m))
