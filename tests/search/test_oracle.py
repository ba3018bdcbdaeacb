"""Ground-truth scorer and oracle on a tiny simulated scene (32 x 24 renders, coarse grids)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from aes_planner.geometry import PanTilt
from aes_planner.platform import DroneBox, DronePlatform
from aes_planner.search import GroundTruthScorer, SearchConfig, oracle_search, search_views
from aes_planner.sim import SimCameraConfig, SimSource
from aes_planner.teachers import get_teacher


@pytest.fixture(scope="module")
def tiny():
    source = SimSource("tabletop:0", supersample=1, camera=SimCameraConfig(width=32, height=24))
    return source, get_teacher()


def test_ground_truth_scorer_matches_teacher(tiny):
    source, teacher = tiny
    pt = PanTilt(source.platform.rig)
    poses = torch.as_tensor(pt.forward(np.array([0.0, 0.3]), np.array([-0.2, 0.1])))
    scorer = GroundTruthScorer(source, teacher)
    out = scorer.score(poses)
    images = torch.from_numpy(source.render_rgb(poses.numpy())).permute(0, 3, 1, 2)
    torch.testing.assert_close(out.score, teacher.score(images))
    assert torch.equal(out.coverage, torch.ones(2)) and not scorer.differentiable
    assert set(out.terms) >= {"score"} and scorer.renders == 2


def test_search_on_ground_truth_improves_on_inputs(tiny):
    source, teacher = tiny
    pt = PanTilt(source.platform.rig)
    j = pt.sweep(3)
    inputs = pt.forward(j[:, 0], j[:, 1])
    scorer = GroundTruthScorer(source, teacher)
    cfg = SearchConfig.preset("fast", steps=3)
    result = search_views(scorer, inputs, source.platform, cfg)
    best_input = float(scorer.score(torch.as_tensor(inputs)).score.max())
    assert result.best.score >= best_input - 1e-6  # the inputs are candidates of stage 1
    assert pt.within_limits(result.best.pan_rad, result.best.tilt_rad)


def test_oracle_rig_is_cached_and_beats_its_grid(tiny, tmp_path):
    source, teacher = tiny
    kw = dict(step_deg=30.0, refine_starts=1, min_step_deg=10.0, random_samples=4, cache_dir=tmp_path)
    best, pose, extras = oracle_search(source, teacher, **kw)
    assert not extras["cached"] and best >= float(extras["grid_scores"].max()) - 1e-9
    assert extras["grid_scores"].shape == (len(extras["pan_values"]) * len(extras["tilt_values"]),)
    pt = PanTilt(source.platform.rig)
    pan, tilt = extras["best_params"]
    assert pt.within_limits(pan, tilt)
    np.testing.assert_allclose(pt.forward(pan, tilt), pose, atol=1e-12)
    again = oracle_search(source, teacher, **kw)
    assert again[2]["cached"] and again[0] == best
    np.testing.assert_array_equal(again[1], pose)
    files = sorted(p.suffix for p in tmp_path.iterdir())
    assert files == [".json", ".npz"]
    assert json.loads(next(tmp_path.glob("*.json")).read_text())["step_deg"] == 30.0
    # a different setting is a different cache entry
    assert not oracle_search(source, teacher, **{**kw, "random_samples": 3})[2]["cached"]


def test_oracle_free_inside_box(tiny, tmp_path):
    source, teacher = tiny
    box = DroneBox((-0.5, -0.5, 1.0), (0.5, 0.5, 1.5))
    platform = DronePlatform(source.platform.intrinsics, box)
    best, pose, extras = oracle_search(
        source, teacher, platform, free_positions=(1, 1, 1), free_step_deg=90.0, refine_starts=1,
        min_step_deg=45.0, random_samples=2, cache_dir=tmp_path,
    )  # fmt: skip
    assert box.contains(pose[:3, 3]) and np.isfinite(best)
    assert best >= float(extras["grid_scores"].max()) - 1e-9


def test_search_on_an_empty_scene(tmp_path):
    """Nothing in view (sky only): the ground-truth search still returns a finite view inside the limits."""
    scene = tmp_path / "empty.yaml"
    scene.write_text("name: empty\nobjects: []\nrig:\n  pan_tilt:\n    pan_limits_deg: [-90, 90]\n")
    source = SimSource(str(scene), supersample=1, camera=SimCameraConfig(width=16, height=12))
    pt = PanTilt(source.platform.rig)
    j = pt.sweep(2)
    result = search_views(
        GroundTruthScorer(source, get_teacher()), pt.forward(j[:, 0], j[:, 1]), source.platform,
        SearchConfig.preset("fast", steps=2),
    )  # fmt: skip
    best = result.best
    assert np.isfinite(best.score) and np.all(np.isfinite(best.cam2world))
    assert pt.within_limits(best.pan_rad, best.tilt_rad)
