"""Bad-input sweep of the graph machinery (aes_planner.graph): launch files and ``--set``
overrides, single- and multi-process launches, and the node runner's stop. Every bad launch ends in
one ``error:`` line with exit 2, fast, before any node starts; a key of the wrong shape is named.
"""

import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.errors import AesPlannerError
from tests.helpers import write_file

# --------------------------------------------------------------------------------- launch files
LAUNCH_FILES = {
    "list.yaml": ("- 1\n- 2\n", "is a mapping"),
    "scalar.yaml": ("42\n", "is a mapping"),
    "unicode_id.yaml": ("nodes: [{id: é, type: planner}]\n", "ASCII"),
    "long_id.yaml": ("nodes: [{id: " + "a" * 5000 + ", type: planner}]\n", "64 at most"),
    "bigint.yaml": ("nodes: [{id: p, type: planner, config: {max_moves: " + "9" * 5000 + "}}]\n", "cannot be read"),
    "month13.yaml": ("nodes: [{id: p, type: planner}]\nscene: !!timestamp 2001-13-45\n", "cannot be read"),
}


@pytest.mark.parametrize("name", sorted(LAUNCH_FILES))
def test_launch_file_bad_input(work, cli_error, name):
    text, match = LAUNCH_FILES[name]
    (work / name).write_text(text)
    cli_error(["launch", work / name, "--timeout", "5"], match, seconds=20)


def test_launch_remap_of_a_topic_the_node_does_not_have(work, cli_error):
    (work / "l.yaml").write_text("nodes: [{id: p, type: planner, remap: {no/such/topic: x/y}}]\n")
    cli_error(["launch", work / "l.yaml", "--timeout", "5"], "is not a topic of planner", seconds=30)


SET_CASES = [
    ("planner.max_moves=[1,2", "not valid YAML"),
    ("planner.max_moves=!!python/object/apply:os.system ['true']", "constructor"),
    ("planner.max_moves=" + "9" * 5000, "cannot be read"),
    ("planner.max_moves=&a [*a, *a]", "max_moves"),
]


@pytest.mark.parametrize("item, match", SET_CASES, ids=range(len(SET_CASES)))
def test_launch_set_bad_values(cli_error, item, match):
    cli_error(["launch", "sim_closed_loop", "--set", item, "--timeout", "5"], match, seconds=30)


@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
def test_launch_and_demo_timeout_must_be_finite_and_positive(work, cli_error, value):
    cli_error(["launch", "sim_closed_loop", "--timeout", value], "--timeout", seconds=10)
    cli_error(["demo", "--timeout", value, "--out", work / "run"], "--timeout", seconds=10)
    assert not (work / "run").exists()


@given(st.text(max_size=40))
def test_set_values_never_crash_the_launch_parser(text):
    from aes_planner.graph.launch_file import apply_overrides, parse_launch

    data = {"nodes": [{"id": "planner", "type": "planner"}]}
    try:
        parse_launch(apply_overrides(data, [f"planner.max_moves={text}", f"scene={text}"]))
    except AesPlannerError as exc:
        assert "\n" not in str(exc).strip() and len(str(exc)) < 1200


def test_alias_bomb_message_is_said_once(work, cli_error):
    lines = ['a: &a ["x","x","x","x","x","x","x","x","x"]']
    lines += [f"{c}: &{c} [{', '.join(['*' + p] * 9)}]" for p, c in zip("abcdefgh", "bcdefghi")]
    (work / "bomb.yaml").write_text("\n".join(lines) + "\nnodes: [{id: p, type: planner}]\n")
    line = cli_error(["launch", work / "bomb.yaml"], "expands to more than")
    assert "cannot be read" not in line


