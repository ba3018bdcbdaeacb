"""Refinement at the best photo: the photos warped into a nearby view stand for it, and the view
picked there beats the best photo on the scene's true render."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aes_planner.bench.photos import render_photo_set
from aes_planner.config import ConfigError
from aes_planner.geometry.poses import cam2world_to_view, view_to_cam2world
from aes_planner.photos.refine import (
    RefineConfig,
    estimate_error,
    photo_composite,
    refine_at_best_photo,
    subject_distance,
)
from aes_planner.platform import HandHeldPlatform
from aes_planner.sim import load_scene, render
from aes_planner.teachers import get_teacher


@pytest.fixture(scope="module")
def cc0_walk(tmp_path_factory):
    """Ten 320 x 240 views of a CC0-photo scene on a hand-held arc, as photos (JPEG, read back) with
    their true poses, and the scene to render any other view."""
    import cv2

    images_dir, truth, scene_file = render_photo_set(tmp_path_factory.mktemp("walk"), 10, (320, 240), seed=3)
    images = [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in sorted(images_dir.glob("*.jpg"))]
    return images, truth, load_scene(scene_file, allow_outside=True)


@pytest.fixture(scope="module")
def refined(cc0_walk):
    """``refined(cfg)``: the walk refined with the composition teacher under ``cfg``, computed once
    per config for the module (each is 5-9 s at load 10; tests asking the same question share it)."""
    images, truth, scene = cc0_walk
    found = {}

    def run(cfg: RefineConfig):
        if cfg not in found:
            found[cfg] = refine_at_best_photo(get_teacher(), truth, images, scene.intrinsics(), cfg)
        return found[cfg]

    return run


def _teacher_scores(teacher, images) -> np.ndarray:
    import torch

    x = torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).float() / 255.0
    with torch.no_grad():
        return teacher.score(x).double().numpy()


def test_a_turn_on_the_spot_is_the_photo_warped(cc0_walk):
    images, truth, scene = cc0_walk
    k = scene.intrinsics()
    v = cam2world_to_view(truth[4])
    turned = view_to_cam2world(v + np.array([0, 0, 0, math.radians(4), math.radians(-3)]))
    want = render(scene, turned, k).rgb.astype(np.float64)  # [H, W, 3]
    got, cover, own = photo_composite([images[4]], truth[4:5], k.K, turned, [0], None)
    assert 0.8 < cover < 1.0 and own == cover  # the photo covers most of the turned view, not all of it
    err_warped = np.abs(got.astype(np.float64) - want).mean()
    err_as_is = np.abs(images[4].astype(np.float64) - want).mean()
    err_jpeg = np.abs(images[4].astype(np.float64) - render(scene, truth[4], k).rgb).mean()  # the photo at its own pose
    assert err_warped < 0.45 * err_as_is and err_warped < 2 * err_jpeg, (err_warped, err_as_is, err_jpeg)
    # with its neighbours the whole view is covered
    _, cover_all, own_all = photo_composite(images, truth, k.K, turned, [4, 3, 5, 2, 6], None)
    assert cover_all > cover and own_all == cover


def test_the_pick_beats_the_best_photo_on_the_true_render(cc0_walk):
    images, truth, scene = cc0_walk
    k = scene.intrinsics()
    teacher = get_teacher()
    platform = HandHeldPlatform.around_photos(k, truth)
    found = refine_at_best_photo(teacher, truth, images, k, RefineConfig(), platform)
    cands, best = found.suggestions, found.best_photo
    assert best == int(np.argmax(_teacher_scores(teacher, images)))
    assert set(found.photo_of.tolist()) <= set(np.argsort(-found.photo_scores)[:2].tolist())
    assert np.all(found.own_cover > 0.5)
    assert len(cands) > 50 and found.confident and found.pick is cands[0] and cands[0].terms["photo_gain"] > 0
    assert all(bool(platform.contains(c.position_m)) for c in cands)
    # ranked by the lower bound: the prediction less one expected error of the estimate
    low = np.array([c.terms["photo_gain_low"] for c in cands])
    assert np.all(np.diff(low) <= 1e-12)
    np.testing.assert_allclose(low, [c.terms["photo_gain"] - c.terms["estimate_error"] for c in cands])
    assert low[0] >= RefineConfig().min_gain
    # the photo itself (levelled) is one of the candidates
    base = cam2world_to_view(truth[best])
    assert any(np.allclose(cam2world_to_view(c.cam2world), base, atol=1e-9) for c in cands)
    true = _teacher_scores(teacher, [render(scene, c.cam2world, k).rgb for c in cands[:1]])
    true_photos = _teacher_scores(teacher, [render(scene, p, k).rgb for p in truth])
    assert true[0] > true_photos.max() + 0.01, (true[0], true_photos.max())


def test_not_trusted_gives_the_best_photo_as_taken(cc0_walk, refined):
    images, truth, scene = cc0_walk
    teacher = get_teacher()
    # no refined view clears the best photo by 0.5 after its expected error: the photo itself, as taken
    found = refined(RefineConfig(min_gain=0.5))
    assert found.suggestions and not found.confident
    pick = found.pick
    np.testing.assert_array_equal(pick.cam2world, truth[found.best_photo])  # with its roll
    assert pick.score == found.photo_scores.max() and pick.terms["photo_gain"] == 0.0
    # more caution lowers every candidate's bound by its expected error, never its prediction
    bold = refine_at_best_photo(teacher, truth, images, scene.intrinsics(), RefineConfig(caution=0.0))
    assert all(c.terms["photo_gain_low"] == pytest.approx(c.terms["photo_gain"]) for c in bold.suggestions)
    assert max(c.score for c in bold.suggestions) == pytest.approx(max(c.score for c in found.suggestions))


def _turned(rb, dy_deg, dp_deg):  # [3, 3] the photo's rotation turned about the vertical, tilted about its right axis
    a, p = math.radians(dy_deg), math.radians(dp_deg)
    rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    return rz @ rb @ rx


def _grid_of(rot, rb, cfg) -> tuple[float, float] | None:
    """The grid's (turn, tilt) that gives ``rot`` from the photo's ``rb`` with its roll kept, or None."""
    steps = np.arange(-cfg.max_turn_deg, cfg.max_turn_deg + 1e-9, cfg.turn_step_deg)
    return next(((dy, dp) for dy in steps for dp in steps if np.allclose(rot, _turned(rb, dy, dp), atol=1e-9)), None)


def test_keep_roll_turns_the_photo_as_it_was_taken(cc0_walk, refined):
    images, truth, scene = cc0_walk
    cfg = RefineConfig(keep_roll=True, forward_fracs=(0.0,), around_best=1)
    found = refine_at_best_photo(get_teacher(), truth, images, scene.intrinsics(), cfg)
    b = found.best_photo
    rb = truth[b, :3, :3]
    assert abs(rb[2, 0]) > 1e-3  # the hand's roll jitter: the photo is not level
    assert len(found.suggestions) > 5 and set(found.photo_of.tolist()) == {b}
    # every candidate is the photo as taken turned about the vertical and tilted about its own right
    # axis, on the spot; the photo itself is not one of them (it is the as-taken answer, its score exact)
    grid = [_grid_of(c.cam2world[:3, :3], rb, cfg) for c in found.suggestions]
    assert None not in grid and (0.0, 0.0) not in grid
    assert all(np.allclose(c.position_m, truth[b, :3, 3]) for c in found.suggestions)
    # the pure turns keep the photo's roll (its right axis's height); the levelled grid's are level
    assert all(np.isclose(c.cam2world[2, 0], rb[2, 0]) for c, (_, dp) in zip(found.suggestions, grid) if dp == 0)
    levelled = refined(RefineConfig(around_best=1))
    assert all(abs(c.cam2world[2, 0]) < 1e-9 for c in levelled.suggestions)


def test_the_fallback_turn_is_the_best_photo_turned_on_the_spot(cc0_walk, refined):
    images, truth, scene = cc0_walk
    teacher = get_teacher()
    # nothing is trusted (min_gain 0.5): the fall-back turns the best photo as taken on the spot
    cfg = RefineConfig(min_gain=0.5, fallback_turn=True, fallback_min_gain=-1.0)
    found = refine_at_best_photo(teacher, truth, images, scene.intrinsics(), cfg)
    b = found.best_photo
    assert not found.confident and found.kind == "turn" and found.pick is found.turn
    turn = found.turn
    np.testing.assert_allclose(turn.position_m, truth[b, :3, 3], atol=1e-9)  # on the spot
    assert _grid_of(turn.cam2world[:3, :3], truth[b, :3, :3], cfg) not in (None, (0.0, 0.0))  # its roll kept
    assert turn.terms["photo_gain_low"] == pytest.approx(turn.terms["photo_gain"] - turn.terms["estimate_error"])
    # the fall-back's views are not ranked with the grid (which stays the levelled one)
    assert all(abs(c.cam2world[2, 0]) < 1e-9 for c in found.suggestions)
    # without it, or when no turn clears the best photo by fallback_min_gain: the photo as taken
    for strict in (RefineConfig(min_gain=0.5), RefineConfig(min_gain=0.5, fallback_turn=True, fallback_min_gain=0.5)):
        none = refined(strict)
        assert none.kind == "as_taken" and none.turn is None and none.pick is none.as_taken
    # trusted: the refined view, whatever the fall-back
    bold = refine_at_best_photo(teacher, truth, images, scene.intrinsics(), RefineConfig(fallback_turn=True))
    assert bold.kind == "refined" and bold.pick is bold.suggestions[0] and bold.turn is None


def test_the_estimate_error_grows_with_the_step_and_the_other_photos_share():
    base = estimate_error(0.0, 1.0)
    assert 0.0 < base < estimate_error(0.3, 1.0) and base < estimate_error(0.0, 0.8)
    assert estimate_error(np.array([0.0, 0.3]), np.array([1.0, 0.5])).shape == (2,)


def test_off_or_photos_of_two_sizes_gives_nothing(cc0_walk):
    images, truth, scene = cc0_walk
    teacher = get_teacher()
    off = refine_at_best_photo(teacher, truth, images, scene.intrinsics(), RefineConfig(max_turn_deg=0))
    assert off.suggestions == [] and off.best_photo == -1
    mixed = [images[0][:200], *images[1:]]
    assert refine_at_best_photo(teacher, truth, mixed, scene.intrinsics(), RefineConfig()).suggestions == []


def test_refining_at_one_or_three_photos(refined):
    one = refined(RefineConfig(around_best=1))
    assert set(one.photo_of.tolist()) == {one.best_photo}
    found = refined(RefineConfig(around_best=3))
    three = np.argsort(-found.photo_scores)[:3]
    assert set(found.photo_of.tolist()) == set(three.tolist())
    gains = [s.terms["photo_gain"] for s in found.suggestions]
    np.testing.assert_allclose(gains, [s.score - found.photo_scores.max() for s in found.suggestions])


def test_subject_distance_meets_the_axes_in_front():
    from aes_planner.geometry.poses import look_at

    target = np.array([3.0, 0.0, 0.7])
    poses = np.stack([look_at(np.array([3 - 4 * math.cos(a), 4 * math.sin(a), 1.5]), target) for a in (-0.5, 0, 0.5)])
    d = subject_distance(poses, 1)
    assert d == pytest.approx(np.linalg.norm(poses[1, :3, 3] - target), rel=1e-6)
    parallel = poses.copy()
    parallel[:, :3, :3] = poses[1, :3, :3]
    assert subject_distance(parallel, 0) is None  # all axes parallel: no subject to step towards


@pytest.mark.parametrize(
    "field, value",
    [("max_turn_deg", -1.0), ("max_turn_deg", float("nan")), ("turn_step_deg", 0.0), ("forward_fracs", (0.9,)),
     ("forward_fracs", ()), ("work_width_px", 8), ("min_photo_cover", 0.0), ("around_best", 0),
     ("caution", -0.5), ("min_gain", 2.0), ("keep_roll", 1), ("fallback_turn", "yes"), ("fallback_min_gain", 2.0),
     ("fallback_min_own", 1.5), ("plane_depth", 0.1), ("plane_depth", float("nan"))],
)  # fmt: skip
def test_config_names_the_bad_field(field, value):
    with pytest.raises(ConfigError, match=field if field != "max_turn_deg" or value == value else "refine"):
        RefineConfig(**{field: value})


@settings(max_examples=30, deadline=None)
@given(
    yaw=st.floats(-0.3, 0.3), pitch=st.floats(-0.3, 0.3), fwd=st.floats(-1e6, 1e6, allow_nan=False)
)  # fmt: skip
def test_composite_is_finite_for_any_view_near_or_far(yaw, pitch, fwd):
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(2)]
    k = np.array([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])
    photos = np.stack([view_to_cam2world(np.array([0, y, 1.5, 0, 0.0])) for y in (0.0, 0.5)])
    target = view_to_cam2world(np.array([fwd, 0, 1.5, yaw, pitch]))
    img, cover, own = photo_composite(images, photos, k, target, [0, 1], (np.array([1.0, 0, 0]), 5.0))
    assert img.shape == (24, 32, 3) and img.dtype == np.uint8 and 0.0 <= own <= cover <= 1.0
