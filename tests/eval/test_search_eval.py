"""``eval search`` on one tiny scene with the ground-truth methods only (no scorer to build)."""

from pathlib import Path

import numpy as np
import pytest
import torch

from aes_planner.cli import main
from aes_planner.eval.search import SearchEvalConfig, markdown, run_search_eval

GT_METHODS = ["best_input", "inplane", "rotation", "random", "oracle"]


def tiny(tmp_path, **kw) -> SearchEvalConfig:
    base = dict(
        scenes=["tabletop:102"], views=[2], modes=["rig", "free"], methods=GT_METHODS, oracle_step_deg=30.0,
        random_samples=6, local_grid=3, oracle_free_positions=(1, 1, 1), oracle_free_step_deg=90.0,
        oracle_min_step_deg=45.0, oracle_refine_starts=1, width=32, height=24, ablations=False, cache_dir=str(tmp_path / "cache"),
    )  # fmt: skip
    return SearchEvalConfig(**{**base, **kw})


def test_eval_search_tables_and_normalisation(tmp_path):
    doc = run_search_eval(tiny(tmp_path), out_dir=tmp_path / "out")
    for mode in ("rig", "drone"):
        table = doc["views"]["2"][mode]
        assert set(table) == set(GT_METHODS)
        assert table["oracle"]["normalized"] == pytest.approx(1.0)
        assert table["random"]["normalized"] == pytest.approx(0.0, abs=1e-9)
        # the rotation grid includes each input itself, so it is never worse than the best input
        assert table["rotation"]["teacher"] >= table["best_input"]["teacher"] - 1e-9
        for v in table.values():
            assert set(v) >= {"teacher", "evaluator", "normalized"}
            assert v["normalized_se"] is None  # one scene: no spread to estimate
            assert "vs_field_balanced" not in v  # the reference did not run
    assert doc["scenes"] == ["tabletop:102"]
    assert (tmp_path / "out" / "search_eval.md").read_text().startswith("# Search evaluation")
    assert (tmp_path / "out" / "top_view_tabletop_102.png").is_file() is False  # needs a learned scorer


def _row(scene: str, **normalized: float) -> dict:
    methods = {m: {"teacher": x, "evaluator": x, "normalized": x} for m, x in normalized.items()}
    return {"scene": scene, "mode": "rig", "views": 4, "oracle": 0.8, "methods": methods, "latency_ms": {}}


def test_spread_and_paired_differences_against_balanced():
    """Every mean comes with its standard error over scenes, and every method with its paired
    difference from field_balanced on the scenes both ran: mean, standard error, and the count
    better / the same (within SAME_TOL) / worse."""
    from aes_planner.eval.search import SAME_TOL, _aggregate, paired_difference, standard_error

    assert standard_error([0.5]) is None
    assert standard_error([0.2, 0.4, 0.9]) == pytest.approx(np.std([0.2, 0.4, 0.9], ddof=1) / np.sqrt(3))
    rows = [
        _row("a", field_balanced=0.8, field_fast=0.5, rgb=0.6),
        _row("b", field_balanced=0.6, field_fast=0.6 + SAME_TOL / 2, rgb=0.7),
        _row("c", field_balanced=0.4, field_fast=0.7),  # rgb did not run here: left out of its pairs
    ]
    fast = paired_difference(rows, "field_fast", "field_balanced")
    assert fast["diff"] == pytest.approx(np.mean([-0.3, SAME_TOL / 2, 0.3]))
    assert fast["diff_se"] == pytest.approx(standard_error([-0.3, SAME_TOL / 2, 0.3]))
    assert (fast["better"], fast["same"], fast["worse"]) == (1, 1, 1)
    rgb = paired_difference(rows, "rgb", "field_balanced")
    assert rgb["diff"] == pytest.approx(-0.05) and (rgb["better"], rgb["same"], rgb["worse"]) == (1, 0, 1)
    assert paired_difference(rows, "oracle", "field_balanced") is None

    cfg = SearchEvalConfig(
        scenes=["a", "b", "c"], views=[4], modes=["rig"], methods=["field_fast", "field_balanced", "rgb"]
    )
    table = _aggregate(rows, cfg)["views"]["4"]["rig"]
    assert table["field_balanced"]["normalized_se"] == pytest.approx(standard_error([0.8, 0.6, 0.4]))
    assert "vs_field_balanced" not in table["field_balanced"]
    assert table["rgb"]["n"] == 2 and table["rgb"]["vs_field_balanced"] == rgb
    md = markdown(_aggregate(rows, cfg))
    assert "| field_balanced | 0.600 | 0.600 | 0.600 ± 0.115 | reference |" in md
    assert "| rgb | 0.650 | 0.650 | 0.650 ± 0.050 | -0.050 ± 0.150 (1 / 0 / 1) |" in md
    assert "Per scene" not in md  # no per-scene rows in this document
    md = markdown({**_aggregate(rows, cfg), "per_scene": rows})
    assert "| scene | field_fast | field_balanced | rgb | oracle teacher |" in md
    assert "| c | 0.700 | 0.400 |  | 0.800 |" in md  # rgb did not run on scene c