# -------------------------------------------------------------- launch files of the wrong shape
SHAPES = {
    "type_list": ("nodes: [{id: p, type: [planner]}]\n", "nodes[0].type"),
    "type_mapping": ("nodes: [{id: p, type: {a: 1}}]\n", "nodes[0].type"),
    "type_missing": ("nodes: [{id: p}]\n", "nodes[0].type"),
    "id_list": ("nodes: [{id: [p], type: planner}]\n", "nodes[0].id"),
    "config_list": ("nodes: [{id: p, type: planner, config: [1]}]\n", "nodes[0].config"),
    "config_int_key": ("nodes: [{id: p, type: planner, config: {1: 2}}]\n", "nodes[0].config"),
    "remap_int": ("nodes: [{id: p, type: planner, remap: {a/b: 3}}]\n", "nodes[0].remap"),
    "respawn_str": ("nodes: [{id: p, type: planner, respawn: yes please}]\n", "nodes[0].respawn"),
    "nodes_mapping": ("nodes: {p: 1}\n", "nodes"),
    "nodes_ints": ("nodes: [1, 2]\n", "nodes[0]"),
    "nodes_string": ("nodes: abc\n", "nodes"),
    "only_external": ("nodes: [{id: fc, type: external}]\n", "external"),
    "huge_int": ("nodes: [{id: p, type: planner, config: {max_moves: 100000000000000000000000}}]\n", "64 bits"),
}


@pytest.mark.parametrize("name", sorted(SHAPES))
@pytest.mark.parametrize("with_set", [False, True], ids=["plain", "set"])
def test_launch_file_of_the_wrong_shape_names_the_key(tmp_path, cli_error, name, with_set):
    text, key = SHAPES[name]
    launch = write_file(tmp_path, "l.yaml", text)
    extra = ["--set", "p.settle_s=0.5"] if with_set and name != "only_external" else []
    line = cli_error(["launch", launch, *extra, "--timeout", "3"], key, seconds=30)
    assert "unhashable" not in line and "has no attribute" not in line


# ----------------------------------------------------------------------- multi-process launches
PROCESS_LAUNCHES = {
    "remap.yaml": ("nodes: [{id: p, type: planner, remap: {no/such/topic: x/y}}]\n", "is not a topic of planner"),
    "noscene.yaml": ("nodes: [{id: c, type: sim_camera}]\n", "needs a scene"),
    "badscene.yaml": ("scene: nowhere:1\nnodes: [{id: c, type: sim_camera}]\n", "unknown scene family"),
}


@pytest.mark.parametrize("name", sorted(PROCESS_LAUNCHES))
def test_multi_process_launch_checks_what_the_children_would_die_of(work, cli_error, name):
    text, match = PROCESS_LAUNCHES[name]
    (work / name).write_text(text)
    cli_error(["launch", work / name, "--processes", "--timeout", "5"], match, seconds=30)


def test_multi_process_launch_needs_a_fixed_hub_port(cli_error):
    cli_error(["launch", "sim_closed_loop", "--processes", "--listen", "tcp/127.0.0.1:0"], "fixed port", seconds=30)


def test_only_external_nodes_refused_by_a_multi_process_launch_too(tmp_path, cli_error):
    launch = write_file(tmp_path, "l.yaml", "nodes: [{id: fc, type: external}, {id: fc2, type: external}]\n")
    cli_error(["launch", launch, "--processes", "--timeout", "3"], "would start nothing", seconds=30)


# ---------------------------------------------------------------------------------- node runner


def test_a_node_with_a_very_long_period_still_stops_promptly():
    from aes_planner.graph.base import Node
    from aes_planner.graph.runner import NodeRunner
    from aes_planner.messages import Diagnostics
    from aes_planner.transport import InProcessBus

    class Slow(Node):
        config_class = dict
        inputs = {"x/in": (Diagnostics, 1)}

        @property
        def period_s(self):
            return 1e9

        def step(self, inputs, now):
            return {}

    bus = InProcessBus()
    runner = NodeRunner(Slow({}, "slow"), bus)
    runner.open()
    runner.start_thread()
    time.sleep(0.2)
    t0 = time.monotonic()
    runner.request_stop()
    runner.join(5.0)
    assert time.monotonic() - t0 < 1.0 and not runner._thread.is_alive()
    runner.close()
    bus.close()
