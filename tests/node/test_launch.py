"""Launch files: the shipped ones load, unknown keys are errors naming them, --set overrides."""

import pytest

from aes_planner.config import ConfigError
from aes_planner.graph import build_nodes, load_launch
from aes_planner.graph.launch_file import apply_overrides, parse_launch


@pytest.mark.parametrize("name", ["sim_closed_loop", "pan_tilt_rig", "drone"])
def test_shipped_launch_files_parse(name):
    spec = load_launch(name)
    assert {e.id for e in spec.nodes} >= {"planner"}


def test_sim_closed_loop_builds_its_nodes():
    nodes = build_nodes(load_launch("sim_closed_loop", ["scene=tabletop:1"]))
    assert [n.node_id for n, _ in nodes] == ["gimbal", "camera", "planner"]
    planner = nodes[-1][0]
    assert planner.kind == "rig" and planner.config.rig is not None


def test_drone_external_by_default_and_sim_on_request():
    assert [n.node_id for n, _ in build_nodes(load_launch("drone"))] == ["planner"]
    nodes = build_nodes(load_launch("drone", ["drone.type=sim"]))
    assert [type(n).__name__ for n, _ in nodes] == ["SimDroneNode", "PlannerNode"]
    assert nodes[1][0].kind == "drone"


@pytest.mark.parametrize("launch_file, sets", [("sim_closed_loop", []), ("drone", ["drone.type=sim"])])
def test_a_camera_larger_than_a_frame_message_is_refused_when_built(launch_file, sets):
    """It failed on every step instead (a traceback per frame, and a loop that captured nothing)."""
    node = "camera" if launch_file == "sim_closed_loop" else "drone"
    big = [f"{node}.camera.width=9000", f"{node}.camera.height=16", f"{node}.camera.supersample=1"]
    with pytest.raises(ConfigError, match=f"{node}.camera.width: a 9000x16 camera is larger than a camera/frame"):
        build_nodes(load_launch(launch_file, [*sets, *big]))


def test_unknown_keys_are_errors_naming_them():
    base = {"nodes": [{"id": "planner", "type": "planner", "config": {}}]}
    with pytest.raises(ConfigError, match="nodes\\[0\\].config.max_movez"):
        build_nodes(parse_launch(apply_overrides(base, ["planner.max_movez=3"])))
    with pytest.raises(ConfigError, match="nodes\\[0\\].colour"):
        parse_launch({"nodes": [{"id": "p", "type": "planner", "colour": 1}]})
    with pytest.raises(ConfigError, match="launch"):
        parse_launch({"launch": []})
    with pytest.raises(ConfigError, match="type"):
        parse_launch({"nodes": [{"id": "p", "type": "teleporter"}]})
    with pytest.raises(ConfigError, match="remap"):
        parse_launch({"nodes": [{"id": "p", "type": "planner", "remap": {"camera/frame": "bad topic!"}}]})
    with pytest.raises(ConfigError, match="duplicate"):
        parse_launch({"nodes": [{"id": "p", "type": "planner"}, {"id": "p", "type": "planner"}]})


def test_overrides_set_nested_keys_and_values_as_yaml():
    spec = load_launch(
        "sim_closed_loop", ["planner.max_moves=2", "gimbal.device.profile_velocity_deg_s=90", "camera.respawn=true"]
    )
    assert spec.entry("planner").config["max_moves"] == 2
    assert spec.entry("gimbal").config["device"]["profile_velocity_deg_s"] == 90
    assert spec.entry("camera").respawn is True
    with pytest.raises(ConfigError, match="nobody"):
        load_launch("sim_closed_loop", ["nobody.x=1"])


def test_launch_cli_reports_bad_files_in_one_line(tmp_path, capsys):
    from aes_planner.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text("nodes:\n  - {id: planner, type: planner, config: {explore_viewz: 2}}\n")
    assert main(["launch", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "explore_viewz" in err[0]