def test_eval_search_config_errors(tmp_path):
    from aes_planner.config import ConfigError

    with pytest.raises(ConfigError, match="methods"):
        tiny(tmp_path, methods=["magic"])
    with pytest.raises(ConfigError, match="modes"):
        tiny(tmp_path, modes=["boat"])


def test_eval_cli_rejects_bad_views(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "search", "--views", "four"])
    assert "comma-separated integers" in capsys.readouterr().err


def test_held_out_scenes_are_none_of_the_fields():
    """The search's held-out scenes are in the evaluation range and past what ``eval field`` uses
    (docs/field.md, seeds): never trained or validated on."""
    from aes_planner.eval.field import default_scenes
    from aes_planner.eval.search import HELD_OUT_SCENES, HELD_OUT_SEED_START
    from aes_planner.field.train import EVAL_SEED_END, EVAL_SEED_START, TRAIN_SEED_START, VAL_SEED_START

    seeds = [int(s.rsplit(":", 1)[1]) for s in HELD_OUT_SCENES]
    assert all(EVAL_SEED_START <= s < EVAL_SEED_END <= VAL_SEED_START < TRAIN_SEED_START for s in seeds)
    assert not set(HELD_OUT_SCENES) & set(default_scenes(4 * HELD_OUT_SEED_START))
    from aes_planner.bench.search import SCENES

    assert set(SCENES) <= set(HELD_OUT_SCENES)


YARD_DRONE = str(Path(__file__).parents[1] / "scenes" / "yard_drone.yaml")


def test_eval_search_on_a_drone_scene_flies_its_own_box(tmp_path):
    """A drone scene (no rig) evaluates in free mode inside the scene's box, from inputs that turn
    around the circle; every judged pose stays inside that box."""
    from aes_planner.eval.search import _drone_inputs, _free_platform, _source
    from aes_planner.geometry.poses import cam2world_to_view
    from aes_planner.sim.scene import load_scene

    cfg = tiny(tmp_path, scenes=[YARD_DRONE], modes=["free"], views=[4])
    source = _source(load_scene(YARD_DRONE), cfg)
    platform = _free_platform(source, cfg.free_box_m)
    assert platform.kind == "drone" and platform.drone.bounds_min_m == (-1.5, -1.5, 0.8)
    views = cam2world_to_view(torch.as_tensor(_drone_inputs(platform, 4))).numpy()  # [4, 5]
    lo, hi = np.asarray(platform.drone.bounds_min_m), np.asarray(platform.drone.bounds_max_m)
    assert np.all((views[:, :3] >= lo) & (views[:, :3] <= hi))
    assert len({round(float(y), 3) for y in views[:, 3]}) == 4  # four different headings

    doc = run_search_eval(cfg)
    table = doc["views"]["4"]["drone"]
    assert table["oracle"]["normalized"] == pytest.approx(1.0)
    assert table["rotation"]["teacher"] >= table["best_input"]["teacher"] - 1e-9


def test_eval_search_rig_mode_on_a_drone_scene_is_refused_before_any_work(tmp_path):
    from aes_planner.eval.search import SearchEvalError

    with pytest.raises(SearchEvalError, match="--modes drone"):
        run_search_eval(tiny(tmp_path, scenes=["tabletop:102", YARD_DRONE], modes=["rig"]))


def test_eval_search_both_modes_over_rig_and_drone_scenes(tmp_path):
    """With both modes (the CLI's default) a drone scene runs in free mode only: the rig table
    holds the rig scene, the free table both, and the ablations (rig mode) skip the drone scene."""
    doc = run_search_eval(tiny(tmp_path, scenes=[YARD_DRONE, "tabletop:102"], methods=["best_input", "oracle"]))
    rows = {(r["scene"], r["mode"]) for r in doc["per_scene"]}
    assert rows == {(YARD_DRONE, "drone"), ("tabletop:102", "rig"), ("tabletop:102", "drone")}
    assert doc["views"]["2"]["rig"]["oracle"]["n"] == 1
    assert doc["views"]["2"]["drone"]["oracle"]["n"] == 2
    md = markdown(doc)
    assert "2 input views, rig (Table 2 analogue, 1 scene)" in md
    assert "2 input views, drone (Table 2 analogue, 2 scenes)" in md

    only_drones = run_search_eval(tiny(tmp_path, scenes=[YARD_DRONE], methods=["oracle"], ablations=True))
    assert set(only_drones["views"]["2"]) == {"drone", "latency_ms"}
    assert only_drones["ablations"] == {}  # rig-mode tables: no rig scene to run them on


