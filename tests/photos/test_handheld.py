"""The hand-held search space: the region walked (capsules around the paths between the photos'
cameras), its projection, its random poses and its place in a folder's metadata."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from aes_planner.config import ConfigError
from aes_planner.geometry.camera import Intrinsics
from aes_planner.platform import HandHeldPlatform, platform_from_meta, walked_edges
from aes_planner.search import SearchConfig
from aes_planner.search.space import random_poses, space_for

K = Intrinsics.from_fov(64, 48, 60.0)
CENTRES = ((0.0, 0.0, 1.5), (1.0, 0.0, 1.5), (2.0, 0.5, 1.6), (3.0, 1.5, 1.5))


def _platform(margin=0.3) -> HandHeldPlatform:
    return HandHeldPlatform(K, CENTRES, margin, (-30.0, 10.0))


def test_the_walk_links_neighbours_whatever_the_file_order():
    shuffled = np.asarray(CENTRES)[[2, 0, 3, 1]]
    edges = {tuple(sorted(e)) for e in walked_edges(shuffled).tolist()}
    # back in the shuffled indices: 0-1, 1-2, 2-3 of the walk are (1, 3), (3, 0), (0, 2)
    assert edges == {(1, 3), (0, 3), (0, 2)}


def test_contains_and_clamp():
    p = _platform()
    assert bool(p.contains([0.5, 0.2, 1.5])) and not bool(p.contains([0.5, 1.0, 1.5]))
    pose = np.eye(4)
    pose[:3, 3] = [0.5, 1.0, 1.5]  # 1 m beside the first segment
    clamped = p.clamp(pose)
    np.testing.assert_allclose(clamped[:3, 3], [0.5, 0.3, 1.5], atol=1e-12)
    assert p.clamp(clamped) is clamped  # inside: unchanged


@given(st.lists(st.floats(-20, 20), min_size=5, max_size=5))
def test_the_projection_lands_inside_and_is_idempotent(values):
    space = space_for(_platform(), SearchConfig.preset("fast", mode="handheld"))
    params = torch.tensor([values], dtype=torch.float64)
    once = space.project(params)
    assert torch.isfinite(once).all()
    assert bool(_platform().contains(once[0, :3].numpy()))
    lo, hi = space.lower[4], space.upper[4]
    assert lo - 1e-12 <= once[0, 4] <= hi + 1e-12
    torch.testing.assert_close(space.project(once), once)


def test_the_pitch_range_is_the_photos_and_the_search_presets_read_handheld():
    cfg = SearchConfig.preset("balanced", mode="handheld")
    space = space_for(_platform(), cfg)
    assert space.kind == "handheld"
    np.testing.assert_allclose(np.degrees([float(space.lower[4]), float(space.upper[4])]), [-30.0, 10.0])


def test_random_poses_stay_in_the_region():
    p = _platform()
    poses = random_poses(p, 200, np.random.default_rng(0))
    assert bool(p.contains(poses[:, :3, 3]).all())
    # spread along the whole walk, not bunched at one camera
    assert poses[:, 0, 3].min() < 0.5 and poses[:, 0, 3].max() > 2.5


def test_around_photos_takes_a_quarter_of_the_spread_and_the_photos_pitches():
    from aes_planner.geometry.poses import view_to_cam2world

    views = np.array([[0, 0, 1.5, 0, -0.3], [2, 0, 1.5, 0.2, -0.1], [4, 0, 1.5, 0.4, -0.2]])
    p = HandHeldPlatform.around_photos(K, view_to_cam2world(views))
    assert p.margin_m == pytest.approx(1.0)
    assert p.pitch_limits_deg == pytest.approx((np.degrees(-0.3) - 10, np.degrees(-0.1) + 10))


def test_meta_round_trip_and_refusals():
    p = _platform()
    back = platform_from_meta(p.to_meta(), K)
    assert back == p
    meta = p.to_meta()
    meta["handheld"]["margin_m"] = -1.0
    with pytest.raises(ConfigError, match="margin_m"):
        platform_from_meta(meta, K)
    meta = p.to_meta()
    meta["handheld"]["centres_m"] = [[0.0, float("nan"), 1.0]]
    with pytest.raises(ConfigError):
        platform_from_meta(meta, K)
    meta = p.to_meta()
    del meta["handheld"]["pitch_limits_deg"]
    with pytest.raises(ConfigError, match="pitch_limits_deg"):
        platform_from_meta(meta, K)


def test_importing_the_package_and_the_commands_loads_no_pycolmap():
    import subprocess
    import sys

    code = (
        "import sys, aes_planner, aes_planner.photos, aes_planner.cli, aes_planner.bench.photos;"
        "from aes_planner.cli import build_parser; build_parser();"
        "print('pycolmap' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.strip() == "False"
