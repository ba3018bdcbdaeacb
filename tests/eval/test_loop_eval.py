"""``eval loop``: perturbation specs, scene specs, the summary's spread and the report (no loop run here:
the closed loop itself is tested in tests/node and by ``make demo``)."""

from __future__ import annotations

import pytest

from aes_planner.config import ConfigError
from aes_planner.eval.loop import (
    DEV_LOOP_SCENES,
    HELD_OUT_LOOP_SCENES,
    LoopEvalConfig,
    markdown,
    parse_perturbation,
    split_scene,
    summarise,
)
from aes_planner.sim import load_scene


def test_perturbations_parse_and_combine():
    p = parse_perturbation("torch+threads:1+noise:1e-6+seed:2")
    assert (p.backend, p.threads, p.noise_rel, p.seed) == ("torch", 1, 1e-6, 2)
    assert parse_perturbation("base") == parse_perturbation("base")
    assert parse_perturbation("base").backend is None


@pytest.mark.parametrize("bad", ["fast", "threads:0", "threads:x", "noise:1", "noise:nan", "seed:-1", "torch:1"])
def test_bad_perturbations_name_the_flag(bad):
    with pytest.raises(ConfigError, match="--perturb"):
        parse_perturbation(bad)


def test_scene_specs_carry_the_platform():
    assert split_scene("indoor:3@drone") == ("indoor:3", "drone")
    assert split_scene("indoor:3") == ("indoor:3", None)
    with pytest.raises(ConfigError, match="rig or drone"):
        split_scene("indoor:3@boat")
    with pytest.raises(ConfigError, match="scene"):
        LoopEvalConfig(scenes=[])


def test_held_out_and_dev_sets_load_and_do_not_overlap():
    held = {split_scene(s)[0] for s in HELD_OUT_LOOP_SCENES}
    dev = {split_scene(s)[0] for s in DEV_LOOP_SCENES}
    assert not held & dev
    seeds = {int(s.split(":")[1]) for s in held | dev if ":" in s and "/" not in s}
    assert all(200 <= s < 400 for s in seeds)  # none of the field's (0.., 100.., 500.., >= 1000) seeds
    for s in sorted(held | dev):
        if "/" in s:  # the files (the procedural ones load as fast, but are many)
            assert load_scene(s).spec.objects


def _run(norm, moves=2):
    return {"state": "done", "normalized": norm, "moves": moves}


def test_summary_reports_spread_worst_and_moves():
    runs = {
        "a|base": _run(0.95),
        "a|torch": _run(0.80, 5),
        "b|base": _run(1.0),
        "b|torch": {"state": "error", "error": "boom"},
    }
    s = summarise(runs, ["a", "b"], ["base", "torch"])
    assert s["per_scene"]["a"]["spread"] == pytest.approx(0.15)
    assert s["per_scene"]["b"]["n"] == 1
    assert s["min"] == pytest.approx(0.80)
    assert s["runs_below_0_9"] == 1
    assert s["max_moves"] == 5
    assert s["errors"] == 1
    text = markdown({"runs": runs, "moves": 4}, ["a", "b"], ["base", "torch"])
    assert "| a | 0.950 (2) | 0.800 (5) | 0.875 | 0.800 | 0.150 |" in text
    assert "| b | 1.000 (2) | error |" in text


def test_every_run_starts_without_the_previous_runs_teacher_maps(tmp_path):
    """The field's teacher maps are cached per process by image content: a noise run's noisy maps
    of the views every run of the scene shares (initial, exploration) changed the path of the next
    run in the same process. Each run starts with the cache empty."""
    import numpy as np
    import torch

    from aes_planner.eval.loop import run_one
    from aes_planner.field import model as field_model

    seen = []

    def fake_demo(scene, mode, out, moves, overrides, timeout_s, planner_overrides=None, hook=None):
        seen.append(len(field_model._feature_cache))
        out.mkdir(parents=True, exist_ok=True)
        (out / "captures.json").write_text("[]")
        return {"state": "done", "normalized": 1.0, "moves": 0}

    field_model._feature_cache[("t", (1,), np.zeros(1, np.uint8).tobytes())] = torch.zeros(1)
    for p in ("noise:1e-6", "seed:1"):
        row = run_one(fake_demo, "indoor:200", parse_perturbation(p), 4, tmp_path / p)
        field_model._feature_cache[("t", (2,), p.encode())] = torch.zeros(1)  # what a run leaves
        assert row["normalized"] == 1.0
    assert seen == [0, 0]


def test_a_noise_run_draws_its_noise_by_pose_for_rig_and_drone(tmp_path):
    """The camera's noise of a noise run is keyed by the view, not drawn one per rendered frame
    (how many frames come before a capture differs between processes); and the overrides load."""
    from aes_planner.eval.loop import run_one
    from aes_planner.graph.launch_file import load_launch

    got = {}

    def fake_demo(scene, mode, out, moves, overrides, timeout_s, planner_overrides=None, hook=None):
        got[mode] = list(overrides)
        out.mkdir(parents=True, exist_ok=True)
        (out / "captures.json").write_text("[]")
        return {"state": "done", "normalized": 1.0, "moves": 0}

    run_one(fake_demo, "indoor:200", parse_perturbation("noise:1e-6"), 4, tmp_path / "rig")
    run_one(fake_demo, "indoor:200@drone", parse_perturbation("noise:1e-6"), 4, tmp_path / "drone")
    assert "camera.camera.noise_by_pose=true" in got[None] or "camera.camera.noise_by_pose=true" in got["rig"]
    assert "drone.camera.noise_by_pose=true" in got["drone"]
    spec = load_launch("sim_closed_loop.yaml", ["scene=indoor:200", *next(v for k, v in got.items() if k != "drone")])
    cam = next(n for n in spec.nodes if n.id == "camera")
    assert cam.config["camera"]["noise_by_pose"] is True
    from aes_planner.config import from_dict
    from aes_planner.node.sim_camera import SimCameraNodeConfig

    assert from_dict(SimCameraNodeConfig, cam.config, "camera")._camera.noise_by_pose is True


def test_a_noise_run_of_a_drone_scene_file_sets_the_drones_camera(tmp_path):
    """A scene file whose platform is a drone box (no @drone: the hand-written ``*_drone.yaml``)
    runs ``drone.yaml``, whose camera is the node ``drone``: its noise overrides go there (they
    went to ``camera``, a node that launch has not, and every noise run of such a scene failed)."""
    from pathlib import Path

    from aes_planner.eval.loop import run_one

    got = {}

    def fake_demo(scene, mode, out, moves, overrides, timeout_s, planner_overrides=None, hook=None):
        got[scene] = list(overrides)
        out.mkdir(parents=True, exist_ok=True)
        (out / "captures.json").write_text("[]")
        return {"state": "done", "normalized": 1.0, "moves": 0}

    drone = str(Path(__file__).resolve().parents[1] / "scenes" / "garden_drone.yaml")
    run_one(fake_demo, drone, parse_perturbation("noise:1e-6"), 4, tmp_path / "drone")
    run_one(fake_demo, "indoor:200", parse_perturbation("noise:1e-6"), 4, tmp_path / "rig")
    assert "drone.camera.noise_by_pose=true" in got[drone]
    assert not any(o.startswith("camera.") for o in got[drone])
    assert "camera.camera.noise_by_pose=true" in got["indoor:200"]