@pytest.mark.parametrize("path", sorted((Path(__file__).parents[1] / "scenes").glob("*.yaml")), ids=lambda p: p.stem)
def test_hand_written_scenes_load_and_show_their_objects(path, tmp_path):
    """The hand-written check scenes (docs/journal/benchmarks.md, "The closed loop's plans") stay
    loadable, and their inputs see something besides sky."""
    from aes_planner.eval.search import _free_platform, _inputs, _source
    from aes_planner.sim.scene import load_scene

    cfg = tiny(tmp_path)
    source = _source(load_scene(str(path)), cfg)
    platform = _free_platform(source, cfg.free_box_m)
    frames = [source.capture(p) for p in _inputs(source, platform, 4)]
    depth_m = np.stack([f.depth_m for f in frames])  # [4, h, w], 0 = sky
    assert (depth_m > 0).mean() > 0.3


def test_repeated_scenes_views_and_modes_count_once(caplog):
    """indoor:100 twice gave n = 2 and a standard error of 0 from one scene."""
    from aes_planner.eval.field import FieldEvalConfig

    with caplog.at_level("WARNING"):
        cfg = SearchEvalConfig(scenes=["indoor:100", "indoor:100"], views=[2, 2], modes=["rig", "rig"])
    assert (cfg.scenes, cfg.views, cfg.modes) == (["indoor:100"], [2], ["rig"])
    assert "indoor:100 given more than once" in caplog.text
    assert FieldEvalConfig(views=[4, 2, 4]).views == [4, 2]


def test_covered_oracle_is_the_best_grid_view_the_inputs_cover(tmp_path):
    """What one shot can know: never above the oracle, a view the inputs cover, and the oracle's
    own coverage reported beside it (below 1: part of the best view was never seen)."""
    from aes_planner.eval.search import _inputs, _source, covered_oracle, scene_oracle
    from aes_planner.search import SearchConfig, build_search_scorer
    from aes_planner.sim.scene import load_scene
    from aes_planner.teachers import get_teacher

    cfg = tiny(tmp_path, modes=["rig"], methods=["oracle", "covered_oracle"])
    doc = run_search_eval(cfg)
    row = doc["per_scene"][0]
    assert row["methods"]["covered_oracle"]["teacher"] <= row["methods"]["oracle"]["teacher"] + 1e-9
    assert 0.0 <= row["oracle_coverage"] <= 1.0
    teacher = get_teacher()
    source = _source(load_scene("tabletop:102"), cfg)
    o_score, o_pose, o_extra = scene_oracle("tabletop:102", source, teacher, source.platform, cfg)
    inputs = _inputs(source, source.platform, 2)
    frames = [source.capture(p) for p in inputs]
    pose, _ = covered_oracle(frames, source.platform, o_pose, o_extra, teacher)
    grid = _grid_poses(source, o_extra)  # [G, 4, 4]
    scfg = SearchConfig.preset("balanced")
    with torch.no_grad():
        alpha = build_search_scorer("rgb", frames, scfg, teacher).render(torch.as_tensor(grid))[1]
    cov = alpha.double().mean((1, 2)).numpy()  # [G]
    chosen = int(np.argmin(np.abs(grid - pose[None]).reshape(len(grid), -1).max(1)))
    assert np.allclose(grid[chosen], pose)  # one of the oracle grid's views
    covered = cov >= scfg.coverage_min
    if covered.any():  # the best-scoring covered view
        assert covered[chosen]
        assert o_extra["grid_scores"][chosen] == pytest.approx(o_extra["grid_scores"][covered].max())
    else:  # nothing covered: the best-covered view
        assert cov[chosen] == pytest.approx(cov.max())


def _grid_poses(source, o_extra):
    from aes_planner.search import SearchConfig
    from aes_planner.search.space import space_for

    space = space_for(source.platform, SearchConfig())
    return space.to_poses(torch.as_tensor(o_extra["grid_params"])).numpy()


def test_the_search_seed_moves_the_searches_not_the_oracle(tmp_path, monkeypatch):
    """``--search-seed`` (the spread over seeds): the presets search with it, the oracle and the
    random views (the normalisation) keep ``seed``; a negative one is refused, naming the field."""
    from aes_planner.config import ConfigError
    from aes_planner.eval import search as ev

    with pytest.raises(ConfigError, match="search_seed"):
        tiny(tmp_path, search_seed=-1)
    seen = []
    real = ev.search_views
    monkeypatch.setattr(ev, "search_views", lambda scorer, inputs, platform, cfg: seen.append(cfg.seed) or real(scorer, inputs, platform, cfg))  # fmt: skip
    a = run_search_eval(tiny(tmp_path, modes=["rig"], methods=["field_fast", "oracle", "random"]))
    b = run_search_eval(tiny(tmp_path, modes=["rig"], methods=["field_fast", "oracle", "random"], search_seed=3))
    assert seen == [0, 0, 3, 3]  # the warm-up's and the method's search, each run
    assert b["search_seed"] == 3 and a["search_seed"] == 0
    assert a["per_scene"][0]["oracle"] == b["per_scene"][0]["oracle"]
    assert a["per_scene"][0]["mean_random"] == b["per_scene"][0]["mean_random"]
