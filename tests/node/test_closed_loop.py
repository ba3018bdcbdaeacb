"""The simulated closed loop end to end (sim camera, the real Dynamixel driver on the emulator's
pty, the planner with RGB scoring and the search): the final captured view beats the initial
one and reaches >= 0.7 of the oracle (oracle-normalised, true teacher scores of ground-truth
renders). Seeded, small images, few moves."""

import json
from pathlib import Path

from aes_planner.cli.demo import run_demo


def test_short_closed_loop_improves_the_view(tmp_path):
    out = tmp_path / "run"
    summary = run_demo(
        "tabletop:1",
        "rig",
        out,
        moves=3,
        overrides=["camera.rate_hz=10"],
        timeout_s=600,
        planner_overrides={"preset": "fast", "explore_views": 8, "scorer": "rgb", "seed": 0},
    )
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["final"] == summary["final"]
    for key in (
        "initial",
        "final",
        "oracle",
        "normalized",
        "moves",
        "polish_captures",
        "time_s",
        "scene",
        "mode",
        "initial_cam2world",
        "final_cam2world",
        "final_pan_deg",
        "final_tilt_deg",
        "clock",
        "sim_time_s",
    ):
        assert key in on_disk, key
    assert on_disk["clock"] == "sim"  # the demo's default: the same views whatever the load
    assert (out / "report.png").stat().st_size > 1000 and (out / "suggestions.json").is_file()
    assert summary["state"] == "done" and summary["moves"] <= 3
    assert summary["final"] > summary["initial"]
    assert summary["normalized"] >= 0.7, summary
    assert len(on_disk["final_cam2world"]) == 4 and len(on_disk["final_cam2world"][0]) == 4


def test_demo_cli_rejects_a_bad_scene_in_one_line(tmp_path, capsys):
    from aes_planner.cli import main

    assert main(["demo", "--scene", "nowhere:3", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0]


def test_demo_cli_takes_its_mode_from_the_scene(tmp_path, capsys):
    from aes_planner.cli import main

    drone_scene = str(Path(__file__).parents[1] / "scenes" / "yard_drone.yaml")
    assert main(["demo", "--scene", drone_scene, "--mode", "rig", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--mode drone" in err[0]
