"""The simulated closed loop on the simulated clock: the multi-process run (gimbal and camera in
their own processes over Zenoh, beside two busy processes) equals the in-process one to the view,
the score and the simulated second; ``--clock wall`` still runs in real time; the recording says
which clock ran."""

import contextlib
import subprocess
import sys

import pytest

from aes_planner.graph import Launch, build_nodes, load_launch
from aes_planner.graph.runner import run_graph
from aes_planner.graph.supervisor import Supervisor
from aes_planner.transport.record import read_recording, recording_metadata
from tests.transport.conftest import free_port

# a short loop: the start, two exploration views, one move, the settle
SHORT = [
    "scene=tabletop:1",
    "camera.rate_hz=10",
    "planner.explore_views=2",
    "planner.max_moves=1",
    "planner.polish_captures=0",
    "planner.scorer=rgb",
    "planner.preset=fast",
    "planner.seed=0",
]


@contextlib.contextmanager
def busy_processes(n: int = 2):
    """``n`` processes that spin on a core each: a loaded machine."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def figures(planner) -> dict:
    """What a run is judged by: every capture (where, what it scored, when on the graph's clock),
    every suggestion, the loop's end."""
    return {
        "captures": [(c.kind, c.pan_rad, c.tilt_rad, c.score, c.stamp_s) for c in planner.captures],
        "suggestions": [
            (s.stamp_s, s.kind, [(cd.score, cd.cam2world.round(12).tolist()) for cd in s.candidates])
            for s in planner.suggestions
        ],
        "state": planner.state.value,
        "moves": planner.moves,
        "finished_s": planner.finished_s,
    }


def run_in_process(sets):
    spec = load_launch("sim_closed_loop", sets)
    nodes = build_nodes(spec)
    planner = next(n for n, _ in nodes if n.node_id == "planner")
    ok, _ = run_graph(Launch(nodes, clock=spec.clock), timeout_s=600)
    assert ok, planner.state
    return figures(planner)


def run_processes(sets):
    """The demo's layout: the planner here, the gimbal and the camera each in a process."""
    spec = load_launch("sim_closed_loop", sets)
    local = [(n, r) for n, r in build_nodes(spec) if n.node_id == "planner"]
    sup = Supervisor(
        "sim_closed_loop", sets, endpoint=f"tcp/127.0.0.1:{free_port()}", local_nodes=local, out=open("/dev/null", "w")
    )
    ok, _ = run_graph(sup, timeout_s=600)
    assert ok, (local[0][0].state, sup.events)
    return figures(local[0][0])


def test_a_multi_process_run_beside_busy_processes_equals_the_in_process_runs():
    """Two in-process runs (idle, then beside two busy processes) and a multi-process one (beside
    them too) give the same captures at the same simulated times: the emulated servos, in their
    own process, take each move at the tick that sent it however late they get the CPU."""
    alone = run_in_process(SHORT)
    assert alone["state"] == "done" and alone["moves"] == 1
    assert [c[0] for c in alone["captures"]] == ["initial", "explore", "explore", "move", "settle"]
    with busy_processes(2):
        again = run_in_process(SHORT)
        spread = run_processes(SHORT)
    assert again == alone
    assert spread == alone


@pytest.mark.slow
def test_the_demo_gives_the_same_summary_in_one_process_and_in_several_under_load(tmp_path):
    import argparse
    import json

    from aes_planner.cli.demo import run_demo

    def demo(out, processes):
        flags = argparse.Namespace(
            processes=processes,
            listen=f"tcp/127.0.0.1:{free_port()}",
            connect=[],
            allow_remote=False,
            foxglove=None,
            record=None,
        )
        run_demo("indoor:3", "rig", out, transport=flags, progress=lambda *_: None)
        return json.loads((out / "summary.json").read_text())

    def captures(out):
        return json.loads((out / "captures.json").read_text())

    alone = demo(tmp_path / "alone", False)
    with busy_processes(2):
        again = demo(tmp_path / "again", False)
        spread = demo(tmp_path / "spread", True)
    assert alone["clock"] == spread["clock"] == "sim"
    wall = ("time_s", "loop_s")  # wall-clock seconds: the only figures allowed to differ
    for other in (again, spread):
        assert {k: v for k, v in other.items() if k not in wall} == {k: v for k, v in alone.items() if k not in wall}
    assert captures(tmp_path / "again") == captures(tmp_path / "alone") == captures(tmp_path / "spread")


@pytest.mark.parametrize("clock", ["wall", "sim"])
def test_launch_runs_on_the_clock_asked_for_and_the_recording_says_which(tmp_path, clock, capsys):
    from aes_planner.cli import main

    rec = tmp_path / "run.mcap"
    sets = [x for s in SHORT if "max_moves" not in s for x in ("--set", s)]
    code = main(
        ["launch", "sim_closed_loop", "--clock", clock, *sets, "--set", "planner.max_moves=0", "--record", str(rec)]
    )
    assert code == 0, capsys.readouterr()
    assert "planner: done after 0 moves" in capsys.readouterr().out
    assert recording_metadata(rec)["run"]["clock"] == clock
    topics = {t for t, _, _ in read_recording(rec)}
    assert {"camera/frame", "gimbal/state", "gimbal/command"} <= topics
    assert ("clock" in topics) == (clock == "sim") and ("clock/ack" in topics) == (clock == "sim")


def test_a_real_gimbal_cannot_run_on_a_simulated_clock(capsys):
    from aes_planner.cli import main

    assert main(["launch", "pan_tilt_rig", "--clock", "sim", "--timeout", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "drives a real gimbal" in err[0] and "--clock wall" in err[0]
