"""Bad-input sweep of the search API: inputs and platforms that are not what the
search needs are a SearchError naming them, never an AttributeError or a silent result."""

import numpy as np
import pytest

from aes_planner.search import SearchConfig, SearchError, search_views
from tests.search.test_search import AimScorer, rig_inputs, rig_platform


def scaled(p):
    p = p.copy()
    p[:, :3, :3] *= 2.0
    return p


def mirrored(p):
    p = p.copy()
    p[:, :, 0] *= -1.0
    return p


def sheared(p):
    p = p.copy()
    p[:, 0, 1] += 0.3
    return p


def bad_last_row(p):
    p = p.copy()
    p[:, 3, 0] = 1.0
    return p


def huge(p):
    p = p.copy()
    p[:, :3, 3] = 1e300
    return p


@pytest.mark.parametrize("make", [scaled, mirrored, sheared, bad_last_row, huge])
def test_search_refuses_non_rigid_inputs(make, clean_error):
    platform = rig_platform()
    inputs = rig_inputs(platform)
    cfg = SearchConfig.preset("fast", steps=0)
    clean_error(
        search_views, AimScorer(np.array([1.0, 0.0, 0.0])), make(inputs), platform, cfg, match="inputs_cam2world"
    )


@pytest.mark.parametrize("platform", [None, "rig", {"kind": "rig"}])
def test_search_refuses_what_is_not_a_platform(platform):
    inputs = rig_inputs(rig_platform())
    with pytest.raises(SearchError, match="platform"):
        search_views(AimScorer(np.array([1.0, 0.0, 0.0])), inputs, platform, SearchConfig.preset("fast", steps=0))


DAMAGES = {
    "truncated": lambda p: p.write_bytes(p.read_bytes()[:100]),
    "nan": lambda p: np.savez(p, **{**dict(np.load(p)), "best_score": np.float64("nan")}),
    "objects": lambda p: np.savez(p, **{**dict(np.load(p)), "best_cam2world": np.array([{}], dtype=object)}),
}


@pytest.mark.parametrize("how", sorted(DAMAGES))
def test_oracle_recomputes_a_damaged_cache_file(tmp_path, how):
    from aes_planner.search import oracle_search
    from aes_planner.sim import SimSource
    from aes_planner.sim.camera import SimCameraConfig
    from aes_planner.teachers import get_teacher

    source = SimSource("tabletop:0", supersample=1, camera=SimCameraConfig(width=16, height=12))
    kw = dict(step_deg=45.0, refine_starts=1, min_step_deg=30.0, random_samples=2, cache_dir=tmp_path)
    best, pose, _ = oracle_search(source, get_teacher(), **kw)
    (npz,) = tmp_path.glob("*.npz")
    DAMAGES[how](npz)
    again, pose2, extras = oracle_search(source, get_teacher(), **kw)
    assert not extras["cached"] and again == best and np.array_equal(pose, pose2)
    assert oracle_search(source, get_teacher(), **kw)[2]["cached"]  # rewritten whole
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".json", ".npz"]  # no temporary left


def test_reversed_and_strided_pose_views_are_poses_like_any_other():
    """numpy views with negative strides (poses[::-1]) raised torch's ValueError everywhere."""
    from aes_planner.geometry import cam2world_to_view, world2cam

    platform = rig_platform()
    inputs = rig_inputs(platform)
    cfg = SearchConfig.preset("fast", steps=0)
    scorer = AimScorer(np.array([1.0, 0.0, 0.0]))
    got = search_views(scorer, inputs[::-1], platform, cfg).best
    want = search_views(scorer, np.ascontiguousarray(inputs[::-1]), platform, cfg).best
    np.testing.assert_allclose(got.cam2world, want.cam2world)
    np.testing.assert_allclose(cam2world_to_view(inputs[::-1]), cam2world_to_view(inputs.copy()[::-1].copy()))
    np.testing.assert_allclose(
        world2cam(inputs[::-1])[0], world2cam(inputs[-1]), atol=1e-12
    )  # a batch may round differently


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(cfg={"steps": 1}), "cfg must be a SearchConfig"),
        (dict(inputs_cam2world="abc"), "inputs_cam2world must be poses"),
        (dict(inputs_cam2world=[np.eye(4), np.eye(3)]), "inputs_cam2world must be poses"),
        (dict(avoid=5), "avoid must be"),
        (dict(avoid=np.eye(3)[None]), "avoid must be"),
    ],
)
def test_search_arguments_are_named(kwargs, match, clean_error):
    platform = rig_platform()
    args = dict(inputs_cam2world=rig_inputs(platform), cfg=SearchConfig.preset("fast", steps=0))
    args.update(kwargs)
    scorer = AimScorer(np.array([1.0, 0.0, 0.0]))
    clean_error(search_views, scorer, args["inputs_cam2world"], platform, args["cfg"], args.get("avoid"), match=match)


@pytest.mark.parametrize(
    "override",
    [
        {"seed": -1},
        {"pitch_limits_deg": None},
        {"pitch_limits_deg": 5},
        {"jitter_fov": 1e308},
        {"shift_frac": 1e308},
        {"coverage_penalty": 1e39},
    ],
)
def test_search_settings_that_would_overflow_or_crash_later_are_refused(override):
    from aes_planner.config import ConfigError

    with pytest.raises(ConfigError, match=next(iter(override))):
        SearchConfig.preset("fast", **override)


def test_a_field_of_no_frames_is_refused_like_rgb_scoring():
    from aes_planner.search import build_search_scorer

    for kind in ("field", "rgb"):
        with pytest.raises(SearchError, match="no frames"):
            build_search_scorer(kind, [], SearchConfig.preset("fast"))
